"""The DeepMind Control Suite's pendulum, cart-pole and acrobot swing-ups as seagul tasks (docs/tutorials/dmc-tasks.md).

``make_task("dmc_pendulum")``, ``make_task("dmc_cartpole")`` and ``make_task("dmc_acrobot")`` are CasADi models equal
to the suite's MJCF files (``dm_control/suite/{pendulum,cartpole,acrobot}.xml``): the state is
``x = [qpos, qvel]`` in the file's joint order, so ``np.concatenate([physics.data.qpos, physics.data.qvel])`` of a
dm_control environment is the task's state, and the control ``u`` is the actuator's ``ctrl`` in its ``ctrlrange``
(the gear multiplies it). Masses, centres of mass and inertias are derived from the geoms by MuJoCo's rules; joint
damping, gear, gravity, integrator and timestep are the files'. ``task.extras["mujoco_step"]`` is MuJoCo's own
``mj_step`` (the suite's control step) as a CasADi function, and ``extras["mass_matrix"]``, ``["bias"]``,
``["passive"]`` and ``["qacc"]`` are ``mj_fullM``, ``qfrc_bias``, ``qfrc_passive`` and ``qacc``;
``tests/test_dmc_tasks.py`` checks all of them against MuJoCo and dm_control to 1e-9.

The costs are smooth surrogates of the suite's rewards (each module's docstring says which and why); the benchmark's
score is always dm_control's own reward (``dmc_*_reward`` computes it from a state). The models need neither
dm_control nor MuJoCo; comparing with them needs the ``seagul[dmc]`` extra.
"""

from __future__ import annotations

from collections.abc import Callable

from seagul_envs.tasks.base import Task
from seagul_envs.tasks.dmc.acrobot import (
    DMCAcrobotParams,
    dmc_acrobot_model,
    dmc_acrobot_reward,
    make_dmc_acrobot_task,
)
from seagul_envs.tasks.dmc.cartpole import (
    DMCCartpoleParams,
    dmc_cartpole_model,
    dmc_cartpole_reward,
    make_dmc_cartpole_task,
)
from seagul_envs.tasks.dmc.common import SuiteRewardSuccess
from seagul_envs.tasks.dmc.mechanics import ChainModel, PlanarBody
from seagul_envs.tasks.dmc.pendulum import (
    DMCPendulumParams,
    dmc_pendulum_model,
    dmc_pendulum_reward,
    make_dmc_pendulum_task,
)

DMC_TASK_FACTORIES: dict[str, Callable[[], Task]] = {
    "dmc_acrobot": make_dmc_acrobot_task,
    "dmc_cartpole": make_dmc_cartpole_task,
    "dmc_pendulum": make_dmc_pendulum_task,
}
"""Task name -> factory of the suite tasks (``seagul_envs.tasks.TASK_FACTORIES`` includes them)."""

DMC_SUITE_NAMES = {
    "dmc_acrobot": ("acrobot", "swingup"),
    "dmc_cartpole": ("cartpole", "swingup"),
    "dmc_pendulum": ("pendulum", "swingup"),
}
"""Task name -> ``(domain, task)`` of ``dm_control.suite.load`` (Gymnasium through shimmy:
``gym.make("dm_control/<domain>-<task>-v0")``)."""

__all__ = [
    "DMC_SUITE_NAMES",
    "DMC_TASK_FACTORIES",
    "ChainModel",
    "DMCAcrobotParams",
    "DMCCartpoleParams",
    "DMCPendulumParams",
    "PlanarBody",
    "SuiteRewardSuccess",
    "dmc_acrobot_model",
    "dmc_acrobot_reward",
    "dmc_cartpole_model",
    "dmc_cartpole_reward",
    "dmc_pendulum_model",
    "dmc_pendulum_reward",
    "make_dmc_acrobot_task",
    "make_dmc_cartpole_task",
    "make_dmc_pendulum_task",
]
