"""The runtime watchdog (wbmpc.runtime.watchdog): trips on plan age and on consecutive overruns only, latched,
each trip reported once; the damping-mode command; argument checks."""

import numpy as np
import pytest

from wbmpc.runtime.robot import MotorCommand
from wbmpc.runtime.watchdog import Watchdog

damping_command = MotorCommand.damping_mode


def test_trips_once_on_plan_age_and_stays_tripped():
    dog = Watchdog(max_plan_age_s=0.1, max_consecutive_overruns=3)
    for now in (0.0, 0.05, 0.1):
        state = dog.check(now, 0.0, False)
        assert not state.tripped and state.reason == "" and state.plan_age_s == pytest.approx(now)
    state = dog.check(0.31, 0.0, False)
    assert state.tripped and state.just_tripped and state.tripped_at_s == 0.31
    assert state.reason == "no new plan for 0.31 s (limit 0.10 s)"
    assert dog.events == [(0.31, state.reason)]
    later = dog.check(0.32, 0.315, False)  # a fresh plan does not clear the latch
    assert later.tripped and not later.just_tripped and later.reason == state.reason
    dog.trip("the MPC worker died", 0.33)
    assert dog.events == [(0.31, state.reason)] and dog.reason == state.reason  # reported once
    dog.reset()
    assert not dog.check(0.4, 0.39, False).tripped
    assert dog.check(0.6, 0.39, False).just_tripped and len(dog.events) == 2


def test_trips_on_consecutive_overruns_not_on_isolated_ones():
    dog = Watchdog(max_plan_age_s=1.0, max_consecutive_overruns=3)
    pattern = [True, False, True, True, False, True, False] * 5
    for k, overrun in enumerate(pattern):
        assert not dog.check(k * 0.002, 0.0, overrun).tripped
    states = [dog.check(0.1 + k * 0.002, 0.1, True) for k in range(3)]
    assert [s.tripped for s in states] == [False, False, True]
    assert [s.consecutive_overruns for s in states] == [1, 2, 3]
    assert states[-1].reason == "3 control ticks in a row overran their deadline (limit 3)"
    assert len(dog.events) == 1
    fast = Watchdog(max_plan_age_s=0.0125, max_consecutive_overruns=3)
    assert fast.check(0.05, 0.019, False).reason == "no new plan for 0.031 s (limit 0.0125 s)"


def test_external_trip_and_startup_grace():
    dog = Watchdog(0.1, 2, startup_grace_s=1.0)
    assert not dog.check(5.0, None, False).tripped  # no plan yet: the grace runs from the first check
    assert not dog.check(5.9, None, False).tripped
    state = dog.check(6.2, None, False)
    assert state.tripped and state.reason == "no plan received 1.20 s after start (limit 1.00 s)"
    dog.reset()
    state = dog.trip("observation contains NaN (joint 3 position)")
    assert state.tripped and state.just_tripped and state.tripped_at_s == 6.2  # the last check's time
    assert dog.events[-1] == (6.2, "observation contains NaN (joint 3 position)")
    assert not dog.trip("another cause", 7.0).just_tripped and len(dog.events) == 2


def test_the_damping_command_only_damps():
    cmd = damping_command(18, 2.0)
    for name in ("q", "dq", "tau", "kp", "kd"):
        assert getattr(cmd, name).shape == (18,), name
    assert np.all(cmd.kp == 0) and np.all(cmd.tau == 0) and np.all(cmd.q == 0) and np.all(cmd.dq == 0)
    assert np.all(cmd.kd == 2.0)
    dq = np.linspace(-3, 3, 18)
    q_measured = np.linspace(-1, 1, 18)
    torque = cmd.tau + cmd.kp * (cmd.q - q_measured) + cmd.kd * (cmd.dq - dq)
    np.testing.assert_allclose(torque, -2.0 * dq)
    assert torque @ dq <= 0  # it only takes energy out
    per_joint = damping_command(3, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(per_joint.kd, [1.0, 2.0, 3.0])


@pytest.mark.parametrize(
    ("call", "name"),
    [
        (lambda: Watchdog(0.0, 3), "max_plan_age_s"),
        (lambda: Watchdog(float("inf"), 3), "max_plan_age_s"),
        (lambda: Watchdog(0.1, 0), "max_consecutive_overruns"),
        (lambda: Watchdog(0.1, 2.5), "max_consecutive_overruns"),
        (lambda: Watchdog(0.1, 3, startup_grace_s=-1.0), "startup_grace_s"),
        (lambda: Watchdog(0.1, 3).check(float("nan"), 0.0, False), "now_s"),
        (lambda: Watchdog(0.1, 3).check(0.0, float("nan"), False), "plan_time_s"),
        (lambda: Watchdog(0.1, 3).check(0.0, 0.0, "yes"), "overrun"),
        (lambda: Watchdog(0.1, 3).trip(""), "reason"),
        (lambda: damping_command(0, 1.0), "nj"),
        (lambda: damping_command(3, 0.0), "kd"),
        (lambda: damping_command(3, [1.0, -1.0, 1.0]), "kd"),
        (lambda: damping_command(3, [1.0, 2.0]), "kd"),
        (lambda: damping_command(3, float("nan")), "kd"),
    ],
)
def test_bad_arguments_are_named(call, name):
    with pytest.raises(ValueError, match=name):
        call()
