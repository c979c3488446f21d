"""``SeagulAcrobotMujoco-v0``: the same acrobot as an MJCF (``assets/acrobot.xml``) stepped by MuJoCo."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from seagul_envs.envs.base import BufferedFunction, SeagulEnv
from seagul_envs.rendering import acrobot_frame
from seagul_envs.tasks import make_task

ACROBOT_XML = Path(__file__).resolve().parent.parent / "assets" / "acrobot.xml"


class AcrobotMujocoEnv(SeagulEnv):
    """The SEAGuL acrobot as an MJCF model stepped by MuJoCo's RK4 integrator.

    Registered as ``SeagulAcrobotMujoco-v0``. The task (costs, X0, time to go) is the acrobot task itself,
    ``make_task("acrobot")``; the numbers below are the defaults of its parameter dataclass ``AcrobotParams``
    (``seagul_envs/tasks/acrobot.py``), named next to each value, and of the MJCF file.

    **Description**

    The acrobot of ``SeagulAcrobot-v0`` (Spong 1995): two links hanging from an unactuated shoulder, a motor at the
    elbow, the goal ``x* = [pi, 0, 0, 0]`` (upright) held until the time to go runs out. The physics is MuJoCo
    (Todorov et al. 2012) on the MJCF ``seagul_envs/assets/acrobot.xml``: explicit inertials (``m1 = m2 = 1.0`` kg,
    centres of mass at ``lc1 = 0.5`` and ``lc2 = 1.0`` m, ``Ic1 = 0.083`` and ``Ic2 = 0.33`` kg m^2), link 1 of
    ``l1 = 1.0`` m, hinge axes along ``-y`` so that ``qpos = 0`` hangs down, joint damping ``b1 = b2 = 0.1`` N m s,
    gravity 9.81 m/s^2 and no contacts. Its mass matrix and bias forces equal the analytic model's to rounding. Each
    control period ``dt`` (``control_period = 0.1`` s) is ``ceil(dt / max_substep)`` MuJoCo RK4 steps of equal
    length (20 of 5 ms by default) with ``ctrl`` held constant.

    **Action Space**

    ``Box(-20.0, 20.0, (1,), float32)``: the elbow torque in N m (``u_max = 20.0``, the motor's ``ctrlrange``), in
    physical units. Actions outside the box are clipped, and the reward charges the clipped torque. A NaN/inf or
    wrongly shaped action raises ``ValueError`` and leaves the env unchanged.

    **Observation Space**

    ``Box((5,), float32)``: ``[th1, th2, dth1, dth2, time_to_go]`` = ``[qpos, qvel, time_to_go]``:

    | Index | Observation                                      | Unit  | Bounds                  |
    |-------|--------------------------------------------------|-------|-------------------------|
    | 0     | ``th1``: shoulder angle, 0 hanging straight down | rad   | +- float32 max          |
    | 1     | ``th2``: elbow angle relative to link 1          | rad   | +- float32 max          |
    | 2     | ``dth1``: shoulder angular velocity              | rad/s | +- float32 max          |
    | 3     | ``dth2``: elbow angular velocity                 | rad/s | +- float32 max          |
    | 4     | time to go                                       | s     | ``[0, 5.0]`` (``tau``)  |

    Angles are not wrapped. ``info["state"]`` is the float64 state and ``info["time_to_go"]`` the time to go, in the
    infos of ``reset`` and ``step``.

    **Rewards**

    As ``SeagulAcrobot-v0``: ``-h * l(x_k, u_k)`` per step of length ``h``, ``l(x, u) = (x - x*)' Q (x - x*) + R u^2``
    with ``Q = diag(1.0, 1.0, 0.1, 0.1)`` (``Q``) and ``R = 0.01`` (``R``) at the start of the step, plus
    ``-l_f(x_N)`` on the last step (``Qf``, the discrete-time LQR cost-to-go at the goal, ``task.extras["Qf"]``). An
    episode's return is minus the cost of the trajectory flown.

    **Starting State**

    Uniform in X0 = ``x* +- x0_half_width`` with ``x0_half_width = (0.3, 0.3, 0.5, 0.5)``: ``th1`` in
    ``[pi - 0.3, pi + 0.3]``, ``th2`` in ``[-0.3, 0.3]``, ``dth1, dth2`` in ``[-0.5, 0.5]``, drawn with the env's
    ``np_random``; the time to go is ``tau = 5.0`` s.

    **Episode End**

    Termination: never; the acrobot's state has no bounds. (A state that stops being finite would terminate it.)

    Truncation: when the time to go reaches 0, after ``ceil(tau / dt)`` steps, 50 steps of 0.1 s by default
    (``tau / control_period = 5.0 / 0.1``); a last step shortened if ``tau`` is not a multiple of ``dt``. The
    registered spec has ``max_episode_steps = 50`` (T0 is the single value ``tau = 5.0`` s), so ``gym.make``'s
    ``TimeLimit`` truncates on the same step as the env. Stepping after the end warns once and returns the final
    observation with reward 0.

    **Arguments**

    ``gym.make("SeagulAcrobotMujoco-v0", dt=None, render_mode=None, max_substep=None, params=None)``:

    * ``dt``: the control period in seconds (default ``control_period = 0.1``). The registered ``TimeLimit`` counts
      default periods; with another ``dt`` also pass ``max_episode_steps=ceil(5.0 / dt)`` or
      ``max_episode_steps=-1`` to leave the episode end to the env.
    * ``render_mode``: ``"rgb_array"`` (drawn with numpy; MuJoCo's OpenGL renderer is not needed) or ``"human"``;
      ``render_fps`` is 10.
    * ``max_substep``: the largest MuJoCo timestep in seconds (default ``Task.max_sim_substep = 0.005``).
    * ``params``: another robot than the model, a mapping ``{name: value}`` over ``task.parameters.names``
      (``m1, m2, l1, lc2, b1, b2``; the others keep the model's values) or a full vector, written into the loaded
      MJCF model; the env then equals ``SeagulAcrobot-v0`` with the same ``params``.

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
    * E. Todorov, T. Erez and Y. Tassa, "MuJoCo: A physics engine for model-based control", IEEE/RSJ International
      Conference on Intelligent Robots and Systems (IROS), 2012.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 10}  # noqa: RUF012 (Gymnasium convention)

    def __init__(
        self,
        dt: float | None = None,
        render_mode: str | None = None,
        max_substep: float | None = None,
        params: Any = None,
    ) -> None:
        super().__init__(make_task("acrobot"), dt=dt, render_mode=render_mode, max_substep=max_substep, params=params)

    def _restore_runtime(self) -> None:
        self.model = mujoco.MjModel.from_xml_path(str(ACROBOT_XML))
        self.data = mujoco.MjData(self.model)
        self._stage_cost = BufferedFunction(self.task.stage_cost)
        self._n_sub = max(1, math.ceil(self.dt / self.max_substep - 1e-9))  # equal MuJoCo steps per period
        self._apply_params()

    def _params_changed(self) -> None:
        self._apply_params()

    def _apply_params(self) -> None:
        """Write the robot's :class:`AcrobotParams` into the loaded MJCF: link masses, centres of mass, inertias,
        the elbow's position on link 1 and the joint damping (the XML holds the nominal ones), then recompute
        MuJoCo's derived constants."""
        p, m = self.task.params, self.model
        link1 = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "link1")
        link2 = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "link2")
        m.body_mass[link1], m.body_mass[link2] = p.m1, p.m2
        m.body_ipos[link1] = (0.0, 0.0, -p.lc1)
        m.body_ipos[link2] = (0.0, 0.0, -p.lc2)
        m.body_inertia[link1] = (p.Ic1, p.Ic1, p.Ic1)
        m.body_inertia[link2] = (p.Ic2, p.Ic2, p.Ic2)
        m.body_pos[link2] = (0.0, 0.0, -p.l1)
        for joint, damping in (("shoulder", p.b1), ("elbow", p.b2)):
            m.dof_damping[m.jnt_dofadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, joint)]] = damping
        mujoco.mj_setConst(m, self.data)

    def _runtime_keys(self) -> tuple[str, ...]:
        return ("model", "data", "_stage_cost", "_n_sub")

    def _set_sim_state(self, x: np.ndarray) -> None:
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:] = x[:2]
        self.data.qvel[:] = x[2:]
        mujoco.mj_forward(self.model, self.data)

    def _advance(self, u: np.ndarray, h: float) -> tuple[np.ndarray, float]:
        cost = self._stage_cost
        cost.args[0][:] = self._x
        cost.args[1][:] = u
        cost()
        n = self._n_sub if h == self.dt else max(1, math.ceil(h / self.max_substep - 1e-9))
        self.model.opt.timestep = h / n
        self.data.ctrl[:] = u
        mujoco.mj_step(self.model, self.data, nstep=n)
        return np.concatenate([self.data.qpos, self.data.qvel]), float(cost.res[0][0])

    def _render_frame(self) -> np.ndarray:
        p = self.task.params
        return acrobot_frame(
            float(self.data.qpos[0]),
            float(self.data.qpos[1]),
            p.l1,
            p.l2,
            u=float(self._last_u[0]),
            u_max=float(self.task.u_high[0]),
            ttg_fraction=self._ttg_fraction(),
        )
