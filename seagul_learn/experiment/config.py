"""What one ``seagul reproduce`` run is: :class:`ExperimentConfig` (the command's options), the task's
:class:`Preset` it resolves to (every number of the experiment), and the names of methods and policies in tables.

Presets (one place for every number of the experiment; the paper's settings are §6 of the paper) are data in the
task's recipe file, ``seagul_learn/recipes/<task>.yml`` (:func:`seagul_learn.recipes.preset`; a task without a file
of its own gets ``default.yml``'s); :func:`task_preset` makes the :class:`Preset`:

* ``quick`` — the README's main job: fewer seeds, a smaller budget and a coarser closed-loop grid than the paper,
  same algorithms.
* ``smoke`` — seconds of work past the validation set: checks the whole pipeline (tests, CI), says nothing.
* ``paper`` — acrobot: 100 solves per network, 10 solves every 500 training steps (10,000 steps), 10 paired seeds,
  a 20 x 20 closed-loop grid; glider: the same schedule with its own grid.

``ExperimentConfig.methods`` replaces the preset's methods with any names of
:data:`~seagul_learn.experiment.methods.METHOD_NAMES`. With ``shipped`` among them the run trains the task's recipe
(``TrainConfig.recipe(task)``, the settings behind the README's closed-loop success) and takes its schedule from it:
the recipe's budget, solves and Adam steps per round for every method, one snapshot at the full budget, and the
recipe's network and label settings (:data:`~seagul_learn.experiment.methods.SHARED_RECIPE_FIELDS`) shared by every
method, so the methods differ only in how they spend the same solves (as in the closed-loop benchmark's full run).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Annotated, Any

import tyro

from seagul_envs import Task, make_task, resolve_task
from seagul_envs.tasks import task_label
from seagul_learn.baselines import ALGOS
from seagul_learn.experiment.methods import (
    METHOD_NAMES,
    METHODS,
    PAPER_METHODS,
    SCHEDULE_FIELDS,
    SHARED_RECIPE_FIELDS,
    SHIPPED_METHOD,
    flat_key,
    flat_settings,
    shipped_recipe,
)

SB3_ALGOS = ALGOS
"""The stable-baselines3 algorithms of :attr:`ExperimentConfig.sb3_algo` (those of :mod:`seagul_learn.baselines`)."""

METHOD_LABELS: dict[str, str] = {
    "uniform": "uniform",
    "adversarial": "SEAGuL",
    "closed-loop": "closed-loop",
    SHIPPED_METHOD: "shipped-recipe",
}
"""Names of the methods in tables and figures (the policy of a method is ``"<label> MPC"``)."""

SHIPPED_LABEL = "shipped MPC"
"""The shipped controller's name in tables, figures and its stored episodes (``shipped/episodes``)."""

BASELINE_METHOD = "uniform"
"""The method every other one is compared to on validation error (``learning.json``)."""
REFERENCE_METHOD = "closed-loop"
"""The method every other one is compared to on closed-loop success (``closed_loop/summary.json``); a run without
it compares with :data:`~seagul_learn.experiment.methods.SHIPPED_METHOD` if it has that (:func:`reference_method`)."""


def reference_method(methods: tuple[str, ...] | list[str]) -> str | None:
    """The method of a run that every other one is paired with on closed-loop success: ``closed-loop``, else
    ``shipped``, else none (no paired success tests)."""
    return next((m for m in (REFERENCE_METHOD, SHIPPED_METHOD) if m in methods), None)


def versus_key(reference: str) -> str:
    """The key of a method's paired test against ``reference`` in ``closed_loop/summary.json``: ``vs_closed_loop``,
    ``vs_shipped``."""
    return "vs_" + reference.replace("-", "_")


#: TrainConfig fields the experiment sets itself (a preset's ``train_overrides`` may not touch them).
OWNED_TRAIN_FIELDS = (
    "task", "sampler", "budget", "solves_per_round", "train_steps_per_round", "seed", "snapshots", "workers",
    "backend", "progress",
)  # fmt: skip


def method_label(method: str) -> str:
    """The method's name in tables and figures."""
    return METHOD_LABELS.get(method, method)


def policy_label(method: str, seed: int, budget: int | None = None, reference: bool = False) -> str:
    """The closed-loop policy name of one network: ``"SEAGuL MPC (seed 0)"``, ``"... (seed 0, 20 solves)"``, ...

    ``budget`` None is the final (full-budget) network; ``reference`` marks its episodes on the reference grid.
    """
    extra = "" if budget is None else f", {budget} solves"
    extra += ", reference grid" if reference else ""
    return f"{method_label(method)} MPC (seed {seed}{extra})"


@dataclass(frozen=True)
class Preset:
    """The numbers of one experiment size (everything else is the library's defaults)."""

    seeds: int
    """Paired seeds (each trains one network per method from identical initial parameters)."""
    budget: int
    """Solves per network."""
    solves_per_round: int
    """New solves between training phases."""
    train_steps_per_round: int
    """Adam steps after each round."""
    grid_points: int
    """Closed-loop grid points per axis for the learned MPCs and LQR."""
    reference_grid_points: int
    """Closed-loop grid points per axis for the (expensive) full-horizon MPC."""
    mpc_horizon: int
    """Lookahead steps of the limited-lookahead MPC (deployed, and the closed-loop method's collector)."""
    methods: tuple[str, ...] = PAPER_METHODS
    """Learning methods compared (names in :data:`~seagul_learn.experiment.methods.METHOD_NAMES`; must include the
    uniform baseline)."""
    budgets: tuple[int, ...] = ()
    """Budgets of the success-per-solve curve (each a round's end; the largest is ``budget``; empty: ``(budget,)``)."""
    train_overrides: tuple[tuple[str, Any], ...] = ()
    """TrainConfig overrides of this preset: ``("field", value)`` for every method, ``("method:field", value)`` for
    one (a per-method entry wins over :data:`METHODS`; an every-method entry may not collide with it)."""
    heldout_starts: int = 0
    """Held-out starts every final network also runs from (:func:`seagul_control.evaluation.heldout_starts`: uniform
    draws from X0 with one fixed seed, the closed-loop benchmark's), reported as ``heldout_success_rate`` beside the
    grid success; 0: none."""
    query_samples: int = 20
    """Planner queries re-solved per (method, seed) for the planner-query error."""
    query_tail_stride: int = 1
    """Only queries whose tail problem has a multiple of this many intervals are sampled (fixed-step tasks; each
    interval count is an optimizer of its own, compiled on first use: the smoke preset keeps to a few)."""

    def __post_init__(self) -> None:
        if not self.budgets:
            object.__setattr__(self, "budgets", (self.budget,))
        object.__setattr__(self, "methods", tuple(self.methods))
        object.__setattr__(self, "budgets", tuple(int(b) for b in self.budgets))
        object.__setattr__(self, "train_overrides", tuple((str(k), v) for k, v in self.train_overrides))
        self.validate()

    def validate(self) -> None:
        """Raise a ValueError naming the first bad field."""
        for name in ("seeds", "budget", "solves_per_round", "grid_points", "reference_grid_points", "mpc_horizon"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"preset {name} must be >= 1, got {getattr(self, name)}")
        if self.train_steps_per_round < 0:
            raise ValueError(f"preset train_steps_per_round must be >= 0, got {self.train_steps_per_round}")
        if self.heldout_starts < 0:
            raise ValueError(f"preset heldout_starts must be >= 0, got {self.heldout_starts}")
        if self.query_samples < 1:
            raise ValueError(f"preset query_samples must be >= 1, got {self.query_samples}")
        if self.query_tail_stride < 1:
            raise ValueError(f"preset query_tail_stride must be >= 1, got {self.query_tail_stride}")
        unknown = [m for m in self.methods if m not in METHOD_NAMES]
        if unknown or not self.methods or len(set(self.methods)) != len(self.methods):
            raise ValueError(
                f"preset methods must be distinct names from {list(METHOD_NAMES)}, got {list(self.methods)}"
            )
        if BASELINE_METHOD not in self.methods:
            raise ValueError(f"preset methods must include the {BASELINE_METHOD!r} baseline, got {list(self.methods)}")
        b = self.budgets
        if list(b) != sorted(set(b)) or b[0] < 1 or b[-1] != self.budget:
            raise ValueError(f"preset budgets must increase from >= 1 to budget = {self.budget}, got {list(b)}")
        off_round = [x for x in b if x != self.budget and x % self.solves_per_round]
        if off_round:
            raise ValueError(
                f"preset budgets {off_round} are not ends of rounds of {self.solves_per_round} solves (no snapshot)"
            )
        for key, _ in self.train_overrides:
            method, _, name = key.rpartition(":")
            if method and method not in self.methods:
                raise ValueError(f"preset train_overrides {key!r}: {method!r} is not one of {list(self.methods)}")
            if flat_key(name) in OWNED_TRAIN_FIELDS:
                raise ValueError(f"preset train_overrides may not set {name!r} (the experiment sets it)")
            clash = [m for m in self.methods if not method and flat_key(name) in METHODS.get(m, {})]
            if clash:
                raise ValueError(
                    f"preset train_overrides {key!r} applies to every method but METHODS sets it for {clash}; "
                    f"use '<method>:{name}'"
                )

    def train_fields(self, method: str) -> dict[str, Any]:
        """The TrainConfig overrides of one method: every-method overrides, :data:`METHODS` (none for ``shipped``,
        whose settings are the task's recipe), per-method ones."""
        common = {flat_key(k): v for k, v in self.train_overrides if ":" not in k}
        own = {flat_key(k.rpartition(":")[2]): v for k, v in self.train_overrides if k.rpartition(":")[0] == method}
        return {**common, **METHODS.get(method, {}), **own}


def preset_data(task: Task) -> dict[str, dict[str, Any]]:
    """The experiment presets of ``task``: name -> :class:`Preset` field values, from the task's recipe file
    (:func:`seagul_learn.recipes.presets`)."""
    from seagul_learn import recipes

    return {str(k): dict(v) for k, v in recipes.presets(task).items()}


def task_preset(task: Task, name: str) -> Preset:
    """The preset ``name`` of ``task`` (:func:`preset_data`; a preset without ``mpc_horizon`` gets the task's
    default horizon).

    Raises:
        ValueError: the task has no preset of that name, or its fields are not a valid :class:`Preset`.
    """
    presets = preset_data(task)
    if name not in presets:
        raise ValueError(f"unknown preset {name!r} for task {task.name!r}; choose one of {sorted(presets)}")
    values = {"mpc_horizon": task.profile.default_horizon(task), **presets[name]}
    try:
        return Preset(**values)
    except TypeError as exc:
        raise ValueError(f"task {task.name!r}: preset {name!r} is not a valid Preset ({exc})") from exc


def builtin_presets() -> dict[str, dict[str, Preset]]:
    """Task name -> preset name -> :class:`Preset` of the built-in tasks (behind the deprecated
    ``seagul_learn.experiment.PRESETS``)."""
    from seagul_envs.tasks import BUILTIN_TASKS

    tasks = {n: make_task(n) for n in sorted(BUILTIN_TASKS)}
    return {n: {p: task_preset(t, p) for p in preset_data(t)} for n, t in tasks.items()}


@dataclass
class ExperimentConfig:
    """One ``seagul reproduce`` run: each field is a ``seagul reproduce`` flag (derived by tyro, helped by the
    field's docstring; :mod:`seagul_learn.commands.reproduce`), the task its positional argument."""

    task: Annotated[str | Task, tyro.conf.Suppress] = "acrobot"
    """A registered task name or a Task object (``seagul reproduce module:factory``); ``experiment.json`` stores its
    name and fingerprint. (The command line's positional ``TASK``, not a flag.)"""
    preset: str = "quick"
    """``"quick"``, ``"paper"`` or ``"smoke"``: one of the task's presets (``seagul_learn/recipes/<task>.yml``,
    :func:`task_preset`)."""
    seeds: int | None = None
    """Override of the preset's number of paired seeds."""
    workers: int = 1
    """Parallel processes (training runs and closed-loop episodes; results do not depend on it)."""
    backend: str = "local"
    """``"local"`` or ``"ray"`` for the solves."""
    ppo_model: str | None = None
    """Deprecated spelling of ``--sb3 MODEL --sb3-algo PPO``: a saved stable-baselines3 PPO model evaluated next to
    the MPCs (labelled ``PPO``; kept so that old runs' ``experiment.json`` and scripts still work)."""
    progress: bool = True
    """Show progress bars."""
    sb3_models: tuple[str, ...] = ()
    """Saved stable-baselines3 model zips, each evaluated on the same grid and starts as the MPCs (with the
    ``vecnormalize.pkl`` beside it, if any), labelled ``<algo>[<parent directory>]`` in the tables."""
    sb3_algo: str = "PPO"
    """The stable-baselines3 algorithm class of every ``sb3_models`` entry: ``"PPO"`` or ``"SAC"``."""
    envs: tuple[str, ...] = ()
    """Other Gymnasium envs of the task (e.g. ``SeagulAcrobotMujoco-v0``, the MuJoCo acrobot) in which the final
    networks, LQR and the SB3 models also run on the main grid; the report's "Other simulators" section puts each
    controller's success in every simulator side by side."""
    shipped_jit: bool = False
    """Compile the shipped MPC (:mod:`seagul_learn.shipped`) as the closed-loop benchmark deployed it. Off, the
    same MPC (problem, solver, options) runs with CasADi interpreted: slower steps, which the report labels as
    such. Compiled, its first build on a cold cache is about 2 minutes of gcc per network architecture, a third of
    the quick preset's time."""
    methods: tuple[str, ...] = ()
    """The learning methods compared, instead of the preset's (names of
    :data:`~seagul_learn.experiment.methods.METHODS`, or ``shipped`` for the task's own recipe; ``uniform`` among
    them), e.g. ``shipped,uniform``. With ``shipped`` every method takes the recipe's budget and schedule."""

    def __post_init__(self) -> None:
        # experiment.json stores the tuple as a JSON list; a single path given as a string is one model.
        models = self.sb3_models
        self.sb3_models = (str(models),) if isinstance(models, str | os.PathLike) else tuple(str(m) for m in models)
        self.envs = (self.envs,) if isinstance(self.envs, str) else tuple(str(e) for e in self.envs)
        methods = self.methods
        self.methods = tuple(m for m in methods.split(",") if m) if isinstance(methods, str) else tuple(methods)

    def validate(self) -> None:
        """Raise a ValueError naming the first bad field."""
        task = self.resolve_task()
        presets = preset_data(task)
        if self.preset not in presets:
            raise ValueError(f"unknown preset {self.preset!r}; choose one of {sorted(presets)}")
        if self.seeds is not None and self.seeds < 1:
            raise ValueError(f"seeds must be >= 1, got {self.seeds}")
        if self.workers < 1:
            raise ValueError(f"workers must be >= 1, got {self.workers}")
        if self.backend not in ("local", "ray"):
            raise ValueError(f"unknown backend {self.backend!r}; choose 'local' or 'ray'")
        if self.ppo_model is not None and not Path(self.ppo_model).exists():
            raise FileNotFoundError(f"PPO model {self.ppo_model!r} does not exist")
        if self.sb3_algo not in SB3_ALGOS:
            raise ValueError(f"unknown sb3_algo {self.sb3_algo!r}; choose one of {list(SB3_ALGOS)}")
        seen: set[Path] = set()
        for path in self.sb3_models:
            if not Path(path).is_file():
                raise FileNotFoundError(f"SB3 model {path!r} does not exist")
            if Path(path).resolve() in seen:
                raise ValueError(f"SB3 model {path!r} is given twice in sb3_models")
            seen.add(Path(path).resolve())
        self.sb3_policies()  # the labels can be made
        from seagul_control.evaluation import check_env_task

        for env_id in self.envs:
            if env_id == task.profile.env_id:
                raise ValueError(f"envs: {env_id!r} is the task's own env, where every controller already runs")
            check_env_task(task, env_id)
        if len(set(self.envs)) != len(self.envs):
            raise ValueError(f"envs lists an env twice: {list(self.envs)}")
        self.resolve()  # the methods and the preset make a valid Preset

    def sb3_policies(self) -> list[tuple[str, str, str]]:
        """``(label, path, algo)`` of every SB3 model to evaluate: ``ppo_model`` (label ``"PPO"``), then each of
        ``sb3_models`` (label ``"<algo>[<parent directory>]"``; models whose parent directories share a name are
        told apart by ``<parent>/<file stem>``, then by their position ``#k`` in ``sb3_models``).

        The labels are unique, also as the file names of the stored episodes (:func:`_slug`), and a function of
        the config only, so a resumed run finds the episodes it stored.
        """
        out: list[tuple[str, str, str]] = [("PPO", self.ppo_model, "PPO")] if self.ppo_model else []
        paths = [Path(p) for p in self.sb3_models]
        names = [p.parent.name or p.stem for p in paths]
        clash = _clashing(names)
        names = [
            (f"{p.parent.name}/{p.stem}" if p.parent.name else p.name) if k in clash else n
            for k, (p, n) in enumerate(zip(paths, names, strict=True))
        ]
        clash = _clashing(names)
        names = [f"{n} #{k + 1}" if k in clash else n for k, n in enumerate(names)]
        out += [(f"{self.sb3_algo}[{n}]", str(p), self.sb3_algo) for p, n in zip(paths, names, strict=True)]
        if len(_clashing([label for label, _, _ in out])) > 0:
            raise ValueError(f"cannot give the SB3 models distinct labels: {[label for label, _, _ in out]}")
        return out

    def resolve_task(self) -> Task:
        """The Task of the run: the object given, or the registered name's shared task (ValueError if unknown)."""
        if not isinstance(self.task, Task | str):
            raise ValueError(f"task must be a registered task name or a seagul_envs Task, got {self.task!r}")
        return resolve_task(self.task)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict of the fields (the task by its name)."""
        out = {f.name: getattr(self, f.name) for f in fields(self)}
        out["task"] = task_label(self.task)
        return out

    def resolve(self) -> Preset:
        """The preset with this run's overrides: ``seeds``, then ``methods`` (the preset's per-method train overrides
        of the methods kept stay), then, with ``shipped`` among the methods, the recipe's schedule and shared
        settings (module docstring)."""
        task = self.resolve_task()
        preset = task_preset(task, self.preset)
        if self.seeds is not None:
            preset = replace(preset, seeds=self.seeds)
        if self.methods:
            kept = tuple((k, v) for k, v in preset.train_overrides if k.rpartition(":")[0] in ("", *self.methods))
            preset = replace(preset, methods=self.methods, train_overrides=kept)
        if SHIPPED_METHOD in preset.methods:
            preset = recipe_schedule(task, preset)
        return preset


def recipe_schedule(task: Task, preset: Preset) -> Preset:
    """``preset`` on the schedule of the task's recipe: its budget (one snapshot, at the full budget), solves and
    Adam steps per round, and its network and label settings (:data:`SHARED_RECIPE_FIELDS`) for every method in
    place of the preset's every-method overrides (per-method ones stay); the task's default MPC horizon, which the
    closed-loop benchmark deploys the recipe's networks with."""
    recipe = flat_settings(shipped_recipe(task))
    schedule: dict[str, Any] = {name: int(recipe[name]) for name in SCHEDULE_FIELDS}
    shared = tuple((name, recipe[name]) for name in SHARED_RECIPE_FIELDS)
    own = tuple((k, v) for k, v in preset.train_overrides if ":" in k)
    horizon = task.profile.default_horizon(task)  # the deployed horizon the recipe was measured with
    return replace(preset, **schedule, budgets=(schedule["budget"],), train_overrides=shared + own, mpc_horizon=horizon)


def _slug(name: str) -> str:
    return "".join(ch if ch.isalnum() else "-" for ch in name.lower())


def _clashing(names: Sequence[str]) -> set[int]:
    """Positions of the names whose :func:`_slug` (the stored episodes' file name) another name shares."""
    slugs = [_slug(n) for n in names]
    return {k for k, s in enumerate(slugs) if slugs.count(s) > 1}
