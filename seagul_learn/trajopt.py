"""Full-horizon trajectory optimization (paper Eq. 1) with the value gradient from the duals (paper Eq. 5).

:class:`TrajectoryOptimizer` builds its transcription(s) once and reuses them for every solve. One solve from
``(x_init, tau)`` returns a :class:`~seagul_learn.results.SolveResult`: the value, ``dV/dx_init`` and ``dV/dtau``
(parametric sensitivities ``-lam_p``, docs/reference/spec.md §6.2) and one label per knot (state, time to go, cost to
go, ``dV_k/dx_k`` from the defect multipliers).

Robustness: a deterministic sequence of attempts (solver and initial guess) is tried until one succeeds, so the label
of a start depends only on ``(x_init, tau)`` and the configuration, never on what was solved before (batch and
parallel solving stay reproducible). The default plans (each task's ``task.profile.solver``) start with the fastest
solver from a straight-line guess and end with IPOPT from "the goal everywhere"; see :class:`TrajOptConfig` and
docs/experiments/trajopt.md.

``grad_tau`` of a fixed-step task (the acrobot, ``h = tau / m``) is the sensitivity of ``V`` to stretching every
step; it is not the derivative of a free-final-time value and the acrobot's ``T0`` is a single value anyway.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
import warnings
from dataclasses import dataclass, field
from typing import Any, Literal

import casadi as ca
import numpy as np

from seagul_control.transcription import Transcription, TranscriptionOptions, TranscriptionSolution
from seagul_envs.tasks import BUILTIN_TASKS, make_task
from seagul_envs.tasks.base import Task, rk4_map
from seagul_learn.results import SolveResult

SolverName = Literal["ipopt", "ipopt_fast", "fatrop"]
SOLVER_NAMES: tuple[str, ...] = ("ipopt", "ipopt_fast", "fatrop")
#: Iteration cap of the ``ipopt_fast`` variant: it either converges quickly or hands over to the careful IPOPT.
FAST_IPOPT_MAX_ITER = 150
#: IPOPT options of the ``ipopt_fast`` variant (over the careful IPOPT's).
FAST_IPOPT_OPTIONS: dict[str, Any] = {"ipopt.accept_every_trial_step": "yes"}
GuessName = Literal["line", "goal", "hold", "kinematic"]

GUESS_NAMES: tuple[str, ...] = ("line", "goal", "hold", "kinematic")

# The per-task defaults (attempt plan, multi-start, kinematic pairs) live on the task: ``task.profile.solver``
# (:class:`~seagul_envs.tasks.profile.SolverDefaults`; the acrobot's and the glider's, with their measurements, in
# their task modules). ``TASK_DEFAULTS`` and ``KINEMATIC_PAIRS`` remain as deprecated views of the built-in tasks'.
_DEPRECATED_VIEWS = ("TASK_DEFAULTS", "KINEMATIC_PAIRS")


def __getattr__(name: str) -> Any:
    """``TASK_DEFAULTS`` / ``KINEMATIC_PAIRS``: deprecated name-keyed views of the built-in tasks' profiles."""
    if name in _DEPRECATED_VIEWS:
        warnings.warn(
            f"seagul_learn.trajopt.{name} is deprecated; the defaults live on the task: task.profile.solver",
            DeprecationWarning,
            stacklevel=2,
        )
        tasks = {n: make_task(n) for n in sorted(BUILTIN_TASKS)}
        if name == "TASK_DEFAULTS":
            return {n: t.profile.solver.config_defaults() for n, t in tasks.items()}
        return {n: t.profile.solver.kinematic_pairs for n, t in tasks.items() if t.profile.solver.kinematic_pairs}
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


@dataclass(frozen=True)
class TrajOptConfig:
    """Options of :class:`TrajectoryOptimizer` (hashable, so workers can cache one optimizer per configuration)."""

    plan: tuple[str, ...] | None = None
    """Attempts ``"solver:guess"`` tried in order until one succeeds. None: derived from ``solver``,
    ``fallback_solver`` and ``guesses`` if any of them is set, else the task's default (``task.profile.solver``).
    Solvers: ``"ipopt"``, ``"fatrop"``, ``"ipopt_fast"`` (IPOPT with ``accept_every_trial_step``, capped at
    :data:`FAST_IPOPT_MAX_ITER` iterations)."""
    solver: SolverName | None = None
    """Solver of the first attempt when the plan is derived (default ``"ipopt"``)."""
    fallback_solver: SolverName = "ipopt"
    """Solver of the fallback attempts of a derived plan and of the multi-start."""
    guesses: tuple[str, ...] | None = None
    """Initial guesses of a derived plan: the first with ``solver``, all with ``fallback_solver`` (default
    ``("line", "goal")``). Names: ``"line"`` straight line from ``x_init`` to the goal, ``"goal"`` the goal at
    every knot, ``"hold"`` ``x_init`` at every knot, ``"kinematic"`` the line with each (position, velocity) pair of
    ``task.profile.solver.kinematic_pairs`` made consistent (velocity linear from the start's so that the position
    reaches the goal's at ``tau``). Inputs start at zero, steps at ``tau / m``."""
    multi_start: Literal["never", "on_suspect", "always"] | None = None
    """Also solve from every guess in ``multi_start_guesses`` (with the fallback solver) and keep the lowest value:
    ``"always"``; ``"on_suspect"`` when the first successful value exceeds ``suspect_value`` (a cheap guard against
    poor local optima, docs/experiments/trajopt.md); ``"never"``. None: the task's default (``task.profile.solver``)."""
    multi_start_guesses: tuple[str, ...] | None = None
    """Extra guesses of the multi-start (None: the task's default)."""
    suspect_value: float | None = None
    """Value above which ``multi_start="on_suspect"`` triggers (None: the task's default)."""
    tol: float = 1e-8
    """Solver tolerance (IPOPT ``tol``, fatrop ``tol``)."""
    acceptable_tol: float = 1e-6
    """IPOPT ``acceptable_tol``."""
    max_iter: int = 500
    """Iteration limit per attempt."""
    substeps: int | None = None
    """RK4 substeps per interval (default: the task's)."""
    horizon: int | None = None
    """Number of intervals (default: the task's ``m``). A shorter horizon on a fixed-step task solves the tail problem
    from a mid-trajectory knot (same step, ``tau`` may then be below ``T0``)."""
    soft_bounds_weight: float | None = None
    """None: the state bounds (path bounds, terminal box) are hard constraints (the full problem). A weight ``M > 0``
    makes them the exact L1 penalty ``M * sum_k sum_i max(0, x_k,i - hi, lo - x_k,i)`` over knots ``1..m``
    (``TranscriptionOptions(soft_bounds_weight=M)``; IPOPT attempts only): the value where the bounds can be met, a
    finite, graded value where they cannot (tails from the glider's planned terminal states, from which the perch may be
    unreachable or a crash unavoidable). The penalties are part of the value and of every knot's label."""
    model_params: bool = False
    """The task's varying physical parameters (``task.parameters``) enter every solver as NLP parameters:
    :meth:`TrajectoryOptimizer.solve` takes ``theta`` (default the task's own values), one built solver serves every
    robot in ``Theta``, and ``SolveResult.grad_theta = dV/dtheta`` comes from the multipliers (CasADi's ``lam_p``)."""
    max_solve_time: float | None = 30.0
    """Wall-time limit of one attempt (s; None: none). IPOPT stops itself (``ipopt.max_wall_time``, unless
    ``solver_options`` sets its own); a fatrop attempt runs in a killable child
    (``TranscriptionOptions(max_solve_time=)``, :mod:`seagul_control._watchdog`) and an overrun fails with status
    ``"timeout: ..."``, so the plan's next attempt takes over. fatrop's regularisation loop has no upper bound: one
    full solve from an adversarial start looped for 50 minutes inside fatrop and stopped a 2,000-solve training run
    (docs/experiments/closed-loop.md)."""
    codegen: bool = True
    """Compile the NLP functions to C (cached on disk) when a compiler is available."""
    solver_options: tuple[tuple[str, Any], ...] = ()
    """Extra options for every solver (e.g. ``(("ipopt.linear_solver", "mumps"),)``), merged last."""

    def with_updates(self, **changes: Any) -> TrajOptConfig:
        """A copy with some fields changed (``solver_options`` may be given as a dict).

        Raises:
            ValueError: a name that is not a field.
        """
        unknown = set(changes) - {f.name for f in dataclasses.fields(TrajOptConfig)}
        if unknown:
            raise ValueError(f"unknown TrajectoryOptimizer options {sorted(unknown)}")
        if isinstance(changes.get("solver_options"), dict):
            changes["solver_options"] = tuple(sorted(changes["solver_options"].items()))
        for key in ("guesses", "plan"):
            if isinstance(changes.get(key), list):
                changes[key] = tuple(changes[key])
        if isinstance(changes.get("multi_start_guesses"), list):
            changes["multi_start_guesses"] = tuple(changes["multi_start_guesses"])
        return dataclasses.replace(self, **changes)

    def resolved(self, task: Task | str) -> TrajOptConfig:
        """A copy with the None fields filled from the task's defaults (``task.profile.solver``; a name is resolved
        with ``make_task``)."""
        task = make_task(task) if isinstance(task, str) else task
        defaults = task.profile.solver.config_defaults()
        if self.solver is not None or self.guesses is not None:
            defaults.pop("plan", None)
        changes = {k: v for k, v in defaults.items() if getattr(self, k) is None}
        cfg = dataclasses.replace(self, **changes) if changes else self
        if cfg.plan is None:
            solver = cfg.solver or "ipopt"
            guesses = cfg.guesses or ("line", "goal")
            plan = [f"{solver}:{guesses[0]}"] + [f"{cfg.fallback_solver}:{g}" for g in guesses[1:]]
            if solver != cfg.fallback_solver:
                # The fast solver's failure is often the solver's, not the guess's: retry its first guess too.
                plan.insert(1, f"{cfg.fallback_solver}:{guesses[0]}")
            cfg = dataclasses.replace(cfg, plan=tuple(plan))
        return cfg

    def validate(self) -> None:
        """Raise ValueError on unknown solver or guess names and bad numbers."""
        steps = [p.split(":", 1) for p in (self.plan or ())]
        if any(len(st) != 2 for st in steps):
            raise ValueError(f"plan entries must read 'solver:guess', got {self.plan}")
        if self.plan is not None and not self.plan:
            raise ValueError("plan must name at least one attempt")
        for s in (self.solver, self.fallback_solver, *(st[0] for st in steps)):
            if s is None:
                continue
            if s not in SOLVER_NAMES:
                raise ValueError(f"unknown solver {s!r}; use 'ipopt' or 'fatrop' (or 'ipopt_fast')")
        if self.guesses is not None and not self.guesses:
            raise ValueError("guesses must name at least one initial guess")
        for gname in (*(self.guesses or ()), *(self.multi_start_guesses or ()), *(st[1] for st in steps)):
            if gname not in GUESS_NAMES:
                raise ValueError(f"unknown guess {gname!r}; use one of {GUESS_NAMES}")
        if self.multi_start not in (None, "never", "on_suspect", "always"):
            raise ValueError(f"unknown multi_start {self.multi_start!r}")
        if self.max_iter < 1 or self.tol <= 0:
            raise ValueError("max_iter must be >= 1 and tol > 0")
        if self.max_solve_time is not None and not (math.isfinite(self.max_solve_time) and self.max_solve_time > 0):
            raise ValueError(f"max_solve_time must be positive seconds or None, got {self.max_solve_time!r}")
        if self.soft_bounds_weight is not None and not (
            math.isfinite(self.soft_bounds_weight) and self.soft_bounds_weight > 0
        ):
            raise ValueError(f"soft_bounds_weight must be a positive number or None, got {self.soft_bounds_weight!r}")
        if self.soft_bounds_weight is not None and any(st[0] == "fatrop" for st in steps):
            raise ValueError(
                f"soft_bounds_weight (soft state bounds) needs IPOPT attempts; the plan has fatrop: {self.plan}"
            )


@dataclass
class _Attempt:
    label: str
    sol: TranscriptionSolution


_IPOPT_WALL_TIME = "Maximum_WallTime_Exceeded"
"""IPOPT's status when ``ipopt.max_wall_time`` stopped it."""


@dataclass
class _Counters:
    """What :meth:`TrajectoryOptimizer.solve` did since the optimizer was built (read by benchmarks and tests)."""

    solves: int = 0
    fallbacks: int = 0
    """Solves that needed more than one attempt of the plan."""
    failures: int = 0
    timeouts: int = 0
    """Attempts stopped at ``max_solve_time``: a fatrop attempt killed by the guard (status ``"timeout: ..."``) or an
    IPOPT one that stopped itself (``"Maximum_WallTime_Exceeded"``); each gave way to the plan's next attempt."""
    statuses: dict[str, int] = field(default_factory=dict)
    """Final status of each solve, counted."""


class TrajectoryOptimizer:
    """Solves paper Eq. 1 from many starts with solvers built once.

    Args:
        task: a :class:`Task` or its registry name.
        config: a :class:`TrajOptConfig`; keyword ``options`` override its fields
            (e.g. ``TrajectoryOptimizer("acrobot", solver="fatrop", guesses=("line",))``).
    """

    def __init__(self, task: Task | str, config: TrajOptConfig | None = None, **options: Any) -> None:
        self.task: Task = make_task(task) if isinstance(task, str) else task
        cfg = config or TrajOptConfig()
        if options:
            cfg = cfg.with_updates(**options)
        cfg.validate()
        cfg = cfg.resolved(self.task)
        cfg.validate()  # again with the task's plan filled in (e.g. soft bounds with a default plan that has fatrop)
        self.config = cfg
        self.horizon = self.task.num_steps if cfg.horizon is None else int(cfg.horizon)
        self._transcriptions: dict[str, Transcription] = {}
        self._theta_jacobians: dict[tuple[int, int], ca.Function] = {}
        self.counters = _Counters()
        # Build the first solver now (fail early on bad options); fallbacks are built on first use.
        self._transcription(self._plan()[0][0])

    # ---------------------------------------------------------------- solvers
    def _solver_options(self, solver: str) -> dict[str, Any]:
        cfg = self.config
        base = "fatrop" if solver == "fatrop" else "ipopt"
        if base == "ipopt":
            opts: dict[str, Any] = {
                "ipopt.tol": cfg.tol,
                "ipopt.acceptable_tol": cfg.acceptable_tol,
                "ipopt.max_iter": cfg.max_iter,
            }
            if solver == "ipopt_fast":
                opts.update(FAST_IPOPT_OPTIONS)
                opts["ipopt.max_iter"] = min(cfg.max_iter, FAST_IPOPT_MAX_ITER)
        else:
            opts = {"fatrop.tol": cfg.tol, "fatrop.max_iter": cfg.max_iter}
        # Plugin options go to their own solver only ("ipopt.x" never reaches fatrop); others go to every solver.
        opts.update({k: v for k, v in cfg.solver_options if "." not in k or k.split(".", 1)[0] == base})
        return opts

    def _transcription(self, solver: str) -> Transcription:
        if solver not in self._transcriptions:
            options = TranscriptionOptions(
                substeps=self.config.substeps,
                solver="fatrop" if solver == "fatrop" else "ipopt",
                solver_options=self._solver_options(solver),
                codegen=self.config.codegen,
                soft_bounds_weight=self.config.soft_bounds_weight,
                model_params=self.config.model_params,
                max_solve_time=self.config.max_solve_time,
            )
            self._transcriptions[solver] = Transcription(self.task, self.horizon, options)
        return self._transcriptions[solver]

    def prepare(self) -> TrajectoryOptimizer:
        """Build every solver the plan and the multi-start may use (long-lived workers: no build inside a solve)."""
        for solver, _ in self._plan():
            self._transcription(solver)
        if self.config.multi_start != "never":
            self._transcription(self.config.fallback_solver)
        return self

    # ---------------------------------------------------------------- guesses
    def guess(self, name: str, x_init: np.ndarray, tau: float, solver: str | None = None) -> np.ndarray:
        """The primal initial guess called ``name`` (see :attr:`TrajOptConfig.guesses`); depends only on inputs."""
        tr = self._transcription(solver or self._plan()[0][0])
        if name == "line":
            return tr.line_guess(x_init, tau)
        if name == "goal":
            return tr.line_guess(self.task.goal, tau)
        if name == "hold":
            return tr.line_guess(x_init, tau, target=x_init)
        if name == "kinematic":
            return self._kinematic_guess(tr, x_init, tau)
        raise ValueError(f"unknown guess {name!r}; use one of {GUESS_NAMES}")

    def _kinematic_guess(self, tr: Transcription, x_init: np.ndarray, tau: float) -> np.ndarray:
        m = tr.horizon
        s = np.linspace(0.0, 1.0, m + 1)[:, None]
        states = (1 - s) * x_init + s * self.task.goal
        for ip, iv in self.task.profile.solver.kinematic_pairs:
            # Velocity linear in time from the start's; its mean covers the distance to the goal in tau.
            v0 = x_init[iv]
            v1 = 2 * (self.task.goal[ip] - x_init[ip]) / tau - v0
            states[:, iv] = v0 + (v1 - v0) * s[:, 0]
            states[:, ip] = x_init[ip] + tau * (v0 * s[:, 0] + 0.5 * (v1 - v0) * s[:, 0] ** 2)
        steps = np.full(m, tau / m) if tr.free_time else None
        return tr.pack_guess(states, np.zeros((m, self.task.nu)), steps)

    def _plan(self) -> list[tuple[str, str]]:
        return [tuple(p.split(":", 1)) for p in self.config.plan or ()]  # type: ignore[misc]

    # ------------------------------------------------------------------ solve
    def check_inputs(self, x_init: Any, tau: Any = None) -> tuple[np.ndarray, float]:
        """Validate ``(x_init, tau)``; raise ValueError naming the problem."""
        x = self.task.check_state(x_init, "x_init")
        tau_v = self.task.tau_nominal if tau is None else tau
        shorter = self.horizon != self.task.num_steps
        tau_f = self.task.check_tau(tau_v, allow_shorter=shorter)
        if tau_f <= 0.0:
            raise ValueError(f"{self.task.name}: time to go must be positive, got {tau_f}")
        return x, tau_f

    def check_theta(self, theta: Any) -> np.ndarray | None:
        """Validate the robot's parameters ``theta`` (an array in ``task.parameters.names`` order or a mapping; None:
        the task's own); None when the optimizer was built without ``model_params``.

        Raises:
            ValueError: ``theta`` is malformed, or given to an optimizer built without ``model_params=True``.
        """
        if not self.config.model_params:
            if theta is not None:
                raise ValueError(
                    f"{self.task.name}: theta needs TrajectoryOptimizer(..., model_params=True) (or solve the task "
                    "task.with_params(theta))"
                )
            return None
        space = self.task.parameters
        assert space is not None  # the first Transcription refused model_params without parameters
        return self.task.theta if theta is None else space.resolve(theta, self.task.theta, self.task.name)

    def solve(self, x_init: Any, tau: float | None = None, theta: Any = None) -> SolveResult:
        """Solve from ``x_init`` with time to go ``tau`` (default the task's nominal), for the robot ``theta``
        (optimizers built with ``model_params=True``; default the task's own parameters).

        Never raises for an infeasible or hard start: the result then has ``success=False`` and the last status.

        Raises:
            ValueError: ``x_init`` is not a finite ``(nx,)`` vector, ``tau`` is outside the task's range, or
                ``theta`` is malformed (:meth:`check_theta`).
        """
        x, tau_f = self.check_inputs(x_init, tau)
        phys = self.check_theta(theta)
        start = time.perf_counter()
        attempts: list[_Attempt] = []
        best: _Attempt | None = None
        for solver, gname in self._plan():
            att = self._attempt(solver, gname, x, tau_f, phys)
            attempts.append(att)
            if att.sol.success:
                best = att
                break
        cfg = self.config
        if best is not None and (
            cfg.multi_start == "always"
            or (cfg.multi_start == "on_suspect" and best.sol.objective > float(cfg.suspect_value or np.inf))
        ):
            tried = {a.label for a in attempts}
            for gname in cfg.multi_start_guesses or ():
                label = f"{cfg.fallback_solver}:{gname}"
                if label in tried:
                    continue
                att = self._attempt(cfg.fallback_solver, gname, x, tau_f, phys)
                attempts.append(att)
                # Strictly lower by a margin, so ties keep the deterministic first choice.
                if att.sol.success and att.sol.objective < best.sol.objective - 1e-6 * (1 + abs(best.sol.objective)):
                    best = att
        elapsed = time.perf_counter() - start
        final = best if best is not None else attempts[-1]
        self.counters.solves += 1
        self.counters.fallbacks += int(len(attempts) > 1)
        self.counters.failures += int(best is None)
        status = final.sol.status
        self.counters.statuses[status] = self.counters.statuses.get(status, 0) + 1
        return self._result(
            x,
            tau_f,
            final.sol,
            success=best is not None,
            iterations=sum(a.sol.iterations for a in attempts),
            solve_time=elapsed,
            labels=[a.label for a in attempts],
            transcription=self._transcription(final.label.split(":")[0]),
            theta=phys,
        )

    def _attempt(self, solver: str, gname: str, x: np.ndarray, tau: float, phys: np.ndarray | None = None) -> _Attempt:
        tr = self._transcription(solver)
        sol = tr.solve(x, tau, guess=self.guess(gname, x, tau, solver), model_params=phys)
        self.counters.timeouts += int(sol.status.startswith("timeout") or sol.status == _IPOPT_WALL_TIME)
        return _Attempt(f"{solver}:{gname}", sol)

    def _result(
        self,
        x: np.ndarray,
        tau: float,
        sol: TranscriptionSolution,
        *,
        success: bool,
        iterations: int,
        solve_time: float,
        labels: list[str],
        transcription: Transcription,
        theta: np.ndarray | None = None,
    ) -> SolveResult:
        nx = self.task.nx
        steps = np.asarray(sol.steps, dtype=float)
        stage = transcription.stage_costs(sol.states, sol.controls, steps)
        terminal = self.task.terminal_cost_value(sol.states[-1])
        # cost_to_go[k] = sum_{i>=k} h_i l(x_i, u_i) + l_f(x_m) (+ the soft bounds' penalties of knots j > k); its
        # first entry is the value.
        cost_to_go = np.concatenate([np.cumsum(stage[::-1])[::-1], [0.0]]) + terminal
        penalty = transcription.bound_penalties(sol.states)
        cost_to_go += np.concatenate([np.cumsum(penalty[::-1])[::-1][1:], [0.0]])
        elapsed = np.concatenate([[0.0], np.cumsum(steps)])
        time_to_go = tau - elapsed
        time_to_go[0], time_to_go[-1] = tau, 0.0  # exact ends: sum(h) = tau holds to the solver's tolerance
        time_to_go = np.maximum(time_to_go, 0.0)
        states = np.array(sol.states, dtype=float)
        states[0] = x  # x_0 = x_init is a constraint; IPOPT leaves ~1e-33 residues, store the start exactly
        grad_x = np.asarray(sol.param_sensitivity[:nx], dtype=float)
        grad_tau = float(sol.param_sensitivity[nx])
        knot_grads = np.vstack([grad_x[None, :], np.asarray(sol.defect_multipliers, dtype=float)])
        # p = [x_init, tau, model_params] (no terminal-cost parameters here): dV/dtheta is the tail of the sensitivity.
        grad_theta = None if theta is None else np.asarray(sol.param_sensitivity[nx + 1 :], dtype=float)
        knot_grad_theta = None
        if theta is not None:
            # Per knot, by the envelope theorem on each tail: dV_k/dtheta = sum_{j >= k} lambda_{j+1}' dF_j/dtheta with
            # lambda_{j+1} = dV_{j+1}/dx_{j+1} (the defect multipliers); row 0 equals grad_theta (tested).
            jac = self._theta_jacobian(transcription)
            # The map stacks the (nx, k) blocks side by side, interval after interval: [r, i, j] = dF_j,r/dtheta_i.
            blocks = np.asarray(jac(sol.states[:-1].T, sol.controls.T, steps[None, :], theta)).reshape(
                nx, theta.size, transcription.horizon, order="F"
            )
            per_interval = np.einsum("jr,rij->ji", knot_grads[1:], blocks)
            knot_grad_theta = np.vstack([np.cumsum(per_interval[::-1], axis=0)[::-1], np.zeros((1, theta.size))])
        return SolveResult(
            x_init=x.copy(),
            tau=tau,
            success=success,
            status=sol.status,
            value=float(cost_to_go[0]) if success else float("nan"),
            grad_x=grad_x,
            grad_tau=grad_tau,
            states=states,
            controls=np.asarray(sol.controls, dtype=float),
            steps=steps,
            time_to_go=time_to_go,
            cost_to_go=cost_to_go,
            knot_grads=knot_grads,
            iterations=iterations,
            solve_time=solve_time,
            attempts=labels,
            theta=None if theta is None else np.array(theta, dtype=float),
            grad_theta=grad_theta,
            knot_grad_theta=knot_grad_theta,
        )

    def _theta_jacobian(self, transcription: Transcription) -> ca.Function:
        """``dF/dtheta`` of the transcription's RK4 map, mapped over its intervals (built once per horizon)."""
        key = (transcription.horizon, transcription.substeps)
        fn = self._theta_jacobians.get(key)
        if fn is None:
            task = self.task
            step = task.rk4_step_params(transcription.substeps)
            x, u, h = ca.SX.sym("x", task.nx), ca.SX.sym("u", task.nu), ca.SX.sym("h")
            th = ca.SX.sym("theta", step.nnz_in(3))
            one = ca.Function("dF_dtheta", [x, u, h, th], [ca.jacobian(step(x, u, h, th), th)])
            fn = one.map(transcription.horizon, [False, False, False, True], [False], {})
            self._theta_jacobians[key] = fn
        return fn


@functools.cache
def _fine_replay(task: Task, nsub: int) -> ca.Function:
    """``(x, c, u, dt) -> (x, c)`` after ``nsub`` RK4 substeps of ``dt`` of the state and the running cost."""
    xa = ca.SX.sym("xa", task.nx + 1)
    u = ca.SX.sym("u", task.nu)
    x = xa[: task.nx]
    aug = ca.Function("aug", [xa, u], [ca.vertcat(task.dynamics(x, u), task.stage_cost(x, u))])
    step = rk4_map(aug, task.nx + 1, task.nu, 1, f"{task.name}_fine")
    acc = step.mapaccum("acc", nsub, [0], [0])
    xs, us, dts = ca.MX.sym("x", task.nx + 1), ca.MX.sym("u", task.nu), ca.MX.sym("dt")
    out = acc(xs, ca.repmat(us, 1, nsub), ca.repmat(dts, 1, nsub))
    return ca.Function(f"{task.name}_replay_{nsub}", [xs, us, dts], [out[:, -1]])


def integrator_error(task: Task, result: SolveResult, max_substep: float = 1e-4) -> dict[str, float]:
    """Accuracy of a solved trajectory against a fine RK4 (substeps <= ``max_substep``, inputs held per interval).

    Returns:
        ``max_state_error``: the integrator error, largest one-interval ``|x_{k+1} - Phi_fine(x_k, u_k, h_k)|_inf``
        (the defect the transcription's RK4 leaves against the true flow).
        ``cost_quadrature_rel_error``: the transcription's running cost (rectangle rule ``h_k l(x_k, u_k)``,
        docs/reference/spec.md §5.3) against the fine integral of ``l`` along each interval, ``|diff| / max(V, 1)``
        (zero for the glider, whose ``l`` depends on ``u`` only).
        ``replay_final_error``, ``replay_cost_rel_error``: open-loop replay of the inputs from ``x_init``. The
        acrobot's goal is unstable, so its 5 s replay drifts by construction even with an exact integrator: for
        information only.
    """
    steps = np.asarray(result.steps, dtype=float)
    nsub = max(1, int(np.ceil(steps.max() / max_substep - 1e-9)))
    replay = _fine_replay(task, nsub)
    max_err = 0.0
    fine_cost = 0.0
    x_open = np.append(result.states[0], 0.0)
    for k, h in enumerate(steps):
        local = np.asarray(replay(np.append(result.states[k], 0.0), result.controls[k], h / nsub)).ravel()
        max_err = max(max_err, float(np.max(np.abs(local[: task.nx] - result.states[k + 1]))))
        fine_cost += float(local[-1])
        x_open = np.asarray(replay(x_open, result.controls[k], h / nsub)).ravel()
    terminal = task.terminal_cost_value(result.states[-1])
    value = float(result.cost_to_go[0])
    open_cost = float(x_open[-1]) + task.terminal_cost_value(x_open[: task.nx])
    return {
        "max_state_error": max_err,
        "cost_quadrature_rel_error": abs(fine_cost + terminal - value) / max(abs(value), 1.0),
        "replay_final_error": float(np.max(np.abs(x_open[: task.nx] - result.states[-1]))),
        "replay_cost_rel_error": abs(open_cost - value) / max(abs(value), 1e-12),
    }
