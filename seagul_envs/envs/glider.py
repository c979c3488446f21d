"""``SeagulGlider-v0``: the perching glider simulated from the Task's CasADi model."""

from __future__ import annotations

from typing import Any

import numpy as np

from seagul_envs.envs.base import TaskSimulatorEnv, resolve_task
from seagul_envs.rendering import glider_frame
from seagul_envs.tasks.base import Task
from seagul_envs.tasks.glider import GliderParams


class GliderEnv(TaskSimulatorEnv):
    """The perching glider of SEAGuL (docs/spec.md §4), integrated from the Task's CasADi model.

    ## Description

    A flat-plate glider (wing at the centre of mass, elevator on a tail boom) launched at ~7 m/s must land on a perch
    (a string at the origin) by pitching up to a post-stall attitude and bleeding its speed, reaching
    ``x_d = [0, 0, pi/4, 0, 0, 0, 0]`` when the time to go runs out. The dynamics are Drake's ``GliderPlant``
    (parameters in :class:`~seagul_envs.tasks.glider.GliderParams`); the env integrates ``task.dynamics`` with RK4
    substeps of at most 5 ms over each 25 ms control period, the elevator rate held constant (zero-order hold).

    ## Action Space

    ``Box(-13, 13, (1,), float32)``: elevator rate ``dphi`` in rad/s. Out-of-range actions are clipped, and so is a
    rate that would drive the elevator past its range within the step (a mechanical stop: ``phi`` stays in
    ``[-0.9473, 0.4463]``); the reward charges the rate applied. A NaN/inf or wrongly shaped action raises
    ValueError and leaves the env unchanged.

    ## Observation Space

    ``Box((8,), float32)``:

    | Num | Observation                              | Unit  |
    |-----|------------------------------------------|-------|
    | 0   | ``x``: horizontal COM position (perch at 0) | m  |
    | 1   | ``z``: vertical COM position             | m     |
    | 2   | ``th``: pitch, positive nose-up          | rad   |
    | 3   | ``phi``: elevator angle relative to body | rad   |
    | 4   | ``dx``                                   | m/s   |
    | 5   | ``dz``                                   | m/s   |
    | 6   | ``dth``                                  | rad/s |
    | 7   | time to go                               | s     |

    ``info["state"]`` holds the float64 state and ``info["time_to_go"]`` the time to go.

    ## Rewards

    ``-dt * 100 u^2`` per step (the running cost at the start of the period, the transcription's left-point rule),
    plus ``-(x - x_d)' diag(10, 10, 1, 10, 1, 1, 1) (x - x_d)`` on the step where the episode ends (also on a crash,
    so crashing is never cheaper than arriving at the crash point): an episode's return is minus the trajectory cost.

    ## Starting State

    Uniform in X0: ``x in [-3.75, -3.25]``, ``z in [0, 0.3]``, ``dx in [6.5, 7.5]``, other states 0; time to go
    0.8 s. ``reset(options={"state": x0, "time_to_go": tau})`` chooses a start inside the state bounds and any
    ``tau`` in ``(0, 0.85]``.

    ## Episode End

    * Termination (crash): the state leaves the task's path bounds ``x in [-4, 1]``, ``z in [-1, 1]``,
      ``th in [-pi/2, pi/2]`` (``phi`` is kept inside its range by the action limit above).
    * Truncation: the time to go reaches 0 (32 steps of 25 ms from 0.8 s; the last step is shortened if ``tau`` is
      not a multiple of ``dt``).

    ## Arguments

    ``gym.make("SeagulGlider-v0", dt=0.025, render_mode=None, task=None, max_substep=None, params=None)``: control
    period (s), render mode (``"rgb_array"`` headless, or ``"human"``), optionally a custom glider Task, the largest
    RK4 substep (default ``task.max_sim_substep`` = 5 ms; one 25 ms step then matches a 1e-12 reference to < 1e-6),
    and another glider than the model: ``{name: value}`` of ``m, S_w, S_e, rho`` (the rest the model's), also per
    episode with ``reset(options={"params": ...})``.
    """

    params_class: type = GliderParams
    """The parameter class of the tasks this env simulates (any name: variants of the system included)."""

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 40}  # noqa: RUF012 (Gymnasium convention)

    def __init__(
        self,
        dt: float | None = None,
        render_mode: str | None = None,
        task: Task | None = None,
        max_substep: float | None = None,
        params: Any = None,
    ) -> None:
        super().__init__(
            resolve_task(task, "glider", type(self).__name__, self.params_class),
            dt=dt,
            render_mode=render_mode,
            max_substep=max_substep,
            params=params,
        )
        self._trail: list[tuple[float, float]] = []

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        self._trail = []
        return super().reset(seed=seed, options=options)

    def _limit_action(self, u: np.ndarray, h: float) -> np.ndarray:
        # The elevator's range acts as a mechanical stop: dphi = u exactly, so clipping u to the travel left over
        # this step keeps phi inside [phi_min, phi_max] without touching the model. Trajectories that respect the
        # bounds (all optimizer solutions) are unchanged; random exploration no longer "crashes" on the elevator.
        phi = self._x[3]
        lo = max(self._u_low[0], (self._x_low[3] - phi) / h)
        hi = min(self._u_high[0], (self._x_high[3] - phi) / h)
        return np.array([min(max(u[0], lo), hi)])

    def _render_frame(self) -> np.ndarray:
        # The flown path is kept only while rendering (no cost on the training hot path).
        self._trail.append((float(self._x[0]), float(self._x[1])))
        p = self.task.params
        return glider_frame(
            self._x,
            p.l_h,
            p.l_e,
            (float(self.task.x_low[0]), float(self.task.x_high[0])),
            (float(self.task.x_low[1]), float(self.task.x_high[1])),
            trail=self._trail,
            ttg_fraction=self._ttg_fraction(),
        )
