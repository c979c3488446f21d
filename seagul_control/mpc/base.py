"""The receding-horizon machinery both MPCs share: one problem solved per step, warm starts, fallbacks, step info.

:class:`_MPCBase` implements stable-baselines3's predictor protocol on the seagul envs' observations, keeps one
warm start per env index (the previous plan shifted by one step, dropped on ``episode_start``), falls back on a
failed solve to the previous plan shifted by one step, then to the LQR reference, then to a zero (clipped) input,
and records each step as an :class:`MPCStepInfo`. A subclass chooses the problem to solve for a time to go
(``_select``); :meth:`_MPCBase._build` builds it as a :class:`~seagul_control.transcription.Transcription` with the
configured solver, JIT-compiled when a C compiler exists. The mechanisms are described in :mod:`seagul_control.mpc`.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
import time
import warnings
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from seagul_control.codegen import codegen_cache_dir, jit_solver_options
from seagul_control.lqr import LQRPolicy, episode_start_mask, output_actions, split_observation
from seagul_control.mpc.options import FullHorizonOptions, MPCOptions, Multistart, SolverName
from seagul_control.transcription import Transcription, TranscriptionSolution
from seagul_control.transcription_options import TranscriptionOptions
from seagul_envs.tasks.base import Task

_TIME_EPS = 1e-4


# ------------------------------------------------------------------------------------------------ step info
@dataclass
class MPCStepInfo:
    """What happened in one control step of one env."""

    source: str
    """Where the action came from: ``"solver"``, ``"shifted"`` (previous plan), ``"lqr"`` or ``"zero"``."""
    status: str
    """The solver's return status (or ``"exception: ..."``)."""
    success: bool
    """True iff the solve converged."""
    iterations: int
    """Solver iterations."""
    solve_time: float
    """Wall time of the solver call (s)."""
    step_time: float
    """Wall time of the whole step for this env, including warm start and fallback (s)."""
    phase: str
    """Which problem was solved: ``"lookahead"``, ``"final"`` or ``"full"``."""
    objective: float
    """Optimal objective (NaN on failure)."""
    terminal_state: tuple[float, ...] | None = None
    """The planned terminal state ``x_n`` of a converged solve whose terminal cost was the learned value (the
    planner's *query* of ``Vhat``), else None."""
    terminal_tau: float = float("nan")
    """Time to go at ``x_n`` (``tau_now - sum(h)``) when :attr:`terminal_state` is set."""
    terminal_theta: tuple[float, ...] | None = None
    """The robot the plan (and its value query) was made for, when :attr:`terminal_state` is set and the MPC plans
    over robots (``model_params``), else None."""
    extra_starts: int = 0
    """Extra starts the condensed solver descended from in this step (``multistart``; 0: the warm start alone)."""

    def as_dict(self) -> dict[str, Any]:
        """Plain dict (for JSON)."""
        return asdict(self)


# ----------------------------------------------------------------------------------------------- JIT cache
# The JIT options, the compiler lookup and the cache directory live with the code generation
# (seagul_control.codegen): one cache for every compiled CasADi artefact. Re-exported by seagul_control.mpc.
default_cache_dir = codegen_cache_dir


_JIT_DIR: str | None = None


def _jit_directory() -> str:
    """A private per-process directory for CasADi's JIT files (CasADi deletes them itself when unloading)."""
    global _JIT_DIR
    if _JIT_DIR is None or not os.path.isdir(_JIT_DIR):
        _JIT_DIR = tempfile.mkdtemp(prefix="seagul_jit_")
    return _JIT_DIR


# -------------------------------------------------------------------------------------------- the problems
class _Problem:
    """One transcription solved repeatedly, optionally with its first step pinned to the control period."""

    def __init__(
        self, trans: Transcription, phase: str, pin_first_step: bool, shrink_steps: bool = False, min_step: float = 0.0
    ) -> None:
        self.trans = trans
        self.phase = phase
        self.pin_first_step = pin_first_step and trans.free_time
        self.shrink_steps = shrink_steps
        self.min_step = min_step

    def solve(
        self,
        x: np.ndarray,
        tau: float,
        theta: np.ndarray,
        dt: float,
        guess: np.ndarray,
        lam_g: np.ndarray | None = None,
        lam_x: np.ndarray | None = None,
        model_params: np.ndarray | None = None,
        starts: int = 0,
    ) -> TranscriptionSolution:
        trans = self.trans
        if self.pin_first_step:
            # The first step must equal the env's hold time.
            h0 = min(dt, max(tau, 0.0))
            trans.set(0, "lbh", h0)
            trans.set(0, "ubh", h0)
            if self.shrink_steps:
                # Steps shrink with the time left (a zero lower bound makes degenerate zero-length steps).
                hi = trans.step_bounds[1]
                rest = max(tau - h0, 0.0) / max(trans.horizon - 1, 1)
                lo_k, hi_k = min(self.min_step, 0.5 * rest), max(hi, rest)
                for k in range(1, trans.horizon):
                    trans.set(k, "lbh", lo_k)
                    trans.set(k, "ubh", hi_k)
        phys = model_params if trans.model_params else None
        extra = {"starts": starts} if starts else {}
        return trans.solve(x, tau, theta, guess=guess, lam_g=lam_g, lam_x=lam_x, model_params=phys, **extra)

    def cold_guess(self, x: np.ndarray, tau: float, dt: float, kind: str) -> np.ndarray:
        """A first guess: a zero-input rollout (``"rollout"``, also the first guess of ``"best"``) or the
        transcription's straight line (``"line"``)."""
        trans = self.trans
        n = trans.horizon
        if trans.free_time:
            lo, hi = trans.step_bounds
            rest = (tau - dt) / max(n - 1, 1) if self.phase != "lookahead" else float(np.mean(trans.step_bounds))
            steps = np.full(n, float(np.clip(rest, lo, hi)))
            if self.pin_first_step:
                steps[0] = min(dt, max(tau, 0.0))
        else:
            steps = np.full(n, trans.step if trans.step is not None else tau / n)
        if kind == "line":
            return trans.line_guess(x, tau) if not trans.free_time else self._line_with_steps(x, steps)
        step = trans.task.rk4_step(trans.substeps)
        states = np.zeros((n + 1, trans.task.nx))
        states[0] = x
        u = np.zeros(trans.task.nu)
        for k in range(n):
            nxt = np.asarray(step(states[k], u, steps[k])).ravel()
            states[k + 1] = nxt if np.all(np.isfinite(nxt)) else states[k]
        return trans.pack_guess(states, np.zeros((n, trans.task.nu)), steps if trans.free_time else None)

    def cold_alternatives(self, x: np.ndarray, tau: float, dt: float, kind: str) -> list[np.ndarray]:
        """The further first guesses a cold start of kind ``kind`` also descends from: the straight line after the
        rollout for ``"best"`` on a lifted fixed-step problem, else none (the condensed solver reads only the
        guess's inputs, zero in both, and has its own extra starts; free-time problems keep their one guess)."""
        if kind != "best" or self.trans.condensed or self.trans.free_time:
            return []
        return [self.cold_guess(x, tau, dt, "line")]

    def _line_with_steps(self, x: np.ndarray, steps: np.ndarray) -> np.ndarray:
        s = np.linspace(0.0, 1.0, self.trans.horizon + 1)[:, None]
        states = (1 - s) * x + s * self.trans.task.goal
        return self.trans.pack_guess(states, np.zeros((self.trans.horizon, self.trans.task.nu)), steps)


@dataclass
class _Plan:
    """The last successful solution of one env, for warm starts and the shifted-plan fallback."""

    problem: _Problem
    states: np.ndarray
    controls: np.ndarray
    steps: np.ndarray
    lam_x: np.ndarray
    lam_g: np.ndarray
    objective: float = float("nan")
    """The plan's optimal objective (``multistart="rise"`` compares the next step's with it)."""
    age: int = 0
    """Control steps taken since the solve."""


def _shifted(arr: np.ndarray, age: int, length: int) -> np.ndarray:
    """``arr[age:]`` with its last row repeated (or cut) to ``length`` rows."""
    tail = arr[min(age, arr.shape[0] - 1) :]
    pad = max(0, length - tail.shape[0])
    return np.concatenate([tail, np.repeat(tail[-1:], pad, axis=0)])[:length].copy()


def _shift_guess(
    plan: _Plan, target: _Problem, x: np.ndarray, dt: float, tau: float
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """The plan advanced by ``plan.age`` steps (tail repeated), resized to ``target``'s horizon, ``x_0 = x``.

    Returns ``(primal, lam_g, lam_x)``; the multipliers are shifted the same way when the plan came from the same
    problem (same layout), else None.
    """
    trans = target.trans
    n, a = trans.horizon, plan.age
    states = _shifted(plan.states, a, n + 1)
    states[0] = x
    controls = _shifted(plan.controls, a, n)
    steps = _shifted(plan.steps, a, n)
    if trans.free_time:
        steps = np.clip(steps, *trans.step_bounds)
        if target.pin_first_step:
            steps[0] = min(dt, max(tau, 0.0))
    primal = trans.pack_guess(states, controls, steps if trans.free_time else None)
    if plan.problem is not target:
        return primal, None, None
    # Bound multipliers in the primal layout, constraint multipliers stage by stage (the transcription's index maps).
    lx = plan.lam_x
    lx_states = _shifted(lx[trans.state_index], a, n + 1)
    lx_controls = _shifted(lx[trans.control_index], a, n)
    lx_steps = _shifted(lx[trans.step_index], a, n) if trans.free_time else None
    lam_x = trans.pack_guess(lx_states, lx_controls, lx_steps)
    t_idx = trans.time_index
    if trans.free_time and len(t_idx):
        # pack_guess fills the elapsed-time states from the steps; their multipliers shift like the states.
        lam_x[t_idx] = _shifted(lx[t_idx], a, n + 1)
    lam_g = plan.lam_g.copy()
    rows = trans.defect_rows
    defects = _shifted(plan.lam_g[rows], a, n)
    # x_{a} - x_init takes over the multiplier of the defect that fixed x_a.
    init = trans.initial_rows
    lam_g[init] = plan.lam_g[rows[min(a, n) - 1]] if a >= 1 else plan.lam_g[init]
    lam_g[rows] = defects
    return primal, lam_g, lam_x


def _converged(sol: TranscriptionSolution) -> bool:
    return bool(sol.success and np.all(np.isfinite(sol.controls[0])) and np.isfinite(sol.objective))


def _lower(first: TranscriptionSolution, other: TranscriptionSolution) -> TranscriptionSolution:
    """The lower converged of two solves of one problem (``first`` on a tie or when neither converged), with the
    solve times and iterations of both."""
    better = _converged(other) and (not _converged(first) or other.objective < first.objective)
    kept, dropped = (other, first) if better else (first, other)
    kept.solve_time += dropped.solve_time
    kept.iterations += dropped.iterations
    return kept


# --------------------------------------------------------------------------------------------- base class
class _MPCBase:
    """Shared predictor machinery: observation checks, warm starts per env, fallbacks and step statistics."""

    name = "MPC"

    def __init__(self, task: Task, dt: float | None, warm_start: bool, cold_guess: str) -> None:
        self.task = task
        self.dt = float(task.control_period if dt is None else dt)
        if not (np.isfinite(self.dt) and self.dt > 0):
            raise ValueError(f"{self.name}: dt must be a positive number of seconds, got {dt!r}")
        if cold_guess not in ("rollout", "line", "best"):
            raise ValueError(f"{self.name}: cold_guess must be 'rollout', 'line' or 'best', got {cold_guess!r}")
        self.warm_start = bool(warm_start)
        self.cold_guess = cold_guess
        self._plans: dict[int, _Plan] = {}
        self._backup: LQRPolicy | None = None
        self._backup_failed = False
        self.last_info: list[MPCStepInfo] = []
        """Per env of the last ``predict`` call."""
        self.stats: list[MPCStepInfo] = []
        """Every step since construction or :meth:`reset_stats`."""
        self.model_params = False
        """True when the solvers take the robot's physical parameters (``set_robot``)."""
        self._robot: np.ndarray | None = None
        self.multistart: Multistart = "never"
        """When the condensed solver also descends from extra starts (:class:`LimitedLookaheadMPC`)."""
        self.multistart_starts = 0
        """How many extra starts then."""

    # ------------------------------------------------------------------ protocol
    def predict(
        self,
        observation: Any,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        """SB3 predictor protocol; ``state`` is passed through unchanged (details in :attr:`last_info`)."""
        xs, taus, batched = split_observation(observation, self.task.nx, self.name)
        starts = episode_start_mask(episode_start, xs.shape[0])
        actions = np.zeros((xs.shape[0], self.task.nu))
        infos = []
        for i, (x, tau) in enumerate(zip(xs, taus, strict=True)):
            if starts[i]:
                self._forget(i)
            actions[i], info = self.act(x, float(tau), env_index=i)
            infos.append(info)
        self.last_info = infos
        return output_actions(actions, batched), state

    def reset(self) -> None:
        """Forget every warm start (all envs)."""
        self._plans.clear()

    def _forget(self, env_index: int) -> None:
        """A new episode starts in env ``env_index``: forget what belongs to its last one (its warm start)."""
        self._plans.pop(env_index, None)

    def reset_stats(self) -> None:
        """Clear :attr:`stats`."""
        self.stats = []

    def step_times(self) -> np.ndarray:
        """Solver wall times (s) of the recorded steps."""
        return np.array([s.solve_time for s in self.stats])

    # ------------------------------------------------------------------ one step
    def act(self, x: np.ndarray, tau: float, env_index: int = 0) -> tuple[np.ndarray, MPCStepInfo]:
        """Input for state ``x`` at time to go ``tau`` (never raises on a solver failure)."""
        start = time.perf_counter()
        x = self.task.check_state(x, f"{self.name} state")
        tau = max(float(tau), 0.0)
        problem, theta = self._select(tau)
        plan = self._plans.get(env_index) if self.warm_start else None
        lam_g = lam_x = None
        alternatives: list[np.ndarray] = []
        if plan is not None:
            plan.age += 1
            guess, lam_g, lam_x = _shift_guess(plan, problem, x, self.dt, tau)
        else:
            guess = problem.cold_guess(x, tau, self.dt, self.cold_guess)
            alternatives = problem.cold_alternatives(x, tau, self.dt, self.cold_guess)
        mode = self.multistart if problem.trans.condensed else "never"
        # "rise": a fresh plan of the same problem to compare with, else (a cold start, a phase switch, a failed
        # last step) the extra starts at once.
        fresh = plan is not None and plan.age == 1 and plan.problem is problem and np.isfinite(plan.objective)
        extra = self.multistart_starts if mode == "always" or (mode == "rise" and not fresh) else 0
        try:
            sol = problem.solve(x, tau, theta, self.dt, guess, lam_g, lam_x, self._robot, starts=extra)
            for alternative in alternatives:
                # A cold start also descends from the other first guesses; the lowest converged plan is kept (the
                # first guess wins ties, and a guess whose solve raises is skipped).
                with contextlib.suppress(Exception):
                    sol = _lower(sol, problem.solve(x, tau, theta, self.dt, alternative, None, None, self._robot))
            ok = sol.success and bool(np.all(np.isfinite(sol.controls[0])))
            if ok and mode == "rise" and not extra and plan is not None:
                previous = plan.objective
                if sol.objective > previous + 1e-6 * (1.0 + abs(previous)):
                    # The warm-started plan costs more than the last one promised: its basin has worsened, so look
                    # for a lower one (the warm start descends again; the lowest converged plan is kept).
                    extra = self.multistart_starts
                    again = problem.solve(x, tau, theta, self.dt, guess, lam_g, lam_x, self._robot, starts=extra)
                    again_ok = again.success and bool(np.all(np.isfinite(again.controls[0])))
                    if again_ok and again.objective <= sol.objective:
                        again.solve_time += sol.solve_time
                        again.iterations += sol.iterations
                        sol = again
                    else:
                        sol.solve_time += again.solve_time
                        sol.iterations += again.iterations
            status, iters, solve_time, objective = sol.status, sol.iterations, sol.solve_time, sol.objective
        except Exception as exc:  # a solver exception must not stop a closed loop
            sol, ok = None, False
            status, iters, solve_time, objective = f"exception: {exc}", -1, time.perf_counter() - start, np.nan
        terminal_state, terminal_tau, terminal_theta = None, float("nan"), None
        if ok and sol is not None:
            u = sol.controls[0]
            source = "solver"
            if self._queries_value(theta):
                terminal_state = tuple(float(v) for v in sol.states[-1])
                terminal_tau = float(tau - np.sum(sol.steps))
                if self._robot is not None or getattr(self, "model_params", False):
                    robot = self.task.theta if self._robot is None else self._robot
                    terminal_theta = tuple(float(v) for v in robot)
            self._plans[env_index] = _Plan(
                problem, sol.states, sol.controls, sol.steps, sol.lam_x, sol.lam_g, float(sol.objective)
            )
        else:
            objective = float("nan")
            u, source = self._fallback(x, tau, env_index)
        u = np.clip(np.asarray(u, dtype=float).reshape(self.task.nu), self.task.u_low, self.task.u_high)
        info = MPCStepInfo(
            source=source,
            status=str(status),
            success=bool(ok),
            iterations=int(iters),
            solve_time=float(solve_time),
            step_time=time.perf_counter() - start,
            phase=problem.phase,
            objective=float(objective),
            terminal_state=terminal_state,
            terminal_tau=terminal_tau,
            terminal_theta=terminal_theta,
            extra_starts=int(extra),
        )
        self.stats.append(info)
        return u, info

    def _fallback(self, x: np.ndarray, tau: float, env_index: int) -> tuple[np.ndarray, str]:
        plan = self._plans.get(env_index)
        if plan is not None and plan.age < plan.controls.shape[0]:
            return plan.controls[plan.age], "shifted"
        self._plans.pop(env_index, None)
        backup = self._backup_policy()
        if backup is not None:
            return backup.action(x, tau), "lqr"
        return np.clip(np.zeros(self.task.nu), self.task.u_low, self.task.u_high), "zero"

    def _backup_policy(self) -> LQRPolicy | None:
        if self._backup is None and not self._backup_failed:
            try:
                self._backup = LQRPolicy(self.task, dt=self.dt)
            except Exception as exc:
                warnings.warn(f"{self.name}: no LQR fallback ({exc}); using a zero input", stacklevel=2)
                self._backup_failed = True
        return self._backup

    # ------------------------------------------------------------------ subclass hooks
    def _select(self, tau: float) -> tuple[_Problem, np.ndarray]:
        raise NotImplementedError

    def _matrix_form(self) -> bool:
        """True when the value function is an MX (matrix) graph: the lookahead is then compiled unexpanded."""
        fn = getattr(self, "_vf_fn", None)
        return fn is not None and bool(fn.is_a("MXFunction"))

    def _queries_value(self, theta: np.ndarray) -> bool:
        """True when a solve with these parameters used a learned terminal cost (its ``x_n`` is a query)."""
        return False

    # ------------------------------------------------------------------ building
    def _build(
        self,
        phase: str,
        pin: bool,
        shrink: bool = False,
        jit: bool = True,
        solver: SolverName | None = None,
        *,
        horizon: int,
        terminal_cost: ca.Function | None = None,
        terminal_model: tuple[ca.Function, ca.Function] | None = None,
        n_theta: int = 0,
        **options: Any,
    ) -> _Problem:
        """A transcription with the configured solver (or ``solver``), JIT-compiled when possible (falls back to
        interpreted); ``options`` are :class:`~seagul_control.transcription_options.TranscriptionOptions` fields."""
        solver = self.solver if solver is None else solver
        options.setdefault("max_solve_time", self.max_solve_time)
        nlp_options = dict(self._solver_options) if solver == self.solver else self._options_for(solver)
        jit_options = self._jit_options if (self.jit and jit) else None

        def transcription(**extra: Any) -> Transcription:
            trans_options = TranscriptionOptions(
                **{"solver": solver, "solver_options": nlp_options, **options, **extra}
            )
            return Transcription(
                self.task,
                horizon,
                trans_options,
                terminal_cost=terminal_cost,
                terminal_model=terminal_model,
                n_theta=n_theta,
            )

        if jit_options is not None and self._matrix_form():
            # Unexpanded code generation keeps the matrix-form value function (and its Hessian) dense products;
            # Transcription falls back to the interpreted solver with a warning when compiling fails.
            trans = transcription(codegen=True, codegen_dir=self._jit_cache_dir, codegen_flags=self._codegen_flags)
            return _Problem(trans, phase, pin, shrink, self.task.step_bounds[0])
        if jit_options is not None:
            try:
                # CasADi writes the generated C file into the working directory: keep it out of the user's tree.
                # A fresh directory per build: CasADi deletes its files when the solver is unloaded.
                with contextlib.chdir(tempfile.mkdtemp(dir=_jit_directory())):
                    trans = transcription(solver_options={**nlp_options, **jit_options})
                return _Problem(trans, phase, pin, shrink, self.task.step_bounds[0])
            except Exception as exc:
                warnings.warn(f"{self.name}: JIT compilation failed ({exc}); solving interpreted", stacklevel=2)
        return _Problem(transcription(), phase, pin, shrink, self.task.step_bounds[0])

    def _options_for(self, solver: SolverName, only_its_own: bool = True) -> dict[str, Any]:
        """nlpsol options of ``solver``: this controller's limits and the user's options (``only_its_own``: only those
        meant for it, i.e. without a plugin prefix or with ``solver``'s; a second solver, such as the final phase's,
        then never sees the first's options; the main solver gets every user option, so a misspelt one raises)."""
        base = f"{solver}."
        limits = {base + "max_iter": self._max_iter, base + "tol": self._tol}
        user = self._user_solver_options
        if only_its_own:
            user = {k: v for k, v in user.items() if "." not in k or k.startswith(base)}
        return {**limits, **user}

    def default_solver(self, free_time: bool) -> SolverName:
        """fatrop for fixed steps; IPOPT for free time.

        The transcription keeps free-time problems stage-wise (elapsed time is a stage state), so fatrop accepts
        them, but on the glider's full-horizon MPC it took 200 iterations and 3.3 s per step (median) against
        IPOPT's 0.7 s with the same warm starts.
        """
        return "ipopt" if free_time else "fatrop"

    def _configure_solver(self, options: MPCOptions | FullHorizonOptions, free_time: bool) -> None:
        """Read the solver fields of ``options`` (validated there) into this controller's solver settings."""
        solver = self.default_solver(free_time) if options.solver is None else options.solver
        self.max_solve_time = options.max_solve_time
        """Wall-time limit of one solve (s); a solve that hits it fails and the step falls back (None: no limit)."""
        self.solver: SolverName = solver
        self._max_iter, self._tol = options.max_iter, options.tol
        self._user_solver_options = dict(options.solver_options)
        self._solver_options = self._options_for(solver, only_its_own=False)
        cache_dir, jit_flags = options.jit_cache_dir, options.jit_flags
        self._jit_cache_dir = None if cache_dir is None else Path(cache_dir)
        self._jit_options = jit_solver_options(self._jit_cache_dir, ("-O1",) if jit_flags is None else jit_flags)
        self._codegen_flags = ("-O3", "-fPIC", "-shared") if jit_flags is None else (*jit_flags, "-fPIC", "-shared")
        if options.jit and self._jit_options is None:
            warnings.warn(f"{self.name}: no C compiler found; solving without JIT (slower)", stacklevel=4)
        self.jit = options.jit and self._jit_options is not None
