"""The notebooks as a researcher sees them: JupyterLab in a real (headless) Chromium, driven by Playwright.

JupyterLab runs on 127.0.0.1 (a free port, a random token) on a copy of notebook 00 in a temporary folder,
in quick mode. The test runs all of it, moves the forward-speed slider and checks that the plan was solved
again (the panel's status line counts the solves), that the live meshcat scene changed (the plan's base path
in meshcat's scene tree, read inside the scene's iframe), that no cell has an error output and that
JupyterLab's Log Console holds no error. A second test opens an exported replay (a self-contained HTML file)
and checks that it plays and loops.

Chromium is Debian's ``chromium`` (``.ci/run`` installs it where it can), driven through Playwright's
``executable_path``: Playwright's own browser download is not used. Without a Chromium executable (or
without the ``playwright`` package) the tests skip and say why. ``WBMPC_CHROMIUM`` names another executable.

Every wait is explicit, with a timeout; nothing is asserted on elapsed time.
"""

from __future__ import annotations

import io
import json
import os
import re
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
NOTEBOOK = REPO / "notebooks" / "00_quickstart.ipynb"
CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
CHROMIUM_ARGS = [
    "--no-sandbox",  # CI runs as root
    "--disable-dev-shm-usage",
    "--use-angle=swiftshader",  # software WebGL for meshcat's three.js, no GPU needed
    "--enable-unsafe-swiftshader",
]
RUN_ALL_TIMEOUT_S = 900  # Run All of 00 in quick mode (about a minute alone; the suite runs beside it)
SOLVE_TIMEOUT_S = 180


def _chromium() -> str | None:
    explicit = os.environ.get("WBMPC_CHROMIUM")
    if explicit:
        return explicit if Path(explicit).is_file() else None
    for name in CHROMIUM_NAMES:
        found = shutil.which(name)
        if found:
            return found
    return None


CHROMIUM = _chromium()
pytestmark = [
    pytest.mark.skipif(
        CHROMIUM is None,
        reason="no Chromium executable on PATH (chromium, chromium-browser, google-chrome), no "
        "WBMPC_CHROMIUM: the browser tests need one (.ci/run installs Debian's chromium with apt-get)",
    ),
    # JupyterLab, its kernel and Chromium are processes on the wall clock: beside another test worker (a
    # compile, solves on both cores) their pages took longer than the 120 s waits in fresh-clone CI runs.
    pytest.mark.wallclock,
]


def _playwright():
    return pytest.importorskip(
        "playwright.sync_api",
        reason="the playwright package is not installed (it is pinned in environment.txt)",
    )


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _readout(slider) -> str | None:
    try:
        return slider.locator(".widget-readout").first.text_content(timeout=5_000)
    except Exception:  # noqa: BLE001 - only for a failure message
        return None


def _wait_for(predicate, timeout: float, what: str, interval: float = 0.5, on_timeout=None):
    """Poll ``predicate`` until it returns something truthy; fail with ``what`` after ``timeout`` seconds
    (and what ``on_timeout()`` says, if given)."""
    deadline = time.monotonic() + timeout
    last_error = None
    while time.monotonic() < deadline:
        try:
            value = predicate()
        except Exception as exc:  # noqa: BLE001 - e.g. the server not up yet
            last_error = exc
        else:
            if value:
                return value
        time.sleep(interval)
    more = f"; {on_timeout()}" if on_timeout is not None else ""
    pytest.fail(f"timed out after {timeout:.0f} s waiting for {what} (last error: {last_error}){more}")


@pytest.fixture(scope="module")
def browser():
    sync_api = _playwright()
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        yield browser
        browser.close()


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """JupyterLab on 127.0.0.1 serving a copy of notebook 00, in quick mode; yields (base URL, token)."""
    root = tmp_path_factory.mktemp("lab")
    shutil.copy(NOTEBOOK, root / NOTEBOOK.name)
    port, token = _free_port(), secrets.token_hex(16)
    env = dict(os.environ, WBMPC_QUICK="1", MPLBACKEND="Agg")
    for name in ("JUPYTER_CONFIG_DIR", "JUPYTER_DATA_DIR", "JUPYTER_RUNTIME_DIR", "IPYTHONDIR"):
        env[name] = str(root / f".{name.lower()}")
    command = [
        sys.executable, "-m", "jupyterlab", "--no-browser",
        "--ServerApp.ip=127.0.0.1", f"--ServerApp.port={port}", "--ServerApp.port_retries=0",
        f"--IdentityProvider.token={token}", f"--ServerApp.root_dir={root}",
        f"--LabApp.workspaces_dir={root / '.workspaces'}", f"--LabApp.user_settings_dir={root / '.settings'}",
        "--LabApp.expose_app_in_browser=True", "--LabApp.news_url=None", "--ServerApp.open_browser=False",
        "--allow-root",  # CI runs as root
    ]  # fmt: skip
    log = (root / "jupyterlab.log").open("w")
    nice = ["nice", "-n", "19"] if shutil.which("nice") else []
    server = subprocess.Popen(nice + command, cwd=root, env=env, stdout=log, stderr=subprocess.STDOUT,
                              start_new_session=True)  # fmt: skip
    base = f"http://127.0.0.1:{port}"

    def up():
        if server.poll() is not None:
            pytest.fail(
                f"JupyterLab exited ({server.returncode}): {(root / 'jupyterlab.log').read_text()[-3000:]}"
            )
        with urllib.request.urlopen(f"{base}/api/status?token={token}", timeout=5) as response:
            return response.status == 200

    try:
        _wait_for(up, 120, "JupyterLab to answer")
        yield base, token, root
    finally:
        _stop(server)
        log.close()


def _stop(server: subprocess.Popen) -> None:
    """Stop the server's process group: the server, its kernels and their meshcat servers."""
    for sig, wait in ((signal.SIGTERM, 30), (signal.SIGKILL, 10)):
        try:
            os.killpg(server.pid, sig)
        except ProcessLookupError:
            return
        try:
            server.wait(wait)
            return
        except subprocess.TimeoutExpired:
            continue


# --- in the page -----------------------------------------------------------------------------------------
NOTEBOOK_STATE = """() => {
  const panel = window.jupyterapp.shell.currentWidget;
  if (!panel || !panel.content || !panel.sessionContext || !panel.sessionContext.session) return null;
  const cells = [];
  for (const cell of panel.content.widgets) {
    const m = cell.model;
    if (m.type !== 'code') continue;
    const outputs = m.outputs.toJSON();
    cells.push({
      count: m.executionCount,
      errors: outputs.filter(o => o.output_type === 'error').map(o => `${o.ename}: ${o.evalue}`),
    });
  }
  return {status: panel.sessionContext.kernelDisplayStatus, cells};
}"""

# The points of the plan's base path (a Line under /meshcat/plan/base) in meshcat's scene tree, read without
# creating nodes (SceneNode.find creates missing ones).
BASE_PATH = """() => {
  let node = window.viewer && window.viewer.scene_tree;
  for (const name of ['meshcat', 'plan', 'base', 'line']) {
    node = node && node.children[name];
  }
  const object = node && node.object;
  const line = object && (object.geometry ? object : object.children.find(c => c.geometry));
  return line ? Array.from(line.geometry.attributes.position.array) : null;
}"""

REPLAY_STATE = """() => {
  const a = window.viewer && window.viewer.animator;
  if (!a || !a.actions.length) return null;
  const action = a.actions[0];
  return {time: action.time, duration: action.getClip().duration, running: action.isRunning(),
          scrubber: a.time_scrubber !== null,
          loop: action.repetitions, elapsed: action.time + action._loopCount * action.getClip().duration};
}"""


def _state(page):
    return page.evaluate(NOTEBOOK_STATE)


def _scene_frame(page):
    handle = page.wait_for_selector("iframe.wbmpc-live-scene", state="attached", timeout=60_000)
    return handle.content_frame()


def _solve_count(page) -> int:
    # text_content, not inner_text: JupyterLab leaves cells out of view unrendered (content-visibility)
    text = page.locator(".wbmpc-resolve-status .wbmpc-solve-count").first.text_content(timeout=10_000)
    return int(text.split()[-1])


def _log_console_text(page) -> str:
    page.evaluate("() => window.jupyterapp.commands.execute('logconsole:open')")
    panel = page.wait_for_selector(".jp-LogConsolePanel", state="attached", timeout=30_000)
    return panel.inner_text()


@pytest.fixture(scope="module")
def ran(lab, browser):
    """A page with notebook 00 open after Run All (no cell error); yields (page, console errors)."""
    base, token, root = lab
    page = browser.new_page(viewport={"width": 1400, "height": 1000})
    console_errors = []
    page.on("console", lambda m: console_errors.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: console_errors.append(str(e)))
    page.goto(f"{base}/lab/tree/{NOTEBOOK.name}?token={token}", timeout=120_000)
    page.wait_for_function(
        "() => window.jupyterapp && window.jupyterapp.shell.currentWidget", timeout=120_000
    )
    _wait_for(lambda: (_state(page) or {}).get("status") == "idle", 180, "the kernel to start")

    page.evaluate("() => window.jupyterapp.commands.execute('notebook:run-all-cells')")

    def finished():
        state = _state(page)
        if state is None:
            return False
        errors = [e for c in state["cells"] for e in c["errors"]]
        if errors:
            return {"errors": errors}
        return state["status"] == "idle" and all(c["count"] is not None for c in state["cells"]) and state

    state = _wait_for(finished, RUN_ALL_TIMEOUT_S, "Run All of notebook 00", interval=2.0)
    assert "errors" not in state, f"a cell shows an error: {state['errors']}"
    assert state["cells"], "no code cell found"
    yield page, console_errors
    page.close()


def test_run_all_then_slider_resolves_and_redraws(ran):
    page, console_errors = ran
    # The plan view before the slider moves.
    frame = _scene_frame(page)
    before = _wait_for(
        lambda: frame.evaluate(BASE_PATH), 120, "the plan's base path in the live meshcat scene"
    )
    solves = _solve_count(page)

    # Drag the forward-speed handle to the right and release it: one (debounced) solve.
    slider = page.locator(".widget-slider", has_text="v_x").first
    slider.scroll_into_view_if_needed(timeout=30_000)
    handle = slider.locator(".noUi-handle").first
    value = _readout(slider)
    handle.hover(timeout=30_000)  # scrolled into view and stable: the box below is where the handle is
    box = handle.bounding_box(timeout=30_000)
    assert box is not None, "the v_x slider's handle is not on screen"
    x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    page.mouse.move(x, y)
    page.mouse.down()
    page.mouse.move(x + 40, y, steps=5)
    page.mouse.up()
    if _readout(slider) == value:  # the drag missed (a layout shift): the keyboard, released at once
        handle.focus()
        page.keyboard.press("ArrowRight")
    assert _readout(slider) != value, f"the v_x slider did not move from {value}"

    status_line = page.locator(".wbmpc-resolve-status").first
    _wait_for(
        lambda: _solve_count(page) > solves,
        SOLVE_TIMEOUT_S,
        f"the re-solve after the slider's release (the v_x readout: {_readout(slider)!r})",
        on_timeout=lambda: f"status line: {status_line.text_content()!r}",
    )
    status = status_line.text_content()
    assert "v_x:" in status, f"the status line does not say the speed changed: {status!r}"
    assert "3-D view updated" in status, status

    def moved():
        after = frame.evaluate(BASE_PATH)
        return after is not None and (len(after) != len(before) or not np.allclose(after, before)) and after

    after = _wait_for(moved, 60, "the plan's base path to change in the live meshcat scene")
    assert np.ptp(np.reshape(after, (-1, 3))[:, 0]) != pytest.approx(
        np.ptp(np.reshape(before, (-1, 3))[:, 0])
    )

    state = _state(page)
    errors = [e for c in state["cells"] for e in c["errors"]]
    assert not errors, f"a cell shows an error: {errors}"
    log_text = _log_console_text(page)
    for marker in ("Traceback", "Error"):
        assert marker not in log_text, f"the Log Console has an error:\n{log_text[-3000:]}"
    widget_errors = [e for e in console_errors if "widget model not found" in e or "ZMQError" in e]
    assert not widget_errors, widget_errors


# --- the saved notebook, reopened without its kernel ------------------------------------------------------
# The code cells that show a 3-D scene (an output with a live view), each marked (data-wbmpc-cell) and
# scrolled to so that JupyterLab's windowed notebook renders it; per cell: index, trust, what it shows.
SCENE_CELLS = """async () => {
  const notebook = window.jupyterapp.shell.currentWidget.content;
  const found = [];
  for (const [i, cell] of notebook.widgets.entries()) {
    if (cell.model.type !== 'code') continue;
    if (!JSON.stringify(cell.model.outputs.toJSON()).includes('wbmpc-live-scene')) continue;  // a 3-D view
    await notebook.scrollToItem(i, 'center');
    // A large output (the replay's snapshot: megabytes of HTML) is attached a while after the scroll.
    const shown = () => cell.node.querySelector(
      '.wbmpc-scene, .jp-OutputArea-output img, .jp-OutputArea-output iframe');
    for (let t = 0; t < 300 && !shown(); t++) {
      await new Promise(resolve => setTimeout(resolve, 100));
    }
    cell.node.setAttribute('data-wbmpc-cell', String(i));
    const imgs = Array.from(cell.node.querySelectorAll('.jp-OutputArea-output img'));
    found.push({index: i, trusted: cell.model.trusted,
                live: cell.node.querySelectorAll('iframe.wbmpc-live-scene').length,
                snapshot: cell.node.querySelectorAll('iframe.wbmpc-static-scene').length,
                images: imgs.map(im => [im.naturalWidth, im.naturalHeight])});
  }
  return found;
}"""

# Meshes drawn under /meshcat/robot in a meshcat page (read without creating nodes).
ROBOT_MESHES = """() => {
  let node = window.viewer && window.viewer.scene_tree;
  for (const name of ['meshcat', 'robot']) node = node && node.children[name];
  let meshes = 0;
  if (node && node.object) node.object.traverse(o => { if (o.isMesh && o.geometry) meshes += 1; });
  return meshes;
}"""
SHOW_ROBOT = """(visible) => {
  const viewer = window.viewer;
  viewer.scene_tree.children['meshcat'].children['robot'].set_property('visible', visible);
  if (viewer.set_dirty) viewer.set_dirty(); else viewer.needs_render = true;  // meshcat draws on demand
}"""


def _api(base: str, token: str, method: str, path: str):
    request = urllib.request.Request(
        f"{base}{path}", method=method, headers={"Authorization": f"token {token}"}
    )
    with urllib.request.urlopen(request, timeout=30) as response:
        body = response.read()
    return json.loads(body) if body else None


def _refused(url: str) -> bool:
    try:
        urllib.request.urlopen(url, timeout=5).close()
    except urllib.error.URLError as exc:
        return isinstance(exc.reason, ConnectionRefusedError)
    return False


@pytest.fixture(scope="module")
def saved(ran, lab):
    """Notebook 00 saved from JupyterLab after Run All, then its kernel shut down (its meshcat servers too).

    Returns the live views' addresses (refused by then)."""
    page, _ = ran
    base, token, root = lab
    page.evaluate("() => window.jupyterapp.commands.execute('docmanager:save')")

    def saved_with_outputs():
        nb = json.loads((root / NOTEBOOK.name).read_text())
        html = [
            "".join(o.get("data", {}).get("text/html", ""))
            for c in nb["cells"]
            for o in c.get("outputs", [])
        ]  # fmt: skip
        return sum("wbmpc-static-scene" in h for h in html) >= 2 and html

    html = _wait_for(saved_with_outputs, 120, "the notebook saved with its 3-D cells' outputs")
    live = sorted({url for h in html for url in re.findall(r'class="wbmpc-live-scene" src="([^"]+)"', h)})
    assert live, "the saved 3-D cells have no live view"
    for session in _api(base, token, "GET", "/api/sessions"):
        _api(base, token, "DELETE", f"/api/sessions/{session['id']}")
    _wait_for(
        lambda: all(_refused(url) for url in live), 60, f"the meshcat servers {live} to stop with the kernel"
    )
    return live


def _open(browser, base: str, token: str, name: str):
    """A new page with notebook ``name`` open (not run); returns (page, failed requests)."""
    page = browser.new_page(viewport={"width": 1400, "height": 1000})
    failed = []
    page.on("requestfailed", lambda r: failed.append((r.url, r.failure)))
    # A workspace of its own: the default one would restore the notebooks opened earlier (the Run All one,
    # with all its outputs) beside this one, which under a loaded machine took JupyterLab past the wait
    # below (CI, 2026-12-04). The wait is still for this notebook's own tab.
    workspace = f"wbmpc-{secrets.token_hex(4)}"
    try:
        page.goto(f"{base}/lab/workspaces/{workspace}/tree/{name}?token={token}", timeout=120_000)
        page.wait_for_function(
            "(name) => { const w = window.jupyterapp && window.jupyterapp.shell.currentWidget;"
            " return w && w.context && w.context.isReady && w.context.path.endsWith(name)"
            " && w.content.widgets.length > 0; }",
            arg=name,
            timeout=120_000,
        )
    except Exception:
        # A page left open keeps rendering in the shared browser and starves the next test's page (CI,
        # 2026-12-04: the exported replay's local file then did not load in 120 s either).
        page.close()
        raise
    return page, failed


def _differing_share(a: bytes, b: bytes) -> float:
    """Share of the pixels that differ (by more than a little) between two PNG screenshots of one element."""
    from PIL import Image

    x, y = (np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=int) for png in (a, b))
    assert x.shape == y.shape, (x.shape, y.shape)
    return float((np.abs(x - y).sum(axis=2) > 30).mean())


def _check_snapshot_draws_the_robot(page, index: int) -> None:
    """In cell ``index``: the live view failed to connect; unfolded, the snapshot draws the robot's meshes
    (hiding them changes the picture)."""
    scene = page.locator(f'[data-wbmpc-cell="{index}"] .wbmpc-scene').first
    live = scene.locator("iframe.wbmpc-live-scene").first.element_handle(timeout=30_000).content_frame()
    _wait_for(lambda: live.url.startswith("chrome-error://"), 60, "the live view to fail without its server")
    scene.locator("summary").first.click(timeout=30_000)  # unfold the snapshot
    iframe = scene.locator("iframe.wbmpc-static-scene").first
    iframe.scroll_into_view_if_needed(timeout=30_000)
    frame = iframe.element_handle(timeout=30_000).content_frame()
    url = _wait_for(lambda: frame.url not in ("", "about:blank") and frame.url, 60, "the snapshot to load")
    if url == "about:blank#blocked":  # e.g. a data: URL beyond Chromium's 2 MiB
        size = len(iframe.get_attribute("src", timeout=30_000) or "")
        raise AssertionError(f"cell {index}: Chromium blocked the snapshot frame (a {size:,}-character src)")
    meshes = _wait_for(
        lambda: (n := frame.evaluate(ROBOT_MESHES)) >= 20 and n,
        120,
        f"the robot's meshes in cell {index}'s snapshot",
    )
    time.sleep(1.0)  # a few frames drawn
    shown = iframe.screenshot(timeout=30_000)
    frame.evaluate(SHOW_ROBOT, False)
    time.sleep(1.0)
    hidden = iframe.screenshot(timeout=30_000)
    frame.evaluate(SHOW_ROBOT, True)
    share = _differing_share(shown, hidden)
    assert share > 0.01, f"cell {index}: the robot ({meshes} meshes) covers {share:.1%} of its snapshot"


@pytest.mark.skipif(
    os.environ.get("WBMPC_BROWSER_FULL") != "1",
    reason="by hand (WBMPC_BROWSER_FULL=1): unfolding the megabyte snapshots renders them in software WebGL, "
    "which took minutes and timed out clicks on a 2-vCPU machine; CI checks the saved pages with nbclient "
    "(tests/test_notebook_hygiene.py) and the untrusted notebook's pictures here",
)
def test_saved_notebook_shows_the_robot_without_its_kernel(saved, lab, browser):
    """Reopened (not run) after its kernel and meshcat servers are gone, each 3-D cell of the saved notebook
    still shows the robot: the live view fails to connect, the static snapshot under it draws the scene."""
    base, token, root = lab
    page, failed = _open(browser, base, token, NOTEBOOK.name)
    cells = page.evaluate(SCENE_CELLS)
    assert len(cells) >= 2, cells
    assert all(c["trusted"] for c in cells), f"JupyterLab saved it, so it should trust it: {cells}"
    for cell in cells:
        assert cell["snapshot"] == 1, f"cell {cell['index']} shows no static snapshot: {cell}"
        _check_snapshot_draws_the_robot(page, cell["index"])
    snapshot_failures = [(url[:80], why) for url, why in failed if not any(url.startswith(s) for s in saved)]
    assert not snapshot_failures, f"requests that failed besides the live views': {snapshot_failures}"
    page.close()


def test_untrusted_saved_notebook_shows_the_robot(saved, lab, browser):
    """The same saved notebook opened where JupyterLab does not trust it (a copy with one edit, as a notebook
    received from elsewhere): its 3-D cells still show the robot, as a snapshot or an image."""
    base, token, root = lab
    nb = json.loads((root / NOTEBOOK.name).read_text())
    nb["metadata"]["wbmpc_received"] = True  # the signature no longer matches: untrusted
    name = f"received_{NOTEBOOK.name}"
    (root / name).write_text(json.dumps(nb))
    page, _ = _open(browser, base, token, name)
    try:
        cells = page.evaluate(SCENE_CELLS)
    finally:
        page.close()
    assert len(cells) >= 2 and not any(c["trusted"] for c in cells), cells
    blank = [c for c in cells if not c["snapshot"] and not any(w >= 100 and h >= 100 for w, h in c["images"])]
    assert not blank, f"3-D cells that show nothing of the robot in an untrusted notebook: {blank}"


def test_exported_replay_loops(browser, tmp_path):
    from wbmpc.model.robot import load_b1_z1
    from wbmpc.viz import Viewer, ViewerUnavailableError

    robot = load_b1_z1()
    times = np.linspace(0.0, 0.5, 6)
    qs = np.tile(robot.q_nominal, (len(times), 1))
    qs[:, 0] = np.linspace(0.0, 0.3, len(times))  # the base moves 30 cm forward in 0.5 s
    try:
        viewer = Viewer(robot)
    except ViewerUnavailableError as exc:
        pytest.skip(f"no meshcat server here: {exc}")
    with viewer:
        viewer.animation(qs, times, fps=10.0)
        path = viewer.export_html(tmp_path / "replay.html")

    page = browser.new_page(viewport={"width": 800, "height": 600})
    try:
        page.goto(path.as_uri(), timeout=120_000)
        first = _wait_for(lambda: page.evaluate(REPLAY_STATE), 120, "the replay's animation to load")
        assert first["loop"] == float("inf") or first["loop"] > 1e9, f"the replay does not loop: {first}"

        # Played on: the action's total time goes past one clip and the action is still running (it looped).
        def past_its_end():
            state = page.evaluate(REPLAY_STATE)
            return state["elapsed"] > 1.5 * state["duration"] and state["running"] and state

        looped = _wait_for(
            past_its_end,
            120,
            "the replay to play past its end and go on",
        )
        assert 0.0 <= looped["time"] <= looped["duration"] + 1e-6
        assert looped["scrubber"], "meshcat's Animations panel has no time slider"
    finally:
        page.close()
