"""PPO baseline on the seagul envs (stable-baselines3), to compare with the SEAGuL MPC on the same starts.

Run::

    .venv/bin/python examples/train_ppo.py --env-id SeagulAcrobot-v0 --out runs/ppo_acrobot
    .venv/bin/python examples/train_ppo.py --env-id SeagulGlider-v0 --out runs/ppo_glider
    .venv/bin/python examples/train_ppo.py --test          # seconds, for CI

then evaluate next to the MPC (the ``vecnormalize.pkl`` beside the model is picked up automatically)::

    seagul evaluate --task acrobot --sb3 runs/ppo_acrobot/model.zip --network <network.pt> --lqr --out <dir>

Hyperparameters are adapted from rl-zoo3's tuned ``Pendulum-v1`` PPO (the closest continuous-torque swing/balance
task in ``hyperparams/ppo.yml``): 4 envs, ``n_steps=1024``, ``gae_lambda=0.95``, 10 epochs, ``lr=1e-3``,
``clip_range=0.2``, gSDE with ``sde_sample_freq=4``, no entropy bonus. Changes, with reasons: ``gamma=0.98``
(zoo: 0.9) because our episodes are 50 (acrobot) or 32 (glider) steps and the terminal cost arrives at the end;
``VecNormalize`` on observations and rewards (zoo uses ``normalize: true`` for Acrobot-v1 and
MountainCarContinuous) because a diverging acrobot earns rewards of -1e5 per step while balancing earns ~-1e-3;
``2e5`` steps (zoo: 1e5) as two tasks' worth of a small budget. The script prints the environment steps used, to
report next to the number of NLP solves SEAGuL used.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import gymnasium as gym
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

import seagul_envs  # noqa: F401  (registers the envs)


@dataclass
class Config:
    """Everything that defines a run (CleanRL style)."""

    env_id: str = "SeagulAcrobot-v0"
    """Gymnasium id (SeagulAcrobot-v0 or SeagulGlider-v0)."""
    out: str = "runs/ppo_acrobot"
    """Output directory: model.zip, vecnormalize.pkl, config.json."""
    seed: int = 0
    """Seed of the envs and of PPO."""
    total_timesteps: int = 200_000
    """Environment steps (summed over the parallel envs)."""
    n_envs: int = 4
    """Parallel envs (zoo Pendulum-v1: 4)."""
    n_steps: int = 1024
    """Rollout length per env per update (zoo: 1024)."""
    batch_size: int = 64
    """Minibatch size (SB3 default; the zoo entry keeps it)."""
    n_epochs: int = 10
    """Epochs per update (zoo: 10)."""
    gamma: float = 0.98
    """Discount (zoo: 0.9; longer here, see the module docstring)."""
    gae_lambda: float = 0.95
    """GAE lambda (zoo: 0.95)."""
    learning_rate: float = 1e-3
    """Adam learning rate (zoo: 1e-3)."""
    clip_range: float = 0.2
    """PPO clip range (zoo: 0.2)."""
    ent_coef: float = 0.0
    """Entropy bonus (zoo: 0)."""
    use_sde: bool = True
    """Generalised state-dependent exploration (zoo: True)."""
    sde_sample_freq: int = 4
    """Resample the gSDE noise every this many steps (zoo: 4)."""
    normalize: bool = True
    """VecNormalize observations and rewards (saved next to the model)."""
    test: bool = False
    """Shrink everything to a few seconds (CI smoke test)."""


def parse_args() -> Config:
    """Every Config field as a ``--flag`` (booleans as ``--flag`` / ``--no-flag``)."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    for f in fields(Config):
        flag = "--" + f.name.replace("_", "-")
        if f.type in ("bool", bool):
            parser.add_argument(flag, action=argparse.BooleanOptionalAction, default=f.default)
        else:
            kind = {"int": int, "float": float, "str": str}[str(f.type)]
            parser.add_argument(flag, type=kind, default=f.default)
    config = Config(**vars(parser.parse_args()))
    if config.env_id not in ("SeagulAcrobot-v0", "SeagulGlider-v0"):
        parser.error(f"--env-id must be SeagulAcrobot-v0 or SeagulGlider-v0, got {config.env_id!r}")
    if config.test:
        config.total_timesteps, config.n_envs, config.n_steps, config.batch_size, config.n_epochs = 256, 2, 64, 32, 1
    return config


config = parse_args()
out = Path(config.out)
out.mkdir(parents=True, exist_ok=True)

# 1. Vectorised envs (observations: state and time to go), normalised as in the zoo's `normalize: true`.
venv = make_vec_env(config.env_id, n_envs=config.n_envs, seed=config.seed, vec_env_cls=DummyVecEnv)
if config.normalize:
    venv = VecNormalize(venv, norm_obs=True, norm_reward=True, gamma=config.gamma)

# 2. PPO with the zoo-derived hyperparameters.
model = PPO(
    "MlpPolicy",
    venv,
    n_steps=config.n_steps,
    batch_size=config.batch_size,
    n_epochs=config.n_epochs,
    gamma=config.gamma,
    gae_lambda=config.gae_lambda,
    learning_rate=config.learning_rate,
    clip_range=config.clip_range,
    ent_coef=config.ent_coef,
    use_sde=config.use_sde,
    sde_sample_freq=config.sde_sample_freq,
    seed=config.seed,
    device="cpu",
    verbose=0,
)

# 3. Train and save the model, the normalisation statistics and the config.
start = time.perf_counter()
model.learn(total_timesteps=config.total_timesteps, progress_bar=False)
elapsed = time.perf_counter() - start
model.save(out / "model.zip")
if config.normalize:
    venv.save(str(out / "vecnormalize.pkl"))
(out / "config.json").write_text(json.dumps({**asdict(config), "env_steps": int(model.num_timesteps)}, indent=2))

# 4. A quick deterministic check on one fresh episode, then the budget used.
check_env = gym.make(config.env_id)
obs, _ = check_env.reset(seed=config.seed + 1000)
total, done = 0.0, False
while not done:
    norm_obs = venv.normalize_obs(obs) if config.normalize else obs
    action, _ = model.predict(norm_obs, deterministic=True)
    obs, reward, terminated, truncated, _ = check_env.step(action)
    total += float(reward)
    done = terminated or truncated
print(f"{config.env_id}: trained {elapsed:.1f} s, one test episode cost {-total:.4g}")
print(f"env steps used: {model.num_timesteps}")
print(out / "model.zip")
