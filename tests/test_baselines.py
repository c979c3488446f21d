"""RL baselines: the config (zoo defaults, validation, command line) and a tiny training run's outputs."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from seagul_control.evaluation import heldout_starts
from seagul_learn.baselines import (
    ZOO_DEFAULTS,
    SB3Config,
    ZeroPolicy,
    config_from_args,
    episode_stats,
    extends,
    smoke_config,
    task_of_env,
    train_sb3,
    training_env,
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


def _fixed_torque_episode(config: SB3Config) -> tuple[list[float], float, bool]:
    """One training-env episode at a fixed torque: the learner's rewards, Monitor's return, SB3's timeout flag."""
    venv = training_env(config)
    venv.reset()
    action = np.full((1, 1), 7.0, dtype=np.float32)  # the same episode for every config
    rewards = []
    while True:
        _, reward, done, info = venv.step(action)
        rewards.append(float(reward[0]))
        if done[0]:
            return rewards, float(info[0]["episode"]["r"]), bool(info[0]["TimeLimit.truncated"])


def test_reward_scale_scales_what_the_learner_sees_not_the_logged_return():
    plain, plain_return, _ = _fixed_torque_episode(SB3Config(algo="SAC", seed=3, normalize=False))
    scaled, scaled_return, _ = _fixed_torque_episode(SB3Config(algo="SAC", seed=3, reward_scale=0.01, normalize=False))
    assert len(plain) == len(scaled) == 50 and min(plain) < -1.0
    np.testing.assert_allclose(scaled, 0.01 * np.array(plain), rtol=1e-6)  # the VecEnv keeps float32
    assert scaled_return == pytest.approx(plain_return, rel=1e-5)  # Monitor: the task's units
    assert plain_return == pytest.approx(sum(plain), rel=1e-5)
    assert SB3Config(algo="SAC", reward_scale=0.01).resolved()["reward_scale"] == 0.01
    stored = SB3Config(algo="SAC").to_dict()
    del stored["reward_scale"]  # a config.json written before the field existed
    assert SB3Config(algo="SAC").describes(stored)
    assert not SB3Config(algo="SAC", reward_scale=0.01).describes(stored)


def test_the_horizon_end_is_a_termination_for_the_learner():
    # SB3 bootstraps gamma * Q(next obs) past a truncation (info["TimeLimit.truncated"]); a finite-horizon task's
    # last step has nothing after it, so by default the learner sees a termination there.
    rewards, _, timeout = _fixed_torque_episode(SB3Config(algo="SAC", seed=3, normalize=False))
    assert len(rewards) == 50 and timeout is False
    old_rewards, _, old_timeout = _fixed_torque_episode(
        SB3Config(algo="SAC", seed=3, normalize=False, terminal_at_horizon=False)
    )
    assert old_timeout is True and old_rewards == rewards
    stored = SB3Config(algo="PPO").to_dict()
    del stored["terminal_at_horizon"]  # a run from before the field: it bootstrapped past the end
    assert SB3Config(algo="PPO", terminal_at_horizon=False).describes(stored)
    assert not SB3Config(algo="PPO").describes(stored)


def test_miss_penalty_charges_the_last_reward_for_missing_the_success_rule():
    """``miss_penalty``: only the episode's last reward changes, by ``-miss_penalty * violation`` of the final state
    (the glider's perch box in units of its tolerances); Monitor's return stays the trajectory cost."""
    from seagul_envs import make_task

    glider = make_task("glider")
    rule = glider.profile.success
    assert rule.violation(glider, glider.goal) == 0.0
    miss = glider.goal.copy()
    miss[0] -= 0.15  # 0.1 m beyond the 0.05 m tolerance: 2 tolerances
    miss[4] += 3.0  # 1 m/s beyond 2 m/s: half a tolerance
    assert rule.violation(glider, miss) == pytest.approx(2.5)
    acrobot = make_task("acrobot")
    far = acrobot.goal + np.array([0.0, 0.3, 0.4, 0.0])  # distance 0.5: 9 tolerances of 0.05 beyond it
    assert acrobot.profile.success.violation(acrobot, far) == pytest.approx(9.0)

    base = SB3Config(algo="SAC", env_id="SeagulGlider-v0", seed=3, normalize=False)
    plain, plain_return, _ = _fixed_torque_episode(base)
    venv = training_env(replace(base, miss_penalty=10.0))
    venv.reset()
    rewards = []
    while True:
        _, reward, done, info = venv.step(np.full((1, 1), 7.0, dtype=np.float32))
        rewards.append(float(reward[0]))
        if done[0]:
            break
    assert len(rewards) == len(plain) and rewards[:-1] == plain[:-1]
    violation = rule.violation(glider, info[0]["state"])
    assert violation > 1.0
    assert rewards[-1] == pytest.approx(plain[-1] - 10.0 * violation, rel=1e-5)
    assert float(info[0]["episode"]["r"]) == pytest.approx(plain_return, rel=1e-6)
    stored = SB3Config(algo="SAC").to_dict()
    del stored["miss_penalty"]  # a config.json written before the field existed
    assert SB3Config(algo="SAC").describes(stored)
    assert not SB3Config(algo="SAC", miss_penalty=1.0).describes(stored)
    with pytest.raises(ValueError, match="miss_penalty"):
        SB3Config(miss_penalty=-1.0)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"algo": "DQN"}, "unknown algo"),
        ({"total_timesteps": 0}, "total_timesteps"),
        ({"gamma": 1.5}, "gamma"),
        ({"learning_rate": -1.0}, "learning_rate"),
        ({"net_arch": (0,)}, "net_arch"),
        ({"eval_every": -1}, "eval_every"),
        ({"reward_scale": 0.0}, "reward_scale"),
        ({"reward_scale": float("inf")}, "reward_scale"),
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
    assert at_goal["mean_miss"] == 0.0
    away = episode_stats(task, ZeroPolicy(task.nu), starts)
    assert away["success_rate"] == 0.0 and away["mean_final_distance"] > 1.0
    # The miss is the distance's excess over the goal radius in radii (the acrobot's rule is one distance).
    radius = task.profile.success.distance
    assert away["mean_miss"] == pytest.approx((away["mean_final_distance"] - radius) / radius)


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

    def fake_train(cfg, out, extend=False):
        raise Retrained(f"{cfg.total_timesteps} extend={extend}")

    monkeypatch.setattr(bench, "train_sb3", fake_train)
    # the same run with a larger budget: continued, not thrown away
    with pytest.raises(Retrained, match="16000 extend=True"):
        bench._run(SB3Config(algo="SAC", total_timesteps=16000, seed=100, eval_every=0), run)
    assert (run / "result.json").exists()
    # a smaller budget, or another setting: trained afresh in its place
    with pytest.raises(Retrained, match="4000 extend=False"):
        bench._run(SB3Config(algo="SAC", total_timesteps=4000, seed=100, eval_every=0), run)
    assert not (run / "result.json").exists()


def test_a_finished_run_is_extended_to_a_larger_budget_with_its_curve_and_statistics(tmp_path):
    """``train_sb3(extend=True)``: a finished run of the same config with fewer steps goes on from its model and
    normalisation statistics; its curve is kept and continued, its wall time added to; another config is refused."""
    short = smoke_config(SB3Config(algo="PPO", seed=3))
    first = train_sb3(short, tmp_path)
    longer = replace(short, total_timesteps=2 * short.total_timesteps)
    assert extends(longer, first["config"]) and not extends(short, first["config"])
    assert not extends(replace(longer, gamma=0.9), first["config"])
    assert extends(replace(longer, eval_every=7 * short.eval_every), first["config"])  # curve spacing only
    second = train_sb3(longer, tmp_path, extend=True)
    assert second["extended_from"] == [first["env_steps"]]
    assert second["env_steps"] >= longer.total_timesteps > first["env_steps"]
    assert second["curve"][: len(first["curve"])] == first["curve"]
    steps = [p["env_steps"] for p in second["curve"]]
    assert steps == sorted(steps) and len(set(steps)) == len(steps) and steps[-1] == second["env_steps"]
    assert second["train_wall_s"] >= first["train_wall_s"]
    import stable_baselines3

    assert stable_baselines3.PPO.load(tmp_path / "model.zip").num_timesteps == second["env_steps"]


def _bench_with_fake_runs(monkeypatch):
    """``benchmarks.bench_rl_baselines`` with ``_run`` replaced by a stand-in that records each config and returns
    a two-point curve, grid success 25 % and held-out 50 %; returns ``(bench, seen)``."""
    import importlib
    from pathlib import Path

    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[1]))
    bench = importlib.import_module("benchmarks.bench_rl_baselines")
    seen: list[SB3Config] = []

    def fake_run(config, out, n_grid=0, n_heldout=100):
        seen.append(config)
        curve = [
            {
                "env_steps": s,
                "wall_s": 1.0,
                "success_rate": 0.0,
                "mean_return": -5.0 * s,
                "mean_final_distance": 4.0,
                "mean_miss": 7.0,
            }
            for s in (10, 20)
        ]
        return {
            "config": config.to_dict(),
            "resolved": config.resolved(),
            "env_steps": 20,
            "train_wall_s": 2.0,
            "curve": curve,
            "model": str(out / "model.zip"),
            "grid": {"success_rate": 0.25, "mean_return": -1.0, "mean_final_distance": 3.0},
            "heldout": {"success_rate": 0.5, "mean_return": -1.0, "mean_final_distance": 3.0},
        }

    monkeypatch.setattr(bench, "_run", fake_run)
    return bench, seen


def test_bench_update_of_one_algorithm_keeps_the_others_and_takes_settings_from_a_stored_sweep(
    tmp_path, monkeypatch
) -> None:
    """``bench_rl_baselines --algos SAC --settings-from SWEEP --update FILE``: SAC trains with the sweep's best
    setting and replaces its entry; the task's PPO entry, its sweep rows and the other task stay as they were."""
    from pathlib import Path

    bench, seen = _bench_with_fake_runs(monkeypatch)
    sweep = tmp_path / "sweep.json"
    sweep.write_text(json.dumps({"acrobot": {"SAC": {"best": {"learning_rate": 3e-4, "net_arch": [32, 32]}}}}))
    result = tmp_path / "rl.json"
    old_ppo = {"algo": "PPO", "success_rate": 0.0, "env_steps": 1000}
    result.write_text(
        json.dumps(
            {
                "acrobot": {"ppo": old_ppo, "sweep": {"PPO": {"rows": [1]}}, "machine": {"wall_s": 7}},
                "glider": {"ppo": {"algo": "PPO"}},
                "machine": {"wall_s": 7},
            }
        )
    )
    args = ["--quick", "--tasks", "acrobot", "--algos", "SAC", "--seeds", "2", "--workers", "1"]
    args += ["--settings-from", str(sweep), "--out", str(tmp_path / "w"), "--update", str(result)]
    assert bench.main(args) == 0
    assert [(c.learning_rate, c.net_arch, c.seed) for c in seen] == [(3e-4, (32, 32), 0), (3e-4, (32, 32), 1)]
    merged = json.loads(result.read_text())
    assert merged["glider"]["ppo"] == {"algo": "PPO"}
    acro = merged["acrobot"]
    assert {k: v for k, v in acro["ppo"].items() if k != "machine"} == old_ppo
    assert acro["ppo"]["machine"] == {"wall_s": 7}  # the run that made it
    assert acro["sweep"] == {"PPO": {"rows": [1]}}
    assert acro["sac"]["success_rate"] == 0.25 and acro["sac"]["settings_from"] == str(sweep)
    assert len(acro["sac"]["curves"]) == 2 and acro["sac"]["curves"][0][1]["env_steps"] == 20
    # Each point keeps the distance and the miss (the third panel), so a later --update can redraw it.
    assert acro["sac"]["curves"][0][1]["mean_final_distance"] == 4.0 and acro["sac"]["curves"][0][1]["mean_miss"] == 7.0
    # PPO's curves were not stored, so this run's figure is SAC's alone, under its own name.
    assert Path(acro["figure"]).name == "rl_curves_acrobot_sac.png" and Path(acro["figure"]).is_file()


def test_bench_replot_redraws_a_stored_result_without_training(tmp_path, monkeypatch, capsys) -> None:
    """``bench_rl_baselines --replot FILE``: each task's figure is redrawn from the stored per-seed curves into the
    path the file names, nothing trains; a task without stored curves is skipped by name; a bad file is refused."""
    bench, seen = _bench_with_fake_runs(monkeypatch)
    point = {"env_steps": 10, "wall_s": 1.0, "success_rate": 0.5, "mean_return": -3.0, "mean_miss": 0.4}
    figure = tmp_path / "curves.png"
    stored = {
        "acrobot": {"ppo": {"curves": [[point, {**point, "env_steps": 20}]] * 2}, "figure": str(figure)},
        "glider": {"ppo": {"algo": "PPO"}, "figure": str(tmp_path / "never.png")},
    }
    path = tmp_path / "rl.json"
    path.write_text(json.dumps(stored))
    assert bench.main(["--replot", str(path)]) == 0
    assert seen == [] and figure.is_file() and figure.stat().st_size > 10_000
    assert not (tmp_path / "never.png").exists()
    out, err = capsys.readouterr()
    assert json.loads(out.splitlines()[-1]) == {"replotted": {"acrobot": str(figure)}}
    assert "glider: no stored curves" in err
    path.write_text("{not json")
    with pytest.raises(SystemExit, match="not a readable result JSON"):
        bench.main(["--replot", str(path)])


def test_bench_set_overrides_a_setting_per_task_and_algorithm_and_refuses_bad_ones(tmp_path, monkeypatch) -> None:
    """``bench_rl_baselines --set acrobot:SAC:net_arch=64,64``: the seeds of that task and algorithm train with it
    (over the sweep's or the zoo's), the result records it, and unknown fields, fixed fields or bad values are
    refused by name."""
    bench, seen = _bench_with_fake_runs(monkeypatch)
    args = ["--quick", "--tasks", "acrobot", "--algos", "SAC", "--seeds", "1", "--workers", "1"]
    args += ["--out", str(tmp_path / "w"), "--set", "acrobot:SAC:net_arch=64,64"]
    args += ["--set", "acrobot:SAC:normalize_reward=true", "--set", "glider:SAC:gamma=0.9"]
    args += ["--update", str(tmp_path / "rl.json")]
    assert bench.main(args) == 0
    recorded = json.loads((tmp_path / "rl.json").read_text())["acrobot"]["sac"]["settings_set"]
    assert recorded == {"net_arch": [64, 64], "normalize_reward": True}
    (config,) = seen
    assert config.net_arch == (64, 64) and config.normalize_reward is True and config.gamma == 0.98
    assert config.resolved()["net_arch"] == [64, 64]
    assert bench._parse_set("glider:PPO:learning_rate=1e-3") == (("glider", "PPO"), "learning_rate", 1e-3)
    for bad, match in [
        ("acrobot:SAC:widths=64", "not a setting"),
        ("acrobot:SAC:seed=3", "not a setting"),
        ("acrobot:SAC:gamma=2", "bad value for gamma"),
        ("acrobot:SAC:normalize_reward=maybe", "bad value"),
        ("cartpole:SAC:gamma=0.9", "look like"),
        ("acrobot:SAC:gamma", "look like"),
    ]:
        with pytest.raises(Exception, match=match):
            bench._parse_set(bad)
    with pytest.raises(SystemExit):
        bench.main(["--quick", "--set", "acrobot:DQN:gamma=0.9"])
    assert json.loads(json.dumps(bench._parse_set('acrobot:SAC:algo_overrides={"tau": 0.01}')[2])) == {"tau": 0.01}
