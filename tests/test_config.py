"""The nested TrainConfig: its parts, the flat names of earlier versions, data and files, recipes and presets."""

from __future__ import annotations

import dataclasses
import json
import warnings
from pathlib import Path

import pytest

from seagul_envs import make_task
from seagul_learn import recipes
from seagul_learn.config import LEGACY_NAMES, accepted_names, flat_name, new_name
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
    UniformOptions,
)

RESULTS = Path(__file__).resolve().parents[1] / "benchmarks" / "results"


def _quiet(**kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        return TrainConfig(**kwargs)


def test_the_config_has_few_top_level_fields_and_the_sampler_is_one_options_class():
    names = [f.name for f in dataclasses.fields(TrainConfig)]
    assert len(names) <= 20
    config = TrainConfig(task="acrobot")
    assert isinstance(config.sampler, AdversarialOptions) and config.sampler == "adversarial"
    assert TrainConfig(sampler=ClosedLoopOptions(episodes=3)).sampler.episodes == 3
    for name, cls in (
        ("uniform", UniformOptions),
        ("adversarial", AdversarialOptions),
        ("closed-loop", ClosedLoopOptions),
    ):
        assert isinstance(TrainConfig(sampler=name).sampler, cls)  # type: ignore[arg-type]
    with pytest.raises(dataclasses.FrozenInstanceError):
        config.sampler.max_steps = 2  # type: ignore[misc]


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: NetworkConfig(hidden=()), r"network\.hidden must be positive"),
        (lambda: ScheduleConfig(lr=0.0), r"schedule\.lr must be a positive number"),
        (lambda: ScheduleConfig(newest_fraction=2.0), r"schedule\.newest_fraction must be in \[0, 1\]"),
        (lambda: LossConfig(grad_label_max=float("inf")), r"loss\.grad_label_max must be a number >= 0"),
        (lambda: RefitConfig(steps=10, ensemble=2, candidates=2), r"refit\.candidates must exceed refit\.ensemble"),
        (lambda: SelectionConfig(episodes=0), r"selection\.episodes must be >= 1"),
        (lambda: RuntimeConfig(backend="dask"), r"unknown runtime\.backend 'dask'"),  # type: ignore[arg-type]
        (lambda: TrainConfig(sampler="greedy"), r"unknown sampler 'greedy'"),  # type: ignore[arg-type]
        (lambda: TrainConfig(budget=0), r"budget must be >= 1"),
        (
            lambda: TrainConfig(sampler=ClosedLoopOptions(keep_best=True), refit=RefitConfig(steps=5)),
            r"sampler\.keep_best needs refit\.steps = 0",
        ),
        (lambda: TrainConfig.from_dict({"network": {"hiden": [8]}}), r"unknown network fields \['network\.hiden'\]"),
        (lambda: TrainConfig.from_dict({"sobolev": 1.0}), r"unknown TrainConfig fields \['sobolev'\]"),
        (lambda: TrainConfig.from_dict({"sampler": {"name": "closed-loop", "episode": 3}}), r"sampler\.episode"),
    ],
)
def test_bad_values_name_their_field(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_flat_names_still_work_and_warn_naming_the_new_place():
    with pytest.warns(DeprecationWarning, match=r"cl_episodes -> sampler\.episodes") as caught:
        config = TrainConfig(task="acrobot", budget=40, sampler="closed-loop", cl_episodes=5, sobolev_weight=1.0)  # type: ignore[call-arg]
    assert any("sobolev_weight -> loss.sobolev_weight" in str(w.message) for w in caught)
    assert config == TrainConfig(
        task="acrobot", budget=40, sampler=ClosedLoopOptions(episodes=5), loss=LossConfig(sobolev_weight=1.0)
    )
    with pytest.warns(
        DeprecationWarning, match=r"TrainConfig\.cl_episodes is deprecated; use TrainConfig\.sampler\.episodes"
    ):
        assert config.cl_episodes == 5
    with pytest.warns(DeprecationWarning, match="refit_steps"):
        assert config.refit_steps == 0
    with pytest.warns(DeprecationWarning, match="cl_horizon"):
        assert config.cl_horizon == 0  # the flat "task's default" spelling of horizon=None
    with pytest.warns(DeprecationWarning, match="adv_max_steps"):
        assert config.adv_max_steps == AdversarialOptions().max_steps  # another sampler's field: its default
    with pytest.warns(DeprecationWarning, match=r"TrainConfig\.hidden is deprecated; set TrainConfig\.network\.hidden"):
        config.hidden = (16, 16)  # type: ignore[misc]
    assert config.network.hidden == (16, 16)
    with pytest.warns(DeprecationWarning, match=r"cl_horizon -> sampler\.horizon"):
        moved = dataclasses.replace(config, cl_horizon=3)  # type: ignore[call-arg]
    assert moved.sampler.horizon == 3 and moved.sampler.episodes == 5
    # a flat field of another sampler has no effect (as before), and the library itself warns about nothing
    assert _quiet(sampler="uniform", cl_episodes=3).sampler == UniformOptions()
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        TrainConfig.recipe("acrobot")
        TrainConfig.recipe("glider", "shipped", seed=2)
        config.replaced(**{"sampler.episodes": 7, "loss.value_cap": 10.0})


def test_every_flat_name_maps_to_a_field_and_back():
    config = TrainConfig(sampler=ClosedLoopOptions())
    for legacy in LEGACY_NAMES:
        part, _, name = new_name(legacy).rpartition(".")
        owner = config.sampler if part == "sampler" else getattr(config, part)
        if part == "sampler" and legacy.startswith("adv_"):
            owner = AdversarialOptions()
        assert hasattr(owner, name), legacy
        assert new_name(legacy) in accepted_names() and legacy in accepted_names()
    assert flat_name("sampler.episodes") == "cl_episodes" and flat_name("sampler.max_steps") == "adv_max_steps"
    assert flat_name("refit.steps") == "refit_steps" and flat_name("budget") == "budget"


def test_dict_round_trip_and_files(tmp_path):
    config = TrainConfig(
        task="glider",
        seed=3,
        sampler=ClosedLoopOptions(episodes=4, horizon=6, keep_best=True),
        network=NetworkConfig(hidden=(16, 8), ensemble=2),
        loss=LossConfig(sobolev_weight=0.5),
        runtime=RuntimeConfig(snapshots=(20, 10), workers=2),
        solver_options={"tol": 1e-6},
    )
    data = config.to_dict()
    assert json.loads(json.dumps(data)) == data  # JSON-ready
    assert data["sampler"]["name"] == "closed-loop" and data["network"]["hidden"] == [16, 8]
    assert data["runtime"]["snapshots"] == [10, 20]
    assert TrainConfig.from_dict(data) == config
    assert TrainConfig.from_dict(config.flat_dict()) == config
    for suffix in (".yml", ".yaml", ".json"):
        path = config.save(tmp_path / f"config{suffix}")
        assert TrainConfig.load(path) == config
    assert (tmp_path / "config.yml").read_text().startswith("task: glider")
    assert "runtime" not in config.result_fields() or "workers" not in config.result_fields()["runtime"]


def test_an_old_flat_config_json_still_loads():
    """A committed run config of an earlier version (flat names, some fields it did not have yet)."""
    stored = RESULTS / "closed_loop_glider" / "keep-best" / "b2000" / "train_config_seed1.json"
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)  # reading a stored run is no deprecated use
        config = TrainConfig.from_dict(json.loads(stored.read_text()))
    assert config.sampler == ClosedLoopOptions(
        episodes=20,
        jit=False,
        keep_best=True,
        selection="random",
        trust_region="none",
        uniform_solves=1000,
        warmup_rounds=0,
        tail_stride=5,
    )
    assert (config.task, config.seed, config.budget, config.network.hidden) == ("glider", 1, 2000, (64, 64))
    assert config.loss == LossConfig(sobolev_weight=1.0, value_cap=1500.0, grad_label_max=10.0, renormalize=True)


def _shipped_settings(task: str) -> dict:
    """The shipped method's settings as the committed benchmark result records them (``train_settings``)."""
    block = json.loads((RESULTS / "closed_loop.json").read_text())[task]
    return dict(block["train_settings"])


def test_the_shipped_recipe_is_what_the_benchmark_trained():
    """``TrainConfig.recipe(task, "shipped", seed=s)`` is, field by field, the config the closed-loop benchmark
    trains the shipped network with for seed ``s``: its recorded settings (benchmarks/results/closed_loop.json), the
    full run's budget, snapshots at its budgets, no progress bars."""
    for task, budget, snapshots in (("acrobot", 1000, (1000,)), ("glider", 2000, (1000, 2000))):
        settings = _shipped_settings(task)
        for seed in (0, 3):
            bench = _quiet(**settings, budget=budget, snapshots=snapshots, seed=seed, progress=False)
            assert TrainConfig.recipe(task, "shipped", seed=seed) == bench, task
        # the default recipe is the same training without the runtime settings
        assert TrainConfig.recipe(task) == _quiet(**settings, budget=budget)


def test_the_acrobot_shipped_recipe_written_out():
    """The README's 99 % recipe, every field that differs from the defaults written out."""
    config = TrainConfig.recipe("acrobot", "shipped", seed=4)
    assert config == TrainConfig(
        task="acrobot",
        seed=4,
        budget=1000,
        sampler=ClosedLoopOptions(
            episodes=20,
            trust_region="none",
            warmup_rounds=5,
            selection="random",
            tail_stride=5,
            uniform_solves=500,
            jit=False,
            visited_fraction=0.5,
            slice_fraction=0.5,
            collect_refit=True,
        ),
        network=NetworkConfig(hidden=(64, 64), pessimism=0.0),
        schedule=ScheduleConfig(solves_per_round=50, train_steps_per_round=1000),
        loss=LossConfig(sobolev_weight=1.0, value_cap=50.0, grad_label_max=10.0, renormalize=True),
        refit=RefitConfig(steps=20000, ensemble=3, candidates=6),
        selection=SelectionConfig(episodes=100, finalists=4, final_episodes=300, slice_fraction=0.5),
        runtime=RuntimeConfig(snapshots=(1000,), progress=False),
    )


def test_the_robust_recipes_are_the_default_ones_over_robots_within_3000_solves():
    """The glider's ``robust`` recipe is its default closed-loop recipe learning over Theta, with the budget raised
    to 3,000 solves (half of them uniform over ``X0 x Theta``); the acrobot's is its default over robots."""
    for task in ("acrobot", "glider"):
        robust = TrainConfig.recipe(task, "robust", seed=2)
        assert robust.model_params and robust.budget <= 3000 and robust.seed == 2
    over_robots = {"model_params": True, "runtime.progress": False}
    glider = {"budget": 3000, "sampler.uniform_solves": 1500, "runtime.snapshots": (1500, 3000)}
    assert TrainConfig.recipe("glider", "robust") == TrainConfig.recipe("glider").replaced(**over_robots, **glider)
    acrobot = {"budget": 2000, "refit.candidates": 0, "runtime.snapshots": (1000, 2000)}
    assert TrainConfig.recipe("acrobot", "robust") == TrainConfig.recipe("acrobot").replaced(**over_robots, **acrobot)
    # the glider's shipped robust recipes: the value fed the robot's invariants, then the round chosen on more episodes
    invariants = TrainConfig.recipe("glider", "robust-invariants")
    assert invariants == TrainConfig.recipe("glider", "robust").replaced(**{"network.robot_invariants": True})
    select = {
        "selection.rounds": 10,
        "selection.episodes": 40,
        "selection.finalists": 3,
        "selection.final_episodes": 100,
    }
    assert TrainConfig.recipe("glider", "robust-select") == invariants.replaced(**select)
    # ... and with the labels above the cap compressed; the replay recipe is robust-select plus the replay
    compress = TrainConfig.recipe("glider", "robust-compress")
    assert compress == invariants.replaced(**select, **{"loss.value_compress": True})
    replay = TrainConfig.recipe("glider", "robust-replay")
    assert replay == invariants.replaced(**select, **{"sampler.replay_failed": 0.25})


def test_recipes_overrides_and_other_samplers():
    assert TrainConfig.recipe("acrobot", "paper") == TrainConfig(task="acrobot")
    mixed = TrainConfig.recipe("acrobot", budget=1500, network=NetworkConfig(hidden=(32,)))
    assert (mixed.budget, mixed.network.hidden, mixed.sampler.name) == (1500, (32,), "closed-loop")
    assert mixed.loss.sobolev_weight == 1.0  # the rest from the recipe
    # another sampler than the recipe's starts from the defaults
    assert TrainConfig.recipe("acrobot", sampler="uniform") == TrainConfig(task="acrobot", sampler=UniformOptions())
    with pytest.raises(ValueError, match=r"unknown recipe 'fastest' for task 'acrobot'"):
        TrainConfig.recipe("acrobot", "fastest")
    with pytest.raises(ValueError, match=r"overrides name unknown fields \['budjet'\]"):
        TrainConfig.recipe("acrobot", budjet=5)
    task = make_task("acrobot")
    assert TrainConfig.recipe(task).task is task


def test_the_samplers_options_keep_their_old_modules_names_and_old_pickles_load():
    """The option classes live in the torch-free ``seagul_learn.sampler_options``; ``seagul_learn.samplers``,
    ``seagul_learn.closed_loop`` and ``seagul_learn.training`` serve the same class objects under the old names,
    silently, so a config pickled when ``ClosedLoopOptions`` was defined in ``closed_loop`` loads as today's."""
    import pickle

    from seagul_learn import closed_loop, sampler_options, samplers

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert samplers.UniformOptions is sampler_options.UniformOptions is UniformOptions
        assert samplers.AdversarialOptions is sampler_options.AdversarialOptions is AdversarialOptions
        assert samplers.SamplerOptions is sampler_options.SamplerOptions
        assert closed_loop.ClosedLoopOptions is sampler_options.ClosedLoopOptions is ClosedLoopOptions
        assert closed_loop.SELECTIONS == sampler_options.SELECTIONS == ("farthest", "spread", "lowest", "random")
    config = TrainConfig(task="acrobot", budget=40, sampler=ClosedLoopOptions(episodes=3, selection="spread"))
    today = pickle.dumps(config, protocol=0)  # protocol 0 names each class as "module\nname\n" text
    here = b"seagul_learn.sampler_options\nClosedLoopOptions\n"
    assert today.count(here) == 1
    old = today.replace(here, b"seagul_learn.closed_loop\nClosedLoopOptions\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        loaded = pickle.loads(old)
    assert loaded == config and type(loaded.sampler) is ClosedLoopOptions and loaded.sampler.selection == "spread"
    adversarial = pickle.dumps(AdversarialOptions(max_steps=2), protocol=0)
    old = adversarial.replace(b"seagul_learn.sampler_options\n", b"seagul_learn.samplers\n")
    assert old != adversarial and pickle.loads(old) == AdversarialOptions(max_steps=2)


def test_presets_are_the_task_files_data_and_a_users_file_can_be_registered(tmp_path):
    quick = recipes.preset("acrobot", "quick")
    assert quick["budgets"] == (30, 60) and quick["grid_points"] == 8
    assert dict(quick["train_overrides"])["closed-loop:sampler.episodes"] == 10
    smoke = recipes.preset("glider", "smoke")
    assert dict(smoke["train_overrides"]) == {
        "sampler.jit": False,
        "sampler.episodes": 1,
        "sampler.uniform_solves": 0,
        "sampler.uniform_fraction": 0.5,
        "sampler.tail_stride": 5,
    }
    assert sorted(recipes.presets("acrobot")) == ["paper", "quick", "smoke"]
    with pytest.raises(ValueError, match="unknown preset 'huge'"):
        recipes.preset("glider", "huge")
    # every dotted override of every preset is a TrainConfig field, and applies
    for task in ("acrobot", "glider"):
        for fields in recipes.presets(task).values():
            for key, _ in fields.get("train_overrides", ()):
                assert key.rpartition(":")[2] in accepted_names(), key
    config = TrainConfig(sampler="closed-loop", **dict(smoke["train_overrides"]))  # type: ignore[arg-type]
    assert config.sampler.episodes == 1 and config.sampler.jit is False
    # a file of one's own
    own = tmp_path / "mine.yml"
    own.write_text(
        "recipes:\n  default: {budget: 30, loss: {sobolev_weight: 2.0}}\n  big: {extends: default, budget: 90}\n"
    )
    assert recipes.recipe("acrobot", "big", path=own) == {"budget": 90, "loss": {"sobolev_weight": 2.0}}
    bad = tmp_path / "bad.yml"
    bad.write_text("recipes:\n  default: {budjet: 30}\n")
    with pytest.raises(ValueError, match=r"bad\.yml.*budjet"):
        recipes.recipe("acrobot", path=bad)
    try:
        recipes.register("acrobot", own)
        assert TrainConfig.recipe("acrobot").budget == 30
        assert recipes.recipe_names("acrobot") == ["big", "default"]
    finally:
        recipes._REGISTERED.pop("acrobot")
    assert TrainConfig.recipe("acrobot").budget == 1000


def test_the_profile_no_longer_holds_recipes_but_old_readers_and_users_tasks_work():
    task = make_task("acrobot")
    with pytest.warns(DeprecationWarning, match=r"TaskProfile\.presets is deprecated"):
        assert task.profile.presets["quick"]["budgets"] == (30, 60)
    with pytest.warns(DeprecationWarning, match=r"TaskProfile\.train_recipe is deprecated"):
        old = dict(task.profile.train_recipe)
    assert old["cl_uniform_solves"] == 500 and old["hidden"] == (64, 64) and old["sampler"] == "closed-loop"
    # copies neither warn nor change the fingerprint; recipes are not part of the problem
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        copy = dataclasses.replace(task, profile=dataclasses.replace(task.profile))
        assert copy.fingerprint() == task.fingerprint()
    # a user's task that still sets them: warned, used, and part of its fingerprint
    with pytest.warns(DeprecationWarning, match=r"TaskProfile\(train_recipe=\.\.\.\) is deprecated"):
        profile = dataclasses.replace(task.profile, train_recipe={"budget": 7, "sampler": "uniform"})
    mine = dataclasses.replace(task, profile=profile)
    assert mine.fingerprint() != task.fingerprint()
    assert TrainConfig.recipe(mine) == _quiet(task=mine, budget=7, sampler="uniform")
    with pytest.warns(DeprecationWarning):
        plain = dataclasses.replace(task, profile=dataclasses.replace(task.profile, train_recipe={}))
    assert TrainConfig.recipe(plain) == TrainConfig(task=plain)


def test_profile_settings_are_validated():
    from seagul_envs.tasks import MPCDefaults
    from seagul_envs.tasks.profile import SolverDefaults, TaskProfile

    with pytest.raises(ValueError, match=r"trust_region must be one of \['lqr', 'box', 'none'\]"):
        TaskProfile(mpc=MPCDefaults(trust_region="wall"))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="heatmap_metric"):
        TaskProfile(heatmap_metric="colour")
    with pytest.raises(ValueError, match=r"attempt 'snopt:line'"):
        SolverDefaults(plan=("ipopt:line", "snopt:line"))
    with pytest.raises(ValueError, match="multi_start must be one of"):
        SolverDefaults(multi_start="sometimes")
    with pytest.raises(ValueError, match=r"unknown guesses \['zero'\]"):
        SolverDefaults(multi_start_guesses=("zero",))
