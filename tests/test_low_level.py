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


def test_references_follow_the_horizon_past_the_torque_nodes_and_stay_bounded():
    """Only the first nodes have torques (n_tau = 2 here), but q, v, a exist at every node: a plan kept in
    use past its torque nodes (a slow solve) must give the references of the interval that holds t, not
    v_des = v_1 + a_1 (t - t_1) growing without bound, and hold them at the horizon's end."""
    p = plan()
    p.tau = p.tau[:2]  # torques at nodes 0 and 1 only
    p.v = np.array([np.r_[np.zeros(6), [k, -k]] for k in (1.0, 2.0, 3.0, 4.0)])  # differs per node
    p.a = np.array([np.r_[np.zeros(6), [a, -a]] for a in (10.0, -5.0, 7.0)])
    p.q = np.array([np.r_[np.zeros(7), [k, 2 * k]] for k in (0.0, 0.1, 0.2, 0.3)])
    low = LowLevelController()
    low.update(p)
    ref = low.reference(0.04)  # on [t2, t3] = [0.03, 0.07], past the torque nodes
    assert ref.tau_ff == pytest.approx([10.0, 10.0])  # the last torque node, held
    assert ref.q_des == pytest.approx([0.2 + 3.0 * 0.01, 0.4 - 3.0 * 0.01])
    assert ref.v_des == pytest.approx([3.0 + 7.0 * 0.01, -3.0 - 7.0 * 0.01])
    late = low.reference(10.0)  # long after the horizon's end: held at its last interval's end
    assert late.v_des == pytest.approx([3.0 + 7.0 * 0.04, -3.0 - 7.0 * 0.04])
    assert late.q_des == pytest.approx([0.2 + 3.0 * 0.04, 0.4 - 3.0 * 0.04])
