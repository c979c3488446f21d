"""A Gymnasium env for any :class:`~seagul_envs.tasks.base.Task`: :class:`TaskEnv`.

:func:`~seagul_envs.registration.make_env` (``seagul_envs.make_env``), which picks the env class of a task and makes
it like ``gym.make``, lives with the env registration in :mod:`seagul_envs.registration`; this module knows no
registry, so the registry imports it and not the other way round. ``make_env`` and ``env_class_for`` imported from
here still work, with a ``DeprecationWarning``, until the next release.
"""

from __future__ import annotations

import importlib
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np

from seagul_envs.envs.base import TaskSimulatorEnv
from seagul_envs.tasks import Task, validate_task

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


_MOVED = ("make_env", "env_class_for")
"""Functions that moved to :mod:`seagul_envs.registration` (old names kept for one release)."""


def __getattr__(name: str) -> Any:
    """``make_env`` and ``env_class_for``, moved to :mod:`seagul_envs.registration`: imported from there by module
    path on first use (an import at module level would be the old import cycle), with a deprecation warning."""
    if name in _MOVED:
        new = "seagul_envs.make_env" if name == "make_env" else f"seagul_envs.registration.{name}"
        warnings.warn(
            f"seagul_envs.envs.task_env.{name} is deprecated and will be removed in the next release; use {new}",
            DeprecationWarning,
            stacklevel=2,
        )
        return getattr(importlib.import_module("seagul_envs.registration"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
