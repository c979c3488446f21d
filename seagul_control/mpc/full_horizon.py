"""The full-horizon MPC: the upper reference that re-solves the task's whole remaining problem at every step."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from seagul_control._options import merge_deprecated
from seagul_control.mpc.base import _MPCBase, _Problem
from seagul_control.mpc.options import FullHorizonOptions
from seagul_control.mpc.saving import load_mpc, save_mpc
from seagul_envs.tasks.base import Task


class FullHorizonMPC(_MPCBase):
    """The upper reference: the task's full problem re-solved at every step from the current state.

    Fixed-step tasks (acrobot): ``round(tau_now / dt)`` steps of ``dt`` and ``l_f`` (a solver per remaining
    horizon, built lazily and kept). Free-time tasks (glider): ``task.num_steps`` steps with ``sum(h) = tau_now``,
    ``h_k in [0, h_max]``, the first step pinned to ``min(dt, tau_now)``, the terminal box and ``l_f`` (one solver).
    Options: :class:`~seagul_control.mpc.FullHorizonOptions` (the old keyword arguments, ``dt=``, ``solver=``,
    ..., still work and warn); ``horizon`` (default the task's ``num_steps``) and ``model_params`` (the solvers take
    the robot's physical parameters, :meth:`set_robot`) stay keywords. JIT is off by default (compiling the long
    problem takes minutes). ``max_solve_time`` defaults to 60 s, not the lookahead's 5 s: the reference is not a
    real-time controller, and a limit that a loaded machine reaches made its episodes depend on the load (glider
    from its far corner: cost 422 idle; 508-726 under load 10 on 2 cores, where its steps took 0.5-7.5 s and hit
    5 s). 60 s still stops a hung solve. :meth:`save` / :meth:`load` write and rebuild it
    (:mod:`seagul_control.mpc.saving`).
    """

    name = "FullHorizonMPC"

    def __init__(
        self,
        task: Task,
        options: FullHorizonOptions | None = None,
        *,
        horizon: int | None = None,
        model_params: bool = False,
        **deprecated: Any,
    ) -> None:
        options = merge_deprecated(self.name, FullHorizonOptions, options, deprecated)
        super().__init__(task, options.dt, options.warm_start, options.cold_guess)
        self._configure_solver(options, not task.fixed_step)
        if model_params and task.parameters is None:
            raise ValueError(f"{self.name}: model_params=True needs a task that declares which parameters vary")
        self.model_params = bool(model_params)
        self.substeps = options.substeps
        self.free_time = not task.fixed_step
        self.horizon = int(task.num_steps if horizon is None else horizon)
        if self.horizon < 1:
            raise ValueError(f"{self.name}: horizon must be >= 1, got {horizon!r}")
        self.options: FullHorizonOptions = options.replace(dt=self.dt, solver=self.solver)
        """The options with the task-dependent defaults (``dt``, ``solver``) resolved."""
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
                substeps=self.substeps,
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

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the controller to one zip file (options, horizon, the task's fingerprint); returns the path."""
        return save_mpc(self, path)

    @classmethod
    def load(cls, path: str | os.PathLike[str], task: Task | None = None) -> FullHorizonMPC:
        """Rebuild a controller written by :meth:`save` (``task``: default ``make_task`` of the stored name)."""
        mpc = load_mpc(path, task)
        if not isinstance(mpc, cls):
            raise ValueError(f"{os.fspath(path)!r} holds a {type(mpc).__name__}, not a {cls.__name__}")
        return mpc
