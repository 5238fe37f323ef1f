"""What a user sets and gets back around a solve: commands, the MPC's configuration, the plan.

:class:`Commands` (velocities, arm velocity and force, base height, gait), :class:`MPCConfig` (the runtime
configuration: gait, swing, weights, time steps, fallbacks, push recovery), :class:`SolverSettings` (how the
NLP is solved, fixed at construction) and :class:`MPCSolution` (a plan over the horizon with its solver
report). :class:`wbmpc.control.mpc.WholeBodyMPC` consumes the first three and returns the last; all are
re-exported from :mod:`wbmpc.control.mpc`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace

import numpy as np

from wbmpc import checks
from wbmpc.model.robot import Robot
from wbmpc.ocp.gait import (
    Gait,
    GaitSchedule,
    SwingParams,
    make_gait,
)
from wbmpc.ocp.time_grid import node_times
from wbmpc.solver.codegen import RELEASE_FLAGS
from wbmpc.solver.nlpsol import SOLVERS, TOL, WARM_MAX_ITER, WARM_MU_INIT

DT_BOUNDS = (1e-4, 1.0)  # [s] sane range of the MPC's time steps


def default_weights(robot: Robot) -> tuple[np.ndarray, np.ndarray]:
    """Diagonal state and input weights ``Q`` (2 nv,) and ``R`` (nv + n_f + nj,) after the paper's code.

    State ``[dq, v]``: base position (x, y free; z 1e3), roll/pitch 1e4, yaw free; leg joints
    hip/thigh/calf 1000/500/500; arm joints 100; base velocity 2000 (lin x), 5000 (lin y), 1000 (lin z,
    ang x, y), 2000 (yaw rate); leg joint velocity 2; arm joint velocity 10. Inputs ``[a, F, tau]``: 1e-3,
    5e-4, 1e-4 (legs) and 1e-2 (arm).

    The lateral velocity weight is 2.5 times the paper's 2000: with 2000 a lateral command is overshot by
    20-25 % on the B1 + Z1 (12-14 % on the B1 alone), the plan itself keeping the base faster than
    commanded over its first stages; the joint-posture terms (the swing legs' hips held at their nominal
    angles, the foot landing under the hip) outweigh the velocity error. With 5000 the overshoot is about
    12 %, forward and yaw tracking unchanged (``data/results/command_tracking.csv``).
    """
    n_arm = len(robot.arm_joint_names)
    n_leg = robot.nj - n_arm
    leg_pos = np.tile([1000.0, 500.0, 500.0], n_leg // 3) if n_leg % 3 == 0 else np.full(n_leg, 500.0)
    Q = np.concatenate(
        [
            [0.0, 0.0, 1000.0, 10000.0, 10000.0, 0.0],
            leg_pos,
            np.full(n_arm, 100.0),
            [2000.0, 5000.0, 1000.0, 1000.0, 1000.0, 2000.0],
            np.full(n_leg, 2.0),
            np.full(n_arm, 10.0),
        ]
    )
    R = np.concatenate(
        [
            np.full(robot.nv, 1e-3),
            np.full(3 * len(robot.contact_frames), 5e-4),
            np.full(n_leg, 1e-4),
            np.full(n_arm, 1e-2),
        ]
    )
    return Q, R


@dataclass
class Commands:
    """What the user asks of the robot for one solve.

    Attributes:
        base_linear_velocity: Base linear velocity [m/s] in the heading frame (x forward, y left, z up).
        base_angular_velocity: Base angular velocity [rad/s] in the heading frame (yaw rate is z).
        ee_velocity: Arm end-effector linear velocity [m/s], world axes: (3,) held over the horizon (the
            paper), or (3, N-1) one per stage (e.g. a reference trajectory's future velocities).
        ee_force: Force [N] the environment applies on the end effector, world axes (e.g. a pulled load
            pulls back: negative x when the robot pulls towards +x).
        base_height: Nominal base height [m]; ``None`` keeps the robot's nominal pose height.
        gait: The gait or :class:`~wbmpc.ocp.gait.GaitSchedule` of this solve's stage contacts (a command
            schedule's, :class:`wbmpc.control.command_schedule.CommandSchedule`); ``None``: the MPC's
            configured ``MPCConfig.gait``.
    """

    base_linear_velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    base_angular_velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    ee_velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    ee_force: np.ndarray = field(default_factory=lambda: np.zeros(3))
    base_height: float | None = None
    gait: Gait | GaitSchedule | None = None

    def validated(self) -> Commands:
        out = {}
        for name in ("base_linear_velocity", "base_angular_velocity", "ee_velocity", "ee_force"):
            value = np.asarray(getattr(self, name), dtype=float)
            if name == "ee_velocity" and value.ndim == 2 and value.shape[0] == 3:
                pass  # one command per stage; the stage count is checked when the parameters are packed
            elif value.shape != (3,):
                raise ValueError(f"command {name} must have shape (3,), got {value.shape}")
            if not np.isfinite(value).all():
                raise ValueError(f"command {name} contains NaN or inf: {value}")
            out[name] = value
        if self.gait is not None and not isinstance(self.gait, Gait | GaitSchedule):
            raise ValueError(
                f"command gait must be a Gait or GaitSchedule (wbmpc.ocp.gait), got {self.gait!r}"
            )
        if self.base_height is not None:
            out["base_height"] = checks.number(
                "command base_height", self.base_height, low=0.0, high=5.0, low_open=True, unit="m"
            )
        if all(value is getattr(self, name) for name, value in out.items()):
            return self  # already float arrays and a float height: nothing to convert (every tick)
        return replace(self, **out)


@dataclass
class MPCConfig:
    """Runtime configuration: every field can change between solves without a rebuild (how the NLP is solved
    is :class:`SolverSettings`, fixed at construction).

    Attributes:
        gait: Gait (see :func:`wbmpc.ocp.gait.make_gait`) or a :class:`wbmpc.ocp.gait.GaitSchedule` of gaits
            in time (stand, trot, stand); the same object decides the plant's contacts in a closed loop.
        swing: Swing-foot spline parameters.
        dt_min, dt_max: First and last time step [s] of the geometric grid (equal: uniform grid).
        mu: Friction coefficient of the cone constraint.
        Q, R: Diagonal weights; ``None`` uses :func:`default_weights`.
        front_force_ratio: Share of the weight the force targets put on the front feet.
        dual_warm_start: Pass the previous constraint multipliers as the initial dual guess.
        cold_retry: After a failed warm-started solve, retry once from a cold start (same tick) before
            falling back to the previous plan (its iteration cap: ``SolverSettings.retry_max_iter``).
        kick_recovery: Swing abort after a push [m/s]: when the measured horizontal base velocity jumps off
            the last plan's by more than this, a swing in its first ``kick_recovery_phase`` is aborted: the
            foot is brought down at ``touchdown_speed`` (at least ``touchdown_time``) and planned in stance
            until its nominal touchdown (a push at a lift-off). A trot
            otherwise leaves one diagonal pair on the ground for a whole swing, over which the base is an
            inverted pendulum on a line that cannot be slowed across it. ``None`` disables it.
        kick_recovery_phase: Swing phase (fraction of the swing) below which a swing is aborted.
        touchdown_speed: Downward foot speed [m/s] of an aborted swing; touchdown_time: its minimum [s].
        kick_recovery_hold: Also abort the early swings while recovering (base velocity further than
            ``kick_recovery`` from the command); False: only the swings in progress when the push is detected.
        kick_ee_release: While recovering from a push, the end-effector velocity reference [s]: it starts at
            the measured end-effector velocity and ramps to the command over this time (the arm moves with the
            pushed base instead of holding the hand still at once); ``None``: the command throughout.
    """

    gait: Gait | GaitSchedule = field(default_factory=lambda: make_gait("trot", 0.8))
    swing: SwingParams = field(default_factory=SwingParams)
    dt_min: float = 0.01
    dt_max: float = 0.1
    mu: float = 0.7
    Q: np.ndarray | None = None
    R: np.ndarray | None = None
    front_force_ratio: float | None = None
    dual_warm_start: bool = True
    cold_retry: bool = True
    kick_recovery: float | None = 0.3
    kick_recovery_phase: float = 0.15
    touchdown_speed: float = 0.3
    touchdown_time: float = 0.03
    kick_recovery_hold: bool = False
    kick_ee_release: float | None = 0.2

    def __post_init__(self):
        for name in ("dt_min", "dt_max", "mu"):
            value = getattr(self, name)
            if not isinstance(value, int | float | np.number) or not np.isfinite(value) or value <= 0:
                raise ValueError(f"MPCConfig.{name} must be a positive number, got {value!r}")
        for name in ("dt_min", "dt_max"):
            if not DT_BOUNDS[0] <= getattr(self, name) <= DT_BOUNDS[1]:
                raise ValueError(
                    f"MPCConfig.{name} = {getattr(self, name)} s is outside "
                    f"[{DT_BOUNDS[0]}, {DT_BOUNDS[1]}] s (the paper's steps: 0.01 to 0.1 s)"
                )
        for name in ("touchdown_speed", "touchdown_time", "kick_recovery_phase") + tuple(
            name for name in ("kick_recovery", "kick_ee_release") if getattr(self, name) is not None
        ):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float | np.number) or not value > 0:
                raise ValueError(f"MPCConfig.{name} must be a positive number, got {value!r}")
        if not isinstance(self.kick_recovery_hold, bool | np.bool_):
            hold = self.kick_recovery_hold
            raise ValueError(f"MPCConfig.kick_recovery_hold must be True or False, got {hold!r}")
        for name in ("Q", "R"):
            value = getattr(self, name)
            if value is not None:
                value = np.asarray(value, dtype=float)
                if value.ndim != 1 or not np.all(np.isfinite(value)) or np.any(value < 0):
                    raise ValueError(
                        f"MPCConfig.{name} must be a 1-D array of finite weights >= 0, got {value!r}"
                    )
        if self.front_force_ratio is not None and not 0.0 <= self.front_force_ratio <= 1.0:
            raise ValueError(f"MPCConfig.front_force_ratio must be in [0, 1], got {self.front_force_ratio!r}")
        if self.dt_max < self.dt_min:
            raise ValueError(f"MPCConfig.dt_max ({self.dt_max}) must be >= dt_min ({self.dt_min})")
        if not isinstance(self.gait, Gait | GaitSchedule):
            raise ValueError(
                f"MPCConfig.gait must be a Gait or GaitSchedule (see wbmpc.ocp.gait), got {self.gait!r}"
            )
        if not isinstance(self.swing, SwingParams):
            raise ValueError(f"MPCConfig.swing must be a SwingParams (wbmpc.ocp.gait), got {self.swing!r}")
        checks.gait_velocities("MPCConfig.gait", self.gait)


@dataclass(frozen=True)
class SolverSettings:
    """How the MPC's NLP is solved: fixed when the MPC builds its solvers (frozen; a new MPC for others).

    Attributes:
        solver: ``"fatrop"`` or ``"ipopt"``.
        compiled: Solve with the generated and compiled NLP functions (Fatrop only; built once and cached,
            see :mod:`wbmpc.solver.codegen`).
        compile_flags: gcc flags of the compiled library built first (and of the direct driver's).
        release_flags: gcc flags of the release library that replaces it: built from the same C in a
            background process at the lowest priority while the first library serves, switched to between two
            solves when ready, used from the start once cached (:mod:`wbmpc.solver.release`; left out in quick
            mode). ``None``: no release library.
        release_build: Build the release library in the background when it is not cached; False: use it
            only if it is (the runtime's MPC worker: a compiler beside the control loops would take a core).
        tol: Solver tolerance (paper: 1e-3).
        max_iter: Iteration cap of a warm-started solve.
        cold_max_iter: Iteration cap of a cold start (the first solve).
        retry_max_iter: Iteration cap of the cold retry after a failed warm solve (``MPCConfig.cold_retry``).
        mu_init_warm, mu_init_cold: Initial barrier parameter of warm and cold starts.
        direct: Solve with the direct primal-dual warm-started Fatrop driver (:mod:`wbmpc.solver.direct`)
            instead of the casadi plugin, which stays its fallback. With ``compiled`` its stage functions are
            generated C (built per problem and cached; ``compile_flags`` are their flags); without, the
            same functions run in CasADi's virtual machine inside the driver, which is compiled once per
            machine in a few seconds (no problem is compiled). ``None`` (default): the direct driver in
            process, the plugin when ``compiled`` (``direct=True`` for the compiled driver). Fatrop only.
        threads: Threads on which the direct driver evaluates the stages (1..8; the solution does not depend
            on it). ``None`` (default): 2 on a machine with 2 cores or more for the in-process driver (its
            evaluations are most of its time), 1 for the compiled one (a control loop shares the cores).

    Raises:
        ValueError: On an unknown solver, ``compiled`` or ``direct`` without Fatrop, a non-positive tolerance
            or barrier parameter, an iteration cap below 1, threads outside 1..8, or flags that are not
            strings.
    """

    solver: str = "fatrop"
    compiled: bool = False
    compile_flags: tuple[str, ...] = ("-O1",)
    release_flags: tuple[str, ...] | None = RELEASE_FLAGS
    release_build: bool = True
    tol: float = TOL
    max_iter: int = WARM_MAX_ITER
    cold_max_iter: int = 200
    retry_max_iter: int = 100
    mu_init_warm: float = WARM_MU_INIT
    mu_init_cold: float = 1e-1
    direct: bool | None = None
    threads: int | None = None

    @property
    def direct_driver(self) -> bool:
        """Whether the MPC solves with the direct driver (``direct``, its ``None`` resolved)."""
        if self.direct is None:
            return self.solver == "fatrop" and not self.compiled
        return bool(self.direct)

    @property
    def driver_threads(self) -> int:
        """The direct driver's evaluation threads (``threads``, its ``None`` resolved)."""
        if self.threads is not None:
            return int(self.threads)
        return 2 if self.direct_driver and not self.compiled and (os.cpu_count() or 1) >= 2 else 1

    def __post_init__(self):
        for name in ("tol", "mu_init_warm", "mu_init_cold"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float | np.number):
                raise ValueError(f"SolverSettings.{name} must be a positive number, got {value!r}")
            if not np.isfinite(value) or value <= 0:
                raise ValueError(f"SolverSettings.{name} must be a positive number, got {value!r}")
        for name in ("max_iter", "cold_max_iter", "retry_max_iter"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
                raise ValueError(f"SolverSettings.{name} must be an integer >= 1, got {value!r}")
        if self.solver not in SOLVERS:
            raise ValueError(f"unknown solver {self.solver!r}; available: {list(SOLVERS)}")
        if self.compiled and self.solver != "fatrop":
            raise ValueError(
                "SolverSettings.compiled needs solver='fatrop' (the library holds Fatrop's functions)"
            )
        if not isinstance(self.release_build, bool | np.bool_):
            build = self.release_build
            raise ValueError(f"SolverSettings.release_build must be True or False, got {build!r}")
        if self.direct is not None and not isinstance(self.direct, bool | np.bool_):
            raise ValueError(f"SolverSettings.direct must be True, False or None, got {self.direct!r}")
        if self.direct and self.solver != "fatrop":
            raise ValueError("SolverSettings.direct needs solver='fatrop' (it is a Fatrop driver)")
        if self.threads is not None:
            checks.integer("SolverSettings.threads", self.threads, low=1, high=8)
        checks.names("SolverSettings.compile_flags", self.compile_flags, unique=False)
        object.__setattr__(self, "compile_flags", tuple(self.compile_flags))
        if self.release_flags is not None:
            checks.names("SolverSettings.release_flags", self.release_flags, unique=False)
            object.__setattr__(self, "release_flags", tuple(self.release_flags))


@dataclass
class MPCSolution:
    """A plan over the horizon, in absolute quantities.

    Attributes:
        t: Time [s] of node 0 (the measurement time).
        dts: Time steps [s] (N-1,).
        q: Configurations (N, nq); v: velocities (N, nv); a: accelerations (N-1, nv).
        forces: Contact forces on the robot (N-1, n_c, 3) [N], world axes; swing feet already zeroed.
        tau: Joint torques (n_tau, nj) [N m] (all N-1 stages for forward dynamics; the RNEA torques of the
            plan for the centroidal formulations).
        contact: Contact flags (4, N-1).
        success: Whether the solver converged. iterations, solve_time [s], status: solver report.
        constraint_violation: Max bound violation of the constraints at the returned point.
        fallback: True if this is not a new converged plan: the previous plan re-used after a failed
            solve, or, when no solve has converged yet, the static hold (``hold``).
        hold: True for the static hold: the measured pose held with static-equilibrium torques, returned
            when a solve fails before any converged plan exists (never the unconverged iterate).
        reason: Why the solve failed (empty on success).
        findings: Physical prechecks that flagged the commands or the state before this solve.
        w, lam_g: Raw primal and constraint-multiplier vectors (for warm starts).
    """

    t: float
    dts: np.ndarray
    q: np.ndarray
    v: np.ndarray
    a: np.ndarray
    forces: np.ndarray
    tau: np.ndarray
    contact: np.ndarray
    success: bool
    iterations: int
    solve_time: float
    status: str
    constraint_violation: float
    fallback: bool = False
    hold: bool = False
    reason: str = ""
    findings: tuple = ()
    w: np.ndarray | None = None
    lam_g: np.ndarray | None = None
    timings: dict = field(default_factory=dict)

    @property
    def node_times(self) -> np.ndarray:
        """Times of the plan's nodes [s] (N,): ``t`` and the cumulated ``dts``."""
        return node_times(self.dts, self.t)
