"""Tasks: one symbolic model per system (see :class:`~seagul_envs.tasks.base.Task`).

The registry maps a task name to a factory (a callable returning the :class:`Task`). The built-in tasks are always
there; :func:`seagul_envs.register_task` adds a user's factory for the current process. :func:`make_task` builds each
task once per process and shares the object (the simulators and solvers cache their kernels per task object).
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

from seagul_envs.tasks.acrobot import AcrobotParams, make_acrobot_task
from seagul_envs.tasks.base import Task, rk4_map, validate_task
from seagul_envs.tasks.dmc import DMC_TASK_FACTORIES
from seagul_envs.tasks.glider import GliderParams, make_glider_task
from seagul_envs.tasks.mpc_defaults import MPCDefaults
from seagul_envs.tasks.profile import (
    EvaluationGrid,
    SolverDefaults,
    SuccessRule,
    TaskProfile,
    TrajectoryPlot,
    ValidationSpec,
)

TASK_FACTORIES: dict[str, Callable[[], Task]] = {
    "acrobot": make_acrobot_task,
    "glider": make_glider_task,
    **DMC_TASK_FACTORIES,  # the DeepMind Control Suite models: dmc_acrobot, dmc_cartpole, dmc_pendulum
}
"""Every task name of this process and its factory: the built-ins plus the ones added by ``register_task``."""

BUILTIN_TASKS: frozenset[str] = frozenset(TASK_FACTORIES)
"""The tasks that ship with seagul (their names cannot be re-registered)."""

_TASKS: dict[str, Task] = {}  # the shared object of each name built so far
_FILE_MODULES: dict[str, ModuleType] = {}  # modules load_task loaded from a file path, by module name
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


def load_task(spec: str) -> Task:
    """The task that a command-line ``--task`` value names: a registered name, or ``module:factory``.

    * ``"acrobot"`` (any name :func:`available_tasks` lists): ``make_task(name)``.
    * ``"my_package.my_tasks:make_cartpole"``: imports the module (the current directory is put on ``sys.path``
      first, as ``python -m`` would) and calls ``make_cartpole()``, which must return a :class:`Task`;
      ``"path/to/file.py:make_cartpole"`` loads the file instead (its directory joins ``sys.path``, so worker
      processes can import it too). The attribute may also be a Task itself. The factory is called once; the Task
      object then travels (pickled to workers), its name need not be registered.

    Raises:
        ValueError: an unknown name; a module that cannot be imported (or raised while importing); a missing
            attribute; a factory that raised, or returned something that is not a Task; a malformed Task. Each
            message names the problem and the value given.
    """
    if not isinstance(spec, str) or not spec.strip():
        raise ValueError(f"expected a task name ({', '.join(available_tasks())}) or module:factory, got {spec!r}")
    module_name, sep, attr = spec.rpartition(":")
    if not sep:
        return make_task(spec)
    if not module_name or not attr:
        raise ValueError(f"task {spec!r}: write module:factory (e.g. examples.custom_system:make_cartpole)")
    module = _import_task_module(spec, module_name)
    target: object = module
    for part in attr.split("."):
        if not hasattr(target, part):
            raise ValueError(f"task {spec!r}: module {module.__name__!r} has no attribute {attr!r}")
        target = getattr(target, part)
    if isinstance(target, Task):
        return validate_task(target)
    if not callable(target):
        raise ValueError(
            f"task {spec!r}: {attr!r} is a {type(target).__name__}, not a factory (a callable returning a Task)"
        )
    try:
        task = target()
    except Exception as e:
        raise ValueError(f"task {spec!r}: the factory {attr}() raised {type(e).__name__}: {e}") from e
    if not isinstance(task, Task):
        raise ValueError(
            f"task {spec!r}: the factory {attr}() returned a {type(task).__name__}, not a seagul_envs Task"
        )
    return validate_task(task)


def _import_task_module(spec: str, module_name: str) -> ModuleType:
    """The module of a ``module:factory`` task spec (a dotted module name or a ``.py`` file path)."""
    path = Path(module_name)
    if module_name.endswith(".py") or os.sep in module_name or "/" in module_name:
        if not path.is_file():
            raise ValueError(f"task {spec!r}: no Python file {module_name!r}")
        folder = str(path.resolve().parent)
        if folder not in sys.path:
            sys.path.insert(0, folder)
        name = path.stem
        if name in sys.modules and getattr(sys.modules[name], "__file__", None) == str(path.resolve()):
            with _LOCK:
                _FILE_MODULES.setdefault(name, sys.modules[name])
            return sys.modules[name]
        loader_spec = importlib.util.spec_from_file_location(name, path.resolve())
        if loader_spec is None or loader_spec.loader is None:
            raise ValueError(f"task {spec!r}: cannot load {module_name!r} as a Python module")
        module = importlib.util.module_from_spec(loader_spec)
        sys.modules[name] = module
        try:
            loader_spec.loader.exec_module(module)
        except Exception as e:
            sys.modules.pop(name, None)
            raise ValueError(f"task {spec!r}: loading {module_name!r} raised {type(e).__name__}: {e}") from e
        with _LOCK:
            _FILE_MODULES[name] = module
        return module
    cwd = os.getcwd()
    if cwd not in sys.path and "" not in sys.path:
        sys.path.insert(0, cwd)
    try:
        return importlib.import_module(module_name)
    except ModuleNotFoundError as e:
        if e.name is not None and (module_name == e.name or module_name.startswith(e.name + ".")):
            raise ValueError(
                f"task {spec!r}: no module named {module_name!r} (run from the directory that contains it, put it "
                "on PYTHONPATH, or give the file: path/to/file.py:factory)"
            ) from None
        raise ValueError(f"task {spec!r}: importing {module_name!r} failed: {e}") from e
    except Exception as e:
        raise ValueError(f"task {spec!r}: importing {module_name!r} raised {type(e).__name__}: {e}") from e


def file_task_modules() -> tuple[ModuleType, ...]:
    """The modules :func:`load_task` loaded from a file path in this process.

    Local worker processes inherit ``sys.path`` (the file's directory is on it) and import them by name; Ray workers
    do not, so the Ray backend has its pickler send the classes and functions of these modules by value.
    """
    with _LOCK:
        return tuple(_FILE_MODULES.values())


def task_label(task: Task | str) -> str:
    """The name of a Task or a task name (for messages, file names and tables)."""
    return task.name if isinstance(task, Task) else str(task)


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
    "EvaluationGrid",
    "GliderParams",
    "MPCDefaults",
    "SolverDefaults",
    "SuccessRule",
    "Task",
    "TaskProfile",
    "TrajectoryPlot",
    "ValidationSpec",
    "available_tasks",
    "build_task",
    "file_task_modules",
    "load_task",
    "make_task",
    "resolve_task",
    "rk4_map",
    "shared_task",
    "task_label",
    "validate_task",
]
