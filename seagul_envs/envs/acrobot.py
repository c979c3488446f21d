"""``SeagulAcrobot-v0``: the acrobot swing-up simulated from the Task's CasADi model."""

from __future__ import annotations

from typing import Any

import numpy as np

from seagul_envs.envs.base import TaskSimulatorEnv, resolve_task
from seagul_envs.rendering import acrobot_frame
from seagul_envs.tasks.acrobot import AcrobotParams
from seagul_envs.tasks.base import Task


class AcrobotEnv(TaskSimulatorEnv):
    """The acrobot swing-up and balance task of SEAGuL (docs/spec.md §3), integrated from the Task's CasADi model.

    ## Description

    Two links hang from an unactuated shoulder; a motor at the elbow applies a torque. The goal is to swing the
    chain up and balance it upright (``x* = [pi, 0, 0, 0]``) within the time to go. The dynamics are Drake's
    ``AcrobotPlant`` (``M(q) ddq + C(q, dq) dq = tau_g(q) + B u - b dq``, parameters in
    :class:`~seagul_envs.tasks.acrobot.AcrobotParams`); the env integrates ``task.dynamics`` with RK4 substeps of at
    most 5 ms over each control period (``task.simulator(dt)``), the action held constant (zero-order hold).

    ## Action Space

    ``Box(-20, 20, (1,), float32)``: the elbow torque in N m (physical units). Actions outside the bounds are
    clipped; a NaN/inf or wrongly shaped action raises ValueError and leaves the env unchanged.

    ## Observation Space

    ``Box((5,), float32)``:

    | Num | Observation                         | Unit  |
    |-----|-------------------------------------|-------|
    | 0   | ``th1``: shoulder angle, 0 = down   | rad   |
    | 1   | ``th2``: elbow angle relative to link 1 | rad |
    | 2   | ``dth1``                            | rad/s |
    | 3   | ``dth2``                            | rad/s |
    | 4   | time to go                          | s     |

    Angles are not wrapped (the cost is not periodic). ``info["state"]`` holds the float64 state and
    ``info["time_to_go"]`` the time to go.

    ## Rewards

    ``-dt * l(x_k, u_k)`` per step with ``l = (x - x*)' Q (x - x*) + R u^2`` evaluated at the start of the period
    (the transcription's left-point rule), plus ``-l_f(x_end)`` (``l_f`` = discrete LQR cost-to-go at the goal) on the
    last step: an episode's return is minus the trajectory cost of the optimal-control problem.

    ## Starting State

    Uniform in X0: ``th1 in pi +- 0.3``, ``th2 in +- 0.3``, ``dth1, dth2 in +- 0.5``, time to go 5 s.
    ``reset(options={"state": x0, "time_to_go": tau})`` chooses any finite start and any ``tau`` in ``(0, 5]``.

    ## Episode End

    Truncation when the time to go reaches 0 (50 steps of 0.1 s by default; the last step is shortened if ``tau`` is
    not a multiple of ``dt``). The acrobot's state is unbounded, so it never terminates.

    ## Arguments

    ``gym.make("SeagulAcrobot-v0", dt=0.1, render_mode=None, task=None, max_substep=None, params=None)``: ``dt`` is
    the control period (s); ``task`` a custom acrobot :class:`~seagul_envs.tasks.base.Task` (e.g.
    ``make_acrobot_task(AcrobotParams(b1=0))``), default ``make_task("acrobot")``; ``params`` another robot than the
    task's model, ``{name: value}`` of ``task.parameters.names`` (``m1, m2, l1, lc2, b1, b2``; the rest the model's)
    or a full vector: the env simulates ``task.with_params(params)`` (``env.unwrapped.task``; the model stays
    ``env.unwrapped.model_task``), and ``reset(options={"params": ...})`` changes it per episode (domain
    randomisation); ``render_mode`` is
    ``"rgb_array"`` (headless) or ``"human"``; ``max_substep`` the largest RK4 substep (default
    ``task.max_sim_substep`` = 5 ms). Accuracy of one 0.1 s step against a 1e-12 reference, 5 ms substeps: ~5e-8 at
    X0 speeds, ~1e-6 up to 6 rad/s, ~2e-4 at 10-20 rad/s; at the ~30 rad/s of violent swings use
    ``max_substep=0.001`` or less for evaluation (error ~1e-2 at 5 ms there, RK4 error falls as the substep^4).
    """

    params_class: type = AcrobotParams
    """The parameter class of the tasks this env simulates (any name: variants of the system included)."""

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 10}  # noqa: RUF012 (Gymnasium convention)

    def __init__(
        self,
        dt: float | None = None,
        render_mode: str | None = None,
        task: Task | None = None,
        max_substep: float | None = None,
        params: Any = None,
    ) -> None:
        super().__init__(
            resolve_task(task, "acrobot", type(self).__name__, self.params_class),
            dt=dt,
            render_mode=render_mode,
            max_substep=max_substep,
            params=params,
        )

    def _render_frame(self) -> np.ndarray:
        p = self.task.params
        return acrobot_frame(
            float(self._x[0]),
            float(self._x[1]),
            p.l1,
            p.l2,
            u=float(self._last_u[0]),
            u_max=float(self.task.u_high[0]),
            ttg_fraction=self._ttg_fraction(),
        )
