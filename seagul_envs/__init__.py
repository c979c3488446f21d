"""seagul_envs: tasks (one CasADi model per system) and their Gymnasium environments.

Importing this package registers ``SeagulAcrobot-v0``, ``SeagulAcrobotMujoco-v0`` and ``SeagulGlider-v0``
(idempotently), so ``gym.make("seagul_envs:SeagulGlider-v0")`` also works in subprocess vector envs.

Custom tasks: :func:`make_env` turns any :class:`Task` into an env with the built-ins' conventions, and
:func:`register_task` adds a task factory to :func:`make_task` and to ``gym.make`` (in the calling process; workers
must import the module that registers it, or receive the Task by pickling). A task's :class:`TaskProfile` carries
how the library treats it (solver plan, validation set, success rule, presets, ...); :func:`load_task` resolves a
command-line ``--task`` value (a name or ``module:factory``). See docs/tutorials/custom-system.md.
"""

from __future__ import annotations

from seagul_envs.envs.task_env import TaskEnv
from seagul_envs.registration import ENV_IDS, make_env, register_envs, register_task, task_env_id, unregister_task
from seagul_envs.tasks import (
    EvaluationGrid,
    MPCDefaults,
    SolverDefaults,
    SuccessRule,
    Task,
    TaskProfile,
    TrajectoryPlot,
    ValidationSpec,
    available_tasks,
    load_task,
    make_task,
    resolve_task,
    rk4_map,
    validate_task,
)

register_envs()

__all__ = [
    "ENV_IDS",
    "EvaluationGrid",
    "MPCDefaults",
    "SolverDefaults",
    "SuccessRule",
    "Task",
    "TaskEnv",
    "TaskProfile",
    "TrajectoryPlot",
    "ValidationSpec",
    "available_tasks",
    "load_task",
    "make_env",
    "make_task",
    "register_envs",
    "register_task",
    "resolve_task",
    "rk4_map",
    "task_env_id",
    "unregister_task",
    "validate_task",
]
