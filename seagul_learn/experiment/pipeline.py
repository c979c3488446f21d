"""The experiment pipeline: methods x seeds x budget snapshots, training, closed-loop evaluation of every snapshot
on the start grids, the planner-query error, the shipped controller's evaluation and resume
(:class:`Experiment`, ``seagul reproduce``). Its training runs go through
:func:`~seagul_learn.experiment.runs.train_runs`, as the closed-loop benchmark's
(:mod:`seagul_learn.experiment.benchmark`) do.

See :mod:`seagul_learn.experiment` for the stages, their files and how a run resumes.
"""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from seagul_envs import Task, available_tasks
from seagul_envs.tasks import task_label
from seagul_learn.comparison import METRICS, final_metric, paired_comparison, plot_curves_with_band
from seagul_learn.dataset import atomic_write_text
from seagul_learn.experiment import closed_loop_stage
from seagul_learn.experiment.config import BASELINE_METHOD, ExperimentConfig, method_label, policy_label
from seagul_learn.experiment.methods import SHIPPED_METHOD, shipped_recipe, train_config, train_field_names
from seagul_learn.experiment.runs import deployment_options, network_spec, train_runs
from seagul_learn.experiment.sections import experiment_sections
from seagul_learn.shipped import shipped_network


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

        The closed-loop method's collecting MPC has the deployed horizon (``mpc_horizon``) and guard unless the
        preset says otherwise; the other samplers ignore the ``cl_*`` fields. ``shipped`` is the task's recipe
        (``TrainConfig.recipe``) on the run's schedule (the recipe's own:
        :func:`~seagul_learn.experiment.config.recipe_schedule`) with the preset's per-method overrides of
        ``shipped``, if any.
        """
        p = self.preset
        overrides = p.train_fields(method)
        unknown = sorted(set(overrides) - train_field_names())
        if unknown:
            raise ValueError(f"preset train_overrides / METHODS[{method!r}] name unknown TrainConfig fields {unknown}")
        schedule: dict[str, Any] = {
            "budget": p.budget,
            "solves_per_round": p.solves_per_round,
            "train_steps_per_round": p.train_steps_per_round,
            "seed": seed,
            "snapshots": p.budgets,
            "progress": False,
        }
        if method == SHIPPED_METHOD:
            return shipped_recipe(self.task, **{**schedule, **overrides})
        base: dict[str, Any] = {
            "task": self.task,
            **schedule,
            "cl_horizon": p.mpc_horizon,
            # The closed-loop method collects with the guard the experiment deploys (deployment()).
            "cl_trust_region": dict(self.deployment())["trust_region"],
        }
        return train_config(**{**base, **overrides})

    def deployment(self) -> tuple[tuple[str, Any], ...]:
        """``LimitedLookaheadMPC`` options every learned network is evaluated with: the preset's horizon, IPOPT and
        the ``lqr`` guard; a run with ``shipped`` deploys as the closed-loop benchmark measured the recipe (the
        task's guard ``profile.mpc.trust_region`` and goal blend, the MPC's default solver).

        IPOPT, not fatrop: fatrop can loop without end inside a single solve from a shifted warm start at an extreme
        state (docs/experiments/closed-loop.md); IPOPT's max_iter bounds every solve. Its steps are slower, so step
        times here are IPOPT's. The "lqr" guard, explicitly: the presets' networks (30-100 solves) are not the
        shipped recipe's, and the task's default guard ("none" for the built-ins) is measured on the recipe's
        networks.
        """
        horizon = self.preset.mpc_horizon
        if SHIPPED_METHOD in self.preset.methods:
            profile = self.task.profile
            return deployment_options(horizon, profile.mpc.trust_region, float(profile.mpc.goal_blend))
        return deployment_options(horizon, "lqr", solver="ipopt")

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
        jobs = [(config, self.run_dir(method, config.seed)) for method, config in todo]
        train_runs(
            jobs,
            workers=self.config.workers,
            backend=self.config.backend,
            cache=self._solver_cache(),
            progress=self.config.progress,
            total=total,
        )

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
        from seagul_learn.experiment.shipped_stage import measure_shipped

        return measure_shipped(self)

    # --------------------------------------------------------------------------------------------- closed loop
    def learned_policies(self) -> list[LearnedPolicy]:
        """Every snapshot network of every (method, seed) run as a limited-lookahead MPC, by method, seed, budget
        (:func:`~seagul_learn.experiment.runs.network_spec`, deployed as :meth:`deployment` says)."""
        p = self.preset
        horizon = self.deployment()
        out = []
        for method in p.methods:
            for seed in range(p.seeds):
                for budget in p.budgets:
                    final = budget == p.budget
                    label = policy_label(method, seed, None if final else budget)
                    path = str(self.network_path(method, seed, budget))
                    out.append(LearnedPolicy(method, seed, budget, final, network_spec(label, path, horizon)))
        return out

    def baseline_specs(self) -> tuple[list[Any], list[Any]]:
        """``(main, reference)``: LQR and the SB3 models (:meth:`ExperimentConfig.sb3_policies`) on the main grid;
        the (expensive) full-horizon MPC on the coarse one."""
        from seagul_control.evaluation import PolicySpec

        main = [PolicySpec("lqr", "LQR")]
        for label, path, algo in self.config.sb3_policies():
            main.append(PolicySpec("sb3", label, path, (("algo", algo),)))
        return main, [PolicySpec("full", "full-horizon MPC")]

    def evaluate_closed_loop(self) -> dict[str, Any]:
        """Closed-loop runs of every network and baseline over the start grids, the per-method statistics, figures
        (:func:`~seagul_learn.experiment.closed_loop_stage.evaluate_closed_loop`).

        Writes ``closed_loop/summary.json`` (``policies``: one row per policy and grid; ``methods``: see
        :func:`~seagul_learn.experiment.statistics.method_statistics`, with each final network's held-out success;
        the grids, budgets and the number of held-out starts) and ``success_vs_solves.png``.
        """
        return closed_loop_stage.evaluate_closed_loop(self)

    def evaluate_other_envs(self) -> dict[str, Any]:
        """Every final network of every seed, LQR and the SB3 models on the main grid in each of ``config.envs``
        (:func:`~seagul_learn.experiment.closed_loop_stage.evaluate_other_envs`); writes
        ``closed_loop/other_envs.json``."""
        return closed_loop_stage.evaluate_other_envs(self)

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
        versions (:func:`~seagul_learn.experiment.sections.experiment_sections`)."""
        from seagul_learn.report import write_report

        sections = experiment_sections(self, learning, closed_loop, shipped)
        title = f"Learned value functions as MPC terminal costs: {self.task.name}"
        return write_report(self.out, title, sections)
