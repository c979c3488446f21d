"""Closed-loop evaluation: grids, determinism across workers, tables and figures, SB3 models, the CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest

from seagul_control.evaluation import (
    PolicySpec,
    evaluate,
    is_success,
    start_grid,
    summarize,
    write_outputs,
)
from seagul_envs import make_task


def test_start_grids_follow_the_paper_figures():
    acro = make_task("acrobot")
    starts, grid = start_grid(acro, 3)
    assert starts.shape == (9, 4) and grid["dims"] == ["th1", "th2"]
    assert np.all(starts[:, 2:] == 0.0)  # zero velocity (Fig. 2)
    assert starts[:, 0].min() == pytest.approx(acro.x0_low[0]) and starts[:, 1].max() == pytest.approx(acro.x0_high[1])
    glider = make_task("glider")
    starts, grid = start_grid(glider, 2)
    assert grid["dims"] == ["x", "z"] and starts.shape == (4, 7)
    assert all(glider.in_x0(s) for s in starts)
    with pytest.raises(ValueError, match="grid size"):
        start_grid(acro, 0)


def test_success_definitions():
    acro, glider = make_task("acrobot"), make_task("glider")
    assert is_success(acro, acro.goal + 0.02)
    assert not is_success(acro, acro.goal + 0.03)  # norm 0.06
    perched = np.array([0.01, -0.02, 0.8, 0.0, 1.9, -1.5, 0.0])
    assert is_success(glider, perched)
    assert not is_success(glider, perched + np.array([0, 0, 0, 0, 0.2, 0, 0]))  # dx > 2
    assert not is_success(glider, perched, terminated=True)


def test_results_do_not_depend_on_the_number_of_workers(tmp_path):
    task = make_task("acrobot")
    starts, grid = start_grid(task, 2)
    specs = [PolicySpec("lqr", "lqr"), PolicySpec("mpc", "mpc", None, (("jit", False),))]
    one = evaluate("acrobot", specs, starts, workers=1, progress=False)
    two = evaluate("acrobot", specs, starts, workers=2, progress=False, chunk_size=1)
    assert [(r.policy, r.index) for r in one] == [(r.policy, r.index) for r in two]
    for a, b in zip(one, two, strict=True):
        np.testing.assert_allclose(a.final_state, b.final_state, rtol=1e-9, atol=1e-12)
    rows = summarize("acrobot", one)
    assert [r["policy"] for r in rows] == ["lqr", "mpc"]
    assert np.isnan(rows[0]["median_step_ms"]) and rows[1]["median_step_ms"] > 0
    paths = write_outputs(tmp_path, "acrobot", one, grid)
    for key in ("results", "summary_json", "summary_csv", "heatmap"):
        assert paths[key].is_file() and paths[key].stat().st_size > 0
    summary = json.loads(paths["summary_json"].read_text())
    assert summary["policies"][1]["episodes"] == 4
    assert paths["summary_csv"].read_text().splitlines()[0].startswith("policy,episodes,success_rate")


def test_glider_trajectory_figure(tmp_path):
    task = make_task("glider")
    starts, grid = start_grid(task, 1)
    results = evaluate("glider", [PolicySpec("lqr", "tvlqr")], starts, progress=False, record=True)
    assert len(results[0].states) == results[0].steps + 1 == 32 + 1
    paths = write_outputs(tmp_path, "glider", results, grid)
    assert paths["trajectories"].is_file()
    assert "perch_success_rate" in summarize("glider", results)[0]


def test_saved_sb3_model_with_vecnormalize_stats(tmp_path):
    import gymnasium as gym
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    import seagul_envs  # noqa: F401

    venv = VecNormalize(DummyVecEnv([lambda: gym.make("SeagulAcrobot-v0")]))
    model = PPO("MlpPolicy", venv, n_steps=64, batch_size=32, seed=0, device="cpu")
    model.save(tmp_path / "model.zip")
    venv.save(str(tmp_path / "vecnormalize.pkl"))
    task = make_task("acrobot")
    starts, _ = start_grid(task, 1)
    spec = PolicySpec("sb3", "ppo", str(tmp_path / "model.zip"))
    results = evaluate("acrobot", [spec], starts, progress=False)
    assert results[0].steps == 50 and np.isfinite(results[0].cost)
    from seagul_control.evaluation import build_policy

    assert build_policy("acrobot", spec).normalizer is not None


def test_policy_spec_errors():
    with pytest.raises(ValueError, match="unknown policy kind"):
        PolicySpec("dqn")
    with pytest.raises(ValueError, match="needs the path"):
        PolicySpec("sb3")
    with pytest.raises(FileNotFoundError, match="does not exist"):
        PolicySpec("mpc", path="/nonexistent/network.pt")
    with pytest.raises(ValueError, match="labels must be unique"):
        evaluate("acrobot", [PolicySpec("lqr"), PolicySpec("lqr")], np.zeros((1, 4)), progress=False)


def test_cli_evaluate(tmp_path, capsys):
    from seagul_learn.cli import main

    out = tmp_path / "eval"
    code = main(["evaluate", "--task", "acrobot", "--lqr", "--grid", "2", "--out", str(out), "--no-progress"])
    assert code == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[-1] == str(out) and lines[0].startswith("lqr: success")
    assert (out / "heatmap.png").is_file()
    assert main(["evaluate", "--task", "acrobot", "--out", str(out)]) == 2
    assert "no policy to evaluate" in capsys.readouterr().err
