"""Shared machinery of the seagul Gymnasium envs (docs/reference/spec.md §7).

Every env simulates one :class:`~seagul_envs.tasks.base.Task` with a zero-order hold over a control period ``dt``.
Conventions shared by all of them:

* Observation ``[x_0, ..., x_{nx-1}, time_to_go]`` (float32); ``info["state"]`` is the exact float64 state and
  ``info["time_to_go"]`` the float time to go, in both reset and step infos.
* Reward of a step from ``x_k`` with input ``u_k`` over ``h``: ``-h * l(x_k, u_k)``, the same left-point rule as the
  transcription's running cost ``sum_k h_k l(x_k, u_k)``; on the step where the episode ends (time to go reaches 0,
  or the state leaves the task's bounds) ``-l_f(x_end)`` is added, so an episode's return is minus the cost of the
  trajectory flown. Charging ``l_f`` at a crash too keeps a crash from being cheaper than arriving at that same place.
* The episode has ``ceil(tau / dt)`` steps (:func:`episode_steps`), counted with an integer (no float
  accumulation); when ``tau`` is not a multiple of ``dt`` the last step is shorter so the time to go reaches
  exactly 0. The env itself reports ``truncated`` on that step.
* ``gym.make`` also wraps the env in Gymnasium's ``TimeLimit`` with the registered ``max_episode_steps``: the
  longest admissible episode at the task's control period, ``episode_steps(max T0, control_period)``
  (:func:`longest_episode_steps`). The env's own truncation comes first or on the same step, so the two never
  disagree for any admissible ``time_to_go``. The limit counts default control periods: with another ``dt``, pass
  ``gym.make`` the ``max_episode_steps`` that :func:`longest_episode_steps` gives for it
  (:func:`seagul_envs.make_env` does), or ``max_episode_steps=-1`` (no ``TimeLimit``).
* Actions are clipped to the Box (as Gymnasium's continuous envs do), then to any state-dependent limit of the env
  (the glider's elevator stops); a NaN/inf or wrongly shaped action raises a ValueError before anything changes.
  The reward charges the input actually applied.
* ``terminated`` when the state leaves the task's bounds ``[x_low, x_high]`` (with a 1e-8 rounding slack) or stops
  being finite.
* Stepping after the episode ended warns once (as Gymnasium's classic-control envs do) and returns the final
  observation again with reward 0, so the episode's return stays minus its cost.
"""

from __future__ import annotations

import math
from typing import Any, SupportsFloat

import casadi as ca
import gymnasium as gym
import numpy as np
from gymnasium import logger, spaces

from seagul_envs.rendering import HumanViewer
from seagul_envs.tasks import BUILTIN_TASKS, make_task, shared_task
from seagul_envs.tasks.base import Task

_RESET_OPTION_KEYS = frozenset({"state", "time_to_go", "params"})
# Observation bounds of the state entries: Gymnasium's own convention (CartPole) for unbounded coordinates.
# Infinite bounds make `check_env` warn, and the task bounds cannot serve: a crash step observes a state past them.
_FLOAT32_MAX = float(np.finfo(np.float32).max)
_BOUND_SLACK = 1e-8


class BufferedFunction:
    """A numeric CasADi Function called through its FunctionBuffer on preallocated numpy arrays.

    ``Function.__call__`` converts every argument to a DM and every result back (~20 us for the acrobot's one-period
    map); the buffer interface evaluates the same compiled SX instructions on our own memory (~8 us).
    """

    def __init__(self, function: ca.Function) -> None:
        self.function = function
        self.args = [np.zeros(function.nnz_in(i)) for i in range(function.n_in())]
        self.res = [np.zeros(function.nnz_out(i)) for i in range(function.n_out())]
        self._buffer, self._eval = function.buffer()
        # casadi.pyi lists a separate byte size; the binding takes it from the buffer (``set_arg(i, memoryview)``).
        for i, a in enumerate(self.args):
            self._buffer.set_arg(i, a.data)  # type: ignore[call-arg]
        for i, r in enumerate(self.res):
            self._buffer.set_res(i, r.data)  # type: ignore[call-arg]

    def __call__(self) -> None:
        """Evaluate on ``self.args`` into ``self.res`` (fill the inputs in place first)."""
        self._eval()


def episode_steps(tau: float, dt: float) -> int:
    """The number of control steps of an episode of time to go ``tau`` at control period ``dt``:
    ``max(1, ceil(tau / dt - 1e-9))`` (the ``1e-9`` keeps ``5.0 / 0.1 = 50.000000000000007`` from adding a 51st
    step of 1e-15 s)."""
    return max(1, math.ceil(float(tau) / float(dt) - 1e-9))


def longest_episode_steps(task: Task, dt: float | None = None) -> int:
    """The longest admissible episode of ``task`` in control steps: :func:`episode_steps` of the largest time to go
    of T0 (``task.tau_range[1]``) at ``dt`` (default ``task.control_period``).

    It is the ``max_episode_steps`` of the registered Gymnasium ids, so ``gym.make``'s ``TimeLimit`` never ends an
    episode before the env's own truncation (time to go 0), whatever ``reset(options={"time_to_go": tau})`` chose.
    """
    period = task.control_period if dt is None else dt
    return episode_steps(task.tau_range[1], _positive_seconds(period, f"{task.name}: dt"))


def resolve_task(task: Task | None, name: str, env_name: str, params_class: type | None = None) -> Task:
    """The registered task ``name``, or any :class:`Task` of the same system: one whose parameters are a
    ``params_class`` (whatever its name, e.g. a renamed variant); without ``params_class``, a task named ``name``.
    Anything else is a ValueError naming both."""
    task = make_task(name) if task is None else task
    if params_class is not None:
        if not isinstance(task.params, params_class):
            raise ValueError(
                f"{env_name} simulates {params_class.__name__} systems; task {task.name!r} has parameters of type "
                f"{type(task.params).__name__} (use seagul_envs.make_env(task) for any other system)"
            )
    elif task.name != name:
        raise ValueError(f"{env_name} needs a {name} task, got {task.name!r}")
    return task


def step_function(task: Task, dt: float, max_substep: float | None = None, params: bool = False) -> ca.Function:
    """``(x, u) -> (x(t + dt), l(x, u))``: ``task.simulator(dt, max_substep)`` and the stage cost in one call; with
    ``params`` the map of the parametric dynamics, ``(x, u, theta) -> ...`` (the same RK4 substeps)."""
    x = ca.SX.sym("x", task.nx)
    u = ca.SX.sym("u", task.nu)
    if not params:
        sim = task.simulator(dt, max_substep)
        return ca.Function(f"{task.name}_env_step", [x, u], [sim(x, u), task.stage_cost(x, u)], ["x", "u"], ["xn", "l"])
    theta = ca.SX.sym("theta", task.parameters.size if task.parameters is not None else 0)
    x_next = task.rk4_step_params(task.simulator_substeps(dt, max_substep))(x, u, dt, theta)
    return ca.Function(
        f"{task.name}_env_step_theta", [x, u, theta], [x_next, task.stage_cost(x, u)], ["x", "u", "theta"], ["xn", "l"]
    )


def variable_step_function(task: Task, substeps: int, params: bool = False) -> ca.Function:
    """``(x, u, h) -> (x(t + h), l(x, u))`` with ``substeps`` RK4 substeps (``task.rk4_step``) and the stage cost;
    with ``params`` ``(x, u, h, theta) -> ...`` of the parametric dynamics."""
    x = ca.SX.sym("x", task.nx)
    u = ca.SX.sym("u", task.nu)
    h = ca.SX.sym("h")
    if not params:
        x_next = task.rk4_step(substeps)(x, u, h)
        return ca.Function(
            f"{task.name}_env_step_h", [x, u, h], [x_next, task.stage_cost(x, u)], ["x", "u", "h"], ["xn", "l"]
        )
    theta = ca.SX.sym("theta", task.parameters.size if task.parameters is not None else 0)
    x_next = task.rk4_step_params(substeps)(x, u, h, theta)
    return ca.Function(
        f"{task.name}_env_step_h_theta",
        [x, u, h, theta],
        [x_next, task.stage_cost(x, u)],
        ["x", "u", "h", "theta"],
        ["xn", "l"],
    )


class SeagulEnv(gym.Env[np.ndarray, np.ndarray]):
    """Base class of the seagul envs; subclasses set the state and advance it (see the module docstring).

    Subclasses implement :meth:`_set_sim_state`, :meth:`_advance` and :meth:`_render_frame`, and may override
    :meth:`_restore_runtime` to rebuild unpicklable simulator handles after unpickling.
    """

    # Not a ClassVar: gymnasium.Env declares ``metadata`` as an attribute an instance may replace (TaskEnv does).
    metadata: dict[str, Any] = {"render_modes": ["human", "rgb_array"], "render_fps": 10}  # noqa: RUF012

    def __init__(
        self,
        task: Task,
        dt: float | None = None,
        render_mode: str | None = None,
        max_substep: float | None = None,
        params: Any = None,
    ) -> None:
        # The model the env was made for, and the robot it simulates (the model unless ``params`` say otherwise).
        self.model_task = task
        self.task = task if params is None else self._robot(params)
        self.dt = _positive_seconds(task.control_period if dt is None else dt, f"{task.name}: dt")
        self.max_substep = _positive_seconds(
            task.max_sim_substep if max_substep is None else max_substep, f"{task.name}: max_substep"
        )
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}")
        self.render_mode = render_mode

        nx = task.nx
        self.action_space = spaces.Box(task.u_low.astype(np.float32), task.u_high.astype(np.float32), dtype=np.float32)
        tau_max = float(task.tau_range[1])
        low = np.concatenate([np.full(nx, -_FLOAT32_MAX), [0.0]]).astype(np.float32)
        high = np.concatenate([np.full(nx, _FLOAT32_MAX), [tau_max]]).astype(np.float32)
        self.observation_space = spaces.Box(low, high, dtype=np.float32)

        # Hot-path constants (plain floats/arrays: no attribute chains or validation per step).
        self._nx = nx
        self._nu = task.nu
        self._u_low = task.u_low.astype(np.float64)
        self._u_high = task.u_high.astype(np.float64)
        self._u_low_1, self._u_high_1 = float(self._u_low[0]), float(self._u_high[0])
        self._x_low = task.x_low.astype(np.float64)
        self._x_high = task.x_high.astype(np.float64)
        # Rounding slack so that a state exactly on a bound (e.g. the glider's elevator at its stop after RK4
        # substeps, or an optimizer's solution within its tolerance) does not end the episode.
        self._x_low_tol = self._x_low - _BOUND_SLACK
        self._x_high_tol = self._x_high + _BOUND_SLACK
        self._bounded = bool(np.any(np.isfinite(self._x_low)) or np.any(np.isfinite(self._x_high)))

        # Episode bookkeeping; a fresh env must be reset before stepping (Gymnasium's OrderEnforcing checks it).
        self._x = np.zeros(nx)
        self._tau = 0.0
        self._k = 0
        self._n_steps = 0
        self._last_h = self.dt
        self._last_u = np.zeros(task.nu)
        self._terminated = False
        self._truncated = False
        self._warned_done = False
        self._viewer: HumanViewer | None = None
        self._restore_runtime()

    # ------------------------------------------------------------------ hooks
    def _set_sim_state(self, x: np.ndarray) -> None:
        """Put the simulator in state ``x`` (float64, validated)."""
        raise NotImplementedError

    def _advance(self, u: np.ndarray, h: float) -> tuple[np.ndarray, float]:
        """Integrate over ``h`` with ``u`` held; return ``(x_next, l(x_k, u))`` with a fresh ``x_next`` array."""
        raise NotImplementedError

    def _render_frame(self) -> np.ndarray:
        """An RGB frame (H, W, 3) uint8 of the current state."""
        raise NotImplementedError

    def _restore_runtime(self) -> None:
        """(Re)build handles that cannot be pickled (numeric kernels, simulators)."""

    def _limit_action(self, u: np.ndarray, h: float) -> np.ndarray:
        """State-dependent limits on the (already box-clipped) input over a step of ``h``; default none."""
        return u

    def _params_changed(self) -> None:
        """The simulated robot (``self.task``) changed at a reset: update the simulator (default: rebuild)."""
        self._restore_runtime()

    def _robot(self, params: Any) -> Task:
        """The task of the robot with ``params`` (a mapping of some of ``task.parameters.names``, the rest the
        model's; or a full vector); ValueError naming the problem."""
        if self.model_task.parameters is None:
            raise ValueError(
                f"{self.model_task.name}: params need a task that declares which parameters vary (Task.parameters)"
            )
        robot = self.model_task.with_params(params)
        return self.model_task if np.array_equal(robot.theta, self.model_task.theta) else robot

    @property
    def params(self) -> dict[str, float]:
        """The simulated robot's varying parameters ``{name: value}`` (empty for a task without parameters)."""
        if self.task.parameters is None:
            return {}
        return self.task.parameters.as_dict(self.task.theta)

    # ------------------------------------------------------------- properties
    @property
    def state(self) -> np.ndarray:
        """A float64 copy of the current state."""
        return self._x.copy()

    @property
    def time_to_go(self) -> float:
        """Time to go of the episode (s), derived from the integer step counter."""
        if self._k >= self._n_steps:
            return 0.0
        return self._tau - self._k * self.dt

    @property
    def max_episode_steps(self) -> int:
        """Number of steps of the current episode (``ceil(tau / dt)``, :func:`episode_steps`); the registered
        ``spec.max_episode_steps`` is the longest admissible one (:func:`longest_episode_steps`)."""
        return self._n_steps

    # ------------------------------------------------------------- Gymnasium
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        """Start an episode; ``options={"state": x0, "time_to_go": tau, "params": theta}`` (all optional) choose the
        start and the robot.

        Without ``"state"`` the start is a uniform draw from X0 with ``self.np_random``; without ``"time_to_go"`` it
        is the task's nominal ``tau``. ``"params"`` (domain randomisation) sets the simulated robot from this episode
        on: a mapping ``{name: value}`` of some of ``task.parameters.names`` (the others are the model's, so ``{}``
        is the model itself) or a full vector, e.g. ``env.unwrapped.model_task.parameters.sample(rng)``; without it
        the robot stays what it was. Raises ValueError for unknown option keys, a state of the wrong shape, with
        NaN/inf or outside the task's state bounds, a time to go that is not in ``(0, max T0]``, and malformed
        params.
        """
        super().reset(seed=seed)
        options = {} if options is None else options
        if not isinstance(options, dict):
            raise ValueError(f"{self.task.name}: reset options must be a dict, got {type(options).__name__}")
        unknown = set(options) - _RESET_OPTION_KEYS
        if unknown:
            raise ValueError(
                f"{self.task.name}: unknown reset option(s) {sorted(unknown)}; accepted: {sorted(_RESET_OPTION_KEYS)}"
            )
        # Validate everything before touching the episode, so a bad call leaves the env as it was.
        robot = self._robot(options["params"]) if options.get("params") is not None else None
        if options.get("state") is not None:
            try:
                x0 = self.task.check_state(options["state"], "reset state")
            except TypeError:  # e.g. a dict: numpy cannot make a float array of it
                raise ValueError(
                    f"{self.task.name}: reset state must be {self.task.nx} numbers, got {options['state']!r}"
                ) from None
            if np.any(x0 < self._x_low_tol) or np.any(x0 > self._x_high_tol):
                raise ValueError(
                    f"{self.task.name}: reset state {x0.tolist()} is outside the state bounds "
                    f"[{self._x_low.tolist()}, {self._x_high.tolist()}]"
                )
        else:
            x0 = self.task.sample_x0(self.np_random)
        if options.get("time_to_go") is not None:
            tau = self.task.check_tau(self._snap_tau(options["time_to_go"]), allow_shorter=True)
            if tau <= 0.0:
                raise ValueError(f"{self.task.name}: time to go must be positive, got {tau}")
        else:
            tau = float(self.task.tau_nominal)

        if robot is not None:
            self.task = robot
            self._params_changed()
        self._set_sim_state(x0)
        self._x = x0.copy()
        self._tau = tau
        self._k = 0
        self._n_steps = episode_steps(tau, self.dt)
        last = tau - (self._n_steps - 1) * self.dt
        self._last_h = self.dt if abs(last - self.dt) <= 1e-9 * self.dt else last
        self._last_u = np.zeros(self._nu)
        self._terminated = self._truncated = False
        self._warned_done = False
        if self.render_mode == "human":
            self.render()
        return self._obs(), self._info()

    def step(self, action: Any) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict[str, Any]]:
        """Advance one control period (see the module docstring for reward and episode end)."""
        if self._n_steps == 0:
            raise gym.error.ResetNeeded("Cannot call env.step() before calling env.reset()")
        if self._terminated or self._truncated:
            if not self._warned_done:
                logger.warn(
                    "You are calling 'step()' even though this environment has already returned terminated = True "
                    "or truncated = True. You should always call 'reset()' once you receive 'terminated = True' or "
                    "'truncated = True' -- the state is frozen and the reward is 0."
                )
                self._warned_done = True
            return self._obs(), 0.0, self._terminated, self._truncated, self._info()

        u = self._check_action(action)
        k = self._k
        h = self.dt if k < self._n_steps - 1 else self._last_h
        u = self._limit_action(u, h)
        x_next, stage = self._advance(u, h)
        self._x = x_next
        self._k = k + 1
        self._last_u = u
        reward = -h * stage
        self._truncated = self._k >= self._n_steps
        # One float sum detects NaN/inf (and blow-ups that overflow) cheaper than np.isfinite(...).all().
        finite = math.isfinite(float(x_next.sum()))
        if self._bounded:
            self._terminated = not (finite and (x_next >= self._x_low_tol).all() and (x_next <= self._x_high_tol).all())
        else:
            self._terminated = not finite
        if self._terminated or self._truncated:
            reward -= float(self.task.terminal_cost(x_next))
        if self.render_mode == "human":
            self.render()
        return self._obs(), float(reward), self._terminated, self._truncated, self._info()

    def render(self) -> np.ndarray | None:
        """``rgb_array``: an (H, W, 3) uint8 frame; ``human``: show it (nothing is shown without a display)."""
        if self.render_mode is None:
            logger.warn(
                "You are calling render method without specifying any render mode. You can specify the render_mode "
                f'at initialization, e.g. gym.make("{self.spec.id if self.spec else type(self).__name__}", '
                'render_mode="rgb_array")'
            )
            return None
        frame = self._render_frame()
        if self.render_mode == "rgb_array":
            return frame
        if self._viewer is None:
            self._viewer = HumanViewer(type(self).__name__, self.metadata["render_fps"])
        self._viewer.show(frame)
        return None

    def close(self) -> None:
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None

    # ---------------------------------------------------------------- helpers
    def _snap_tau(self, tau: Any) -> Any:
        """Accept the float32 rounding of the largest time to go (an observation's last entry fed back)."""
        hi = float(self.task.tau_range[1])
        numeric = isinstance(tau, (float, int, np.floating, np.integer)) or (
            isinstance(tau, np.ndarray) and tau.ndim == 0 and np.issubdtype(tau.dtype, np.number)
        )
        # Snapping also keeps the episode within the registered max_episode_steps: check_tau accepts hi + 1e-9,
        # which would otherwise add a last step of 1e-9 s.
        if numeric and hi < float(tau) <= hi * (1 + 1e-6):
            return hi
        return tau

    def _check_action(self, action: Any) -> np.ndarray:
        """Validate (shape, finiteness) and clip an action; raise ValueError before any state changes."""
        u = np.asarray(action, dtype=np.float64)
        if self._nu == 1 and u.shape == (1,):
            # Hot path of every 1-input task: scalar math is ~5x cheaper than numpy ufuncs on a 1-vector.
            value = u.item()
            if not math.isfinite(value):
                raise ValueError(f"{self.task.name}: action contains NaN or inf: {[value]}")
            return np.array([min(max(value, self._u_low_1), self._u_high_1)])
        if u.shape != (self._nu,):
            if u.shape == () and self._nu == 1:
                u = u.reshape(1)
            else:
                raise ValueError(
                    f"{self.task.name}: action must have shape ({self._nu},) {list(self.task.control_names)}, "
                    f"got shape {u.shape}"
                )
        if not np.isfinite(u).all():
            raise ValueError(f"{self.task.name}: action contains NaN or inf: {u.tolist()}")
        return np.minimum(np.maximum(u, self._u_low), self._u_high)

    def _obs(self) -> np.ndarray:
        obs = np.empty(self._nx + 1, dtype=np.float32)
        obs[: self._nx] = self._x
        obs[self._nx] = self.time_to_go
        return obs

    def _info(self) -> dict[str, Any]:
        return {"state": self._x.copy(), "time_to_go": self.time_to_go}

    def _ttg_fraction(self) -> float:
        return self.time_to_go / max(float(self.task.tau_range[1]), 1e-12)

    # --------------------------------------------------------------- pickling
    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        for key in self._runtime_keys():
            state.pop(key, None)
        state["_viewer"] = None
        # A built-in task's shared object is restored by name (cheap, keeps the simulator cache); any other task
        # (custom, or registered with register_task, which the receiving process may not know) pickles by value.
        for key in ("task", "model_task"):
            if state[key] is _shared_task(state[key].name):
                state[key] = state[key].name
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        for key in ("task", "model_task"):
            if isinstance(state.get(key), str):
                state[key] = make_task(state[key])
        state.setdefault("model_task", state["task"])
        self.__dict__.update(state)
        self._restore_runtime()
        if self._n_steps > 0:
            self._set_sim_state(self._x)

    def _runtime_keys(self) -> tuple[str, ...]:
        """Attributes rebuilt by :meth:`_restore_runtime` instead of pickled."""
        return ()


def _positive_seconds(value: Any, what: str) -> float:
    try:
        seconds = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be a positive number of seconds, got {value!r}") from None
    if not (math.isfinite(seconds) and seconds > 0.0):
        raise ValueError(f"{what} must be a positive number of seconds, got {seconds}")
    return seconds


def _shared_task(name: str) -> Task | None:
    """The shared object of the built-in task ``name`` if this process has built it (never builds one)."""
    return shared_task(name) if name in BUILTIN_TASKS else None


class TaskSimulatorEnv(SeagulEnv):
    """An env that integrates the Task's CasADi model with the RK4 map of ``task.simulator(dt)``.

    The hot path is one FunctionBuffer evaluation of ``(x, u) -> (x_next, l(x, u))`` generated from the model
    (:func:`step_function`), on preallocated arrays. A shortened last step (``tau`` not a multiple of ``dt``) uses
    the same number of RK4 substeps with the step length as an input (:func:`variable_step_function`), so arbitrary
    ``tau`` values never build new kernels.
    """

    def _restore_runtime(self) -> None:
        # The model's own kernels, and for another robot (params) the parametric ones with its theta as an input:
        # each built once per env, so domain randomisation never builds a kernel at a reset.
        self._kernels: dict[bool, BufferedFunction] = {}
        self._kernels_h: dict[bool, BufferedFunction] = {}  # shortened last steps, built on first use
        self._params_changed()

    def _params_changed(self) -> None:
        parametric = self.task is not self.model_task
        if parametric not in self._kernels:
            self._kernels[parametric] = BufferedFunction(
                step_function(self.model_task, self.dt, self.max_substep, params=parametric)
            )
        self._kernel = self._kernels[parametric]
        self._kernel_h: BufferedFunction | None = self._kernels_h.get(parametric)
        if parametric:
            theta = self.task.theta
            self._kernel.args[2][:] = theta
            if self._kernel_h is not None:
                self._kernel_h.args[3][:] = theta

    def _runtime_keys(self) -> tuple[str, ...]:
        return ("_kernels", "_kernels_h", "_kernel", "_kernel_h")

    def _set_sim_state(self, x: np.ndarray) -> None:
        pass  # the state lives in self._x

    def _advance(self, u: np.ndarray, h: float) -> tuple[np.ndarray, float]:
        if h == self.dt:
            kernel = self._kernel
        else:
            if self._kernel_h is None:
                substeps = max(1, math.ceil(self.dt / self.max_substep - 1e-9))  # h < dt: substeps stay shorter
                parametric = self.task is not self.model_task
                self._kernel_h = BufferedFunction(variable_step_function(self.model_task, substeps, parametric))
                self._kernels_h[parametric] = self._kernel_h
                if parametric:
                    self._kernel_h.args[3][:] = self.task.theta
            kernel = self._kernel_h
            kernel.args[2][0] = h
        x_arg, u_arg = kernel.args[0], kernel.args[1]
        x_arg[:] = self._x
        u_arg[:] = u
        kernel()
        return kernel.res[0].copy(), float(kernel.res[1][0])
