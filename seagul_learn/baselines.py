"""Reinforcement-learning baselines: stable-baselines3 PPO and SAC on the seagul envs, judged on the MPCs' starts.

One config (:class:`SB3Config`, CleanRL style) declares a run; :func:`train_sb3` trains it, records a learning
curve (success on the task's evaluation grid and mean return, every ``eval_every`` environment steps, deterministic
actions) and saves ``model.zip``, ``vecnormalize.pkl`` (the observation statistics, picked up by
:class:`seagul_control.evaluation.SB3Policy`) and ``curve.json`` into the run directory.

Hyperparameters start from rl-baselines3-zoo's tuned entries for the closest tasks (``ZOO_DEFAULTS``):

* **PPO**: ``hyperparams/ppo.yml``, ``Pendulum-v1`` (continuous-torque swing/balance): 4 envs, ``n_steps=1024``,
  ``gae_lambda=0.95``, 10 epochs, ``lr=1e-3``, ``clip_range=0.2``, gSDE with ``sde_sample_freq=4``, no entropy bonus.
* **SAC**: ``hyperparams/sac.yml``, ``InvertedDoublePendulumBulletEnv-v0`` (a two-link balance task, the zoo's
  pybullet defaults, marked tuned): ``lr=7.3e-4``, buffer 300,000, batch 256, ``ent_coef="auto"``, ``tau=0.02``,
  ``train_freq=gradient_steps=8``, ``learning_starts=10000``, gSDE with ``log_std_init=-3``, ``net_arch=[400, 300]``.

Changed for these tasks, with reasons: ``gamma=0.98`` for both (zoo: 0.9 for Pendulum, 0.98 for the double
pendulum): episodes are 50 (acrobot) or ~32 (glider) steps and the terminal cost arrives at the end;
observation normalisation (``VecNormalize``) for both and reward normalisation for PPO, because a diverging acrobot
costs up to 1e5 per step while balancing costs ~1e-3. SAC's ``learning_starts`` is 1,000 (zoo: 10,000): SAC
budgets here are 20-40 k steps (each step is a gradient update, ~10-20 ms on one core), and 10 k random steps would
be a third to half of them; 1,000 steps are still 20-30 random episodes. The sweep in
``benchmarks/bench_rl_baselines.py`` varies the settings that matter (learning rate, discount, network size).

What the learner sees (``training_env``): the horizon's end is a termination (``terminal_at_horizon``; the envs
report it as ``truncated``, which makes SB3 bootstrap past a finite horizon), and rewards can carry a fixed scale
(``reward_scale``). Logged returns and all evaluations are in the task's units.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import MISSING, asdict, dataclass, field, fields, replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

ALGOS = ("PPO", "SAC")

#: rl-baselines3-zoo settings each algorithm starts from (module docstring), as SB3 constructor arguments.
ZOO_DEFAULTS: dict[str, dict[str, Any]] = {
    "PPO": {
        "n_envs": 4,
        "learning_rate": 1e-3,
        "net_arch": (64, 64),
        "algo_kwargs": {
            "n_steps": 1024,
            "batch_size": 64,
            "n_epochs": 10,
            "gae_lambda": 0.95,
            "clip_range": 0.2,
            "ent_coef": 0.0,
            "use_sde": True,
            "sde_sample_freq": 4,
        },
    },
    "SAC": {
        "n_envs": 1,
        "learning_rate": 7.3e-4,
        "net_arch": (400, 300),
        "algo_kwargs": {
            "buffer_size": 300_000,
            "batch_size": 256,
            "ent_coef": "auto",
            "tau": 0.02,
            "train_freq": 8,
            "gradient_steps": 8,
            "learning_starts": 1_000,
            "use_sde": True,
        },
        "policy_kwargs": {"log_std_init": -3.0},
    },
}


#: What a ``config.json`` written before a field existed meant by it, where that is not the field's default.
_PREDATED: dict[str, Any] = {"terminal_at_horizon": False}


@dataclass
class SB3Config:
    """Everything that defines an RL baseline run (one place; the example's command line is derived from it)."""

    algo: str = "PPO"
    """``"PPO"`` or ``"SAC"``."""
    env_id: str = "SeagulAcrobot-v0"
    """Gymnasium id to train in (any registered seagul env)."""
    total_timesteps: int = 1_000_000
    """Environment steps (summed over the parallel envs)."""
    seed: int = 0
    """Seed of the envs, the networks and the exploration."""
    learning_rate: float = 0.0
    """Adam learning rate (0 = the zoo entry's)."""
    gamma: float = 0.98
    """Discount."""
    net_arch: tuple[int, ...] = ()
    """Hidden widths of the policy and value/Q networks (empty = the zoo entry's: PPO 64,64; SAC 400,300)."""
    n_envs: int = 0
    """Parallel envs (0 = the zoo entry's: PPO 4, SAC 1)."""
    normalize: bool = True
    """Normalise observations with ``VecNormalize`` (rewards: ``normalize_reward``); the statistics are saved."""
    normalize_reward: bool | None = None
    """Also scale rewards by the running spread of the discounted return (``None``: PPO yes, SAC no, as in the
    zoo). Acrobot costs span 1e-3 (balancing) to 1e5 (diverging) per step, which a critic's targets feel."""
    reward_scale: float = 1.0
    """A fixed factor on the training reward (SAC's reward scale, Haarnoja et al. 2018, sec. 5.2): the optimal
    policy is unchanged, the critic's targets shrink (the acrobot's zero-torque return is -2.2e4). Applied inside
    each env after its ``Monitor``, so logged episode returns and every evaluation stay in the task's units."""
    miss_penalty: float = 0.0
    """Added to the learner's last reward of an episode: ``-miss_penalty * violation``, the final state's miss of
    the task's success rule in units of its tolerances (``SuccessRule.violation``; 0 when it succeeds). The
    glider's NLP imposes the perch as a constraint, which its env's reward (the trajectory cost) does not carry:
    there not perching is cheaper than perching, and a learner is not asked to perch without this. Logged returns
    and evaluations stay the trajectory cost."""
    terminal_at_horizon: bool = True
    """The end of the task's horizon is a termination for the learner, not a time-limit truncation. The seagul envs
    are finite-horizon problems with the time to go in the observation and the terminal cost in the last reward, so
    nothing follows the last step (Pardo et al. 2018, "Time Limits in Reinforcement Learning"). Gymnasium's
    ``truncated`` makes SB3 bootstrap ``gamma * Q(x_N)`` at an observation (time to go 0) that no transition ever
    starts from: with ``gamma = 0.995`` that extrapolation can stand for up to ``1 / (1 - gamma) = 200`` more steps.
    ``False`` is what a stored ``config.json`` without this field was trained with."""
    eval_every: int = 50_000
    """Environment steps between two points of the learning curve (0 = only at the end)."""
    eval_grid: int = 0
    """Grid points per axis of the curve's evaluation (0 = the task's evaluation grid, acrobot 20, glider 6)."""
    progress: bool = False
    """Show SB3's progress bar."""
    algo_overrides: dict[str, Any] = field(default_factory=dict)
    """Further SB3 constructor arguments over the zoo entry's (e.g. ``{"ent_coef": 0.01}``)."""

    def __post_init__(self) -> None:
        self.net_arch = tuple(int(w) for w in self.net_arch)
        if self.algo not in ALGOS:
            raise ValueError(f"unknown algo {self.algo!r}; choose one of {list(ALGOS)}")
        if int(self.total_timesteps) < 1:
            raise ValueError(f"total_timesteps must be >= 1, got {self.total_timesteps}")
        if not (0.0 < self.gamma <= 1.0):
            raise ValueError(f"gamma must be in (0, 1], got {self.gamma}")
        if not (self.learning_rate >= 0 and math.isfinite(self.learning_rate)):
            raise ValueError(f"learning_rate must be >= 0 (0: the zoo's), got {self.learning_rate}")
        for name in ("n_envs", "eval_every", "eval_grid"):
            if int(getattr(self, name)) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if any(w < 1 for w in self.net_arch):
            raise ValueError(f"net_arch widths must be >= 1, got {self.net_arch}")
        if not (self.reward_scale > 0 and math.isfinite(self.reward_scale)):
            raise ValueError(f"reward_scale must be a finite number > 0, got {self.reward_scale}")
        if not (self.miss_penalty >= 0 and math.isfinite(self.miss_penalty)):
            raise ValueError(f"miss_penalty must be a finite number >= 0, got {self.miss_penalty}")

    # ------------------------------------------------------------------------------------ resolved settings
    def resolved(self) -> dict[str, Any]:
        """The settings actually used: the zoo entry with this config's values over it."""
        zoo = ZOO_DEFAULTS[self.algo]
        kwargs = {**zoo["algo_kwargs"], **self.algo_overrides}
        return {
            "n_envs": self.n_envs or zoo["n_envs"],
            "learning_rate": self.learning_rate or zoo["learning_rate"],
            "net_arch": list(self.net_arch or zoo["net_arch"]),
            "algo_kwargs": kwargs,
            "policy_kwargs": dict(zoo.get("policy_kwargs", {})),
            "normalize_reward": self.reward_normalized(),
            "reward_scale": float(self.reward_scale),
            "miss_penalty": float(self.miss_penalty),
        }

    def reward_normalized(self) -> bool:
        """Whether rewards are normalised (``normalize_reward``, its ``None`` resolved per algorithm)."""
        if not self.normalize:
            return False
        return self.algo == "PPO" if self.normalize_reward is None else bool(self.normalize_reward)

    def describes(self, stored: dict[str, Any]) -> bool:
        """Whether ``stored`` (a ``config.json``) is this config; fields it predates count at their defaults, or
        at what runs did before the field existed where that differs (``terminal_at_horizon``: ``False``)."""
        defaults = {f.name: f.default for f in fields(self) if f.default is not MISSING} | _PREDATED
        filled = {k: v for k, v in json.loads(json.dumps(defaults)).items() if k not in stored} | stored
        mine = json.loads(json.dumps(self.to_dict()))
        try:  # normalize_reward compares by what it resolves to (None is the algorithm's default)
            filled["normalize_reward"] = replace(
                self,
                normalize_reward=filled["normalize_reward"],
                normalize=bool(filled["normalize"]),
                algo=filled["algo"],
            ).reward_normalized()
        except (KeyError, ValueError, TypeError):
            return False
        mine["normalize_reward"] = self.reward_normalized()
        return filled == mine

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (``config.json``)."""
        out = asdict(self)
        out["net_arch"] = list(self.net_arch)
        return out


def task_of_env(env_id: str) -> Any:
    """The Task an env id simulates (its ``unwrapped.task``)."""
    import gymnasium as gym

    import seagul_envs  # noqa: F401  (registers the envs)

    env = gym.make(env_id)
    try:
        return env.unwrapped.task  # type: ignore[attr-defined]
    finally:
        env.close()


def _learner_view(env: Any, scale: float, terminal_at_horizon: bool, miss_penalty: float = 0.0) -> Any:
    """``env`` as the learner sees it: ``-miss_penalty * violation`` on an episode's last step, reward times
    ``scale``, and (``terminal_at_horizon``) the horizon's end a termination (``SB3Config.miss_penalty``,
    ``SB3Config.reward_scale``, ``SB3Config.terminal_at_horizon``)."""
    import gymnasium as gym

    class MissPenalty(gym.Wrapper):
        """The last reward of an episode also pays for missing the task's success rule (its final state's
        ``SuccessRule.violation``)."""

        def __init__(self, inner: Any) -> None:
            super().__init__(inner)
            self.task = inner.unwrapped.task  # the seagul envs simulate one Task
            self.rule = self.task.profile.success

        def step(self, action: Any) -> Any:
            obs, reward, terminated, truncated, info = self.env.step(action)
            if terminated or truncated:
                reward = float(reward) - miss_penalty * self.rule.violation(self.task, info["state"])
            return obs, reward, terminated, truncated, info

    class HorizonEndTerminates(gym.Wrapper):
        """``terminated = terminated or truncated``, ``truncated = False``: the finite horizon's end is terminal."""

        def step(self, action: Any) -> Any:
            obs, reward, terminated, truncated, info = self.env.step(action)
            return obs, reward, bool(terminated or truncated), False, info

    if miss_penalty:
        env = MissPenalty(env)
    if scale != 1.0:
        env = gym.wrappers.TransformReward(env, lambda r: float(r) * scale)
    return HorizonEndTerminates(env) if terminal_at_horizon else env


class _NormalizedPolicy:
    """A live SB3 model behind the predictor protocol (observations normalised with the current statistics)."""

    def __init__(self, model: Any, venv: Any) -> None:
        self.model, self.venv = model, venv

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None, deterministic: bool = True):
        obs = np.asarray(observation, dtype=np.float32)
        if self.venv is not None:
            obs = self.venv.normalize_obs(obs)
        return self.model.predict(obs, deterministic=deterministic)


class ZeroPolicy:
    """The zero-input policy (the curves' floor: what doing nothing achieves)."""

    def __init__(self, nu: int) -> None:
        self.nu = int(nu)

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None, deterministic: bool = True):
        return np.zeros(self.nu, dtype=np.float32), None


def episode_stats(task: Any, policy: Any, starts: np.ndarray, env_id: str | None = None) -> dict[str, float]:
    """Success rate (the task's rule), mean return, mean final distance ``||x(T) - x*||`` and mean miss of the
    success rule (``SuccessRule.violation`` of the final state, in units of its tolerances; 0 where it succeeds) of
    ``policy`` from ``starts``. The miss is the measure of learning that is comparable across tasks: the glider's
    return (its trajectory cost) rises when a policy stops perching, and its raw distance mixes metres and m/s."""
    from seagul_control.evaluation import run_policy_episode

    results = [run_policy_episode(task, policy, x0, index=i, env_id=env_id)[0] for i, x0 in enumerate(starts)]
    rule = task.profile.success
    return {
        "success_rate": float(np.mean([r.success for r in results])),
        "mean_return": float(np.mean([-r.cost for r in results])),
        "mean_final_distance": float(np.mean([r.final_distance for r in results])),
        "mean_miss": float(np.mean([rule.violation(task, np.asarray(r.final_state)) for r in results])),
    }


def _make_model(config: SB3Config, venv: Any) -> Any:
    import stable_baselines3

    settings = config.resolved()
    cls = getattr(stable_baselines3, config.algo)
    policy_kwargs = {**settings["policy_kwargs"], "net_arch": settings["net_arch"]}
    return cls(
        "MlpPolicy",
        venv,
        learning_rate=settings["learning_rate"],
        gamma=config.gamma,
        policy_kwargs=policy_kwargs,
        seed=config.seed,
        device="cpu",
        verbose=0,
        **settings["algo_kwargs"],
    )


def training_env(config: SB3Config) -> Any:
    """The vectorised env ``config`` trains in: ``n_envs`` seeded copies of ``env_id``, each ``Monitor``-ed (episode
    returns in the task's units), then seen through ``reward_scale`` and ``terminal_at_horizon``, then
    ``VecNormalize`` if asked."""
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    venv: Any = make_vec_env(
        config.env_id,
        n_envs=config.resolved()["n_envs"],
        seed=config.seed,
        vec_env_cls=DummyVecEnv,
        wrapper_class=partial(
            _learner_view,
            scale=float(config.reward_scale),
            terminal_at_horizon=bool(config.terminal_at_horizon),
            miss_penalty=float(config.miss_penalty),
        ),
    )
    if config.normalize:
        venv = VecNormalize(venv, norm_obs=True, norm_reward=config.reward_normalized(), gamma=config.gamma)
    return venv


def extends(config: SB3Config, stored: dict[str, Any]) -> bool:
    """Whether ``stored`` (a finished run's ``config``) is ``config`` with fewer ``total_timesteps``: a run that
    :func:`train_sb3` ``(extend=True)`` continues instead of starting afresh. ``eval_every`` may differ (it spaces
    the curve's points, not the training); the continued run's points follow this config's."""
    if int(stored.get("total_timesteps", 0)) >= int(config.total_timesteps):
        return False
    earlier = replace(config, total_timesteps=int(stored["total_timesteps"]))
    return replace(earlier, eval_every=int(stored.get("eval_every", config.eval_every))).describes(stored)


def train_sb3(
    config: SB3Config,
    out: str | Path,
    on_point: Callable[[dict[str, Any]], None] | None = None,
    extend: bool = False,
) -> dict[str, Any]:
    """Train ``config`` into ``out``; returns the run's summary (also ``curve.json``).

    The learning curve's points (``curve``) hold ``env_steps``, ``wall_s`` (training time so far, evaluation
    excluded), ``success_rate`` and ``mean_return`` on the grid; ``on_point`` sees each as it is made, and
    ``curve.partial.json`` holds the points so far until the run completes.

    ``extend``: when ``out`` holds a finished run of this config with fewer ``total_timesteps`` (:func:`extends`),
    continue it to ``total_timesteps`` instead of starting over: its model, observation/reward statistics and curve
    are loaded and training goes on from its step count (SB3 ``reset_num_timesteps=False``; the wall time adds to
    its own). The continued run is a valid longer run but not bit-identical to one trained in one go (the envs
    restart their episodes and PPO its rollout); the summary records ``extended_from`` (the earlier steps).
    """
    import torch
    from stable_baselines3.common.callbacks import BaseCallback

    from seagul_control.evaluation import start_grid

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(1)  # small networks: one thread is fastest and keeps runs machine-independent
    task = task_of_env(config.env_id)
    settings = config.resolved()
    prior: dict[str, Any] | None = None
    if extend and (out / "curve.json").is_file():
        stored = json.loads((out / "curve.json").read_text())
        prior = stored if extends(config, stored.get("config", {})) else None
    venv = training_env(config)
    if prior is None:
        model = _make_model(config, venv)
    else:
        import stable_baselines3
        from stable_baselines3.common.vec_env import VecNormalize

        if config.normalize:
            venv = VecNormalize.load(str(out / "vecnormalize.pkl"), venv.venv)
            venv.training = True
        model = getattr(stable_baselines3, config.algo).load(out / "model.zip", env=venv, device="cpu")
    n_grid = config.eval_grid or task.profile.grid.points
    grid, _ = start_grid(task, n_grid)
    live = _NormalizedPolicy(model, venv if config.normalize else None)
    curve: list[dict[str, Any]] = list(prior["curve"]) if prior else []
    clock = {"train": float(prior["train_wall_s"]) if prior else 0.0, "since": time.perf_counter()}

    def point() -> None:
        clock["train"] += time.perf_counter() - clock["since"]
        row = {"env_steps": int(model.num_timesteps), "wall_s": round(clock["train"], 1)}
        row.update(episode_stats(task, live, grid, config.env_id))
        curve.append(row)
        # A run of hours is visible while it runs, and a killed one leaves its curve so far (``complete: false``).
        _write_json(out / "curve.partial.json", {"config": config.to_dict(), "complete": False, "curve": curve})
        if on_point is not None:
            on_point(row)
        clock["since"] = time.perf_counter()

    class Curve(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.next_point = config.eval_every
            while curve and config.eval_every and self.next_point <= curve[-1]["env_steps"]:
                self.next_point += config.eval_every

        def _on_step(self) -> bool:
            if config.eval_every and self.num_timesteps >= self.next_point:
                point()
                self.next_point += config.eval_every
            return True

    done = int(model.num_timesteps) if prior else 0
    model.learn(
        total_timesteps=int(config.total_timesteps) - done,
        callback=Curve(),
        progress_bar=config.progress,
        reset_num_timesteps=prior is None,
    )
    if not curve or curve[-1]["env_steps"] != model.num_timesteps:
        point()
    model.save(out / "model.zip")
    if config.normalize:
        venv.save(str(out / "vecnormalize.pkl"))
    summary = {
        "config": config.to_dict(),
        "resolved": settings,
        "env_steps": int(model.num_timesteps),
        "train_wall_s": curve[-1]["wall_s"],
        "curve": curve,
        "model": str(out / "model.zip"),
    }
    if prior:
        summary["extended_from"] = [*prior.get("extended_from", []), int(prior["env_steps"])]
    _write_json(out / "curve.json", summary)
    (out / "curve.partial.json").unlink(missing_ok=True)
    return summary


def _write_json(path: Path, payload: Any) -> None:
    from seagul_control._io import atomic_write_text

    atomic_write_text(path, json.dumps(payload, indent=1))


def config_from_args(argv: list[str] | None = None, description: str = "") -> tuple[SB3Config, Path]:
    """``(config, out)`` from the command line: one ``--flag`` per :class:`SB3Config` field (help from the field
    docstrings), ``--out DIR`` and ``--test`` (a seconds-long run for CI)."""
    import argparse

    from seagul_learn.commands._config import Option, add_dataclass_arguments, dataclass_from_args

    parser = argparse.ArgumentParser(
        description=description or "Train an SB3 baseline on a seagul env.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_dataclass_arguments(parser, SB3Config, {"algo": Option(choices=ALGOS)})
    parser.add_argument("--out", type=Path, default=None, help="run directory (default: runs/<algo>_<env id>)")
    parser.add_argument("--test", action="store_true", help="a seconds-long run (CI smoke test)")
    args = parser.parse_args(argv)
    try:
        config = dataclass_from_args(SB3Config, args)
    except ValueError as exc:
        parser.error(str(exc))
    if args.test:
        config = smoke_config(config)
    out = args.out or Path("runs") / f"{config.algo.lower()}_{config.env_id}"
    return config, out


def smoke_config(config: SB3Config) -> SB3Config:
    """``config`` shrunk to a seconds-long run (CI): tiny budget and networks, a 3 x 3 curve grid."""
    small = (
        {"n_steps": 64, "batch_size": 32, "n_epochs": 1}
        if config.algo == "PPO"
        else {"learning_starts": 64, "batch_size": 32, "buffer_size": 1000}
    )
    return replace(
        config,
        total_timesteps=256,
        eval_every=128,
        eval_grid=3,
        net_arch=(16,),
        algo_overrides={**config.algo_overrides, **small},
    )
