"""``dmc_acrobot``: the DeepMind Control Suite's ``acrobot-swingup`` as a seagul task.

Model [src: ``dm_control/suite/acrobot.xml``, Coulom's acrobot]: the body ``upper_arm`` (``pos="0 0 2"``) turns on
the hinge ``shoulder`` about y, the body ``lower_arm`` (1 m along it) on the hinge ``elbow``; each arm is one
capsule from its joint to 1 m along the body's +z (``mass="1"`` from the default class, radii 0.05 and 0.049), so
each centre of mass is 0.5 m from its joint and each inertia is MuJoCo's capsule rule
(:func:`~seagul_envs.tasks.dmc.mechanics.capsule_inertia`). The usual acrobot equations follow with
``x = [shoulder, elbow, shoulder_vel, elbow_vel]`` (``qpos``, ``qvel``; both angles 0 with the arm pointing up,
``elbow`` relative to the upper arm), joint damping 0.05 N m s on both (default class), and the elbow motor
``gear = 2`` (N m per unit ctrl, ``u = ctrl in [-1, 1]``). Unlike seagul's own ``acrobot``, angle 0 is *upright*
and the torque is ``2 u``. The file sets ``integrator="RK4"`` and ``timestep = 0.01 s`` and disables constraints;
the suite's control step is one such step (``n_sub_steps = 1``, 1000 steps per 10 s episode). The task's simulator
and transcription use RK4 with 0.01 s substeps: MuJoCo's own step, to round-off.

Reward [src: ``dm_control/suite/acrobot.py``, ``Balance._get_reward``, smooth variant]:
``tolerance(d, bounds=(0, 0.2), margin=1)`` of the distance ``d`` from the site ``tip`` (the lower arm's end) to
the site ``target`` at ``(0, 0, 4)``: 1 within the target's radius 0.2 m, a gaussian of the excess beyond it.
Cost [choice]: ``l = d^2 + 0.01 u^2`` with ``d^2 = (sin s + sin(s + e))^2 + (2 - cos s - cos(s + e))^2``. The reward
is a decreasing function of ``d``, so states rank the same under both, but the reward is flat inside 0.2 m and
vanishes (with its gradient) a metre beyond, which leaves IPOPT without a slope from a hanging start; ``d^2``
is smooth, periodic and graded everywhere (``d`` itself is not differentiable at the goal). The small control
weight makes the optimum unique. The score is always dm_control's own reward.

Start box [src: ``Balance.initialize_episode``]: ``shoulder, elbow ~ U[-pi, pi)``, velocities 0.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from seagul_envs.tasks.base import Task
from seagul_envs.tasks.dmc.common import SuiteRewardSuccess, TaskSpec, build_dmc_task
from seagul_envs.tasks.dmc.mechanics import GRAVITY, ChainModel, PlanarBody, capsule_inertia, tolerance_gaussian


@dataclass(frozen=True)
class DMCAcrobotParams:
    """Every constant of ``dmc_acrobot``, with its unit and its place in dm_control 1.0.52's suite."""

    shoulder_height: float = 2.0
    """Height of the shoulder (m): ``acrobot.xml`` body ``upper_arm`` ``pos="0 0 2"``."""
    upper_mass: float = 1.0
    """Upper-arm mass (kg): default class geom ``mass="1"`` (the decoration cylinder has ``mass="0"``)."""
    upper_radius: float = 0.05
    """Upper-arm capsule radius (m): geom ``upper_arm`` ``size="0.05"``."""
    upper_length: float = 1.0
    """Upper-arm length (m): geom ``upper_arm`` ``fromto="0 0 0 0 0 1"``; body ``lower_arm`` ``pos="0 0 1"``."""
    lower_mass: float = 1.0
    """Lower-arm mass (kg): default class geom ``mass="1"``."""
    lower_radius: float = 0.049
    """Lower-arm capsule radius (m): geom ``lower_arm`` ``size="0.049"``."""
    lower_length: float = 1.0
    """Lower-arm length (m): geom ``lower_arm`` ``fromto="0 0 0 0 0 1"``; site ``tip`` ``pos="0 0 1"``."""
    damping: float = 0.05
    """Damping of both joints (N m s): default class joint ``damping=".05"``."""
    gear: float = 2.0
    """Elbow torque per unit ctrl (N m): motor ``elbow`` ``gear="2"``."""
    ctrl_max: float = 1.0
    """Control bound: motor ``elbow`` ``ctrlrange="-1 1"``."""
    g: float = GRAVITY
    """Gravity (m/s^2): MuJoCo's default."""
    timestep: float = 0.01
    """MuJoCo step (s): ``<option timestep="0.01" integrator="RK4">``."""
    n_sub_steps: int = 1
    """MuJoCo steps per control step: ``acrobot.py`` ``swingup`` passes no ``control_timestep``."""
    time_limit: float = 10.0
    """Suite episode length (s): ``acrobot.py`` ``_DEFAULT_TIME_LIMIT``."""
    target_height: float = 4.0
    """Height of the target (m): site ``target`` ``pos="0 0 4"`` (the tip's height when upright)."""
    target_radius: float = 0.2
    """The reward is 1 within this distance (m): site ``target`` ``size="0.2"``."""
    reward_margin: float = 1.0
    """Gaussian margin of the reward beyond the target (m): ``rewards.tolerance(..., margin=1)``."""
    control_weight: float = 0.01
    """Surrogate cost's input weight (per second) [choice]."""
    tau: float = 5.0
    """Time to go of the full-horizon problem (s) [choice]."""
    horizon_steps: int = 100
    """Transcription intervals (0.05 s each) [choice]."""
    rk4_substeps: int = 5
    """RK4 substeps per interval: 0.01 s, MuJoCo's own RK4 step [choice]."""


def dmc_acrobot_model(p: DMCAcrobotParams) -> ChainModel:
    """The MJCF's mechanics: bodies ``upper_arm`` and ``lower_arm``."""
    upper = PlanarBody(
        parent=-1,
        pos=(0.0, p.shoulder_height),
        joint="hinge",
        mass=p.upper_mass,
        com=(0.0, p.upper_length / 2),
        inertia_y=capsule_inertia(p.upper_mass, p.upper_radius, p.upper_length)[0],
    )
    lower = PlanarBody(
        parent=0,
        pos=(0.0, p.upper_length),
        joint="hinge",
        mass=p.lower_mass,
        com=(0.0, p.lower_length / 2),
        inertia_y=capsule_inertia(p.lower_mass, p.lower_radius, p.lower_length)[0],
    )
    return ChainModel(
        bodies=(upper, lower),
        damping=(p.damping, p.damping),
        actuated=1,
        gear=p.gear,
        ctrl_range=(-p.ctrl_max, p.ctrl_max),
        timestep=p.timestep,
        integrator="RK4",
        g=p.g,
    )


def dmc_acrobot_tip_to_target(p: DMCAcrobotParams, x: Any) -> tuple[Any, Any]:
    """``(dx, dz)`` from the site ``tip`` to the site ``target`` (m), for numbers or CasADi symbols."""
    lib = ca if isinstance(x, ca.SX) else np
    s, e = x[0], x[1]
    tip_x = p.upper_length * lib.sin(s) + p.lower_length * lib.sin(s + e)
    tip_z = p.shoulder_height + p.upper_length * lib.cos(s) + p.lower_length * lib.cos(s + e)
    return -tip_x, p.target_height - tip_z


def dmc_acrobot_reward(p: DMCAcrobotParams, x: np.ndarray, u: np.ndarray) -> float:
    """The suite's smooth reward at ``x``: ``tolerance(d, bounds=(0, 0.2), margin=1)`` of the tip-to-target
    distance ``d``."""
    del u
    dx, dz = dmc_acrobot_tip_to_target(p, np.asarray(x, dtype=np.float64))
    d = float(np.hypot(dx, dz))
    return float(tolerance_gaussian(d, p.reward_margin, bound=p.target_radius))


def make_dmc_acrobot_task(params: DMCAcrobotParams | None = None) -> Task:
    """Build ``dmc_acrobot`` (module docstring)."""
    p = params or DMCAcrobotParams()

    def stage_cost(x: ca.SX, u: ca.SX) -> ca.SX:
        dx, dz = dmc_acrobot_tip_to_target(p, x)
        return dx**2 + dz**2 + p.control_weight * u[0] ** 2

    inf = np.inf
    return build_dmc_task(
        TaskSpec(
            name="dmc_acrobot",
            state_names=("shoulder", "elbow", "shoulder_vel", "elbow_vel"),
            control_name="elbow",
            model=dmc_acrobot_model(p),
            stage_cost=stage_cost,
            angles=(0, 1),
            x_low=np.full(4, -inf),
            x_high=np.full(4, inf),
            x0_low=np.array([-np.pi, -np.pi, 0.0, 0.0]),
            x0_high=np.array([np.pi, np.pi, 0.0, 0.0]),
            tau=p.tau,
            horizon_steps=p.horizon_steps,
            rk4_substeps=p.rk4_substeps,
            n_sub_steps=p.n_sub_steps,
            success=SuiteRewardSuccess(dmc_acrobot_reward, 1.0),
            success_text=f"suite reward 1 at x(T): tip within {p.target_radius:g} m of the target",
            params=p,
            suite=("acrobot", "swingup"),
        )
    )
