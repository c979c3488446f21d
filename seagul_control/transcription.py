"""The one NLP builder: direct multiple-shooting transcription of paper Eq. 1 (full horizon) and Eq. 3 (MPC).

Decision variables are ordered stage by stage, ``(x_k, u_k[, h_k])`` for ``k = 0..n-1`` then ``x_n``, and so are the
constraints (stage 0: ``x_0 - x_init = 0``; stage k: the defect ``x_{k+1} - F(x_k, u_k, h_k) = 0``, the form
fatrop requires; then the time constraint), so that the structure-exploiting ``fatrop`` solver can detect the
optimal-control structure; IPOPT solves the same NLP. ``x_init``, ``tau`` and the terminal-cost parameters
``theta`` are NLP *parameters*: a solver is built once and reused for every start, time to go and value network.

Time: with ``free_time`` the steps ``h_k`` are decision variables in ``step_bounds`` and the elapsed time is the sum
of the steps; ``time_mode`` says how the horizon meets ``tau``: ``"equal"`` (``sum(h) = tau``, the full-horizon
problem), ``"at_most"`` (``sum(h) <= tau``) or ``"free"``. For a fixed step, ``h_k = tau / n`` (``step=None``, the
full-horizon problem) or a given constant (the MPC's control period).

The terminal cost is a CasADi Function ``(x_n, tau_remaining, theta) -> scalar``; by default the task's ``l_f``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Literal

import casadi as ca
import numpy as np

from seagul_envs.tasks.base import Task

TimeMode = Literal["equal", "at_most", "free"]

#: IPOPT statuses we accept as a (locally) optimal solution.
SUCCESS_STATUSES = frozenset({"Solve_Succeeded", "Solved_To_Acceptable_Level", "Success"})


@dataclass
class TranscriptionSolution:
    """Raw primal-dual solution of one transcription solve (interpretation lives with the caller)."""

    success: bool
    """True iff the solver reports a (locally) optimal solution and the defects are satisfied."""
    status: str
    """The solver's return status."""
    objective: float
    """Optimal objective."""
    states: np.ndarray
    """``(n + 1, nx)`` knot states."""
    controls: np.ndarray
    """``(n, nu)`` inputs."""
    steps: np.ndarray
    """``(n,)`` steps."""
    param_sensitivity: np.ndarray
    """``d objective / d p`` for ``p = [x_init, tau, theta]`` (minus CasADi's ``lam_p``)."""
    defect_multipliers: np.ndarray
    """``(n, nx)`` multipliers of the defects ``F(x_k, u_k, h_k) - x_{k+1} = 0``: row ``k`` is ``dV_{k+1}/dx_{k+1}``."""
    iterations: int
    """Solver iterations."""
    solve_time: float
    """Wall time (s)."""
    primal: np.ndarray = field(repr=False)
    """Full primal vector (for warm starts)."""
    lam_g: np.ndarray = field(repr=False)
    """Constraint multipliers (for warm starts)."""
    lam_x: np.ndarray = field(repr=False)
    """Bound multipliers (for warm starts)."""


def default_ipopt_options() -> dict[str, Any]:
    """Quiet, exact-Hessian IPOPT settings used unless the caller overrides them."""
    return {
        "ipopt.print_level": 0,
        "ipopt.sb": "yes",
        "ipopt.tol": 1e-8,
        "ipopt.acceptable_tol": 1e-6,
        "ipopt.max_iter": 500,
        "ipopt.mu_strategy": "adaptive",
        "print_time": False,
    }


def default_fatrop_options() -> dict[str, Any]:
    """Quiet fatrop settings (structure detected from the stage-wise variable and constraint order)."""
    return {"fatrop.print_level": 0, "print_time": False, "structure_detection": "auto", "fatrop.max_iter": 500}


class Transcription:
    """Direct multiple-shooting transcription, built once and solved many times.

    Args:
        task: the task (dynamics, costs, bounds).
        horizon: number of intervals ``n`` (default: the task's ``num_steps``).
        free_time: steps are decision variables (default: ``not task.fixed_step``).
        step: fixed step (s) when not ``free_time``; ``None`` means ``tau / n``.
        step_bounds: bounds of free steps (default: the task's).
        time_mode: how ``sum(h)`` meets ``tau`` (see the module docstring); only used with ``free_time``.
        final_box: impose the task's terminal box ``x_final_low <= x_n <= x_final_high``.
        terminal_cost: ``(x, tau_remaining, theta) -> scalar``; default the task's ``l_f(x)``.
        n_theta: length of ``theta`` (terminal-cost parameters).
        substeps: RK4 substeps per interval (default: the task's).
        solver: ``"ipopt"`` or ``"fatrop"``.
        solver_options: options merged over the defaults of that solver.
    """

    def __init__(
        self,
        task: Task,
        horizon: int | None = None,
        *,
        free_time: bool | None = None,
        step: float | None = None,
        step_bounds: tuple[float, float] | None = None,
        time_mode: TimeMode = "equal",
        final_box: bool = True,
        terminal_cost: ca.Function | None = None,
        n_theta: int = 0,
        substeps: int | None = None,
        solver: Literal["ipopt", "fatrop"] = "ipopt",
        solver_options: dict[str, Any] | None = None,
    ) -> None:
        n = task.num_steps if horizon is None else int(horizon)
        if n < 1:
            raise ValueError(f"horizon must be >= 1 interval, got {horizon}")
        if solver not in ("ipopt", "fatrop"):
            raise ValueError(f"unknown solver {solver!r}; use 'ipopt' or 'fatrop'")
        if time_mode not in ("equal", "at_most", "free"):
            raise ValueError(f"unknown time_mode {time_mode!r}; use 'equal', 'at_most' or 'free'")
        self.task = task
        self.horizon = n
        self.free_time = (not task.fixed_step) if free_time is None else bool(free_time)
        self.step = None if step is None else float(step)
        self.step_bounds = tuple(task.step_bounds if step_bounds is None else step_bounds)
        self.time_mode: TimeMode = time_mode
        self.final_box = final_box
        self.n_theta = int(n_theta)
        self.substeps = task.rk4_substeps if substeps is None else int(substeps)
        self.solver_name = solver
        nx, nu = task.nx, task.nu

        if terminal_cost is None:
            xs, ts, th = ca.SX.sym("x", nx), ca.SX.sym("t"), ca.SX.sym("theta", self.n_theta)
            terminal_cost = ca.Function("task_terminal", [xs, ts, th], [task.terminal_cost(xs)])
        self.terminal_cost = terminal_cost

        x_init = ca.SX.sym("x_init", nx)
        tau = ca.SX.sym("tau")
        theta = ca.SX.sym("theta", self.n_theta)
        p = ca.vertcat(x_init, tau, theta)
        F = task.rk4_step(self.substeps)

        w: list[ca.SX] = []
        lbw: list[np.ndarray] = []
        ubw: list[np.ndarray] = []
        g: list[ca.SX] = []
        lbg: list[np.ndarray] = []
        ubg: list[np.ndarray] = []
        equality: list[bool] = []
        # Index bookkeeping to read the solution back.
        self._x_idx: list[np.ndarray] = []
        self._u_idx: list[np.ndarray] = []
        self._h_idx: list[int] = []
        self._defect_rows: list[np.ndarray] = []

        def add_var(sym: ca.SX, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
            start = sum(int(v.numel()) for v in w)
            w.append(sym)
            lbw.append(np.broadcast_to(lo, (sym.numel(),)).astype(float))
            ubw.append(np.broadcast_to(hi, (sym.numel(),)).astype(float))
            return np.arange(start, start + sym.numel())

        def add_con(expr: ca.SX, lo: np.ndarray | float, hi: np.ndarray | float) -> np.ndarray:
            start = sum(int(c.numel()) for c in g)
            g.append(expr)
            lo_arr = np.broadcast_to(lo, (expr.numel(),)).astype(float)
            hi_arr = np.broadcast_to(hi, (expr.numel(),)).astype(float)
            lbg.append(lo_arr)
            ubg.append(hi_arr)
            equality.extend(bool(v) for v in (lo_arr == hi_arr))
            return np.arange(start, start + expr.numel())

        objective = 0
        elapsed = 0
        fixed_h = (tau / n) if self.step is None else self.step
        x_k = ca.SX.sym("x_0", nx)
        self._x_idx.append(add_var(x_k, -np.inf, np.inf))
        add_con(x_k - x_init, 0.0, 0.0)
        for k in range(n):
            u_k = ca.SX.sym(f"u_{k}", nu)
            self._u_idx.append(add_var(u_k, task.u_low, task.u_high))
            if self.free_time:
                h_k = ca.SX.sym(f"h_{k}")
                self._h_idx.append(int(add_var(h_k, self.step_bounds[0], self.step_bounds[1])[0]))
            else:
                h_k = fixed_h
            objective = objective + h_k * task.stage_cost(x_k, u_k)
            elapsed = elapsed + h_k
            x_next = ca.SX.sym(f"x_{k + 1}", nx)
            last = k == n - 1
            lo = np.maximum(task.x_low, task.x_final_low) if (last and final_box) else task.x_low
            hi = np.minimum(task.x_high, task.x_final_high) if (last and final_box) else task.x_high
            self._x_idx.append(add_var(x_next, lo, hi))
            # fatrop's structure detection requires gap-closing rows written as x_{k+1} - F(x_k, u_k).
            self._defect_rows.append(add_con(x_next - F(x_k, u_k, h_k), 0.0, 0.0))
            x_k = x_next
        if self.free_time and time_mode == "equal":
            self._time_row = int(add_con(elapsed - tau, 0.0, 0.0)[0])
        elif self.free_time and time_mode == "at_most":
            self._time_row = int(add_con(elapsed - tau, -np.inf, 0.0)[0])
        else:
            self._time_row = -1
        objective = objective + terminal_cost(x_k, tau - elapsed, theta)

        self._w = ca.vertcat(*w)
        self._lbw, self._ubw = np.concatenate(lbw), np.concatenate(ubw)
        self._lbg, self._ubg = np.concatenate(lbg), np.concatenate(ubg)
        self._np = int(p.numel())
        self._equality = equality
        nlp = {"x": self._w, "p": p, "f": objective, "g": ca.vertcat(*g)}
        if solver == "ipopt":
            options = {**default_ipopt_options(), "expand": True, **(solver_options or {})}
        else:
            options = {**default_fatrop_options(), "expand": True, "equality": equality, **(solver_options or {})}
        self._solver = ca.nlpsol(f"{task.name}_{solver}_n{n}", solver, nlp, options)
        # Stage costs and elapsed time of a solution, for per-knot labels.
        self._stage_cost_fn = task.stage_cost.map(n)

    # ----------------------------------------------------------------- sizes
    @property
    def num_variables(self) -> int:
        """Length of the primal vector."""
        return int(self._w.numel())

    @property
    def num_parameters(self) -> int:
        """Length of ``p = [x_init, tau, theta]``."""
        return self._np

    # ---------------------------------------------------------------- guesses
    def pack_guess(self, states: np.ndarray, controls: np.ndarray, steps: np.ndarray | None = None) -> np.ndarray:
        """Primal vector from ``(n+1, nx)`` states, ``(n, nu)`` controls and (free time) ``(n,)`` steps."""
        w0 = np.zeros(self.num_variables)
        states = np.asarray(states, dtype=float).reshape(self.horizon + 1, self.task.nx)
        controls = np.asarray(controls, dtype=float).reshape(self.horizon, self.task.nu)
        for k, idx in enumerate(self._x_idx):
            w0[idx] = states[k]
        for k, idx in enumerate(self._u_idx):
            w0[idx] = controls[k]
        if self.free_time:
            h = np.full(self.horizon, float(np.mean(self.step_bounds))) if steps is None else np.asarray(steps)
            w0[self._h_idx] = h
        return w0

    def line_guess(self, x_init: np.ndarray, tau: float, target: np.ndarray | None = None) -> np.ndarray:
        """Straight line in state space from ``x_init`` to ``target`` (default the goal), zero inputs, even steps."""
        target = self.task.goal if target is None else np.asarray(target, dtype=float)
        s = np.linspace(0.0, 1.0, self.horizon + 1)[:, None]
        states = (1 - s) * np.asarray(x_init, dtype=float) + s * target
        steps = np.full(self.horizon, np.clip(tau / self.horizon, *self.step_bounds)) if self.free_time else None
        return self.pack_guess(states, np.zeros((self.horizon, self.task.nu)), steps)

    # ------------------------------------------------------------------ solve
    def solve(
        self,
        x_init: np.ndarray,
        tau: float,
        theta: np.ndarray | None = None,
        *,
        guess: np.ndarray | None = None,
        lam_g: np.ndarray | None = None,
        lam_x: np.ndarray | None = None,
    ) -> TranscriptionSolution:
        """Solve from ``x_init`` with time to go ``tau`` (inputs assumed validated by the caller)."""
        theta_arr = np.zeros(self.n_theta) if theta is None else np.asarray(theta, dtype=float).ravel()
        if theta_arr.size != self.n_theta:
            raise ValueError(f"theta must have {self.n_theta} entries, got {theta_arr.size}")
        p = np.concatenate([np.asarray(x_init, dtype=float).ravel(), [float(tau)], theta_arr])
        w0 = self.line_guess(x_init, tau) if guess is None else np.asarray(guess, dtype=float)
        args: dict[str, Any] = {
            "x0": w0,
            "p": p,
            "lbx": self._lbw,
            "ubx": self._ubw,
            "lbg": self._lbg,
            "ubg": self._ubg,
        }
        if lam_g is not None:
            args["lam_g0"] = lam_g
        if lam_x is not None:
            args["lam_x0"] = lam_x
        start = time.perf_counter()
        out = self._solver(**args)
        elapsed = time.perf_counter() - start
        stats = self._solver.stats()
        w = np.asarray(out["x"]).ravel()
        lam_g_out = np.asarray(out["lam_g"]).ravel()
        states = np.stack([w[idx] for idx in self._x_idx])
        controls = np.stack([w[idx] for idx in self._u_idx])
        if self.free_time:
            steps = w[self._h_idx]
        else:
            steps = np.full(self.horizon, tau / self.horizon if self.step is None else self.step)
        status = str(stats.get("return_status", "unknown"))
        success = bool(stats.get("success", False)) or status in SUCCESS_STATUSES
        return TranscriptionSolution(
            success=success and bool(np.all(np.isfinite(w))),
            status=status,
            objective=float(out["f"]),
            states=states,
            controls=controls,
            steps=steps,
            param_sensitivity=-np.asarray(out["lam_p"]).ravel(),
            # Negated: the NLP rows are x_{k+1} - F, the documented convention is F - x_{k+1}.
            defect_multipliers=np.stack([-lam_g_out[rows] for rows in self._defect_rows]),
            iterations=int(stats.get("iter_count", -1)),
            solve_time=elapsed,
            primal=w,
            lam_g=lam_g_out,
            lam_x=np.asarray(out["lam_x"]).ravel(),
        )

    def stage_costs(self, states: np.ndarray, controls: np.ndarray, steps: np.ndarray) -> np.ndarray:
        """``h_k * l(x_k, u_k)`` for ``k = 0..n-1``."""
        rates = np.asarray(self._stage_cost_fn(states[:-1].T, controls.T)).ravel()
        return rates * np.asarray(steps)
