"""The one env registry: the built-in env ids (idempotent; Gymnasium 1.x has no plugin entry points),
:func:`register_task`, which adds a user's task to :func:`~seagul_envs.tasks.make_task` and to ``gym.make``, and the
task -> env lookup, :func:`env_class_for` and :func:`make_env` (``seagul_envs.make_env``).

It imports the env classes (:class:`~seagul_envs.envs.task_env.TaskEnv`); no env module imports it, so there is no
import cycle and every import is at module level.

Every seagul id is registered with ``max_episode_steps`` computed from its task: the longest admissible episode at
the task's control period, ``ceil(max T0 / control_period)``
(:func:`~seagul_envs.envs.base.longest_episode_steps`). The envs truncate themselves when the time to go reaches 0,
and an episode may be reset with any time to go in ``(0, max T0]``; a ``TimeLimit`` of the nominal episode
(``tau_nominal / control_period``) would cut the longer ones before their end and drop their terminal cost. With
the longest one, ``gym.make``'s ``TimeLimit`` and the env's own truncation end an episode of ``max T0`` on the same
step, and a shorter episode ends earlier by the env alone. ``reward_threshold`` stays None (see
:func:`register_envs`).
"""

from __future__ import annotations

import functools
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import cloudpickle
import gymnasium as gym
from gymnasium.envs.registration import EnvSpec, load_env_creator

from seagul_envs.envs.base import TaskSimulatorEnv, longest_episode_steps
from seagul_envs.envs.task_env import TaskEnv
from seagul_envs.tasks import (
    _LOCK,
    BUILTIN_TASKS,
    TASK_FACTORIES,
    Task,
    _describe,
    _set_factory,
    build_task,
    make_task,
    shared_task,
    validate_task,
)

ENV_IDS: dict[str, str] = {
    "SeagulAcrobot-v0": "seagul_envs.envs.acrobot:AcrobotEnv",
    "SeagulAcrobotMujoco-v0": "seagul_envs.envs.acrobot_mujoco:AcrobotMujocoEnv",
    "SeagulGlider-v0": "seagul_envs.envs.glider:GliderEnv",
}

ENV_TASKS: dict[str, str] = {
    "SeagulAcrobot-v0": "acrobot",
    "SeagulAcrobotMujoco-v0": "acrobot",
    "SeagulGlider-v0": "glider",
}
"""The task each built-in id simulates; its ``max_episode_steps`` is computed from that task."""

TASK_ENV_IDS: dict[str, str] = {}
"""Task name -> Gymnasium id, for the tasks registered with :func:`register_task` in this process."""

_TASK_NAME = re.compile(r"[a-z][a-z0-9]*(?:_[a-z0-9]+)*")


def register_envs() -> None:
    """Register every seagul env id once; calling it again is a no-op.

    ``max_episode_steps`` is the task's longest admissible episode (module docstring): 50 steps of 0.1 s for the
    acrobot (T0 is the single value 5 s) and 34 steps of 25 ms for the glider (``tau_max = 0.85`` s; the nominal
    0.8 s episode has 32 and ends by the env's own truncation). ``reward_threshold`` is None: success is a condition
    on the final state (``task.profile.success``: the acrobot within 0.05 of upright, the glider on the perch
    without a crash), not a return level, and the return (minus the trajectory cost) depends on the start, so no
    single return separates success from failure.
    """
    for env_id, entry_point in ENV_IDS.items():
        if env_id not in gym.registry:
            gym.register(
                id=env_id,
                entry_point=entry_point,
                max_episode_steps=longest_episode_steps(make_task(ENV_TASKS[env_id])),
                reward_threshold=None,  # success is not a return level (see the docstring)
                disable_env_checker=False,
            )


def task_env_id(name: str) -> str:
    """The Gymnasium id of task ``name``: ``"pendulum"`` -> ``"SeagulPendulum-v0"``, ``"cart_pole"`` ->
    ``"SeagulCartPole-v0"``."""
    return "Seagul" + "".join(part[:1].upper() + part[1:] for part in name.split("_")) + "-v0"


@dataclass(frozen=True)
class TaskEnvCreator:
    """The entry point of a registered task's Gymnasium id: ``TaskEnvCreator(name, factory)(**env_kwargs)``.

    It carries the factory, so a spec pickled into a subprocess vector env (``gym.make_vec(id,
    vectorization_mode="async")``, which cloudpickles the spec) builds the task there even if that process never
    imported the module that called :func:`register_task`; the name is then registered in the worker too.
    """

    name: str
    factory: Callable[[], Task]

    def __call__(self, **kwargs: Any) -> gym.Env:
        task = kwargs.pop("task", None)
        if task is None:
            task = _task_for(self.name, self.factory)
        elif not isinstance(task, Task) or task.name != self.name:
            got = task.name if isinstance(task, Task) else type(task).__name__
            raise ValueError(f"{task_env_id(self.name)} needs a {self.name} task, got {got!r}")
        return TaskEnv(task=task, **kwargs)


def register_task(name: str, factory: Callable[[], Task], *, overwrite: bool = False) -> str:
    """Register ``factory`` as task ``name`` in this process; return its Gymnasium id (``"Seagul<CamelName>-v0"``).

    Afterwards ``seagul_envs.make_task(name)`` returns the task (built once, here, to check it; shared afterwards),
    ``available_tasks()`` lists it, and ``gym.make(id)`` / ``gym.make_vec(id, ...)`` make a
    :class:`~seagul_envs.envs.task_env.TaskEnv` of it (``gym.make(id, task=variant)`` takes a variant of the same
    name). Registering the same factory again is a no-op, so a module may call this at import time. The id's
    ``max_episode_steps`` is the task's longest admissible episode, ``ceil(max T0 / control_period)``, so ``gym.make``'s
    ``TimeLimit`` agrees with the env's own truncation; its ``reward_threshold`` is None.

    The registration lives in this process only. A worker process (multiprocessing, Ray, a ``spawn``/``forkserver``
    subprocess) that calls ``make_task(name)`` or ``gym.make(id)`` must import the module that calls
    ``register_task`` first, or be given the Task object itself (Tasks and envs pickle by value). Forked workers
    inherit it; async vector envs made from the id carry the factory (see ``TaskEnvCreator``); and Gymnasium's
    ``gym.make("my_package.my_tasks:SeagulPendulum-v0")`` imports ``my_package.my_tasks`` (which registers) first.

    Args:
        name: lower snake case (``"pendulum"``, ``"cart_pole"``): a letter, then letters, digits and single
            underscores. It must equal the ``name`` of the Task the factory returns; built-in names are reserved.
        factory: a picklable zero-argument callable returning the :class:`~seagul_envs.tasks.base.Task` (a
            module-level function, a ``functools.partial`` of one, or an instance of a module-level class).
        overwrite: replace a different factory already registered under ``name`` (envs made before keep their
            task; ``make_task(name)`` returns the new one).

    Raises:
        ValueError: a bad or built-in name; ``name`` already registered with a different factory and not
            ``overwrite``; its Gymnasium id already taken by another env; the task's name is not ``name``; a
            malformed task (see :func:`~seagul_envs.tasks.base.validate_task`).
        TypeError: ``factory`` is not callable, not picklable, or does not return a Task.
    """
    if not isinstance(name, str) or not _TASK_NAME.fullmatch(name):
        raise ValueError(
            f"bad task name {name!r}: use lower snake case (e.g. 'pendulum', 'cart_pole'): a letter, then letters, "
            "digits and single underscores"
        )
    if name in BUILTIN_TASKS:
        raise ValueError(f"{name!r} is a built-in task and cannot be re-registered; choose another name")
    if isinstance(factory, Task):
        raise TypeError(
            f"register_task({name!r}, ...) needs a factory returning the Task, not the Task itself (e.g. a "
            "module-level function that builds it)"
        )
    if not callable(factory):
        raise TypeError(f"the factory of task {name!r} must be a callable returning a Task, got {factory!r}")
    env_id = task_env_id(name)
    with _LOCK:
        existing = TASK_FACTORIES.get(name)
        if existing is not None and not overwrite:
            if not _same_factory(existing, factory):
                raise ValueError(
                    f"task {name!r} is already registered with a different factory ({_describe(existing)}); pass "
                    "overwrite=True to replace it"
                )
            if TASK_ENV_IDS.get(name) == env_id and env_id in gym.registry:
                return env_id  # the same registration again (e.g. a module imported twice)
        owner = gym.registry.get(env_id)
        ours = owner is not None and isinstance(owner.entry_point, TaskEnvCreator) and owner.entry_point.name == name
        if owner is not None and not ours and (env_id in ENV_IDS or not overwrite):
            raise ValueError(
                f"the Gymnasium id {env_id!r} of task {name!r} is already registered (entry point "
                f"{owner.entry_point!r}); choose another task name"
            )
        try:
            cloudpickle.dumps(factory)
        except Exception as e:
            raise TypeError(
                f"the factory of task {name!r} must be picklable (a module-level function, a functools.partial of "
                f"one, or an instance of a module-level class): {type(e).__name__}: {e}"
            ) from e
        task = build_task(name, factory)  # raises before anything is registered
        _set_factory(name, factory, task)
        gym.registry.pop(env_id, None)  # ours (overwrite) or, with overwrite=True, someone else's
        gym.register(
            id=env_id,
            entry_point=TaskEnvCreator(name, factory),
            max_episode_steps=longest_episode_steps(task),
            reward_threshold=None,  # a task's success is its SuccessRule on the final state, not a return level
            disable_env_checker=False,
        )
        TASK_ENV_IDS[name] = env_id
    return env_id


def unregister_task(name: str) -> None:
    """Undo :func:`register_task`: drop ``name`` from ``make_task`` and its id from the Gymnasium registry.

    Raises:
        ValueError: ``name`` is built in or not registered.
    """
    with _LOCK:
        if name in BUILTIN_TASKS:
            raise ValueError(f"{name!r} is a built-in task and cannot be unregistered")
        if name not in TASK_FACTORIES:
            raise ValueError(f"task {name!r} is not registered; registered tasks: {sorted(TASK_ENV_IDS)}")
        _set_factory(name, None)
        env_id = TASK_ENV_IDS.pop(name, None)
        if env_id is not None:
            gym.registry.pop(env_id, None)


def _task_for(name: str, factory: Callable[[], Task]) -> Task:
    """The task a registered id's entry point simulates, in whatever process it runs."""
    with _LOCK:
        current = TASK_FACTORIES.get(name)
        if current is None:  # a worker that received the spec by pickling: register here as well
            register_task(name, factory)
            return make_task(name)
        if _same_factory(current, factory):
            return make_task(name)
        return build_task(name, factory)  # the name was re-registered since this spec was made: keep its factory


def _same_factory(a: object, b: object) -> bool:
    """Same callable: identical, equal, partials of the same thing, or one module-level function defined again
    (a re-imported module)."""
    if a is b:
        return True
    try:
        if a == b:
            return True
    except Exception:
        return False
    if isinstance(a, functools.partial) and isinstance(b, functools.partial):
        try:
            return _same_factory(a.func, b.func) and a.args == b.args and a.keywords == b.keywords
        except Exception:
            return False
    qa, qb = getattr(a, "__qualname__", None), getattr(b, "__qualname__", None)
    return (
        isinstance(qa, str)
        and qa == qb
        and "<" not in qa  # lambdas and closures with one qualname may build different tasks
        and getattr(a, "__module__", None) == getattr(b, "__module__", None)
    )


# ------------------------------------------------------------------------------------------------ task -> env
def env_class_for(task: Task) -> type[TaskSimulatorEnv]:
    """The env class that simulates ``task``: the class registered under ``task.profile.env_id`` when it simulates
    systems of the task's parameter class (its ``params_class``: a built-in system and its variants, which render
    and, for the glider, have the elevator stop), else the generic :class:`TaskEnv`. Nothing is looked up by name."""
    env_id = task.profile.env_id
    if not env_id or env_id not in gym.registry:
        return TaskEnv
    registered = gym.registry[env_id].entry_point
    entry: Any = load_env_creator(registered) if isinstance(registered, str) else registered
    params_class = getattr(entry, "params_class", None)
    if isinstance(entry, type) and issubclass(entry, TaskSimulatorEnv) and params_class is not None:
        if isinstance(task.params, params_class):
            return entry
    return TaskEnv


def make_env(task: Task | str, **kwargs: Any) -> gym.Env:
    """A Gymnasium env for ``task`` (any :class:`Task`, or a task name), made like ``gym.make`` makes the built-ins.

    The result is what ``gym.make`` returns (the env wrapped in Gymnasium's env checker and order enforcing;
    ``.unwrapped`` is the seagul env, with ``spec`` set so ``env.spec.make()`` makes a copy):

    * a built-in task (``make_task("acrobot")``, or a variant of the same system such as
      ``make_acrobot_task(AcrobotParams(b1=0))``) gives its built-in env, exactly ``gym.make("SeagulAcrobot-v0")``
      (``task=`` the variant); ``make_env("glider")`` is ``gym.make("SeagulGlider-v0")``;
    * the shared task of a name registered with :func:`seagul_envs.register_task` gives ``gym.make`` of its id;
    * any other task gives a :class:`TaskEnv` (observation = state + time to go, action = the task's input box,
      reward = ``-h l(x, u)`` per step and ``-l_f`` at the end, ``reset(options={"state", "time_to_go"})``).

    ``kwargs`` are the env's (``dt``, ``render_mode``, ``max_substep``; ``renderer`` for a :class:`TaskEnv`) and
    ``gym.make``'s own (``max_episode_steps``, ``disable_env_checker``, ...). An unregistered task travels inside the
    env (and its spec): pickling the env pickles the Task by value, so workers need not know the task's name.

    Unless ``max_episode_steps`` is given, the ``TimeLimit`` is the task's longest admissible episode at the env's
    ``dt`` (:func:`~seagul_envs.envs.base.longest_episode_steps`): a ``dt`` other than the task's control period,
    or a variant task with another T0, gets the limit that fits it (a plain ``gym.make(id, dt=...)`` keeps the
    registered one, counted in default control periods).

    Raises:
        TypeError: ``task`` is neither a Task nor a name.
        ValueError: an unknown name, or a malformed Task (see :func:`~seagul_envs.tasks.base.validate_task`).
    """
    if isinstance(task, str):
        task = make_task(task)
    if not isinstance(task, Task):
        raise TypeError(f"make_env needs a seagul_envs Task or a task name, got {type(task).__name__}")
    cls = env_class_for(task)
    if cls is not TaskEnv:
        env_id = str(task.profile.env_id)
        kwargs = _with_time_limit(task, gym.spec(env_id).max_episode_steps, kwargs)
        return gym.make(env_id, **kwargs) if task is shared_task(task.name) else gym.make(env_id, task=task, **kwargs)
    validate_task(task)
    registered_id = TASK_ENV_IDS.get(task.name)
    if registered_id is not None and task is shared_task(task.name):
        return gym.make(registered_id, **_with_time_limit(task, gym.spec(registered_id).max_episode_steps, kwargs))
    # gym.make calls entry_point(**kwargs) with ``task`` among them; Gymnasium's EnvCreator protocol (``**kwargs`` only)
    # rejects a constructor with a named ``task`` parameter.
    spec = EnvSpec(
        id=task_env_id(task.name),
        entry_point=TaskEnv,  # type: ignore[arg-type]
        max_episode_steps=_with_time_limit(task, None, kwargs).get("max_episode_steps"),
        disable_env_checker=False,
    )
    return gym.make(spec, task=task, **kwargs)


def _with_time_limit(task: Task, registered: int | None, kwargs: dict[str, Any]) -> dict[str, Any]:
    """``kwargs`` with ``max_episode_steps`` = the task's longest episode at ``kwargs["dt"]`` when that differs from
    the ``registered`` limit; the caller's own ``max_episode_steps`` wins, and a bad ``dt`` is left to the env's
    constructor to name."""
    if "max_episode_steps" in kwargs:
        return kwargs
    try:
        steps = longest_episode_steps(task, kwargs.get("dt"))
    except ValueError:
        return kwargs
    return kwargs if steps == registered else {**kwargs, "max_episode_steps": steps}
