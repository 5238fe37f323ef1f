"""Shared pytest setup."""

import os

import pytest

# Headless plotting for tests and for notebooks executed by nbmake.
os.environ["MPLBACKEND"] = "Agg"


@pytest.fixture(scope="session")
def shared_cache(tmp_path_factory):
    """One compiled-library cache for the whole test session (compiling costs ~20 s per problem)."""
    return tmp_path_factory.mktemp("wbmpc_cache")


def fake_plan(robot, t0=0.0, ee_force_z=0.0):
    """A 15-node plan without a solve: geometric steps 10 -> 100 ms, the base moves 10 cm, a trot switch at
    node 11 (FR + RL stance before, FL + RR after), 300 N per stance foot."""
    from types import SimpleNamespace

    import numpy as np

    n_nodes = 15
    dts = 0.01 * (10.0 ** (np.arange(n_nodes - 1) / (n_nodes - 2)))
    q = np.tile(robot.q_nominal, (n_nodes, 1))
    q[:, 0] = np.linspace(0.0, 0.1, n_nodes)
    contact = np.zeros((4, n_nodes - 1), dtype=bool)
    contact[[1, 2], :11] = True
    contact[[0, 3], 11:] = True
    forces = np.zeros((n_nodes - 1, 5, 3))
    forces[:, :4, 2] = 300.0 * contact.T
    forces[:, 4, 2] = ee_force_z
    return SimpleNamespace(
        t=t0,
        dts=dts,
        node_times=t0 + np.concatenate([[0.0], np.cumsum(dts)]),
        q=q,
        forces=forces,
        contact=contact,
        success=True,
        iterations=6,
        solve_time=0.17,
    )


def forward_progress(q, minimum):
    """Signed displacement [m] of the base along its initial heading and to its left, from logged
    configurations (T, nq). Asserts at least ``minimum`` forward (a norm such as ``distance_travelled_m``
    also passes walking backwards or sideways) and a path within 27 degrees of the heading (sideways less
    than half of forward: short runs from rest drift a few centimetres sideways)."""
    import numpy as np
    import pinocchio as pin

    q = np.asarray(q)
    R0 = pin.Quaternion(q[0, 3:7]).normalized().toRotationMatrix()
    forward = R0[:2, 0] / np.linalg.norm(R0[:2, 0])
    left = np.array([-forward[1], forward[0]])
    step = q[-1, :2] - q[0, :2]
    along, across = float(step @ forward), float(step @ left)
    assert along > minimum, (
        f"forward {along:.3f} m, wanted more than {minimum:.3f} m (sideways {across:.3f} m)"
    )
    assert abs(across) < along / 2, f"sideways {across:.3f} m for {along:.3f} m forward"
    return along, across
