"""The CLI options derived from the config dataclasses: every field reachable, typed, defaulted and helped by the
dataclass; the established option spellings still parse."""

from __future__ import annotations

import argparse
import ast
import dataclasses
import inspect
import re
import textwrap
import warnings
from pathlib import Path
from typing import Any

import pytest

from seagul_learn.cli import build_parser, discover_commands
from seagul_learn.commands.train import SAMPLER_WORDS, config_flags
from seagul_learn.experiment import ExperimentConfig
from seagul_learn.training import (
    AdversarialOptions,
    ClosedLoopOptions,
    LossConfig,
    NetworkConfig,
    RefitConfig,
    RuntimeConfig,
    ScheduleConfig,
    SelectionConfig,
    TrainConfig,
)

ROOT = Path(__file__).resolve().parents[1]

# Option strings of ``seagul train`` that scripts rely on: each stays accepted (translated to the nested flags, with
# a deprecation message) whatever the TrainConfig fields are called.
OLD_TRAIN_FLAGS = """--sobolev --solves-per-round
--train-steps-per-round --batch-size --newest-fraction --lr --hidden --ensemble --ensemble-pessimism
--pretrain-solves --pretrain-steps
--adv-max-steps --adv-step-fraction --adv-eps --adv-optimizer --adv-projection --adv-uniform-fraction --adv-ascend-tau
--no-adv-ascend-tau --adv-stop-on-decrease --no-adv-stop-on-decrease --cl-episodes
--cl-horizon --cl-trust-region --cl-warmup-rounds --cl-selection --cl-tail-stride --cl-uniform-fraction
--cl-uniform-solves --cl-jit --no-cl-jit --value-cap --snapshots --eval-every --cache-dir
--no-progress --workers --backend""".split()
RUN_FLAGS = "--task --out --resume --recipe --config --solver-options".split()


def _subparser(name: str) -> argparse.ArgumentParser:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices[name]


def _actions_by_dest(parser: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    """The visible action of each dest (aliases are hidden actions of the same dest)."""
    return {a.dest: a for a in parser._actions if a.help != argparse.SUPPRESS}


def _train(*extra: str) -> TrainConfig:
    return config_flags(["--out", "x", *extra])


def _quiet(**kwargs: Any) -> TrainConfig:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        return TrainConfig(**kwargs)


def field_docstrings(cls: type) -> dict[str, str]:
    """The string literal right below each annotated field of the dataclass ``cls`` and its dataclass bases (what tyro
    prints as the flag's help), cleaned by :func:`inspect.cleandoc`."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if not dataclasses.is_dataclass(klass):
            continue
        node = ast.parse(textwrap.dedent(inspect.getsource(klass))).body[0]
        assert isinstance(node, ast.ClassDef)
        for stmt, following in zip(node.body, node.body[1:], strict=False):
            doc = (
                following.value.value
                if isinstance(following, ast.Expr) and isinstance(following.value, ast.Constant)
                else None
            )
            if isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name) and isinstance(doc, str):
                docs[stmt.target.id] = inspect.cleandoc(doc)
    return docs


def _role_text(match: re.Match[str]) -> str:
    content = match.group(1)
    if "<" in content:
        return content.split("<", 1)[0].strip()
    return content[1:].rsplit(".", 1)[-1] if content.startswith("~") else content


def plain_text(doc: str) -> str:
    """A docstring as one line of plain text: reST roles and literals unwrapped, whitespace collapsed."""
    text = re.sub(r"``(.+?)``", r"\1", re.sub(r":[\w:.-]+:`([^`]+)`", _role_text, doc))
    return " ".join(text.split())


def _help(capsys, *argv: str) -> str:
    with pytest.raises(SystemExit) as info:
        config_flags([*argv, "--help"])
    assert info.value.code == 0
    return " ".join(re.sub(r"[│╭╮╰╯─•]", " ", capsys.readouterr().out).split())


# ------------------------------------------------------------------------------------------------ seagul train
def test_every_train_config_field_is_a_flag_with_its_docstring(capsys):
    """tyro derives one flag per field of every part, helped by the field's docstring (first words)."""
    text = _help(capsys, "--task", "acrobot") + " " + _help(capsys, "--task", "acrobot", "sampler:closed-loop")
    parts = {"network": NetworkConfig, "schedule": ScheduleConfig, "loss": LossConfig, "refit": RefitConfig}
    parts |= {"selection": SelectionConfig, "runtime": RuntimeConfig, "sampler": ClosedLoopOptions}
    for part, cls in parts.items():
        docs = field_docstrings(cls)
        for field in dataclasses.fields(cls):
            flag = f"--{part}.{field.name.replace('_', '-')}"
            assert flag in text, flag
            first = " ".join(plain_text(docs[field.name]).split()[:3])
            assert first.replace("`", "") in text.replace("`", ""), (flag, first)
    for field in ("seed", "budget", "model-params", "uniform-tau", "validate"):
        assert f"--{field}" in text
    assert "sampler:uniform" in text and "sampler:adversarial" in text
    assert all(flag in text for flag in RUN_FLAGS)


def test_defaults_are_the_tasks_recipe_a_named_recipe_or_a_saved_config(tmp_path):
    """Flags not given take the task's recipe (``--recipe``, default ``default``) or a saved config (``--config``);
    flags given win; another sampler than the recipe's starts from the dataclass defaults."""
    for task in ("acrobot", "glider"):
        assert _train("--task", task) == TrainConfig.recipe(task)
        assert _train("--task", task, "--recipe", "paper") == TrainConfig(task=task)
        assert _train("--task", task, "--recipe", "shipped", "--seed", "2") == TrainConfig.recipe(
            task, "shipped", seed=2
        )
    recipe = TrainConfig.recipe("acrobot")
    given = _train("--task", "acrobot", "--budget", "1500", "--network.hidden", "32", "--sampler.episodes", "5")
    assert (given.budget, given.network.hidden, given.sampler.episodes) == (1500, (32,), 5)
    assert given.sampler.slice_fraction == recipe.sampler.slice_fraction == 0.5  # the rest from the recipe
    assert _train("--task", "acrobot", "--sampler.no-collect-refit").sampler.collect_refit is False
    assert _train("--task", "glider", "sampler:adversarial") == TrainConfig(task="glider", sampler="adversarial")
    assert _train("--task", "acrobot", "sampler:closed-loop", "--budget", "900").budget == 900  # the recipe's own
    with pytest.raises(SystemExit):  # tyro reports the config's ValueError (naming the field) and exits with 2
        _train("--task", "acrobot", "--refit.steps", "0")
    with pytest.raises(ValueError, match="unknown recipe 'best'"):
        _train("--task", "acrobot", "--recipe", "best")
    saved = TrainConfig(task="glider", budget=30, loss=LossConfig(sobolev_weight=2.0)).save(tmp_path / "c.yml")
    assert _train("--config", str(saved), "--budget", "40") == TrainConfig(
        task="glider", budget=40, loss=LossConfig(sobolev_weight=2.0)
    )
    assert _train("--config", str(saved), "--task", "acrobot").task == "acrobot"
    assert _train("--task", "acrobot", "--solver-options", '{"max_iter": 5}').solver_options == {"max_iter": 5}


def test_nested_flags_give_the_train_config():
    config = _train(
        "--task", "glider", "--recipe", "paper", "sampler:adversarial", "--sampler.stop-on-decrease",
        "--uniform-tau", "--network.hidden", "16", "16", "--sampler.no-ascend-tau", "--no-validate",
        "--runtime.torch-threads", "2", "--loss.sobolev-weight", "0.25", "--runtime.snapshots", "10", "20",
        "--budget", "20", "--network.ensemble", "3", "--sampler.optimizer", "adam", "--schedule.lr", "0.01",
        "--seed", "-4", "--runtime.no-progress", "--runtime.workers", "2", "--runtime.backend", "ray",
        "--runtime.cache-dir", "cache",
    )  # fmt: skip
    assert config == TrainConfig(
        task="glider",
        seed=-4,
        budget=20,
        sampler=AdversarialOptions(stop_on_decrease=True, ascend_tau=False, optimizer="adam"),
        network=NetworkConfig(hidden=(16, 16), ensemble=3),
        schedule=ScheduleConfig(lr=0.01),
        loss=LossConfig(sobolev_weight=0.25),
        uniform_tau=True,
        validate=False,
        runtime=RuntimeConfig(torch_threads=2, snapshots=(10, 20), progress=False, workers=2, backend="ray",
                              cache_dir="cache"),
    )  # fmt: skip


def test_old_flat_flags_parse_with_a_deprecation_message(capsys):
    config = _train(
        "--task", "glider", "--adv-stop-on-decrease", "--uniform-tau", "--hidden", "16,16", "--no-adv-ascend-tau",
        "--no-validate", "--torch-threads", "2", "--sobolev-weight", "0.25", "--snapshots", "10,20", "--budget", "20",
        "--solver-options", '{"max_iter": 5}', "--no-cl-jit", "--cl-selection", "spread", "--cache-dir", "cache",
        "--sampler", "closed-loop", "--ensemble", "3", "--adv-optimizer", "adam", "--lr", "0.01", "--seed", "-4",
        "--no-progress", "--workers", "2", "--backend", "ray", "--recipe", "paper",
    )  # fmt: skip
    expected = _quiet(
        task="glider",
        adv_stop_on_decrease=True,
        uniform_tau=True,
        hidden=(16, 16),
        adv_ascend_tau=False,
        validate=False,
        torch_threads=2,
        sobolev_weight=0.25,
        snapshots=(10, 20),
        budget=20,
        solver_options={"max_iter": 5},
        cl_jit=False,
        cl_selection="spread",
        cache_dir="cache",
        sampler="closed-loop",
        ensemble=3,
        adv_optimizer="adam",
        lr=0.01,
        seed=-4,
        progress=False,
        workers=2,
        backend="ray",
    )
    assert config == expected
    err = capsys.readouterr().err
    assert "deprecated" in err and "--hidden 16,16 -> --network.hidden 16 16" in err
    assert "--no-cl-jit -> --sampler.no-jit" in err and "--sampler closed-loop -> sampler:closed-loop" in err
    assert "--adv-optimizer adam (ignored: the closed-loop sampler has no such option)" in err


@pytest.mark.parametrize(
    ("argv", "changes"),
    [
        (["--sobolev", "0.5"], {"sobolev_weight": 0.5}),
        (["--sobolev", "1", "--sobolev-weight", "2"], {"sobolev_weight": 2.0}),
        (["--no-progress"], {"progress": False}),
        (["--workers", "4", "--backend", "ray"], {"workers": 4, "backend": "ray"}),
        (["--hidden", "32"], {"hidden": (32,)}),
        (["--hidden=64,32", "--ensemble", "2", "--ensemble-pessimism", "0"], {"hidden": (64, 32), "ensemble": 2,
                                                                               "ensemble_pessimism": 0.0}),
        (["--snapshots", "100,300", "--budget", "300"], {"snapshots": (100, 300), "budget": 300}),
        (["--adv-ascend-tau", "--no-adv-stop-on-decrease"], {"adv_ascend_tau": True, "adv_stop_on_decrease": False}),
        (["--sampler", "closed-loop", "--cl-trust-region", "none", "--cl-horizon", "4", "--value-cap", "300"],
         {"sampler": "closed-loop", "cl_trust_region": "none", "cl_horizon": 4, "value_cap": 300.0}),
        (["--sampler", "closed-loop", "--cl-horizon", "0"], {"sampler": "closed-loop", "cl_horizon": 0}),
        (["--recipe", "task", "--sampler", "uniform"], {"sampler": "uniform"}),
    ],
)  # fmt: skip
def test_old_train_spellings_parse(argv, changes):
    assert _train("--task", "acrobot", "--recipe", "paper", *argv) == _quiet(task="acrobot", **changes)


def test_every_old_flag_is_still_read():
    from seagul_learn.commands.train import translate_legacy

    for flag in OLD_TRAIN_FLAGS:
        sampler = "closed-loop" if flag.startswith(("--cl-", "--no-cl-")) else "adversarial"
        argv = [flag] if flag.startswith("--no-") or flag in ("--cl-jit", "--adv-ascend-tau") else [flag, "1"]
        new, notes = translate_legacy(argv, sampler)
        assert notes and new[0].startswith("--") and new[0] != flag, flag


def test_run_options_are_not_config_fields():
    parser = _subparser("train")
    assert all(flag in parser._option_string_actions for flag in RUN_FLAGS)
    assert not hasattr(TrainConfig(), "out") and not hasattr(TrainConfig(), "resume")


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--loss.sobolev-weight", "-1"], r"loss\.sobolev_weight must be >= 0"),
        (["--runtime.torch-threads", "0"], r"runtime\.torch_threads must be >= 1, got 0"),
        (["--sampler.selection", "best"], None),
        (["--seed", "x"], None),
        (["--validate", "yes"], None),
    ],
)
def test_bad_flags_are_named(argv, message, capsys):
    with pytest.raises(SystemExit) as info:
        _train("--task", "acrobot", *argv)
    assert info.value.code == 2
    err = " ".join(capsys.readouterr().err.split())
    if message is not None:  # a value the config refuses: its message names the field
        assert re.search(message, err), err
    else:
        assert argv[0] in err or argv[1] in err, err


def _documented_train_flags() -> set[str]:
    """Every ``--flag`` of a ``seagul train`` command in the README and docs (continuation lines included)."""
    flags: set[str] = set()
    for path in [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]:
        text = path.read_text().replace("\\\n", " ")
        for line in text.splitlines():
            for command in re.findall(r"seagul train\b[^`\n]*", line):
                flags.update(re.findall(r"(?<![\w-])--[a-z][a-z0-9.-]*", command))
    return flags


def test_documented_train_flags_exist(capsys):
    documented = _documented_train_flags()
    assert {"--budget", "--resume"} <= documented  # the scan finds the commands
    text = " ".join(
        _help(capsys, *argv) for argv in (("--task", "acrobot"), ("sampler:closed-loop",), ("sampler:adversarial",))
    )
    from seagul_learn.commands.train import _legacy_flags

    old = set(_legacy_flags()) | {"--no-" + f[2:] for f in _legacy_flags()} | {"--sampler"}
    assert sorted(f for f in documented if f not in text and f not in old) == []


# ------------------------------------------------------------------------------------------------ seagul reproduce
def _reproduce_help(capsys) -> str:
    from seagul_learn.commands.reproduce import config_flags as reproduce_flags

    with pytest.raises(SystemExit) as info:
        reproduce_flags(["acrobot", "--help"])
    assert info.value.code == 0
    return " ".join(re.sub(r"[│╭╮╰╯─•]", " ", capsys.readouterr().out).split())


def test_every_experiment_config_field_is_a_flag_with_its_docstring(capsys):
    text = _reproduce_help(capsys)
    for field in dataclasses.fields(ExperimentConfig):
        if field.name == "task":  # the positional TASK
            continue
        flag = "--" + field.name.replace("_", "-")
        assert flag in text, f"ExperimentConfig.{field.name} has no flag {flag}"
    assert "Override of the preset's number of paired seeds." in text  # the field's docstring is its help
    assert "--out DIR" in text and "--resume DIR" in text
    assert "--progress, --no-progress" in text and "--shipped-jit, --no-shipped-jit" in text


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["acrobot"], ExperimentConfig(task="acrobot", workers=2)),
        (
            ["glider", "--preset", "smoke", "--seeds", "3", "--workers", "1", "--backend", "ray", "--ppo", "m.zip",
             "--no-progress"],
            ExperimentConfig(
                task="glider", preset="smoke", seeds=3, workers=1, backend="ray", ppo_model="m.zip", progress=False
            ),
        ),
        (["acrobot", "--ppo-model", "p.zip"], ExperimentConfig(task="acrobot", workers=2, ppo_model="p.zip")),
        (["--preset=smoke", "acrobot", "--shipped-jit"], ExperimentConfig(preset="smoke", workers=2, shipped_jit=True)),
        (["acrobot", "--methods", "shipped,uniform"], ExperimentConfig(workers=2, methods=("shipped", "uniform"))),
        (["acrobot", "--methods", "shipped", "uniform"], ExperimentConfig(workers=2, methods=("shipped", "uniform"))),
        (["glider", "--envs", "a,b"], ExperimentConfig(task="glider", workers=2, envs=("a", "b"))),
    ],
)  # fmt: skip
def test_reproduce_flags_give_the_experiment_config(argv, expected):
    from seagul_learn.commands.reproduce import parse

    config, run = parse(argv)
    assert config == expected
    assert run.out is None and run.resume is None


def test_reproduce_old_spellings_print_a_deprecation_message(capsys):
    from seagul_learn.commands.reproduce import config_flags as reproduce_flags

    config = reproduce_flags(["acrobot", "--ppo", "m.zip", "--sb3", "a.zip"])
    assert config.ppo_model == "m.zip" and config.sb3_models == ("a.zip",)
    err = capsys.readouterr().err
    assert (
        "deprecated" in err and "--ppo m.zip -> --ppo-model m.zip" in err and "--sb3 a.zip -> --sb3-models a.zip" in err
    )
    reproduce_flags(["acrobot", "--ppo-model", "m.zip", "--sb3-models", "a.zip"])
    assert capsys.readouterr().err == ""


def test_reproduce_run_options_and_task_errors(capsys):
    from seagul_learn.commands.reproduce import parse

    config, run = parse(["glider", "--out", "o", "--seeds", "2"])
    assert run.out == "o" and run.task == "glider" and config.task == "glider" and config.seeds == 2
    _, run = parse(["acrobot", "--resume", "r"])
    assert run.resume == "r"
    for argv, message in (
        (["--seeds", "2"], "required: TASK"),
        (["nosuchtask"], "unknown task 'nosuchtask'"),
        (["acrobot", "--backend", "dask"], "argument --backend: invalid choice: 'dask'"),
        (["acrobot", "--methods", "uniform", "nope"], "argument --methods: unknown methods ['nope']"),
        (["acrobot", "--methods", "uniform,uniform"], "argument --methods: a method is named twice"),
    ):
        with pytest.raises(SystemExit) as info:
            parse(argv)
        assert info.value.code == 2
        assert message in capsys.readouterr().err
    with pytest.raises(SystemExit) as info:
        parse(["acrobot", "--seeds", "two"])
    assert info.value.code == 2 and "--seeds" in capsys.readouterr().err


def test_every_reproduce_flag_help_prints_is_documented(capsys):
    """Each flag tyro derives for ``seagul reproduce`` is in the reference page, and so are the earlier spellings."""
    page = (ROOT / "docs" / "reference" / "cli.md").read_text()
    section = page[page.index("## `seagul reproduce`") :]
    flags = set(re.findall(r"(?<![\w-])--[a-z][a-z0-9.-]*[a-z0-9]", _reproduce_help(capsys)))
    assert {"--preset", "--methods", "--sb3-models", "--no-shipped-jit", "--out", "--resume"} <= flags
    missing = sorted(f for f in flags | {"--ppo", "--sb3"} if f"`{f}" not in section and f != "--help")
    assert missing == [], f"seagul reproduce flags missing from docs/reference/cli.md: {missing}"


def test_every_command_still_builds():
    assert {c.name for c in discover_commands()} >= {"evaluate", "generate", "reproduce", "train"}


def test_every_train_flag_help_prints_is_documented(capsys):
    """The other direction: each flag tyro derives (top level and every sampler's) is in the reference page."""
    page = (ROOT / "docs" / "reference" / "cli.md").read_text()
    helps = [_help(capsys, "--task", "acrobot")] + [_help(capsys, word) for word in SAMPLER_WORDS]
    flags = {f for text in helps for f in re.findall(r"(?<![\w-])--[a-z][a-z0-9.-]*[a-z0-9]", text)}
    assert {"--sampler.episodes", "--network.hidden", "--runtime.no-progress"} <= flags
    missing = sorted(f for f in flags if f"`{f}" not in page and f != "--help")
    assert missing == [], f"seagul train flags missing from docs/reference/cli.md: {missing}"
