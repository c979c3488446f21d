"""Tasks: one symbolic model per system (see :class:`~seagul_envs.tasks.base.Task`).

The registry maps a task name to a factory (a callable returning the :class:`Task`). The built-in tasks are always
there; :func:`seagul_envs.register_task` adds a user's factory for the current process. :func:`make_task` builds each
task once per process and shares the object (the simulators and solvers cache their kernels per task object).
"""

from __future__ import annotations

import threading
from collections.abc import Callable

from seagul_envs.tasks.acrobot import AcrobotParams, make_acrobot_task
from seagul_envs.tasks.base import Task, rk4_map, validate_task
from seagul_envs.tasks.glider import GliderParams, make_glider_task

TASK_FACTORIES: dict[str, Callable[[], Task]] = {
    "acrobot": make_acrobot_task,
    "glider": make_glider_task,
}
"""Every task name of this process and its factory: the built-ins plus the ones added by ``register_task``."""

BUILTIN_TASKS: frozenset[str] = frozenset(TASK_FACTORIES)
"""The tasks that ship with seagul (their names cannot be re-registered)."""

_TASKS: dict[str, Task] = {}  # the shared object of each name built so far
_LOCK = threading.RLock()  # reentrant: a factory may itself call make_task


def make_task(name: str) -> Task:
    """Return the task called ``name`` (cached: one shared object per process).

    ``name`` is a built-in task or one registered with :func:`seagul_envs.register_task` *in this process*: a worker
    process (multiprocessing, Ray, a subprocess vector env started with ``spawn``/``forkserver``) knows a registered
    name only if it imports the module that calls ``register_task`` (or receives the Task object itself by pickling).

    Raises:
        ValueError: for an unknown name; the message lists the available ones.
    """
    if not isinstance(name, str):
        raise ValueError(f"unknown task {name!r}; available tasks: {available_tasks()}")
    with _LOCK:
        task = _TASKS.get(name)
        if task is not None:
            return task
        factory = TASK_FACTORIES.get(name)
        if factory is None:
            raise ValueError(f"unknown task {name!r}; available tasks: {available_tasks()}")
        task = build_task(name, factory)
        _TASKS[name] = task
        return task


def resolve_task(task: Task | str) -> Task:
    """The :class:`Task` that ``task`` stands for: a Task object itself (checked), or a registered name's shared task.

    Entry points that accept "a Task object or a registered name" (``solve_many``, ``trajopt_batch_solver``) call it
    once, in the calling process; from then on the object travels (by pickling to worker processes and Ray actors)
    and caches are keyed by its :meth:`Task.fingerprint`, never by the name.

    Raises:
        TypeError: ``task`` is neither a Task nor a str (the message names what it is).
        ValueError: an unknown name (the message lists the available ones), or a malformed Task (``validate_task``).
    """
    if isinstance(task, Task):
        return validate_task(task)
    if isinstance(task, str):
        return make_task(task)
    raise TypeError(
        f"expected a seagul_envs Task or a registered task name (one of {available_tasks()}), "
        f"got {type(task).__name__}: {_short_repr(task)}"
    )


def build_task(name: str, factory: Callable[[], Task]) -> Task:
    """Call ``factory()`` and check that it made a well-formed :class:`Task` called ``name`` (not cached).

    Raises:
        TypeError: the factory returned something that is not a Task.
        ValueError: the task's ``name`` is not ``name``, or the task is malformed (see ``validate_task``).
    """
    try:
        task = factory()
    except Exception as e:
        e.add_note(f"(raised by the factory of task {name!r}: {_describe(factory)})")
        raise
    if not isinstance(task, Task):
        raise TypeError(
            f"the factory of task {name!r} ({_describe(factory)}) must return a seagul_envs Task, "
            f"got {type(task).__name__}"
        )
    if task.name != name:
        raise ValueError(
            f"the factory of task {name!r} ({_describe(factory)}) returned a task named {task.name!r}; a task's name "
            f"is its registry name (use dataclasses.replace(task, name={name!r}) in the factory)"
        )
    return validate_task(task)


def shared_task(name: str) -> Task | None:
    """The shared task ``name`` if :func:`make_task` has built it in this process, else None (never builds)."""
    with _LOCK:
        return _TASKS.get(name)


def available_tasks() -> list[str]:
    """Names accepted by :func:`make_task` (built-in and registered in this process)."""
    with _LOCK:
        return sorted(TASK_FACTORIES)


def _set_factory(name: str, factory: Callable[[], Task] | None, task: Task | None = None) -> None:
    """Registry update used by ``register_task``/``unregister_task`` (validation is theirs): set or drop ``name``."""
    if name in BUILTIN_TASKS:
        raise ValueError(f"{name!r} is a built-in task and cannot be replaced or removed")
    with _LOCK:
        _TASKS.pop(name, None)
        if factory is None:
            TASK_FACTORIES.pop(name, None)
            return
        TASK_FACTORIES[name] = factory
        if task is not None:
            _TASKS[name] = task


def _short_repr(obj: object, limit: int = 80) -> str:
    text = repr(obj)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _describe(factory: object) -> str:
    module = getattr(factory, "__module__", None)
    qualname = getattr(factory, "__qualname__", None)
    return f"{module}.{qualname}" if module and qualname else repr(factory)


__all__ = [
    "BUILTIN_TASKS",
    "TASK_FACTORIES",
    "AcrobotParams",
    "GliderParams",
    "Task",
    "available_tasks",
    "build_task",
    "make_task",
    "resolve_task",
    "rk4_map",
    "shared_task",
    "validate_task",
]
