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
    """The SEAGuL acrobot (docs/spec.md §3.7) as an MJCF model stepped by MuJoCo's RK4 integrator.

    ## Description

    Identical task to ``SeagulAcrobot-v0`` (same Task object: costs, bounds, X0, time to go), but the physics is the
    MJCF ``seagul_envs/assets/acrobot.xml``: explicit inertials, hinge axes along ``-y`` (``qpos = 0`` hangs down),
    joint damping, no contacts. Its mass matrix and bias forces equal the analytic model's to rounding (tested), and
    MuJoCo's RK4 with the same substep reproduces the analytic env's control step (see ``tests/test_dynamics.py``).
    Each control period is ``ceil(dt / 5 ms)`` MuJoCo RK4 steps of equal length with ``ctrl`` held constant.

    ## Action Space

    ``Box(-20, 20, (1,), float32)``: elbow torque in N m (the motor's ``ctrlrange``). Out-of-range actions are
    clipped; a NaN/inf or wrongly shaped action raises ValueError and leaves the env unchanged.

    ## Observation Space

    ``Box((5,), float32)``: ``[th1, th2, dth1, dth2, time_to_go]`` = ``[qpos, qvel, time_to_go]`` (rad, rad/s, s).
    Angles are not wrapped. ``info["state"]`` (float64) and ``info["time_to_go"]`` as in every seagul env.

    ## Rewards

    As ``SeagulAcrobot-v0``: ``-dt * l(x_k, u_k)`` per step plus ``-l_f(x_end)`` on the last step, so an episode's
    return is minus the trajectory cost.

    ## Starting State

    Uniform in X0 (``th1 in pi +- 0.3``, ``th2 in +- 0.3``, velocities ``+- 0.5``), time to go 5 s; or
    ``reset(options={"state": x0, "time_to_go": tau})``.

    ## Episode End

    Truncation when the time to go reaches 0; the state is unbounded, so no termination.

    ## Arguments

    ``gym.make("SeagulAcrobotMujoco-v0", dt=0.1, render_mode=None, max_substep=None, params=None)``: control period
    (s), render mode (``"rgb_array"`` draws headless with numpy, MuJoCo's OpenGL renderer is not needed), the largest
    MuJoCo timestep inside a period (default ``task.max_sim_substep`` = 5 ms), and the robot's parameters
    (``{name: value}`` of ``task.parameters.names``: masses, link-1 length, link-2 centre of mass, damping; written
    into the MJCF model, equal to the analytic env with the same ``params``; ``reset(options={"params": ...})``
    changes them per episode).
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
