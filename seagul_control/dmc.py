"""Episodes in the DeepMind Control Suite, scored by dm_control's own reward: the benchmark's yardstick.

A controller is scored the way the suite scores an agent: ``gym.make("dm_control/<domain>-<task>-v0")`` (shimmy's
wrapper of ``dm_control.suite.load``), reset with a seed (dm_control's own reset distribution: the pendulum and the
acrobot's angles uniform in ``[-pi, pi)``, the cartpole hanging down with small noise), 1,000 control steps (the
suite's time limit; dm_control truncates the episode itself), and the **sum of dm_control's per-step rewards** (each
in ``[0, 1]``, so a score is in ``[0, 1000]``). Nothing of seagul's own envs, costs or success rules is involved.

What the controller sees is the physics state ``x = [qpos, qvel]`` in the MJCF's joint order (:func:`physics_state`),
not dm_control's observation (sines and cosines); this is the state of the CasADi tasks ``dmc_pendulum``,
``dmc_cartpole`` and ``dmc_acrobot``, and the action is dm_control's, the actuator's ``ctrl`` in its ``ctrlrange``
(the torque or force is ``gear * ctrl``).

Usage::

    from seagul_control.dmc import run_dmc_episode

    episode = run_dmc_episode("acrobot-swingup", lambda x, t: np.zeros(1), seed=0)
    episode.score  # dm_control's return of the episode

    # a seagul policy (SB3's predict protocol, observations [x, time to go]), one decision per 2 control steps
    episode = run_dmc_episode("acrobot-swingup", PredictController(mpc), seed=0, hold=2)

Controllers are either a callable ``controller(x, t) -> action`` (``x`` the float64 physics state, ``t`` the
episode time in seconds) or an object with SB3's ``predict`` (wrapped by :class:`PredictController`, which builds
the observation ``[x, time to go]`` the seagul envs emit). A controller with a ``reset()`` method has it called at
the start of every episode (warm starts, internal state).

A controller trained on dm_control's own observation (an RL agent) declares it with the attribute
``observation = "dm_control"``: it is then called with ``gymnasium.spaces.flatten`` of the observation dict (what
``gymnasium.wrappers.FlattenObservation`` gives, float64; :func:`dm_control_observation`) instead of the physics
state. Without the attribute (or with ``observation = "physics"``) it gets the physics state as above.

Actions are checked, not silently changed: dm_control clips nothing itself (MuJoCo clamps the simulated force to
``ctrlrange``, but the cartpole's reward reads the unclamped ``ctrl``), so an action beyond a bound by more than
:data:`ACTION_TOLERANCE` raises ``ValueError`` naming the bound; an excess up to that tolerance (a solver's round-off
on a saturated input) is clipped onto the bound. NaN or infinite actions, and actions of the wrong size, raise.

``dm_control`` and ``shimmy`` are optional (the ``seagul[dmc]`` extra); they are imported when an env is made, and
their absence raises ``ImportError`` saying what to install.
"""

from __future__ import annotations

import importlib
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

__all__ = [
    "ACTION_TOLERANCE",
    "DMC_ENV_IDS",
    "DMC_TASKS",
    "EPISODE_STEPS",
    "OBSERVATION_MODES",
    "DMCEpisode",
    "PredictController",
    "as_controller",
    "dm_control_observation",
    "dmc_env_id",
    "make_dmc_env",
    "observation_mode",
    "physics_of",
    "physics_state",
    "run_dmc_episode",
    "run_dmc_episodes",
]

#: The suite's swing-up tasks seagul is benchmarked on (Gymnasium ids, registered by shimmy).
DMC_ENV_IDS: tuple[str, ...] = (
    "dm_control/pendulum-swingup-v0",
    "dm_control/cartpole-swingup-v0",
    "dm_control/cartpole-swingup_sparse-v0",
    "dm_control/acrobot-swingup-v0",
)

#: The seagul CasADi task (``seagul_envs.make_task`` name) modelling each env's physics: state ``[qpos, qvel]``,
#: control the actuator's ``ctrl``.
DMC_TASKS: dict[str, str] = {
    "dm_control/pendulum-swingup-v0": "dmc_pendulum",
    "dm_control/cartpole-swingup-v0": "dmc_cartpole",
    "dm_control/cartpole-swingup_sparse-v0": "dmc_cartpole",
    "dm_control/acrobot-swingup-v0": "dmc_acrobot",
}

#: Control steps of every episode of :data:`DMC_ENV_IDS` (the suite's time limits: pendulum 20 s at 0.02 s, the
#: cartpole and the acrobot 10 s at 0.01 s).
EPISODE_STEPS = 1000

#: How far (in ``ctrl`` units) an action may pass a bound of the action space and still be accepted, clipped onto
#: the bound: the round-off of an optimiser's saturated input. Anything further raises ``ValueError``.
ACTION_TOLERANCE = 1e-6


#: What a controller may be called with (its ``observation`` attribute; ``"physics"`` without one): the physics
#: state ``[qpos, qvel]`` or dm_control's flattened observation.
OBSERVATION_MODES: tuple[str, ...] = ("physics", "dm_control")


def observation_mode(controller: Any) -> str:
    """The controller's ``observation`` attribute (one of :data:`OBSERVATION_MODES`; ``"physics"`` when it has
    none); any other value raises ``ValueError``."""
    mode = getattr(controller, "observation", "physics")
    if mode not in OBSERVATION_MODES:
        raise ValueError(f"controller.observation must be one of {list(OBSERVATION_MODES)}, got {mode!r}")
    return str(mode)


def dm_control_observation(env: gym.Env, observation: Any) -> np.ndarray:
    """dm_control's observation as an RL agent sees it: ``gymnasium.spaces.flatten`` of the observation dict in
    ``env``'s observation space (the output of ``gymnasium.wrappers.FlattenObservation``), as float64."""
    return np.asarray(gym.spaces.flatten(env.observation_space, observation), dtype=float)


def dmc_env_id(name: str) -> str:
    """The Gymnasium id of one of :data:`DMC_ENV_IDS`, from itself or its short form ``"<domain>-<task>"``
    (``"acrobot-swingup"`` -> ``"dm_control/acrobot-swingup-v0"``); anything else raises ``ValueError`` listing
    the supported ids."""
    full = name if name.startswith("dm_control/") else f"dm_control/{name}-v0"
    if full not in DMC_ENV_IDS:
        short = ", ".join(i.removeprefix("dm_control/").removesuffix("-v0") for i in DMC_ENV_IDS)
        raise ValueError(f"unknown DeepMind Control Suite env {name!r}: supported are {short} (or their gym ids)")
    return full


def make_dmc_env(env_id: str, **kwargs: Any) -> gym.Env:
    """``gym.make`` of one of :data:`DMC_ENV_IDS` (short names accepted, :func:`dmc_env_id`); ``kwargs`` go to
    ``gym.make`` (e.g. ``render_mode="rgb_array"``). Raises ``ImportError`` without dm_control and shimmy."""
    full = dmc_env_id(env_id)
    try:
        importlib.import_module("dm_control.suite")
        importlib.import_module("shimmy")
    except ImportError as exc:
        raise ImportError(f"{full} needs dm_control and shimmy (pip install 'seagul[dmc]'): {exc}") from exc
    return gym.make(full, **kwargs)


def physics_of(env: Any) -> Any:
    """The dm_control ``Physics`` behind ``env``: a Gymnasium env made by shimmy (any wrappers; shimmy's
    ``DmControlCompatibilityV0`` keeps the dm_control environment as ``_env``), a dm_control environment, or a
    Physics itself. The same object lives through resets, so it may be kept."""
    if hasattr(env, "named") and hasattr(env, "data"):
        return env
    inner = getattr(env, "unwrapped", env)
    dm_env = getattr(inner, "_env", inner)
    physics = getattr(dm_env, "physics", None)
    if physics is None:
        raise TypeError(f"{type(env).__name__} is not a dm_control env (no physics found behind it)")
    return physics


def physics_state(env: Any) -> np.ndarray:
    """``[qpos, qvel]`` (float64 copy, MJCF joint order) of the dm_control physics behind ``env`` (:func:`physics_of`).

    For the swing-ups: pendulum ``[hinge, d hinge]``; cartpole ``[slider, hinge_1, d slider, d hinge_1]``; acrobot
    ``[shoulder, elbow, d shoulder, d elbow]``. Angles are measured from the upright (zero is pole up: the suite's
    MJCF bodies point along +z), unwrapped as MuJoCo integrates them.
    """
    physics = physics_of(env)
    return np.concatenate([np.asarray(physics.data.qpos, dtype=float), np.asarray(physics.data.qvel, dtype=float)])


class PredictController:
    """A controller ``(x, t) -> action`` from an object with SB3's ``predict(observation, state, episode_start,
    deterministic)`` (seagul's ``LimitedLookaheadMPC``, ``FullHorizonMPC``, ``LQRPolicy``, an SB3 model).

    The observation is built as the seagul envs build it (:mod:`seagul_envs.envs.base`): float32
    ``[x_0, ..., x_{nx-1}, time_to_go]``, with ``episode_start=[True]`` on the first decision of each episode (it
    resets the MPC's warm start) and ``deterministic=True``. The time to go is:

    * ``time_to_go=None`` (default): the episode's remaining time ``T - t`` (``T`` the dm_control time limit), capped
      at the largest time to go the policy's task admits (``policy.task.tau_range[1]``, when the policy has a task):
      a swing-up scored over the whole episode is, for a value function trained up to ``tau_max``, a problem with
      at least ``tau_max`` to go until the last ``tau_max`` seconds;
    * a number: that constant time to go at every decision (a stationary policy);
    * a callable ``t -> tau``.

    ``observation_dtype`` may be set to ``np.float64`` to give the policy the exact state (the seagul envs round it
    to float32; the default keeps what the policies were evaluated with).
    """

    def __init__(
        self,
        policy: Any,
        *,
        time_to_go: float | Callable[[float], float] | None = None,
        episode_time: float | None = None,
        observation_dtype: Any = np.float32,
    ) -> None:
        if not callable(getattr(policy, "predict", None)):
            raise TypeError(f"{type(policy).__name__} has no predict method (SB3's predictor protocol)")
        self.policy = policy
        self.time_to_go = time_to_go
        self.episode_time = episode_time
        self.observation_dtype = observation_dtype
        self.name = str(getattr(policy, "name", type(policy).__name__))
        self._start = True

    def reset(self) -> None:
        """Mark the next decision as an episode's first (``episode_start=[True]``)."""
        self._start = True

    def tau(self, t: float) -> float:
        """The time to go given to the policy at episode time ``t`` (s); see the class docstring."""
        if callable(self.time_to_go):
            return float(self.time_to_go(t))
        if self.time_to_go is not None:
            return float(self.time_to_go)
        if self.episode_time is None:
            raise ValueError("PredictController: episode_time is unknown; run it through run_dmc_episode")
        remaining = max(self.episode_time - t, 0.0)
        task = getattr(self.policy, "task", None)
        tau_range = getattr(task, "tau_range", None)
        return min(remaining, float(tau_range[1])) if tau_range is not None else remaining

    def __call__(self, x: np.ndarray, t: float) -> np.ndarray:
        obs = np.append(np.asarray(x, dtype=float), self.tau(t)).astype(self.observation_dtype)
        action, _ = self.policy.predict(obs, episode_start=np.array([self._start]), deterministic=True)
        self._start = False
        return np.asarray(action, dtype=float)


def as_controller(controller: Any, *, episode_time: float | None = None) -> Callable[[np.ndarray, float], Any]:
    """``controller`` as a callable ``(x, t) -> action``: an object with ``predict`` is wrapped in
    :class:`PredictController` (a :class:`PredictController` whose episode time is unset gets ``episode_time``);
    any other callable is returned as it is."""
    if isinstance(controller, PredictController):
        if controller.episode_time is None:
            controller.episode_time = episode_time
        return controller
    if callable(getattr(controller, "predict", None)):
        return PredictController(controller, episode_time=episode_time)
    if callable(controller):
        return controller
    raise TypeError(
        f"controller must be a callable (x, t) -> action or have SB3's predict method, got {type(controller).__name__}"
    )


@dataclass(frozen=True)
class DMCEpisode:
    """One scored episode in a DeepMind Control Suite env (see :func:`run_dmc_episode`)."""

    env_id: str
    """Gymnasium id, e.g. ``"dm_control/acrobot-swingup-v0"``."""
    seed: int
    """The reset seed (dm_control's task ``RandomState``)."""
    controller: str
    """The controller's name (its ``name`` attribute, else its type's or function's name)."""
    hold: int
    """Control steps each decision is held for."""
    score: float
    """dm_control's return: the sum of its per-step rewards over the episode (``[0, steps]``)."""
    steps: int
    """Control steps taken (1,000 for every env of :data:`DMC_ENV_IDS`)."""
    control_dt: float
    """dm_control's control period (s)."""
    start: tuple[float, ...]
    """The physics state ``[qpos, qvel]`` after the reset."""
    final_state: tuple[float, ...]
    """The physics state after the last step."""
    rewards: tuple[float, ...]
    """dm_control's reward of every step."""
    decisions: int
    """Times the controller was asked (``ceil(steps / hold)``)."""
    decision_ms_median: float
    """Median wall time of one controller call (ms)."""
    decision_ms_p95: float
    """95th percentile of the wall time of one controller call (ms)."""
    wall_s: float
    """Wall time of the whole episode, simulation included (s)."""
    states: tuple[tuple[float, ...], ...] | None = field(default=None)
    """With ``record=True``: the physics state before each step and after the last (``steps + 1`` rows)."""
    actions: tuple[tuple[float, ...], ...] | None = field(default=None)
    """With ``record=True``: the action applied at each step (``steps`` rows)."""

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (lists for tuples; ``states``/``actions`` ``None`` unless recorded)."""
        out: dict[str, Any] = {}
        for key, value in self.__dict__.items():
            if isinstance(value, tuple):
                value = [list(v) if isinstance(v, tuple) else v for v in value]
            out[key] = value
        return out


def _name(controller: Any) -> str:
    name = getattr(controller, "name", None)
    if isinstance(name, str):
        return name
    return str(getattr(controller, "__name__", type(controller).__name__))


def _check_action(action: Any, low: np.ndarray, high: np.ndarray, step: int, t: float) -> np.ndarray:
    """The action as a float64 array of the action space's shape, clipped within :data:`ACTION_TOLERANCE`."""
    arr = np.asarray(action, dtype=float)
    if arr.size != low.size:
        raise ValueError(
            f"controller returned an action of shape {arr.shape} at step {step} (t = {t:.3f} s); the action space "
            f"has {low.size} entries (shape {low.shape})"
        )
    arr = arr.reshape(low.shape)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"controller returned a non-finite action {arr.tolist()} at step {step} (t = {t:.3f} s)")
    below, above = arr < low - ACTION_TOLERANCE, arr > high + ACTION_TOLERANCE
    if np.any(below) or np.any(above):
        i = int(np.flatnonzero(below | above)[0])
        bound, which = (low[i], "lower") if below[i] else (high[i], "upper")
        raise ValueError(
            f"controller returned action[{i}] = {float(arr[i])!r} at step {step} (t = {t:.3f} s), beyond the {which} "
            f"bound {float(bound)!r} of the action space (low {low.tolist()}, high {high.tolist()}; dm_control "
            "clips nothing: clip in the controller if saturation is meant)"
        )
    return np.clip(arr, low, high)


def run_dmc_episode(
    env_id: str,
    controller: Any,
    seed: int,
    *,
    hold: int = 1,
    record: bool = False,
    env: gym.Env | None = None,
) -> DMCEpisode:
    """One episode of ``controller`` in ``env_id`` (one of :data:`DMC_ENV_IDS`, or its short form), reset with
    ``seed``, scored by dm_control's own rewards summed over its 1,000 control steps.

    ``controller``: a callable ``(x, t) -> action`` on the physics state (:func:`physics_state`) and the episode
    time (s), or an object with SB3's ``predict`` (wrapped by :class:`PredictController`). Its ``reset()``, if any,
    is called first. A controller with ``observation = "dm_control"`` gets dm_control's flattened observation
    (:func:`dm_control_observation`) as ``x`` instead of the physics state (:func:`observation_mode`).

    ``hold``: the controller decides at every ``hold``-th control step and its action is applied for ``hold``
    consecutive control steps (zero-order hold), so a controller may act at a coarser period ``hold * control_dt``
    than the suite's (an MPC planning at 0.02 s on the acrobot's 0.01 s steps: ``hold=2``). The episode still has
    dm_control's 1,000 steps and every step's reward counts; a last decision held past the end is cut short.

    Actions: see the module docstring (within :data:`ACTION_TOLERANCE` of a bound clipped onto it; beyond, NaN, or
    of the wrong size: ``ValueError``). ``record=True`` keeps the states and actions in the result. ``env``: an env
    made by :func:`make_dmc_env` for this id, to reuse across episodes (it is reset, not closed); by default one is
    made and closed here.

    The wall time per decision (median, 95th percentile) times the controller call alone.
    """
    full = dmc_env_id(env_id)
    if not isinstance(hold, (int, np.integer)) or isinstance(hold, bool) or hold < 1:
        raise ValueError(f"hold must be a positive integer number of control steps, got {hold!r}")
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    mode = observation_mode(controller)
    own_env = env is None
    the_env = make_dmc_env(full) if env is None else env
    try:
        dm_env = getattr(the_env.unwrapped, "_env", None)
        if dm_env is None:
            raise TypeError(f"env {type(the_env).__name__} is not shimmy's dm_control env")
        spec_id = getattr(the_env.spec, "id", None)
        if spec_id is not None and spec_id != full:
            raise ValueError(f"env is {spec_id}, not {full}")
        control_dt = float(dm_env.control_timestep())
        episode_time = EPISODE_STEPS * control_dt
        policy = as_controller(controller, episode_time=episode_time)
        space = the_env.action_space
        if not isinstance(space, gym.spaces.Box):
            raise TypeError(f"{full}: expected a Box action space, got {space}")
        low = np.asarray(space.low, dtype=float)
        high = np.asarray(space.high, dtype=float)
        wall0 = time.perf_counter()
        obs, _ = the_env.reset(seed=int(seed))
        reset = getattr(policy, "reset", None)
        if callable(reset):
            reset()
        x = physics_state(the_env)
        start = tuple(x.tolist())
        seen = dm_control_observation(the_env, obs) if mode == "dm_control" else x
        rewards: list[float] = []
        states: list[tuple[float, ...]] = [start] if record else []
        actions: list[tuple[float, ...]] = []
        decision_s: list[float] = []
        action = np.zeros_like(low)
        step, done = 0, False
        while not done:
            t = step * control_dt
            if step % hold == 0:
                tic = time.perf_counter()
                raw = policy(seen.copy(), t)
                decision_s.append(time.perf_counter() - tic)
                action = _check_action(raw, low, high, step, t)
            obs, reward, terminated, truncated, _ = the_env.step(action.copy())
            rewards.append(float(reward))
            step += 1
            done = bool(terminated or truncated)
            x = physics_state(the_env)
            seen = dm_control_observation(the_env, obs) if mode == "dm_control" else x
            if record:
                actions.append(tuple(action.tolist()))
                states.append(tuple(x.tolist()))
        wall = time.perf_counter() - wall0
    finally:
        if own_env:
            the_env.close()
    ms = np.asarray(decision_s) * 1e3
    return DMCEpisode(
        env_id=full,
        seed=int(seed),
        controller=_name(controller),
        hold=int(hold),
        score=float(np.sum(rewards)),
        steps=step,
        control_dt=control_dt,
        start=start,
        final_state=tuple(x.tolist()),
        rewards=tuple(rewards),
        decisions=len(decision_s),
        decision_ms_median=float(np.median(ms)),
        decision_ms_p95=float(np.percentile(ms, 95)),
        wall_s=float(wall),
        states=tuple(states) if record else None,
        actions=tuple(actions) if record else None,
    )


def run_dmc_episodes(
    env_id: str, controller: Any, seeds: Sequence[int], *, hold: int = 1, record: bool = False
) -> list[DMCEpisode]:
    """:func:`run_dmc_episode` for each seed, in order, in one env (made once, closed at the end)."""
    env = make_dmc_env(env_id)
    try:
        return [run_dmc_episode(env_id, controller, int(s), hold=hold, record=record, env=env) for s in seeds]
    finally:
        env.close()
