"""Condensed single shooting: a short fixed-step lookahead solved over its inputs alone.

For a fixed-step transcription whose only inequality constraints are input bounds (the acrobot's lookahead: ``n``
steps of ``h``, ``|u| <= u_max``, no state bounds), the multiple-shooting NLP of
:class:`~seagul_control.transcription.Transcription`::

    min_{x, u}  sum_k h l(x_k, u_k) + T(x_n, tau - n h; theta)
    s.t.        x_0 = x_init,  x_{k+1} = F(x_k, u_k, h),  lo <= u_k <= hi

is the same problem as ``min_{lo <= U <= hi} J(U; p)`` with the states rolled out (``U = (u_0, ..., u_{n-1})``,
``p = [x_init, tau, theta, model_params]``): both have the same local minima with the same inputs. With one input
and five steps ``U`` has five entries. :class:`ShootingSolver` minimises ``J`` by the projected Newton method of
Bertsekas (1982, "Projected Newton methods for optimization problems with simple constraints"):

1. one call of a compiled ``(J, dJ/dU, d2J/dU2)`` per iteration (the states, the stage costs, the terminal cost and
   their exact derivatives through the RK4 rollout, in one generated C function);
2. the variables at a bound whose gradient pushes outward form the active set ``A`` (within
   ``eps = min(eps0, |U - P(U - g)|)``); on the free set the Newton direction uses the Hessian with its eigenvalues
   replaced by their absolute values, floored at ``delta`` (the saddle-free modification: a descent direction where
   ``J`` is not convex, the exact Newton step where it is); active variables take a scaled gradient step;
3. an Armijo search along the projection arc ``P(U + alpha d)`` on ``J`` alone.

It stops when the projected gradient ``|U - P(U - g)|_inf`` is below ``tol``. ``J`` is not convex (a learned
terminal cost has local minima the warm start may sit in), so with the option ``starts = m`` the solver also
descends from ``m`` constant inputs spread over the bounds and keeps the lowest converged ``J`` (the given start
wins ties). Converged inputs satisfy the same
first-order conditions as the lifted NLP's; the states, the defects' multipliers (the costates
``dJ/dx_{k+1}`` with the inputs fixed, equal to the lifted NLP's multipliers at a KKT point) and the sensitivity
``dV/dp`` (envelope theorem: the bounds do not depend on ``p``) come from one more compiled call.

Python overhead dominates: a step of the acrobot's 5-step MPC with a 3 x (2 x 64) ensemble costs a few compiled
calls of ~0.05 ms each, against fatrop's ~1.1 ms per iteration on the lifted 30-variable NLP (docs/experiments/mpc.md).
Each solve is bounded (``max_iter`` iterations of at most ``max_backtracks`` function evaluations), so it needs no
watchdog; ``max_solve_time`` is checked between iterations.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

#: Options of the ``"shooting"`` solver (``TranscriptionOptions(solver_options={"shooting.<name>": value})``).
SHOOTING_DEFAULTS: dict[str, float] = {
    "max_iter": 50,
    "tol": 1e-6,
    "armijo": 1e-4,
    "max_backtracks": 30,
    "eps_active": 1e-3,
    "starts": 0,
}


def condensation_problems(task: Any, *, free_time: bool, final_box: bool, soft_bounds: bool) -> list[str]:
    """Why a transcription of ``task`` cannot be solved by :class:`ShootingSolver` (empty: it can): it needs fixed
    steps, finite input bounds and no state bounds on knots ``1..n`` (path bounds, the terminal box with
    ``final_box``, soft bounds)."""
    problems = []
    if free_time:
        problems.append("free steps")
    if soft_bounds:
        problems.append("soft bounds")
    bounded = np.isfinite(task.x_low) | np.isfinite(task.x_high)
    if final_box:
        bounded = bounded | np.isfinite(task.x_final_low) | np.isfinite(task.x_final_high)
    if np.any(bounded):
        problems.append("finite state bounds on knots 1..n (path bounds or the terminal box)")
    if not (np.all(np.isfinite(task.u_low)) and np.all(np.isfinite(task.u_high))):
        problems.append("infinite input bounds")
    return problems


class BufferedFunction:
    """A CasADi Function evaluated through its numeric buffer (``Function.buffer``): inputs and outputs are numpy
    arrays bound once, so a call costs the compiled code plus ~1 us, instead of converting every argument (the
    MPC's parameter vector holds the network's ~14,000 weights: 1 ms per ordinary call)."""

    def __init__(self, fn: ca.Function) -> None:
        self.fn = fn
        self.inputs: list[np.ndarray] = [np.zeros(fn.nnz_in(i)) for i in range(fn.n_in())]
        self.outputs: list[np.ndarray] = []
        for i in range(fn.n_out()):
            if fn.sparsity_out(i).is_dense():
                shape = (fn.size2_out(i), fn.size1_out(i))  # column-major storage seen row-major: the transpose
                self.outputs.append(np.zeros(shape))
            else:
                raise ValueError(f"{fn.name()}: output {i} must be dense for the buffered call")
        self._buf, self._eval = fn.buffer()
        buf: Any = self._buf  # casadi's stubs declare (index, buffer, size); the Python binding takes a memoryview
        for i, arr in enumerate(self.inputs):
            buf.set_arg(i, memoryview(arr))  # type: ignore[arg-type]
        for i, arr in enumerate(self.outputs):
            buf.set_res(i, memoryview(arr))  # type: ignore[arg-type]

    def set_input(self, i: int, value: np.ndarray) -> None:
        """Copy ``value`` into input ``i`` (kept for later calls)."""
        self.inputs[i][:] = np.asarray(value, dtype=float).ravel()

    def __call__(self, u: np.ndarray) -> list[np.ndarray]:
        """Evaluate with input 0 set to ``u`` (the other inputs as last set); returns the output arrays (transposed
        matrices: ``out.T`` is the CasADi matrix; reused by the next call)."""
        self.inputs[0][:] = u
        self._eval()
        return self.outputs


@dataclass
class ShootingResult:
    """One condensed solve."""

    success: bool
    status: str
    objective: float
    controls: np.ndarray
    """``(n * nu,)`` inputs."""
    iterations: int
    projected_gradient: float
    """``|U - P(U - dJ/dU)|_inf`` at the returned inputs."""
    gradient: np.ndarray
    """``dJ/dU`` at the returned inputs (the active bounds' multipliers are ``-gradient`` there)."""
    start: int = 0
    """Which start the result descended from: 0 the given one, ``i >= 1`` the ``i``-th extra start (``starts``)."""


class ShootingSolver:
    """Projected Newton on ``J(U; p)`` with box bounds on ``U`` (module docstring).

    Args:
        f: ``(U, p) -> J``.
        fgh: ``(U, p) -> (J, dJ/dU, d2J/dU2)``.
        lo: lower bounds of ``U`` (finite).
        hi: upper bounds of ``U`` (finite).
        options: :data:`SHOOTING_DEFAULTS` entries.
    """

    def __init__(self, f: ca.Function, fgh: ca.Function, lo: np.ndarray, hi: np.ndarray, **options: Any) -> None:
        unknown = sorted(set(options) - set(SHOOTING_DEFAULTS))
        if unknown:
            raise ValueError(
                f"unknown shooting solver option(s) {unknown}; known: {sorted(SHOOTING_DEFAULTS)} "
                "(given as 'shooting.<name>')"
            )
        opts = {**SHOOTING_DEFAULTS, **options}
        self.max_iter = int(opts["max_iter"])
        self.tol = float(opts["tol"])
        self.armijo = float(opts["armijo"])
        self.max_backtracks = int(opts["max_backtracks"])
        self.eps_active = float(opts["eps_active"])
        self.starts = int(opts["starts"])
        if self.starts < 0 or self.starts != opts["starts"]:
            raise ValueError(f"shooting solver option starts: a whole number >= 0 needed, got {opts['starts']!r}")
        if self.max_iter < 0 or not self.tol > 0 or not 0 < self.armijo < 0.5 or self.max_backtracks < 1:
            raise ValueError(
                "shooting solver options: max_iter >= 0, tol > 0, 0 < armijo < 0.5 and max_backtracks >= 1 needed, "
                f"got {opts}"
            )
        self.f = BufferedFunction(f)
        self.fgh = BufferedFunction(fgh)
        self.lo = np.asarray(lo, dtype=float).ravel().copy()
        self.hi = np.asarray(hi, dtype=float).ravel().copy()
        if not (np.all(np.isfinite(self.lo)) and np.all(np.isfinite(self.hi)) and np.all(self.lo <= self.hi)):
            raise ValueError("the shooting solver needs finite input bounds with lo <= hi")

    def solve(
        self,
        u0: np.ndarray,
        p: np.ndarray,
        lo: np.ndarray | None = None,
        hi: np.ndarray | None = None,
        max_time: float | None = None,
        starts: int | None = None,
    ) -> ShootingResult:
        """Minimise ``J(., p)`` from ``u0`` (projected onto the bounds) within ``lo``/``hi`` (default: the built).

        With ``starts = m > 0`` (this call's, default the ``starts`` option) it also descends from ``m`` constant
        inputs spread evenly over the bounds (``m = 1``: their midpoint; ``m >= 2``: both bounds and ``m - 2`` levels
        between them) and returns the converged result of lowest ``J``; ``u0``'s is kept unless another is lower by
        more than ``tol * (1 + |J|)``."""
        lo = self.lo if lo is None else np.asarray(lo, dtype=float)
        hi = self.hi if hi is None else np.asarray(hi, dtype=float)
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            raise ValueError("the shooting solver needs finite input bounds (set both lbu and ubu)")
        start = time.perf_counter()
        m = self.starts if starts is None else int(starts)
        if m < 0:
            raise ValueError(f"starts must be >= 0, got {starts!r}")
        best = self._descend(u0, p, lo, hi, max_time, start)
        if m == 0:
            return best
        levels = [0.5] if m == 1 else np.linspace(0.0, 1.0, m)
        iterations = best.iterations
        for i, level in enumerate(levels, start=1):
            other = self._descend(lo + level * (hi - lo), p, lo, hi, max_time, start)
            iterations += other.iterations
            margin = self.tol * (1.0 + abs(best.objective))
            if other.success and (not best.success or other.objective < best.objective - margin):
                best, best.start = other, i
        best.iterations = iterations  # the solve's total over its starts
        return best

    def _descend(
        self, u0: np.ndarray, p: np.ndarray, lo: np.ndarray, hi: np.ndarray, max_time: float | None, start: float
    ) -> ShootingResult:
        """One projected Newton descent from ``u0`` (``start``: the solve's start time, for ``max_time``)."""
        u = np.clip(np.where(np.isfinite(u0), u0, 0.0), lo, hi)
        pg_norm = float("inf")
        self.f.set_input(1, p)
        self.fgh.set_input(1, p)
        j, g, h = self._fgh(u)
        for it in range(self.max_iter + 1):
            if not (np.isfinite(j) and np.all(np.isfinite(g))):
                return ShootingResult(False, "non-finite objective or gradient", j, u, it, pg_norm, g)
            pg_norm = float(np.max(np.abs(u - np.clip(u - g, lo, hi)))) if u.size else 0.0
            if pg_norm <= self.tol:
                return ShootingResult(True, "Success", j, u, it, pg_norm, g)
            if it == self.max_iter:
                break
            if max_time is not None and time.perf_counter() - start > max_time:
                return ShootingResult(False, f"timeout: {max_time:g} s", j, u, it, pg_norm, g)
            if not np.all(np.isfinite(h)):
                return ShootingResult(False, "non-finite Hessian", j, u, it, pg_norm, g)
            d = self._direction(u, g, h, lo, hi, pg_norm)
            # The full step is evaluated with its derivatives (usually accepted: then they serve the next
            # iteration); shorter steps with J alone.
            alpha, accepted = 1.0, False
            for trial_index in range(self.max_backtracks):
                trial = np.clip(u + alpha * d, lo, hi)
                decrease = float(g @ (trial - u))
                if decrease >= 0:  # the projection bent the step uphill: shorten it
                    alpha *= 0.5
                    continue
                trial_out = self._fgh(trial) if trial_index == 0 else None
                jt = trial_out[0] if trial_out is not None else float(self.f(trial)[0].ravel()[0])
                if np.isfinite(jt) and jt <= j + self.armijo * decrease:
                    u, accepted = trial, True
                    j, g, h = trial_out if trial_out is not None else self._fgh(u)
                    break
                alpha *= 0.5
            if not accepted:
                # No decrease along the arc: stationary to the precision J can be evaluated at.
                ok = pg_norm <= 1e3 * self.tol
                return ShootingResult(ok, "Success" if ok else "line search failed", j, u, it, pg_norm, g)
        return ShootingResult(False, "Maximum_Iterations_Exceeded", j, u, self.max_iter, pg_norm, g)

    def _fgh(self, u: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        """``J``, ``dJ/dU`` and ``d2J/dU2`` at ``u`` (copies; the parameters as last set)."""
        out = self.fgh(u)
        return float(out[0].ravel()[0]), out[1].ravel().copy(), out[2].T.copy()

    def _direction(
        self, u: np.ndarray, g: np.ndarray, h: np.ndarray, lo: np.ndarray, hi: np.ndarray, pg_norm: float
    ) -> np.ndarray:
        """Bertsekas' projected Newton direction: saddle-free Newton on the free set, scaled gradient on the
        active set (variables at a bound within ``eps`` whose gradient pushes outward)."""
        eps = min(self.eps_active * float(np.max(hi - lo, initial=1.0)), pg_norm)
        active = ((u <= lo + eps) & (g > 0)) | ((u >= hi - eps) & (g < 0))
        free = ~active
        d = np.zeros_like(u)
        if np.any(free):
            hf = h[np.ix_(free, free)]
            w, v = np.linalg.eigh(0.5 * (hf + hf.T))
            delta = 1e-8 * max(1.0, float(np.max(np.abs(w))))
            d[free] = -v @ ((v.T @ g[free]) / np.maximum(np.abs(w), delta))
        if np.any(active):
            d[active] = -g[active] / np.maximum(np.abs(np.diag(h)[active]), 1e-8)
        return d
