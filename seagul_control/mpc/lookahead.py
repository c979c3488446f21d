"""The limited-lookahead MPC (paper Eq. 3): ``horizon`` steps and a learned terminal cost (:mod:`seagul_control.mpc`).

This module holds the controller's construction (options resolved against the task), its phases (the lookahead,
then the final phase at the episode's end) and its robot handling (``model_params``, ``estimate_robot``); the
terminal cost is :mod:`seagul_control.mpc.terminal_cost`, the per-step machinery :mod:`seagul_control.mpc.base`.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from seagul_control._options import merge_deprecated
from seagul_control.estimation import ParameterEstimator
from seagul_control.mpc.base import _TIME_EPS, MPCStepInfo, _Problem
from seagul_control.mpc.options import MPCOptions, SolverName, TrustRegion
from seagul_control.mpc.saving import load_mpc, save_mpc
from seagul_control.mpc.terminal_cost import TerminalCostMPC, _taylor_forms
from seagul_control.shooting import condensation_problems
from seagul_control.value_function import CasadiValueFunction
from seagul_envs.tasks.base import Task


class LimitedLookaheadMPC(TerminalCostMPC):
    """Paper Eq. 3: ``horizon`` steps and a (guarded) learned terminal cost; see :mod:`seagul_control.mpc`.

    Args:
        task: the task.
        value_function: a :class:`~seagul_control.value_function.CasadiValueFunction` (e.g. a ``ValueNetwork``), or
            None for the task's own terminal cost ``l_f``. One that records a task fingerprint (``task_fingerprint``)
            must have been trained for this very task (a same-named variant raises a ValueError).
        horizon: number of steps ``n`` (paper: 5 for the acrobot, ~250 ms = 10 steps for the glider).
        options: solver, terminal-cost and end-of-episode settings (:class:`~seagul_control.mpc.MPCOptions`; default
            ``MPCOptions()``). Its task-dependent defaults are resolved here; :attr:`options` holds the result.
        trust_region: ``"lqr"``, ``"box"`` or ``"none"``: overrides ``options.trust_region`` (kept as a keyword: the
            guard is the first thing a study varies).
        model_params: the lookahead's model takes the robot's physical parameters as NLP parameters (one build for
            every robot; :meth:`set_robot`); needs a task that declares them (``Task.parameters``).
        estimate_robot: plan for an online estimate of the robot (needs ``model_params``): before each step the
            env's last transition updates a :class:`~seagul_control.estimation.ParameterEstimator` of that env's
            episode, and the MPC plans for its estimate (:meth:`set_robot`). True for the estimator's defaults, or
            a dict of its options (``window``, ``prior``, ``iterations``, ``min_transitions``).
        **deprecated: the old keyword arguments (``dt=``, ``solver=``, ``jit=``, ``max_iter=``, ``cold_guess=``, ...:
            every field of :class:`~seagul_control.mpc.MPCOptions`) still work; each moves into the options with a
            ``DeprecationWarning``.

    The solver choice: ``"shooting"`` condenses the lookahead to its inputs and solves it by projected Newton
    (:mod:`seagul_control.shooting`; fixed steps and input bounds only; a value network enters through its
    hand-derived Taylor forms): the same NLP, measured ~10x faster per step than fatrop on the acrobot with the
    shipped 3 x (2 x 64) ensemble (docs/experiments/mpc.md). ``max_solve_time``: IPOPT stops itself
    (``ipopt.max_wall_time``); fatrop cannot (its regularisation loop is unbounded) and runs in a forked child that
    is killed (:mod:`seagul_control._watchdog`, ~0.1 ms per step). ``cold_guess``: at long horizons the rollout alone
    is a poor guess for an unstable system: 20 zero-input steps of the acrobot are a 2 s fall, from which fatrop
    converged to a swing-around plan (objective 33-45 where the 10-step plan costs 0.01-5.6) or failed
    (docs/method/mpc.md). ``final_soft_weight``: the glider's 1e4 was measured: 1 fallback step in 1,152 on the
    6 x 6 grid instead of 337, mean cost 347 against 483, the same perch rate. ``multistart``: measured on a
    ``closed-loop+select`` acrobot network (``acrobot_closed-loop_select_b2000_seed0.pt``, docs/experiments/mpc.md):
    grid success 94.5 % -> 98.5 % with ``"rise"`` (extra starts on ~5 % of steps) or ``"always"`` (~10x the step
    time).

    A value function over robots (``n_params > 0``, e.g. a network trained with ``TrainConfig.model_params``) is
    evaluated at the robot the MPC plans for: the task's own parameters, or those of :meth:`set_robot`.

    :meth:`save` writes the controller to one file and :meth:`load` rebuilds it without torch
    (:mod:`seagul_control.mpc.saving`).
    """

    name = "LimitedLookaheadMPC"

    def __init__(
        self,
        task: Task,
        value_function: CasadiValueFunction | None,
        horizon: int,
        options: MPCOptions | None = None,
        *,
        trust_region: TrustRegion | None = None,
        model_params: bool = False,
        estimate_robot: bool | dict[str, Any] = False,
        **deprecated: Any,
    ) -> None:
        options = merge_deprecated(self.name, MPCOptions, options, deprecated)
        if trust_region is not None:
            options = options.replace(trust_region=trust_region)
        if model_params and task.parameters is None:
            raise ValueError(f"{self.name}: model_params=True needs a task that declares which parameters vary")
        if estimate_robot is not False and not model_params:
            raise ValueError(f"{self.name}: estimate_robot needs model_params=True (the plan uses the estimate)")
        if isinstance(horizon, bool) or not isinstance(horizon, (int, np.integer)) or int(horizon) < 1:
            raise ValueError(f"{self.name}: horizon must be an integer >= 1 step, got {horizon!r}")
        self.horizon = int(horizon)
        steps = options.steps
        has_box = bool(np.any(np.isfinite(task.x_final_low)) or np.any(np.isfinite(task.x_final_high)))
        equilibrium = task.goal_is_equilibrium(cost=True)
        # ----- the task's defaults
        resolved: dict[str, Any] = {}
        if options.end_phase is None:
            resolved["end_phase"] = "shrink" if has_box else "switch"
        if options.trust_region is None:
            resolved["trust_region"] = task.profile.mpc.trust_region
        if options.cold_guess is None:
            resolved["cold_guess"] = "best" if steps == "fixed" else "rollout"
        if options.anchor_goal is None:
            resolved["anchor_goal"] = equilibrium
        if options.goal_blend is None:
            resolved["goal_blend"] = float(task.profile.mpc.goal_blend) if equilibrium else 0.0
        if options.final_soft_weight is None:
            weight = task.profile.mpc.final_soft_weight
            resolved["final_soft_weight"] = 0.0 if weight is None else weight  # 0: a hard box
        try:
            options = options.replace(**resolved)
        except ValueError as exc:
            raise ValueError(f"{self.name}: the task's default is invalid ({exc})") from exc
        end_phase, trust_weight = options.end_phase, options.trust_weight
        super().__init__(task, options.dt, options.warm_start, options.cold_guess or "best")
        self.model_params = bool(model_params)
        self.estimate_robot: bool | dict[str, Any] = estimate_robot
        """As given (saved with the controller)."""
        self._estimator_options: dict[str, Any] | None = None
        if estimate_robot is not False:
            self._estimator_options = {} if estimate_robot is True else dict(estimate_robot)
        self._estimators: dict[int, ParameterEstimator] = {}
        """One estimator per env (env 0's built here: bad options fail at construction), reset per episode."""
        if self._estimator_options is not None:
            self._estimators[0] = ParameterEstimator(task, self.dt, **self._estimator_options)
        self._last_step: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.trust_region = options.trust_region or "none"
        self.trust_weight = float(trust_weight)
        self.clamp = options.clamp
        self.anchor_goal = bool(options.anchor_goal)
        if self.anchor_goal and not equilibrium:
            raise ValueError(f"{self.name}: anchor_goal needs a goal that is a zero-cost equilibrium of the task")
        self.goal_blend = float(options.goal_blend or 0.0)
        if self.goal_blend > 0 and not equilibrium:
            raise ValueError(f"{self.name}: goal_blend needs a goal that is a zero-cost equilibrium of the task")
        self._configure_solver(options, steps == "free")
        if options.multistart not in (None, "never") and self.solver != "shooting":
            raise ValueError(
                f"{self.name}: multistart={options.multistart!r} needs solver='shooting', not {self.solver!r}"
            )
        self.multistart = (
            ("rise" if self.solver == "shooting" else "never") if options.multistart is None else options.multistart
        )
        self.multistart_starts = options.multistart_starts

        self.free_time = steps == "free"
        self._vf_fn = None
        self._vf_theta = np.zeros(0)
        self._vf_robots = None
        """A private copy of a value function over robots (re-conditioned by :meth:`set_robot`), else None."""
        self._anchor_cache = {}
        n_vf = 0
        self._vf_taylor = None
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
        self._value_function = value_function
        if value_function is not None:
            box = options.trust_box
            self.set_value_function(
                value_function, trust_box=None if box is None else (np.asarray(box[0]), np.asarray(box[1]))
            )

        final_solver = options.final_solver
        self.final_soft_weight = float(options.final_soft_weight) if options.final_soft_weight else None
        if self.final_soft_weight is not None and final_solver is None:
            final_solver = "ipopt"  # soft bounds need IPOPT (slack variables)
        if self.final_soft_weight is not None and final_solver != "ipopt":
            raise ValueError(f"{self.name}: final_soft_weight needs final_solver='ipopt', got {final_solver!r}")
        if final_solver is None and self.solver == "shooting" and has_box and options.final_box:
            final_solver = "fatrop"  # the final phase imposes the terminal box: not a condensable problem
        self.final_solver: SolverName = self.solver if final_solver is None else final_solver
        self.end_phase = end_phase
        self.final_box = options.final_box
        self.substeps = options.substeps
        self.options: MPCOptions = options.replace(
            dt=self.dt, solver=self.solver, multistart=self.multistart, final_solver=self.final_solver
        )
        """The options with every task-dependent default resolved (what :meth:`save` stores)."""
        self._final_fixed: dict[int, _Problem] = {}
        self._final: _Problem | None = None
        common: dict[str, Any] = {
            "horizon": self.horizon,
            "terminal_cost": terminal,
            "terminal_model": terminal_model,
            "n_theta": n_theta,
            "substeps": self.substeps,
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
        # The lookahead never imposes the terminal box (final_box=False) and has hard bounds.
        problems = condensation_problems(self.task, free_time=free_time, final_box=False, soft_bounds=False)
        condensable = not problems and self.horizon <= self.SHOOTING_MAX_HORIZON
        return "shooting" if condensable else super().default_solver(free_time)

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

    # ------------------------------------------------------------------ saving
    @property
    def value_function(self) -> CasadiValueFunction | None:
        """The value function given at construction or by the last :meth:`set_value_function` (None: ``l_f``)."""
        return self._value_function

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the controller to one zip file (:func:`seagul_control.mpc.saving.save_mpc`); returns the path."""
        return save_mpc(self, path)

    @classmethod
    def load(cls, path: str | os.PathLike[str], task: Task | None = None) -> LimitedLookaheadMPC:
        """Rebuild a controller written by :meth:`save`, without torch (:func:`seagul_control.mpc.saving.load_mpc`;
        ``task``: default ``seagul_envs.make_task`` of the stored name; its fingerprint must match)."""
        mpc = load_mpc(path, task)
        if not isinstance(mpc, cls):
            raise ValueError(f"{os.fspath(path)!r} holds a {type(mpc).__name__}, not a {cls.__name__}")
        return mpc
