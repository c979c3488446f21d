"""``dmc_pendulum``: the DeepMind Control Suite's ``pendulum-swingup`` as a seagul task.

Model [src: ``dm_control/suite/pendulum.xml``]: one hinge ``hinge`` about y at the body ``pole`` (``pos="0 0 .6"``);
its only massive geom is the sphere ``mass`` (``mass="1"``, radius 0.05, at 0.5 m along the pole; the ``pole``
capsule and ``base`` cylinder have ``mass="0"``), so ``M = 2 m r^2 / 5 + m l^2 = 0.251 kg m^2``::

    M qacc = m g l sin(hinge) - b qvel + gear u,   x = [hinge, hinge_vel],   u = ctrl in [-1, 1]

with ``hinge = 0`` upright (the pole's geoms point along the body's +z), ``b = 0.1 N m s``, ``gear = 1``. MuJoCo
integrates it with the default ``Euler`` integrator (semi-implicit, implicit damping) at ``timestep = 0.02 s``; the
suite's control step is one such step (``control.Environment`` without ``control_timestep``: ``n_sub_steps = 1``),
1000 steps per 20 s episode (``_DEFAULT_TIME_LIMIT = 20``). ``task.extras["mujoco_step"]`` reproduces that step; the
task's ``dynamics`` is the continuous model, which the optimizer and seagul's simulator integrate by RK4 (0.02 s
substeps), within ``O(h)`` of MuJoCo's Euler step (measured in docs/tutorials/dmc-tasks.md).

Reward [src: ``dm_control/suite/pendulum.py``, ``SwingUp.get_reward``]: ``tolerance(cos(hinge), (cos 8deg, 1))``,
1 within 8 degrees of upright and 0 elsewhere. Cost [choice]: the smooth surrogate ``l = (1 - cos hinge) +
0.01 u^2``. The indicator has no gradient, and ``1 - cos`` is the same function of the same quantity (the pole's
vertical component, which the reward thresholds), smooth and periodic; the small control weight makes the
optimal control unique where the angle term is flat. The score is always dm_control's own reward.

Start box [src: ``SwingUp.initialize_episode``]: ``hinge ~ U[-pi, pi)``, ``hinge_vel = 0``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from seagul_envs.tasks.base import Task
from seagul_envs.tasks.dmc.common import SuiteRewardSuccess, TaskSpec, build_dmc_task
from seagul_envs.tasks.dmc.mechanics import GRAVITY, ChainModel, PlanarBody, sphere_inertia


@dataclass(frozen=True)
class DMCPendulumParams:
    """Every constant of ``dmc_pendulum``, with its unit and its place in dm_control 1.0.52's suite."""

    pivot_height: float = 0.6
    """Height of the hinge (m): ``pendulum.xml`` body ``pole`` ``pos="0 0 .6"`` (no effect on the dynamics)."""
    mass: float = 1.0
    """Bob mass (kg): geom ``mass`` ``mass="1"`` (the geoms ``base`` and ``pole`` have ``mass="0"``)."""
    bob_radius: float = 0.05
    """Bob radius (m): geom ``mass`` ``size="0.05"`` (a solid sphere)."""
    length: float = 0.5
    """Hinge to the bob's centre (m): geom ``mass`` ``pos="0 0 0.5"``."""
    damping: float = 0.1
    """Hinge damping (N m s): joint ``hinge`` ``damping="0.1"``."""
    gear: float = 1.0
    """Torque per unit ctrl (N m): motor ``torque`` ``gear="1"``."""
    ctrl_max: float = 1.0
    """Control bound: motor ``torque`` ``ctrlrange="-1 1"`` (``ctrllimited``: MuJoCo clamps)."""
    g: float = GRAVITY
    """Gravity (m/s^2): MuJoCo's default (the file sets none)."""
    timestep: float = 0.02
    """MuJoCo step (s): ``<option timestep="0.02">``, default ``Euler`` integrator."""
    n_sub_steps: int = 1
    """MuJoCo steps per control step: ``pendulum.py`` ``swingup`` passes no ``control_timestep``."""
    time_limit: float = 20.0
    """Suite episode length (s): ``pendulum.py`` ``_DEFAULT_TIME_LIMIT``."""
    angle_bound_deg: float = 8.0
    """The reward is 1 within this angle of upright (deg): ``pendulum.py`` ``_ANGLE_BOUND``."""
    control_weight: float = 0.01
    """Surrogate cost's input weight (per second) [choice]."""
    tau: float = 10.0
    """Time to go of the full-horizon problem (s) [choice: |u| <= 1 N m against m g l = 4.9 N m takes several
    swings; the optimal swing-ups found from the suite's starts reach the top within about 7 s]."""
    horizon_steps: int = 100
    """Transcription intervals (0.1 s each) [choice]."""
    rk4_substeps: int = 5
    """RK4 substeps per interval: 0.02 s, MuJoCo's step [choice]."""


def dmc_pendulum_model(p: DMCPendulumParams) -> ChainModel:
    """The MJCF's mechanics: body ``pole``, the bob's mass, centre of mass and inertia."""
    body = PlanarBody(
        parent=-1,
        pos=(0.0, p.pivot_height),
        joint="hinge",
        mass=p.mass,
        com=(0.0, p.length),
        inertia_y=sphere_inertia(p.mass, p.bob_radius),
    )
    return ChainModel(
        bodies=(body,),
        damping=(p.damping,),
        actuated=0,
        gear=p.gear,
        ctrl_range=(-p.ctrl_max, p.ctrl_max),
        timestep=p.timestep,
        integrator="Euler",
        g=p.g,
    )


def dmc_pendulum_reward(p: DMCPendulumParams, x: np.ndarray, u: np.ndarray) -> float:
    """The suite's reward at ``x``: 1 if ``cos(hinge) >= cos(8 deg)`` (the pole's ``xmat zz``), else 0."""
    del u
    return float(math.cos(float(x[0])) >= math.cos(math.radians(p.angle_bound_deg)))


def make_dmc_pendulum_task(params: DMCPendulumParams | None = None) -> Task:
    """Build ``dmc_pendulum`` (module docstring)."""
    p = params or DMCPendulumParams()

    def stage_cost(x: ca.SX, u: ca.SX) -> ca.SX:
        return (1 - ca.cos(x[0])) + p.control_weight * u[0] ** 2

    inf = np.inf
    return build_dmc_task(
        TaskSpec(
            name="dmc_pendulum",
            state_names=("hinge", "hinge_vel"),
            control_name="torque",
            model=dmc_pendulum_model(p),
            stage_cost=stage_cost,
            angles=(0,),
            x_low=np.array([-inf, -inf]),
            x_high=np.array([inf, inf]),
            x0_low=np.array([-np.pi, 0.0]),
            x0_high=np.array([np.pi, 0.0]),
            tau=p.tau,
            horizon_steps=p.horizon_steps,
            rk4_substeps=p.rk4_substeps,
            n_sub_steps=p.n_sub_steps,
            success=SuiteRewardSuccess(dmc_pendulum_reward, 1.0),
            success_text=f"suite reward 1 at x(T): within {p.angle_bound_deg:g} deg of upright",
            params=p,
            suite=("pendulum", "swingup"),
        )
    )
