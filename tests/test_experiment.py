"""`seagul reproduce`: the whole pipeline on the smoke preset, its report, and resume after SIGKILL; the named
methods (the shipped recipe included) it shares with the closed-loop benchmark."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from seagul_learn.cli import main
from seagul_learn.experiment import Experiment, ExperimentConfig


@pytest.fixture(scope="module")
def smoke_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """The smoke preset's run, made once per test session and copied for this module: the xdist workers share one
    build (under a file lock in the session's directory; a copied run resumes like the original, tested below), and
    the tests that change a run change their own copy. Returns the copy and the run's stdout as if made there."""
    import contextlib
    import io
    import shutil

    from filelock import FileLock

    shared = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        shared = shared.parent  # the session's directory, above each worker's own
    built = shared / "smoke-reproduce"
    with FileLock(str(shared / "smoke-reproduce.lock")):
        if not (built / "stdout.txt").is_file():
            shutil.rmtree(built, ignore_errors=True)
            stdout = io.StringIO()
            with contextlib.redirect_stdout(stdout):
                argv = ["reproduce", "acrobot", "--preset", "smoke", "--out", str(built / "run"), "--workers", "1"]
                code = main([*argv, "--no-progress", "--envs", "SeagulAcrobotMujoco-v0"])
            assert code == 0
            (built / "stdout.txt").write_text(stdout.getvalue())
    out = tmp_path_factory.mktemp("reproduce") / "run"
    shutil.copytree(built / "run", out)
    return out, (built / "stdout.txt").read_text().replace(str(built / "run"), str(out))


def test_reproduce_writes_report_with_figures_and_tables(smoke_run: tuple[Path, str]) -> None:
    out, stdout = smoke_run
    report = out / "report.md"
    assert stdout.strip().splitlines()[-1] == str(report)  # the last line is the report's path
    text = report.read_text()
    for heading in ("## Summary", "## Value-function learning", "## Closed loop", "## Timings", "## Library versions"):
        assert heading in text
    # The per-method table, the per-seed policy rows and the baselines.
    for policy in ("SEAGuL MPC", "uniform MPC", "closed-loop MPC", "LQR", "full-horizon MPC"):
        assert f"| {policy} |" in text
    for seed in (0, 1):
        for policy in ("SEAGuL MPC", "uniform MPC", "closed-loop MPC"):
            assert f"| {policy} (seed {seed}) |" in text
    figures = (
        "validation_curves.png",
        "success_vs_solves.png",
        "closed_loop/main/heatmap.png",
        "closed_loop/reference/heatmap.png",
    )
    for figure in figures:
        assert f"]({figure})" in text
        assert (out / figure).stat().st_size > 1000
    assert "data:image/png;base64," in (out / "report.html").read_text()
    learning = json.loads((out / "learning.json").read_text())
    for method in ("uniform", "adversarial", "closed-loop"):
        assert len(learning["mse_initial"][method]) == len(learning["mse_all_knots"][method]) == 2
    assert set(learning["mse_initial"]["vs_uniform"]) == {"adversarial", "closed-loop"}
    stored = json.loads((out / "experiment.json").read_text())
    assert {"validation set", "training", "closed-loop evaluation", "total"} <= set(stored["timings"])


def test_report_opens_with_the_shipped_controller(smoke_run: tuple[Path, str]) -> None:
    """The first part of the report is the shipped MPC beside LQR and the full-horizon MPC with its animation; the
    comparison of the samplers follows under a heading that says it is not the shipped recipe."""
    out, _ = smoke_run
    text = (out / "report.md").read_text()
    parts = [line for line in text.splitlines() if line.startswith("## ")]
    assert parts[0] == "## Shipped controller: acrobot in closed loop"
    assert parts[1].startswith("## Equal-budget comparison of the samplers (4 solves per network, 2 seeds)")
    assert parts[1].endswith("not the shipped recipe")
    shipped = text[text.index(parts[0]) : text.index(parts[1])]
    for row in ("| shipped MPC |", "| LQR |", "| full-horizon MPC |"):
        assert row in shipped
    assert "**The shipped MPC manages to reach the goal" in shipped and "with CasADi interpreted" in shipped
    assert "](shipped/shipped_vs_lqr.gif)" in shipped
    page = (out / "report.html").read_text()
    assert page.index("<h2>Shipped controller: acrobot in closed loop</h2>") < page.index("<h2>Equal-budget")
    assert page.index("data:image/gif;base64,") < page.index("<h2>Equal-budget")  # the GIF is embedded
    from PIL import Image

    with Image.open(out / "shipped" / "shipped_vs_lqr.gif") as gif:
        assert gif.format == "GIF" and gif.n_frames > 10
    result = json.loads((out / "shipped" / "shipped.json").read_text())
    assert [e["policy"] for e in result["animation"]["episodes"]] == ["shipped MPC", "LQR"]
    assert result["animation"]["start"] == pytest.approx([math.pi - 0.3, -0.3, 0.0, 0.0])


def test_experiment_json_has_the_shipped_block(smoke_run: tuple[Path, str]) -> None:
    from seagul_learn.shipped import SHIPPED_RESULTS

    out, _ = smoke_run
    block = json.loads((out / "experiment.json").read_text())["shipped"]
    declared = json.loads(SHIPPED_RESULTS.read_text())["acrobot"]
    assert block["network"] == declared["network"] and isinstance(block["network"], str)
    assert block["horizon"] == declared["horizon"] and type(block["horizon"]) is int
    for key in ("success_rate", "full_horizon_success_rate", "median_ms", "p95_ms"):
        assert type(block[key]) is float, key
    assert 0.0 <= block["success_rate"] <= 1.0 and 0.0 <= block["full_horizon_success_rate"] <= 1.0
    assert 0.0 < block["median_ms"] <= block["p95_ms"]
    assert block["jit"] is False and block["grid"] == "1x1" and block["starts"] == 1
    # The numbers are this run's: the shipped MPC's stored episodes, the full horizon's from the reference grid.
    ours = json.loads((out / "shipped" / "episodes" / "shipped-mpc.json").read_text())
    assert block["success_rate"] == sum(e["success"] for e in ours) / len(ours)
    full = json.loads((out / "closed_loop" / "episodes" / "full-horizon-mpc.json").read_text())
    assert block["full_horizon_success_rate"] == sum(e["success"] for e in full) / len(full)
    assert [e["start"] for e in ours] == [e["start"] for e in full]  # the same starts


def test_resume_reuses_the_shipped_evaluation(smoke_run: tuple[Path, str]) -> None:
    """A resumed run reads ``shipped/shipped.json``: no episode is run again, the GIF is not redrawn."""
    import shutil

    out, _ = smoke_run
    stored = (out / "shipped" / "shipped.json").read_text()
    gif = (out / "shipped" / "shipped_vs_lqr.gif").stat().st_mtime_ns
    block = json.loads((out / "experiment.json").read_text())["shipped"]
    episodes = out / "shipped" / "episodes"
    kept = out / "shipped_episodes_kept"
    shutil.copytree(episodes, kept)
    shutil.rmtree(episodes)
    try:
        assert main(["reproduce", "acrobot", "--resume", str(out), "--no-progress"]) == 0
        assert not episodes.exists()  # evaluating again would have stored them
        assert (out / "shipped" / "shipped.json").read_text() == stored
        assert (out / "shipped" / "shipped_vs_lqr.gif").stat().st_mtime_ns == gif
        assert json.loads((out / "experiment.json").read_text())["shipped"] == block
        assert (out / "report.md").read_text().startswith("# Learned value functions as MPC terminal costs")
    finally:
        shutil.rmtree(episodes, ignore_errors=True)
        shutil.move(kept, episodes)


def test_summary_has_per_seed_statistics_of_every_method(smoke_run: tuple[Path, str]) -> None:
    out, _ = smoke_run
    summary = json.loads((out / "closed_loop" / "summary.json").read_text())
    seeds, budgets = summary["seeds"], summary["budgets"]
    assert seeds == 2 and budgets == [2, 4]
    assert set(summary["methods"]) == {"uniform", "adversarial", "closed-loop"}
    for method, stats in summary["methods"].items():
        assert len(stats["success"]) == len(stats["reference_success"]) == seeds
        assert all(0.0 <= s <= 1.0 for s in stats["success"])
        assert stats["success_q25"] <= stats["success_median"] <= stats["success_q75"]
        assert stats["curve"]["budgets"] == budgets and len(stats["curve"]["median"]) == len(budgets)
        assert [row[-1] for row in stats["curve"]["per_seed"]] == stats["success"]
        errors = stats["query_error"]
        assert len(errors["per_seed"]) == seeds
        assert all(e["sampled"] >= 1 and e["available"] >= e["sampled"] for e in errors["per_seed"])
        # NaN only if every re-solve failed (no reference value to compare with)
        assert math.isfinite(errors["median"]) or all(e["failed"] == e["sampled"] for e in errors["per_seed"])
        assert not math.isfinite(errors["median"]) or errors["p95"] >= 0
        if method == "closed-loop":
            assert "vs_closed_loop" not in stats
        else:
            c = stats["vs_closed_loop"]
            assert c["seeds"] == seeds and c["wins"] + c["losses"] + c["ties"] == seeds
    assert {"LQR", "full-horizon MPC"} <= set(summary["baselines"])
    # Every snapshot network of every seed ran on the main grid; the per-budget networks exist.
    policies = {row["policy"] for row in summary["policies"]}
    for seed in range(seeds):
        assert f"closed-loop MPC (seed {seed}, 2 solves)" in policies
        assert (out / "train" / f"closed-loop-seed{seed}" / "network_2.pt").is_file()
    text = (out / "report.md").read_text()
    assert "query error" in text and "](success_vs_solves.png)" in text


def test_report_shows_the_controllers_in_both_simulators(smoke_run: tuple[Path, str]) -> None:
    """``--envs SeagulAcrobotMujoco-v0``: the final networks and LQR also run in the MuJoCo acrobot, from the same
    grid starts; the report has a column per simulator."""
    out, _ = smoke_run
    other = json.loads((out / "closed_loop" / "other_envs.json").read_text())
    assert other["envs"] == ["SeagulAcrobot-v0", "SeagulAcrobotMujoco-v0"]
    assert set(other["rows"]) == {"SEAGuL MPC", "uniform MPC", "closed-loop MPC", "LQR"}
    summary = json.loads((out / "closed_loop" / "summary.json").read_text())
    # The task's own column is the main evaluation's (LQR: one policy; the methods: the median over seeds).
    assert other["rows"]["LQR"]["SeagulAcrobot-v0"] == summary["baselines"]["LQR"]
    for row in other["rows"].values():
        assert 0.0 <= row["SeagulAcrobotMujoco-v0"] <= 1.0
    stored = list((out / "closed_loop" / "episodes_seagulacrobotmujoco-v0").glob("*.json"))
    assert len(stored) == 2 * 3 + 1  # every seed's final network of the three methods, and LQR
    episodes = json.loads((out / "closed_loop" / "episodes_seagulacrobotmujoco-v0" / "lqr.json").read_text())
    own = json.loads((out / "closed_loop" / "episodes" / "lqr.json").read_text())
    assert [e["start"] for e in episodes] == [e["start"] for e in own]  # the same starts
    text = (out / "report.md").read_text()
    assert "## Other simulators" in text and "| success in SeagulAcrobotMujoco-v0 |" in text


def test_other_envs_must_simulate_the_task() -> None:
    with pytest.raises(ValueError, match="not 'acrobot'"):
        ExperimentConfig(preset="smoke", envs=("SeagulGlider-v0",)).validate()
    with pytest.raises(ValueError, match="the task's own env"):
        ExperimentConfig(preset="smoke", envs=("SeagulAcrobot-v0",)).validate()
    with pytest.raises(ValueError, match="unknown env id 'Nope-v0'"):
        ExperimentConfig(preset="smoke", envs=("Nope-v0",)).validate()


def test_reproduce_refuses_to_overwrite_and_checks_resume_dir(smoke_run: tuple[Path, str], tmp_path: Path) -> None:
    out, _ = smoke_run
    with pytest.raises(FileExistsError, match="--resume"):
        Experiment.create(ExperimentConfig(task="acrobot", preset="smoke"), out)
    with pytest.raises(FileNotFoundError, match=r"no experiment\.json"):
        Experiment.resume(tmp_path)
    assert main(["reproduce", "glider", "--resume", str(out)]) == 2  # a run of another task


def test_final_networks_are_scored_on_held_out_starts_too(smoke_run: tuple[Path, str]) -> None:
    """Every final network also runs from the preset's held-out starts (the benchmark's fixed-seed draws): per-seed
    ``heldout_success`` and its median ``heldout_success_rate`` beside the grid success, a column of the report."""
    out, _ = smoke_run
    summary = json.loads((out / "closed_loop" / "summary.json").read_text())
    assert summary["heldout_starts"] == 2  # the smoke preset's
    for method, stats in summary["methods"].items():
        assert len(stats["heldout_success"]) == summary["seeds"]
        assert all(s in (0.0, 0.5, 1.0) for s in stats["heldout_success"]), method  # 2 starts each
        assert stats["heldout_success_rate"] == pytest.approx(float(np.median(stats["heldout_success"])))
    from seagul_control.evaluation import heldout_starts

    stored = json.loads((out / "closed_loop" / "episodes_heldout" / "seagul-mpc--seed-1-.json").read_text())
    assert np.allclose([row["start"] for row in stored], heldout_starts("acrobot", 2))
    assert "held-out success median" in (out / "report.md").read_text()


def test_a_run_stored_without_held_out_episodes_resumes_with_only_those(smoke_run: tuple[Path, str]) -> None:
    """A resumed run reuses every stored episode table and evaluates only what is missing: here the held-out
    episodes of one network (as in a run stored before they existed), to the same summary."""
    out, _ = smoke_run
    held = out / "closed_loop" / "episodes_heldout" / "uniform-mpc--seed-0-.json"
    grid = out / "closed_loop" / "episodes" / "uniform-mpc--seed-0-.json"
    before = (out / "closed_loop" / "summary.json").read_text(), held.read_text(), grid.stat().st_mtime_ns
    held.unlink()
    assert main(["reproduce", "acrobot", "--resume", str(out), "--no-progress"]) == 0
    assert grid.stat().st_mtime_ns == before[2]  # the grid episodes were reused
    again = [(e["start"], e["success"], e["steps"]) for e in json.loads(held.read_text())]
    assert again == [(e["start"], e["success"], e["steps"]) for e in json.loads(before[1])]  # times aside
    assert (out / "closed_loop" / "summary.json").read_text() == before[0]


def test_evaluate_snapshot_runs_grid_and_held_out_starts() -> None:
    from seagul_control.evaluation import PolicySpec, heldout_starts, start_grid
    from seagul_envs import make_task
    from seagul_learn.experiment import evaluate_snapshot, success_fields

    task = make_task("acrobot")
    starts, _ = start_grid(task, 2)
    grid, held = evaluate_snapshot(task, PolicySpec("lqr", "LQR"), starts, 3)
    assert len(grid) == len(starts) and len(held) == 3
    assert np.allclose([e.start for e in grid], starts) and np.allclose(
        [e.start for e in held], heldout_starts(task, 3)
    )
    row = success_fields(grid, held)
    assert row["grid_success"] == [e.success for e in grid]
    assert row["heldout_success_rate"] == pytest.approx(np.mean([e.success for e in held]))
    assert math.isnan(success_fields(grid, [])["heldout_success_rate"])


def test_resume_of_finished_run_changes_nothing(smoke_run: tuple[Path, str]) -> None:
    out, _ = smoke_run
    before = (out / "learning.json").read_text(), (out / "closed_loop" / "summary.json").read_text()
    assert main(["reproduce", "acrobot", "--resume", str(out), "--no-progress"]) == 0
    after = (out / "learning.json").read_text(), (out / "closed_loop" / "summary.json").read_text()
    assert before == after


def test_finished_run_without_a_snapshot_is_retrained_to_the_same_weights(smoke_run: tuple[Path, str]) -> None:
    # SIGKILL between a round's checkpoint and its snapshot leaves a run that resumes past the snapshot.
    out, _ = smoke_run
    import torch

    snapshot = out / "train" / "uniform-seed1" / "network_2.pt"
    before = torch.load(snapshot, weights_only=True)["state_dict"]
    learning = (out / "learning.json").read_text()
    snapshot.unlink()
    assert main(["reproduce", "acrobot", "--resume", str(out), "--no-progress"]) == 0
    after = torch.load(snapshot, weights_only=True)["state_dict"]
    assert before.keys() == after.keys() and all(torch.equal(before[k], after[k]) for k in before)
    assert (out / "learning.json").read_text() == learning


def _strip_times(summary: dict) -> dict:
    for row in summary["policies"]:
        for key in ("median_step_ms", "p95_step_ms", "max_step_ms"):
            row.pop(key, None)
    return summary


@pytest.mark.slow
def test_sigkill_then_resume_gives_the_uninterrupted_results(smoke_run: tuple[Path, str], tmp_path: Path) -> None:
    """The whole ``seagul reproduce`` killed by SIGKILL once a training run has checkpointed, then resumed: the same
    learning curves and closed-loop summary as the uninterrupted run. A second full smoke experiment (~90 s), so it
    runs with ``-m slow``; the default suite checks the same contract by its parts: training killed at any moment and
    resumed (``tests/test_training.py``), killed mid-round (``tests/test_interrupt.py``), and the experiment resuming
    a run stored without its held-out episodes or its snapshot (the two tests above)."""
    reference, _ = smoke_run
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "seagul_learn.cli", "reproduce", "acrobot", "--preset", "smoke", "--workers", "1"]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen([*cmd, "--out", str(out), "--no-progress"], env=env, stdout=subprocess.DEVNULL)
    # Kill in the middle of training: once the first run has checkpointed but before everything is done.
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline and proc.poll() is None:
        if any((out / "train").glob("*/checkpoint.pt")):
            break
        time.sleep(0.05)
    assert proc.poll() is None, "the run finished before it could be interrupted"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not (out / "report.md").exists()
    done = subprocess.run([*cmd, "--resume", str(out), "--no-progress"], env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == str(out / "report.md")
    assert json.loads((out / "learning.json").read_text()) == json.loads((reference / "learning.json").read_text())
    killed = _strip_times(json.loads((out / "closed_loop" / "summary.json").read_text()))
    uninterrupted = _strip_times(json.loads((reference / "closed_loop" / "summary.json").read_text()))
    assert killed == uninterrupted


# ------------------------------------------------------------------------------------ SB3 baselines (no training)
def _tiny_sb3_model(path: Path, algo: str) -> str:
    """An untrained SB3 model of the acrobot env saved at ``path`` (seconds: ``learn`` is never called)."""
    import gymnasium as gym
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.vec_env import DummyVecEnv

    import seagul_envs  # noqa: F401  (registers the envs)

    venv = DummyVecEnv([lambda: gym.make("SeagulAcrobot-v0")])
    if algo == "PPO":
        model: Any = PPO("MlpPolicy", venv, n_steps=64, batch_size=32, seed=0, device="cpu")
    else:
        model = SAC("MlpPolicy", venv, buffer_size=100, seed=0, device="cpu")
    path.parent.mkdir(parents=True, exist_ok=True)
    model.save(path)
    return str(path)


@pytest.fixture(scope="module")
def sb3_models(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    root = tmp_path_factory.mktemp("sb3")
    return {
        "ppo": _tiny_sb3_model(root / "ppo_acrobot" / "model.zip", "PPO"),
        "sac_a": _tiny_sb3_model(root / "sac_a" / "model.zip", "SAC"),
        "sac_b": _tiny_sb3_model(root / "sac_b" / "model.zip", "SAC"),
    }


def test_sb3_models_are_baselines_next_to_lqr(sb3_models: dict[str, str], tmp_path: Path) -> None:
    from seagul_control.evaluation import PolicySpec, build_policy

    config = ExperimentConfig(
        preset="smoke",
        ppo_model=sb3_models["ppo"],
        sb3_models=(sb3_models["sac_a"], sb3_models["sac_b"]),
        sb3_algo="SAC",
    )
    config.validate()
    main_specs, reference_specs = Experiment(config, tmp_path).baseline_specs()
    assert main_specs == [
        PolicySpec("lqr", "LQR"),
        PolicySpec("sb3", "PPO", sb3_models["ppo"], (("algo", "PPO"),)),
        PolicySpec("sb3", "SAC[sac_a]", sb3_models["sac_a"], (("algo", "SAC"),)),
        PolicySpec("sb3", "SAC[sac_b]", sb3_models["sac_b"], (("algo", "SAC"),)),
    ]
    assert reference_specs == [PolicySpec("full", "full-horizon MPC")]
    from stable_baselines3 import PPO, SAC

    assert isinstance(build_policy("acrobot", main_specs[2]).model, SAC)  # the algo option reaches SB3Policy
    assert isinstance(build_policy("acrobot", main_specs[1]).model, PPO)
    # Without sb3 models LQR is the only main-grid baseline (its stored episodes keep their name).
    assert Experiment(ExperimentConfig(preset="smoke"), tmp_path).baseline_specs()[0] == [PolicySpec("lqr", "LQR")]


def test_sb3_labels_stay_unique_when_parent_directories_share_a_name() -> None:
    config = ExperimentConfig(sb3_models=("a/sac/best.zip", "b/sac/final.zip", "c/ppo/model.zip"), sb3_algo="SAC")
    assert [label for label, _, _ in config.sb3_policies()] == ["SAC[sac/best]", "SAC[sac/final]", "SAC[ppo]"]
    config = ExperimentConfig(sb3_models=("a/sac/model.zip", "b/sac/model.zip", "model.zip"))
    assert [label for label, _, _ in config.sb3_policies()] == ["PPO[sac/model #1]", "PPO[sac/model #2]", "PPO[model]"]
    assert [algo for _, _, algo in config.sb3_policies()] == ["PPO"] * 3


def test_sb3_config_errors_name_the_bad_value(sb3_models: dict[str, str], tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"unknown sb3_algo 'A2C'; choose one of \['PPO', 'SAC'\]"):
        ExperimentConfig(preset="smoke", sb3_models=(sb3_models["sac_a"],), sb3_algo="A2C").validate()
    missing = str(tmp_path / "nowhere" / "model.zip")
    with pytest.raises(FileNotFoundError, match=f"SB3 model '{missing}' does not exist"):
        ExperimentConfig(preset="smoke", sb3_models=(sb3_models["sac_a"], missing), sb3_algo="SAC").validate()
    with pytest.raises(ValueError, match="given twice"):
        ExperimentConfig(preset="smoke", sb3_models=(sb3_models["sac_a"],) * 2).validate()
    with pytest.raises(FileNotFoundError):
        Experiment.create(ExperimentConfig(preset="smoke", sb3_models=(missing,)), tmp_path / "run")
    assert not (tmp_path / "run").exists()  # refused before the run directory is made


def test_old_experiment_file_with_ppo_model_resumes(sb3_models: dict[str, str], tmp_path: Path) -> None:
    """An ``experiment.json`` without ``sb3_models``/``sb3_algo`` loads with their defaults."""
    from seagul_control.evaluation import PolicySpec

    old = {"task": "acrobot", "preset": "smoke", "seeds": None, "workers": 1, "backend": "local",
           "ppo_model": sb3_models["ppo"], "progress": False}  # fmt: skip
    (tmp_path / "experiment.json").write_text(json.dumps({"config": old, "timings": {}}))
    experiment = Experiment.resume(tmp_path, workers=1, progress=False)
    assert experiment.config == ExperimentConfig(**old)
    assert experiment.config.sb3_models == () and experiment.config.sb3_algo == "PPO"
    assert experiment.baseline_specs()[0][1] == PolicySpec("sb3", "PPO", sb3_models["ppo"], (("algo", "PPO"),))
    # A new run's stored config (a JSON list of models) round-trips to the same config.
    config = ExperimentConfig(preset="smoke", sb3_models=(sb3_models["sac_a"],), sb3_algo="SAC")
    assert ExperimentConfig(**json.loads(json.dumps(config.to_dict()))) == config


# --------------------------------------------------------------------------------------- methods and recipes
def test_methods_shipped_trains_the_tasks_recipe_on_its_schedule(tmp_path: Path) -> None:
    """``--methods shipped,uniform``: the shipped recipe at its own budget, the uniform sampler on the same schedule
    with the recipe's network and label settings, deployed as the benchmark deploys the recipe, paired tests
    against the shipped method."""
    from seagul_envs import make_task
    from seagul_learn.experiment import SHIPPED_METHOD, reference_method, versus_key
    from seagul_learn.experiment.methods import SHARED_RECIPE_FIELDS, flat_settings, shipped_recipe

    config = ExperimentConfig(task="acrobot", preset="smoke", methods=("shipped", "uniform"))
    config.validate()
    preset = config.resolve()
    recipe = flat_settings(shipped_recipe("acrobot"))
    assert preset.methods == (SHIPPED_METHOD, "uniform") and preset.budgets == (recipe["budget"],) == (1000,)
    assert (preset.budget, preset.solves_per_round, preset.train_steps_per_round) == (1000, 50, 1000)
    experiment = Experiment(config, tmp_path)
    shipped = flat_settings(experiment.train_config("shipped", 1))
    expected = flat_settings(shipped_recipe("acrobot", seed=1, snapshots=(1000,), progress=False))
    assert {k: v for k, v in shipped.items() if k != "task"} == {k: v for k, v in expected.items() if k != "task"}
    uniform = flat_settings(experiment.train_config("uniform", 1))
    assert uniform["sampler"] == "uniform" and uniform["seed"] == 1
    for name in (*SHARED_RECIPE_FIELDS, "budget", "solves_per_round", "train_steps_per_round"):
        assert uniform[name] == recipe[name], name
    assert list(uniform["snapshots"]) == [1000]
    task = make_task("acrobot")
    options = dict(experiment.deployment())
    assert options["trust_region"] == task.profile.mpc.trust_region
    assert options["horizon"] == task.profile.default_horizon(task) and "solver" not in options
    assert reference_method(preset.methods) == "shipped" and versus_key("shipped") == "vs_shipped"
    # The paper's presets keep their schedule and the experiment's own deployment.
    paper = Experiment(ExperimentConfig(task="acrobot", preset="smoke"), tmp_path / "smoke")
    assert dict(paper.deployment()) == {"horizon": 3, "solver": "ipopt", "trust_region": "lqr"}


def test_the_shipped_method_trains_what_the_benchmark_ships(tmp_path: Path) -> None:
    """One table of methods: ``seagul reproduce --methods shipped`` and the closed-loop benchmark's shipped method
    (``seagul_learn.experiment.benchmark``, behind ``benchmarks/bench_closed_loop.py``) train the same settings."""
    from seagul_learn.experiment import METHODS, benchmark
    from seagul_learn.experiment.methods import SHIPPED, flat_settings, train_config

    assert benchmark.METHODS is METHODS
    bench = benchmark.BenchConfig.for_task("acrobot", quick=False)
    budget = max(bench.budgets)
    shipped = {**benchmark.method_config(bench, SHIPPED), "budget": budget, "seed": 2, "snapshots": (budget,)}
    ours = Experiment(ExperimentConfig(task="acrobot", preset="smoke", methods=("shipped", "uniform")), tmp_path)
    ours_settings = flat_settings(ours.train_config("shipped", 2))
    theirs = flat_settings(train_config(**shipped, progress=False))
    assert {k: v for k, v in ours_settings.items() if k != "task"} == {k: v for k, v in theirs.items() if k != "task"}


def test_methods_override_the_presets_and_are_checked() -> None:
    quick = ExperimentConfig(task="acrobot", preset="quick", methods=("uniform", "closed-loop")).resolve()
    assert quick.methods == ("uniform", "closed-loop") and quick.budget == 60  # the preset's schedule
    assert quick.train_overrides and all(k.startswith("closed-loop:") for k, _ in quick.train_overrides)
    plain = ExperimentConfig(task="acrobot", preset="quick", methods=("uniform", "adversarial")).resolve()
    assert plain.train_overrides == ()  # the closed-loop method's overrides went with it
    with pytest.raises(ValueError, match="'uniform' baseline"):
        ExperimentConfig(preset="smoke", methods=("shipped",)).validate()
    with pytest.raises(ValueError, match="distinct names"):
        ExperimentConfig(preset="smoke", methods=("uniform", "nope")).validate()
    with pytest.raises(SystemExit):
        main(["reproduce", "acrobot", "--methods", "uniform,nope"])
    assert ExperimentConfig(methods="shipped,uniform").methods == ("shipped", "uniform")  # as stored or typed


_TINY_BOOK = """
recipes:
  default:
    budget: 4
    sampler: {name: closed-loop, episodes: 1, jit: false, uniform_solves: 2, tail_stride: 5}
    schedule: {solves_per_round: 2, train_steps_per_round: 20}
    loss: {sobolev_weight: 1.0, value_cap: 50.0}
  shipped:
    extends: default
    runtime: {snapshots: [4], progress: false}
presets:
  smoke:
    seeds: 2
    budget: 4
    solves_per_round: 2
    train_steps_per_round: 20
    grid_points: 2
    reference_grid_points: 1
    budgets: [2, 4]
    query_samples: 2
    query_tail_stride: 10
"""


@pytest.mark.slow  # a second whole smoke run (~30 s); the recipe book's configs are checked in test_layers.py
def test_reproduce_runs_the_shipped_recipe_through_the_same_pipeline(tmp_path: Path, monkeypatch) -> None:
    """``seagul reproduce acrobot --methods shipped,uniform`` with a recipe file of 4-solve recipes (registered for
    the acrobot): the shipped recipe trains, is evaluated and compared beside the uniform sampler on its schedule."""
    from seagul_learn import recipes

    book = tmp_path / "acrobot.yml"
    book.write_text(_TINY_BOOK)
    monkeypatch.setattr(recipes, "_REGISTERED", {})
    recipes.register("acrobot", book)
    out = tmp_path / "run"
    argv = ["reproduce", "acrobot", "--preset", "smoke", "--methods", "shipped,uniform", "--out", str(out)]
    assert main([*argv, "--workers", "1", "--no-progress"]) == 0
    stored = json.loads((out / "train" / "shipped-seed1" / "config.json").read_text())
    assert stored["budget"] == 4 and stored["sampler"]["name"] == "closed-loop" and stored["seed"] == 1
    uniform = json.loads((out / "train" / "uniform-seed1" / "config.json").read_text())
    assert uniform["sampler"]["name"] == "uniform" and uniform["schedule"] == stored["schedule"]
    summary = json.loads((out / "closed_loop" / "summary.json").read_text())
    assert set(summary["methods"]) == {"shipped", "uniform"} and summary["reference_method"] == "shipped"
    assert summary["budgets"] == [4] and summary["methods"]["uniform"]["vs_shipped"]["seeds"] == 2
    text = (out / "report.md").read_text()
    assert "comparison with the shipped recipe (4 solves per network, 2 seeds)" in text
    assert "| shipped-recipe MPC |" in text and "Paired tests against the shipped-recipe method" in text


# --------------------------------------------------------------- the closed-loop benchmark's pipeline (library)
@pytest.mark.parametrize("task_name", ["acrobot", "glider"])
def test_the_tasks_recipe_is_what_the_benchmark_ships(task_name: str) -> None:
    """``TrainConfig.recipe(task)`` (``seagul train``'s default) trains exactly what the closed-loop benchmark
    measured and ships for the task (its full run: the largest budget, the shipped method's settings)."""
    from seagul_learn.experiment.benchmark import SHIPPED, BenchConfig, method_config
    from seagul_learn.experiment.methods import train_config
    from seagul_learn.training import TrainConfig

    bench = BenchConfig.for_task(task_name, quick=False)
    shipped = train_config(**method_config(bench, SHIPPED), budget=max(bench.budgets))
    assert TrainConfig.recipe(task_name) == shipped
    assert TrainConfig.recipe(task_name) != TrainConfig(task=task_name)  # not the paper's defaults


def test_the_shipped_recipe_is_the_2000_solve_one_with_its_budget_split_halved() -> None:
    """The shipped ``closed-loop+rest-1000`` differs from the 2,000-solve ``closed-loop+rest`` it scales down only in
    how its 1,000 solves split: the same fractions of uniform draws, guarded and deployed-collector rounds."""
    from seagul_learn.experiment.benchmark import SHIPPED, BenchConfig, method_config
    from seagul_learn.experiment.methods import flat_settings, train_config

    bench = BenchConfig.for_task("acrobot", quick=False)
    assert SHIPPED == "closed-loop+rest-1000" and max(bench.budgets) == 1000
    shipped = flat_settings(train_config(**method_config(bench, "closed-loop+rest"), budget=2000))
    scaled = flat_settings(train_config(**method_config(bench, SHIPPED), budget=1000))

    def split(c: dict) -> tuple[float, float]:
        rounds = (c["budget"] - c["cl_uniform_solves"]) / c["solves_per_round"]
        return c["cl_uniform_solves"] / c["budget"], c["cl_warmup_rounds"] / rounds

    assert split(scaled) == split(shipped) == (0.5, 0.5)
    assert {k for k in shipped if shipped[k] != scaled[k]} == {"budget", "cl_uniform_solves", "cl_warmup_rounds"}


def test_the_glider_block_carries_the_contract_fields() -> None:
    """The benchmark's glider settings come from the task (horizon, grid), and its block names the perch rate as the
    contract (``benchmarks/results/closed_loop.json``) spells it."""
    from seagul_learn.experiment.benchmark import SHIPPED, BenchConfig, method_config, shipped_block

    glider = BenchConfig.for_task("glider", quick=False)
    assert (glider.horizon, glider.grid, glider.goal_blend) == (10, 6, 0.0)
    assert glider.train["value_cap"] == 1500.0 and glider.train["refit_steps"] == 0
    recipe = method_config(glider, SHIPPED)  # what the shipped method trains with and train_settings shows
    assert (recipe["cl_warmup_rounds"], recipe["cl_collect_refit"], recipe["refit_ensemble"]) == (0, False, 1)
    assert recipe["cl_keep_best"] is True and recipe["value_cap"] == 1500.0 and recipe["task"] == "glider"
    rows = [
        {"seed": s, "success_rate": r, "heldout_success_rate": r, "query_error": {"median": 1.0, "p95": 2.0}}
        for s, r in enumerate([0.5, 0.9, 0.7])
    ]
    full = {"success_rate": 1.0, "heldout_success_rate": float("nan")}
    timing = {"median_ms": 5.0, "p95_ms": 30.0, "steps": 10, "success_rate": 0.7}
    block = shipped_block(glider, rows, full, Path("net.pt"), timing, 2000)
    assert block["perch_success_rate"] == block["success_rate"] == 0.7 and block["method"] == "closed-loop+sobolev"
    assert block["full_horizon_perch_success_rate"] == 1.0 and block["seeds"] == 3 and block["horizon"] == 10
    acrobot = BenchConfig.for_task("acrobot", quick=False)
    assert "perch_success_rate" not in shipped_block(acrobot, rows, full, Path("net.pt"), timing, 2000)


def test_the_benchmark_aggregates_several_budgets_with_grid_only_rows_and_draws_the_curve(tmp_path: Path) -> None:
    """``--aggregate`` over budgets: per-budget folders, a budget may lack seeds or held-out rates; the contract's
    fields are the shipped budget's; other methods are paired with the shipped one seed by seed; the figure."""
    from seagul_learn.experiment.benchmark import SHIPPED, BenchConfig, aggregate_task, parse_compare

    glider = BenchConfig.for_task("glider", quick=False)
    glider.budgets = (2000, 3000)
    glider.seed_list = (0, 1)
    (tmp_path / "b2000").mkdir()
    (tmp_path / "b3000").mkdir()
    grid_only = {"success_rate": 0.5, "fallback_steps": 3}
    (tmp_path / "b2000" / "seed0.json").write_text(json.dumps(grid_only))
    (tmp_path / "b2000" / "seed1.json").write_text(json.dumps({**grid_only, "success_rate": 0.7}))
    full_row = {"success_rate": 0.9, "heldout_success_rate": 0.8, "fallback_steps": 1, "solve_time_s": 600.0}
    full_row["query_error"] = {"median": 5.0, "p95": 50.0, "mean_signed": -1.0}
    (tmp_path / "b3000" / "seed0.json").write_text(json.dumps(full_row))  # seed 1 not evaluated at 3000
    (tmp_path / "full-horizon.json").write_text(json.dumps({"success_rate": 1.0, "heldout_success_rate": None}))
    timing = {"median_ms": 5.0, "p95_ms": 9.0, "steps": 3, "success_rate": 1.0}
    figure = tmp_path / "curve.png"
    other = tmp_path / "other" / "b2000"
    other.mkdir(parents=True)
    for seed, rate in ((0, 0.25), (1, 0.5)):
        (other / f"seed{seed}.json").write_text(json.dumps({**grid_only, "success_rate": rate}))
    flat = tmp_path / "flat"  # one budget's seed<N>.json directly in the folder: the budget comes with it
    flat.mkdir()
    (flat / "seed1.json").write_text(json.dumps({**grid_only, "success_rate": 0.1}))
    label, spec = parse_compare(f"closed-loop+rest-2000={flat}@2000")
    assert (label, spec) == ("closed-loop+rest-2000", (flat, 2000))
    assert parse_compare("x=a/b")[1] == (Path("a/b"), None)
    for bad in ("no-label", "=dir", "x=dir@many"):
        with pytest.raises(ValueError, match="LABEL=DIR"):
            parse_compare(bad)
    compare = {"last": (tmp_path / "other", None), label: spec}
    block = aggregate_task(glider, tmp_path, Path("net.pt"), 3000, figure, compare, timing=timing)
    assert list(block["methods"][label]["budgets"]) == ["2000"]  # not the shipped budget, 3000
    assert block["methods"][label]["budgets"]["2000"]["success_median"] == 0.1
    versus = block["methods"]["last"]["budgets"]["2000"]
    assert versus["success_median"] == 0.375 and versus["vs_shipped"]["wins"] == 2  # the shipped method, seed by seed
    assert versus["vs_shipped"]["median_difference"] == pytest.approx(0.225)
    assert set(versus["vs_shipped"]) == {"median_difference", "wins", "losses", "p"}  # the committed keys
    assert block["budget"] == 3000 and block["perch_success_rate"] == 0.9 and block["heldout_success_rate"] == 0.8
    assert block["method"] == "closed-loop+sobolev" and SHIPPED not in block["methods"]  # the glider's name
    rows = block["methods"]["closed-loop+sobolev"]["budgets"]
    assert rows["2000"]["success_median"] == 0.6 and rows["2000"]["seeds"] == [0, 1]
    assert math.isnan(rows["2000"]["heldout_median"]) and rows["3000"]["seeds"] == [0]
    assert block["train_settings"]["value_cap"] == 1500.0 and figure.stat().st_size > 0
    assert "network" not in versus  # no row names its network


def test_a_method_whose_rows_name_their_networks_gets_the_median_seeds() -> None:
    """The summary names the representative network of a method (the seed closest to the median; ties: the lower
    seed) when its rows name their networks."""
    from seagul_learn.experiment.benchmark import BenchConfig, summarize

    bench = BenchConfig.for_task("acrobot", quick=False)
    rows = [
        {"seed": s, "success_rate": r, "heldout_success_rate": h, "network": f"net{s}.pt"}
        for s, r, h in ((0, 0.1, 0.2), (1, 0.3, 0.1), (2, 0.2, 0.3), (3, 0.25, 0.3))
    ]
    summary = summarize(bench, {"uniform": {2000: rows}}, {"success_rate": 1.0})
    at = summary["uniform"]["budgets"]["2000"]
    assert at["success_median"] == pytest.approx(0.225) and at["network_seed"] == 2 and at["network"] == "net2.pt"
    assert summary["uniform"]["smallest_budget_98pct_of_full_horizon"] is None
