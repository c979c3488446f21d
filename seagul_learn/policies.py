"""Policies from descriptions, every kind: the learned ones built here, the control ones by ``seagul_control``.

:class:`~seagul_control.evaluation.PolicySpec` describes a policy and :func:`build_policy` builds it in whatever
process runs the episodes. ``seagul_control.evaluation`` keeps a registry of policy kinds, each naming its builder by
module path; the kinds that need a learned artefact, and so torch, are built by this module:

* ``"mpc"`` with a value network file (``PolicySpec("mpc", path="net.pt")``): :func:`build_network_mpc_policy` loads
  the network (:meth:`~seagul_learn.value_network.ValueNetwork.load`) and hands it to the control layer's
  limited-lookahead builder as the MPC's terminal cost (paper Alg. 1: ``Vhat`` at the end of the lookahead);
* ``"sb3"`` (``PolicySpec("sb3", path="model.zip")``): :func:`build_sb3_policy`, a saved stable-baselines3 model
  behind the predictor protocol (:class:`SB3Policy`).

The registry names these builders by path (``"seagul_learn.policies:build_sb3_policy"``), so a spec of a learned kind
made by code that never imported ``seagul_learn`` still builds, and joblib/loky workers import this module only when
they build one. Other kinds are added with :func:`~seagul_control.evaluation.register_policy_kind`.

Imports: module level, except stable-baselines3, an import of about a second that only the ``"sb3"`` kind needs,
made when an :class:`SB3Policy` is constructed.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from seagul_control.evaluation import (
    PolicySpec,
    build_lookahead_policy,
    build_policy,
    episode_env,
    evaluate,
    register_policy_kind,
)
from seagul_control.mpc import LimitedLookaheadMPC
from seagul_envs.tasks.base import Task
from seagul_envs.wrappers import LearnerView, learner_env
from seagul_learn.value_network import ValueNetwork

__all__ = [
    "PolicySpec",
    "SB3Policy",
    "build_network_mpc_policy",
    "build_policy",
    "build_sb3_policy",
    "evaluate",
    "register_policy_kind",
]


class SB3Policy:
    """A saved stable-baselines3 model behind the predictor protocol on the raw env.

    Beside the model it picks up ``vecnormalize.pkl`` (observation statistics) and ``view.json`` (the learner's
    view: angle features, scaled time to go, actions in ``[-1, 1]``; ``seagul_envs.wrappers.LearnerView``), so a
    model trained on the learner's view acts on the env's own observations and returns physical actions.
    """

    def __init__(
        self, task: Task, path: str, algo: str = "PPO", vecnormalize: str | None = None, view: str | None = None
    ) -> None:
        import stable_baselines3  # optional at import time: see the module docstring
        from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

        cls = getattr(stable_baselines3, algo, None)
        if cls is None:
            raise ValueError(f"unknown stable-baselines3 algorithm {algo!r}")
        self.model = cls.load(path, device="cpu")
        view_file = view or _beside(path, "view.json")
        self.view: LearnerView | None = LearnerView.load(view_file) if view_file is not None else None
        stats = vecnormalize or _beside(path, "vecnormalize.pkl")
        self.normalizer: Any = None
        if stats is not None:
            view_ = self.view
            # The statistics were kept on the learner's observations: load them over an env that makes those.
            venv = DummyVecEnv([lambda: episode_env(task) if view_ is None else learner_env(episode_env(task), view_)])
            self.normalizer = VecNormalize.load(stats, venv)
            self.normalizer.training = False
            self.normalizer.norm_reward = False

    def predict(
        self, observation: Any, state: Any = None, episode_start: Any = None, deterministic: bool = True
    ) -> tuple[np.ndarray, Any]:
        obs = np.asarray(observation, dtype=np.float32)
        if self.view is not None:
            obs = self.view.observe(obs)
        if self.normalizer is not None:
            obs = self.normalizer.normalize_obs(obs)
        action, state = self.model.predict(obs, state=state, episode_start=episode_start, deterministic=deterministic)
        return (self.view.action(action) if self.view is not None else action), state


def _beside(path: str, name: str) -> str | None:
    """The file ``name`` next to the model file, if any."""
    candidate = Path(path).with_name(name)
    return str(candidate) if candidate.is_file() else None


def build_sb3_policy(task: Task, spec: PolicySpec) -> SB3Policy:
    """``"sb3"``: the model saved at ``spec.path`` (options: ``algo``, ``vecnormalize``, ``view``)."""
    return SB3Policy(task, str(spec.path), **spec.option_dict())


def build_network_mpc_policy(task: Task, spec: PolicySpec) -> LimitedLookaheadMPC:
    """``"mpc"`` with a file: the limited-lookahead MPC whose terminal cost is the value network saved at
    ``spec.path`` (the spec's options as for the control kind: ``horizon``, ``trust_region``, ...)."""
    return build_lookahead_policy(task, spec, ValueNetwork.load(str(spec.path)))
