"""The paper's experiment end to end (``seagul reproduce``): the task's shipped controller in closed loop, validation
set, three ways of learning the value function trained over paired seeds, closed-loop MPC evaluation of every
network next to LQR and the full-horizon MPC, and a report.

**Shipped controller** (``shipped/shipped.json``, ``shipped/shipped_vs_lqr.gif``; the ``shipped`` block of
``experiment.json``; the report's first section). The network the closed-loop benchmark ships for the task
(:func:`seagul_learn.shipped.shipped_network`: ``benchmarks/results/closed_loop.json``) as the terminal cost of the
limited-lookahead MPC deployed as that benchmark deploys it, from the reference grid's starts beside LQR and the
full-horizon MPC (whose episodes there the closed-loop evaluation shares), and one animation of it beside LQR from the
hardest corner of X0. The MPC runs with CasADi interpreted unless ``--shipped-jit`` (the same problem and solver;
compiling it is about 2 minutes of gcc on a cold cache). A task without a shipped network gets a line saying so and
no block.

**Learning methods** (:data:`METHODS`: a name and its :class:`~seagul_learn.training.TrainConfig` overrides). Every
method of a seed starts from IDENTICAL pretrained parameters and spends the same number of solves and training steps:

* ``uniform`` — the baseline: starts drawn uniformly from X0 at the nominal time to go.
* ``adversarial`` — SEAGuL (paper Alg. 1): projected gradient-ascent chains on the network's error, started from the
  baseline's starts.
* ``closed-loop`` — each round the deployed limited-lookahead MPC (the experiment's horizon) is rolled out and the
  tail problems at its planned terminal states are solved (:mod:`seagul_learn.closed_loop`); Sobolev training.

**Validation** (``learning.json``, ``validation_curves.png``): both validation MSEs of every run, each method paired
against the uniform baseline per seed (median ratio, win fraction, Wilcoxon test; :mod:`seagul_learn.comparison`).

**Closed loop for every seed** (``closed_loop/summary.json``, ``success_vs_solves.png``). Every (method, seed) run
saves its network after each budget of :attr:`Preset.budgets`; each of these networks is the terminal cost of the
limited-lookahead MPC over the main start grid. Per method the summary holds the grid success of every seed at the
full budget, its median and 25/75 % quantiles, the median at every budget (the success-per-solve curve), the
planner-query error (``|Vhat - V|`` at a sample of the final MPC's planned terminal states, re-solved as tail
problems: :func:`seagul_learn.closed_loop.query_errors`; median over seeds of the per-seed median and p95) and a
paired test of the method against the closed-loop method on the per-seed success rates
(:func:`paired_success_comparison`). LQR, the saved stable-baselines3 models given (``--sb3 MODEL --sb3-algo
PPO|SAC``: :meth:`ExperimentConfig.sb3_policies`) and the full-horizon MPC (on the coarser reference grid, next to
every final network) run as baselines.

Every stage writes its results into the run directory before the next starts, and a finished stage is never run
again: training runs checkpoint after each round (``seagul_learn.training``), solves (training, query errors) are
cached on disk bit for bit, the closed-loop episodes of each policy and each query error are stored as soon as
they are complete, and the shipped controller's evaluation is read back from ``shipped/shipped.json``. So Ctrl-C
(or SIGKILL) at any moment leaves a run that ``seagul reproduce TASK --resume DIR`` finishes with the same numbers.

Presets (one place for every number of the experiment; the paper's settings are §6 of the paper) live on the task,
``task.profile.presets`` (the acrobot's and the glider's in their task modules, a new task gets
:data:`seagul_envs.tasks.profile.DEFAULT_PRESETS`); :func:`task_preset` makes the :class:`Preset`:

* ``quick`` — the README's main job: fewer seeds, a smaller budget and a coarser closed-loop grid than the paper,
  same algorithms.
* ``smoke`` — seconds of work past the validation set: checks the whole pipeline (tests, CI), says nothing.
* ``paper`` — acrobot: 100 solves per network, 10 solves every 500 training steps (10,000 steps), 10 paired seeds,
  a 20 x 20 closed-loop grid; glider: the same schedule with its own grid.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field, fields, replace
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from seagul_envs import Task, available_tasks, make_task, resolve_task
from seagul_envs.tasks import task_label
from seagul_learn.baselines import ALGOS
from seagul_learn.comparison import (
    METRICS,
    PairedComparison,
    final_metric,
    paired_comparison,
    plot_curves_with_band,
)
from seagul_learn.dataset import atomic_write_text
from seagul_learn.shipped import shipped_network

SB3_ALGOS = ALGOS
"""The stable-baselines3 algorithms of :attr:`ExperimentConfig.sb3_algo` (those of :mod:`seagul_learn.baselines`)."""

METHODS: dict[str, dict[str, Any]] = {
    "uniform": {"sampler": "uniform"},
    "adversarial": {"sampler": "adversarial"},
    "closed-loop": {"sampler": "closed-loop", "sobolev_weight": 1.0},
}
"""The learning methods: name -> :class:`~seagul_learn.training.TrainConfig` overrides (module docstring)."""

METHOD_LABELS: dict[str, str] = {"uniform": "uniform", "adversarial": "SEAGuL", "closed-loop": "closed-loop"}
"""Names of the methods in tables and figures (the policy of a method is ``"<label> MPC"``)."""

SHIPPED_LABEL = "shipped MPC"
"""The shipped controller's name in tables, figures and its stored episodes (``shipped/episodes``)."""

BASELINE_METHOD = "uniform"
"""The method every other one is compared to on validation error (``learning.json``)."""
REFERENCE_METHOD = "closed-loop"
"""The method every other one is compared to on closed-loop success (``closed_loop/summary.json``)."""

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
    methods: tuple[str, ...] = tuple(METHODS)
    """Learning methods compared (names in :data:`METHODS`; must include the uniform baseline)."""
    budgets: tuple[int, ...] = ()
    """Budgets of the success-per-solve curve (each a round's end; the largest is ``budget``; empty: ``(budget,)``)."""
    train_overrides: tuple[tuple[str, Any], ...] = ()
    """TrainConfig overrides of this preset: ``("field", value)`` for every method, ``("method:field", value)`` for
    one (a per-method entry wins over :data:`METHODS`; an every-method entry may not collide with it)."""
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
        if self.query_samples < 1:
            raise ValueError(f"preset query_samples must be >= 1, got {self.query_samples}")
        if self.query_tail_stride < 1:
            raise ValueError(f"preset query_tail_stride must be >= 1, got {self.query_tail_stride}")
        unknown = [m for m in self.methods if m not in METHODS]
        if unknown or not self.methods or len(set(self.methods)) != len(self.methods):
            raise ValueError(f"preset methods must be distinct names from {list(METHODS)}, got {list(self.methods)}")
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
            if name in OWNED_TRAIN_FIELDS:
                raise ValueError(f"preset train_overrides may not set {name!r} (the experiment sets it)")
            clash = [m for m in self.methods if not method and name in METHODS[m]]
            if clash:
                raise ValueError(
                    f"preset train_overrides {key!r} applies to every method but METHODS sets it for {clash}; "
                    f"use '<method>:{name}'"
                )

    def train_fields(self, method: str) -> dict[str, Any]:
        """The TrainConfig overrides of one method: every-method overrides, :data:`METHODS`, per-method ones."""
        common = {k: v for k, v in self.train_overrides if ":" not in k}
        own = {k.rpartition(":")[2]: v for k, v in self.train_overrides if k.rpartition(":")[0] == method}
        return {**common, **METHODS[method], **own}


def task_preset(task: Task, name: str) -> Preset:
    """The preset ``name`` of ``task`` (``task.profile.presets``; a preset without ``mpc_horizon`` gets the task's
    default horizon).

    Raises:
        ValueError: the task has no preset of that name, or its fields are not a valid :class:`Preset`.
    """
    presets = task.profile.presets
    if name not in presets:
        raise ValueError(f"unknown preset {name!r} for task {task.name!r}; choose one of {sorted(presets)}")
    values = {"mpc_horizon": task.profile.default_horizon(task), **presets[name]}
    try:
        return Preset(**values)
    except TypeError as exc:
        raise ValueError(f"task {task.name!r}: preset {name!r} is not a valid Preset ({exc})") from exc


def __getattr__(name: str) -> Any:
    """``PRESETS``: a deprecated name-keyed view (task -> preset name -> :class:`Preset`) of the built-in tasks'
    ``profile.presets``."""
    if name == "PRESETS":
        import warnings

        from seagul_envs.tasks import BUILTIN_TASKS

        warnings.warn(
            "seagul_learn.experiment.PRESETS is deprecated; the presets live on the task: task_preset(task, name)",
            DeprecationWarning,
            stacklevel=2,
        )
        tasks = {n: make_task(n) for n in sorted(BUILTIN_TASKS)}
        return {n: {p: task_preset(t, p) for p in t.profile.presets} for n, t in tasks.items()}
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


@dataclass
class ExperimentConfig:
    """One ``seagul reproduce`` run."""

    task: str | Task = "acrobot"
    """A registered task name or a Task object (``seagul reproduce module:factory``); ``experiment.json`` stores its
    name and fingerprint."""
    preset: str = "quick"
    """``"quick"``, ``"paper"`` or ``"smoke"``: one of the task's ``profile.presets`` (:func:`task_preset`)."""
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

    def __post_init__(self) -> None:
        # experiment.json stores the tuple as a JSON list; a single path given as a string is one model.
        models = self.sb3_models
        self.sb3_models = (str(models),) if isinstance(models, str | os.PathLike) else tuple(str(m) for m in models)
        self.envs = (self.envs,) if isinstance(self.envs, str) else tuple(str(e) for e in self.envs)

    def validate(self) -> None:
        """Raise a ValueError naming the first bad field."""
        task = self.resolve_task()
        if self.preset not in task.profile.presets:
            raise ValueError(f"unknown preset {self.preset!r}; choose one of {sorted(task.profile.presets)}")
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
        """The preset with this run's overrides."""
        preset = task_preset(self.resolve_task(), self.preset)
        if self.seeds is not None:
            preset = replace(preset, seeds=self.seeds)
        return preset


@dataclass(frozen=True)
class LearnedPolicy:
    """One trained network as a closed-loop policy: which run and budget it comes from."""

    method: str
    seed: int
    budget: int
    final: bool
    """The full-budget network (its queries are recorded for the planner-query error)."""
    spec: Any = field(compare=False)
    """Its :class:`~seagul_control.evaluation.PolicySpec`."""


class Experiment:
    """A run directory and its stages; see the module docstring."""

    def __init__(self, config: ExperimentConfig, out: Path) -> None:
        self.config = config
        self.out = Path(out)
        self.preset = config.resolve()
        self.task = config.resolve_task()
        self.state_path = self.out / "experiment.json"
        self.timings: dict[str, float] = {}
        self.shipped: dict[str, Any] | None = None
        """The shipped controller's block of ``experiment.json`` (:meth:`evaluate_shipped`; None until measured or
        for a task without one)."""
        if self.state_path.is_file():
            stored = json.loads(self.state_path.read_text())
            self.timings = {k: float(v) for k, v in stored.get("timings", {}).items()}
            self.shipped = stored.get("shipped")

    # ------------------------------------------------------------------------------------------------ creation
    @classmethod
    def create(cls, config: ExperimentConfig, out: Path | None = None) -> Experiment:
        """A new run directory (default ``runs/<task>-<timestamp>``)."""
        config.validate()
        if out is None:
            stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
            out = Path("runs") / f"{task_label(config.task)}-{stamp}"
        out = Path(out)
        if (out / "experiment.json").exists():
            raise FileExistsError(f"{str(out)!r} already holds an experiment; use --resume {out} to continue it")
        shipped_network(config.resolve_task())  # a declared but missing network file fails here, before any work
        out.mkdir(parents=True, exist_ok=True)
        experiment = cls(config, out)
        experiment.train_jobs()  # checks the preset's TrainConfig overrides before any work
        experiment._save_state()
        return experiment

    @classmethod
    def resume(
        cls, out: Path, workers: int | None = None, progress: bool = True, task: Task | str | None = None
    ) -> Experiment:
        """Reopen an interrupted run (its stored configuration wins; only ``workers``/``progress`` may change).

        ``task``: the Task of a run made with a task object that is not registered (``module:factory``); it must
        have the stored name and fingerprint. Without it the stored name is resolved with ``make_task``.

        Raises:
            FileNotFoundError: no experiment in ``out``.
            ValueError: a damaged experiment file, another task (name or fingerprint), or an unregistered task
                without ``task``.
        """
        path = Path(out) / "experiment.json"
        if not path.is_file():
            raise FileNotFoundError(f"{str(out)!r} holds no seagul experiment (no experiment.json)")
        try:
            stored = json.loads(path.read_text())
            config = ExperimentConfig(**stored["config"])
        except (ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"{str(path)!r} is not a valid experiment file ({exc})") from exc
        stored_name = str(config.task)
        if task is not None:
            if task_label(task) != stored_name:
                raise ValueError(f"{str(out)!r} is a {stored_name} run, not {task_label(task)}")
            config.task = task
        elif stored_name not in available_tasks():
            raise ValueError(
                f"{str(out)!r} is a run of task {stored_name!r}, which is not registered in this process; give the "
                f"task: seagul reproduce module:factory --resume {out} (or Experiment.resume(out, task=...))"
            )
        resolved = config.resolve_task()
        fingerprint = stored.get("task_fingerprint")
        if fingerprint is not None and fingerprint != resolved.fingerprint():
            raise ValueError(
                f"cannot resume {str(out)!r}: it was run on task {stored_name!r} with fingerprint {fingerprint}, and "
                f"the task given now has fingerprint {resolved.fingerprint()} (same name, other content); resume with "
                "the task the run was made with"
            )
        if workers is not None:
            config.workers = workers
        config.progress = progress
        config.validate()
        return cls(config, Path(out))

    def _save_state(self) -> None:
        payload = {
            "config": self.config.to_dict(),
            "task_fingerprint": self.task.fingerprint(),
            "settings": asdict(self.preset),
            "timings": self.timings,
        }
        if self.shipped is not None:
            payload["shipped"] = self.shipped
        atomic_write_text(self.state_path, json.dumps(payload, indent=2, sort_keys=True))

    def _timed(self, stage: str, fn: Callable[[], Any]) -> Any:
        start = time.perf_counter()
        result = fn()
        if stage not in self.timings:  # a resumed stage keeps the time of the run that did the work
            self.timings[stage] = time.perf_counter() - start
        self._save_state()
        return result

    # -------------------------------------------------------------------------------------------------- stages
    def run(self) -> Path:
        """Run every unfinished stage; return the path of ``report.md``."""
        start = time.perf_counter()
        shipped = self._timed("shipped controller", self.evaluate_shipped)
        self._timed("validation set", self.validation_set)
        runs = self._timed("training", self.train_all)
        learning = self._timed("comparison", lambda: self.compare(runs))
        closed_loop = self._timed("closed-loop evaluation", self.evaluate_closed_loop)
        if self.config.envs:
            closed_loop["other_envs"] = self._timed("other simulators", self.evaluate_other_envs)
        self.timings.setdefault("total", time.perf_counter() - start)
        report = self.write_report(runs, learning, closed_loop, shipped)
        self._save_state()
        return report

    def _solver_cache(self) -> Path:
        return self.out / "cache" / "solves"

    def validation_set(self) -> int:
        """Solve (or load from the shared cache) the task's validation set; returns its size."""
        from seagul_learn.solving import solver_key, trajopt_batch_solver
        from seagul_learn.training import default_cache_dir, validation_dataset

        solver = trajopt_batch_solver(self.task, workers=self.config.workers, backend=self.config.backend)
        records = validation_dataset(
            self.task,
            solver,
            solver_key(None, self.task),
            default_cache_dir(),
            self.config.workers,
            self.config.progress,
        )
        failures = sum(not r.success for r in records)
        atomic_write_text(
            self.out / "validation.json", json.dumps({"solves": len(records), "failures": failures}, indent=2)
        )
        return len(records)

    # ------------------------------------------------------------------------------------------------ training
    def train_config(self, method: str, seed: int) -> Any:
        """The :class:`~seagul_learn.training.TrainConfig` of one (method, seed) run.

        The closed-loop method's collecting MPC has the deployed horizon (``mpc_horizon``) unless the preset says
        otherwise; the other samplers ignore the ``cl_*`` fields.
        """
        from seagul_learn.training import TrainConfig

        p = self.preset
        overrides = p.train_fields(method)
        known = {f.name for f in fields(TrainConfig)}
        unknown = sorted(set(overrides) - known)
        if unknown:
            raise ValueError(f"preset train_overrides / METHODS[{method!r}] name unknown TrainConfig fields {unknown}")
        base: dict[str, Any] = {
            "task": self.task,
            "budget": p.budget,
            "solves_per_round": p.solves_per_round,
            "train_steps_per_round": p.train_steps_per_round,
            "seed": seed,
            "snapshots": p.budgets,
            "cl_horizon": p.mpc_horizon,
            # The closed-loop method collects with the guard the experiment deploys ("lqr", evaluate_closed_loop).
            "cl_trust_region": "lqr",
            "progress": False,
        }
        return TrainConfig(**{**base, **overrides})

    def train_jobs(self) -> list[tuple[str, Any]]:
        """``(method, TrainConfig)`` of every run, by seed then method."""
        return [(m, self.train_config(m, seed)) for seed in range(self.preset.seeds) for m in self.preset.methods]

    def run_dir(self, method: str, seed: int) -> Path:
        """Where one training run lives."""
        return self.out / "train" / f"{method}-seed{seed}"

    def network_path(self, method: str, seed: int, budget: int | None = None) -> Path:
        """The network of a run after ``budget`` solves (None or the full budget: the final ``network.pt``)."""
        if budget is None or budget == self.preset.budget:
            return self.run_dir(method, seed) / "network.pt"
        return self.run_dir(method, seed) / f"network_{budget}.pt"

    def _run_complete(self, method: str, seed: int) -> bool:
        if not (self.run_dir(method, seed) / "metrics.json").is_file():
            return False
        return all(self.network_path(method, seed, b).is_file() for b in self.preset.budgets)

    def train_all(self) -> dict[str, list[dict[str, Any]]]:
        """Train every (method, seed) run not finished yet; returns the metrics per method, by seed.

        A finished run lacking a snapshot (killed between its checkpoint and the snapshot's write) is trained again
        from scratch: training is deterministic and its solves come from the cache, so it ends with the same weights.
        """
        jobs = self.train_jobs()
        self._train([(m, c) for m, c in jobs if not self._run_complete(m, c.seed)], total=len(jobs))
        lacking = [(m, c) for m, c in jobs if not self._run_complete(m, c.seed)]
        for m, c in lacking:
            shutil.rmtree(self.run_dir(m, c.seed))
        self._train(lacking, total=len(lacking))
        still = [str(self.run_dir(m, c.seed)) for m, c in jobs if not self._run_complete(m, c.seed)]
        if still:
            raise RuntimeError(f"training runs {still} finished without their snapshots {list(self.preset.budgets)}")
        runs: dict[str, list[dict[str, Any]]] = {m: [] for m in self.preset.methods}
        for m, c in jobs:
            runs[m].append(json.loads((self.run_dir(m, c.seed) / "metrics.json").read_text()))
        return runs

    def _train(self, todo: list[tuple[str, Any]], total: int) -> None:
        from joblib import Parallel, delayed
        from tqdm.auto import tqdm

        if not todo:
            return
        cache = self._solver_cache()
        bar = tqdm(total=total, initial=total - len(todo), desc="training runs", disable=not self.config.progress)
        if self.config.backend == "ray" or self.config.workers == 1:
            # Ray parallelises the solves inside each run; locally with one worker there is nothing to spread.
            for method, config in todo:
                out = self.run_dir(method, config.seed)
                _train_one(config, out, cache, workers=self.config.workers, backend=self.config.backend)
                bar.update(1)
        else:
            jobs = (delayed(_train_one)(c, self.run_dir(m, c.seed), cache) for m, c in todo)
            for _ in Parallel(n_jobs=self.config.workers, return_as="generator_unordered")(jobs):
                bar.update(1)
        bar.close()

    def compare(self, runs: dict[str, list[dict[str, Any]]]) -> dict[str, Any]:
        """Validation errors at the full budget, each method paired against the uniform baseline; the figure.

        ``learning.json``: per metric, every method's per-seed errors and ``vs_uniform`` (a
        :class:`~seagul_learn.comparison.PairedComparison` per other method); the failed solves per method and the
        training steps after pretraining.
        """
        methods = self.preset.methods
        out: dict[str, Any] = {}
        for metric in METRICS:
            block: dict[str, Any] = {m: final_metric(runs[m], metric) for m in methods}
            block["vs_uniform"] = {
                m: asdict(paired_comparison(block[m], block[BASELINE_METHOD])) for m in methods if m != BASELINE_METHOD
            }
            out[metric] = block
        out["failures"] = {m: int(sum(r["metrics"][-1]["failures"] for r in runs[m])) for m in methods}
        out["train_steps"] = int(runs[BASELINE_METHOD][0]["metrics"][-1]["train_steps"])
        plot_curves_with_band(
            {method_label(m): runs[m] for m in methods},
            self.out / "validation_curves.png",
            title=f"{self.task.name}: validation MSE vs solves (median, 25-75 % band over {self.preset.seeds} seeds)",
        )
        atomic_write_text(self.out / "learning.json", json.dumps(out, indent=2, allow_nan=True))
        return out

    # ---------------------------------------------------------------------------------------- shipped controller
    def shipped_grid(self) -> tuple[np.ndarray, dict[str, Any]]:
        """The starts of the shipped controller's evaluation: the preset's reference grid, where the (expensive)
        full-horizon MPC runs for the comparison too, so the three controllers share its starts and its episodes."""
        from seagul_control.evaluation import start_grid

        return start_grid(self.task, self.preset.reference_grid_points)

    def evaluate_shipped(self) -> dict[str, Any]:
        """The task's shipped controller (:func:`seagul_learn.shipped.shipped_network`) in closed loop on
        :meth:`shipped_grid` beside LQR and the full-horizon MPC, and an animation of it beside LQR from the hard
        start (:func:`seagul_learn.report.hard_start`).

        Writes ``shipped/shipped.json`` (the stage's result: ``block``, the ``experiment.json`` block; ``rows``, a
        :func:`~seagul_learn.report.summarize` row per controller; the grid, the deployment and the animation's
        episodes) and ``shipped/shipped_vs_lqr.gif``; a resumed run reads the stored result and evaluates nothing.
        The shipped MPC's and LQR's episodes are stored in ``shipped/episodes``; the full-horizon MPC's are the
        closed-loop evaluation's (``closed_loop/episodes``, same starts). A task without a shipped controller gets
        ``{"block": None}``.
        """
        path = self.out / "shipped" / "shipped.json"
        if path.is_file():
            result: dict[str, Any] = json.loads(path.read_text())
        else:
            result = self._measure_shipped()
            atomic_write_text(path, json.dumps(result, indent=2, allow_nan=True))
        self.shipped = result.get("block")
        return result

    def _measure_shipped(self) -> dict[str, Any]:
        from seagul_control.evaluation import PolicySpec, build_policy
        from seagul_learn.report import controller_animation, hard_start, summarize

        controller = shipped_network(self.task)
        if controller is None:
            return {"block": None, "task": self.task.name}
        starts, grid = self.shipped_grid()
        folder = self.out / "shipped" / "episodes"
        spec = controller.spec(SHIPPED_LABEL, jit=self.config.shipped_jit)
        lqr = PolicySpec("lqr", "LQR")
        episodes = [r for policy in (spec, lqr) for r in self._episodes(policy, starts, False, folder=folder)]
        paths_shown = self.task.profile.trajectory_plot is not None  # as the closed-loop evaluation stores them
        _, reference_specs = self.baseline_specs()
        full = [r for s in reference_specs for r in self._episodes(s, starts, paths_shown)]
        rows = summarize(self.task, episodes + full)
        by = {row["policy"]: row for row in rows}
        ours, full_row = by[SHIPPED_LABEL], by[reference_specs[0].name]
        x0 = hard_start(self.task)
        policies = [(SHIPPED_LABEL, build_policy(self.task, spec)), ("LQR", build_policy(self.task, lqr))]
        _, shown = controller_animation(self.task, policies, x0, self.out / "shipped" / "shipped_vs_lqr.gif")
        n1, n2 = grid["shape"]
        block = {
            "network": controller.declared,
            "horizon": controller.horizon,
            "success_rate": float(ours["success_rate"]),
            "full_horizon_success_rate": float(full_row["success_rate"]),
            "median_ms": float(ours["median_step_ms"]),
            "p95_ms": float(ours["p95_step_ms"]),
            "lqr_success_rate": float(by["LQR"]["success_rate"]),
            "full_horizon_median_ms": float(full_row["median_step_ms"]),
            "full_horizon_p95_ms": float(full_row["p95_step_ms"]),
            "trust_region": controller.trust_region,
            "goal_blend": controller.goal_blend,
            "jit": bool(self.config.shipped_jit),
            "benchmark_jit": controller.jit,
            "grid": f"{n1}x{n2}",
            "starts": len(starts),
            "network_file": str(controller.network),
            "results": "shipped/shipped.json",
            "animation": "shipped/shipped_vs_lqr.gif",
            "benchmark": dict(controller.measured),
            "benchmark_results": str(controller.source),
        }
        return {
            "block": block,
            "task": self.task.name,
            "grid": grid,
            "rows": rows,
            "deployment": controller.describe(),
            "animation": {
                "path": block["animation"],
                "start": [float(v) for v in x0],
                "episodes": [
                    {"policy": e.policy, "success": bool(e.success), "cost": float(e.cost), "steps": int(e.steps)}
                    for e in shown
                ],
            },
        }

    # --------------------------------------------------------------------------------------------- closed loop
    def learned_policies(self) -> list[LearnedPolicy]:
        """Every snapshot network of every (method, seed) run as a limited-lookahead MPC, by method, seed, budget."""
        from seagul_control.evaluation import PolicySpec

        p = self.preset
        # IPOPT, not fatrop: fatrop can loop without end inside a single solve from a shifted warm start at an
        # extreme state (docs/experiments/closed-loop.md); IPOPT's max_iter bounds every solve. Its steps are
        # slower, so step times here are IPOPT's.
        # The "lqr" guard, explicitly: the presets' networks (30-100 solves) are not the shipped recipe's, and the
        # task's default guard ("none" for the built-ins) is measured on the recipe's networks.
        horizon = (("horizon", p.mpc_horizon), ("solver", "ipopt"), ("trust_region", "lqr"))
        out = []
        for method in p.methods:
            for seed in range(p.seeds):
                for budget in p.budgets:
                    final = budget == p.budget
                    label = policy_label(method, seed, None if final else budget)
                    path = str(self.network_path(method, seed, budget))
                    out.append(LearnedPolicy(method, seed, budget, final, PolicySpec("mpc", label, path, horizon)))
        return out

    def baseline_specs(self) -> tuple[list[Any], list[Any]]:
        """``(main, reference)``: LQR and the SB3 models (:meth:`ExperimentConfig.sb3_policies`) on the main grid;
        the (expensive) full-horizon MPC on the coarse one."""
        from seagul_control.evaluation import PolicySpec

        main = [PolicySpec("lqr", "LQR")]
        for label, path, algo in self.config.sb3_policies():
            main.append(PolicySpec("sb3", label, path, (("algo", algo),)))
        return main, [PolicySpec("full", "full-horizon MPC")]

    def _episodes(
        self,
        spec: Any,
        starts: np.ndarray,
        record: bool,
        record_queries: bool = False,
        env_id: str | None = None,
        folder: Path | None = None,
    ) -> list[Any]:
        """One policy's episodes (in ``env_id``, else the task's env), from its stored table if an interrupted run
        finished it. Stored in ``folder`` (default ``closed_loop/episodes`` or ``closed_loop/episodes_<env>``) as
        ``<slug of the label>.json``."""
        from seagul_control.evaluation import EpisodeResult, evaluate

        if folder is None:
            folder = self.out / "closed_loop" / ("episodes" if env_id is None else f"episodes_{_slug(env_id)}")
        path = folder / f"{_slug(spec.name)}.json"
        if path.is_file():
            return [EpisodeResult(**row) for row in json.loads(path.read_text())]
        results = evaluate(
            self.task,
            [spec],
            starts,
            self.config.workers,
            self.config.progress,
            record,
            record_queries=record_queries,
            env_id=env_id,
        )
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, json.dumps([asdict(r) for r in results], allow_nan=True))
        return results

    def _query_error(self, policy: LearnedPolicy, episodes: Sequence[Any]) -> dict[str, Any]:
        """The planner-query error of a final network over its grid episodes' queries (stored when computed)."""
        path = self.out / "closed_loop" / "query_errors" / f"{policy.method}-seed{policy.seed}.json"
        if path.is_file():
            return json.loads(path.read_text())
        from seagul_learn.closed_loop import query_errors
        from seagul_learn.solving import CachedBatchSolver, solver_key, trajopt_batch_solver
        from seagul_learn.value_network import ValueNetwork

        queries = np.array([q for e in episodes for q in e.queries], dtype=np.float64).reshape(-1, self.task.nx + 1)
        stride = self.preset.query_tail_stride
        if stride > 1:
            queries = queries[[_tail_multiple(self.task, float(t), stride) for t in queries[:, -1]]]
        solver = CachedBatchSolver(
            trajopt_batch_solver(self.task, workers=self.config.workers, backend=self.config.backend),
            self._solver_cache(),
            solver_key(None, self.task),
        )
        network = ValueNetwork.load(policy.spec.path)
        # One sampling seed for every network: the sample is a function of the queries only.
        error = query_errors(self.task, network, queries, solver, num=self.preset.query_samples, seed=0).as_dict()
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, json.dumps(error, indent=2, allow_nan=True))
        return error

    def evaluate_closed_loop(self) -> dict[str, Any]:
        """Closed-loop runs of every network and baseline over the start grids, the per-method statistics, figures.

        Writes ``closed_loop/summary.json`` (``policies``: one row per policy and grid; ``methods``: see
        :func:`method_statistics`; the grids and budgets) and ``success_vs_solves.png``.
        """
        from seagul_control.evaluation import start_grid
        from seagul_learn.report import summarize

        p = self.preset
        # Tasks with a trajectory figure (the glider, paper Fig. 3 centre) record the seed-0 paths.
        paths_shown = self.task.profile.trajectory_plot is not None
        starts, grid = start_grid(self.task, p.grid_points)
        ref_starts, ref_grid = start_grid(self.task, p.reference_grid_points)
        learned = self.learned_policies()
        finals = [lp for lp in learned if lp.final]
        episodes: dict[str, list[Any]] = {}
        for lp in learned:
            record = paths_shown and lp.final and lp.seed == 0
            episodes[lp.spec.name] = self._episodes(lp.spec, starts, record, record_queries=lp.final)
        errors = {(lp.method, lp.seed): self._query_error(lp, episodes[lp.spec.name]) for lp in finals}
        main_specs, reference_specs = self.baseline_specs()
        base_results = [r for spec in main_specs for r in self._episodes(spec, starts, paths_shown)]
        ref_results = [r for spec in reference_specs for r in self._episodes(spec, ref_starts, paths_shown)]
        # Every final network on the reference grid too, so its success compares with the full-horizon MPC's.
        ref_learned: dict[tuple[str, int], list[Any]] = {}
        for lp in finals:
            spec = replace(lp.spec, label=policy_label(lp.method, lp.seed, reference=True))
            ref_learned[(lp.method, lp.seed)] = self._episodes(spec, ref_starts, False)

        main_results = [r for lp in learned for r in episodes[lp.spec.name]] + base_results
        reference_results = ref_results + [r for lp in finals for r in ref_learned[(lp.method, lp.seed)]]
        shown = [r for lp in finals if lp.seed == 0 for r in episodes[lp.spec.name]] + base_results
        shown_ref = ref_results + [r for lp in finals if lp.seed == 0 for r in ref_learned[(lp.method, lp.seed)]]
        main_paths = self._grid_outputs("main", main_results, shown, grid)
        ref_paths = self._grid_outputs("reference", reference_results, shown_ref, ref_grid)
        rows = summarize(self.task, main_results) + summarize(self.task, reference_results)

        success = {lp: _success_rate(episodes[lp.spec.name]) for lp in learned}
        methods = {
            m: method_statistics(
                m,
                {(lp.seed, lp.budget): s for lp, s in success.items() if lp.method == m},
                {s: _success_rate(ref_learned[(m, s)]) for s in range(p.seeds)},
                [errors[(m, s)] for s in range(p.seeds)],
                p.seeds,
                p.budgets,
            )
            for m in p.methods
        }
        if REFERENCE_METHOD in methods:
            for m in p.methods:
                if m != REFERENCE_METHOD:
                    methods[m]["vs_closed_loop"] = paired_success_comparison(
                        methods[m]["success"], methods[REFERENCE_METHOD]["success"]
                    )
        baselines = {
            name: _success_rate([r for r in base_results + ref_results if r.policy == name])
            for name in dict.fromkeys(r.policy for r in base_results + ref_results)
        }
        summary = {
            "methods": methods,
            "baselines": baselines,
            "reference_method": REFERENCE_METHOD if REFERENCE_METHOD in methods else None,
            "budgets": list(p.budgets),
            "seeds": p.seeds,
            "grid": grid,
            "reference_grid": ref_grid,
            "policies": rows,
        }
        atomic_write_text(self.out / "closed_loop" / "summary.json", json.dumps(summary, indent=2, allow_nan=True))
        n, m = grid["shape"]
        plot_success_vs_solves(
            methods,
            self.out / "success_vs_solves.png",
            references={
                f"full-horizon MPC ({ref_grid['shape'][0]} x {ref_grid['shape'][1]} reference grid)": baselines.get(
                    "full-horizon MPC", math.nan
                ),
                "LQR": baselines.get("LQR", math.nan),
            },
            title=f"{self.task.name}: closed-loop success on the {n} x {m} grid vs solves per network "
            f"(median, 25-75 % band over {p.seeds} seeds)",
        )
        figures = [
            ("success_vs_solves.png", "Grid success vs solves per network: median and 25-75 % band over seeds"),
            (str(main_paths["heatmap"].relative_to(self.out)), self.task.profile.heatmap_text(self.task, grid)),
            (str(ref_paths["heatmap"].relative_to(self.out)), "The same on the coarser reference grid (seed 0)"),
        ]
        figure = self.task.profile.trajectory_plot
        if "trajectories" in main_paths and figure is not None:
            figures.append((str(main_paths["trajectories"].relative_to(self.out)), figure.caption))
        report_policies = [lp.spec.name for lp in finals] + [r.policy for r in reference_results + base_results]
        return {
            "rows": rows,
            "report_policies": list(dict.fromkeys(report_policies)),
            "methods": methods,
            "baselines": baselines,
            "figures": figures,
        }

    def evaluate_other_envs(self) -> dict[str, Any]:
        """Every final network of every seed, LQR and the SB3 models on the main grid in each of ``config.envs``
        (the same starts as in the task's env). Writes ``closed_loop/other_envs.json``: per controller (a method's
        seeds pooled into their median), its success in the task's env and in each other env."""
        from seagul_control.evaluation import start_grid

        starts, _ = start_grid(self.task, self.preset.grid_points)
        own = self.task.profile.env_id or self.task.name
        finals = [lp for lp in self.learned_policies() if lp.final]
        main_specs, _ = self.baseline_specs()
        rows: dict[str, dict[str, Any]] = {}
        for env_id in (None, *self.config.envs):
            column = own if env_id is None else env_id
            per_method: dict[str, list[float]] = {}
            for lp in finals:
                rate = _success_rate(self._episodes(lp.spec, starts, False, record_queries=False, env_id=env_id))
                per_method.setdefault(lp.method, []).append(rate)
            for method, rates in per_method.items():
                row = rows.setdefault(f"{method_label(method)} MPC", {"seeds": len(rates)})
                row[column] = _nanmedian(rates)
            for spec in main_specs:
                rows.setdefault(spec.name, {"seeds": 1})[column] = _success_rate(
                    self._episodes(spec, starts, False, env_id=env_id)
                )
        result = {"envs": [own, *self.config.envs], "grid_points": self.preset.grid_points, "rows": rows}
        atomic_write_text(self.out / "closed_loop" / "other_envs.json", json.dumps(result, indent=2, allow_nan=True))
        return result

    def _grid_outputs(self, name: str, results: list[Any], shown: list[Any], grid: dict[str, Any]) -> dict[str, Path]:
        """Tables of every episode on one grid (queries left out) and the heatmap of the ``shown`` policies."""
        from seagul_learn.report import plot_heatmaps, write_outputs

        out = self.out / "closed_loop" / name
        paths = write_outputs(out, self.task, [replace(r, queries=[]) for r in results], None, {"grid": grid})
        paths["heatmap"] = plot_heatmaps(self.task, shown, grid, out / "heatmap.png")
        return paths

    # -------------------------------------------------------------------------------------------------- report
    def write_report(
        self,
        runs: dict[str, Any],
        learning: dict[str, Any],
        closed_loop: dict[str, Any],
        shipped: Mapping[str, Any] | None = None,
    ) -> Path:
        """``report.md`` and ``report.html``: the shipped controller (:meth:`evaluate_shipped`) first, then the
        equal-budget comparison of the learning methods with its figures and tables, then settings, timings and
        versions."""
        from seagul_learn.report import Section, Table, library_versions, machine_description, write_report

        p = self.preset
        validation = json.loads((self.out / "validation.json").read_text())
        methods = closed_loop["methods"]
        shown = set(closed_loop["report_policies"])  # the per-budget rows are in closed_loop/summary.json
        final_rows = [row for row in closed_loop["rows"] if row["policy"] in shown]
        names = ", ".join(f"{method_label(m)} (`{m}`)" for m in p.methods)
        sections = [
            shipped_section(self.task, shipped or {"block": None}),
            Section(
                comparison_title(self.config.preset, p.budget, p.seeds),
                [comparison_intro(self.task, p)],
            ),
            Section(
                "Summary",
                [
                    learning_headline(learning, p.methods, p.budget, p.seeds),
                    closed_loop_headline(self.task, methods, closed_loop["baselines"], p.seeds),
                ],
                level=3,
            ),
            Section(
                "Value-function learning (paper Fig. 1 / Fig. 3 left)",
                [
                    f"Methods: {names}. Every method of a seed starts from identical network parameters (pretrained "
                    "on the same random solves), spends the same number of solves and takes the same number of "
                    f"training steps ({learning['train_steps']} after pretraining); adversarial chains start from the "
                    "uniform baseline's starts; the closed-loop method solves tail problems at the deployed MPC's "
                    "planned terminal states (with Sobolev training). Validation: "
                    f"{validation['solves']} solves ({validation['failures']} failed and are excluded).",
                ],
                [
                    Table(
                        [
                            "metric",
                            "method",
                            "method (median)",
                            "uniform (median)",
                            "ratio (median per seed)",
                            "method wins",
                            "Wilcoxon p",
                        ],
                        comparison_rows(learning, p.methods),
                    )
                ],
                [("validation_curves.png", "Validation MSE vs solves: median and 25-75 % band over seeds")],
                level=3,
            ),
            Section(
                "Closed loop (paper Fig. 2 / Fig. 3 centre / Fig. 4)",
                [
                    f"Limited-lookahead MPC with {p.mpc_horizon} steps and each network as terminal cost, for every "
                    f"seed of every method, next to clipped LQR"
                    + "".join(f", {label}" for label, _, _ in self.config.sb3_policies())
                    + " and the full-horizon MPC (on a coarser reference grid: it solves the whole problem at every "
                    "step; every final network runs there too). Success: fraction of grid starts "
                    f"({self.task.profile.describe_success(self.task)}) at "
                    f"{p.budget} solves per network, median and quartiles over {p.seeds} seeds. Query error: "
                    f"`|Vhat - V|` at {p.query_samples} of the final MPC's planned terminal states per seed, "
                    "re-solved as tail problems (median and p95 per seed, then the median over seeds).",
                    "Paired tests against the closed-loop method: per-seed differences of the success rate "
                    "(Wilcoxon signed-rank; n/a with fewer than 2 seeds or all differences 0).",
                ],
                [
                    Table(
                        [
                            "method",
                            "success median",
                            "q25-q75",
                            "per seed",
                            "query error median",
                            "query error p95",
                            "validation mse_all_knots median",
                        ],
                        method_rows(methods, learning),
                    ),
                    Table(
                        ["method", "vs", "median difference", "wins", "losses", "Wilcoxon p"],
                        paired_rows(methods),
                    ),
                    Table(
                        list(CLOSED_LOOP_COLUMNS),
                        [[row.get(c, "") for c in CLOSED_LOOP_COLUMNS] for row in final_rows],
                    ),
                ],
                closed_loop["figures"],
                level=3,
            ),
            *([_other_envs_section(closed_loop["other_envs"], p.seeds)] if "other_envs" in closed_loop else []),
            Section(
                "Solver failures",
                [
                    "Failed training solves (counted against the budget, never trained on): "
                    + ", ".join(f"{method_label(m)} {learning['failures'][m]}" for m in p.methods)
                    + "."
                ],
                level=3,
            ),
            Section(
                "Settings",
                [
                    f"Task `{self.task.name}`, preset `{self.config.preset}`, workers {self.config.workers}, "
                    f"backend `{self.config.backend}`, shipped MPC compiled: {self.config.shipped_jit}. Run "
                    f"directory: `{self.out}`. TrainConfig overrides of the "
                    "methods (`METHODS`; the preset's `train_overrides` below come on top): "
                    + "; ".join(f"`{m}`: {METHODS[m]}" for m in p.methods)
                    + "."
                ],
                [Table(["setting", "value"], [[k, v] for k, v in asdict(p).items()])],
            ),
            Section(
                "Timings",
                [f"Machine: {machine_description()}."],
                [Table(["stage", "wall time (s)"], [[k, round(v, 1)] for k, v in self.timings.items()])],
            ),
            Section("Library versions", tables=[Table(["library", "version"], list(library_versions().items()))]),
        ]
        title = f"Learned value functions as MPC terminal costs: {self.task.name}"
        return write_report(self.out, title, sections)


def _other_envs_section(other: Mapping[str, Any], seeds: int) -> Any:
    """The report's table of every controller's grid success in each simulator of the task."""
    from seagul_learn.report import Section, Table

    envs = list(other["envs"])
    rows = [[name, *(_pct(row.get(e, math.nan)) for e in envs)] for name, row in other["rows"].items()]
    return Section(
        "Other simulators",
        [
            f"The same controllers from the same {other['grid_points']} x {other['grid_points']} grid starts, "
            f"simulated in each env of the task: `{envs[0]}` (the task's own, where they were trained and "
            "evaluated above) and " + ", ".join(f"`{e}`" for e in envs[1:]) + ". Learned methods: the median "
            f"over their {seeds} seeds' final networks. A controller that transfers keeps its success; the "
            "difference between the columns is the model mismatch of the simulators (for the MuJoCo acrobot: "
            "MuJoCo's RK4 integration of the same MJCF dynamics)."
        ],
        [Table(["controller", *[f"success in {e}" for e in envs]], rows)],
        level=3,
    )


def _train_one(config: Any, out: Path, cache: Path, workers: int = 1, backend: str = "local") -> None:
    """One training run behind the experiment's bit-exact solve cache (runs in a worker process)."""
    import torch

    from seagul_learn.solving import CachedBatchSolver, solver_key, trajopt_batch_solver
    from seagul_learn.training import train

    torch.set_num_threads(1)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    key = solver_key(None, config.task)
    solver = CachedBatchSolver(trajopt_batch_solver(config.task, workers=workers, backend=backend), cache, key)
    config = replace(config, workers=workers, backend=backend)
    train(config, out, resume=(out / "config.json").is_file(), batch_solver=solver, solver_name=key)


def _slug(name: str) -> str:
    return "".join(ch if ch.isalnum() else "-" for ch in name.lower())


def _clashing(names: Sequence[str]) -> set[int]:
    """Positions of the names whose :func:`_slug` (the stored episodes' file name) another name shares."""
    slugs = [_slug(n) for n in names]
    return {k for k, s in enumerate(slugs) if slugs.count(s) > 1}


def _tail_multiple(task: Any, tau: float, stride: int) -> bool:
    """Whether the tail problem from time to go ``tau`` has a multiple of ``stride`` intervals."""
    from seagul_learn.closed_loop import snap_tau
    from seagul_learn.solving import tail_horizon

    try:
        k = tail_horizon(task, snap_tau(task, tau))
    except ValueError:
        return False
    return k is None or k % stride == 0


def _success_rate(episodes: Sequence[Any]) -> float:
    return float(np.mean([e.success for e in episodes])) if episodes else math.nan


def _nanmedian(values: Sequence[float]) -> float:
    finite = [float(v) for v in values if v is not None and math.isfinite(float(v))]
    return float(np.median(finite)) if finite else math.nan


# ------------------------------------------------------------------------------------------------- statistics
def paired_success_comparison(method: Sequence[float], reference: Sequence[float]) -> dict[str, Any]:
    """Paired per-seed success rates (higher is better) of a method against a reference method.

    Returns ``median_difference`` (median of ``method - reference``), ``wins``/``losses``/``ties`` (seeds where the
    method's rate is higher/lower/equal), ``p_value`` (two-sided Wilcoxon signed-rank test on the differences; NaN
    with fewer than 2 seeds or when every difference is 0) and ``seeds``.
    """
    a = np.asarray(method, dtype=float)
    b = np.asarray(reference, dtype=float)
    if a.shape != b.shape or a.ndim != 1 or a.size == 0:
        raise ValueError(f"need two equally long, non-empty lists of per-seed success rates, got {a.shape}, {b.shape}")
    diff = a - b
    p = math.nan
    if a.size >= 2 and np.any(diff != 0):
        from scipy.stats import wilcoxon

        p = float(wilcoxon(diff).pvalue)
    return {
        "median_difference": float(np.median(diff)),
        "wins": int(np.sum(diff > 0)),
        "losses": int(np.sum(diff < 0)),
        "ties": int(np.sum(diff == 0)),
        "p_value": p,
        "seeds": int(a.size),
    }


def method_statistics(
    method: str,
    success: Mapping[tuple[int, int], float],
    reference_success: Mapping[int, float],
    query_errors: Sequence[Mapping[str, Any]],
    seeds: int,
    budgets: Sequence[int],
) -> dict[str, Any]:
    """One method's closed-loop statistics over seeds (an entry of ``closed_loop/summary.json``'s ``methods``).

    ``success`` maps ``(seed, budget)`` to the main-grid success rate, ``reference_success`` a seed to its final
    network's rate on the reference grid; ``query_errors`` are the per-seed
    :class:`~seagul_learn.closed_loop.QueryError` dicts. Keys: ``label``, ``policy``, ``success`` (per seed, full
    budget), ``success_median``/``success_q25``/``success_q75``/``success_min``/``success_max``,
    ``reference_success`` (per seed), ``curve`` (``budgets``, ``median``, ``q25``, ``q75``, ``per_seed``
    ``[seed][budget]``) and ``query_error`` (``median`` and ``p95``: medians over seeds of the per-seed values;
    ``per_seed``).
    """
    per_seed = np.array([[success[(s, b)] for b in budgets] for s in range(seeds)], dtype=float)
    final = per_seed[:, -1]
    q25, q75 = np.percentile(final, [25, 75])
    lo, hi = np.percentile(per_seed, [25, 75], axis=0)
    return {
        "label": method_label(method),
        "policy": f"{method_label(method)} MPC",
        "success": final.tolist(),
        "success_median": float(np.median(final)),
        "success_q25": float(q25),
        "success_q75": float(q75),
        "success_min": float(np.min(final)),
        "success_max": float(np.max(final)),
        "reference_success": [float(reference_success[s]) for s in range(seeds)],
        "curve": {
            "budgets": [int(b) for b in budgets],
            "median": np.median(per_seed, axis=0).tolist(),
            "q25": lo.tolist(),
            "q75": hi.tolist(),
            "per_seed": per_seed.tolist(),
        },
        "query_error": {
            "median": _nanmedian([e["median"] for e in query_errors]),
            "p95": _nanmedian([e["p95"] for e in query_errors]),
            "per_seed": [dict(e) for e in query_errors],
        },
    }


def plot_success_vs_solves(
    methods: Mapping[str, Mapping[str, Any]],
    path: str | Path,
    references: Mapping[str, float] | None = None,
    title: str = "",
) -> None:
    """Grid success (%) vs solves per network: median and 25-75 % band over seeds per method (from
    :func:`method_statistics`), a horizontal line per reference controller (matplotlib Agg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 4.4), constrained_layout=True)
    ax.set_xticks(sorted({int(b) for stats in methods.values() for b in stats["curve"]["budgets"]}))
    for stats in methods.values():
        curve = stats["curve"]
        xs = np.asarray(curve["budgets"])
        (line,) = ax.plot(xs, 100 * np.asarray(curve["median"]), marker="o", ms=4, label=stats["policy"])
        ax.fill_between(
            xs, 100 * np.asarray(curve["q25"]), 100 * np.asarray(curve["q75"]), color=line.get_color(), alpha=0.15
        )
    for (name, rate), style in zip((references or {}).items(), ("--", ":", "-."), strict=False):
        if math.isfinite(rate):
            ax.axhline(100 * rate, color="k", ls=style, lw=1, label=f"{name}: {rate:.0%}")
    ax.set_xlabel("solves per network")
    ax.set_ylabel("grid success (%)")
    ax.set_ylim(-3, 103)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(title, fontsize=9)
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ----------------------------------------------------------------------------------------------------- report
CLOSED_LOOP_COLUMNS = (
    "policy", "episodes", "success_rate", "median_final_distance", "mean_cost", "crashes",
    "median_step_ms", "p95_step_ms", "fallback_steps",
)  # fmt: skip


def _pct(rate: float) -> str:
    return f"{rate:.0%}" if math.isfinite(rate) else "n/a"


SHIPPED_COLUMNS = (
    "controller", "episodes", "success", "median step (ms)", "p95 step (ms)", "median final distance", "mean cost",
    "fallback steps",
)  # fmt: skip
"""Columns of the report's shipped-controller table."""


def _fine_pct(rate: Any) -> str:
    """A rate as a percentage with the decimals it has (0.9925 -> ``99.25%``); n/a when missing."""
    try:
        value = float(rate)
    except (TypeError, ValueError):
        return "n/a"
    return f"{100 * value:.2f}".rstrip("0").rstrip(".") + "%" if math.isfinite(value) else "n/a"


def _ms(value: Any) -> str:
    return f"{float(value):.2f} ms" if value is not None and math.isfinite(float(value)) else "n/a"


def shipped_section(task: Task, result: Mapping[str, Any]) -> Any:
    """The report's first section: the shipped controller in closed loop beside LQR and the full-horizon MPC (the
    result of :meth:`Experiment.evaluate_shipped`), or a line saying the task has none."""
    from seagul_learn.report import Section, Table
    from seagul_learn.shipped import SHIPPED_RESULTS

    title = f"Shipped controller: {task.name} in closed loop"
    block = result.get("block")
    if block is None:
        return Section(
            title,
            [
                f"Task `{task.name}` has no shipped controller (no block with a network for it in "
                f"`{SHIPPED_RESULTS.name}` of the closed-loop benchmark, or not the registered task of that name): "
                "this report is the comparison of the learning methods only."
            ],
        )
    rows = {row["policy"]: row for row in result["rows"]}
    n1, n2 = result["grid"]["shape"]
    bench = block.get("benchmark", {})
    step = f"median {_ms(block['median_ms'])}, p95 {_ms(block['p95_ms'])}"
    jit = bool(block.get("jit"))
    if jit:
        timing = f"Step time of the shipped MPC, compiled as the benchmark deploys it: {step}."
    else:
        timing = (
            "Step time of the shipped MPC with CasADi interpreted (jit off in this run; `--shipped-jit` compiles it, "
            f"about 2 minutes of gcc on a cold cache): {step}"
            + (
                f"; compiled, the benchmark measured {_ms(bench['median_ms'])} / {_ms(bench['p95_ms'])}."
                if "median_ms" in bench and "p95_ms" in bench
                else "."
            )
        )
    headline = (
        f"**The shipped MPC manages to {task.profile.success_phrase(task)} from {_pct(block['success_rate'])} of "
        f"the {n1} x {n2} grid starts**; from the same starts LQR {_pct(block['lqr_success_rate'])} and the "
        f"full-horizon MPC {_pct(block['full_horizon_success_rate'])}. {timing}"
    )
    source = bench_text = ""
    if bench:
        heldout = bench.get("heldout_success_rate")
        bench_text = (
            f" It was trained with the task's recipe (`{bench.get('method', 'shipped')}`, "
            f"{int(bench.get('budget', 0)):,} solves) and measured by the benchmark at "
            f"{_fine_pct(bench.get('success_rate'))} of a {bench.get('grid', '?')} grid"
            + (f" and {_fine_pct(heldout)} of {bench.get('heldout_starts', '?')} held-out starts" if heldout else "")
            + "; those are the benchmark's figures, the table below is this run's."
        )
        source = f" (`benchmarks/results/{SHIPPED_RESULTS.name}`, its `{task.name}` block)"
    deployment = (
        f"The controller: {result['deployment']}, deployed as the closed-loop benchmark's results say{source}, "
        f"{'compiled' if jit else 'with jit off'}.{bench_text} Starts: the report's {n1} x {n2} reference grid over "
        f"({', '.join(result['grid']['dims'])}), where the full-horizon MPC (it solves the whole problem at every "
        "step, so it runs on the coarser grid only) is evaluated for the comparison below too. Success: "
        f"{task.profile.describe_success(task)}."
    )
    table = Table(
        list(SHIPPED_COLUMNS),
        [
            [
                name,
                row["episodes"],
                _pct(row["success_rate"]),
                row["median_step_ms"],
                row["p95_step_ms"],
                row["median_final_distance"],
                row["mean_cost"],
                row["fallback_steps"],
            ]
            for name, row in rows.items()
        ],
    )
    animation = result["animation"]
    outcome = ", ".join(
        f"{e['policy']} {'succeeds' if e['success'] else 'fails'} (cost {e['cost']:.1f})" for e in animation["episodes"]
    )
    start = ", ".join(f"{name} = {value:.3g}" for name, value in zip(task.state_names, animation["start"], strict=True))
    caption = f"The shipped MPC and LQR from the hard corner of X0 ({start}), in real time: {outcome}."
    return Section(title, [headline, deployment], [table], [(animation["path"], caption)])


def comparison_title(preset: str, budget: int, seeds: int) -> str:
    """Heading of the report's part that compares the learning methods (never the shipped recipe)."""
    size = "Quick equal-budget" if preset == "quick" else "Equal-budget"
    return f"{size} comparison of the samplers ({budget} solves per network, {seeds} seeds): not the shipped recipe"


def comparison_intro(task: Task, preset: Preset) -> str:
    """What the comparison measures and how it differs from the shipped controller."""
    names = ", ".join(method_label(m) for m in preset.methods)
    recipe = task.profile.train_recipe
    shipped = ""
    if "budget" in recipe:
        hidden = recipe.get("hidden")
        shipped = (
            " The shipped network comes from the task's recipe (`TrainConfig.recipe`: "
            f"{int(recipe['budget']):,} solves, `{recipe.get('sampler', 'uniform')}` sampler"
            + (f", hidden layers {tuple(hidden)}" if hidden else "")
            + "); these networks are the library's default size, trained on the preset's schedule."
        )
    return (
        f"Everything below compares the ways of learning the value function ({names}) at one small, equal budget: "
        f"{preset.budget} solves per network over {preset.seeds} paired seeds, each network deployed in a "
        f"{preset.mpc_horizon}-step MPC with IPOPT and the `lqr` guard. It ranks the samplers against each other "
        f"at this budget; it does not measure the shipped controller above.{shipped}"
    )


def learning_headline(learning: Mapping[str, Any], methods: Sequence[str], budget: int, seeds: int) -> str:
    """One paragraph: each method's validation error relative to the uniform baseline, on both metrics."""
    parts = []
    for metric in METRICS:
        what = "at the starts (`mse_initial`)" if metric == "mse_initial" else f"over every per-knot label (`{metric}`)"
        items = []
        for m in methods:
            if m == BASELINE_METHOD:
                continue
            c = PairedComparison(**learning[metric]["vs_uniform"][m])
            items.append(
                f"{method_label(m)} **{c.ratio_median:.2f}x** (better on {c.win_fraction:.0%} of seeds, Wilcoxon "
                f"p = {c.p_value:.3g})"
            )
        parts.append(f"{what}: " + ", ".join(items))
    return (
        f"At {budget} solves per network over {seeds} paired seeds, validation error relative to the uniform "
        "baseline (median of per-seed ratios) " + "; ".join(parts) + "."
    )


def closed_loop_headline(
    task: Task | str, methods: Mapping[str, Mapping[str, Any]], baselines: Mapping[str, float], seeds: int
) -> str:
    """One paragraph: each method's closed-loop success (median over seeds with the range), query error, baselines
    (what success means comes from the task's ``profile.success_phrase``)."""
    task = resolve_task(task)
    what = task.profile.success_phrase(task)
    rates = ", ".join(
        f"{s['policy']} **{_pct(s['success_median'])}** ({_pct(s['success_min'])}-{_pct(s['success_max'])})"
        for s in methods.values()
    )
    others = ", ".join(f"{name} {_pct(rate)}" for name, rate in baselines.items())
    errors = ", ".join(
        f"{s['label']} {s['query_error']['median']:.3g} (p95 {s['query_error']['p95']:.3g})" for s in methods.values()
    )
    return (
        f"Closed loop: fraction of grid starts from which each controller manages to {what}, median over {seeds} "
        f"seeds (range): {rates}; {others} (the full-horizon MPC on the reference grid). Planner-query error "
        f"|Vhat - V| at the MPC's planned terminal states (median over seeds): {errors}."
    )


def method_rows(methods: Mapping[str, Mapping[str, Any]], learning: Mapping[str, Any]) -> list[list[Any]]:
    """Report rows: method, success median, q25-q75, per seed, query error median and p95, validation MSE median."""
    rows = []
    for m, s in methods.items():
        rows.append(
            [
                s["policy"],
                _pct(s["success_median"]),
                f"{_pct(s['success_q25'])}-{_pct(s['success_q75'])}",
                ", ".join(_pct(v) for v in s["success"]),
                float(s["query_error"]["median"]),
                float(s["query_error"]["p95"]),
                float(np.median(learning["mse_all_knots"][m])),
            ]
        )
    return rows


def paired_rows(methods: Mapping[str, Mapping[str, Any]]) -> list[list[Any]]:
    """Report rows of the paired success tests against the closed-loop method."""
    rows = []
    for s in methods.values():
        c = s.get("vs_closed_loop")
        if c is not None:
            vs = methods[REFERENCE_METHOD]["policy"]
            rows.append([s["policy"], vs, f"{c['median_difference']:+.0%}", c["wins"], c["losses"], c["p_value"]])
    return rows


def comparison_rows(learning: Mapping[str, Any], methods: Sequence[str]) -> list[list[Any]]:
    """Report table rows per metric and method: medians of the method and the baseline, ratio, wins, p."""
    rows = []
    for metric in METRICS:
        block = learning[metric]
        for m in methods:
            if m == BASELINE_METHOD:
                continue
            c = PairedComparison(**block["vs_uniform"][m])
            rows.append(
                [
                    metric,
                    method_label(m),
                    float(np.median(block[m])),
                    float(np.median(block[BASELINE_METHOD])),
                    c.ratio_median,
                    f"{c.win_fraction:.0%}",
                    c.p_value,
                ]
            )
    return rows
