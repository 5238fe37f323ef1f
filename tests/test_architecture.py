"""The package's imports follow its data flow, and its light modules stay light.

robot model -> symbolic dynamics -> OCP -> solver -> controller -> estimator -> logs -> plant/loop -> plots,
``analysis`` (what a robot's log says, and the emulated-robot runs it is checked on) after the loop, with
``studies`` (the command lines) on top and ``checks`` / ``quick`` (argument checks, the quick-mode flag)
usable everywhere. The edges are read from the source (every ``import``, lazy ones inside functions too).
"""

import ast
import re
import subprocess
import sys
import textwrap
from collections import defaultdict
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "wbmpc"

UTILITIES = {"checks", "quick"}
#: Subpackage -> the subpackages it may import (besides itself and the utilities).
ALLOWED = {
    "model": set(),
    "cpin": set(),
    "ocp": {"model", "cpin"},
    "solver": {"ocp"},
    "control": {"model", "ocp", "solver"},
    "estimation": {"model"},
    "io": {"model", "estimation"},
    "sim": {"model", "ocp", "solver", "control", "estimation", "io"},
    "viz": {"model"},
    "analysis": {"model", "ocp", "control", "io", "sim"},
    "runtime": {"model", "ocp", "solver", "control", "estimation", "io", "sim"},
    "studies": {"model", "ocp", "solver", "control", "estimation", "io", "sim", "viz", "analysis", "runtime"},
}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports() -> dict[str, set[str]]:
    """Module -> the wbmpc modules it imports (``from wbmpc.x import y`` counts ``wbmpc.x.y`` if a module)."""
    modules = {_module_name(p) for p in PACKAGE.rglob("*.py")}
    out = defaultdict(set)
    for path in PACKAGE.rglob("*.py"):
        me = _module_name(path)
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "wbmpc":
                for alias in node.names:
                    full = f"{node.module}.{alias.name}"
                    out[me].add(full if full in modules else node.module)
            elif isinstance(node, ast.Import):
                out[me] |= {a.name for a in node.names if a.name.split(".")[0] == "wbmpc"}
    return {m: {t for t in out[m] if t != m} for m in modules}


def _subpackage(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else None


def test_every_subpackage_is_in_the_table():
    found = {p.name for p in PACKAGE.iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    assert found == set(ALLOWED), "add the new subpackage to ALLOWED with the edges the data flow permits"


def test_imports_between_subpackages_follow_the_data_flow():
    wrong = []
    for module, targets in sorted(_imports().items()):
        src = _subpackage(module)
        for target in sorted(targets):
            dst = _subpackage(target)
            if src is None or dst is None or dst == src or dst in UTILITIES:
                continue
            if src in UTILITIES or dst not in ALLOWED.get(src, set()):
                wrong.append(f"{module} imports {target} ({src} -> {dst})")
    assert not wrong, "imports against the data flow:\n" + "\n".join(wrong)


def test_no_import_cycles_between_modules():
    graph = _imports()
    state, cycles = {}, []

    def visit(node, path):
        state[node] = "open"
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == "open":
                cycles.append(" -> ".join([*path[path.index(nxt) :], nxt]))
            elif nxt not in state:
                visit(nxt, [*path, nxt])
        state[node] = "done"

    for module in sorted(graph):
        if module not in state:
            visit(module, [module])
    # A package's __init__ importing its own modules is how packages re-export: not a cycle of concern.
    cycles = [c for c in cycles if not all(part.startswith(c.split(" -> ")[0]) for part in c.split(" -> "))]
    assert not cycles, "import cycles:\n" + "\n".join(cycles)


def test_the_log_format_imports_nothing_heavy():
    """``import wbmpc.io.logs`` (reading a run's log) loads neither casadi nor pybullet nor a BLASFEO."""
    code = textwrap.dedent(
        """
        import sys
        import wbmpc.io.logs
        names = ("casadi", "pybullet", "pinocchio", "wbmpc.solver.blasfeo")
        heavy = sorted(m for m in names if m in sys.modules)
        maps = open("/proc/self/maps").read() if sys.platform.startswith("linux") else ""
        print(heavy, "blasfeo" in maps)
        """
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["[]", "False"], out.stdout


def test_the_readme_module_table_matches_the_tree():
    """Every module and subpackage of each ``wbmpc/<subpackage>/`` is named in the README's table, and
    every file the table names exists (a module added, moved or removed shows here)."""
    readme = (PACKAGE.parent / "README.md").read_text()
    rows = re.findall(r"^\| `wbmpc/(\w+)/` \| (.*?) \|", readme, flags=re.M)
    assert rows, "no module table in the README"
    tabled = {name for name, _ in rows}
    packages = {p.parent.name for p in PACKAGE.glob("*/__init__.py")}
    assert tabled == packages, f"README table rows {sorted(tabled)} != subpackages {sorted(packages)}"
    for name, cell in rows:
        listed = set(re.findall(r"`([\w/.]+)`", cell))
        folder = PACKAGE / name
        present = {p.name for p in folder.glob("*.py") if p.name != "__init__.py"}
        present |= {f"{p.parent.name}/" for p in folder.glob("*/__init__.py")}
        missing = present - listed
        assert not missing, f"wbmpc/{name}/: {sorted(missing)} not in the README's table"
        for item in listed:
            assert next(folder.rglob(item.rstrip("/")), None) is not None, f"README names wbmpc/{name}/{item}"
