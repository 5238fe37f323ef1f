"""Sliders that re-solve an MPC plan in a notebook: commands and weights in, plan plot and 3-D view out.

:class:`ReSolvePanel` holds the sliders of notebook 00 (forward speed, end-effector vertical velocity and
force, the base-height and roll/pitch state weights, the foot-force input weight). Releasing a slider
re-solves after a short debounce, warm-started from the last plan; the "cold start" button re-solves from the
static standing guess. Every solve redraws the plan plot (an image, so it needs no output capture) and the
3-D view, and says what changed since the previous solve. A viewer that was closed, or none at all, is said
in the status line instead of failing silently::

    panel = ReSolvePanel(mpc, robot, commands, default_weights(robot), viewer)
    display(panel.widget)   # the sliders, the button, the status, the plot
    panel.resolve()         # the same solve from code (what a test does)

Commands and weights are runtime parameters of the optimisation problem: no solve rebuilds anything.
"""

from __future__ import annotations

import asyncio
import dataclasses
import html
import io
from dataclasses import dataclass

import numpy as np

from wbmpc.model.robot import Robot
from wbmpc.viz.plots import plot_plan

DEBOUNCE_S = 0.3  # a burst of slider releases (or keyboard steps) gives one solve


@dataclass(frozen=True)
class SliderSpec:
    """One slider: its label, unit, range and step (log sliders: exponents of ten)."""

    label: str
    unit: str
    min: float
    max: float
    step: float | None = None
    log: bool = False


SLIDERS = {
    "speed": SliderSpec("v_x", "m/s", -0.3, 0.5, 0.05),
    "ee_vz": SliderSpec("EE v_z", "m/s", -0.3, 0.3, 0.05),
    "ee_fz": SliderSpec("EE F_z", "N", -100.0, 50.0, 10.0),
    "q_height": SliderSpec("Q height", "", 1.0, 5.0, log=True),
    "q_tilt": SliderSpec("Q roll/pitch", "", 2.0, 6.0, log=True),
    "r_force": SliderSpec("R foot F", "", -6.0, -1.0, log=True),
}


class ReSolvePanel:
    """Sliders, a cold-start button, a status line and the plan plot of an MPC solved from the standing pose.

    Args:
        mpc: A :class:`wbmpc.control.mpc.WholeBodyMPC` (its ``config.Q``/``config.R`` are set by the sliders).
        robot: Its robot (the standing pose the solves start from).
        commands: The :class:`wbmpc.control.config.Commands` the sliders change (base velocity, end-effector
            velocity and force; the rest is kept).
        weights: The default weights ``(Q, R)`` (:func:`wbmpc.control.config.default_weights`) the weight
            sliders change.
        viewer: A :class:`wbmpc.viz.Viewer` to redraw, or ``None``.
        values: Initial slider values by name (see :data:`SLIDERS`); the rest start at the defaults.
        debounce: Delay [s] between the last slider release and the solve.
    """

    def __init__(
        self,
        mpc,
        robot: Robot,
        commands,
        weights: tuple[np.ndarray, np.ndarray],
        viewer=None,
        values: dict | None = None,
        debounce: float = DEBOUNCE_S,
    ):
        import ipywidgets as widgets

        self.mpc, self.robot, self.viewer, self.debounce = mpc, robot, viewer, debounce
        self.base_commands = commands
        self.Q0, self.R0 = (np.array(w, dtype=float) for w in weights)
        # R = [a (nv), F (3 per contact), tau]
        self.foot_forces = slice(robot.nv, robot.nv + 3 * robot.n_feet)
        defaults = {
            "speed": float(np.asarray(commands.base_linear_velocity)[0]),
            "ee_vz": 0.0,
            "ee_fz": 0.0,
            "q_height": self.Q0[2],
            "q_tilt": self.Q0[3],
            "r_force": self.R0[self.foot_forces][0],
        } | dict(values or {})
        self.sliders = {}
        for name, spec in SLIDERS.items():
            label = f"{spec.label} [{spec.unit}]" if spec.unit else spec.label
            common = {"value": defaults[name], "description": label, "continuous_update": False}
            if spec.log:
                slider = widgets.FloatLogSlider(base=10, min=spec.min, max=spec.max, **common)
            else:
                slider = widgets.FloatSlider(min=spec.min, max=spec.max, step=spec.step, **common)
            slider.observe(self._on_release, names="value")
            self.sliders[name] = slider
        tip = "re-solve from the static standing guess, not from the last plan"
        self.button = widgets.Button(description="cold start", button_style="primary", tooltip=tip)
        self.button.on_click(lambda _: self._from_widget(cold=True))
        self.status = widgets.HTML(value="<i>move a slider (the plan is solved when it is released)</i>")
        self.status.add_class("wbmpc-resolve-status")
        self.plot = widgets.Image(format="png", layout=widgets.Layout(max_width="900px"))
        self.widget = widgets.VBox([*self.sliders.values(), self.button, self.status, self.plot])
        self.solves = 0
        self.plan = None
        self.last_error: str | None = None
        self._solved_values: dict | None = None
        self._pending = None

    # --- what the sliders ask for ----------------------------------------------------------------------
    def values(self) -> dict:
        """The slider values by name."""
        return {name: float(slider.value) for name, slider in self.sliders.items()}

    def commands(self):
        """The commands of the sliders: ``commands`` with the base and end-effector entries replaced."""
        s = self.values()
        base = np.array(self.base_commands.base_linear_velocity, dtype=float)
        base[0] = s["speed"]
        return dataclasses.replace(
            self.base_commands,
            base_linear_velocity=base,
            ee_velocity=np.array([0.0, 0.0, s["ee_vz"]]),
            ee_force=np.array([0.0, 0.0, s["ee_fz"]]),
        )

    def weights(self) -> tuple[np.ndarray, np.ndarray]:
        """The state and input weights ``(Q, R)`` of the sliders (the defaults elsewhere)."""
        s = self.values()
        Q, R = self.Q0.copy(), self.R0.copy()
        Q[2], Q[3:5], R[self.foot_forces] = s["q_height"], s["q_tilt"], s["r_force"]
        return Q, R

    def changes(self) -> list[str]:
        """What changed since the previous solve, one ``"label: old → new unit"`` per slider."""
        if self._solved_values is None:
            return []
        out = []
        for name, new in self.values().items():
            old = self._solved_values[name]
            if not np.isclose(old, new, rtol=1e-9, atol=1e-12):
                spec = SLIDERS[name]
                out.append(f"{spec.label}: {old:.3g} → {new:.3g}{' ' + spec.unit if spec.unit else ''}")
        return out

    # --- solving ---------------------------------------------------------------------------------------
    def _on_release(self, _change=None) -> None:
        """A slider was released: solve after :attr:`debounce` seconds without another release."""
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:  # no event loop (a script or a test): solve now
            self._from_widget(cold=False)
            return
        if self._pending is not None:
            self._pending.cancel()
        self._pending = loop.call_later(self.debounce, self._debounced)

    def _debounced(self) -> None:
        self._pending = None
        self._from_widget(cold=False)

    def _from_widget(self, cold: bool) -> None:
        try:
            self.resolve(cold=cold)
        except Exception:  # noqa: BLE001 - already in the status line (resolve wrote it)
            pass

    def resolve(self, cold: bool = True):
        """Solve from the standing pose at rest with the sliders' commands and weights; redraw everything.

        Args:
            cold: Start from the static standing guess (``mpc.reset()``) rather than the last plan.

        Returns:
            The new plan (:class:`wbmpc.control.config.MPCSolution`).
        """
        if self._pending is not None:  # this solve already has the sliders' values
            self._pending.cancel()
            self._pending = None
        changes = self.changes()
        Q, R = self.weights()
        self.mpc.config.Q, self.mpc.config.R = Q, R
        commands = self.commands()
        # Warm only from this panel's own last plan: after anything else (a closed loop at another time, a
        # failed solve) the MPC's previous plan is no guess for a solve from the standing pose at t = 0.
        own = self.plan is not None and getattr(self.mpc, "previous", self.plan) is self.plan
        if not cold and not own:
            cold, why = True, " (the MPC's last plan was not this panel's)"
        else:
            why = ""
        if cold:
            self.mpc.reset()
        try:
            plan = self.mpc.solve(self.robot.q_nominal, np.zeros(self.robot.nv), t=0.0, commands=commands)
        except Exception as exc:  # shown in the panel: a callback's exception only reaches the Log Console
            self.last_error = f"{type(exc).__name__}: {exc}"
            self.status.value = f"<b style='color:#b00'>solve failed: {html.escape(self.last_error)}</b>"
            raise
        self.solves += 1
        self.plan = plan
        self._solved_values = self.values()
        view = self._redraw_viewer(plan)
        fig = plot_plan(plan, self.robot, commands=commands)
        buffer = io.BytesIO()
        fig.savefig(buffer, format="png", dpi=80)
        self.plot.value = buffer.getvalue()
        start = f"cold start{why}" if cold else "warm start from the last plan"
        changed = "; ".join(changes) if changes else "nothing (same sliders)"
        converged = "converged" if plan.success else "<b style='color:#b00'>NOT converged</b>"
        self.status.value = (
            f"<span class='wbmpc-solve-count'>solve {self.solves}</span> ({start}): "
            f"{converged}, {plan.iterations} iterations, {1e3 * plan.solve_time:.0f} ms. "
            f"Changed: {html.escape(changed)}. {view}"
        )
        return plan

    def _redraw_viewer(self, plan) -> str:
        """Draw ``plan`` in the viewer; returns the status line's sentence on what became of the 3-D view."""
        from wbmpc.viz.viewer import ViewerUnavailableError

        if self.viewer is None:
            return "No 3-D view (no viewer)."
        try:
            self.viewer.show_plan(plan)
        except ViewerUnavailableError as exc:
            return f"<b>3-D view not updated</b>: {html.escape(str(exc))}."
        return "3-D view updated."
