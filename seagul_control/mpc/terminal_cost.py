"""The limited-lookahead MPC's terminal cost: the learned value function, its trust-region guards, the goal anchor
and blend, and the end-of-episode switch to the task's ``l_f`` (module docstring of :mod:`seagul_control.mpc`).

The value function enters the NLP as its CasADi form ``(x, tau, theta_vf) -> V`` with its parameters as NLP
parameters, in the vector ``theta = [theta_vf, lo, hi, w, (Vhat(x*), dVhat/dx(x*)), s]``: the trust box, the box
weight, the goal anchor's terms when they are parameters, and the switch ``s`` (1: the learned cost, 0: ``l_f``).
A new value function of the same architecture changes only ``theta`` (:meth:`TerminalCostMPC.set_value_function`).

A value function that records the fingerprint of the task it was trained for (``task_fingerprint``, as
``seagul_learn.ValueNetwork`` files do) must match the MPC's task: a same-named variant (another mass, other
bounds) is refused with a ValueError (:func:`check_fingerprint`); one without a fingerprint is accepted.
"""

from __future__ import annotations

import copy
import inspect
from typing import Any

import casadi as ca
import numpy as np

from seagul_control.mpc.base import _MPCBase, _Problem
from seagul_control.mpc.options import TrustRegion
from seagul_control.value_function import CasadiValueFunction
from seagul_envs.tasks.base import Task


def check_fingerprint(owner: str, vf: Any, task: Task) -> None:
    """Raise a ValueError when ``vf`` records a task fingerprint (``task_fingerprint``) that is neither ``task``'s
    nor that of the task ``task`` was made from by ``with_params`` (:meth:`~seagul_envs.Task.origin_fingerprint`):
    an MPC that plans with a robot's own dynamics (``task.with_params(theta)``) may use the value learned for the
    model it was derived from, as an adaptive or oracle controller does."""
    stored = getattr(vf, "task_fingerprint", None) or ""
    if stored and stored not in (task.fingerprint(), task.origin_fingerprint()):
        raise ValueError(
            f"{owner}: the value function was trained for a task with fingerprint {stored}, but task "
            f"{task.name!r} has fingerprint {task.fingerprint()}: the same name, another variant (parameters, bounds "
            "or costs differ) not made from it by with_params. Use a value function trained for this task, or build "
            "the MPC for the task it was trained for (or for task.with_params(theta) of that task)."
        )


class TerminalCostMPC(_MPCBase):
    """The terminal-cost half of :class:`~seagul_control.mpc.LimitedLookaheadMPC` (see the module docstring)."""

    # Set by LimitedLookaheadMPC.__init__.
    trust_region: TrustRegion
    trust_weight: float
    trust_box: tuple[np.ndarray, np.ndarray]
    clamp: bool
    anchor_goal: bool
    goal_blend: float
    free_time: bool
    n_vf: int
    _vf_fn: ca.Function | None
    _vf_theta: np.ndarray
    _vf_robots: Any
    _vf_taylor: tuple[ca.Function, ca.Function] | None
    _anchor_cache: dict[float, np.ndarray]
    _anchor_fn: ca.Function
    _theta: np.ndarray
    _lookahead: _Problem
    _value_function: CasadiValueFunction | None

    @property
    def robot(self) -> np.ndarray:
        """The parameters the MPC plans for (the task's own unless ``set_robot`` gave others)."""
        return self.task.theta if self._robot is None else self._robot.copy()

    # ------------------------------------------------------------------ value function
    def _check_value_function(self, vf: CasadiValueFunction) -> ca.Function:
        if not (hasattr(vf, "casadi_function") and hasattr(vf, "casadi_parameters")):
            raise TypeError(
                f"{self.name}: value_function must implement casadi_function() and casadi_parameters() "
                f"(CasadiValueFunction), got {type(vf).__name__}"
            )
        name = getattr(vf, "task_name", "")
        if name and name != self.task.name:
            raise ValueError(f"{self.name}: value function was trained for task {name!r}, not {self.task.name!r}")
        check_fingerprint(self.name, vf, self.task)
        fn = _value_function_form(vf, "matrix" if self.jit else "scalar")
        shapes = [(fn.size1_in(i), fn.size2_in(i)) for i in range(fn.n_in())]
        if fn.n_in() != 3 or shapes[0] != (self.task.nx, 1) or fn.nnz_in(1) != 1 or fn.nnz_out(0) != 1:
            raise ValueError(
                f"{self.name}: value function's CasADi form must be (x[{self.task.nx}], tau[1], theta[n]) -> V[1], "
                f"got inputs {shapes} and {fn.n_out()} output(s)"
            )
        return fn

    def set_value_function(
        self, value_function: CasadiValueFunction, trust_box: tuple[np.ndarray, np.ndarray] | None = None
    ) -> None:
        """Use a new value function of the same architecture: only NLP parameters change (no rebuild)."""
        fn = self._check_value_function(value_function)
        if self._vf_fn is None:
            raise ValueError(f"{self.name}: built without a value function; build a new MPC to add one")
        if fn is not self._vf_fn and fn.serialize() != self._vf_fn.serialize():
            raise ValueError(
                f"{self.name}: the new value function has a different CasADi structure (architecture) than the one "
                "the solver was built with; build a new MPC"
            )
        theta = np.asarray(value_function.casadi_parameters(), dtype=float).ravel()
        if theta.size != self.n_vf or not np.all(np.isfinite(theta)):
            raise ValueError(f"{self.name}: value function parameters must be {self.n_vf} finite numbers")
        low, high = self._trust_box(value_function) if trust_box is None else trust_box
        low = self.task.check_state(low, "trust_box low")
        high = self.task.check_state(high, "trust_box high")
        if np.any(high < low):
            raise ValueError(f"{self.name}: trust_box high must be >= low, got {low} and {high}")
        self._vf_robots = None
        if int(getattr(value_function, "n_params", 0) or 0) > 0:
            # Conditioned on the robot the MPC plans for, on a copy: the caller's network keeps its own condition.
            self._vf_robots = copy.deepcopy(value_function)
            self._vf_robots.condition(self.robot)
            theta = np.asarray(self._vf_robots.casadi_parameters(), dtype=float).ravel()
        self._vf_theta = theta
        self._value_function = value_function
        self._anchor_cache.clear()
        self.trust_box = (low, high)
        nx = self.task.nx
        self._theta[: self.n_vf] = theta
        self._theta[self.n_vf : self.n_vf + nx] = low
        self._theta[self.n_vf + nx : self.n_vf + 2 * nx] = high
        self._theta[self.n_vf + 2 * nx] = self.trust_weight
        self.reset()

    def _trust_box(self, vf: Any) -> tuple[np.ndarray, np.ndarray]:
        """Training box of ``vf``: ``training_box()``, else mean +- 2 std of its input standardisation, else X0 +- 1."""
        nx = self.task.nx
        box = getattr(vf, "training_box", None)
        if callable(box):
            box = box()
        if box is not None:
            lo, hi = box
            return np.asarray(lo, dtype=float).ravel()[:nx], np.asarray(hi, dtype=float).ravel()[:nx]
        mean, std = getattr(vf, "in_mean", None), getattr(vf, "in_std", None)
        if mean is not None and std is not None:
            mean = np.asarray(_to_numpy(mean), dtype=float).ravel()[:nx]
            std = np.asarray(_to_numpy(std), dtype=float).ravel()[:nx]
            if mean.size == nx and std.size == nx and np.all(np.isfinite(mean)) and np.all(std > 0):
                return mean - 2 * std, mean + 2 * std
        width = np.maximum(self.task.x0_high - self.task.x0_low, 1.0)
        return self.task.x0_low - width, self.task.x0_high + width

    def _terminal_model(self, n_vf: int) -> tuple[ca.Function, ca.Function]:
        """The condensed solver's ``terminal_model``: ``(x0, tau_rem, theta) -> c`` (the value function's Taylor
        coefficients at ``x0``) and ``(x, tau_rem, theta, x0, c)`` -> the terminal cost with ``Vhat`` replaced by
        its Taylor model (equal to :meth:`_terminal_function` to second order in ``x`` at ``x = x0``)."""
        assert self._vf_taylor is not None
        taylor, _ = self._vf_taylor
        nx = self.task.nx
        x0, tau = ca.MX.sym("x0", nx), ca.MX.sym("tau_rem")
        theta = ca.MX.sym("theta", n_vf + 2 * nx + 2 + self._n_anchor_parameters())
        coeffs = ca.Function("mpc_terminal_taylor", [x0, tau, theta], [taylor.call([x0, tau, theta[:n_vf]], True)[0]])
        return coeffs, self._terminal_function(n_vf, taylor=True)

    def _terminal_function(self, n_vf: int, taylor: bool = False) -> ca.Function:
        """``(x, tau_rem, theta) -> s * guarded Vhat + (1 - s) * l_f`` with ``theta = [vf, lo, hi, w, s]``, or
        ``[vf, lo, hi, w, Vhat(x*), dVhat/dx(x*), s]`` when the goal anchor's terms are parameters.

        ``taylor``: ``(x, tau_rem, theta, x0, c) -> ...``, the same cost with ``Vhat`` replaced by its Taylor model
        at ``x0`` with coefficients ``c`` (:meth:`_terminal_model`)."""
        nx = self.task.nx
        # The matrix form of a value function stays MX (compiled unexpanded); everything else is SX.
        sym: Any = ca.MX if (self._matrix_form() or taylor) else ca.SX
        x = sym.sym("x", nx)
        tau = sym.sym("tau_rem")
        n_anchor = self._n_anchor_parameters()
        theta = sym.sym("theta", n_vf + 2 * nx + 2 + n_anchor)
        model_inputs = []
        if taylor:
            assert self._vf_taylor is not None
            model_inputs = [sym.sym("x0", nx), sym.sym("c", self._vf_taylor[1].nnz_in(2))]
        lf = self.task.terminal_cost(x)
        if self._vf_fn is None:
            return ca.Function("mpc_terminal", [x, tau, theta, *model_inputs], [lf])
        # Inlined in MX: a call node's derivative functions would also carry (zero) sensitivities of the n_vf
        # weights, which made the compiled Hessian 3x slower.
        if taylor:
            assert self._vf_taylor is not None
            v = self._vf_taylor[1].call([x, *model_inputs], True, False)[0]
        else:
            v = self._vf_fn.call([x, tau, theta[:n_vf]], sym is ca.MX, False)[0]
        if self.anchor_goal:
            # V(x*, tau) = 0 and dV/dx(x*, tau) = 0 at an equilibrium goal: remove the network's first-order error
            # there, which otherwise shifts the closed loop's resting point away from the goal.
            xs = sym.sym("xs", nx)
            if n_anchor:
                # Compiled fixed steps: tau_rem is known before each solve, so Vhat(x*, tau_rem) and its gradient
                # are NLP parameters (computed once per tau_rem, :meth:`_anchor_terms`); in the graph they made the
                # compiled Hessian 5x slower.
                t_a, th_a = ca.MX.sym("tau_rem"), ca.MX.sym("theta_vf", n_vf)
                v_a = self._vf_fn.call([xs, t_a, th_a], True, False)[0]
                at_goal = ca.substitute([v_a, ca.jacobian(v_a, xs)], [xs], [ca.DM(self.task.goal)])
                self._anchor_fn = ca.Function("vf_at_goal", [t_a, th_a], at_goal)
                v_goal = theta[n_vf + 2 * nx + 1]
                g_goal = theta[n_vf + 2 * nx + 2 : n_vf + 2 * nx + 2 + nx].T
            else:
                vs = self._vf_fn.call([xs, tau, theta[:n_vf]], sym is ca.MX, False)[0]
                at_goal_fn = ca.Function("vf_at_goal", [xs, tau, theta], [vs, ca.jacobian(vs, xs)])
                v_goal, g_goal = at_goal_fn(ca.DM(self.task.goal), tau, theta)
            v = v - v_goal - ca.mtimes(g_goal, x - self.task.goal)
        if self.clamp:
            v = 0.5 * (v + ca.sqrt(v**2 + 1e-6))  # smooth max(V, 0): a cost-to-go is never negative
        lo, hi = theta[n_vf : n_vf + nx], theta[n_vf + nx : n_vf + 2 * nx]
        w, s = theta[n_vf + 2 * nx], theta[n_vf + 2 * nx + 1 + n_anchor]
        if self.trust_region == "box":
            outside = (ca.fmax(x - hi, 0) + ca.fmin(x - lo, 0)) / ca.fmax(hi - lo, 1e-6)
            v = v + w * ca.sumsqr(outside)
        elif self.trust_region == "lqr":
            v = v + lf
        if self.goal_blend > 0:
            b = ca.exp(-lf / self.goal_blend)
            v = b * lf + (1 - b) * v
        return ca.Function("mpc_terminal", [x, tau, theta, *model_inputs], [s * v + (1 - s) * lf])

    def _n_anchor_parameters(self) -> int:
        """``1 + nx`` when the goal anchor's terms are NLP parameters (compiled matrix form, fixed steps), else 0."""
        return 1 + self.task.nx if (self.anchor_goal and self._matrix_form() and not self.free_time) else 0

    def _anchor_terms(self, theta: np.ndarray, tau_rem: float) -> None:
        """Write ``Vhat(x*, tau_rem)`` and ``dVhat/dx(x*, tau_rem)`` into ``theta`` (cached per ``tau_rem``: fixed
        steps repeat the same few values every episode)."""
        n = self._n_anchor_parameters()
        if n == 0:
            return
        key = round(float(tau_rem), 9)
        terms = self._anchor_cache.get(key)
        if terms is None:
            v_goal, g_goal = self._anchor_fn(key, self._vf_theta)
            terms = np.concatenate([np.asarray(v_goal).ravel(), np.asarray(g_goal).ravel()])
            self._anchor_cache[key] = terms
        start = self.n_vf + 2 * self.task.nx + 1
        theta[start : start + n] = terms

    def _queries_value(self, theta: np.ndarray) -> bool:
        return self._vf_fn is not None and theta.size > 0 and float(theta[-1]) == 1.0

    def terminal_cost_value(self, x: np.ndarray, tau_remaining: float) -> float:
        """The learned (guarded) terminal cost as the NLP sees it, for checks."""
        theta = self._theta.copy()
        if self._vf_fn is not None:
            theta[-1] = 1.0
            self._anchor_terms(theta, tau_remaining)
        return float(self._lookahead.trans.terminal_cost(x, tau_remaining, theta))


def _value_function_form(vf: Any, form: str) -> ca.Function:
    """``vf.casadi_function(form=form)`` when ``vf`` offers that form (a ``form`` parameter), else its only form
    ``vf.casadi_function()`` (a user's value function with a single, scalar form)."""
    if form != "scalar" and "form" in inspect.signature(vf.casadi_function).parameters:
        return vf.casadi_function(form=form)
    return vf.casadi_function()


def _taylor_forms(vf: Any) -> tuple[ca.Function, ca.Function] | None:
    """``vf``'s ``"taylor"`` and ``"taylor_model"`` forms (``(x0, tau, theta) -> c`` and ``(x, x0, c) -> V``, see
    :meth:`seagul_learn.ValueNetwork.casadi_function`) when it offers them, else None (the condensed solver then
    differentiates the value function itself)."""
    if "form" not in inspect.signature(vf.casadi_function).parameters:
        return None
    try:
        coeffs, model = vf.casadi_function(form="taylor"), vf.casadi_function(form="taylor_model")
    except ValueError:
        return None
    ok = isinstance(coeffs, ca.Function) and isinstance(model, ca.Function) and coeffs.n_in() == 3
    return (coeffs, model) if ok and model.n_in() == 3 and model.nnz_in(2) == coeffs.nnz_out(0) else None


def _to_numpy(value: Any) -> np.ndarray:
    """A numpy copy of an array-like (torch tensors included, without importing torch)."""
    detach = getattr(value, "detach", None)
    if callable(detach):
        value = detach().cpu().numpy()
    return np.asarray(value)
