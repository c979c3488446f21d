"""The one NLP builder: direct multiple-shooting transcription of paper Eq. 1 (full horizon) and Eq. 3 (MPC).

Decision variables are ordered stage by stage, ``(x_k[, t_k], u_k[, h_k])`` for ``k = 0..n-1`` then
``x_n[, t_n]``, and so are the constraints (stage 0: ``x_0 - x_init = 0``; stage k: the defect
``x_{k+1} - F(x_k, u_k, h_k) = 0``, the form fatrop requires; then the time constraint), so that the
structure-exploiting ``fatrop`` solver can detect the optimal-control structure; IPOPT solves the same NLP.
``x_init``, ``tau`` and the terminal-cost parameters ``theta`` are NLP *parameters*: a solver is built once and
reused for every start, time to go and value network.

Time: with ``free_time`` the steps ``h_k`` are decision variables in ``step_bounds`` and the elapsed time is carried
as an extra state ``t_k`` (``t_0 = 0``, ``t_{k+1} = t_k + h_k``), so that ``sum(h) = tau`` is a constraint of the
last stage only and the NLP stays stage-wise (fatrop cannot take a constraint that couples every stage);
``time_mode`` says how the horizon meets ``tau``: ``"equal"`` (``sum(h) = tau``, the full-horizon problem),
``"at_most"`` (``sum(h) <= tau``) or ``"free"``. For a fixed step, ``h_k = tau / n`` (``step=None``, the
full-horizon problem) or a given constant (the MPC's control period).

The terminal cost is a CasADi Function ``(x_n, tau_remaining, theta) -> scalar``; by default the task's ``l_f``.

Speed: the NLP is built as an MX graph that *calls* the per-interval integrator (one small SX function), so its
derivatives are per-stage functions too. By default (``codegen=False``) CasADi expands it to SX and interprets it.
With ``codegen=True`` the solver's functions (``nlp_f``, ``nlp_g``, their derivatives, ``nlp_hess_l``) are
generated as C once, compiled with the system C compiler into ``$SEAGUL_CACHE_DIR`` (default
``~/.cache/seagul/casadi``) under the task's fingerprint and a hash of the generated source
(``<task>_<solver>_n<n>_<task fingerprint>_<source hash>.so``), and loaded from there: a new process with the same
problem only regenerates the source (~0.1 s) and loads the library. Without a compiler it falls back to the
interpreted solver with a warning. Measured gains are in docs/experiments/trajopt.md. Compiled CasADi code has one
home, :mod:`seagul_control.codegen` (the MPC's JIT options use the same cache directory and compiler lookup); this
module re-exports its names.

Options: everything that configures the build (free or fixed steps, bounds, solver, code generation, wall time) is
one :class:`~seagul_control.transcription_options.TranscriptionOptions`, ``Transcription(task, n, options)``; the
old keyword arguments (``Transcription(task, n, solver="fatrop")``) still work and warn. The condensed solver's
part of the class lives in :mod:`seagul_control.transcription_condensed`.

Wall time: ``max_solve_time`` bounds one solve. IPOPT stops itself (``ipopt.max_wall_time``); fatrop cannot (its
inertia-correction loop is unbounded), so its solves then run in a killable forked child
(:mod:`seagul_control._watchdog`) and an overrun returns a failed solution with status ``"timeout: ..."``.

Stage access: after the build, bounds and the stored initial guess are read and written per stage in the style of
acados' ``solver.set(stage, field, value)``: :meth:`Transcription.set`, :meth:`Transcription.get` and
:meth:`Transcription.set_guess` (fields in :data:`STAGE_FIELDS`; these methods live in
:mod:`seagul_control.transcription_stages`); the positions of each stage's variables and defects in the NLP vectors
are the read-only arrays ``state_index``, ``control_index``, ``step_index``, ``time_index``, ``defect_rows`` and
``initial_rows``.
"""

from __future__ import annotations

import subprocess  # noqa: F401  (kept as an attribute: callers patch seagul_control.transcription.subprocess.run)
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from seagul_control._interrupt import interrupts_kept
from seagul_control._options import merge_deprecated
from seagul_control._watchdog import ForkedSolver, SolverDied, SolveTimeout
from seagul_control.codegen import (
    CODEGEN_FLAGS,
    codegen_cache_dir,
    compile_nlp_library,
    find_c_compiler,
    jit_solver_options,
)
from seagul_control.transcription_condensed import CondensedSolveMixin
from seagul_control.transcription_options import (
    TimeMode,
    TranscriptionOptions,
    default_fatrop_options,
    default_ipopt_options,
)
from seagul_control.transcription_stages import STAGE_FIELDS, StageAccessMixin
from seagul_envs.tasks.base import Task

#: IPOPT statuses we accept as a (locally) optimal solution (fatrop reports success through ``stats()["success"]``).
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
    """``d objective / d p`` for ``p = [x_init, tau, theta, model_params]`` (minus CasADi's ``lam_p``)."""
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


class Transcription(StageAccessMixin, CondensedSolveMixin):
    """Direct multiple-shooting transcription, built once and solved many times.

    Args:
        task: the task (dynamics, costs, bounds).
        horizon: number of intervals ``n`` (default: the task's ``num_steps``).
        options: how the NLP is built and solved (:class:`TranscriptionOptions`; default ``TranscriptionOptions()``).
            Its ``soft_bounds_weight``: None (default) imposes the state bounds of knots ``1..n`` (the path bounds
            and, at ``x_n``, the terminal box) as bounds; a weight ``M > 0`` makes them *soft*, the exact L1 penalty
            ``M * sum_k sum_i max(0, x_k,i - hi_k,i, lo_k,i - x_k,i)`` (slack variables after the last stage; IPOPT
            only). Where the bounds can be met and ``M`` exceeds their multipliers the solution is the hard
            problem's; where they cannot, the problem stays feasible and its value says how far off they are (a
            finite, graded label where the hard value is infinite). :meth:`bound_penalties` gives the terms. Its
            ``model_params``: the task's varying physical parameters (``task.parameters``) enter the NLP as
            parameters after ``theta``: the dynamics are ``f(x, u, params)`` and one built solver serves every robot
            in ``Theta`` (:meth:`solve`'s ``model_params``, default the task's own values); their sensitivities
            ``dV/dparams`` are the last entries of ``param_sensitivity``. Its ``solver``: ``"ipopt"``, ``"fatrop"`` or
            ``"shooting"`` (condensed single shooting over the inputs, :mod:`seagul_control.shooting`: fixed steps
            and input bounds only, i.e. no finite state bounds on knots ``1..n`` and no soft bounds; the same NLP with
            the states eliminated), with ``solver_options`` merged over that solver's defaults
            (``"shooting.max_iter"``, ``"shooting.tol"``, ... for ``"shooting"``; CasADi's JIT options there mean
            ``codegen``). ``codegen`` falls back to the interpreted solver with a warning when no compiler works.
        terminal_cost: ``(x, tau_remaining, theta) -> scalar``; default the task's ``l_f(x)``.
        terminal_model: ``(coefficients, model)``: ``(x0, tau_remaining, theta) -> c`` and
            ``(x, tau_remaining, theta, x0, c) -> scalar``, together equal to ``terminal_cost`` to second order in
            ``x`` at ``x = x0`` and cheap to differentiate in ``x`` (e.g. a network's hand-derived Taylor
            coefficients, the ``"taylor"`` forms of :class:`~seagul_learn.ValueNetwork`): ``"shooting"`` takes its
            derivatives at ``x0 = x_n`` from it instead of differentiating ``terminal_cost`` (whose values it
            keeps); ignored by the other solvers. Its ``param_sensitivity`` then has only ``dV/dx_init`` (the other
            entries are NaN).
        n_theta: length of ``theta`` (terminal-cost parameters).
        **deprecated: the old keyword arguments (``free_time=``, ``solver=``, ...: every field of
            :class:`TranscriptionOptions`) still work; each moves into the options with a ``DeprecationWarning``.

    Attributes:
        state_index: ``(n + 1, nx)`` positions of ``x_k`` in the primal vector (and in ``lam_x``).
        control_index: ``(n, nu)`` positions of ``u_k``.
        step_index: ``(n,)`` positions of the free steps ``h_k`` (empty for fixed steps).
        time_index: ``(n + 1,)`` positions of the elapsed-time states ``t_k`` (empty for fixed steps).
        defect_rows: ``(n, nx)`` rows of the defects ``x_{k+1} - F(x_k, u_k, h_k)`` in the constraint vector (and in
            ``lam_g``).
        initial_rows: ``(nx,)`` rows of ``x_0 - x_init``.

    The index arrays are read-only. Bounds and the stored initial guess are changed per stage with :meth:`set`
    (acados style) and read with :meth:`get`; they persist across solves.
    """

    def __init__(
        self,
        task: Task,
        horizon: int | None = None,
        options: TranscriptionOptions | None = None,
        *,
        terminal_cost: ca.Function | None = None,
        terminal_model: tuple[ca.Function, ca.Function] | None = None,
        n_theta: int = 0,
        **deprecated: Any,
    ) -> None:
        options = merge_deprecated("Transcription", TranscriptionOptions, options, deprecated)
        self.options = options
        """The options the transcription was built with."""
        n = task.num_steps if horizon is None else int(horizon)
        if n < 1:
            raise ValueError(f"horizon must be >= 1 interval, got {horizon}")
        free_time, step, final_box = options.free_time, options.step, options.final_box
        time_mode, solver, model_params = options.time_mode, options.solver, options.model_params
        solver_options, max_solve_time = options.solver_options, options.max_solve_time
        codegen, codegen_dir, codegen_flags = options.codegen, options.codegen_dir, options.codegen_flags
        self.task = task
        self.horizon = n
        self.free_time = (not task.fixed_step) if free_time is None else bool(free_time)
        self.step = step
        lo_step, hi_step = task.step_bounds if options.step_bounds is None else options.step_bounds
        self.step_bounds: tuple[float, float] = (lo_step, hi_step)
        self.time_mode: TimeMode = time_mode
        self.final_box = final_box
        self.soft_bounds_weight = options.soft_bounds_weight
        box_lo = np.maximum(task.x_low, task.x_final_low) if final_box else task.x_low
        box_hi = np.minimum(task.x_high, task.x_final_high) if final_box else task.x_high
        # Per knot 1..n: the bounds the soft penalty measures (the path bounds, the terminal box at the end).
        self._knot_lo = np.vstack([np.tile(task.x_low, (n - 1, 1)), box_lo[None]])
        self._knot_hi = np.vstack([np.tile(task.x_high, (n - 1, 1)), box_hi[None]])
        self.n_theta = int(n_theta)
        if model_params and task.parameters is None:
            raise ValueError(
                f"{task.name}: model_params=True needs a task that declares which parameters vary (Task.parameters)"
            )
        self.model_params = bool(model_params)
        self.n_model_params = task.parameters.size if (model_params and task.parameters is not None) else 0
        self.substeps = task.rk4_substeps if options.substeps is None else int(options.substeps)
        self.solver_name = solver
        nx, nu = task.nx, task.nu

        if terminal_cost is None:
            xs, ts, th = ca.SX.sym("x", nx), ca.SX.sym("t"), ca.SX.sym("theta", self.n_theta)
            terminal_cost = ca.Function("task_terminal", [xs, ts, th], [task.terminal_cost(xs)])
        self.terminal_cost = terminal_cost

        # MX graph calling the per-interval integrator: with codegen its derivatives stay per-stage functions
        # (compact C); without, ``expand`` turns it into the same flat SX graph as a direct SX build.
        x_init = ca.MX.sym("x_init", nx)
        tau = ca.MX.sym("tau")
        theta = ca.MX.sym("theta", self.n_theta)
        phys = ca.MX.sym("model_params", self.n_model_params)
        p = ca.vertcat(x_init, tau, theta, phys)
        step_fn = task.rk4_step_params(self.substeps) if self.model_params else task.rk4_step(self.substeps)
        extra = [phys] if self.model_params else []

        def F(x: ca.MX, u: ca.MX, h: ca.MX | float) -> ca.MX:
            return step_fn(x, u, h, *extra)

        w: list[ca.MX] = []
        lbw: list[np.ndarray] = []
        ubw: list[np.ndarray] = []
        g: list[ca.MX] = []
        lbg: list[np.ndarray] = []
        ubg: list[np.ndarray] = []
        equality: list[bool] = []
        # Index bookkeeping to read the solution back.
        self._x_idx: list[np.ndarray] = []
        self._u_idx: list[np.ndarray] = []
        self._h_idx: list[int] = []
        self._t_idx: list[int] = []
        self._defect_rows: list[np.ndarray] = []
        n_w = 0
        n_g = 0

        def add_var(sym: ca.MX, lo: np.ndarray | float, hi: np.ndarray | float) -> np.ndarray:
            nonlocal n_w
            w.append(sym)
            lbw.append(np.broadcast_to(lo, (sym.numel(),)).astype(float))
            ubw.append(np.broadcast_to(hi, (sym.numel(),)).astype(float))
            n_w += sym.numel()
            return np.arange(n_w - sym.numel(), n_w)

        def add_con(expr: ca.MX, lo: np.ndarray | float, hi: np.ndarray | float) -> np.ndarray:
            nonlocal n_g
            g.append(expr)
            lo_arr = np.broadcast_to(lo, (expr.numel(),)).astype(float)
            hi_arr = np.broadcast_to(hi, (expr.numel(),)).astype(float)
            lbg.append(lo_arr)
            ubg.append(hi_arr)
            equality.extend(bool(v) for v in (lo_arr == hi_arr))
            n_g += expr.numel()
            return np.arange(n_g - expr.numel(), n_g)

        objective: ca.MX = ca.MX(0)
        self._slack_idx: list[np.ndarray] = []
        self._soft_cols: list[np.ndarray] = []
        soft_states: list[ca.MX] = []
        fixed_h = (tau / n) if self.step is None else self.step
        x_k = ca.MX.sym("x_0", nx)
        self._x_idx.append(add_var(x_k, -np.inf, np.inf))
        if self.free_time:
            # Elapsed time as a state (see the module docstring); t_0 = 0 is a stage-0 constraint, not a fixed bound.
            t_k = ca.MX.sym("t_0")
            self._t_idx.append(int(add_var(t_k, -np.inf, np.inf)[0]))
            add_con(ca.vertcat(x_k - x_init, t_k), 0.0, 0.0)
        else:
            add_con(x_k - x_init, 0.0, 0.0)
        h_k: ca.MX | float  # a decision variable with free time, else the fixed step
        for k in range(n):
            u_k = ca.MX.sym(f"u_{k}", nu)
            self._u_idx.append(add_var(u_k, task.u_low, task.u_high))
            if self.free_time:
                h_k = ca.MX.sym(f"h_{k}")
                self._h_idx.append(int(add_var(h_k, self.step_bounds[0], self.step_bounds[1])[0]))
            else:
                h_k = fixed_h
            objective = objective + h_k * task.stage_cost(x_k, u_k)
            x_next = ca.MX.sym(f"x_{k + 1}", nx)
            if self.soft_bounds_weight is None:
                self._x_idx.append(add_var(x_next, self._knot_lo[k], self._knot_hi[k]))
            else:
                self._x_idx.append(add_var(x_next, -np.inf, np.inf))
                soft_states.append(x_next)
            # fatrop's structure detection requires gap-closing rows written as x_{k+1} - F(x_k, u_k).
            if self.free_time:
                t_next = ca.MX.sym(f"t_{k + 1}")
                self._t_idx.append(int(add_var(t_next, -np.inf, np.inf)[0]))
                rows = add_con(ca.vertcat(x_next - F(x_k, u_k, h_k), t_next - (t_k + h_k)), 0.0, 0.0)
                self._defect_rows.append(rows[:nx])
                t_k = t_next
            else:
                self._defect_rows.append(add_con(x_next - F(x_k, u_k, h_k), 0.0, 0.0))
            x_k = x_next
        if self.free_time:
            elapsed: ca.MX | float = t_k
            if time_mode == "equal":
                self._time_row = int(add_con(t_k - tau, 0.0, 0.0)[0])
            elif time_mode == "at_most":
                self._time_row = int(add_con(t_k - tau, -np.inf, 0.0)[0])
            else:
                self._time_row = -1
        else:
            elapsed = n * fixed_h
            self._time_row = -1
        objective = objective + terminal_cost(x_k, tau - elapsed, theta)
        weight = float(self.soft_bounds_weight or 0.0)  # soft_states is empty unless a weight is set
        for k, x_soft in enumerate(soft_states):
            # Exact L1 penalty: x_k - s <= hi, x_k + s >= lo, s >= 0 (one slack per bounded component of knot k+1).
            lo_k, hi_k = self._knot_lo[k], self._knot_hi[k]
            cols = np.flatnonzero(np.isfinite(lo_k) | np.isfinite(hi_k))
            self._soft_cols.append(cols)
            if not cols.size:
                self._slack_idx.append(np.zeros(0, dtype=np.int64))
                continue
            slack = ca.MX.sym(f"slack_{k + 1}", cols.size)
            self._slack_idx.append(add_var(slack, 0.0, np.inf))
            x_c = x_soft[cols.tolist()]
            add_con(x_c - slack, -np.inf, hi_k[cols])
            add_con(x_c + slack, lo_k[cols], np.inf)
            objective = objective + weight * ca.sum1(slack)

        self._w = ca.vertcat(*w)
        self._lbw, self._ubw = np.concatenate(lbw), np.concatenate(ubw)
        self._lbg, self._ubg = np.concatenate(lbg), np.concatenate(ubg)
        self._np = int(p.numel())
        self._equality = equality
        self.state_index = _read_only(np.stack(self._x_idx))
        self.control_index = _read_only(np.stack(self._u_idx))
        self.step_index = _read_only(np.asarray(self._h_idx, dtype=np.int64))
        self.time_index = _read_only(np.asarray(self._t_idx, dtype=np.int64))
        self.defect_rows = _read_only(np.stack(self._defect_rows))
        self.initial_rows = _read_only(np.arange(nx, dtype=np.int64))
        # Initial guess used by solve() when none is passed (None: the straight line of line_guess).
        self._guess: np.ndarray | None = None
        self.max_solve_time = None if max_solve_time is None else float(max_solve_time)
        self._guard: ForkedSolver | None = None
        # Stage costs and elapsed time of a solution, for per-knot labels.
        self._stage_cost_fn = task.stage_cost.map(n)
        self.codegen_library: Path | None = None
        self._shooting: Any = None
        if solver == "shooting":
            self._build_shooting(
                p, step_fn, terminal_cost, terminal_model, solver_options, codegen, codegen_dir, codegen_flags
            )
            return
        nlp = {"x": self._w, "p": p, "f": objective, "g": ca.vertcat(*g)}
        if solver == "ipopt":
            nlp_options = {**default_ipopt_options(), "expand": True, **(solver_options or {})}
            if max_solve_time is not None:  # IPOPT stops itself (the user's own limit, if any, wins)
                nlp_options.setdefault("ipopt.max_wall_time", float(max_solve_time))
        else:
            nlp_options = {**default_fatrop_options(), "expand": True, "equality": equality, **(solver_options or {})}
        name = f"{task.name}_{solver}_n{n}" + ("_theta" if self.model_params else "")
        compiled: ca.Function | None = None
        if codegen:
            try:
                # Unexpanded: the generated C then holds one function per stage-level derivative, not n copies.
                plain = ca.nlpsol(name, solver, nlp, {**nlp_options, "expand": False})
                self.codegen_library = compile_nlp_library(plain, name, codegen_dir, task.fingerprint(), codegen_flags)
                lib_options = {k: v for k, v in nlp_options.items() if k != "expand"}
                compiled = ca.nlpsol(name, solver, str(self.codegen_library), lib_options)
            except (RuntimeError, OSError) as exc:
                warnings.warn(f"{name}: code generation unavailable ({exc}); solving interpreted", stacklevel=2)
                self.codegen_library = None
                compiled = None
        self._solver: Any = ca.nlpsol(name, solver, nlp, nlp_options) if compiled is None else compiled
        # fatrop cannot stop itself inside one iteration (seagul_control._watchdog): it runs in a killable child.
        if self.max_solve_time is not None and solver == "fatrop" and ForkedSolver.supported:
            self._guard = ForkedSolver(self._solver, self.max_solve_time)

    def _violations(self, states: np.ndarray) -> np.ndarray:
        """``(n, nx)`` bound violations ``max(0, x - hi, lo - x)`` of knots ``1..n``."""
        x = np.asarray(states, dtype=float).reshape(self.horizon + 1, self.task.nx)[1:]
        return np.maximum(0.0, np.maximum(x - self._knot_hi, self._knot_lo - x))

    def bound_penalties(self, states: np.ndarray) -> np.ndarray:
        """``(n + 1,)`` soft-bound penalty of each knot's state (``M`` times its violation; knot 0, the start, and
        every knot of a hard transcription: 0). A knot's label adds the penalties of the knots after it."""
        out = np.zeros(self.horizon + 1)
        if self.soft_bounds_weight is not None:
            out[1:] = self.soft_bounds_weight * self._violations(states).sum(axis=1)
        return out

    # ----------------------------------------------------------------- sizes
    @property
    def num_variables(self) -> int:
        """Length of the primal vector."""
        return int(self._w.numel())

    @property
    def num_parameters(self) -> int:
        """Length of ``p = [x_init, tau, theta, model_params]``."""
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
            w0[self._t_idx] = np.concatenate([[0.0], np.cumsum(h)])
        if self.soft_bounds_weight is not None:  # slacks at the guess's violations (a feasible start)
            over = self._violations(states)
            for k, (idx, cols) in enumerate(zip(self._slack_idx, self._soft_cols, strict=True)):
                w0[idx] = over[k, cols]
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
        model_params: np.ndarray | None = None,
        starts: int | None = None,
    ) -> TranscriptionSolution:
        """Solve from ``x_init`` with time to go ``tau`` (inputs assumed validated by the caller).

        The initial guess is ``guess``, else the stored one (:meth:`set`, :meth:`set_guess`), else
        :meth:`line_guess`; the bounds are the current ones (:meth:`set`). ``model_params``: the robot's
        parameters (built with ``model_params=True``; default the task's own, ``task.theta``). ``starts``: extra
        starts of the condensed solver for this solve (:class:`~seagul_control.shooting.ShootingSolver`; default its
        ``shooting.starts`` option); the other solvers take none.
        """
        if starts and self._shooting is None:
            raise ValueError(f"starts={starts!r}: extra starts need the condensed solver, not {self.solver_name!r}")
        theta_arr = np.zeros(self.n_theta) if theta is None else np.asarray(theta, dtype=float).ravel()
        if theta_arr.size != self.n_theta:
            raise ValueError(f"theta must have {self.n_theta} entries, got {theta_arr.size}")
        if model_params is not None and not self.model_params:
            raise ValueError("model_params given to a transcription built without model_params=True")
        phys = (
            np.zeros(0)
            if not self.model_params
            else (self.task.theta if model_params is None else np.asarray(model_params, dtype=float).ravel())
        )
        if phys.size != self.n_model_params:
            raise ValueError(f"model_params must have {self.n_model_params} entries, got {phys.size}")
        p = np.concatenate([np.asarray(x_init, dtype=float).ravel(), [float(tau)], theta_arr, phys])
        if guess is not None:
            w0 = np.asarray(guess, dtype=float)
        elif self._guess is not None:
            w0 = self._guess.copy()
        else:
            w0 = self.line_guess(x_init, tau)
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
        if self._shooting is not None:
            with interrupts_kept():
                return self._solve_shooting(w0, p, float(tau), starts)
        call: Any = self._solver if self._guard is None else self._guard
        start = time.perf_counter()
        try:
            with interrupts_kept():  # CasADi turns Ctrl-C into a failed solve; this re-raises it after the solve
                out = call(**args)
        except SolveTimeout as exc:
            return self._failed(w0, f"timeout: {exc}", time.perf_counter() - start)
        except SolverDied as exc:  # a crash (or kill) of the guarded solve's child: this solve failed
            return self._failed(w0, f"solver died: {exc}", time.perf_counter() - start)
        elapsed = time.perf_counter() - start
        stats = call.stats()
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
        if self.solver_name == "fatrop":
            # fatrop returns a bare integer code; name it so results read alike across solvers.
            status = "Success" if success else f"fatrop_{stats.get('unified_return_status', 'error')}_{status}"
        return TranscriptionSolution(
            success=success and bool(np.all(np.isfinite(w))),
            status=status,
            objective=float(np.asarray(out["f"]).ravel()[0]),
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

    @property
    def condensed(self) -> bool:
        """True when the condensed solver (``solver="shooting"``) solves this transcription (it takes ``starts``)."""
        return self._shooting is not None

    def _failed(self, w0: np.ndarray, status: str, elapsed: float) -> TranscriptionSolution:
        """A solve that produced nothing (e.g. stopped by ``max_solve_time``): NaN solution, the guess as primal."""
        nan = np.full(self.horizon, np.nan)
        return TranscriptionSolution(
            success=False,
            status=status,
            objective=float("nan"),
            states=np.full((self.horizon + 1, self.task.nx), np.nan),
            controls=np.full((self.horizon, self.task.nu), np.nan),
            steps=nan,
            param_sensitivity=np.full(self._np, np.nan),
            defect_multipliers=np.full((self.horizon, self.task.nx), np.nan),
            iterations=-1,
            solve_time=elapsed,
            primal=np.asarray(w0, dtype=float).copy(),
            lam_g=np.full(self._lbg.size, np.nan),
            lam_x=np.full(self._lbw.size, np.nan),
        )

    def stage_costs(self, states: np.ndarray, controls: np.ndarray, steps: np.ndarray) -> np.ndarray:
        """``h_k * l(x_k, u_k)`` for ``k = 0..n-1``."""
        rates = np.asarray(self._stage_cost_fn(states[:-1].T, controls.T)).ravel()
        return rates * np.asarray(steps)


def _read_only(arr: np.ndarray) -> np.ndarray:
    arr.setflags(write=False)
    return arr


#: Everything this module exported before code generation and the options moved into their own modules.
__all__ = [
    "CODEGEN_FLAGS",
    "STAGE_FIELDS",
    "SUCCESS_STATUSES",
    "TimeMode",
    "Transcription",
    "TranscriptionOptions",
    "TranscriptionSolution",
    "codegen_cache_dir",
    "compile_nlp_library",
    "default_fatrop_options",
    "default_ipopt_options",
    "find_c_compiler",
    "jit_solver_options",
]
