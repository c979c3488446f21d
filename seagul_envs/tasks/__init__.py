"""Tasks: one symbolic model per system (see :class:`~seagul_envs.tasks.base.Task`)."""

from __future__ import annotations

import functools
from collections.abc import Callable

from seagul_envs.tasks.acrobot import AcrobotParams, make_acrobot_task
from seagul_envs.tasks.base import Task, rk4_map
from seagul_envs.tasks.glider import GliderParams, make_glider_task

TASK_FACTORIES: dict[str, Callable[[], Task]] = {
    "acrobot": make_acrobot_task,
    "glider": make_glider_task,
}


@functools.cache
def make_task(name: str) -> Task:
    """Return the task called ``name`` (cached: one shared object per process).

    Raises:
        ValueError: for an unknown name; the message lists the available ones.
    """
    if not isinstance(name, str) or name not in TASK_FACTORIES:
        raise ValueError(f"unknown task {name!r}; available tasks: {sorted(TASK_FACTORIES)}")
    return TASK_FACTORIES[name]()


def available_tasks() -> list[str]:
    """Names accepted by :func:`make_task`."""
    return sorted(TASK_FACTORIES)


__all__ = ["AcrobotParams", "GliderParams", "Task", "available_tasks", "make_task", "rk4_map"]
