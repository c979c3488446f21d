"""The CLI options derived from the config dataclasses: every field reachable, typed, defaulted and helped by the
dataclass; the established option spellings still parse."""

from __future__ import annotations

import argparse
import dataclasses
import re
from pathlib import Path
from typing import Any, Literal

import pytest

from seagul_learn.cli import build_parser, discover_commands
from seagul_learn.commands._config import (
    Option,
    add_dataclass_arguments,
    dataclass_from_args,
    field_docstrings,
    option_name,
    plain_text,
)
from seagul_learn.commands.train import config_from_args
from seagul_learn.experiment import ExperimentConfig
from seagul_learn.training import TrainConfig

ROOT = Path(__file__).resolve().parents[1]

# Option strings of ``seagul train`` that scripts rely on: each stays accepted whatever the TrainConfig fields are
# called.
OLD_TRAIN_FLAGS = """--task --sampler --budget --seed --out --resume --sobolev --solves-per-round
--train-steps-per-round --batch-size --newest-fraction --lr --hidden --ensemble --ensemble-pessimism
--pretrain-solves --pretrain-steps
--adv-max-steps --adv-step-fraction --adv-eps --adv-optimizer --adv-projection --adv-uniform-fraction --adv-ascend-tau
--no-adv-ascend-tau --adv-stop-on-decrease --no-adv-stop-on-decrease --uniform-tau --no-uniform-tau --cl-episodes
--cl-horizon --cl-trust-region --cl-warmup-rounds --cl-selection --cl-tail-stride --cl-uniform-fraction
--cl-uniform-solves --cl-jit --no-cl-jit --value-cap --snapshots --eval-every --solver-options --cache-dir
--no-progress --workers --backend -h --help""".split()
OLD_REPRODUCE_FLAGS = "--preset --seeds --workers --backend --out --resume --ppo --no-progress -h --help".split()


def _subparser(name: str) -> argparse.ArgumentParser:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices[name]


def _actions_by_dest(parser: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    """The visible action of each dest (aliases are hidden actions of the same dest)."""
    return {a.dest: a for a in parser._actions if a.help != argparse.SUPPRESS}


def _train(*extra: str) -> TrainConfig:
    return config_from_args(build_parser().parse_args(["train", "--out", "x", *extra]))


# ------------------------------------------------------------------------------------------------ seagul train
def test_every_train_config_field_is_an_option():
    parser = _subparser("train")
    actions = _actions_by_dest(parser)
    for field in dataclasses.fields(TrainConfig):
        assert field.name in actions, f"TrainConfig.{field.name} has no option"
        assert option_name(field.name) in actions[field.name].option_strings
    for name in ("adv_stop_on_decrease", "adv_ascend_tau", "uniform_tau", "validate", "torch_threads"):
        assert option_name(name) in parser._option_string_actions


def test_defaults_are_the_tasks_recipe_or_with_recipe_paper_the_dataclass_defaults():
    """Options not given take the task's measured best settings (``TrainConfig.recipe``), or the dataclass's (the
    paper's) with ``--recipe paper``; options given win over either, also when they equal a dataclass default."""
    for task in ("acrobot", "glider"):
        assert _train("--task", task) == TrainConfig.recipe(task)
        assert _train("--task", task, "--recipe", "paper") == TrainConfig(task=task)
    recipe = TrainConfig.recipe("acrobot")
    assert recipe.sampler == "closed-loop" and recipe.budget == 1000 and recipe.hidden == (64, 64)
    given = _train("--task", "acrobot", "--budget", "1500", "--hidden", "32", "--sampler", "closed-loop")
    assert (given.budget, given.hidden, given.sampler) == (1500, (32,), "closed-loop")
    assert given.cl_slice_fraction == recipe.cl_slice_fraction == 0.5  # the rest from the recipe
    assert _train("--task", "acrobot", "--no-cl-collect-refit").cl_collect_refit is False  # a boolean given wins
    # another sampler than the recipe's: the recipe (its settings belong to its sampler) does not apply
    assert _train("--task", "glider", "--sampler", "adversarial") == TrainConfig(task="glider", sampler="adversarial")
    with pytest.raises(ValueError, match="--recipe paper"):  # a clash with the recipe names the way out
        _train("--task", "acrobot", "--refit-steps", "0")
    with pytest.raises(SystemExit):
        _train("--task", "acrobot", "--recipe", "best")


def test_a_task_recipe_names_train_config_fields_only():
    """``TrainConfig.recipe``: a task without a recipe gives the dataclass defaults; a recipe or an override with
    a field TrainConfig does not have is an error naming it."""
    import dataclasses as dc

    from seagul_envs import make_task

    task = make_task("acrobot")
    plain = dc.replace(task, profile=dc.replace(task.profile, train_recipe={}))
    assert TrainConfig.recipe(plain) == TrainConfig(task=plain)
    typo = dc.replace(task, profile=dc.replace(task.profile, train_recipe={"budjet": 5}))
    for sampler in ({}, {"sampler": "uniform"}):  # reported also when another sampler sets the recipe aside
        with pytest.raises(ValueError, match=r"train_recipe names unknown fields \['budjet'\]"):
            TrainConfig.recipe(typo, **sampler)
    with pytest.raises(ValueError, match=r"overrides names unknown fields \['budjet'\]"):
        TrainConfig.recipe("acrobot", budjet=5)
    assert TrainConfig.recipe("acrobot", budget=10).budget == 10


def test_parsed_options_give_the_train_config():
    config = _train(
        "--task", "glider", "--adv-stop-on-decrease", "--uniform-tau", "--hidden", "16,16", "--no-adv-ascend-tau",
        "--no-validate", "--torch-threads", "2", "--sobolev-weight", "0.25", "--snapshots", "10,20", "--budget", "20",
        "--solver-options", '{"max_iter": 5}', "--no-cl-jit", "--cl-selection", "spread", "--cache-dir", "cache",
        "--sampler", "closed-loop", "--ensemble", "3", "--adv-optimizer", "adam", "--lr", "0.01", "--seed", "-4",
        "--no-progress", "--workers", "2", "--backend", "ray", "--recipe", "paper",
    )  # fmt: skip
    expected = TrainConfig(
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
    assert isinstance(config.hidden, tuple) and isinstance(config.sobolev_weight, float)


def test_boolean_fields_have_both_forms():
    assert _train("--task", "acrobot", "--no-uniform-tau").uniform_tau is False
    assert _train("--task", "acrobot", "--uniform-tau", "--no-uniform-tau").uniform_tau is False
    assert _train("--task", "acrobot", "--cl-jit").cl_jit is True
    assert _train("--task", "acrobot", "--progress").progress is True


def test_help_strings_come_from_the_docstrings():
    parser = _subparser("train")
    docs = field_docstrings(TrainConfig)
    actions = _actions_by_dest(parser)
    for field in dataclasses.fields(TrainConfig):
        assert docs.get(field.name), f"TrainConfig.{field.name} has no docstring"
        help_text = actions[field.name].help.replace("%%", "%")
        assert help_text.startswith(plain_text(docs[field.name])), field.name
    assert docs["adv_stop_on_decrease"] == "Adversarial: end a chain when its loss decreased from the previous iterate."
    assert actions["hidden"].help == "Hidden-layer widths of the tanh network. (default: 32)"
    assert actions["sobolev_weight"].help.endswith("(also: --sobolev) (default: 0.0)")
    text = " ".join(parser.format_help().split())
    assert "--adv-stop-on-decrease, --no-adv-stop-on-decrease Adversarial: end a chain when its loss decreased" in text
    assert "Draw uniform starts' tau from T0 instead of using the nominal value. (default: false)" in text
    assert "--sobolev " not in text.split("training configuration")[0]  # the alias is hidden from the usage line


def test_train_help_runs():
    with pytest.raises(SystemExit) as info:
        build_parser().parse_args(["train", "--help"])
    assert info.value.code == 0


def test_old_train_flags_still_exist():
    known = _subparser("train")._option_string_actions
    assert [f for f in OLD_TRAIN_FLAGS if f not in known] == []


@pytest.mark.parametrize(
    ("argv", "changes"),
    [
        (["--sobolev", "0.5"], {"sobolev_weight": 0.5}),
        (["--sobolev", "1", "--sobolev-weight", "2"], {"sobolev_weight": 2.0}),
        (["--no-progress"], {"progress": False}),
        (["--workers", "4", "--backend", "ray"], {"workers": 4, "backend": "ray"}),
        (["--hidden", "32"], {"hidden": (32,)}),
        (["--hidden", "64,32", "--ensemble", "2", "--ensemble-pessimism", "0"], {"hidden": (64, 32), "ensemble": 2,
                                                                                 "ensemble_pessimism": 0.0}),
        (["--snapshots", ""], {"snapshots": ()}),
        (["--snapshots", "100,300", "--budget", "300"], {"snapshots": (100, 300), "budget": 300}),
        (["--adv-ascend-tau", "--no-adv-stop-on-decrease"], {"adv_ascend_tau": True, "adv_stop_on_decrease": False}),
        (["--cl-trust-region", "none", "--cl-horizon", "4", "--value-cap", "300"], {"cl_trust_region": "none",
                                                                                 "cl_horizon": 4, "value_cap": 300.0}),
    ],
)  # fmt: skip
def test_old_train_spellings_parse(argv, changes):
    assert _train("--task", "acrobot", "--recipe", "paper", *argv) == dataclasses.replace(
        TrainConfig(task="acrobot"), **changes
    )


def test_out_and_resume_are_not_config_fields():
    args = build_parser().parse_args(["train", "--task", "acrobot", "--out", "runs/a", "--resume"])
    assert args.out == "runs/a" and args.resume is True
    assert not hasattr(TrainConfig(), "out") and not hasattr(TrainConfig(), "resume")


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--sobolev", "-1"], "argument --sobolev: must be a finite number >= 0"),
        (["--sobolev-weight", "-1"], "argument --sobolev-weight: must be a finite number >= 0"),
        (["--torch-threads", "0"], "argument --torch-threads: must be >= 1, got 0"),
        (["--seed", "x"], "argument --seed: expected an integer, got 'x'"),
        (["--adv-eps", "-0.1"], "argument --adv-eps: must be a finite number >= 0"),
        (["--cl-selection", "best"], "argument --cl-selection: invalid choice: 'best'"),
        (["--validate", "yes"], "unrecognized arguments: yes"),
    ],
)
def test_derived_option_errors_name_the_spelling_used(argv, message, capsys):
    with pytest.raises(SystemExit) as info:
        build_parser().parse_args(["train", "--task", "acrobot", "--out", "x", *argv])
    assert info.value.code == 2
    assert message in capsys.readouterr().err


def _documented_train_flags() -> set[str]:
    """Every ``--flag`` of a ``seagul train`` command in the README and docs (continuation lines included)."""
    flags: set[str] = set()
    for path in [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]:
        text = path.read_text().replace("\\\n", " ")
        for line in text.splitlines():
            for command in re.findall(r"seagul train\b[^`\n]*", line):
                flags.update(re.findall(r"(?<![\w-])--[a-z][a-z0-9-]*", command))
    return flags


def test_documented_train_flags_exist():
    documented = _documented_train_flags()
    assert {"--sobolev", "--hidden", "--budget", "--resume"} <= documented  # the scan finds the commands
    known = _subparser("train")._option_string_actions
    assert sorted(documented - set(known)) == []


# ------------------------------------------------------------------------------------------------ seagul reproduce
def test_every_experiment_config_field_is_an_argument():
    parser = _subparser("reproduce")
    actions = _actions_by_dest(parser)
    for field in dataclasses.fields(ExperimentConfig):
        assert field.name in actions, f"ExperimentConfig.{field.name} has no argument"
    assert [f for f in OLD_REPRODUCE_FLAGS if f not in parser._option_string_actions] == []


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["acrobot"], ExperimentConfig(task="acrobot", workers=2)),
        (
            ["glider", "--preset", "smoke", "--seeds", "3", "--workers", "1", "--backend", "ray", "--ppo", "m.zip",
             "--no-progress"],
            ExperimentConfig("glider", "smoke", 3, 1, "ray", "m.zip", False),
        ),
        (["acrobot", "--ppo-model", "p.zip"], ExperimentConfig(task="acrobot", workers=2, ppo_model="p.zip")),
    ],
)  # fmt: skip
def test_reproduce_arguments_give_the_experiment_config(argv, expected):
    args = build_parser().parse_args(["reproduce", *argv])
    assert dataclass_from_args(ExperimentConfig, args) == expected
    assert args.out is None and args.resume is None


def test_every_command_still_builds():
    assert {c.name for c in discover_commands()} >= {"evaluate", "generate", "reproduce", "train"}


# ------------------------------------------------------------------------------------------------ the helper
@dataclasses.dataclass
class _Example:
    """A config exercising every supported annotation."""

    count: int = 3
    """How many (``count``, see :class:`~seagul_learn.training.TrainConfig`)."""
    rate: float = 0.5
    """Share in %, see :mod:`seagul_learn.training`."""
    name: str = "a"
    mode: Literal["fast", "slow"] = "fast"
    """Speed."""
    flag: bool = False
    """Whether to."""
    widths: tuple[int, ...] = (4, 4)
    """Widths."""
    weights: tuple[float, ...] = ()
    """Weights."""
    pair: tuple[int, int] = (1, 2)
    """Exactly two."""
    tags: list[str] = dataclasses.field(default_factory=list)
    """Tags."""
    extra: dict[str, Any] | None = None
    """Extra options."""
    limit: int | None = None
    """Optional limit."""
    path: Path = Path("out")
    """Where."""
    hidden_field: int = dataclasses.field(default=7, init=False)
    """Not an init field."""


def _example_parser(**kwargs: Any) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="example")
    add_dataclass_arguments(parser, _Example, **kwargs)
    return parser


def test_helper_types_from_annotations():
    parser = _example_parser()
    assert dataclass_from_args(_Example, parser.parse_args([])) == _Example()
    args = parser.parse_args(
        ["--count", "5", "--rate", "1e-2", "--name", "b", "--mode", "slow", "--flag", "--widths", "8,16,8",
         "--weights", "0.5, 1.5", "--pair", "3,4", "--tags", "x,y", "--extra", '{"k": [1]}', "--limit", "9",
         "--path", "p/q"]
    )  # fmt: skip
    assert dataclass_from_args(_Example, args) == _Example(
        5, 0.01, "b", "slow", True, (8, 16, 8), (0.5, 1.5), (3, 4), ["x", "y"], {"k": [1]}, 9, Path("p/q")
    )
    assert dataclass_from_args(_Example, parser.parse_args(["--widths", ""])).widths == ()
    assert not hasattr(parser.parse_args([]), "hidden_field")


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--count", "2.5"], "argument --count: expected an integer, got '2.5'"),
        (["--rate", "x"], "argument --rate: expected a number, got 'x'"),
        (["--mode", "medium"], "argument --mode: invalid choice: 'medium'"),
        (["--widths", "4,a"], "argument --widths: expected comma-separated integers like 32,32, got '4,a'"),
        (["--pair", "1,2,3"], "argument --pair: expected 2 comma-separated integers, got '1,2,3'"),
        (["--extra", "[1]"], "argument --extra: expected a JSON object"),
        (["--extra", "{x"], "argument --extra: not valid JSON"),
    ],
)
def test_helper_errors_name_the_option(argv, message, capsys):
    with pytest.raises(SystemExit):
        _example_parser().parse_args(argv)
    assert message in capsys.readouterr().err


def test_helper_docstrings_and_help():
    docs = field_docstrings(_Example)
    assert "name" not in docs and "hidden_field" in docs  # no literal below ``name``
    assert docs["count"] == "How many (``count``, see :class:`~seagul_learn.training.TrainConfig`)."
    assert plain_text(docs["count"]) == "How many (count, see TrainConfig)."
    assert plain_text(docs["rate"]) == "Share in %, see seagul_learn.training."
    assert plain_text(":data:`the presets <seagul_learn.experiment.PRESETS>`\n   here") == "the presets here"
    parser = _example_parser()
    helps = _actions_by_dest(parser)
    assert helps["rate"].help == "Share in %%, see seagul_learn.training. (default: 0.5)"
    assert helps["name"].help == "default: a"
    assert helps["flag"].help == "Whether to. (default: false)"
    assert helps["limit"].help == "Optional limit."
    assert helps["extra"].help == "Extra options."
    assert "Share in %, see" in parser.format_help()  # the escaped % formats


def test_helper_options_refine_fields():
    parser = _example_parser(
        options={
            "count": Option(aliases=("-c", "--n"), default=10),
            "name": Option(required=True, help="the name", choices=("a", "b")),
            "limit": Option(type=lambda v: int(v) * 2, note="doubled"),
        },
        exclude=("path",),
    )
    args = parser.parse_args(["--name", "b", "-c", "4", "--limit", "3"])
    assert dataclass_from_args(_Example, args) == _Example(count=4, name="b", limit=6)
    assert dataclass_from_args(_Example, parser.parse_args(["--name", "a", "--n", "1"])).count == 1
    assert dataclass_from_args(_Example, parser.parse_args(["--name", "a"]), count=0).count == 0
    assert parser.parse_args(["--name", "a"]).count == 10
    assert not hasattr(parser.parse_args(["--name", "a"]), "path")
    helps = _actions_by_dest(parser)
    assert helps["count"].help.endswith("(also: -c, --n) (default: 10)")
    assert helps["name"].help == "the name" and helps["limit"].help == "Optional limit. (doubled)"
    assert "[--n " not in parser.format_usage() and "[-c " not in parser.format_usage()
    assert "[--pair A,B]" in parser.format_usage()


def test_helper_rejects_what_it_cannot_declare():
    with pytest.raises(ValueError, match=r"no fields \['nope'\]"):
        _example_parser(options={"nope": Option()})

    @dataclasses.dataclass
    class Odd:
        value: set[int] = dataclasses.field(default_factory=set)

    with pytest.raises(TypeError, match="no command-line parser"):
        add_dataclass_arguments(argparse.ArgumentParser(), Odd)


def test_a_new_field_needs_no_cli_edit():
    """A field added to a config is an option without touching the command (here: a subclass with one more)."""

    @dataclasses.dataclass
    class Wider(_Example):
        depth: int = 2
        """Layers."""

    parser = argparse.ArgumentParser()
    add_dataclass_arguments(parser, Wider)
    config = dataclass_from_args(Wider, parser.parse_args(["--depth", "5", "--count", "1"]))
    assert config.depth == 5 and config.count == 1
    assert _actions_by_dest(parser)["depth"].help == "Layers. (default: 2)"
    assert _actions_by_dest(parser)["count"].help.startswith("How many")  # inherited docstrings
