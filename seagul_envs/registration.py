"""Idempotent Gymnasium registration (Gymnasium 1.x has no plugin entry points)."""

from __future__ import annotations

import gymnasium as gym

ENV_IDS: dict[str, str] = {
    "SeagulAcrobot-v0": "seagul_envs.envs.acrobot:AcrobotEnv",
    "SeagulAcrobotMujoco-v0": "seagul_envs.envs.acrobot_mujoco:AcrobotMujocoEnv",
    "SeagulGlider-v0": "seagul_envs.envs.glider:GliderEnv",
}


def register_envs() -> None:
    """Register every seagul env id once; calling it again is a no-op."""
    for env_id, entry_point in ENV_IDS.items():
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=entry_point, disable_env_checker=False)
