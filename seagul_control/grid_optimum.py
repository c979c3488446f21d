"""The optimum of the DeepMind Control Suite's ``pendulum-swingup`` by dynamic programming on a grid of its state.

The pendulum's state is two numbers (hinge angle, hinge velocity), so its optimal control problem can be solved
without a learned value and without trajectory optimisation's local minima: value iteration over a grid of the whole
state space with the suite's own step and reward gives, up to the grid's resolution, the **best score any
controller can reach**. It is the yardstick of the pendulum's row in ``benchmarks/results/dmc.json``: how far from
optimal the learned MPC, the classical swing-up and the RL agents are, and whether a published score can be beaten
at all on the same episodes.

What it solves (Bellman's recursion, finite horizon, no discount: the suite's score is an undiscounted sum)::

    V_0(x) = 0,    V_{k+1}(x) = max_{u in A} [ r(f(x, u)) + V_k(f(x, u)) ],

with ``f`` one suite control step (``task.extras["mujoco_step"]``: MuJoCo's semi-implicit Euler step of the MJCF,
the control clamped to ``[-1, 1]``), ``r`` dm_control's reward after that step (1 within 8 degrees of upright,
else 0; dm_control rewards the state the step reaches) and ``A`` :attr:`GridSpec.actions` evenly spaced torques in
``[-1, 1]``. ``V_k(x)`` is the most reward collectable in ``k`` control steps from ``x``. It is stored at the nodes
of a grid periodic in the angle (:attr:`GridSpec.angle_cells` cells over ``[-pi, pi)``) and clipped in the velocity
(:attr:`GridSpec.velocity_points` nodes over ``[-velocity_max, velocity_max]``; the swing-up's fastest motion is
about 9 rad/s), and read between nodes by bilinear interpolation (a semi-Lagrangian scheme: each backup evaluates
``f`` from every node exactly and interpolates ``V_k`` where it lands).

The controller [choice]: ``u(x) = argmax_u r(f(x, u)) + V_K(f(x, u))`` over :attr:`GridSpec.policy_actions` torques
(finer than the backups'), with ``K`` = :attr:`GridSpec.backups` at every step of the episode. The optimal policy
of the 1,000-step episode depends on the steps left, but once ``K`` exceeds the longest swing-up (about 7 s = 350
steps from the suite's starts) ``V_{K+1} - V_K`` is 1 wherever the goal is reachable, the greedy action no longer
changes with ``K``, and the stationary policy is optimal up to the last ``K`` steps' end effects (none: holding the
top is optimal to the end). Its accuracy is a matter of the grid, measured by refining it
(``benchmarks/bench_dmc_optimum.py``, docs/experiments/dmc-learned.md).

Usage::

    from seagul_control.dmc import run_dmc_episode
    from seagul_control.grid_optimum import GridOptimum, GridSpec

    optimum = GridOptimum(GridSpec(angle_cells=720, velocity_points=401)).solve()
    episode = run_dmc_episode("pendulum-swingup", optimum, seed=0)
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from seagul_envs import make_task


@dataclass(frozen=True)
class GridSpec:
    """The grid, the action sets and the number of backups of :class:`GridOptimum` (module docstring)."""

    angle_cells: int = 720
    """Grid cells over the hinge angle's period ``[-pi, pi)`` (0.5 degree each by default)."""
    velocity_points: int = 401
    """Grid nodes over ``[-velocity_max, velocity_max]`` (0.05 rad/s apart by default)."""
    velocity_max: float = 10.0
    """Largest hinge speed on the grid (rad/s); faster states are read at the edge."""
    actions: int = 11
    """Torques evenly spaced in ``[-1, 1]`` in each backup."""
    backups: int = 600
    """``K``: Bellman backups (control steps to go) of the value the controller reads (12 s)."""
    policy_actions: int = 41
    """Torques evenly spaced in ``[-1, 1]`` the controller chooses from."""

    def __post_init__(self) -> None:
        for name, least in (
            ("angle_cells", 4),
            ("velocity_points", 2),
            ("actions", 2),
            ("backups", 1),
            ("policy_actions", 2),
        ):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < least:
                raise ValueError(f"GridSpec.{name} must be an integer >= {least}, got {value!r}")
        if not (math.isfinite(self.velocity_max) and self.velocity_max > 0):
            raise ValueError(f"GridSpec.velocity_max must be a finite number > 0, got {self.velocity_max!r}")


class GridOptimum:
    """Value iteration for ``pendulum-swingup`` and its greedy controller ``(x, t) -> action`` (module docstring).

    :meth:`solve` runs the backups; :meth:`value` reads ``V_K`` anywhere; calling the object is the controller of
    :func:`seagul_control.dmc.run_dmc_episode` (``x = [hinge, hinge_vel]``, the physics state)."""

    name = "grid optimum"

    def __init__(self, spec: GridSpec | None = None) -> None:
        self.spec = spec or GridSpec()
        self.task = make_task("dmc_pendulum")
        p = self.task.params
        self.cone = math.cos(math.radians(p.angle_bound_deg))
        self.step = self.task.extras["mujoco_step"]
        s = self.spec
        self.angles = np.linspace(-np.pi, np.pi, s.angle_cells, endpoint=False)
        self.velocities = np.linspace(-s.velocity_max, s.velocity_max, s.velocity_points)
        self.values: np.ndarray | None = None
        """``V_K`` at the grid's nodes, shape ``(angle_cells, velocity_points)`` (None before :meth:`solve`)."""
        self.backups_done = 0
        self._policy_u = np.linspace(-1.0, 1.0, s.policy_actions)
        self._policy_step = self.step.map(s.policy_actions)

    # ------------------------------------------------------------------------------------------- the grid
    def _corners(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Flat indices ``(4, n)`` of the grid nodes around the states ``x`` (shape ``(2, n)``) and their bilinear
        weights ``(4, n)``: periodic in the angle, clipped in the velocity."""
        s = self.spec
        dq = 2 * np.pi / s.angle_cells
        a = np.mod(np.asarray(x[0]) + np.pi, 2 * np.pi) / dq
        i0 = np.floor(a).astype(np.int64)
        fa = a - i0
        i0 %= s.angle_cells
        i1 = (i0 + 1) % s.angle_cells
        dv = 2 * s.velocity_max / (s.velocity_points - 1)
        v = (np.clip(np.asarray(x[1]), -s.velocity_max, s.velocity_max) + s.velocity_max) / dv
        v = np.clip(v, 0.0, s.velocity_points - 1 - 1e-9)
        j0 = np.floor(v).astype(np.int64)
        fv = v - j0
        j1 = j0 + 1
        n = s.velocity_points
        index = np.stack([i0 * n + j0, i0 * n + j1, i1 * n + j0, i1 * n + j1])
        weight = np.stack([(1 - fa) * (1 - fv), (1 - fa) * fv, fa * (1 - fv), fa * fv])
        return index, weight

    def _reward(self, x: np.ndarray) -> np.ndarray:
        """dm_control's reward at the states ``x`` (shape ``(2, n)``): 1 within the cone, else 0."""
        return (np.cos(np.asarray(x[0])) >= self.cone).astype(np.float64)

    def nodes(self) -> np.ndarray:
        """The grid's nodes as states, shape ``(2, angle_cells * velocity_points)`` (angle-major)."""
        q, v = np.meshgrid(self.angles, self.velocities, indexing="ij")
        return np.stack([q.ravel(), v.ravel()])

    # ------------------------------------------------------------------------------------- value iteration
    def iterate(self) -> Iterator[int]:
        """Run the backups, yielding the number done after each (for a progress bar); :attr:`values` is ``V_k``
        after each yield."""
        s = self.spec
        nodes = self.nodes()
        n = nodes.shape[1]
        step = self.step.map(n)
        transitions = []
        for u in np.linspace(-1.0, 1.0, s.actions):
            x_next = np.asarray(step(nodes, np.full((1, n), u)))
            index, weight = self._corners(x_next)
            transitions.append((index.astype(np.int32), weight.astype(np.float32), self._reward(x_next)))
        values = np.zeros(n)
        self.values = values.reshape(s.angle_cells, s.velocity_points)
        self.backups_done = 0
        for k in range(s.backups):
            best = np.full(n, -np.inf)
            for index, weight, reward in transitions:
                np.maximum(best, reward + (values[index] * weight).sum(axis=0), out=best)
            values = best
            self.values = values.reshape(s.angle_cells, s.velocity_points)
            self.backups_done = k + 1
            yield k + 1

    def solve(self) -> GridOptimum:
        """All :attr:`GridSpec.backups` backups; returns ``self``."""
        for _ in self.iterate():
            pass
        return self

    def value(self, x: np.ndarray) -> np.ndarray:
        """``V_K`` at the states ``x`` (shape ``(2,)`` or ``(2, n)``), interpolated between the nodes."""
        if self.values is None:
            raise RuntimeError("GridOptimum.value: call solve() first")
        x = np.asarray(x, dtype=np.float64)
        flat = x.reshape(2, -1)
        index, weight = self._corners(flat)
        out = (self.values.ravel()[index] * weight).sum(axis=0)
        return out if x.ndim == 2 else out[:1].reshape(())

    # ------------------------------------------------------------------------------------------ the policy
    def reset(self) -> None:
        """Nothing carries over between episodes (the policy is stationary)."""

    def __call__(self, x: np.ndarray, t: float = 0.0) -> np.ndarray:
        """The greedy action at the physics state ``x``: one exact step ahead, then ``V_K``."""
        if self.values is None:
            raise RuntimeError("GridOptimum: call solve() before using it as a controller")
        x = np.asarray(x, dtype=np.float64).reshape(2)
        if not np.all(np.isfinite(x)):
            raise ValueError(f"GridOptimum: the state must be finite, got {x}")
        u = self._policy_u
        x_next = np.asarray(self._policy_step(np.tile(x[:, None], (1, u.size)), u[None, :]))
        scores = self._reward(x_next) + self.value(x_next)
        return np.array([u[int(np.argmax(scores))]])
