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
