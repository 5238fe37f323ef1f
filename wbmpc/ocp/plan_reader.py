"""Reading the physical plan out of a solution without a CasADi call.

The OCP's plan function ``(w, p) -> (dq, v, a, forces, tau)`` (:meth:`OCPBuilder._plan_function
<wbmpc.ocp.builder.OCPBuilder>`) covers every formulation: at the velocity level the accelerations are
finite differences, torques may be RNEA outputs. For the formulations that carry a block as decision
variables, every entry of it is a decision variable, a parameter, a product of the two (a foot force
times its contact flag) or a structural zero, and NumPy reads it in microseconds where the CasADi call
and its conversions took 0.35 ms of every solve. :class:`PlanReader` finds those entries once, from the
expression graph, and evaluates any other output through a CasADi function of its own.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

__all__ = ["PlanReader"]


class PlanReader:
    """``reader(w, p) -> {name: (n_nodes, size) array}``: the plan function's outputs, transposed.

    Args:
        function: The plan function ``(w, p) -> outputs`` (an SX function, or one that expands to it).

    Attributes:
        names: The outputs, in the function's order; read: those read by NumPy; evaluated: those left
            to CasADi.
    """

    def __init__(self, function: ca.Function):
        if not function.is_a("SXFunction"):
            function = function.expand()
        n_w, n_p = function.size1_in(0), function.size1_in(1)
        w, p = ca.SX.sym("w", n_w), ca.SX.sym("p", n_p)
        # [w, p, 0, 1]: an entry is z[a] * z[b]; a variable is (i, ONE), a structural zero (ZERO, ONE).
        self._zero, self._one = n_w + n_p, n_w + n_p + 1
        index = {f"w_{i}": i for i in range(n_w)} | {f"p_{i}": n_w + i for i in range(n_p)}
        self.names = tuple(function.name_out(i) for i in range(function.n_out()))
        outputs = function(w, p)
        outputs = [outputs] if isinstance(outputs, ca.SX) else list(outputs)
        self._read: dict[str, tuple[np.ndarray, np.ndarray, tuple[int, int]]] = {}
        rest = []
        for name, out in zip(self.names, outputs, strict=True):
            factors = self._factors(ca.vec(out), index)
            if factors is None:
                rest.append((name, out))
            else:
                self._read[name] = (*factors, out.shape)
        self.read = tuple(self._read)
        self.n_w = n_w
        self._scatter = self._scatter_plan(n_w)
        self.evaluated = tuple(name for name, _ in rest)
        self._rest = None
        if rest:
            self._rest = ca.Function(
                "plan_rest", [w, p], [o for _, o in rest], ["w", "p"], list(self.evaluated)
            )

    def __call__(self, w: np.ndarray, p: np.ndarray) -> dict[str, np.ndarray]:
        w = np.asarray(w, dtype=float).ravel()
        p = np.asarray(p, dtype=float).ravel()
        z = np.concatenate([w, p, [0.0, 1.0]])
        plan = {}
        for name, (a, b, (rows, cols)) in self._read.items():
            plan[name] = (z[a] * z[b]).reshape(cols, rows)  # column-major (rows, cols), transposed
        if self._rest is not None:
            for name, value in self._rest(w=w, p=p).items():
                plan[name] = np.array(value).T
        return {name: plan[name] for name in self.names}

    @property
    def can_scatter(self) -> bool:
        """Whether :meth:`scatter` can build ``w`` (every decision variable appears exactly once in the
        outputs read by NumPy, alone or times a parameter)."""
        return self._scatter is not None

    def scatter(self, values: dict[str, np.ndarray]) -> np.ndarray:
        """The primal vector ``w`` whose plan holds ``values`` (arrays shaped like :meth:`__call__`'s, each
        missing rows are zero; a parameter factor, such as a contact flag, is not applied).

        Raises:
            RuntimeError: this plan function cannot be inverted so (:attr:`can_scatter` is False).
        """
        if self._scatter is None:
            raise RuntimeError("this plan function is not a scatter of w (see PlanReader.can_scatter)")
        w = np.empty(self.n_w)
        for name, (dest, src, size) in self._scatter.items():
            flat = np.asarray(values[name], dtype=float).reshape(-1)[:size]
            if flat.size < size:  # fewer rows than the plan has (e.g. torques): the rest are zero
                flat = np.concatenate([flat, np.zeros(size - flat.size)])
            w[dest] = flat[src]
        return w

    def _scatter_plan(self, n_w: int) -> dict | None:
        """Per output read by NumPy: the w indices it holds and its entries holding them."""
        owner = np.full(n_w, -1)
        plans = {}
        for name, (a, b, (rows, cols)) in self._read.items():
            is_w_a, is_w_b = a < n_w, b < n_w
            if np.any(is_w_a & is_w_b):  # a product of two decision variables: not a scatter
                return None
            entries = np.flatnonzero(is_w_a | is_w_b)
            dest = np.where(is_w_a, a, b)[entries]
            if np.any(owner[dest] >= 0) or len(np.unique(dest)) != len(dest):
                return None  # a variable in two places: which value to take is the formulation's call
            owner[dest] = 1
            plans[name] = (dest, entries, rows * cols)
        return plans if np.all(owner >= 0) else None

    def _factors(self, out: ca.SX, index: dict[str, int]) -> tuple[np.ndarray, np.ndarray] | None:
        """The two factor indices of every entry of ``out``, or ``None`` if one is anything else."""
        a, b = np.full(out.shape[0], self._zero), np.full(out.shape[0], self._one)
        for i in range(out.shape[0]):
            entry = out[i]
            if entry.is_zero():
                continue
            if entry.is_symbolic():
                a[i] = index[entry.name()]
            elif entry.is_op(ca.OP_MUL) and entry.dep(0).is_symbolic() and entry.dep(1).is_symbolic():
                a[i], b[i] = index[entry.dep(0).name()], index[entry.dep(1).name()]
            else:
                return None
        return a, b
