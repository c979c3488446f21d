"""``dmc_cartpole``: the DeepMind Control Suite's ``cartpole-swingup`` as a seagul task.

Model [src: ``dm_control/suite/cartpole.xml``]: the body ``cart`` (box, ``mass="1"``) slides along x on the joint
``slider``; the body ``pole_1`` hangs from the cart's origin on the hinge ``hinge_1`` about y, its capsule ``pole_1``
(``mass=".1"``, radius 0.045, ``fromto="0 0 0 0 0 1"``: centre of mass 0.5 m from the hinge, inertia by MuJoCo's
capsule rule, :func:`~seagul_envs.tasks.dmc.mechanics.capsule_inertia`)::

    [ m_c + m_p        m_p l cos th ] [xacc ]   [ m_p l sin(th) thd^2 ]   [ -b_x xd + gear u ]
    [ m_p l cos th     I_p + m_p l^2] [thacc] = [ m_p g l sin(th)     ] + [ -b_th thd        ]

with ``x = [slider, hinge_1, slider_vel, hinge_1_vel]`` (MuJoCo's ``qpos``, ``qvel``), ``hinge_1 = 0`` upright,
``b_x = 5e-4 N s/m``, ``b_th = 2e-6 N m s``, ``gear = 10`` (N per unit ctrl), ``u = ctrl in [-1, 1]``. The file sets
``integrator="RK4"`` and ``timestep = 0.01 s``; the suite's control step is one such step (``n_sub_steps = 1``,
1000 steps per 10 s episode). The task's simulator and the transcription integrate ``dynamics`` by RK4 with 0.01 s
substeps: MuJoCo's own step, to round-off (``task.extras["mujoco_step"]`` is that step as a CasADi function).

Slider range [choice]: ``slider`` has ``range="-1.8 1.8"`` (``limited``, soft ``solreflimit=".08 1"``). MuJoCo's
limit constraint acts only beyond the range, so inside it the model above is exact; beyond it the suite's cart
bounces off a soft stop that this task does not model. The task therefore makes ``|slider| <= 1.8`` a path bound:
the optimizer plans inside it and a seagul episode that leaves it terminates (a failure). dm_control's episode does
not end there; the score is its own reward.

Reward [src: ``dm_control/suite/cartpole.py``, ``Balance._get_reward``, smooth variant]::

    r = (cos th + 1)/2 * (1 + g(x; 2))/2 * (4 + 1 - u^2)/5 * (1 + g(thd; 5))/2

``g(z; m) = tolerance(z, margin=m)``, a gaussian that is 1 at 0 and 0.1 at ``|z| = m``; the control factor is
``tolerance(u, margin=1, value_at_margin=0, sigmoid="quadratic") = 1 - u^2`` on the control box. Cost [choice]:
``l = 1 - r(x, u)``, the reward itself: it is already smooth on the control box, so the surrogate is exact and
maximising the suite's return is minimising the transcription's cost (up to the time step).

Start box [src: ``Balance.initialize_episode``, ``swing_up=True``]: ``slider ~ 0.01 N(0, 1)``,
``hinge_1 ~ pi + 0.01 N(0, 1)``, each velocity ``~ 0.01 N(0, 1)``; X0 is that distribution's +-3 sigma box.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from seagul_envs.tasks.base import Task
from seagul_envs.tasks.dmc.common import SuiteRewardSuccess, TaskSpec, build_dmc_task
from seagul_envs.tasks.dmc.mechanics import (
    GRAVITY,
    ChainModel,
    PlanarBody,
    box_inertia,
    capsule_inertia,
    gaussian_sx,
    tolerance_gaussian,
)


@dataclass(frozen=True)
class DMCCartpoleParams:
    """Every constant of ``dmc_cartpole``, with its unit and its place in dm_control 1.0.52's suite."""

    rail_height: float = 1.0
    """Height of the slider (m): ``cartpole.xml`` body ``cart`` ``pos="0 0 1"`` (no effect on the dynamics)."""
    cart_mass: float = 1.0
    """Cart mass (kg): geom ``cart`` ``mass="1"``."""
    cart_half_sizes: tuple[float, float, float] = (0.2, 0.15, 0.1)
    """Cart box half-sizes (m): geom ``cart`` ``size="0.2 0.15 0.1"`` (its inertia never acts: the cart slides)."""
    pole_mass: float = 0.1
    """Pole mass (kg): default class ``pole`` geom ``mass=".1"``."""
    pole_radius: float = 0.045
    """Pole capsule radius (m): class ``pole`` geom ``size="0.045"``."""
    pole_length: float = 1.0
    """Pole capsule length (m): class ``pole`` geom ``fromto="0 0 0 0 0 1"``."""
    slider_damping: float = 5e-4
    """Slider damping (N s/m): joint ``slider`` ``damping="5e-4"``."""
    hinge_damping: float = 2e-6
    """Hinge damping (N m s): class ``pole`` joint ``damping="2e-6"``."""
    slider_range: float = 1.8
    """Slider limit (m): joint ``slider`` ``range="-1.8 1.8"``; a path bound here (module docstring)."""
    gear: float = 10.0
    """Force per unit ctrl (N): motor ``slide`` ``gear="10"``."""
    ctrl_max: float = 1.0
    """Control bound: motor ``slide`` ``ctrlrange="-1 1"``."""
    g: float = GRAVITY
    """Gravity (m/s^2): MuJoCo's default."""
    timestep: float = 0.01
    """MuJoCo step (s): ``<option timestep="0.01" integrator="RK4">``."""
    n_sub_steps: int = 1
    """MuJoCo steps per control step: ``cartpole.py`` ``swingup`` passes no ``control_timestep``."""
    time_limit: float = 10.0
    """Suite episode length (s): ``cartpole.py`` ``_DEFAULT_TIME_LIMIT``."""
    centered_margin: float = 2.0
    """Cart-position margin of the reward (m): ``rewards.tolerance(cart_position, margin=2)``."""
    control_margin: float = 1.0
    """Control margin of the reward: ``rewards.tolerance(control, margin=1, ..., sigmoid='quadratic')``."""
    velocity_margin: float = 5.0
    """Pole-speed margin of the reward (rad/s): ``rewards.tolerance(angular_vel, margin=5)``."""
    reset_std: float = 0.01
    """Standard deviation of the reset noise: ``.01 * random.randn()`` on every coordinate (``initialize_episode``)."""
    reset_box_sigmas: float = 3.0
    """X0's half-width in reset standard deviations [choice: holds 0.9973^4 = 98.9 % of the suite's resets]."""
    success_reward: float = 0.95
    """Final reward (zero control) that counts as a success [choice]."""
    tau: float = 4.0
    """Time to go of the full-horizon problem (s) [choice: the swing-up takes about 2 s at full force]."""
    horizon_steps: int = 80
    """Transcription intervals (0.05 s each) [choice]."""
    rk4_substeps: int = 5
    """RK4 substeps per interval: 0.01 s, MuJoCo's own RK4 step [choice]."""


def dmc_cartpole_model(p: DMCCartpoleParams) -> ChainModel:
    """The MJCF's mechanics: bodies ``cart`` and ``pole_1``."""
    pole_inertia, _ = capsule_inertia(p.pole_mass, p.pole_radius, p.pole_length)
    cart = PlanarBody(
        parent=-1,
        pos=(0.0, p.rail_height),
        joint="slide",
        mass=p.cart_mass,
        com=(0.0, 0.0),
        inertia_y=box_inertia(p.cart_mass, p.cart_half_sizes)[1],
    )
    pole = PlanarBody(
        parent=0, pos=(0.0, 0.0), joint="hinge", mass=p.pole_mass, com=(0.0, p.pole_length / 2), inertia_y=pole_inertia
    )
    return ChainModel(
        bodies=(cart, pole),
        damping=(p.slider_damping, p.hinge_damping),
        actuated=0,
        gear=p.gear,
        ctrl_range=(-p.ctrl_max, p.ctrl_max),
        timestep=p.timestep,
        integrator="RK4",
        g=p.g,
    )


def dmc_cartpole_reward(p: DMCCartpoleParams, x: np.ndarray, u: np.ndarray) -> float:
    """The suite's smooth swing-up reward at ``x`` and ``u`` (module docstring), as dm_control computes it."""
    upright = (np.cos(x[1]) + 1) / 2
    centered = (1 + tolerance_gaussian(x[0], p.centered_margin)) / 2
    scaled_u = float(u[0]) / p.control_margin
    small_control = (4 + (1 - scaled_u**2 if abs(scaled_u) < 1 else 0.0)) / 5
    small_velocity = (1 + tolerance_gaussian(x[3], p.velocity_margin)) / 2
    return float(upright * small_control * small_velocity * centered)


def make_dmc_cartpole_task(params: DMCCartpoleParams | None = None) -> Task:
    """Build ``dmc_cartpole`` (module docstring)."""
    p = params or DMCCartpoleParams()

    def stage_cost(x: ca.SX, u: ca.SX) -> ca.SX:
        upright = (ca.cos(x[1]) + 1) / 2
        centered = (1 + gaussian_sx(x[0], p.centered_margin)) / 2
        small_control = (4 + 1 - (u[0] / p.control_margin) ** 2) / 5  # the quadratic sigmoid on the control box
        small_velocity = (1 + gaussian_sx(x[3], p.velocity_margin)) / 2
        return 1 - upright * small_control * small_velocity * centered

    inf = np.inf
    noise = p.reset_box_sigmas * p.reset_std * np.ones(4)
    start = np.array([0.0, np.pi, 0.0, 0.0])
    return build_dmc_task(
        TaskSpec(
            name="dmc_cartpole",
            state_names=("slider", "hinge_1", "slider_vel", "hinge_1_vel"),
            control_name="slide",
            model=dmc_cartpole_model(p),
            stage_cost=stage_cost,
            angles=(1,),
            x_low=np.array([-p.slider_range, -inf, -inf, -inf]),
            x_high=np.array([p.slider_range, inf, inf, inf]),
            x0_low=start - noise,
            x0_high=start + noise,
            tau=p.tau,
            horizon_steps=p.horizon_steps,
            rk4_substeps=p.rk4_substeps,
            n_sub_steps=p.n_sub_steps,
            success=SuiteRewardSuccess(dmc_cartpole_reward, p.success_reward),
            success_text=f"suite reward >= {p.success_reward:g} at x(T) (zero control), cart inside the rail",
            params=p,
            suite=("cartpole", "swingup"),
        )
    )
