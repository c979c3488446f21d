"""RL baselines: the config (zoo defaults, validation, command line) and a tiny training run's outputs."""

from __future__ import annotations

import json

import numpy as np
import pytest

from seagul_control.evaluation import heldout_starts
from seagul_learn.baselines import (
    ZOO_DEFAULTS,
    SB3Config,
    ZeroPolicy,
    config_from_args,
    episode_stats,
    smoke_config,
    task_of_env,
    train_sb3,
)


def test_config_resolves_zoo_defaults_and_overrides():
    ppo = SB3Config().resolved()
    assert ppo["n_envs"] == 4 and ppo["learning_rate"] == 1e-3 and ppo["net_arch"] == [64, 64]
    assert ppo["algo_kwargs"]["n_steps"] == 1024 and ppo["algo_kwargs"]["use_sde"] is True
    sac = SB3Config(algo="SAC", learning_rate=3e-4, algo_overrides={"tau": 0.01}).resolved()
    assert sac["learning_rate"] == 3e-4 and sac["net_arch"] == [400, 300]
    assert sac["algo_kwargs"]["tau"] == 0.01 and sac["algo_kwargs"]["batch_size"] == 256
    assert ZOO_DEFAULTS["SAC"]["algo_kwargs"]["tau"] == 0.02  # the table itself is untouched


def test_reward_normalisation_resolves_per_algorithm_and_old_configs_still_match():
    assert SB3Config(algo="PPO").reward_normalized() is True
    assert SB3Config(algo="SAC").reward_normalized() is False  # the zoo's
    assert SB3Config(algo="SAC", normalize_reward=True).reward_normalized() is True
    assert SB3Config(algo="SAC", normalize_reward=True, normalize=False).reward_normalized() is False
    assert SB3Config(algo="SAC", normalize_reward=True).resolved()["normalize_reward"] is True
    sac = SB3Config(algo="SAC", total_timesteps=8000)
    stored = sac.to_dict()
    del stored["normalize_reward"]  # a config.json written before the field existed
    assert SB3Config(algo="SAC", total_timesteps=8000, normalize_reward=False).describes(stored)
    assert SB3Config(algo="SAC", total_timesteps=8000).describes(stored)
    assert not SB3Config(algo="SAC", total_timesteps=8000, normalize_reward=True).describes(stored)
    assert not SB3Config(algo="SAC", total_timesteps=9000).describes(stored)
    assert not SB3Config(algo="PPO", total_timesteps=8000).describes(stored)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"algo": "DQN"}, "unknown algo"),
        ({"total_timesteps": 0}, "total_timesteps"),
        ({"gamma": 1.5}, "gamma"),
        ({"learning_rate": -1.0}, "learning_rate"),
        ({"net_arch": (0,)}, "net_arch"),
        ({"eval_every": -1}, "eval_every"),
    ],
)
def test_config_rejects_bad_values(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SB3Config(**kwargs)


def test_command_line_is_derived_from_the_config(tmp_path):
    config, out = config_from_args(
        [
            "--algo",
            "SAC",
            "--net-arch",
            "32,32",
            "--gamma",
            "0.99",
            "--algo-overrides",
            '{"tau": 0.01}',
            "--out",
            str(tmp_path),
        ]
    )
    assert (config.algo, config.net_arch, config.gamma, config.algo_overrides) == ("SAC", (32, 32), 0.99, {"tau": 0.01})
    assert out == tmp_path
    small, _ = config_from_args(["--algo", "PPO", "--test"])
    assert small.total_timesteps == 256 and small.algo_overrides["n_steps"] == 64
    with pytest.raises(SystemExit):
        config_from_args(["--algo", "A2C"])


def test_tiny_run_writes_model_statistics_and_curve(tmp_path):
    config = smoke_config(SB3Config(algo="PPO", seed=3))
    seen: list[list[int]] = []

    def on_point(row):  # while the run goes, its curve so far is on disk
        partial = json.loads((tmp_path / "curve.partial.json").read_text())
        assert partial["complete"] is False and partial["curve"][-1] == row
        seen.append([p["env_steps"] for p in partial["curve"]])

    summary = train_sb3(config, tmp_path, on_point=on_point)
    assert len(seen) >= 2 and seen[-1][:-1] == seen[-2]
    assert not (tmp_path / "curve.partial.json").exists()  # replaced by curve.json at the end
    assert (tmp_path / "model.zip").is_file() and (tmp_path / "vecnormalize.pkl").is_file()
    stored = json.loads((tmp_path / "curve.json").read_text())
    assert stored["env_steps"] == summary["env_steps"] >= config.total_timesteps
    steps = [p["env_steps"] for p in stored["curve"]]
    assert steps == sorted(steps) and steps[-1] == summary["env_steps"] and len(steps) >= 2
    assert all(0.0 <= p["success_rate"] <= 1.0 and np.isfinite(p["mean_return"]) for p in stored["curve"])


def test_zero_input_floor_and_heldout_starts():
    task = task_of_env("SeagulAcrobot-v0")
    starts = heldout_starts(task, 5)
    assert np.array_equal(starts, heldout_starts(task, 5)) and all(task.in_x0(x) for x in starts)
    at_goal = episode_stats(task, ZeroPolicy(task.nu), task.goal[None, :])
    assert at_goal["success_rate"] == 1.0  # the upright equilibrium stays put without input
    away = episode_stats(task, ZeroPolicy(task.nu), starts)
    assert away["success_rate"] == 0.0 and away["mean_final_distance"] > 1.0


def test_bench_reuses_a_stored_run_only_for_the_same_config(tmp_path, monkeypatch) -> None:
    """``bench_rl_baselines._run``: a stored ``result.json`` is returned for its own config; for another config
    (a different budget) the directory is trained afresh instead of being reused silently."""
    import importlib
    import json
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    monkeypatch.syspath_prepend(str(root))
    bench = importlib.import_module("benchmarks.bench_rl_baselines")
    config = SB3Config(algo="SAC", total_timesteps=8000, seed=100, eval_every=0)
    run = tmp_path / "combo0"
    run.mkdir()
    stored = {"config": json.loads(json.dumps(config.to_dict())), "marker": 1}
    (run / "result.json").write_text(json.dumps(stored))
    assert bench._run(config, run) == stored

    class Retrained(Exception):
        pass

    def fake_train(cfg, out):
        raise Retrained(cfg.total_timesteps)

    monkeypatch.setattr(bench, "train_sb3", fake_train)
    with pytest.raises(Retrained, match="16000"):
        bench._run(SB3Config(algo="SAC", total_timesteps=16000, seed=100, eval_every=0), run)
    assert not (run / "result.json").exists()
