"""The ``seagul`` CLI: argument errors name the argument; train/generate run end to end (toy solver injected)."""

from __future__ import annotations

import json
import re
import subprocess
import sys

import numpy as np
import pytest
from toy_problem import ToySolver

import seagul_learn.solving
import seagul_learn.training
from seagul_envs import resolve_task
from seagul_learn.cli import Command, discover_commands, main
from seagul_learn.dataset import Dataset
from seagul_learn.value_network import ValueNetwork


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (
            ["train", "--task", "pendulum", "--out", "x"],
            "argument --task: unknown task 'pendulum'; available tasks: "
            "acrobot, dmc_acrobot, dmc_cartpole, dmc_pendulum, glider",
        ),
        (["train", "--task", "acrobot", "--budget", "0", "--out", "x"], "budget must be >= 1, got 0"),
        (["train", "--task", "acrobot", "--budget", "ten", "--out", "x"], "--budget"),
        (["train", "--task", "acrobot", "--runtime.workers", "0", "--out", "x"], "runtime.workers must be >= 1"),
        (["train", "--task", "acrobot", "--workers", "0", "--out", "x"], "runtime.workers must be >= 1"),
        (["train", "--task", "acrobot", "sampler:greedy", "--out", "x"], "sampler:greedy"),
        (["train", "--task", "acrobot", "--runtime.backend", "dask", "--out", "x"], "--runtime.backend"),
        (["train", "--task", "acrobot", "--sobolev", "-1", "--out", "x"], "loss.sobolev_weight must be >= 0"),
        (["train", "--task", "acrobot", "--network.hidden", "3", "a", "--out", "x"], "--network.hidden"),
        (["train", "--task", "acrobot"], "the following arguments are required: --out"),
        (["train", "--out", "x"], "the following arguments are required: --task (or --config)"),
        (["train", "--task", "acrobot", "--out", "x", "--solver-options", "[1]"], "expected a JSON object"),
        (["generate", "--task", "acrobot"], "one of the arguments --num --validation is required"),
        (["generate", "--task", "glider", "--num", "-3"], "argument --num: must be >= 1, got -3"),
        (["frobnicate"], "invalid choice: 'frobnicate'"),
    ],
)
def test_bad_arguments_are_named(argv, message, capsys):
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    err = " ".join(re.sub(r"[│╭╮╰╯─]", " ", capsys.readouterr().err).split())  # tyro's boxes, wrapped
    assert message in err, err


def test_generate_num_requires_out(capsys):
    assert main(["generate", "--task", "acrobot", "--num", "3"]) == 2
    assert "--out is required with --num" in capsys.readouterr().err


def test_version_is_the_installed_package_version(capsys):
    """``seagul --version`` prints the version pip installed (pyproject's), the one CHANGELOG.md's newest entry has."""
    import tomllib
    from pathlib import Path

    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    declared = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())["project"]["version"]
    assert capsys.readouterr().out.strip() == f"seagul {declared}"


def test_commands_are_discovered_from_the_commands_package():
    names = [c.name for c in discover_commands()]
    assert {"generate", "train"} <= set(names) and names == sorted(names)
    assert all(isinstance(c, Command) for c in discover_commands())


def test_console_script_entry_point_runs():
    out = subprocess.run(
        [sys.executable, "-m", "seagul_learn.cli", "--help"], capture_output=True, text=True, check=True
    ).stdout
    assert "train" in out and "generate" in out


@pytest.fixture
def toy_solver(monkeypatch):
    """Replace the trajectory optimizer by the toy for the CLI (the plumbing is what is tested here)."""
    toys: dict[str, ToySolver] = {}

    def fake(task, **kwargs):  # the commands pass the Task object (resolved once), or a name
        task = resolve_task(task)
        toys.setdefault(task.name, ToySolver(task))
        return toys[task.name]

    monkeypatch.setattr(seagul_learn.training, "trajopt_batch_solver", fake)
    monkeypatch.setattr(seagul_learn.solving, "trajopt_batch_solver", fake)
    return toys


def test_train_end_to_end_and_resume_errors(tmp_path, toy_solver, capsys):
    argv = ["train", "--task", "acrobot", "--sampler", "adversarial", "--budget", "6", "--seed", "3",
            "--out", str(tmp_path / "run"), "--solves-per-round", "3", "--train-steps-per-round", "5",
            "--pretrain-solves", "3", "--pretrain-steps", "5", "--cache-dir", str(tmp_path / "cache"),
            "--no-progress", "--sobolev", "0.5", "--recipe", "paper"]  # fmt: skip
    assert main(argv) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[-1] == str(tmp_path / "run") and "6 solves" in lines[-2]
    assert ValueNetwork.load(tmp_path / "run" / "network.pt").task_name == "acrobot"
    config = json.loads((tmp_path / "run" / "config.json").read_text())
    assert config["loss"]["sobolev_weight"] == 0.5 and config["seed"] == 3 and config["budget"] == 6
    assert config["sampler"]["name"] == "adversarial" and config["schedule"]["solves_per_round"] == 3
    assert main(argv) == 2
    assert "already holds a run" in capsys.readouterr().err
    assert main([*argv, "--resume"]) == 0


def test_generate_uniform_and_validation(tmp_path, toy_solver, capsys):
    out = tmp_path / "data"
    argv = ["generate", "--task", "glider", "--num", "5", "--out", str(out), "--no-progress", "--workers", "2"]
    assert main(argv) == 0
    records = Dataset.open(out).records()
    assert len(records) == 5 and all(r.tau == 0.8 for r in records)
    assert main(argv) == 2 and "pass --resume" in capsys.readouterr().err
    assert main([*argv, "--resume"]) == 0 and "5 reused" in capsys.readouterr().out
    cache = tmp_path / "cache"
    assert main(["generate", "--task", "acrobot", "--validation", "--cache-dir", str(cache), "--no-progress"]) == 0
    assert "200 solves" in capsys.readouterr().out
    starts = np.array([r.x_init for r in Dataset.open(next(cache.iterdir())).records()])
    assert starts.shape == (200, 4)


# ------------------------------------------------------------------------------------------------ reproduce --sb3
@pytest.mark.parametrize(
    ("argv", "models", "algo", "ppo"),
    [
        (["--sb3", "x/model.zip", "--sb3-algo", "SAC"], ("x/model.zip",), "SAC", None),
        (["--sb3", "a.zip", "--sb3", "b,c.zip"], ("a.zip", "b,c.zip"), "PPO", None),  # repeatable, one path each
        (["--sb3-models", "a.zip,b.zip", "--sb3", "c.zip"], ("a.zip", "b.zip", "c.zip"), "PPO", None),
        (["--sb3", "c.zip", "--sb3-models", "a.zip,b.zip"], ("c.zip", "a.zip", "b.zip"), "PPO", None),
        (["--ppo", "p.zip", "--sb3", "s.zip", "--sb3-algo", "SAC"], ("s.zip",), "SAC", "p.zip"),
        ([], (), "PPO", None),
    ],
)
def test_reproduce_sb3_options_give_the_config(argv, models, algo, ppo):
    from seagul_learn.commands.reproduce import config_flags
    from seagul_learn.experiment import ExperimentConfig

    config = config_flags(["acrobot", *argv])
    assert config == ExperimentConfig(task="acrobot", workers=2, ppo_model=ppo, sb3_models=models, sb3_algo=algo)


def test_reproduce_sb3_errors_are_named(tmp_path, capsys):
    with pytest.raises(SystemExit) as info:
        main(["reproduce", "acrobot", "--sb3", "m.zip", "--sb3-algo", "A2C"])
    assert info.value.code == 2
    assert "argument --sb3-algo: invalid choice: 'A2C'" in capsys.readouterr().err
    missing = str(tmp_path / "gone" / "model.zip")
    assert main(["reproduce", "acrobot", "--preset", "smoke", "--sb3", missing, "--out", str(tmp_path / "r")]) == 2
    assert f"SB3 model '{missing}' does not exist" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()
