"""The runtime on the wall clock, with faults: the emulated robot, the MPC worker and the 500 Hz controller
as processes. In every case no NaN or out-of-limit command is written, the controller goes to the damping
mode within two loop periods when it must (and only then), says so once, and the log keeps the run up to
the fault. These runs are short and check what cannot depend on the machine's speed; the 60 s benchmark
(``data/runtime/emulated_dds.json``) measures the timing."""

import numpy as np
import pytest

from wbmpc.model.robot import load_b1_z1
from wbmpc.runtime.faults import Faults
from wbmpc.runtime.run import RuntimeConfig, run_runtime

#: Wall-clock runs of three processes: they run after the parallel part of the suite, with the machine to
#: themselves (scripts/test.sh), since a test process beside them takes the worker's CPU.
pytestmark = pytest.mark.wallclock

#: The faults come at 1.5 s while the robot stands (its solves converge in 3 iterations; on 2 cores a trot's
#: contact switches can still stop the plans for a while, issue 21 open, which says nothing of the fault).
GAIT = "stand:1.8"
FAULT_AT = 1.5
PERIOD = 0.002
#: The worker is killed in the first trot steps.
TROT = "stand:1,trot@0.2:1.5"
KILL_AT = 1.25
#: A SIGKILLed worker is seen dead only once the kernel has freed its memory (~400 MB mapped): 13 and 29 ms
#: measured on this machine; the controller reacts at its next tick after that.
KILL_TEARDOWN = 0.05


@pytest.fixture(scope="module")
def limits():
    robot = load_b1_z1()
    return (
        robot.model.lowerPositionLimit[7:],
        robot.model.upperPositionLimit[7:],
        np.asarray(robot.joint_torque_limits),
    )


def _run(tmp_path, faults: Faults, gait: str = GAIT, **changes):
    # A generous plan-age limit: a slow solve must not trip it; the faults that must trip it do so by other
    # causes (or by far more than this). The controller gets a CPU to itself: what is tested is its
    # reaction to the fault, in ticks. Overruns do not trip the watchdog here: on 2 cores about 1 % of the
    # ticks overrun, a few in a row at times (issue 21 open), which says nothing of the fault; the
    # overrun rule has its own tests (tests/test_runtime_watchdog.py, on a fake clock).
    config = RuntimeConfig(
        gait_schedule=gait,
        faults=faults,
        max_plan_age=0.5,
        **({"cpu_layout": "controller", "max_overruns": 10**6} | changes),
    )
    summary = run_runtime(config, tmp_path)
    log = dict(np.load(tmp_path / "runtime_log.npz"))
    return summary, log


def _commands_are_safe(log, limits):
    low, high, tau = limits
    for key in ("q_cmd", "dq_cmd", "tau_cmd"):
        assert np.all(np.isfinite(log[key])), key
    active = ~log["damping"].astype(bool)
    assert np.all(log["q_cmd"][active] >= low - 1e-9) and np.all(log["q_cmd"][active] <= high + 1e-9)
    assert np.all(np.abs(log["tau_cmd"]) <= tau * (1 + 1e-9))
    damping = ~active
    assert np.all(log["tau_cmd"][damping] == 0) and np.all(log["q_cmd"][damping] == 0)


def _damped_once(summary, reason_part):
    assert summary["damping"]
    events = summary["watchdog_events"]
    assert len(events) == 1, events  # said once
    assert reason_part in events[0]["reason"], events


def test_worker_killed_mid_trot(tmp_path, limits):
    # The worker has a CPU to itself for the trot.
    faults = Faults(kill_worker_at=KILL_AT)
    summary, log = _run(tmp_path, faults, TROT, cpu_layout="split")
    _commands_are_safe(log, limits)
    _damped_once(summary, "worker died")
    assert KILL_AT <= summary["damping_from_s"] <= KILL_AT + KILL_TEARDOWN + 2 * PERIOD
    assert log["t"][-1] > KILL_AT + 0.5  # the log goes on past the fault
    assert summary["worker"]["errors"]  # its account never came: said so, not hidden


def test_stalled_solver_goes_to_damping_when_the_plan_is_too_old(tmp_path, limits):
    summary, log = _run(tmp_path, Faults(stall_at=FAULT_AT, stall_for=0.6), "stand:2.5")
    _commands_are_safe(log, limits)
    _damped_once(summary, "no new plan")
    assert FAULT_AT < summary["damping_from_s"] < FAULT_AT + 0.6


def test_a_short_stall_is_ridden_out(tmp_path, limits):
    """A 0.1 s stall stays under the plan-age limit: the plan in use carries the robot through it."""
    summary, log = _run(tmp_path, Faults(stall_at=FAULT_AT, stall_for=0.1))
    _commands_are_safe(log, limits)
    assert not summary["damping"], summary["watchdog_events"]
    # The run is also a ROS 2 bag: the estimate as joint states and odometry, read back as recorded.
    from wbmpc.io.rosbag import read_bag

    assert summary["bag"] == str(tmp_path / "bag")
    # No raw IMU in the runtime's log; skipped ticks leave gaps of a few periods.
    topics = {"imu": None, "required": (), "max_gap_factor": 1e3}
    bag = read_bag(tmp_path / "bag", topics, robot=load_b1_z1())
    assert bag.signals["t"] == pytest.approx(log["t"], abs=1e-6)
    assert bag.signals["q_meas"][:, 7:] == pytest.approx(log["q_hat"][:, 7:], abs=1e-9)
    assert bag.signals["q_meas"][:, :3] == pytest.approx(log["q_hat"][:, :3], abs=1e-9)


@pytest.mark.parametrize(
    ("faults", "count"),
    [
        (Faults(lose=(FAULT_AT, FAULT_AT + 0.01)), "lost"),
        (Faults(duplicate_at=FAULT_AT), "duplicated"),
        (Faults(reorder_at=FAULT_AT), "reordered"),
    ],
    ids=["lost", "duplicated", "out of order"],
)
def test_lost_duplicated_and_reordered_observations_are_absorbed(tmp_path, limits, faults, count):
    summary, log = _run(tmp_path, faults)
    _commands_are_safe(log, limits)
    assert summary["injected"][count] > 0
    assert not summary["damping"], summary["watchdog_events"]
    if count != "lost":
        assert any("stale" in problem for problem in summary["controller_problems"])


def test_nan_in_a_sensor_field_goes_to_damping_at_once(tmp_path, limits):
    summary, log = _run(tmp_path, Faults(nan_at=FAULT_AT))
    _commands_are_safe(log, limits)
    _damped_once(summary, "not finite")
    assert FAULT_AT <= summary["damping_from_s"] <= FAULT_AT + 2 * PERIOD


def test_a_restarted_robot_is_noticed(tmp_path, limits):
    summary, log = _run(tmp_path, Faults(restart_robot_at=FAULT_AT))
    _commands_are_safe(log, limits)
    _damped_once(summary, "")
    reason = summary["watchdog_events"][0]["reason"]
    assert "restarted" in reason or "no observation" in reason, reason
    # The new robot process needs a moment to publish: until then no observation, then a tick counter
    # that went back; either way the controller stops commanding the plan within two periods of seeing it.
    assert FAULT_AT <= summary["damping_from_s"] <= FAULT_AT + 0.1


def test_runtime_config_refuses_bad_input_before_starting():
    with pytest.raises(ValueError, match="robot must be"):
        RuntimeConfig(robot="real")
    with pytest.raises(ValueError, match="domain"):
        RuntimeConfig(robot="dds", domain=999)
    with pytest.raises(ValueError, match="interface"):
        RuntimeConfig(robot="dds", interface="no-such-if0")
    with pytest.raises(ValueError, match="Faults.nan_at"):
        Faults(nan_at=-1.0)
    with pytest.raises(ValueError, match="duration"):
        RuntimeConfig(duration=1.0)
