"""A toy "trajectory optimizer" with a known value function, so learning code is tested fast and exactly.

``V(x, tau) = (x - g)' P (x - g) * (1 + tau) + bump * exp(-|x - c|^2 / (2 w^2))`` over the task's X0 with
``g`` the task's goal. A "solve" returns the knots of a fixed decaying trajectory
``x_k = g + (x_init - g) * exp(-2 k / m)`` with ``tau_k = tau (1 - k/m)`` and exact labels ``V(x_k, tau_k)``,
``dV/dx(x_k, tau_k)``: exactly what the real optimizer's SolveResult carries, without an NLP.
"""

from __future__ import annotations

import numpy as np

from seagul_envs import Task
from seagul_learn.results import SolveResult


class ToySolver:
    """Known-value "solver"; counts solves, can fail in a region and can crash after a number of solves."""

    def __init__(
        self,
        task: Task,
        num_steps: int = 10,
        bump: float = 5.0,
        fail_above: float | None = None,
        raise_after: int | None = None,
    ) -> None:
        self.task = task
        self.m = num_steps
        width = np.where(task.x0_high > task.x0_low, task.x0_high - task.x0_low, 1.0)
        self.P = np.diag(1.0 / width**2)
        self.center = task.x0_low + 0.8 * (task.x0_high - task.x0_low)
        self.bump_width = width * 0.15
        self.bump = bump
        self.fail_above = fail_above
        self.raise_after = raise_after
        self.num_solves = 0
        self.calls: list[tuple[np.ndarray, float]] = []

    # known function and its gradients
    def value(self, x: np.ndarray, tau: float) -> float:
        e = x - self.task.goal
        d = (x - self.center) / self.bump_width
        return float(e @ self.P @ e * (1 + tau) + self.bump * np.exp(-0.5 * d @ d))

    def grad_x(self, x: np.ndarray, tau: float) -> np.ndarray:
        e = x - self.task.goal
        d = (x - self.center) / self.bump_width
        return 2 * self.P @ e * (1 + tau) - self.bump * np.exp(-0.5 * d @ d) * d / self.bump_width

    def grad_tau(self, x: np.ndarray) -> float:
        e = x - self.task.goal
        return float(e @ self.P @ e)

    def solve(self, x_init: np.ndarray, tau: float | None = None) -> SolveResult:
        if self.raise_after is not None and self.num_solves >= self.raise_after:
            raise KeyboardInterrupt(f"toy solver interrupted after {self.num_solves} solves")
        x_init = np.asarray(x_init, dtype=np.float64)
        tau = self.task.tau_nominal if tau is None else float(tau)
        self.num_solves += 1
        self.calls.append((x_init.copy(), tau))
        k = np.arange(self.m + 1)
        states = self.task.goal + (x_init - self.task.goal) * np.exp(-2.0 * k / self.m)[:, None]
        ttg = tau * (1 - k / self.m)
        nx = self.task.nx
        failed = self.fail_above is not None and x_init[0] > self.fail_above
        values = np.array([self.value(s, t) for s, t in zip(states, ttg, strict=True)])
        grads = np.array([self.grad_x(s, t) for s, t in zip(states, ttg, strict=True)])
        return SolveResult(
            x_init=x_init.copy(),
            tau=tau,
            success=not failed,
            status="Infeasible_Problem_Detected" if failed else "Solve_Succeeded",
            value=float("nan") if failed else values[0],
            grad_x=np.full(nx, np.nan) if failed else grads[0],
            grad_tau=float("nan") if failed else self.grad_tau(x_init),
            states=states,
            controls=np.zeros((self.m, 1)),
            steps=np.full(self.m, tau / self.m),
            time_to_go=ttg,
            cost_to_go=values,
            knot_grads=grads,
            iterations=3,
            solve_time=0.001,
        )

    def __call__(self, starts: np.ndarray, taus: np.ndarray) -> list[SolveResult]:
        """The batch interface used by samplers and training."""
        return [self.solve(x, t) for x, t in zip(np.atleast_2d(starts), np.asarray(taus).reshape(-1), strict=True)]


class ToyRobotSolver(ToySolver):
    """The toy over robots: ``V(x, tau, theta) = V(x, tau) * (1 + c' (theta - theta0) / theta0)`` with ``theta0``
    the task's own parameters, so ``dV/dtheta = V(x, tau) * c / theta0`` at every knot (the shape the real
    optimizer's ``grad_theta`` and ``knot_grad_theta`` have)."""

    def __init__(self, task: Task, **kwargs: object) -> None:
        super().__init__(task, **kwargs)  # type: ignore[arg-type]
        assert task.parameters is not None
        self.theta0 = task.theta
        self.c = np.linspace(0.5, -0.5, task.parameters.size)
        self.theta_calls: list[np.ndarray] = []

    def scale(self, theta: np.ndarray) -> float:
        return float(1.0 + self.c @ ((theta - self.theta0) / self.theta0))

    def solve_robot(self, x_init: np.ndarray, tau: float, theta: np.ndarray) -> SolveResult:
        base = self.solve(x_init, tau)
        theta = np.asarray(theta, dtype=np.float64)
        self.theta_calls.append(theta.copy())
        s = self.scale(theta)
        per_value = base.cost_to_go.copy()
        base.value, base.cost_to_go = base.value * s, base.cost_to_go * s
        base.grad_x, base.knot_grads, base.grad_tau = base.grad_x * s, base.knot_grads * s, base.grad_tau * s
        base.theta = theta.copy()
        base.knot_grad_theta = per_value[:, None] * (self.c / self.theta0)[None, :]
        base.grad_theta = base.knot_grad_theta[0].copy()
        return base

    def __call__(  # type: ignore[override]
        self, starts: np.ndarray, taus: np.ndarray, thetas: np.ndarray | None = None
    ) -> list[SolveResult]:
        if thetas is None:
            raise AssertionError("a run over robots must pass one theta per start")
        rows = zip(np.atleast_2d(starts), np.asarray(taus).reshape(-1), np.atleast_2d(thetas), strict=True)
        return [self.solve_robot(x, t, th) for x, t, th in rows]
