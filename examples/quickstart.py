"""The library in one page: solve, learn a value function with SEAGuL, control with it, evaluate like SB3.

Run::

    .venv/bin/python examples/quickstart.py            # ~2-4 minutes on 2 cores (first run compiles solvers)
    .venv/bin/python examples/quickstart.py --test     # seconds of work, for CI

Top to bottom: (1) one trajectory optimization with its dual gradient, (2) a short SEAGuL training run,
(3) the learned value function as terminal cost of a 5-step MPC in a Gymnasium loop, (4) the same policy through
stable-baselines3's ``evaluate_policy`` next to clipped LQR.
"""

from __future__ import annotations

import argparse
import tempfile
from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv

import seagul_envs  # noqa: F401  (registers the envs)
from seagul_control import LimitedLookaheadMPC, LQRPolicy
from seagul_envs import make_task
from seagul_learn import ScheduleConfig, TrainConfig, TrajectoryOptimizer, train


@dataclass
class Config:
    """Everything this example uses (CleanRL style)."""

    task: str = "acrobot"
    """Task name."""
    budget: int = 40
    """Solves spent by the adversarial sampler."""
    train_steps_per_round: int = 500
    """Adam steps after each round of 10 solves."""
    horizon: int = 5
    """MPC lookahead steps."""
    episodes: int = 4
    """Episodes of the evaluation loops."""
    seed: int = 0
    """Seed of training and of the env starts."""
    out: str = ""
    """Run directory of the training (default: a temporary directory)."""


def main(cfg: Config) -> None:
    task = make_task(cfg.task)

    # 1. One solve of paper Eq. 1: the value, its gradient from the duals, and a label per knot.
    optimizer = TrajectoryOptimizer(task)
    x0 = task.sample_x0(np.random.default_rng(cfg.seed))
    result = optimizer.solve(x0)
    print(f"V(x0, {result.tau} s) = {result.value:.3f}  dV/dx0 = {np.round(result.grad_x, 3)}  ({result.status})")
    print(f"  {result.num_knots} per-knot labels; cost to go at knot 10: {result.cost_to_go[10]:.3f}")

    # 2. SEAGuL: adversarial sampling guided by those gradients, paper Alg. 1 and 2.
    out = Path(cfg.out or tempfile.mkdtemp(prefix="seagul-quickstart-"))
    config = TrainConfig(
        task=cfg.task,
        sampler="adversarial",
        budget=cfg.budget,
        schedule=ScheduleConfig(train_steps_per_round=cfg.train_steps_per_round),
        seed=cfg.seed,
    )
    trained = train(config, out / "adversarial")
    last = trained.metrics[-1]
    print(f"trained on {trained.num_solves} solves: validation mse_initial {last.mse_initial:.3g}")

    # 3. The network as terminal cost of a limited-lookahead MPC, in a plain Gymnasium loop.
    # A network of a few dozen solves sits on the task's quadratic terminal cost ("lqr"); the acrobot's default guard
    # ("none") is for the shipped 2,000-solve networks (docs/experiments/closed-loop.md).
    policy = LimitedLookaheadMPC(task, trained.network, horizon=cfg.horizon, trust_region="lqr")
    env = gym.make("SeagulAcrobot-v0")
    obs, info = env.reset(seed=cfg.seed)
    episode_return, done = 0.0, False
    while not done:
        action, _ = policy.predict(obs, deterministic=True)
        obs, reward, terminated, truncated, info = env.step(action)
        episode_return += float(reward)
        done = terminated or truncated
    distance = np.linalg.norm(info["state"] - task.goal)
    print(f"MPC episode: return {episode_return:.2f}, final distance to the goal {distance:.4f}")

    # 4. Any SB3 evaluation loop takes the MPC (batched observations from a DummyVecEnv).
    vec_env = DummyVecEnv([lambda: Monitor(gym.make("SeagulAcrobot-v0")) for _ in range(2)])
    vec_env.seed(cfg.seed)
    for name, candidate in (("MPC", policy), ("LQR", LQRPolicy(task))):
        mean, std = evaluate_policy(candidate, vec_env, n_eval_episodes=cfg.episodes, deterministic=True)
        print(f"{name}: mean return {mean:.2f} +- {std:.2f} over {cfg.episodes} episodes")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--test", action="store_true", help="shrink everything to seconds (CI)")
    parser.add_argument("--out", default="", help="run directory (default: a temporary one)")
    args = parser.parse_args()
    cfg = Config(out=args.out)
    if args.test:
        cfg = Config(budget=4, train_steps_per_round=20, episodes=2, out=args.out)
    main(cfg)
