"""Notebook hygiene: committed notebooks are clean, well named, titled and quick-mode aware.

Each notebook under ``notebooks/`` is its own test id. The ``check_*`` helpers take a path so they
can be pointed at any notebook.
"""

from __future__ import annotations

import io
import re
from pathlib import Path

import nbformat
import numpy as np
import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
NAME_RE = re.compile(r"^\d{2}_[a-z0-9]+(?:_[a-z0-9]+)*\.ipynb$")
QUICK_MARKERS = ("pick(", "quick_mode(")


def find_notebooks(root: Path = REPO_ROOT) -> list[Path]:
    """Return the sorted ``notebooks/*.ipynb`` files under ``root``."""
    return sorted((root / "notebooks").glob("*.ipynb"))


def _read(path: Path) -> nbformat.NotebookNode:
    return nbformat.read(path, as_version=4)


def check_no_outputs(path: Path) -> list[str]:
    """Problems with code cells that carry outputs or an execution count."""
    problems = []
    for i, cell in enumerate(_read(path).cells):
        if cell.cell_type != "code":
            continue
        if cell.get("outputs"):
            problems.append(f"cell {i}: has {len(cell.outputs)} output(s)")
        if cell.get("execution_count") is not None:
            problems.append(f"cell {i}: execution_count={cell.execution_count}")
    return problems


def check_name(path: Path) -> list[str]:
    """Problems with the file name (must be ``NN_lower_snake.ipynb``)."""
    if NAME_RE.match(path.name):
        return []
    return [f"name {path.name!r} is not NN_lower_snake_topic.ipynb"]


def check_title(path: Path) -> list[str]:
    """Problems with the first cell (must be markdown starting with a ``# `` title)."""
    cells = _read(path).cells
    if not cells:
        return ["notebook has no cells"]
    first = cells[0]
    if first.cell_type != "markdown":
        return [f"first cell is {first.cell_type}, not markdown"]
    lines = [line for line in first.source.splitlines() if line.strip()]
    if not lines or not lines[0].startswith("# "):
        return ["first cell does not start with a '# ' title"]
    return []


def check_quick_flag(path: Path) -> list[str]:
    """Problems if no code cell references the quick-mode flag (``pick(`` or ``quick_mode(``)."""
    code = "\n".join(c.source for c in _read(path).cells if c.cell_type == "code")
    if any(marker in code for marker in QUICK_MARKERS):
        return []
    return ["no code cell calls pick(...) or quick_mode(...) (see wbmpc.quick)"]


NOTEBOOKS = find_notebooks()
_IDS = [p.name for p in NOTEBOOKS]


def test_notebooks_exist():
    assert NOTEBOOKS, f"no notebooks found under {REPO_ROOT / 'notebooks'}"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=_IDS)
def test_no_outputs(path):
    problems = check_no_outputs(path)
    assert not problems, f"{path.name}: strip outputs before committing:\n" + "\n".join(problems)


@pytest.mark.parametrize("path", NOTEBOOKS, ids=_IDS)
def test_name(path):
    assert not check_name(path), check_name(path)[0]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=_IDS)
def test_title(path):
    problems = check_title(path)
    assert not problems, f"{path.name}: " + "; ".join(problems)


@pytest.mark.parametrize("path", NOTEBOOKS, ids=_IDS)
def test_quick_flag(path):
    problems = check_quick_flag(path)
    assert not problems, f"{path.name}: " + "; ".join(problems)


# The numbers the notebooks' text quotes are checked in tests/test_notebook_numbers.py.


# --- a saved notebook still shows the robot -------------------------------------------------------------
QUICKSTART = REPO_ROOT / "notebooks" / "00_quickstart.ipynb"
# the snapshot's page, in a data: URL (src) or inline (srcdoc, HTML-escaped)
STATIC_PAGE = re.compile(
    r'<iframe class="wbmpc-static-scene"[^>]*?\b'
    r'(?:src="(data:text/html;base64,[A-Za-z0-9+/=]+)"|srcdoc="([^"]*)")'
)
SCENE_COMMAND = re.compile(r'fetch\("data:application/octet-binary;base64,([A-Za-z0-9+/=]+)"\)')


def execute_quickstart(folder: Path) -> Path:
    """Notebook 00 run in quick mode (a kernel of this interpreter), saved with its outputs in ``folder``."""

    from nbclient import NotebookClient

    nb = _read(QUICKSTART)
    with pytest.MonkeyPatch.context() as patch:  # the kernel inherits this process's environment
        patch.setenv("WBMPC_QUICK", "1")
        patch.setenv("MPLBACKEND", "Agg")
        NotebookClient(nb, timeout=600, resources={"metadata": {"path": str(QUICKSTART.parent)}}).execute()
    path = folder / QUICKSTART.name
    nbformat.write(nb, path)
    return path


def scene_cells(nb: nbformat.NotebookNode) -> list[tuple[int, nbformat.NotebookNode]]:
    """The code cells that show a 3-D scene: an HTML output with the live view of a ``notebook_view(...)``."""
    return [
        (i, c)
        for i, c in enumerate(nb.cells)
        if c.cell_type == "code"
        and any("wbmpc-live-scene" in o.get("data", {}).get("text/html", "") for o in c.get("outputs", []))
    ]


def static_pages(cell: nbformat.NotebookNode) -> list[tuple[str, str]]:
    """The static scene pages in a cell's HTML outputs: (``data:`` URL, ``""`` for a srcdoc; the page)."""
    import base64
    import html

    pages = []
    for output in cell.get("outputs", []):
        for url, srcdoc in STATIC_PAGE.findall(output.get("data", {}).get("text/html", "")):
            if url:
                pages.append((url, base64.b64decode(url.split(",", 1)[1]).decode("utf-8")))
            else:
                pages.append(("", html.unescape(srcdoc)))
    return pages


def scene_commands(page: str) -> list[dict]:
    """The meshcat commands a static scene page replays.

    Raises ``AssertionError`` if the page loads anything but its own ``data:`` URLs (a server, a CDN).
    """
    import base64

    import umsgpack

    scene_script = page[page.rindex("<script>") :]  # after the embedded meshcat library
    outside = re.sub(SCENE_COMMAND, "", scene_script)
    assert not re.search(r"https?:|wss?:|\.connect\(|127\.0\.0\.1|localhost", outside), outside[:500]
    return [umsgpack.unpackb(base64.b64decode(c)) for c in SCENE_COMMAND.findall(scene_script)]


def saved_scenes(cell: nbformat.NotebookNode) -> list[list[dict]]:
    """The meshcat commands of each static scene page saved in a cell's outputs."""
    return [scene_commands(page) for _, page in static_pages(cell)]


def chromium_blocked(cell: nbformat.NotebookNode) -> list[int]:
    """Lengths of the cell's snapshot ``data:`` URLs that Chromium refuses to load (longer than 2 MiB)."""
    from wbmpc.viz.snapshot import CHROMIUM_MAX_URL

    return [len(url) for url, _ in static_pages(cell) if len(url) > CHROMIUM_MAX_URL]


def _vertices(command: dict) -> int:
    """Vertices of the meshes a ``set_object`` command carries (typed arrays: packed float32 triples)."""
    total = 0
    for geometry in command["object"].get("geometries", []):
        array = geometry.get("data", {}).get("attributes", {}).get("position", {}).get("array", b"")
        raw = getattr(array, "data", array)  # a msgpack extension (typed array) or a plain list
        total += len(raw) // 12 if isinstance(raw, bytes | bytearray) else len(raw) // 3
    return total


@pytest.fixture(scope="module")
def saved_quickstart(tmp_path_factory) -> nbformat.NotebookNode:
    return _read(execute_quickstart(tmp_path_factory.mktemp("saved")))


def test_saved_quickstart_keeps_a_static_scene_of_the_robot(saved_quickstart):
    """Run and saved, 00's 3-D cells hold the scene as a page that needs no kernel and no meshcat server:
    every visual of the robot in it, with its pose, and the replay's animation."""
    from wbmpc.model.robot import load_b1_z1
    from wbmpc.viz.geometry import visual_model

    _, geometry = visual_model(load_b1_z1())
    visuals = {f"/meshcat/robot/visuals/{g.name}" for g in geometry.geometryObjects}
    cells = scene_cells(saved_quickstart)
    assert len(cells) >= 2, "00 shows the plan and the closed-loop replay in 3-D"
    for index, cell in cells:
        scenes = saved_scenes(cell)
        assert len(scenes) == 1, f"cell {index}: {len(scenes)} static scene pages in its outputs"
        (commands,) = scenes
        meshes = {c["path"] for c in commands if c["type"] == "set_object" and c["path"] in visuals}
        assert meshes == visuals, f"cell {index}: the snapshot misses {sorted(visuals - meshes)[:5]}"
        posed = {c["path"] for c in commands if c["type"] == "set_transform"}
        assert visuals <= posed, f"cell {index}: visuals without a pose: {sorted(visuals - posed)[:5]}"
        vertices = sum(_vertices(c) for c in commands if c["type"] == "set_object" and c["path"] in visuals)
        assert vertices > 10_000, f"cell {index}: only {vertices} vertex coordinates in the snapshot"
    replay = [commands for _, cell in cells for commands in saved_scenes(cell) if "replay" in cell.source]
    assert replay and any(c["type"] == "set_animation" for c in replay[0]), (
        "the replay's snapshot does not move"
    )


def test_saved_quickstart_snapshot_loads_in_chromium(saved_quickstart):
    """Chromium loads each saved snapshot: inline (srcdoc) or in a data: URL within its 2 MiB limit."""
    blocked = {i: chromium_blocked(c) for i, c in scene_cells(saved_quickstart) if chromium_blocked(c)}
    assert not blocked, f"snapshot data: URLs longer than Chromium loads, by cell: {blocked}"


def _scene_cell(html: str) -> nbformat.NotebookNode:
    cell = nbformat.v4.new_code_cell("viewer.notebook_view()")
    cell.outputs = [nbformat.v4.new_output("execute_result", data={"text/html": html})]
    return cell


def test_snapshot_checks_see_a_blocked_url_and_an_inline_page():
    """The checks above on made-up outputs: a srcdoc snapshot is read and loads, a long data: URL does not
    load, a page that connects to a server is refused."""
    import base64

    import umsgpack

    from wbmpc.viz.snapshot import CHROMIUM_MAX_URL, snapshot_iframe

    command = {"type": "set_object", "path": "/meshcat/robot/visuals/trunk_0", "object": {}}
    encoded = base64.b64encode(umsgpack.packb(command)).decode()
    page = (
        '<html><body><script>var MeshCat = {}; // the library: "quotes" & <tags>\n</script><script>'
        f'fetch("data:application/octet-binary;base64,{encoded}").then(r => r)</script></body></html>'
    )
    inline = _scene_cell(snapshot_iframe(page))
    assert saved_scenes(inline) == [[command]] and not chromium_blocked(inline)

    padded = page.replace("// the library", "// " + "x" * CHROMIUM_MAX_URL)
    url = "data:text/html;base64," + base64.b64encode(padded.encode()).decode()
    long = _scene_cell(f'<iframe class="wbmpc-static-scene" loading="lazy" src="{url}"></iframe>')
    assert saved_scenes(long) == [[command]] and chromium_blocked(long) == [len(url)]

    served = page.replace("</script><script>", '</script><script>viewer.connect("ws://127.0.0.1:7000");')
    with pytest.raises(AssertionError):
        saved_scenes(_scene_cell(snapshot_iframe(served)))


def test_scene_picture_draws_the_robot_in_the_middle():
    """``scene_png`` (the picture a notebook keeps even untrusted): the robot, framed, on the ground grid."""
    from types import SimpleNamespace

    import pinocchio as pin
    from PIL import Image

    from wbmpc.model.robot import load_b1_z1
    from wbmpc.viz.camera import camera_for_motion, robot_radius
    from wbmpc.viz.geometry import visual_model
    from wbmpc.viz.snapshot import scene_png

    robot = load_b1_z1()
    model, geometry = visual_model(robot)
    q = robot.q_nominal
    data, placements = model.createData(), geometry.createData()
    pin.forwardKinematics(model, data, q)
    pin.updateGeometryPlacements(model, data, geometry, placements)
    target, position = camera_for_motion(q[None, :3], robot_radius(model, geometry, q))

    def picture(geometry, placements):
        viewer = SimpleNamespace(
            geometry=geometry, viz=SimpleNamespace(visual_data=placements), camera_position=position,
            camera_target=target,
        )  # fmt: skip
        png = scene_png(viewer, width=360, height=200)
        return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=int)

    robot_image = picture(geometry, placements)
    empty = pin.GeometryModel()
    ground = picture(empty, empty.createData())
    assert robot_image.shape == ground.shape == (200, 360, 3)
    drawn = np.abs(robot_image - ground).sum(axis=2) > 30
    assert 0.05 < drawn.mean() < 0.6, f"the robot covers {drawn.mean():.0%} of the picture"
    rows, cols = np.nonzero(drawn)
    assert abs(rows.mean() / 200 - 0.5) < 0.2 and abs(cols.mean() / 360 - 0.5) < 0.2, (
        "the robot is not framed"
    )
    assert np.ptp(ground.reshape(-1, 3), axis=0).max() > 50, "no sky gradient or grid drawn"
