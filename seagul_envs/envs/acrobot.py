"""``SeagulAcrobot-v0``: the acrobot swing-up simulated from the Task's CasADi model."""

from __future__ import annotations

from typing import Any

import numpy as np

from seagul_envs.envs.base import TaskSimulatorEnv, resolve_task
from seagul_envs.rendering import acrobot_frame
from seagul_envs.tasks.acrobot import AcrobotParams
from seagul_envs.tasks.base import Task


class AcrobotEnv(TaskSimulatorEnv):
    """The acrobot swing-up and balance task of SEAGuL, integrated from the task's CasADi model.

    Registered as ``SeagulAcrobot-v0``. The numbers below are the defaults of the task's parameter dataclass
    ``AcrobotParams`` (``seagul_envs/tasks/acrobot.py``), named next to each value.

    **Description**

    Two links hang from an unactuated shoulder and a motor at the elbow applies a torque (Spong 1995). The task is
    to bring the chain upright, to the goal ``x* = [pi, 0, 0, 0]``, and hold it there until the time to go runs out,
    at the least trajectory cost. The dynamics are Drake's ``AcrobotPlant`` in manipulator form,
    ``M(q) ddq + C(q, dq) dq = tau_g(q) + B u - b dq`` with ``q = [th1, th2]`` and ``B = [0, 1]'``, and the physical
    parameters ``m1 = m2 = 1.0`` kg, ``l1 = 1.0`` m, ``lc1 = 0.5`` m, ``lc2 = 1.0`` m, ``Ic1 = 0.083`` and
    ``Ic2 = 0.33`` kg m^2, damping ``b1 = b2 = 0.1`` N m s and ``g = 9.81`` m/s^2 (``l2 = 2.0`` m is used only for
    drawing). Each step holds the action over one control period
    ``dt`` (``control_period = 0.1`` s; zero-order hold) and integrates the task's dynamics with RK4 substeps of at
    most ``Task.max_sim_substep = 0.005`` s (20 per period).

    **Action Space**

    ``Box(-20.0, 20.0, (1,), float32)``: the elbow torque in N m (``u_max = 20.0``), in physical units. Actions
    outside the box are clipped, and the reward charges the clipped torque. A NaN/inf or wrongly shaped action raises
    ``ValueError`` and leaves the env unchanged.

    **Observation Space**

    ``Box((5,), float32)``, the state followed by the time to go:

    | Index | Observation                                      | Unit  | Bounds                  |
    |-------|--------------------------------------------------|-------|-------------------------|
    | 0     | ``th1``: shoulder angle, 0 hanging straight down | rad   | +- float32 max          |
    | 1     | ``th2``: elbow angle relative to link 1          | rad   | +- float32 max          |
    | 2     | ``dth1``: shoulder angular velocity              | rad/s | +- float32 max          |
    | 3     | ``dth2``: elbow angular velocity                 | rad/s | +- float32 max          |
    | 4     | time to go                                       | s     | ``[0, 5.0]`` (``tau``)  |

    Angles are not wrapped (the cost is not periodic). ``info["state"]`` is the float64 state and
    ``info["time_to_go"]`` the time to go, in the infos of ``reset`` and ``step``.

    **Rewards**

    A step of length ``h`` from ``x_k`` with torque ``u_k`` earns ``-h * l(x_k, u_k)``, with the running cost
    ``l(x, u) = (x - x*)' Q (x - x*) + R u^2``, ``Q = diag(1.0, 1.0, 0.1, 0.1)`` (``Q``) and ``R = 0.01`` (``R``),
    evaluated at the start of the step (the left-point rule of the trajectory optimizer's transcription). The last
    step also earns ``-l_f(x_N)``, ``l_f(x) = (x - x*)' Qf (x - x*)`` with ``Qf`` the discrete-time LQR cost-to-go
    at the goal (``task.extras["Qf"]``). An episode's return is therefore minus the cost of the trajectory flown.

    **Starting State**

    Uniform in X0 = ``x* +- x0_half_width`` with ``x0_half_width = (0.3, 0.3, 0.5, 0.5)``: ``th1`` in
    ``[pi - 0.3, pi + 0.3]``, ``th2`` in ``[-0.3, 0.3]``, ``dth1, dth2`` in ``[-0.5, 0.5]``, drawn with the env's
    ``np_random``; the time to go is ``tau = 5.0`` s. X0 lies around the upright goal; a start hanging down, e.g.
    ``reset(options={"state": [0, 0, 0, 0]})``, poses the full swing-up.

    **Episode End**

    Termination: never; the acrobot's state has no bounds. (A state that stops being finite would terminate it.)

    Truncation: when the time to go reaches 0, after ``ceil(tau / dt)`` steps, 50 steps of 0.1 s by default
    (``tau / control_period = 5.0 / 0.1``). If ``tau`` is not a multiple of ``dt``, the last step is shortened so that
    the time to go reaches exactly 0. The registered spec has ``max_episode_steps = 50``, the same number (T0 is the
    single value ``tau = 5.0`` s), so ``gym.make``'s ``TimeLimit`` truncates on the same step as the env. Stepping
    after the end warns once and returns the final observation with reward 0.

    **Arguments**

    ``gym.make("SeagulAcrobot-v0", dt=None, render_mode=None, task=None, max_substep=None, params=None)``:

    * ``dt``: the control period in seconds (default ``control_period = 0.1``). The registered ``TimeLimit`` counts
      default periods; with another ``dt`` also pass ``max_episode_steps=ceil(5.0 / dt)`` (``seagul_envs.make_env``
      does it) or ``max_episode_steps=-1`` to leave the episode end to the env.
    * ``render_mode``: ``"rgb_array"`` (a numpy frame, no display needed) or ``"human"``; ``render_fps`` is 10.
    * ``task``: an acrobot ``Task`` with other constants, e.g. ``make_acrobot_task(AcrobotParams(b1=0.0))``;
      default ``make_task("acrobot")``.
    * ``max_substep``: the largest RK4 substep in seconds (default ``Task.max_sim_substep = 0.005``). RK4's error
      falls with the fourth power of the substep: the fast joint speeds of violent swings call for a smaller one.
    * ``params``: another robot than the task's model, a mapping ``{name: value}`` over ``task.parameters.names``
      (``m1, m2, l1, lc2, b1, b2``; the others keep the model's values) or a full vector. The env then simulates
      ``task.with_params(params)`` (``env.unwrapped.task``; the model stays ``env.unwrapped.model_task``).

    ``reset(seed=None, options=None)`` takes the options (all optional):

    * ``"state"``: the start ``[th1, th2, dth1, dth2]``, any finite state.
    * ``"time_to_go"``: ``tau`` in ``(0, 5.0]`` s (the float32 time to go of an observation is accepted).
    * ``"params"``: the robot from this episode on, as the ``params`` argument (domain randomisation).

    Unknown keys and bad values raise ``ValueError`` and leave the env as it was.

    **Version History**

    * v0: initial version.

    **References**

    * B. Landry, H. Dai and M. Pavone, "SEAGuL: Sample Efficient Adversarially Guided Learning of Value
      Functions", Learning for Dynamics and Control (L4DC), PMLR 144, 2021. arXiv:2107.08893.
    * M. W. Spong, "The swing up control problem for the Acrobot", IEEE Control Systems Magazine, 15(1), 1995.
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
