"""Numbers quoted in the notebooks' markdown, checked against what they come from.

A number a cell computes is best left to the cell (it prints it; the text reads it qualitatively). A number
the text keeps quoting is checked here against the same computation (the committed bag and tables, through
``wbmpc``), or against the parameter or committed file it names. Notebook 05 is checked both ways: each
quoted phrase is rebuilt from its source, and every quantity its text quotes (a number with a unit, or a
decimal) must lie in one of those phrases, so a new or edited number fails until it is checked here.
"""

from __future__ import annotations

import inspect
import json
import re
from functools import cache
from pathlib import Path

import nbformat
import numpy as np
import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = REPO_ROOT / "notebooks"
HARDWARE = REPO_ROOT / "data" / "hardware"

# A quantity in running text: a number with a unit, or any decimal number (bare integers are not
# guarded: section numbers, "3 x 3", "max 6").
UNITS = r"%|ms|s|Hz|kHz|cm/s|cm|mm|m/s|rad/s|rad|N m|kg"
QUANTITY = re.compile(
    rf"(?<![\w.])\d+(?:,\d{{3}})*(?:\.\d+)?\s?(?:{UNITS})(?![\w/^])|(?<![\w.])\d+\.\d+(?![\w.])"
)


def _markdown(name: str) -> str:
    """The notebook's markdown cells, whitespace collapsed (line breaks do not split a phrase)."""
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    return " ".join(" ".join(c.source for c in nb.cells if c.cell_type == "markdown").split())


def _code(name: str) -> str:
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    return "\n".join(c.source for c in nb.cells if c.cell_type == "code")


def _default(function, name: str):
    return inspect.signature(function).parameters[name].default


def missing_phrases(text: str, phrases: list[str]) -> list[str]:
    """The phrases not in ``text``."""
    return [p for p in phrases if p not in text]


def unchecked_quantities(text: str, phrases: list[str]) -> list[str]:
    """Quantities of ``text`` (see ``QUANTITY``) outside every occurrence of every phrase, with context."""
    covered = np.zeros(len(text), bool)
    for phrase in phrases:
        for m in re.finditer(re.escape(phrase), text):
            covered[m.start() : m.end()] = True
    return [
        f"{m.group(0)!r} in ...{text[max(0, m.start() - 40) : m.end() + 20]}..."
        for m in QUANTITY.finditer(text)
        if not covered[m.start() : m.end()].all()
    ]


# --- 05: the hardware log -------------------------------------------------------------------------------
NB05 = "05_hardware_log_analysis.ipynb"


@cache
def _bag_analysis():
    """The bag's CoM identification as notebook 05's cell computes it, and the model's own rear share."""
    import pinocchio as pin

    from wbmpc import analysis
    from wbmpc.io.rosbag import read_bag
    from wbmpc.model.robot import load_b1_z1

    robot = load_b1_z1()
    log = read_bag(HARDWARE / "emulated_b1_stand_trot")
    mask = analysis.standing_mask(log, t_min=0.5, t_max=2.0)  # the notebook's window (T_STAND = 2 s)
    ident = analysis.identify_com_offset(log, robot, mask=mask)
    # The model's own split at the same stance: its CoM between the front and the rear feet (fore-aft lever).
    model, data = robot.model, robot.model.createData()
    shares = []
    for q in np.asarray(log["q"], float)[mask][::10]:
        pin.framesForwardKinematics(model, data, q)
        com = pin.centerOfMass(model, data, q)
        x = [data.oMf[robot.frame_id(f)].translation[0] for f in robot.foot_frames]
        front, rear = np.mean(x[:2]), np.mean(x[2:])
        shares.append((front - com[0]) / (front - rear))
    return robot, ident, float(np.mean(shares))


def _pick(code: str, name: str) -> tuple[str, str]:
    """The ``full=`` and ``quick=`` values of ``NAME = pick(full=..., quick=...)`` in a notebook's code."""
    m = re.search(rf"^{name} = pick\(full=([^,]+), quick=([^)]+)\)", code, re.M)
    assert m, f"no {name} = pick(full=..., quick=...) in the notebook's code"
    return m.group(1), m.group(2)


def hardware_notebook_phrases() -> list[str]:
    """Every phrase of notebook 05's text that quotes a number, rebuilt from where the number comes from."""
    from wbmpc import analysis
    from wbmpc.analysis.solve_times import BUDGET_S
    from wbmpc.estimation.identification import identify_joint_friction
    from wbmpc.sim.loop_config import PlantConfig

    how = json.loads((HARDWARE / "emulated_b1_stand_trot.json").read_text())
    emulated = how["emulated_robot"]
    rate, solve_rate = how["signal_rate_hz"], how["solve_rate_hz"]
    budget_ms = 1e3 * BUDGET_S
    assert budget_ms == pytest.approx(1e3 / solve_rate), "the budget is one MPC period"
    stand, trot, speed = re.fullmatch(r"stand:([\d.]+),trot@([\d.]+):([\d.]+)", how["run"]["gait"]).groups()
    stand, speed, trot = float(stand), float(trot), float(speed)
    code = _code(NB05)
    assert _pick(code, "COMPILED")[1] == "False", "the text says quick mode's MPC is in-process"
    quick_nodes = int(_pick(code, "NODES")[1])
    quick_delay = float(_pick(code, "DELAY")[1])
    window = _default(analysis.detect_touchdowns, "window")
    assert window[0] == -window[1], "the text quotes a symmetric window"

    robot, ident, model_rear_share = _bag_analysis()
    offset = np.array(emulated["base_com_offset"])
    error_mm = 1e3 * np.linalg.norm(ident.offset[:2] - offset[:2])

    targets = json.loads((HARDWARE / "emulated_calibrated.json").read_text())["runs"]
    calibrated, nominal = targets["calibrated"], targets["uncalibrated"]
    assert calibrated["converged_fraction"] == 1.0 and calibrated["torque_clipped_steps"] == 0
    assert not calibrated["fell"] and nominal["fell"]
    tracked = {s["commanded"][0]: s["achieved"][0] for s in calibrated["tracking"] if s["commanded"][0] > 0}
    (slow, achieved_slow), (fast, achieved_fast) = sorted(tracked.items())
    nominal_stand = float(re.match(r"stand:([\d.]+)", nominal["gait"]).group(1))

    return [
        # the introduction: how the bag was made (its JSON), and quick mode (the notebook's pick(...) calls)
        f"a base centre of mass {-100 * offset[0]:g} cm behind the model's",
        f"{1e3 * emulated['torque_latency']:g} ms command latency",
        f"the MPC (N = {_default(analysis.record_emulated_run, 'nodes')}, compiled Fatrop)",
        f"{stand:g} s standing, then {trot:g} s trotting at {speed:g} m/s",
        f"joint states and commands at {rate} Hz",
        f"against the {budget_ms:g} ms budget of an {solve_rate} Hz MPC",
        f"an {quick_nodes}-node in-process MPC and a fixed {1e3 * quick_delay:g} ms delay",
        f"({rate} Hz here)",
        # 1. jitter (the cell prints the statistics)
        f"The MPC runs at {solve_rate} Hz, so a solve has $T_b = {budget_ms:g}$ ms",
        f"fits the {budget_ms:g} ms budget",
        # 3. touchdowns: the detector's defaults
        f"at most $\\pm {1e3 * window[1]:g}$ ms",
        f"reaching {100 * _default(analysis.detect_touchdowns, 'fraction'):g} % of the window's peak",
        # 4. the CoM from the torques (the standing mask's defaults, the identification on the bag)
        f"base speed < {100 * _default(analysis.standing_mask, 'max_speed'):g} cm/s",
        f"every joint slower than {_default(analysis.standing_mask, 'max_joint_speed'):g} rad/s",
        f"$m_b$ = {ident.link_mass:g} kg of $M$ = {robot.mass:.1f} kg",
        f"place the base's CoM {-100 * ident.offset[0]:.2f} cm behind the model's",
        f"{error_mm:.1f} mm from the emulated {-100 * offset[0]:g} cm",
        f"CoM: {-100 * ident.com_shift[0]:.1f} cm back",
        f"the rear feet carry {100 * ident.summary()['rear_share']:.0f} % of the weight",
        f"not the model's {100 * model_rear_share:.0f} %",
        # 5. the calibration: the fit's threshold, the plant's rate, the committed targets run
        f"above {100 * _default(identify_joint_friction, 'max_relative_error'):g} % of its estimate",
        f"the drives run at {1e-3 / PlantConfig().dt:g} kHz and the bag samples them at {rate} Hz",
        f"puts the CoM {-100 * ident.com_shift[0]:.1f} cm too far forward",
        f"The committed {calibrated['duration_s']:.0f} s run of both",
        f"calibrated {calibrated['iterations_mean']:.2f} Fatrop iterations mean, "
        f"max {calibrated['iterations_max']}, every solve converged",
        f"{achieved_slow:.3f} and {achieved_fast:.3f} m/s for {slow:g} and {fast:g} m/s, "
        f"max tilt {calibrated['max_tilt_rad']:.3f} rad, no clipped torque",
        f"nominal: falls {nominal['duration_s'] - nominal_stand:.1f} s into the trot, after "
        f"{nominal['max_tilt_rad']:.2f} rad of tilt and {nominal['torque_clipped_steps']} clipped torque "
        "steps",
        # the summary
        f"the share over the {budget_ms:g} ms budget",
        f"locate the base's CoM {error_mm:.1f} mm from the emulated offset",
    ]


def test_hardware_notebook_quotes_match_their_sources():
    """Each number notebook 05's text quotes is what its source (the bag, its JSON, a default) gives."""
    missing = missing_phrases(_markdown(NB05), hardware_notebook_phrases())
    assert not missing, "notebook 05's text no longer says (fix the text or its check):\n" + "\n".join(
        missing
    )


def test_hardware_notebook_quotes_no_unchecked_number():
    """A number in 05's text outside the checked phrases: print it from its cell, or check it here."""
    unchecked = unchecked_quantities(_markdown(NB05), hardware_notebook_phrases())
    assert not unchecked, "notebook 05 quotes numbers nothing checks:\n" + "\n".join(unchecked)


def test_number_guard_sees_quantities():
    """The guard finds numbers with units and decimals, and nothing a phrase covers."""
    text = "ran 12 s at 0.2 m/s, 59 % rear, 3.27 iterations; section 3, N = 15, ROS 2 bag, 2 kHz"
    found = [m.group(0) for m in QUANTITY.finditer(text)]
    assert found == ["12 s", "0.2 m/s", "59 %", "3.27", "2 kHz"]
    assert len(unchecked_quantities(text, ["ran 12 s at 0.2 m/s", "2 kHz"])) == 2  # 59 % and 3.27 remain
    assert missing_phrases(text, ["59 % rear", "60 % rear"]) == ["60 % rear"]


# --- 06: the robustness sweeps --------------------------------------------------------------------------
NB06 = "06_robustness_sweeps.ipynb"


def _ok(rows) -> int:
    return sum(r["status"] == "ok" for r in rows)


def _fell(rows) -> list[dict]:
    return [r for r in rows if r["status"] != "ok"]


def test_robustness_notebook_quotes_its_tables():
    """Notebook 06's text quotes counts of the committed sweep tables its cells read: they must match."""
    from wbmpc.studies import sweeps

    text = _markdown(NB06)
    final = sweeps.committed_table("robustness_landing")
    up_to = [r for r in final if r["status"] in ("ok", "fell") and r["magnitude"] <= 0.8 + 1e-9]
    lift_off = [r for r in up_to if r["phase"] in (0.0, 0.5)]
    assert f"`robustness_landing.csv`, {len(final)} cases" in text
    assert (
        f"{_ok(up_to)} of the {len(up_to)} cases up to 0.8 m/s stand ({100 * _ok(up_to) / len(up_to):.0f} %)"
        in text
    )
    assert f"{_ok(lift_off)} of the {len(lift_off)} lift-off cases" in text

    grid = sweeps.committed_table("robustness_grid")
    up_to = [r for r in grid if r["magnitude"] <= 0.8 + 1e-9]
    assert f"{_ok(up_to)} of the {len(up_to)} cases stand ({100 * _ok(up_to) / len(up_to):.1f} %)" in text
    undisturbed = {
        delay: [
            r["calf_torque_ratio"] for r in grid if (r["delay"] or 0.0) == delay and r["magnitude"] == 0.0
        ]
        for delay in (0.0, 0.0125)
    }
    low, high = (round(100 * f(undisturbed[0.0])) for f in (min, max))
    assert f"uses {low}-{high} % of it ({round(100 * max(undisturbed[0.0125]))} % with the delay)" in text

    forward = [r for r in sweeps.committed_table("robustness") if r.get("direction") == "forward"]
    assert "not in this grid" not in text, "the forward case is in the table (and in its report)"
    assert forward and all(r["status"] == "fell" for r in forward), "the text says the forward case falls"


def test_robustness_notebook_describes_its_tables():
    """What 06 says the tables hold and how a case is judged: the tables' rows and the code's criteria."""
    from wbmpc.control.config import MPCConfig
    from wbmpc.sim.loop_config import ClosedLoopConfig
    from wbmpc.sim.plant import fallen
    from wbmpc.studies import sweeps
    from wbmpc.studies.experiments.common import GAIT_PERIOD
    from wbmpc.studies.sweeps.cases import STUDIES

    text = _markdown(NB06)
    first, final = sweeps.committed_table("robustness"), sweeps.committed_table("robustness_landing")
    grid = sweeps.committed_table("robustness_grid")

    assert f"($T = {GAIT_PERIOD:g}$ s the trot period" in text
    assert (
        f"the base stays above {_default(fallen, 'min_base_height'):g} m and tilts less than "
        f"{ClosedLoopConfig().max_tilt:g} rad until the run ends" in text
    )
    after = {name: {round(r["sim_duration_s"] - r["t_kick"], 2) for r in rows if r["status"] == "ok"}
             for name, rows in (("first", first + final), ("grid", grid))}  # fmt: skip
    assert after == {"first": {1.5}, "grid": {2.0}}, after
    assert "1.5 s after the kick in the first two tables and 2 s in the issue's grid" in text

    # the first table: the lateral grid with the swing abort on, the 0.8 m/s row with it off
    with_abort = [r for r in first if r["kick_recovery"] is not None]
    without = [r for r in first if r["kick_recovery"] is None]
    lateral = [r for r in with_abort if r["direction"] == "lateral"]
    magnitudes, phases = sorted({r["magnitude"] for r in lateral}), {r["phase"] for r in lateral}
    assert f"lateral kicks of {magnitudes[0]:g} to {magnitudes[-1]:g} m/s at {len(phases)} phases" in text
    assert {r["kick_recovery"] for r in with_abort} == {MPCConfig().kick_recovery}
    assert f"(`MPCConfig.kick_recovery = {MPCConfig().kick_recovery:g}` m/s, the default)" in text
    assert {r["magnitude"] for r in without} == {0.8} and "the 0.8 m/s row with it off" in text
    assert {r["phase"] for r in _fell(without) if r["direction"] == "lateral"} == {0.0, 0.5}
    assert "Without the abort, the kicks at the two lift-offs ($\\varphi = 0$ and $0.5$) fall" in text
    assert not _fell(lateral) and "every lateral kick of the grid up to 0.8 m/s survives" in text

    # the final code's table
    assert sorted({r["lift_off"] for r in final}) == [1.2, 2.0] and "the one at 2.0 s" in text
    assert not _fell([r for r in final if r["direction"] == "forward"])
    assert "Forward pushes are survived everywhere up to 1.0 m/s" in text
    lateral = [r for r in final if r["direction"] == "lateral"]
    survived_everywhere = [m for m in sorted({r["magnitude"] for r in lateral})
                           if not _fell([r for r in lateral if r["magnitude"] <= m])]  # fmt: skip
    assert f"lateral ones up to {max(survived_everywhere):g} m/s at every phase" in text
    falls = _fell(final)
    assert {r["phase"] for r in falls} == {0.0, 0.5} and {r["direction"] for r in falls} == {"lateral"}
    assert (
        f"a lateral push of {min(r['magnitude'] for r in falls):g} m/s and more exactly at a lift-off" in text
    )

    # the grid
    assert (
        f"seeds 1 and 2 at {min(r['magnitude'] for r in grid if r['seed'] in (1, 2)):g} m/s and up without"
        in text
    )
    seeded_delayed = [r for r in grid if r["seed"] in (1, 2) and r["delay"]]
    assert {(r["direction"], r["magnitude"]) for r in seeded_delayed} == {("lateral", 0.6)}
    assert f"in {len(seeded_delayed)} lateral 0.6 m/s cases with it" in text
    falls = _fell([r for r in grid if r["magnitude"] <= 0.8 + 1e-9])
    assert {r["direction"] for r in falls} == {"lateral"}
    phases = sorted({r["phase"] for r in falls})
    assert f"(phases {', '.join(f'{p:g}' for p in phases[:-1])} and {phases[-1]:g})" in text
    edge = {d: min(r["magnitude"] for r in falls if (r["delay"] or 0.0) == d) for d in (0.0, 0.0125)}
    assert f"brings the edge down from {edge[0.0]:g} to {edge[0.0125]:g} m/s there" in text
    forward_falls = _fell([r for r in grid if r["direction"] == "forward"])
    assert len(forward_falls) == 1
    (f,) = forward_falls
    assert f"for one case ({f['magnitude']:.1f} m/s at phase {f['phase']:g}, seed {f['seed']})" in text
    on_limit = [r for r in grid if r["direction"] == "lateral" and r["magnitude"] in (0.1, 0.2)
                and r["phase"] in (0.0, 0.125) and not r["delay"]]  # fmt: skip
    assert on_limit and all(r["calf_torque_ratio_plan"] >= 0.999 for r in on_limit)
    assert "a lateral kick of 0.1-0.2 m/s right after a lift-off puts the plan on the torque limit" in text

    # the study's whole grid
    study = STUDIES["robustness"][0](False)
    assert f"the study's whole grid ({len(study):,} cases" in text


# --- 00: the quickstart ---------------------------------------------------------------------------------
def test_quickstart_text_leaves_the_problem_sizes_to_its_cells():
    """Notebook 00 prints the problem's sizes; its text must not quote its own (they went stale before)."""
    text = _markdown("00_quickstart.ipynb")
    stale = [
        m.group(0)
        for pattern in (r"\d[\d,]* decision variables", r"n_[xug] = \d{2,}", r"\*\*\d+ nodes\*\*")
        for m in re.finditer(pattern, text)
    ]
    assert not stale, f"sizes quoted in 00's markdown (print them from a cell instead): {stale}"
