"""What the three DeepMind Control Suite tasks share: the success rule (the suite's own reward at the final state)
and the assembly of a :class:`~seagul_envs.tasks.base.Task` from a :class:`~seagul_envs.tasks.dmc.mechanics.ChainModel`
and a cost."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from seagul_envs.tasks.base import Task
from seagul_envs.tasks.dmc.mechanics import ChainModel, discrete_lqr_cost_to_go, wrapped_quadratic
from seagul_envs.tasks.profile import TaskProfile

RewardFunction = Callable[[Any, np.ndarray, np.ndarray], float]
"""``reward(params, x, u) -> float``: a suite task's reward at state ``x`` and control ``u``, computed from the task's
own kinematics exactly as dm_control computes it from ``physics`` (checked in ``tests/test_dmc_tasks.py``)."""


@dataclass(frozen=True)
class SuiteRewardSuccess:
    """Success of a seagul episode on a suite task: the suite's reward at the final state with zero control is at
    least ``threshold``, and the episode did not leave the state bounds.

    A picklable callable ``(task, x_final, terminated) -> bool`` (:attr:`TaskProfile.success`): angles are periodic,
    so the library's Euclidean :class:`~seagul_envs.tasks.profile.SuccessRule` (``x - x*`` without wrapping) would
    call an upright pendulum at ``2 pi`` a failure. The benchmark's score is dm_control's own return; this rule only
    decides the seagul evaluation's success rate.
    """

    reward: RewardFunction
    """The task's reward function (module-level, so the rule pickles)."""
    threshold: float
    """Smallest final reward that counts as a success."""

    def __call__(self, task: Task, x: Any, terminated: bool = False) -> bool:
        """Whether an episode of ``task`` that ended in ``x`` (``terminated``: by leaving the bounds) succeeded."""
        if terminated:
            return False
        x = np.asarray(x, dtype=np.float64)
        return bool(self.reward(task.params, x, np.zeros(task.nu)) >= self.threshold)


@dataclass(frozen=True)
class TaskSpec:
    """The parts of a suite task that differ between the domains (everything :func:`build_dmc_task` needs)."""

    name: str
    """Registry name (``"dmc_pendulum"``)."""
    state_names: tuple[str, ...]
    """``qpos`` then ``qvel`` names, in MuJoCo's joint order."""
    control_name: str
    """The actuator's name."""
    model: ChainModel
    """The MJCF's mechanics."""
    stage_cost: Callable[[ca.SX, ca.SX], ca.SX]
    """``l(x, u)``: the smooth surrogate of the suite's reward (cost per second)."""
    angles: tuple[int, ...]
    """State indices of the hinge angles: :attr:`Task.periodic` (unbounded, wrapped in the terminal cost and in the
    library's ``x - x*``)."""
    x_low: np.ndarray
    """Path-state lower bounds."""
    x_high: np.ndarray
    """Path-state upper bounds."""
    x0_low: np.ndarray
    """X0's lower corner (the suite's reset distribution)."""
    x0_high: np.ndarray
    """X0's upper corner."""
    tau: float
    """Time to go of the full-horizon problem (s)."""
    horizon_steps: int
    """Transcription intervals."""
    rk4_substeps: int
    """RK4 substeps per interval."""
    n_sub_steps: int
    """MuJoCo steps per suite control step (``control.Environment``'s ``n_sub_steps``)."""
    success: SuiteRewardSuccess
    """The success rule."""
    success_text: str
    """It in one line for reports."""
    params: Any
    """The domain's parameter dataclass."""
    suite: tuple[str, str]
    """``(domain, task)`` of ``dm_control.suite.load``."""


def build_dmc_task(spec: TaskSpec) -> Task:
    """The :class:`Task` of ``spec``: dynamics = the MJCF's, stage cost = the surrogate, terminal cost = the
    wrapped LQR cost to go at the goal (:func:`~seagul_envs.tasks.dmc.mechanics.wrapped_quadratic` of the discrete
    Riccati solution for the transcription's own RK4, stage weights = half the stage cost's Hessian at the goal),
    control period = the suite's control step, the simulator's RK4 substep = MuJoCo's timestep."""
    model = spec.model
    nx = 2 * model.nq
    name = spec.name
    x, u = ca.SX.sym("x", nx), ca.SX.sym("u", 1)
    dynamics = ca.Function(f"{name}_f", [x, u], [model.xdot(x, u)], ["x", "u"], ["xdot"])
    stage = spec.stage_cost(x, u)
    stage_cost = ca.Function(f"{name}_l", [x, u], [stage], ["x", "u"], ["l"])

    goal = np.zeros(nx)  # every suite task's target: upright, at rest (cart centred)
    hessians = ca.Function(f"{name}_l_hessians", [x, u], [ca.hessian(stage, x)[0], ca.hessian(stage, u)[0]])
    Hx, Hu = (np.asarray(m) for m in hessians(goal, np.zeros(1)))
    Q, R = 0.25 * (Hx + Hx.T), 0.5 * Hu  # l = e' Q e + R u^2 + ... near the goal: half the (symmetrised) Hessian
    h = spec.tau / spec.horizon_steps
    P = discrete_lqr_cost_to_go(dynamics, goal, spec.rk4_substeps, h, Q, R, name)
    terminal_cost = ca.Function(f"{name}_lf", [x], [wrapped_quadratic(x, P, spec.angles)], ["x"], ["lf"])

    control_period = spec.n_sub_steps * model.timestep
    lo, hi = model.ctrl_range
    inf = np.full(nx, np.inf)
    profile = TaskProfile(
        success=spec.success,
        success_text=spec.success_text,
        success_goal=f"reach the suite's goal ({spec.success_text})",
        lqr_Q=Q,
        lqr_R=R,
    )
    return Task(
        name=name,
        state_names=spec.state_names,
        control_names=(spec.control_name,),
        dynamics=dynamics,
        stage_cost=stage_cost,
        terminal_cost=terminal_cost,
        goal=goal,
        u_low=np.array([lo]),
        u_high=np.array([hi]),
        x_low=spec.x_low,
        x_high=spec.x_high,
        x_final_low=-inf,
        x_final_high=inf,
        x0_low=spec.x0_low,
        x0_high=spec.x0_high,
        tau_range=(spec.tau, spec.tau),
        tau_nominal=spec.tau,
        num_steps=spec.horizon_steps,
        step_bounds=(h, h),
        fixed_step=True,
        rk4_substeps=spec.rk4_substeps,
        control_period=control_period,
        max_sim_substep=model.timestep,
        params=spec.params,
        extras={
            "Q": Q,
            "R": R,
            "Qf": P,
            "suite": spec.suite,
            "n_sub_steps": spec.n_sub_steps,
            **model.functions(name),
        },
        profile=profile,
        periodic=spec.angles,
    )
