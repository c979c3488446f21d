"""The learner's view of a seagul env: standard Gymnasium wrappers for reinforcement learning.

The seagul envs speak the task's language: raw states in physical units, the time to go in seconds, torques in
N m and the trajectory cost as reward, which spans 1e-3 (balancing) to 1e5 (a diverging acrobot) per step. That is
the right interface for evaluating controllers and the wrong one for training a policy-gradient or actor-critic
learner. :class:`LearnerView` declares the standard preparation, and :func:`learner_env` applies it:

* **Angle features** (:class:`AngleFeatures`): each periodic angle ``q`` becomes ``(cos q, sin q)``, so the
  upright acrobot at ``th1 = pi`` and ``th1 = 3 pi`` look the same and nothing depends on an unwrapped count of
  turns. Angles bounded by the task (the glider's pitch, a crash beyond +-pi/2) stay as they are.
* **Scaled time to go**: the last observation entry divided by the task's largest time to go, in ``[0, 1]``.
* **Actions in [-1, 1]**: Gymnasium's ``RescaleAction``; the policy's Gaussian then samples on the scale its
  initialisation assumes (a unit standard deviation is a twentieth of the acrobot's torque range, not 1 N m).
* **A bounded, success-aware reward** (:class:`LearnerReward`). Per step ``-(h / tau_max) tanh(l(x, u) /
  step_scale)`` with the task's stage cost ``l``; on the episode's last step ``-end_weight tanh(miss / end_scale)
  + success_bonus * success - crash_penalty * crashed``, where ``miss`` is the final state's miss of the task's
  success rule in units of its tolerances (:meth:`~seagul_envs.tasks.profile.SuccessRule.violation`: for the
  acrobot the distance to the goal beyond 0.05, in units of 0.05) and ``crashed`` means the episode left the state
  bounds (the glider's crash). An episode's learner return lies in ``[-(1 + end_weight + crash_penalty),
  success_bonus]``, whatever the state does, so value targets need no running normalisation. The task's own cost
  and success rule still judge every evaluation: the wrapper changes what the learner optimises, not what a
  report shows (``info["task_reward"]`` keeps the env's reward).
* **The horizon's end is terminal** (:class:`HorizonEndTerminates`): the seagul envs are finite-horizon problems
  with the time to go in the observation and the terminal term in the last reward, so nothing follows the last
  step. Gymnasium's ``truncated`` would make SB3 bootstrap a value at an observation (time to go 0) that no
  transition starts from (Pardo et al., "Time Limits in Reinforcement Learning", ICML 2018).

:class:`LearnerView` is a frozen dataclass stored as ``view.json`` beside a trained model; :meth:`LearnerView.observe`
and :meth:`LearnerView.action` are the same maps as pure functions, so a saved policy runs on the raw env
(``seagul_learn.policies.SB3Policy``).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, SupportsFloat

import casadi as ca
import gymnasium as gym
import numpy as np
from gymnasium import spaces

from seagul_envs.envs.base import BufferedFunction

__all__ = [
    "AngleFeatures",
    "HorizonEndTerminates",
    "LearnerReward",
    "LearnerView",
    "RandomRobot",
    "learner_env",
]


@dataclass(frozen=True)
class LearnerView:
    """How a learner sees a seagul env (module docstring). Stored as ``view.json`` beside a trained model."""

    angles: tuple[int, ...] = ()
    """State indices of periodic angles, fed as ``(cos, sin)`` pairs (in this order, before the other entries)."""
    tau_max: float = 1.0
    """The time to go is divided by this (the task's largest time to go, ``task.tau_range[1]``)."""
    u_low: tuple[float, ...] = (-1.0,)
    """The physical action bounds that ``[-1, 1]`` maps onto (the env's action space)."""
    u_high: tuple[float, ...] = (1.0,)
    """Upper physical action bounds."""
    step_scale: float = 1.0
    """Stage cost at which the per-step penalty reaches tanh(1) = 0.76 of its cap ``h / tau_max``."""
    end_weight: float = 1.0
    """Cap of the end term's penalty for missing the success rule."""
    end_scale: float = 10.0
    """Miss (in units of the rule's tolerances) at which the end penalty reaches 0.76 of ``end_weight``."""
    success_bonus: float = 1.0
    """Reward for ending inside the success rule."""
    crash_penalty: float = 1.0
    """Penalty for leaving the state bounds, on top of the largest miss (a crash is worse than any miss)."""
    extra: dict[str, Any] = field(default_factory=dict, compare=False)
    """Free-form notes kept with the view (e.g. the env id it was made for)."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "angles", tuple(int(i) for i in self.angles))
        object.__setattr__(self, "u_low", tuple(float(v) for v in self.u_low))
        object.__setattr__(self, "u_high", tuple(float(v) for v in self.u_high))
        if len(set(self.angles)) != len(self.angles) or any(i < 0 for i in self.angles):
            raise ValueError(f"angles must be distinct state indices >= 0, got {self.angles}")
        pairs = zip(self.u_low, self.u_high, strict=False)
        if len(self.u_low) != len(self.u_high) or not all(lo < hi for lo, hi in pairs):
            raise ValueError(f"u_low must be below u_high entry by entry, got {self.u_low} and {self.u_high}")
        for name in ("tau_max", "step_scale", "end_scale"):
            value = float(getattr(self, name))
            if not (value > 0 and math.isfinite(value)):
                raise ValueError(f"{name} must be a finite number > 0, got {value}")
        for name in ("end_weight", "success_bonus", "crash_penalty"):
            value = float(getattr(self, name))
            if not (value >= 0 and math.isfinite(value)):
                raise ValueError(f"{name} must be a finite number >= 0, got {value}")

    # ------------------------------------------------------------------ construction and storage
    @classmethod
    def for_env(cls, env: gym.Env, **settings: Any) -> LearnerView:
        """The view of ``env`` (a seagul env, wrapped or not): its action bounds and largest time to go, with
        ``settings`` (``angles``, reward weights) over the defaults."""
        base = env.unwrapped
        task = base.task  # type: ignore[attr-defined]
        box: Any = base.action_space
        return cls(
            tau_max=float(task.tau_range[1]),
            u_low=tuple(float(v) for v in np.ravel(box.low)),
            u_high=tuple(float(v) for v in np.ravel(box.high)),
            **settings,
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (``view.json``)."""
        out = asdict(self)
        for key in ("angles", "u_low", "u_high"):
            out[key] = list(out[key])
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> LearnerView:
        """The view stored by :meth:`to_dict`; unknown keys are an error that names them."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown LearnerView keys {unknown}; known: {sorted(known)}")
        return cls(**data)

    def save(self, path: str | Path) -> None:
        """Write ``view.json`` (atomically: a temporary file renamed into place)."""
        path = Path(path)
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(json.dumps(self.to_dict(), indent=1))
        tmp.replace(path)

    @classmethod
    def load(cls, path: str | Path) -> LearnerView:
        """Read a ``view.json``."""
        return cls.from_dict(json.loads(Path(path).read_text()))

    # ------------------------------------------------------------------ the maps as pure functions
    def observe(self, observation: Any) -> np.ndarray:
        """The learner's observation of a raw env observation ``[x..., time_to_go]`` (one or a batch)."""
        obs = np.asarray(observation, dtype=np.float64)
        single = obs.ndim == 1
        obs = np.atleast_2d(obs)
        nx = obs.shape[1] - 1
        if any(i >= nx for i in self.angles):
            raise ValueError(f"angle index out of range for a state of {nx} entries: {self.angles}")
        rest = [i for i in range(nx) if i not in self.angles]
        parts = [np.stack([np.cos(obs[:, i]), np.sin(obs[:, i])], axis=1) for i in self.angles]
        parts += [obs[:, rest], obs[:, -1:] / self.tau_max]
        out = np.concatenate(parts, axis=1).astype(np.float32)
        return out[0] if single else out

    def action(self, action: Any) -> np.ndarray:
        """The physical action of a learner's action in ``[-1, 1]`` (clipped to it first)."""
        a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        low, high = np.asarray(self.u_low), np.asarray(self.u_high)
        return (low + 0.5 * (a + 1.0) * (high - low)).astype(np.float32)

    def observation_space(self, nx: int) -> spaces.Box:
        """The Box of :meth:`observe`'s output for a state of ``nx`` entries."""
        big = float(np.finfo(np.float32).max)
        n_rest = nx - len(self.angles)
        low = np.concatenate([np.full(2 * len(self.angles), -1.0), np.full(n_rest, -big), [0.0]])
        high = np.concatenate([np.full(2 * len(self.angles), 1.0), np.full(n_rest, big), [1.0]])
        return spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32)


class AngleFeatures(gym.ObservationWrapper):
    """``[x..., time_to_go]`` -> ``[cos/sin of the angles, the other entries, time_to_go / tau_max]``."""

    def __init__(self, env: gym.Env, view: LearnerView) -> None:
        super().__init__(env)
        self.view = view
        nx = int(np.prod(env.observation_space.shape)) - 1  # type: ignore[arg-type]
        self.observation_space = view.observation_space(nx)

    def observation(self, observation: Any) -> np.ndarray:
        return self.view.observe(observation)


class LearnerReward(gym.Wrapper):
    """The bounded, success-aware learner reward of :class:`LearnerView` (module docstring) in place of the env's.

    The env's own reward stays in ``info["task_reward"]``; ``info["learner_success"]`` tells on the last step
    whether the task's rule was met.
    """

    def __init__(self, env: gym.Env, view: LearnerView) -> None:
        super().__init__(env)
        self.view = view
        self.task = env.unwrapped.task  # type: ignore[attr-defined]
        x = ca.SX.sym("x", self.task.nx)
        u = ca.SX.sym("u", self.task.nu)
        # Evaluated every step: the buffered call on preallocated arrays, as the env's own step does.
        self._stage_cost = BufferedFunction(ca.Function("stage_cost", [x, u], [self.task.stage_cost(x, u)]))
        self._x = np.zeros(self.task.nx)
        self._tau = 0.0

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        self._x, self._tau = np.asarray(info["state"], dtype=float), float(info["time_to_go"])
        return obs, info

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        u = np.clip(np.asarray(action, dtype=float).reshape(-1), self.task.u_low, self.task.u_high)
        obs, task_reward, terminated, truncated, info = self.env.step(action)
        h = max(0.0, self._tau - float(info["time_to_go"]))
        stage = self._stage_cost
        stage.args[0][:], stage.args[1][:] = self._x, u
        stage()
        cost = float(stage.res[0][0])
        cost = cost if math.isfinite(cost) else math.inf
        reward = -(h / self.view.tau_max) * math.tanh(cost / self.view.step_scale)
        info = {**info, "task_reward": float(task_reward)}
        if terminated or truncated:
            x_end = np.asarray(info["state"], dtype=float)
            profile = self.task.profile
            success = profile.is_success(self.task, x_end, terminated)
            rule = profile.success
            miss = float(rule.violation(self.task, x_end)) if hasattr(rule, "violation") else float(not success)
            miss = miss if math.isfinite(miss) else math.inf
            reward += -self.view.end_weight * math.tanh(miss / self.view.end_scale)
            reward += self.view.success_bonus * float(success)
            if terminated:  # left the state bounds (or stopped being finite)
                reward -= self.view.crash_penalty
            info["learner_success"] = bool(success)
        self._x, self._tau = np.asarray(info["state"], dtype=float), float(info["time_to_go"])
        return obs, reward, terminated, truncated, info


class HorizonEndTerminates(gym.Wrapper):
    """``terminated = terminated or truncated``, ``truncated = False``: the finite horizon's end is terminal."""

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, reward, bool(terminated or truncated), False, info


class RandomRobot(gym.Wrapper):
    """Domain randomisation: every episode simulates its own robot, drawn uniformly from the task's box ``Theta``
    (``Task.parameters``) with the env's own random stream (seeded by ``reset(seed=...)``), so a policy trained
    through this wrapper meets the spread of robots it will be evaluated on (Tobin et al., "Domain Randomization
    for Transferring Deep Neural Networks from Simulation to the Real World", IROS 2017; Peng et al., "Sim-to-Real
    Transfer of Robotic Control with Dynamics Randomization", ICRA 2018).

    The policy does not see the robot: the observation is unchanged. A reset whose ``options`` name ``"params"``
    keeps that robot (an evaluation over given robots). ``scale`` widens or narrows the box about the model's values
    (``ParameterSpace.scaled``). ``info["params"]`` after a reset holds the episode's robot.

    Raises ``ValueError`` when the env's task declares no parameters.
    """

    def __init__(self, env: gym.Env, scale: float = 1.0) -> None:
        super().__init__(env)
        task = getattr(env.unwrapped, "model_task", None)
        space = None if task is None else task.parameters
        if task is None or space is None:
            name = getattr(task, "name", type(env.unwrapped).__name__)
            raise ValueError(f"RandomRobot: {name} declares no physical parameters (Task.parameters) to randomise")
        if not (math.isfinite(scale) and scale > 0):
            raise ValueError(f"RandomRobot: scale must be a finite number > 0, got {scale!r}")
        self.space = space if scale == 1.0 else space.scaled(scale, task.theta)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        if seed is not None:
            self.env.reset(seed=seed)  # seed the env's stream before drawing this episode's robot from it
        options = dict(options or {})
        if "params" not in options:
            options["params"] = self.space.sample(self.env.unwrapped.np_random)
        obs, info = self.env.reset(options=options)
        info["params"] = np.asarray(options["params"], dtype=float)
        return obs, info


def learner_env(env: gym.Env, view: LearnerView) -> gym.Env:
    """``env`` as the learner sees it: :class:`LearnerReward`, :class:`HorizonEndTerminates`,
    :class:`AngleFeatures` and ``RescaleAction`` to ``[-1, 1]`` (module docstring)."""
    env = LearnerReward(env, view)
    env = HorizonEndTerminates(env)
    env = AngleFeatures(env, view)
    return gym.wrappers.RescaleAction(env, np.float32(-1.0), np.float32(1.0))
