"""The 500 Hz low level: linear interpolation of the plan's first nodes, PD, clipping at the limits."""

from types import SimpleNamespace

import numpy as np
import pytest

from wbmpc.control.low_level import LowLevelController


def plan(nj=2):
    dts = np.array([0.01, 0.02, 0.04])
    return SimpleNamespace(
        dts=dts,
        node_times=np.concatenate([[0.0], np.cumsum(dts)]),
        tau=np.array([[0.0] * nj, [10.0] * nj, [30.0] * nj]),
        q=np.zeros((4, 7 + nj)),
        v=np.tile(np.r_[np.zeros(6), np.ones(nj)], (4, 1)),
        a=np.tile(np.r_[np.zeros(6), 2 * np.ones(nj)], (3, 1)),
    )


def test_interpolates_then_moves_to_the_next_interval_and_holds():
    low = LowLevelController()
    low.update(plan())
    assert low.reference(0.005).tau_ff == pytest.approx([5.0, 5.0])  # halfway on [t0, t1]
    assert low.reference(0.02).tau_ff == pytest.approx([20.0, 20.0])  # no new plan: on [t1, t2]
    assert low.reference(0.5).tau_ff == pytest.approx([30.0, 30.0])  # beyond the torque nodes: held
    ref = low.reference(0.005)
    assert ref.q_des == pytest.approx([0.005, 0.005]) and ref.v_des == pytest.approx([1.01, 1.01])


def test_pd_and_clipping_are_counted():
    low = LowLevelController(kp=100.0, kd=0.0, torque_limits=np.array([8.0, 100.0]))
    low.update(plan())
    q = np.zeros(9)
    tau = low.torque(0.005, q, np.zeros(8))
    # tau_ff 5 + kp * (q_des - q) = 5 + 100 * 0.005 = 5.5 on both joints: within the limits
    assert tau == pytest.approx([5.5, 5.5]) and low.violations == 0
    assert low.last_reference.tau_ff == pytest.approx([5.0, 5.0])
    tau = low.torque(0.02, q, np.zeros(8))  # 20 + PD > 8 on the first joint
    assert tau[0] == 8.0 and tau[1] > 8.0 and low.violations == 1


def test_no_plan_is_a_clear_error():
    with pytest.raises(RuntimeError, match="no MPC plan yet"):
        LowLevelController().reference(0.0)
