"""Online estimates of a robot's physical parameters from its observed transitions (docs/reference/spec.md §14).

A controller that meets a robot other than its model (``Task.parameters``: masses, lengths, damping, areas) can
plan for an estimate of the true ``theta`` instead of the nominal one. :class:`ParameterEstimator` fits ``theta``
to the last ``window`` transitions ``(x_i, u_i) -> x_{i+1}`` of one episode by regularised least squares on the
task's own one-period map (the simulator's RK4 with its substeps, at ``theta``)::

    theta_hat = argmin_{theta in Theta_k}  sum_i |W (F(x_i, u_i, dt, theta) - x_{i+1})|^2
                                       + prior * |(theta - theta_0) / width(Theta)|^2

(``Theta_k``: the declared box widened ``box_scale`` times in ratio about ``theta_0``, so that a robot outside the
declared box is still estimated where it is)

``W`` scales each state coordinate by the width of X0 (1 where that is 0), ``theta_0`` is the task's own robot,
and the problem is solved by a few projected Gauss-Newton steps from the previous estimate (the residual's
Jacobian in ``theta`` from CasADi, built once). The prior keeps parameters that the data do not determine (a
resting acrobot says little about its masses) at their nominal values. It is a one-step-ahead prediction-error
fit: exact data of the model family give the true ``theta`` back (tested), noise or unmodelled effects bias it.
"""

from __future__ import annotations

from collections import deque
from typing import Any

import casadi as ca
import numpy as np

from seagul_control.codegen import compile_nlp_library
from seagul_envs.tasks.base import Task


class ParameterEstimator:
    """Least-squares estimate of ``theta`` from an episode's recent transitions (module docstring).

    Args:
        task: the task (its ``parameters`` declare ``theta`` and the box Theta).
        dt: the control period of the transitions (default: the task's).
        window: transitions kept (the most recent). Keep the whole informative part of an episode: a window
            shorter than the swing forgets the transitions that determine ``theta``, and near rest the data leave
            parameters undetermined, so the prior pulls them back to the model's (a 20-transition window ended the
            acrobot's episodes with errors up to half the box; docs/experiments/robust.md).
        prior: weight of the pull towards the task's own parameters, per squared box width (None: the task's
            :attr:`~seagul_envs.tasks.parameters.ParameterSpace.estimator_prior`, 1e-3 unless the task says
            otherwise).
        iterations: Gauss-Newton steps per :meth:`update`.
        box_scale: the estimate is kept inside Theta widened by this factor about the model's values
            (:meth:`~seagul_envs.tasks.parameters.ParameterSpace.scaled`; 1: Theta itself), so that a robot
            outside the declared box is still estimated where it is: on acrobots drawn from twice the box the
            10-step learned MPC goes from 18 % (estimate confined to Theta) to 72 % at 3, and on robots from
            Theta it is unchanged (docs/experiments/robust.md).
        min_transitions: no estimate (the task's own ``theta``) before this many transitions (None: the task's
            :attr:`~seagul_envs.tasks.parameters.ParameterSpace.estimator_min_transitions`, 3 unless the task says
            otherwise).
        codegen: evaluate the one-period map and its Jacobian from compiled C (generated once per task and cached
            on disk, :func:`seagul_control.codegen.compile_nlp_library`); CasADi's virtual machine when False or
            when no C compiler is found. Compiled, an update over 50 acrobot transitions takes about 1 ms instead of
            about 15 ms.
    """

    def __init__(
        self,
        task: Task,
        dt: float | None = None,
        window: int = 100,
        prior: float | None = None,
        box_scale: float = 3.0,
        iterations: int = 3,
        min_transitions: int | None = None,
        codegen: bool = True,
    ) -> None:
        if task.parameters is None:
            raise ValueError(f"{task.name}: a ParameterEstimator needs a task that declares its parameters")
        if min_transitions is None:
            min_transitions = task.parameters.estimator_min_transitions
        if window < 1 or iterations < 1 or min_transitions < 1:
            raise ValueError(
                f"window, iterations and min_transitions must be >= 1, got {window}, {iterations}, {min_transitions}"
            )
        if prior is None:
            prior = task.parameters.estimator_prior
        if not (np.isfinite(prior) and prior > 0):
            raise ValueError(f"prior must be a positive number, got {prior!r}")
        self.task = task
        self.space = task.parameters
        self.limits = self.space.scaled(box_scale, task.theta) if box_scale != 1.0 else self.space
        self.dt = float(task.control_period if dt is None else dt)
        self.window = int(window)
        self.prior = float(prior)
        self.iterations = int(iterations)
        self.min_transitions = int(min_transitions)
        self.theta0 = task.theta
        width = self.space.high - self.space.low
        self._width = np.where(width > 0, width, np.maximum(np.abs(self.theta0), 1.0))
        x_width = task.x0_high - task.x0_low
        self._w = 1.0 / np.where(x_width > 0, x_width, 1.0)
        step = task.rk4_step_params(task.simulator_substeps(self.dt))
        x, u, th = ca.SX.sym("x", task.nx), ca.SX.sym("u", task.nu), ca.SX.sym("theta", self.space.size)
        nxt = step(x, u, self.dt, th)
        self._f = ca.Function("estimator_step", [x, u, th], [nxt, ca.jacobian(nxt, th)])
        if codegen:
            try:
                lib = compile_nlp_library((self._f,), "estimator_step", fingerprint=task.fingerprint())
            except RuntimeError:  # no C compiler (or it failed): the virtual machine gives the same numbers
                pass
            else:
                self._f = ca.external("estimator_step", str(lib))
        self._maps: dict[int, ca.Function] = {}  # one evaluation of every kept transition per call, by count
        self._history: deque[tuple[np.ndarray, np.ndarray, np.ndarray]] = deque(maxlen=self.window)
        self.theta = self.theta0.copy()
        """The current estimate (the task's own parameters until :attr:`min_transitions` transitions)."""

    def reset(self) -> None:
        """Forget the episode: the estimate goes back to the task's own parameters."""
        self._history.clear()
        self.theta = self.theta0.copy()

    def __len__(self) -> int:
        return len(self._history)

    def residual(self, theta: Any) -> float:
        """The weighted sum of squared one-step prediction errors over the window at ``theta``."""
        th = np.asarray(theta, dtype=float)
        return float(
            sum(np.sum((self._w * (np.asarray(self._f(x, u, th)[0]).ravel() - xn)) ** 2) for x, u, xn in self._history)
        )

    def update(self, x: Any, u: Any, x_next: Any) -> np.ndarray:
        """Add the transition ``x --u--> x_next`` (one control period) and return the new estimate."""
        x = np.asarray(x, dtype=float).reshape(self.task.nx)
        u = np.asarray(u, dtype=float).reshape(self.task.nu)
        x_next = np.asarray(x_next, dtype=float).reshape(self.task.nx)
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(u)) and np.all(np.isfinite(x_next))):
            return self.theta.copy()  # a broken transition says nothing about the robot
        self._history.append((x, u, x_next))
        if len(self._history) < self.min_transitions:
            return self.theta.copy()
        theta = self.theta.copy()
        k = self.space.size
        reg = np.sqrt(self.prior) / self._width
        xs, us, xns = (np.array([t[i] for t in self._history]) for i in range(3))
        n = len(xs)
        fmap = self._maps.get(n)
        if fmap is None:
            fmap = self._maps[n] = self._f.map(n)
        for _ in range(self.iterations):
            pred, jac = fmap(xs.T, us.T, np.tile(theta[:, None], (1, n)))
            res = (self._w[:, None] * (np.asarray(pred) - xns.T)).T.ravel()  # transition-major, as the rows below
            # the mapped Jacobian is [J_0 | J_1 | ...], each nx x k
            jac_t = np.asarray(jac).reshape(self.task.nx, n, k).transpose(1, 0, 2) * self._w[None, :, None]
            jac_all = np.vstack([np.diag(reg), jac_t.reshape(n * self.task.nx, k)])
            r_all = np.concatenate([reg * (theta - self.theta0), res])
            step, *_ = np.linalg.lstsq(jac_all, -r_all, rcond=None)
            new = np.clip(theta + step, self.limits.low, self.limits.high)
            if not np.all(np.isfinite(new)):
                break
            done = float(np.max(np.abs(new - theta) / self._width)) < 1e-7  # far below any effect on control
            theta = new
            if done:
                break
        self.theta = theta
        return theta.copy()
