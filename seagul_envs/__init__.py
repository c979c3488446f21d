"""seagul_envs: tasks (one CasADi model per system) and their Gymnasium environments.

Importing this package registers ``SeagulAcrobot-v0``, ``SeagulAcrobotMujoco-v0`` and ``SeagulGlider-v0``
(idempotently), so ``gym.make("seagul_envs:SeagulGlider-v0")`` also works in subprocess vector envs.
"""

from __future__ import annotations

from seagul_envs.registration import ENV_IDS, register_envs
from seagul_envs.tasks import Task, available_tasks, make_task

register_envs()

__all__ = ["ENV_IDS", "Task", "available_tasks", "make_task", "register_envs"]
