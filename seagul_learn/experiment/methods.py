"""Every named way of learning a value function, in one place: a name and its
:class:`~seagul_learn.training.TrainConfig` overrides.

``seagul reproduce`` (:class:`~seagul_learn.experiment.pipeline.Experiment`) and the closed-loop benchmark
(:mod:`seagul_learn.experiment.benchmark`, driven by ``benchmarks/bench_closed_loop.py``) train the same methods
from this table, so a method means the same settings wherever its name appears (tables, figures, ``closed_loop.json``,
the experiment log ``docs/experiments/closed-loop.md``).

* The paper's samplers (:data:`PAPER_METHODS`, the default of every ``seagul reproduce`` preset): ``uniform`` (the
  baseline), ``adversarial`` (SEAGuL, paper Alg. 1) and ``closed-loop`` (tail problems at the deployed MPC's planned
  terminal states, :mod:`seagul_learn.closed_loop`, with Sobolev training).
* The benchmark's recipes (``uniform+sobolev`` ... ``closed-loop+rest-1000``): the steps that led to the shipped
  recipe, each measured in the experiment log; their settings come on top of :data:`FULL_TRAIN`.
* ``shipped`` (:data:`SHIPPED_METHOD`): the task's own recipe, ``TrainConfig.recipe(task, "shipped")`` (the
  settings behind the README's closed-loop success, ``seagul_learn/recipes/<task>.yml``). It has no fixed overrides
  here: they are the task's (:func:`recipe_fields`). For the acrobot it equals :data:`SHIPPED`
  (``closed-loop+rest-1000``) on top of :data:`FULL_TRAIN`; the glider's is :data:`SHIPPED` with
  :data:`TASK_SHIPPED` and :data:`TASK_TRAIN`, reported as ``closed-loop+sobolev`` (:func:`shipped_name`).
  ``tests/test_experiment.py`` keeps the two equal.
"""

from __future__ import annotations

from dataclasses import fields
from typing import Any

METHODS: dict[str, dict[str, Any]] = {
    "uniform": {"sampler": "uniform"},
    "adversarial": {"sampler": "adversarial"},
    "closed-loop": {"sampler": "closed-loop", "sobolev_weight": 1.0},
    "uniform+sobolev": {"sampler": "uniform", "sobolev_weight": 1.0},
    "adversarial+sobolev": {"sampler": "adversarial", "sobolev_weight": 1.0},
    # 1,000 uniform solves; 10 rounds of 50 tail problems at the queries of the "lqr"-guarded collecting MPC (a
    # safer controller than the deployed one: its queries stay teachable); then 10 rounds at the queries of the
    # deployed controller itself (unguarded, blended), each collected with a refit of the buffer so far (the
    # network that would be deployed then: DAgger). Queries chosen at random. The final refit is an ensemble of 3
    # fits, deployed as their mean (docs/experiments/closed-loop.md).
    "closed-loop+sobolev": {
        "sampler": "closed-loop",
        "sobolev_weight": 1.0,
        "cl_uniform_solves": 1000,
        "cl_trust_region": "none",
        "cl_warmup_rounds": 10,
        "cl_collect_refit": True,
        "cl_selection": "random",
        "cl_episodes": 20,
        "cl_jit": False,
        "refit_ensemble": 3,
        "ensemble_pessimism": 0.0,
    },
}
"""Name -> TrainConfig overrides of every named method but ``shipped`` (module docstring)."""
# Half of every closed-loop round's tails started from the states the collecting episodes visited (failed episodes
# first) instead of from the planner's queries: DAgger's labels (alone not better than closed-loop+sobolev: 2 seeds,
# docs/experiments/closed-loop.md).
METHODS["closed-loop+visited"] = {**METHODS["closed-loop+sobolev"], "cl_visited_fraction": 0.5}
# closed-loop+visited, then the final refit fits 6 members and deploys the 3 whose MPC flies best on training
# starts: every 3-subset flies 100, the best 4 fly 300 more (refits of one buffer differ by tens of points of
# closed-loop success; the selection costs no NLP solve, ~5-10 minutes with the condensed MPC solver). The
# selection and the evaluation fly LimitedLookaheadMPC's default, on the acrobot the condensed solver with extra
# starts where the plan's cost rises (multistart="rise").
METHODS["closed-loop+select"] = {
    **METHODS["closed-loop+visited"],
    "refit_candidates": 6,
    "select_episodes": 100,
    "select_finalists": 4,
    "select_final_episodes": 300,
}
# closed-loop+select at 2,000 solves with half of every closed-loop round's episodes, and half of the selection's
# starts, drawn at rest (on the grid's slice of X0, random draws, never its points): uniform draws over the 4-D X0 never
# start at rest, where the grid's failures lay. 5 seeds: 98.75 % of the grid (median; closed-loop+select 95.75 %), 98 %
# held-out.
METHODS["closed-loop+rest"] = {**METHODS["closed-loop+select"], "cl_slice_fraction": 0.5, "select_slice_fraction": 0.5}
# The shipped recipe: closed-loop+rest scaled to 1,000 solves (its budget split kept: half uniform draws, then 5 rounds
# from the "lqr"-guarded collector and 5 from the deployed one). 5 seeds from scratch: 99.25 % of the grid (median),
# 99 % held-out, 221 s of solver time per network, where closed-loop+rest's 2,000 solves gave 98.75 % / 98 % in 319 s:
# the same success with half the solves (docs/experiments/closed-loop.md).
METHODS["closed-loop+rest-1000"] = {**METHODS["closed-loop+rest"], "cl_uniform_solves": 500, "cl_warmup_rounds": 5}

PAPER_METHODS: tuple[str, ...] = ("uniform", "adversarial", "closed-loop")
"""The paper's three samplers: what a ``seagul reproduce`` preset compares unless it names its methods."""

SHIPPED_METHOD = "shipped"
"""The method that trains the task's own recipe (``TrainConfig.recipe(task)``)."""

METHOD_NAMES: tuple[str, ...] = (*METHODS, SHIPPED_METHOD)
"""Every method name :func:`method_overrides` knows."""

#: Training settings every method shares in the benchmark's full run (docs/experiments/closed-loop.md, "A training
#: fix and the goal blend"): a 2 x 64 network, 50 solves and 1,000 Adam steps per round, labels capped at 50, extreme
#: gradient labels dropped, the standardisation following the buffer, and a fresh 20 k-step refit on everything at
#: the end.
FULL_TRAIN: dict[str, Any] = {
    "hidden": (64, 64),
    "solves_per_round": 50,
    "train_steps_per_round": 1000,
    "value_cap": 50.0,
    "grad_label_max": 10.0,
    "renormalize": True,
    "refit_steps": 20000,
}

SHIPPED = "closed-loop+rest-1000"
"""The benchmark's name of the shipped recipe (its ``--methods`` must include it)."""

TASK_SHIPPED_NAME: dict[str, str] = {"glider": "closed-loop+sobolev"}
"""The shipped method's name in a task's results where :data:`TASK_SHIPPED` makes it another recipe: the glider's
overrides turn off everything "+rest" adds (episodes at rest, visited-state tails, candidates and selection), so what
it ships is closed-loop+sobolev with the collector's best kept."""

#: Per-task changes to :data:`FULL_TRAIN` and to the shipped recipe. The glider (docs/experiments/closed-loop.md, the
#: glider's sections): values of 40-1,000 on X0, so the cap sits above them; its tails impose the perch box and path
#: bounds softly (``task.profile.solver``), so no tail fails; the closed loop collects with the deployed, unguarded MPC
#: from the first round, and the network of the collector that flew best is shipped (``cl_keep_best``: the loop's last
#: network perched on a median of 63.9 % of the grid, the best collector's on 91.7 %, 5 seeds; a 20 k-step refit of
#: the same 2,000 solves on 25 % where the loop's perched on 94 %, seed 0).
TASK_TRAIN: dict[str, dict[str, Any]] = {"glider": {"value_cap": 1500.0, "refit_steps": 0}}
TASK_SHIPPED: dict[str, dict[str, Any]] = {
    "glider": {
        # 1,000 uniform draws then 20 rounds from the deployed MPC: the glider ships 2,000 solves (TASK_BUDGETS)
        "cl_uniform_solves": 1000,
        "cl_warmup_rounds": 0,
        "cl_collect_refit": False,
        "refit_ensemble": 1,
        "cl_keep_best": True,
        # free-time steps (no visited-state tails) and the loop's own network (no final refit to select from)
        "cl_visited_fraction": 0.0,
        "refit_candidates": 0,
        # the acrobot's starts at rest: the glider's recipe draws its episodes over all of X0, as measured
        "cl_slice_fraction": 0.0,
        "select_slice_fraction": 0.0,
    }
}

#: The benchmark's full-run budgets per task (snapshots of one run per method and seed; the largest is the shipped
#: budget). The acrobot's shipped recipe spends 1,000 solves, and its split (500 uniform draws first) makes a snapshot
#: below 1,000 a uniform+Sobolev network, so the full run trains to 1,000 only; the paper's samplers at 100-2,000
#: solves are stored evaluations (``benchmarks/results/closed_loop_others``, aggregated with ``--aggregate
#: --compare``).
TASK_BUDGETS: dict[str, tuple[int, ...]] = {"acrobot": (1000,), "glider": (1000, 2000)}

SHARED_RECIPE_FIELDS = ("hidden", "value_cap", "grad_label_max", "renormalize", "refit_steps")
"""TrainConfig fields of the task's recipe that every method of a run with ``shipped`` shares (the network and the
label handling, the keys of :data:`FULL_TRAIN` and :data:`TASK_TRAIN` other than the schedule): the methods then
differ in how they spend the solves only."""

SCHEDULE_FIELDS = ("budget", "solves_per_round", "train_steps_per_round")
"""TrainConfig fields of the recipe that set a run's schedule (the experiment's budget and rounds)."""


def shipped_name(task: str) -> str:
    """The name under which ``task``'s benchmark results report the shipped method."""
    return TASK_SHIPPED_NAME.get(task, SHIPPED)


def shipped_recipe(task: Any, **overrides: Any) -> Any:
    """The TrainConfig of the task's shipped network's run, its ``"shipped"`` recipe
    (``TrainConfig.recipe(task, "shipped")``, ``seagul_learn/recipes/<task>.yml``), then ``overrides`` (flat or
    dotted names, e.g. ``seed``).

    Raises:
        ValueError: the task has no ``shipped`` recipe (the message names its recipe file).
    """
    from seagul_learn.training import TrainConfig

    return train_config(TrainConfig.recipe(task, "shipped"), **overrides)


def has_shipped_recipe(task: Any) -> bool:
    """Whether the task's recipe file has a ``shipped`` recipe (a task without a file of its own has none)."""
    from seagul_learn.recipes import recipe_names

    return "shipped" in recipe_names(task)


def recipe_fields(task: Any) -> dict[str, Any]:
    """The task's shipped recipe (:func:`shipped_recipe`) as the flat TrainConfig fields it sets apart from the
    defaults, ``task`` excluded: what the ``shipped`` method trains with ({} for a task without one)."""
    from seagul_learn.training import TrainConfig

    if not has_shipped_recipe(task):
        return {}
    recipe = flat_settings(shipped_recipe(task))
    default = flat_settings(TrainConfig(task=task))
    return {k: v for k, v in recipe.items() if k != "task" and v != default.get(k)}


# ------------------------------------------------------------------------------ TrainConfig field names
# The methods (and the benchmark's ``train_settings`` in ``closed_loop.json``) name TrainConfig settings by the flat
# names of its earlier versions (``cl_episodes``), the recipe files' presets by dotted ones (``sampler.episodes``);
# the nested TrainConfig (:mod:`seagul_learn.config`) is made from either here without a deprecation warning.
def flat_settings(config: Any) -> dict[str, Any]:
    """Every setting of a TrainConfig by its flat name (``TrainConfig.flat_dict``; the task as given)."""
    return {**config.flat_dict(), "task": config.task}


def flat_key(name: str) -> str:
    """The flat name of a TrainConfig setting given flat or dotted (``"sampler.episodes"`` -> ``"cl_episodes"``; a
    dotted name without a flat one unchanged)."""
    from seagul_learn.config import flat_name

    return str(flat_name(name))


def train_field_names() -> frozenset[str]:
    """Every name a TrainConfig setting may be given by (its fields, their dotted and their flat names)."""
    from seagul_learn.config import accepted_names

    return frozenset(accepted_names())


def train_config(base: Any = None, **settings: Any) -> Any:
    """A TrainConfig from ``settings`` named flat or dotted, on top of ``base`` (a TrainConfig; None: the dataclass
    defaults). A setting of another sampler than the config's has no effect and is left out, as the flat
    TrainConfig ignored it (the presets' every-method overrides name the closed-loop sampler's).

    Raises:
        ValueError: a setting given twice (flat and dotted), or one TrainConfig does not have.
    """
    from seagul_learn.config import LEGACY_NAMES, SAMPLER_OPTIONS, new_name
    from seagul_learn.training import TrainConfig

    chosen = settings.get("sampler", base.sampler if base is not None else TrainConfig().sampler)
    sampler = chosen if isinstance(chosen, str) else chosen.name
    own = {f.name for f in fields(SAMPLER_OPTIONS[sampler])}  # type: ignore[arg-type]
    named: dict[str, Any] = {}
    for key, value in settings.items():
        if key in LEGACY_NAMES:
            owner = LEGACY_NAMES[key][2]
            if owner is not None and owner != sampler:
                continue
            if key == "cl_horizon" and value in (0, None):
                value = None  # the flat 0 meant the task's default horizon
            key = new_name(key)
        elif key.startswith("sampler.") and key.partition(".")[2] not in own:
            continue
        if key in named:
            raise ValueError(f"the TrainConfig setting {key!r} is given twice (flat and dotted)")
        named[key] = value
    if base is None:
        return TrainConfig(**named)
    if named.get("sampler") == base.sampler.name:
        del named["sampler"]  # the same sampler keeps its options
    return base.replaced(**named)


def method_overrides(task: Any, method: str) -> dict[str, Any]:
    """The TrainConfig overrides (flat names) of ``method`` for ``task``: :data:`METHODS`, or the task's recipe for
    ``shipped`` (:func:`recipe_fields`).

    Raises:
        ValueError: an unknown method name.
    """
    if method == SHIPPED_METHOD:
        return recipe_fields(task)
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose one of {list(METHOD_NAMES)}")
    return dict(METHODS[method])
