"""PPO or SAC (stable-baselines3) on a seagul env, to compare with the learned MPC on the same starts.

Run::

    .venv/bin/python examples/train_sb3.py --algo SAC --env-id SeagulAcrobot-v0 --total-timesteps 300000
    .venv/bin/python examples/train_sb3.py --algo PPO --env-id SeagulGlider-v0 --out runs/ppo_glider
    .venv/bin/python examples/train_sb3.py --algo SAC --test      # seconds, for CI

The config (:class:`seagul_learn.baselines.SB3Config`) is declared once and tyro derives a ``--flag`` from every
field (``--help`` lists them with their docstrings). The settings are the env id's tuned entry in
``seagul_learn/hyperparams/`` (the learner's view: cos/sin angles, scaled time to go, actions in [-1, 1], a bounded
success-aware reward; rl-zoo sizes); the dict fields take a JSON object, ``--algo-overrides '{"ent_coef": 0.01}'``
and ``--view-overrides '{"end_scale": 4.0}'``, and change them. The run directory gets ``model.zip``,
``vecnormalize.pkl``, ``view.json`` and, in ``best/``, the checkpoint selected on validation starts, with
``curve.json`` (validation success against environment steps). Then evaluate it next to the MPC (the statistics
and the view beside the model are picked up automatically)::

    seagul evaluate --task acrobot --sb3 runs/sac_SeagulAcrobot-v0/best/model.zip --sb3-algo SAC --lqr --out <dir>
"""

from __future__ import annotations

import json

from seagul_control.starts import heldout_starts
from seagul_learn.baselines import config_from_args, episode_stats, task_of_env, train_sb3


def main() -> None:
    config, out = config_from_args(description=__doc__)
    print(f"{config.algo} on {config.env_id}, {config.total_timesteps} env steps -> {out}", flush=True)
    summary = train_sb3(
        config,
        out,
        on_point=lambda p: print(
            f"  {p['env_steps']:>9} steps  validation success {p['success_rate']:6.1%}  "
            f"median final distance {p['median_final_distance']:.3g}",
            flush=True,
        ),
    )
    # The saved model as a user loads it, on starts it never saw.
    from seagul_learn.policies import SB3Policy

    task = task_of_env(config.env_id)
    policy = SB3Policy(task, summary["model"], algo=config.algo)
    held = episode_stats(task, policy, heldout_starts(task, 10 if 0 < config.total_timesteps < 10_000 else 100))
    print(json.dumps({"env_steps": summary["env_steps"], "train_wall_s": summary["train_wall_s"], "heldout": held}))


if __name__ == "__main__":
    main()
