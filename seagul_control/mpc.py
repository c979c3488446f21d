"""Limited-lookahead MPC (paper Eq. 3) with a learned terminal cost, and the full-horizon MPC reference.

Both controllers follow stable-baselines3's predictor protocol, ``predict(observation, state=None,
episode_start=None, deterministic=True) -> (actions, state)``, on the seagul envs' observations ``[x, time_to_go]``
(one ``(nx + 1,)`` or a batch ``(n_envs, nx + 1)``), so SB3's ``evaluate_policy`` runs them on a ``DummyVecEnv``.

**Problem.** The one NLP builder (:class:`~seagul_control.transcription.Transcription`) with ``n`` intervals,
``x_0 = x_now`` and terminal cost ``Vhat(x_n, tau_now - sum(h))``. The value function enters as its CasADi form
``(x, tau, theta) -> V`` with ``theta`` an NLP *parameter*: swapping in a newly trained network of the same
architecture (:meth:`LimitedLookaheadMPC.set_value_function`) never rebuilds a solver.

**End of the episode.** ``theta`` carries a switch ``s``: the terminal cost is ``s * Vhat_guarded + (1 - s) * l_f``.

* Fixed-step tasks (acrobot, ``h = dt``): ``s = 0`` once ``tau_now - n dt <= 0`` (the task's ``l_f``, the DARE
  quadratic, is then the right tail cost; the lookahead may pass the episode end by < n steps, harmlessly).
* Free-time tasks (glider): while ``tau_now > n * dt`` the lookahead problem has ``h_k`` in the task's step bounds
  and ``sum(h) <= tau_now``; after that a **final-phase problem built once** takes over: ``n`` steps with
  ``sum(h) = tau_now`` exactly, ``h_k in [0, h_max]``, the task's terminal box and ``l_f`` (a shrinking horizon in
  time with a constant number of knots, so one solver serves every remaining time).
* In both, the first step is pinned to the control period (``min(dt, tau_now)``) so that ``u_0`` is held exactly
  as long as the env holds it.

**Trust region (the learned terminal cost is only trustworthy where it was trained).** Three guards, chosen by
``trust_region``; ``clamp=True`` (default) also replaces ``Vhat`` by the smooth ``max(Vhat, 0)`` (a cost-to-go is
never negative) in each of them.

The default is the task's ``profile.mpc_trust_region``: ``"none"`` for the acrobot and the glider, whose shipped
networks are selected and measured unguarded (docs/experiments/closed-loop.md: 99.25 % of the acrobot grid, 91.7 % of
the glider's), ``"lqr"`` for a new task.

* ``"lqr"``: ``Vhat + l_f``, i.e. the task's quadratic terminal cost (acrobot: the DARE matrix) as a
  prior under the network. It biases the cost upward but gives the terminal cost the right curvature at the goal,
  where a network fitted to values of 2-130 over wide swings is flattest and least accurate; measured on the
  acrobot grid it was the only guard with which the learned MPC balanced (``docs/experiments/mpc.md``).
* ``"box"``: ``Vhat + w * sum_i ((x_n,i - clip(x_n,i, lo_i, hi_i)) / (hi_i - lo_i))^2``: zero inside the training
  box, a quadratic wall outside, so the optimizer cannot exploit the network where it never saw data. The box comes
  from the value function (``training_box()`` if it has one, else ``in_mean +- 2 in_std`` of its input
  standardisation, i.e. of its training inputs) or is given; it is part of ``theta``, so a new network brings its
  own box without a rebuild.
* ``"none"``: ``Vhat`` alone (the paper's Eq. 3 as written).

For a zero-cost equilibrium goal (the acrobot) ``anchor_goal`` (default on there) first replaces ``Vhat`` by
``Vhat - Vhat(x*, tau) - dVhat/dx(x*, tau) (x - x*)``: the true value and its gradient vanish at the goal, and a
network's small first-order error there otherwise shifts the closed loop's resting point off the goal.
``goal_blend = c > 0`` then hands the goal's neighbourhood to the task's quadratic: the learned cost becomes
``b l_f + (1 - b) Vhat`` with ``b = exp(-l_f / c)``. Near an equilibrium goal ``l_f`` (the DARE quadratic of the
transcription's own linearisation) *is* the value to second order (measured on the acrobot: ``V = l_f`` while
``l_f <~ 1``), while a network fitted to values up to tens errs there by more than ``V`` itself, so the closed loop
would settle next to the goal instead of on it (docs/experiments/closed-loop.md). Away from the goal (``l_f >> c``) the
network is untouched. The blend is applied to the guarded learned cost, before the end-of-episode switch.

**Speed.** The default solver is the condensed one (``"shooting"``, :mod:`seagul_control.shooting`) for a short
fixed-step lookahead with input bounds only (the acrobot), else CasADi's ``fatrop`` (the transcription orders
variables and constraints stage by stage); with ``jit=True`` (default) the NLP functions are compiled to C once
and the object file is cached on disk
(``$SEAGUL_CACHE_DIR`` or ``~/.cache/seagul/casadi``, keyed by a hash of the generated source and flags), so a new
process pays only code generation and linking. Without a C compiler the same solver runs interpreted (slower).
A value function that offers a *matrix* form (``casadi_function(form="matrix")``: an MX graph of dense
matrix-vector products, as ``ValueNetwork`` and ``ValueEnsemble`` do) is compiled differently: the lookahead NLP is
generated unexpanded (:class:`~seagul_control.transcription.Transcription` ``codegen=True``), so the network and its
exact Hessian stay a few dozen dense products (46 kB of C for a 3 x (2 x 64) ensemble, ~10 s to build) instead of
an expanded scalar graph (30 MB of C for that ensemble, which gcc -O1 did not finish in 21 CPU-minutes). Measured
on the acrobot, 5 steps, 500 closed-loop steps, one other core busy: 2 x 64 network 2.5 ms median / 4.0 ms p95
per step (the scalar JIT: 6.3 ms at load ~1, minutes to compile), 3-member ensemble 5.5 / 10.0 ms (interpreted:
16 / 28 ms); ``-O3`` is the default for this form (-O1: 11 ms for the ensemble).

**Robustness.** ``predict`` never raises on a failed solve: it falls back to the previous plan shifted by one
step, then to the LQR reference (:class:`~seagul_control.lqr.LQRPolicy`), then to a zero (clipped) input, and
records status, iterations, solve time and the source of each action in :attr:`last_info` / :attr:`stats`.
Warm starts are kept per env index (the previous solution shifted by one step) and dropped on ``episode_start``.
A cold start (no plan) of a lifted fixed-step problem descends from both the zero-input rollout and the straight
line to the goal and keeps the lower converged plan (``cold_guess="best"``, the default with fixed steps): over a
long horizon the rollout of an unstable system falls far from the goal and leads the solver to a poor local
minimum.
NaN observations, wrong shapes and a horizon < 1 raise ValueErrors naming the problem.
"""

from __future__ import annotations

import contextlib
import copy
import inspect
import os
import tempfile
import time
import warnings
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Literal

import casadi as ca
import numpy as np

from seagul_control.estimation import ParameterEstimator
from seagul_control.lqr import LQRPolicy, episode_start_mask, output_actions, split_observation
from seagul_control.transcription import (
    Transcription,
    TranscriptionSolution,
    codegen_cache_dir,
    find_c_compiler,
    jit_solver_options,
)
from seagul_control.value_function import CasadiValueFunction
from seagul_envs.tasks.base import Task

TrustRegion = Literal["box", "lqr", "none"]
SolverName = Literal["fatrop", "ipopt", "shooting"]
Multistart = Literal["never", "rise", "always"]

#: Tolerance (s) below which a remaining time counts as zero (observations are float32).
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
# The JIT options, the compiler lookup and the cache directory live with the transcription's code generation
# (seagul_control.transcription): one cache for every compiled CasADi artefact. Re-exported here.
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
        **kwargs: Any,
    ) -> _Problem:
        """A transcription with the configured solver (or ``solver``), JIT-compiled when possible (falls back to
        interpreted)."""
        solver = self.solver if solver is None else solver
        kwargs.setdefault("max_solve_time", self.max_solve_time)
        options = dict(self._solver_options) if solver == self.solver else self._options_for(solver)
        jit_options = self._jit_options if (self.jit and jit) else None
        if jit_options is not None and self._matrix_form():
            # Unexpanded code generation keeps the matrix-form value function (and its Hessian) dense products;
            # Transcription falls back to the interpreted solver with a warning when compiling fails.
            trans = Transcription(
                self.task,
                solver=solver,
                solver_options=options,
                codegen=True,
                codegen_dir=self._jit_cache_dir,
                codegen_flags=self._codegen_flags,
                **kwargs,
            )
            return _Problem(trans, phase, pin, shrink, self.task.step_bounds[0])
        if jit_options is not None:
            try:
                # CasADi writes the generated C file into the working directory: keep it out of the user's tree.
                # A fresh directory per build: CasADi deletes its files when the solver is unloaded.
                with contextlib.chdir(tempfile.mkdtemp(dir=_jit_directory())):
                    trans = Transcription(self.task, solver=solver, solver_options={**options, **jit_options}, **kwargs)
                return _Problem(trans, phase, pin, shrink, self.task.step_bounds[0])
            except Exception as exc:
                warnings.warn(f"{self.name}: JIT compilation failed ({exc}); solving interpreted", stacklevel=2)
        trans = Transcription(self.task, solver=solver, solver_options=options, **kwargs)
        return _Problem(trans, phase, pin, shrink, self.task.step_bounds[0])

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

    def _configure_solver(
        self,
        solver: SolverName | None,
        free_time: bool,
        jit: bool,
        jit_cache_dir: str | os.PathLike[str] | None,
        jit_flags: tuple[str, ...] | None,
        max_iter: int,
        tol: float,
        solver_options: dict[str, Any] | None,
        max_solve_time: float | None = None,
    ) -> None:
        solver = self.default_solver(free_time) if solver is None else solver
        limit = max_solve_time
        if limit is not None and not (isinstance(limit, (int, float, np.floating)) and 0 < limit < np.inf):
            raise ValueError(f"{self.name}: max_solve_time must be a positive number of seconds or None, got {limit!r}")
        self.max_solve_time = None if max_solve_time is None else float(max_solve_time)
        """Wall-time limit of one solve (s); a solve that hits it fails and the step falls back (None: no limit)."""
        if solver not in ("fatrop", "ipopt", "shooting"):
            raise ValueError(f"{self.name}: solver must be 'fatrop', 'ipopt' or 'shooting', got {solver!r}")
        if int(max_iter) < 0:
            raise ValueError(f"{self.name}: max_iter must be >= 0, got {max_iter}")
        self.solver: SolverName = solver
        self._max_iter, self._tol = int(max_iter), float(tol)
        self._user_solver_options = dict(solver_options or {})
        self._solver_options = self._options_for(solver, only_its_own=False)
        self._jit_cache_dir = None if jit_cache_dir is None else Path(jit_cache_dir)
        self._jit_options = jit_solver_options(self._jit_cache_dir, ("-O1",) if jit_flags is None else jit_flags)
        self._codegen_flags = ("-O3", "-fPIC", "-shared") if jit_flags is None else (*jit_flags, "-fPIC", "-shared")
        if jit and self._jit_options is None:
            warnings.warn(f"{self.name}: no C compiler found; solving without JIT (slower)", stacklevel=3)
        self.jit = bool(jit) and self._jit_options is not None


# ------------------------------------------------------------------------------------- limited lookahead
class LimitedLookaheadMPC(_MPCBase):
    """Paper Eq. 3: ``horizon`` steps and a (guarded) learned terminal cost; see the module docstring.

    Args:
        task: the task.
        value_function: a :class:`~seagul_control.value_function.CasadiValueFunction` (e.g. a ``ValueNetwork``), or
            None for the task's own terminal cost ``l_f``.
        horizon: number of steps ``n`` (paper: 5 for the acrobot, ~250 ms = 10 steps for the glider).
        dt: control period (default: the task's).
        solver: ``"shooting"``, ``"fatrop"`` or ``"ipopt"``. ``"shooting"`` condenses the lookahead to its inputs
            and solves it by projected Newton (:mod:`seagul_control.shooting`; fixed steps and input bounds only; a
            value network enters through its hand-derived Taylor forms): the same NLP, measured ~10x faster per
            step than fatrop on the acrobot with the shipped 3 x (2 x 64) ensemble (docs/experiments/mpc.md). Default
            (:meth:`default_solver`): ``"shooting"`` where it applies (the acrobot), else fatrop (IPOPT with free
            steps).
        jit: compile the NLP functions (cached on disk) when a C compiler exists.
        jit_cache_dir: cache directory (default ``$SEAGUL_CACHE_DIR`` or ``~/.cache/seagul/casadi``).
        jit_flags: compiler flags (default ``-O1`` for the scalar JIT, ``-O3`` for a matrix-form value function).
        max_iter: solver iteration limit per step.
        tol: solver tolerance.
        max_solve_time: wall-time limit of one solve (s; None: none). A solve that hits it fails and the step falls
            back like any failed solve (status ``"timeout: ..."``). IPOPT stops itself (``ipopt.max_wall_time``);
            fatrop cannot (its regularisation loop is unbounded) and runs in a forked child that is killed
            (:mod:`seagul_control._watchdog`, ~0.1 ms per step).
        solver_options: extra nlpsol options (e.g. ``{"fatrop.mu_init": 1e-2}``).
        substeps: RK4 substeps per step (default: the task's).
        trust_region: ``"lqr"``, ``"box"`` or ``"none"`` (module docstring); None (default): the task's
            ``profile.mpc_trust_region`` (acrobot and glider ``"none"``, a new task ``"lqr"``).
        trust_box: ``(low, high)`` state box for ``"box"`` (default: from the value function).
        trust_weight: weight ``w`` of the box penalty (value units per squared box width).
        clamp: use ``max(Vhat, 0)`` (smooth) as the learned cost.
        anchor_goal: subtract the network's value and gradient at the goal (``Vhat - Vhat(x*) - dVhat(x*) (x - x*)``),
            exact knowledge for a zero-cost equilibrium goal; default: on for such tasks (acrobot), off otherwise.
        goal_blend: scale ``c`` (value units) of the blend ``b l_f + (1 - b) Vhat``, ``b = exp(-l_f / c)``, that hands
            an equilibrium goal's neighbourhood to the task's quadratic (module docstring); 0 = off. Default: the
            task's ``profile.mpc_goal_blend`` (acrobot 1.0; 0 for a task without an equilibrium goal).
        final_box: impose the task's terminal box in the final-phase problems.
        steps: ``"fixed"`` (default; every step is ``dt``) or ``"free"`` (``h_k`` in the task's step bounds with
            ``sum(h) <= tau_now``, paper Eq. 3's general form; IPOPT by default, see :meth:`default_solver`).
        end_phase: ``"switch"`` (keep the horizon, terminal cost ``l_f`` once ``tau_now - sum(h) <= 0``) or
            ``"shrink"`` (``round(tau_now / dt)`` steps ending exactly at the episode end, terminal box and
            ``l_f``); default ``"shrink"`` for tasks with a terminal box (glider), ``"switch"`` otherwise.
        warm_start: warm-start each env from its previous solution (shifted).
        cold_guess: first guess without a warm start: ``"rollout"`` (zero input), ``"line"`` (to the goal) or
            ``"best"`` (a lifted fixed-step problem descends from both and keeps the lower converged plan; the
            condensed solver and free-time problems take the rollout alone). None (default): ``"best"`` with fixed
            steps, ``"rollout"`` with free steps. At long horizons the rollout alone is a poor guess for an unstable
            system: 20 zero-input steps of the acrobot are a 2 s fall, from which fatrop converged to a swing-around
            plan (objective 33-45 where the 10-step plan costs 0.01-5.6) or failed (docs/method/mpc.md).
        final_solver: solver of the final phase (default: ``solver``; IPOPT with ``final_soft_weight``).
        final_soft_weight: the final phase imposes the terminal box and path bounds as the exact L1
            penalty of this weight (IPOPT), so it returns the plan that ends closest to the box where the box is out
            of exact reach, instead of failing. None: the task's ``profile.mpc_final_soft_weight`` (glider 1e4,
            measured: 1 fallback step in 1,152 on the 6 x 6 grid instead of 337, mean cost 347 against 483, the same
            perch rate); 0: hard bounds.
        model_params: the lookahead's model takes the robot's physical parameters as NLP parameters (one build for
            every robot; :meth:`set_robot`); needs a task that declares them (``Task.parameters``).
        estimate_robot: plan for an online estimate of the robot (needs ``model_params``): before each step the
            env's last transition updates a :class:`~seagul_control.estimation.ParameterEstimator` of that env's
            episode, and the MPC plans for its estimate (:meth:`set_robot`). True for the estimator's defaults, or
            a dict of its options (``window``, ``prior``, ``iterations``, ``min_transitions``).
        multistart: when the condensed solver also descends from ``multistart_starts`` constant inputs spread over
            the bounds and keeps the lowest plan (a learned terminal cost makes the lookahead non-convex, and the
            warm start stays in its basin): ``"rise"`` (default with ``solver="shooting"``) at a cold start and
            whenever the warm-started plan costs more than the last step's plan (the warm basin has worsened),
            ``"always"`` every step, ``"never"`` (the only choice, and default, of the other solvers). Measured on
            a ``closed-loop+select`` acrobot network (``acrobot_closed-loop_select_b2000_seed0.pt``,
            docs/experiments/mpc.md): grid success 94.5 % -> 98.5 % with ``"rise"``
            (extra starts on ~5 % of steps) or ``"always"`` (~10x the step time).
        multistart_starts: how many extra starts (2: both bounds).

    A value function over robots (``n_params > 0``, e.g. a network trained with ``TrainConfig.model_params``) is
    evaluated at the robot the MPC plans for: the task's own parameters, or those of :meth:`set_robot`.
    """

    name = "LimitedLookaheadMPC"

    def __init__(
        self,
        task: Task,
        value_function: CasadiValueFunction | None,
        horizon: int,
        *,
        dt: float | None = None,
        solver: SolverName | None = None,
        jit: bool = True,
        jit_cache_dir: str | os.PathLike[str] | None = None,
        jit_flags: tuple[str, ...] | None = None,
        max_iter: int = 50,
        tol: float = 1e-6,
        max_solve_time: float | None = 5.0,
        solver_options: dict[str, Any] | None = None,
        substeps: int | None = None,
        trust_region: TrustRegion | None = None,
        trust_box: tuple[np.ndarray, np.ndarray] | None = None,
        trust_weight: float = 100.0,
        clamp: bool = True,
        anchor_goal: bool | None = None,
        goal_blend: float | None = None,
        final_box: bool = True,
        steps: str = "fixed",
        end_phase: str | None = None,
        warm_start: bool = True,
        cold_guess: str | None = None,
        final_solver: SolverName | None = None,
        final_soft_weight: float | None = None,
        model_params: bool = False,
        estimate_robot: bool | dict[str, Any] = False,
        multistart: Multistart | None = None,
        multistart_starts: int = 2,
    ) -> None:
        if model_params and task.parameters is None:
            raise ValueError(f"{self.name}: model_params=True needs a task that declares which parameters vary")
        if estimate_robot is not False and not model_params:
            raise ValueError(f"{self.name}: estimate_robot needs model_params=True (the plan uses the estimate)")
        if steps not in ("fixed", "free"):
            raise ValueError(f"{self.name}: steps must be 'fixed' or 'free', got {steps!r}")
        has_box = bool(np.any(np.isfinite(task.x_final_low)) or np.any(np.isfinite(task.x_final_high)))
        end_phase = ("shrink" if has_box else "switch") if end_phase is None else end_phase
        if end_phase not in ("switch", "shrink"):
            raise ValueError(f"{self.name}: end_phase must be 'switch' or 'shrink', got {end_phase!r}")
        if isinstance(horizon, bool) or not isinstance(horizon, (int, np.integer)) or int(horizon) < 1:
            raise ValueError(f"{self.name}: horizon must be an integer >= 1 step, got {horizon!r}")
        if trust_region is None:
            trust_region = task.profile.mpc_trust_region
        if trust_region not in ("box", "lqr", "none"):
            raise ValueError(f"{self.name}: trust_region must be 'box', 'lqr' or 'none', got {trust_region!r}")
        if not (np.isfinite(trust_weight) and trust_weight >= 0):
            raise ValueError(f"{self.name}: trust_weight must be a finite number >= 0, got {trust_weight!r}")
        if cold_guess is None:
            cold_guess = "best" if steps == "fixed" else "rollout"
        super().__init__(task, dt, warm_start, cold_guess)
        self.model_params = bool(model_params)
        self._estimator_options: dict[str, Any] | None = None
        if estimate_robot is not False:
            self._estimator_options = {} if estimate_robot is True else dict(estimate_robot)
        self._estimators: dict[int, ParameterEstimator] = {}
        """One estimator per env (env 0's built here: bad options fail at construction), reset per episode."""
        if self._estimator_options is not None:
            self._estimators[0] = ParameterEstimator(task, self.dt, **self._estimator_options)
        self._last_step: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.horizon = int(horizon)
        self.trust_region: TrustRegion = trust_region
        self.trust_weight = float(trust_weight)
        self.clamp = bool(clamp)
        equilibrium = task.goal_is_equilibrium(cost=True)
        self.anchor_goal = equilibrium if anchor_goal is None else bool(anchor_goal)
        if self.anchor_goal and not equilibrium:
            raise ValueError(f"{self.name}: anchor_goal needs a goal that is a zero-cost equilibrium of the task")
        if goal_blend is None:
            goal_blend = float(getattr(task.profile, "mpc_goal_blend", 0.0)) if equilibrium else 0.0
        self.goal_blend = float(goal_blend)
        if not (np.isfinite(self.goal_blend) and self.goal_blend >= 0):
            raise ValueError(f"{self.name}: goal_blend must be a finite number >= 0 (0 = off), got {goal_blend!r}")
        if self.goal_blend > 0 and not equilibrium:
            raise ValueError(f"{self.name}: goal_blend needs a goal that is a zero-cost equilibrium of the task")
        self._configure_solver(
            solver, steps == "free", jit, jit_cache_dir, jit_flags, max_iter, tol, solver_options, max_solve_time
        )
        if multistart not in (None, "never", "rise", "always"):
            raise ValueError(f"{self.name}: multistart must be 'never', 'rise', 'always' or None, got {multistart!r}")
        if multistart not in (None, "never") and self.solver != "shooting":
            raise ValueError(f"{self.name}: multistart={multistart!r} needs solver='shooting', not {self.solver!r}")
        if isinstance(multistart_starts, bool) or not isinstance(multistart_starts, (int, np.integer)):
            raise ValueError(f"{self.name}: multistart_starts must be an integer >= 1, got {multistart_starts!r}")
        if multistart_starts < 1:
            raise ValueError(f"{self.name}: multistart_starts must be an integer >= 1, got {multistart_starts!r}")
        self.multistart = ("rise" if self.solver == "shooting" else "never") if multistart is None else multistart
        self.multistart_starts = int(multistart_starts)

        self.free_time = steps == "free"
        self._vf_fn: ca.Function | None = None
        self._vf_theta = np.zeros(0)
        self._vf_robots: Any = None
        """A private copy of a value function over robots (re-conditioned by :meth:`set_robot`), else None."""
        self._anchor_cache: dict[float, np.ndarray] = {}
        n_vf = 0
        self._vf_taylor: tuple[ca.Function, ca.Function] | None = None
        if value_function is not None:
            self._vf_fn = self._check_value_function(value_function)
            n_vf = int(self._vf_fn.nnz_in(2))
            if self.solver == "shooting":
                self._vf_taylor = _taylor_forms(value_function)
        self.n_vf = n_vf
        terminal = self._terminal_function(n_vf)
        # The condensed solver differentiates the terminal cost through the value function's Taylor model.
        terminal_model = self._terminal_model(n_vf) if self._vf_taylor is not None else None
        n_theta = int(terminal.nnz_in(2))
        self._theta = np.zeros(n_theta)
        # The final phase ends at the episode's end: its terminal cost is l_f (the learned term's switch s is 0 there).
        # Its own SX function, with the same parameter vector, keeps the network's graph out of its NLP: evaluated
        # at s = 0 it still cost the network's Hessian at every iteration.
        xs, ts, ths = ca.SX.sym("x", task.nx), ca.SX.sym("tau_rem"), ca.SX.sym("theta", n_theta)
        self._final_terminal = ca.Function("mpc_final_terminal", [xs, ts, ths], [task.terminal_cost(xs)])
        if value_function is not None:
            self.set_value_function(value_function, trust_box=trust_box)

        self.free_time = steps == "free"
        if final_solver not in (None, "fatrop", "ipopt", "shooting"):
            raise ValueError(
                f"{self.name}: final_solver must be 'fatrop', 'ipopt', 'shooting' or None, got {final_solver!r}"
            )
        if final_soft_weight is None:
            final_soft_weight = task.profile.mpc_final_soft_weight
        if final_soft_weight is not None and not (np.isfinite(final_soft_weight) and final_soft_weight >= 0):
            raise ValueError(f"{self.name}: final_soft_weight must be a number >= 0 or None, got {final_soft_weight!r}")
        self.final_soft_weight = float(final_soft_weight) if final_soft_weight else None  # 0: a hard box
        if self.final_soft_weight is not None and final_solver is None:
            final_solver = "ipopt"  # soft bounds need IPOPT (slack variables)
        if self.final_soft_weight is not None and final_solver != "ipopt":
            raise ValueError(f"{self.name}: final_soft_weight needs final_solver='ipopt', got {final_solver!r}")
        if final_solver is None and self.solver == "shooting" and has_box and final_box:
            final_solver = "fatrop"  # the final phase imposes the terminal box: not a condensable problem
        self.final_solver: SolverName = self.solver if final_solver is None else final_solver
        self.end_phase = end_phase
        self.final_box = bool(final_box)
        self.substeps = substeps
        self._final_fixed: dict[int, _Problem] = {}
        self._final: _Problem | None = None
        common: dict[str, Any] = {
            "horizon": self.horizon,
            "terminal_cost": terminal,
            "terminal_model": terminal_model,
            "n_theta": n_theta,
            "substeps": substeps,
            "model_params": self.model_params,
        }
        if not self.free_time:
            self._lookahead = self._build("lookahead", False, free_time=False, step=self.dt, final_box=False, **common)
        else:
            self._lookahead = self._build(
                "lookahead", True, free_time=True, time_mode="at_most", final_box=False, **common
            )
            if end_phase == "shrink":
                # One free-time problem serves every remaining time: sum(h) = tau_now, steps shrink with it.
                self._final = self._build(
                    "final",
                    True,
                    shrink=True,
                    free_time=True,
                    step_bounds=(0.0, max(task.step_bounds[1], self.dt)),
                    time_mode="equal",
                    final_box=self.final_box,
                    solver=self.final_solver,
                    soft_bounds_weight=self.final_soft_weight,
                    **{**common, "terminal_cost": self._final_terminal, "terminal_model": None},
                )

    #: Longest lookahead the condensed solver is chosen for by default: single shooting over an unstable system's
    #: long rollouts is ill-conditioned, and its advantage (few inputs) shrinks with the horizon.
    SHOOTING_MAX_HORIZON = 10

    def default_solver(self, free_time: bool) -> SolverName:
        """``"shooting"`` for a short fixed-step lookahead of a task with input bounds only (the acrobot: the same
        NLP ~10x faster per step, docs/experiments/mpc.md), else as :meth:`_MPCBase.default_solver` (fatrop; IPOPT for
        free time)."""
        from seagul_control.shooting import condensation_problems

        # The lookahead never imposes the terminal box (final_box=False) and has hard bounds.
        problems = condensation_problems(self.task, free_time=free_time, final_box=False, soft_bounds=False)
        condensable = not problems and self.horizon <= self.SHOOTING_MAX_HORIZON
        return "shooting" if condensable else super().default_solver(free_time)

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

    # ------------------------------------------------------------------ phases
    def _select(self, tau: float) -> tuple[_Problem, np.ndarray]:
        theta = self._theta.copy()
        remaining = tau - self.horizon * self.dt
        learned = remaining > _TIME_EPS
        if self._vf_fn is not None:
            theta[-1] = 1.0 if learned else 0.0
            if learned:
                self._anchor_terms(theta, remaining)
        if learned or self.end_phase == "switch":
            return self._lookahead, theta
        if self.free_time and self._final is not None:
            return self._final, theta
        # Fixed steps: k = round(tau / dt) steps end exactly at the episode end (one lazily built solver per k).
        k = max(1, min(self.horizon, round(tau / self.dt)))
        if k not in self._final_fixed:
            self._final_fixed[k] = self._build(
                "final",
                False,
                horizon=k,
                free_time=False,
                step=self.dt,
                final_box=self.final_box,
                terminal_cost=self._final_terminal,
                n_theta=self._theta.size,
                substeps=self.substeps,
                jit=True,
                solver=self.final_solver,
                soft_bounds_weight=self.final_soft_weight,
                model_params=self.model_params,
            )
        return self._final_fixed[k], theta

    # ------------------------------------------------------------------ robots
    def set_robot(self, theta: Any) -> None:
        """Plan for the robot with parameters ``theta`` (``task.parameters`` order or a mapping; None: the task's
        own): the lookahead's model takes them (``model_params=True``) and a value function over robots is
        evaluated at them. Only NLP parameters change (no rebuild, warm starts kept), so it may be called at every
        step, e.g. with an online estimate.

        Raises:
            ValueError: the task declares no parameters, the MPC neither takes them nor has a value function over
                robots, or ``theta`` is malformed.
        """
        space = self.task.parameters
        if space is None or not (self.model_params or self._vf_robots is not None):
            raise ValueError(
                f"{self.name}: set_robot needs LimitedLookaheadMPC(..., model_params=True) or a value function over "
                "robots (n_params > 0) on a task that declares its parameters"
            )
        resolved = None if theta is None else space.resolve(theta, self.task.theta, self.task.name)
        if self.model_params:
            self._robot = resolved
        if self._vf_robots is not None:
            self._vf_robots.condition(self.task.theta if resolved is None else resolved)
            self._vf_theta = np.asarray(self._vf_robots.casadi_parameters(), dtype=float).ravel()
            self._theta[: self.n_vf] = self._vf_theta
            self._anchor_cache.clear()

    @property
    def robot(self) -> np.ndarray:
        """The parameters the MPC plans for (the task's own unless :meth:`set_robot` gave others)."""
        return self.task.theta if self._robot is None else self._robot.copy()

    def act(self, x: np.ndarray, tau: float, env_index: int = 0) -> tuple[np.ndarray, MPCStepInfo]:
        """As :meth:`_MPCBase.act`; with ``estimate_robot``, first the env's last transition updates its estimate
        and the MPC plans for it."""
        if self._estimator_options is None:
            return super().act(x, tau, env_index)
        estimator = self._estimators.get(env_index)
        if estimator is None:
            estimator = self._estimators[env_index] = ParameterEstimator(self.task, self.dt, **self._estimator_options)
        last = self._last_step.get(env_index)
        x_now = np.asarray(x, dtype=float).reshape(-1)
        self.set_robot(estimator.update(last[0], last[1], x_now) if last is not None else estimator.theta)
        u, info = super().act(x, tau, env_index)
        self._last_step[env_index] = (x_now.copy(), np.asarray(u, dtype=float).copy())
        return u, info

    def estimate(self, env_index: int = 0) -> np.ndarray:
        """The current robot estimate of env ``env_index`` (``estimate_robot``; the task's own before any step)."""
        if self._estimator_options is None:
            raise ValueError(f"{self.name}: estimate() needs estimate_robot")
        est = self._estimators.get(env_index)
        return self.task.theta if est is None else est.theta.copy()

    def reset(self) -> None:
        """Forget every warm start and, with ``estimate_robot``, every episode's estimate."""
        super().reset()
        for estimator in self._estimators.values():
            estimator.reset()
        self._last_step.clear()

    def _forget(self, env_index: int) -> None:
        super()._forget(env_index)
        if env_index in self._estimators:
            self._estimators[env_index].reset()
        self._last_step.pop(env_index, None)


# ----------------------------------------------------------------------------------------------- full horizon
class FullHorizonMPC(_MPCBase):
    """The upper reference: the task's full problem re-solved at every step from the current state.

    Fixed-step tasks (acrobot): ``round(tau_now / dt)`` steps of ``dt`` and ``l_f`` (a solver per remaining
    horizon, built lazily and kept). Free-time tasks (glider): ``task.num_steps`` steps with ``sum(h) = tau_now``,
    ``h_k in [0, h_max]``, the first step pinned to ``min(dt, tau_now)``, the terminal box and ``l_f`` (one solver).
    Options as for :class:`LimitedLookaheadMPC`; JIT is off by default (compiling the long problem takes minutes).
    ``max_solve_time`` defaults to 60 s, not the lookahead's 5 s: the reference is not a real-time controller, and
    a limit that a loaded machine reaches made its episodes depend on the load (glider from its far corner: cost
    422 idle; 508-726 under load 10 on 2 cores, where its steps took 0.5-7.5 s and hit 5 s). 60 s still stops a
    hung solve.
    """

    name = "FullHorizonMPC"

    def __init__(
        self,
        task: Task,
        *,
        dt: float | None = None,
        solver: SolverName | None = None,
        jit: bool = False,
        jit_cache_dir: str | os.PathLike[str] | None = None,
        jit_flags: tuple[str, ...] | None = None,
        max_iter: int = 500,
        tol: float = 1e-6,
        max_solve_time: float | None = 60.0,
        solver_options: dict[str, Any] | None = None,
        substeps: int | None = None,
        horizon: int | None = None,
        warm_start: bool = True,
        cold_guess: str = "line",
        model_params: bool = False,
    ) -> None:
        super().__init__(task, dt, warm_start, cold_guess)
        self._configure_solver(
            solver, not task.fixed_step, jit, jit_cache_dir, jit_flags, max_iter, tol, solver_options, max_solve_time
        )
        if model_params and task.parameters is None:
            raise ValueError(f"{self.name}: model_params=True needs a task that declares which parameters vary")
        self.model_params = bool(model_params)
        self.substeps = substeps
        self.free_time = not task.fixed_step
        self.horizon = int(task.num_steps if horizon is None else horizon)
        if self.horizon < 1:
            raise ValueError(f"{self.name}: horizon must be >= 1, got {horizon!r}")
        self._problems: dict[int, _Problem] = {}
        if self.free_time:
            hi = max(task.step_bounds[1], self.dt)
            self._problems[0] = self._build(
                "full",
                True,
                shrink=True,
                horizon=self.horizon,
                free_time=True,
                step_bounds=(0.0, hi),
                time_mode="equal",
                final_box=True,
                substeps=substeps,
                model_params=self.model_params,
            )

    def set_robot(self, theta: Any) -> None:
        """Plan for the robot with parameters ``theta`` (``task.parameters`` order or a mapping; None: the model's
        own): the oracle that knows the true robot, with the solvers built once (``model_params=True``)."""
        if not self.model_params:
            raise ValueError(f"{self.name}: set_robot needs FullHorizonMPC(..., model_params=True)")
        space = self.task.parameters
        assert space is not None  # checked at construction
        self._robot = None if theta is None else space.resolve(theta, self.task.theta, self.task.name)

    def _select(self, tau: float) -> tuple[_Problem, np.ndarray]:
        if self.free_time:
            return self._problems[0], np.zeros(0)
        n = max(1, round(tau / self.dt))
        if n not in self._problems:
            self._problems[n] = self._build(
                "full",
                False,
                horizon=n,
                free_time=False,
                step=self.dt,
                final_box=True,
                substeps=self.substeps,
                model_params=self.model_params,
            )
        return self._problems[n], np.zeros(0)


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


__all__ = [
    "FullHorizonMPC",
    "LimitedLookaheadMPC",
    "MPCStepInfo",
    "default_cache_dir",
    "find_c_compiler",
    "jit_solver_options",
]
