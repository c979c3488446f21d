"""A Gymnasium env for any :class:`~seagul_envs.tasks.base.Task`: :class:`TaskEnv` and :func:`make_env`."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.envs.registration import EnvSpec, load_env_creator

from seagul_envs.envs.base import TaskSimulatorEnv, longest_episode_steps
from seagul_envs.tasks import Task, make_task, shared_task, validate_task

Renderer = Callable[[Task, np.ndarray, np.ndarray, float], np.ndarray]
"""``renderer(task, state, last_action, time_to_go) -> (H, W, 3) uint8 frame``: how a custom task draws itself."""


class TaskEnv(TaskSimulatorEnv):
    """Any ``Task`` as a Gymnasium env, with the conventions of the built-in envs.

    Made by ``seagul_envs.make_env(task)``, or by ``gym.make`` of the id ``Seagul<CamelName>-v0`` that
    ``seagul_envs.register_task(name, factory)`` returns. The built-in tasks have their own env classes
    (``SeagulAcrobot-v0``, ``SeagulGlider-v0``); every quantity below is a field of the ``Task``.

    **Description**

    Simulates ``task.dynamics`` with the action held over each control period ``dt`` (zero-order hold), integrated
    with RK4 substeps of at most ``max_substep`` (``task.simulator(dt)``, the same map as the trajectory optimizer
    and the MPC use). The task's costs make the reward, its bounds the termination and its time to go the episode's
    length, so the return of an episode is minus the cost of the optimal-control problem the task poses.

    **Action Space**

    ``Box(task.u_low, task.u_high, (task.nu,), float32)``, in the task's physical units (``task.control_names``).
    Actions outside the box are clipped, and the reward charges the clipped input. A NaN/inf or wrongly shaped
    action raises ``ValueError`` and leaves the env unchanged.

    **Observation Space**

    ``Box((task.nx + 1,), float32)``: the state (``task.state_names``; bounds +- float32 max) followed by the time
    to go in ``[0, task.tau_range[1]]`` seconds. ``info["state"]`` is the float64 state and ``info["time_to_go"]``
    the time to go, in the infos of ``reset`` and ``step``.

    **Rewards**

    A step of length ``h`` from ``x_k`` with input ``u_k`` earns ``-h * l(x_k, u_k)`` (``l = task.stage_cost`` at
    the start of the step, the left-point rule of the transcription). The step on which the episode ends, by
    truncation or termination, also earns ``-l_f(x_end)`` (``l_f = task.terminal_cost``). An episode's return is
    therefore minus the cost of the trajectory flown.

    **Starting State**

    Uniform in X0 = ``[task.x0_low, task.x0_high]``, drawn with the env's ``np_random``; the time to go is
    ``task.tau_nominal``.

    **Episode End**

    Termination: the state leaves ``[task.x_low, task.x_high]`` (with a 1e-8 rounding slack) or stops being finite.

    Truncation: when the time to go reaches 0, after ``ceil(tau / dt)`` steps; the last one is shortened if ``tau``
    is not a multiple of ``dt``, so that the time to go reaches exactly 0. The id registered by ``register_task``
    has ``max_episode_steps = ceil(task.tau_range[1] / task.control_period)``, the longest admissible episode (and
    ``make_env`` counts it in the env's ``dt``), so ``gym.make``'s ``TimeLimit`` never ends an episode before its
    time to go reaches 0, and truncates on the same step as the env for ``tau = task.tau_range[1]``. Stepping after
    the end warns once and returns the final observation with reward 0.

    **Arguments**

    ``TaskEnv(task, dt=None, render_mode=None, max_substep=None, renderer=None, params=None)``, the same keywords
    for ``make_env(task, ...)`` and ``gym.make(id, ...)`` (which also takes ``task``, a variant of the registered
    name):

    * ``dt``: the control period in seconds (default ``task.control_period``). ``make_env`` fits the
      ``TimeLimit`` to it; with ``gym.make`` of a registered id also pass ``max_episode_steps`` or
      ``max_episode_steps=-1``.
    * ``render_mode``: ``"rgb_array"`` or ``"human"``; it needs a ``Renderer``, ``renderer`` or
      ``task.extras["renderer"]``. Without one, ``metadata["render_modes"]`` is empty, ``render_mode`` must be None
      (anything else raises ``ValueError``) and ``render()`` warns and returns None, as Gymnasium expects.
      ``render_fps`` is ``max(1, round(1 / dt))``.
    * ``max_substep``: the largest RK4 substep in seconds (default ``task.max_sim_substep``).
    * ``renderer``: ``renderer(task, state, last_action, time_to_go) -> (H, W, 3) uint8 frame``.
    * ``params``: another robot than the task's model, ``{name: value}`` over ``task.parameters.names`` or a full
      vector (needs ``task.parameters``).

    ``reset(seed=None, options=None)`` takes the options (all optional):

    * ``"state"``: the start, any finite state inside ``[task.x_low, task.x_high]``.
    * ``"time_to_go"``: ``tau`` in ``(0, task.tau_range[1]]`` seconds.
    * ``"params"``: the robot from this episode on, as the ``params`` argument.

    Unknown keys and bad values raise ``ValueError`` and leave the env as it was.

    **Version History**

    * v0: initial version.

    **References**

    * B. Landry, H. Dai and M. Pavone, "SEAGuL: Sample Efficient Adversarially Guided Learning of Value
      Functions", Learning for Dynamics and Control (L4DC), PMLR 144, 2021. arXiv:2107.08893.
    """

    # The class lists every mode a TaskEnv can have (gym.make reads it before construction); each instance narrows it
    # to the modes its task supports.
    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 10}  # noqa: RUF012 (Gymnasium convention)

    def __init__(
        self,
        task: Task,
        dt: float | None = None,
        render_mode: str | None = None,
        max_substep: float | None = None,
        renderer: Renderer | None = None,
        params: Any = None,
    ) -> None:
        validate_task(task)
        renderer = task.extras.get("renderer") if renderer is None else renderer
        if renderer is not None and not callable(renderer):
            raise TypeError(f"{task.name}: renderer must be a callable (see seagul_envs.envs.task_env.Renderer)")
        if render_mode is not None and renderer is None:
            raise ValueError(
                f"{task.name}: render_mode={render_mode!r} needs a renderer, and this task provides none; put a "
                "renderer(task, state, last_action, time_to_go) -> RGB array in task.extras['renderer'] or pass "
                "make_env(task, renderer=...), or use render_mode=None"
            )
        self.renderer = renderer
        self.metadata = {"render_modes": ["human", "rgb_array"] if renderer is not None else [], "render_fps": 10}
        super().__init__(task, dt=dt, render_mode=render_mode, max_substep=max_substep, params=params)
        self.metadata["render_fps"] = max(1, round(1.0 / self.dt))

    def _render_frame(self) -> np.ndarray:
        assert self.renderer is not None  # render_mode is None without one
        frame = np.asarray(self.renderer(self.task, self._x.copy(), self._last_u.copy(), self.time_to_go))
        if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3:
            raise ValueError(
                f"{self.task.name}: the renderer must return an (H, W, 3) uint8 array, got {frame.dtype} of shape "
                f"{frame.shape}"
            )
        return frame


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
    from seagul_envs.registration import TASK_ENV_IDS, task_env_id

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
