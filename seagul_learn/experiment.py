"""The paper's experiment end to end (``seagul reproduce``): validation set, SEAGuL vs uniform training over paired
seeds, closed-loop MPC evaluation of both networks next to LQR and the full-horizon MPC, and a report.

Every stage writes its results into the run directory before the next starts, and a finished stage is never run
again: training runs checkpoint after each round (``seagul_learn.training``), solves are cached on disk, and the
closed-loop table of each policy is stored as soon as it is complete. So Ctrl-C (or SIGKILL) at any moment leaves a
run that ``seagul reproduce TASK --resume DIR`` finishes with the same numbers.

Presets (one place for every number of the experiment; the paper's settings are §6 of the paper):

* ``quick`` — the README's main job; the acrobot finishes in about ten minutes on 2 cores. Fewer seeds, a smaller
  budget and a coarser closed-loop grid than the paper, same algorithms.
* ``smoke`` — seconds of work past the validation set: checks the whole pipeline (tests, CI), says nothing.
* ``paper`` — acrobot: 100 solves per network, 10 solves every 500 training steps (10,000 steps), 10 paired seeds,
  a 20 x 20 closed-loop grid; glider: the same schedule with its own grid.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from seagul_envs import available_tasks, make_task
from seagul_learn.comparison import (
    METRICS,
    PairedComparison,
    final_metric,
    paired_comparison,
    plot_curves_with_band,
)
from seagul_learn.dataset import atomic_write_text

SAMPLER_NAMES = ("uniform", "adversarial")


@dataclass(frozen=True)
class Preset:
    """The numbers of one experiment size (everything else is the library's defaults)."""

    seeds: int
    """Paired seeds (each trains one uniform and one adversarial network from identical initial parameters)."""
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
    """Lookahead steps of the limited-lookahead MPC."""


PRESETS: dict[str, dict[str, Preset]] = {
    "acrobot": {
        "smoke": Preset(
            seeds=2,
            budget=4,
            solves_per_round=2,
            train_steps_per_round=20,
            grid_points=2,
            reference_grid_points=1,
            mpc_horizon=3,
        ),
        "quick": Preset(
            seeds=4,
            budget=60,
            solves_per_round=10,
            train_steps_per_round=500,
            grid_points=10,
            reference_grid_points=5,
            mpc_horizon=5,
        ),
        "paper": Preset(
            seeds=10,
            budget=100,
            solves_per_round=10,
            train_steps_per_round=500,
            grid_points=20,
            reference_grid_points=10,
            mpc_horizon=5,
        ),
    },
    "glider": {
        "smoke": Preset(
            seeds=2,
            budget=2,
            solves_per_round=2,
            train_steps_per_round=20,
            grid_points=1,
            reference_grid_points=1,
            mpc_horizon=5,
        ),
        "quick": Preset(
            seeds=3,
            budget=40,
            solves_per_round=10,
            train_steps_per_round=500,
            grid_points=4,
            reference_grid_points=3,
            mpc_horizon=10,
        ),
        "paper": Preset(
            seeds=10,
            budget=100,
            solves_per_round=10,
            train_steps_per_round=500,
            grid_points=6,
            reference_grid_points=4,
            mpc_horizon=10,
        ),
    },
}


@dataclass
class ExperimentConfig:
    """One ``seagul reproduce`` run."""

    task: str = "acrobot"
    """Task name."""
    preset: str = "quick"
    """``"quick"`` or ``"paper"`` (see :data:`PRESETS`)."""
    seeds: int | None = None
    """Override of the preset's number of paired seeds."""
    workers: int = 1
    """Parallel processes (training runs and closed-loop episodes; results do not depend on it)."""
    backend: str = "local"
    """``"local"`` or ``"ray"`` for the solves."""
    ppo_model: str | None = None
    """Optional saved stable-baselines3 PPO model to evaluate next to the MPCs."""
    progress: bool = True
    """Show progress bars."""

    def validate(self) -> None:
        """Raise a ValueError naming the first bad field."""
        if self.task not in available_tasks():
            raise ValueError(f"unknown task {self.task!r}; available tasks: {available_tasks()}")
        if self.preset not in PRESETS[self.task]:
            raise ValueError(f"unknown preset {self.preset!r}; choose one of {sorted(PRESETS[self.task])}")
        if self.seeds is not None and self.seeds < 1:
            raise ValueError(f"seeds must be >= 1, got {self.seeds}")
        if self.workers < 1:
            raise ValueError(f"workers must be >= 1, got {self.workers}")
        if self.backend not in ("local", "ray"):
            raise ValueError(f"unknown backend {self.backend!r}; choose 'local' or 'ray'")
        if self.ppo_model is not None and not Path(self.ppo_model).exists():
            raise FileNotFoundError(f"PPO model {self.ppo_model!r} does not exist")

    def resolve(self) -> Preset:
        """The preset with this run's overrides."""
        preset = PRESETS[self.task][self.preset]
        if self.seeds is not None:
            preset = replace(preset, seeds=self.seeds)
        return preset


class Experiment:
    """A run directory and its stages; see the module docstring."""

    def __init__(self, config: ExperimentConfig, out: Path) -> None:
        self.config = config
        self.out = Path(out)
        self.preset = config.resolve()
        self.task = make_task(config.task)
        self.state_path = self.out / "experiment.json"
        self.timings: dict[str, float] = {}
        if self.state_path.is_file():
            stored = json.loads(self.state_path.read_text())
            self.timings = {k: float(v) for k, v in stored.get("timings", {}).items()}

    # ------------------------------------------------------------------------------------------------ creation
    @classmethod
    def create(cls, config: ExperimentConfig, out: Path | None = None) -> Experiment:
        """A new run directory (default ``runs/<task>-<timestamp>``)."""
        config.validate()
        if out is None:
            stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
            out = Path("runs") / f"{config.task}-{stamp}"
        out = Path(out)
        if (out / "experiment.json").exists():
            raise FileExistsError(f"{str(out)!r} already holds an experiment; use --resume {out} to continue it")
        out.mkdir(parents=True, exist_ok=True)
        experiment = cls(config, out)
        experiment._save_state()
        return experiment

    @classmethod
    def resume(cls, out: Path, workers: int | None = None, progress: bool = True) -> Experiment:
        """Reopen an interrupted run (its stored configuration wins; only ``workers``/``progress`` may change)."""
        path = Path(out) / "experiment.json"
        if not path.is_file():
            raise FileNotFoundError(f"{str(out)!r} holds no seagul experiment (no experiment.json)")
        try:
            stored = json.loads(path.read_text())
            config = ExperimentConfig(**stored["config"])
        except (ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"{str(path)!r} is not a valid experiment file ({exc})") from exc
        if workers is not None:
            config.workers = workers
        config.progress = progress
        config.validate()
        return cls(config, Path(out))

    def _save_state(self) -> None:
        payload = {
            "config": asdict(self.config),
            "settings": asdict(self.preset),
            "timings": self.timings,
        }
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
        self._timed("validation set", self.validation_set)
        runs = self._timed("training", self.train_all)
        learning = self._timed("comparison", lambda: self.compare(runs))
        closed_loop = self._timed("closed-loop evaluation", self.evaluate_closed_loop)
        self.timings.setdefault("total", time.perf_counter() - start)
        report = self.write_report(runs, learning, closed_loop)
        self._save_state()
        return report

    def _solver_cache(self) -> Path:
        return self.out / "cache" / "solves"

    def validation_set(self) -> int:
        """Solve (or load from the shared cache) the task's validation set; returns its size."""
        from seagul_learn.solving import solver_key, trajopt_batch_solver
        from seagul_learn.training import default_cache_dir, validation_dataset

        solver = trajopt_batch_solver(self.task.name, workers=self.config.workers, backend=self.config.backend)
        records = validation_dataset(
            self.task, solver, solver_key(None), default_cache_dir(), self.config.workers, self.config.progress
        )
        failures = sum(not r.success for r in records)
        atomic_write_text(
            self.out / "validation.json", json.dumps({"solves": len(records), "failures": failures}, indent=2)
        )
        return len(records)

    def train_configs(self) -> list[Any]:
        """One :class:`~seagul_learn.training.TrainConfig` per (seed, sampler)."""
        from seagul_learn.training import TrainConfig

        p = self.preset
        return [
            TrainConfig(
                task=self.task.name,
                sampler=sampler,
                budget=p.budget,
                solves_per_round=p.solves_per_round,
                train_steps_per_round=p.train_steps_per_round,
                seed=seed,
                progress=False,
            )
            for seed in range(p.seeds)
            for sampler in SAMPLER_NAMES
        ]

    def run_dir(self, sampler: str, seed: int) -> Path:
        """Where one training run lives."""
        return self.out / "train" / f"{sampler}-seed{seed}"

    def train_all(self) -> dict[str, list[dict[str, Any]]]:
        """Train every (seed, sampler) run not finished yet; returns the metrics per sampler, by seed."""
        from joblib import Parallel, delayed
        from tqdm.auto import tqdm

        configs = self.train_configs()
        todo = [c for c in configs if not (self.run_dir(c.sampler, c.seed) / "metrics.json").is_file()]
        if todo:
            jobs = (delayed(_train_one)(c, self.run_dir(c.sampler, c.seed), self._solver_cache()) for c in todo)
            bar = tqdm(
                total=len(configs),
                initial=len(configs) - len(todo),
                desc="training runs",
                disable=not self.config.progress,
            )
            if self.config.backend == "ray" or self.config.workers == 1:
                # Ray parallelises the solves inside each run; locally with one worker there is nothing to spread.
                for config in todo:
                    _train_one(
                        config,
                        self.run_dir(config.sampler, config.seed),
                        self._solver_cache(),
                        workers=self.config.workers,
                        backend=self.config.backend,
                    )
                    bar.update(1)
            else:
                for _ in Parallel(n_jobs=self.config.workers, return_as="generator_unordered")(jobs):
                    bar.update(1)
            bar.close()
        runs: dict[str, list[dict[str, Any]]] = {s: [] for s in SAMPLER_NAMES}
        for c in configs:
            runs[c.sampler].append(json.loads((self.run_dir(c.sampler, c.seed) / "metrics.json").read_text()))
        return runs

    def compare(self, runs: dict[str, list[dict[str, Any]]]) -> dict[str, Any]:
        """Paired statistics at the full budget, and the validation-curve figure."""
        out: dict[str, Any] = {}
        for metric in METRICS:
            adversarial = final_metric(runs["adversarial"], metric)
            uniform = final_metric(runs["uniform"], metric)
            out[metric] = {
                "adversarial": adversarial,
                "uniform": uniform,
                "comparison": asdict(paired_comparison(adversarial, uniform)),
            }
        out["failures"] = {s: int(sum(r["metrics"][-1]["failures"] for r in runs[s])) for s in SAMPLER_NAMES}
        out["train_steps"] = int(runs["uniform"][0]["metrics"][-1]["train_steps"])
        plot_curves_with_band(
            runs,
            self.out / "validation_curves.png",
            title=f"{self.task.name}: validation MSE vs solves (median, 25-75 % band over {self.preset.seeds} seeds)",
        )
        atomic_write_text(self.out / "learning.json", json.dumps(out, indent=2, allow_nan=True))
        return out

    def policy_specs(self) -> tuple[list[Any], list[Any]]:
        """``(main, reference)``: the policies run on the main grid, and those (expensive) on the coarser grid.

        The learned MPCs use the seed-0 networks of both samplers (same seed, same initial parameters), so the
        comparison is paired like the learning curves.
        """
        from seagul_control.evaluation import PolicySpec

        horizon = (("horizon", self.preset.mpc_horizon),)
        main = [
            PolicySpec("mpc", "SEAGuL MPC", str(self.run_dir("adversarial", 0) / "network.pt"), horizon),
            PolicySpec("mpc", "uniform MPC", str(self.run_dir("uniform", 0) / "network.pt"), horizon),
            PolicySpec("lqr", "LQR"),
        ]
        if self.config.ppo_model:
            main.append(PolicySpec("sb3", "PPO", self.config.ppo_model))
        reference = [PolicySpec("full", "full-horizon MPC")]
        return main, reference

    def _episodes(self, spec: Any, starts: np.ndarray, record: bool) -> list[Any]:
        """One policy's episodes, from its stored table if a previous (interrupted) run finished it."""
        from seagul_control.evaluation import EpisodeResult, evaluate

        slug = "".join(ch if ch.isalnum() else "-" for ch in spec.name.lower())
        path = self.out / "closed_loop" / "episodes" / f"{slug}.json"
        if path.is_file():
            return [EpisodeResult(**row) for row in json.loads(path.read_text())]
        results = evaluate(self.task.name, [spec], starts, self.config.workers, self.config.progress, record)
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, json.dumps([asdict(r) for r in results], allow_nan=True))
        return results

    def evaluate_closed_loop(self) -> dict[str, Any]:
        """Closed-loop runs of every policy over the start grids (each policy's episodes stored when complete)."""
        from seagul_control.evaluation import start_grid, summarize, write_outputs

        record = self.task.name == "glider"  # the glider's trajectories are plotted (paper Fig. 3 centre)
        main_specs, reference_specs = self.policy_specs()
        starts, grid = start_grid(self.task, self.preset.grid_points)
        ref_starts, ref_grid = start_grid(self.task, self.preset.reference_grid_points)
        main_results = [r for spec in main_specs for r in self._episodes(spec, starts, record)]
        ref_results = [r for spec in reference_specs for r in self._episodes(spec, ref_starts, record)]
        # The learned MPCs on the reference grid too, so every success rate can be compared on the same starts.
        ref_learned = [
            r for spec in main_specs[:2] for r in self._episodes(_relabel(spec, " (reference grid)"), ref_starts, False)
        ]
        main_paths = write_outputs(self.out / "closed_loop" / "main", self.task.name, main_results, grid)
        ref_paths = write_outputs(
            self.out / "closed_loop" / "reference", self.task.name, ref_results + ref_learned, ref_grid
        )
        rows = summarize(self.task.name, main_results) + summarize(self.task.name, ref_results + ref_learned)
        figures = [(str(main_paths["heatmap"].relative_to(self.out)), _heatmap_caption(self.task.name, grid))]
        figures.append((str(ref_paths["heatmap"].relative_to(self.out)), "The same on the coarser reference grid"))
        if "trajectories" in main_paths:
            figures.append((str(main_paths["trajectories"].relative_to(self.out)), "Glider trajectories (Fig. 3)"))
        summary = {"policies": rows, "grid": grid, "reference_grid": ref_grid}
        atomic_write_text(self.out / "closed_loop" / "summary.json", json.dumps(summary, indent=2, allow_nan=True))
        return {"rows": rows, "figures": figures}

    def write_report(self, runs: dict[str, Any], learning: dict[str, Any], closed_loop: dict[str, Any]) -> Path:
        """``report.md`` and ``report.html`` with the figures, tables, settings, timings and versions."""
        from seagul_learn.report import Section, Table, library_versions, machine_description, write_report

        p = self.preset
        c_initial = PairedComparison(**learning["mse_initial"]["comparison"])
        c_all = PairedComparison(**learning["mse_all_knots"]["comparison"])
        validation = json.loads((self.out / "validation.json").read_text())
        headline = (
            f"At {p.budget} solves per network over {p.seeds} paired seeds, SEAGuL's validation error at the "
            f"starts (`mse_initial`) is **{c_initial.ratio_median:.2f}x** the uniform baseline's (median of per-seed "
            f"ratios; adversarial better on {c_initial.win_fraction:.0%} of seeds, Wilcoxon p = "
            f"{c_initial.p_value:.3g}); over every per-knot label (`mse_all_knots`) the ratio is "
            f"**{c_all.ratio_median:.2f}x** (better on {c_all.win_fraction:.0%} of seeds, p = {c_all.p_value:.3g})."
        )
        sections = [
            Section("Summary", [headline, closed_loop_headline(self.task.name, closed_loop["rows"])]),
            Section(
                "Value-function learning (paper Fig. 1 / Fig. 3 left)",
                [
                    "Both samplers start from identical network parameters (pretrained on the same random solves), "
                    "spend the same number of solves and take the same number of training steps "
                    f"({learning['train_steps']} after pretraining); adversarial chains start from the uniform "
                    "baseline's starts. Validation: "
                    f"{validation['solves']} solves ({validation['failures']} failed and are excluded).",
                ],
                [
                    Table(
                        [
                            "metric",
                            "adversarial (median)",
                            "uniform (median)",
                            "ratio (median per seed)",
                            "adversarial wins",
                            "Wilcoxon p",
                        ],
                        comparison_rows(learning),
                    )
                ],
                [("validation_curves.png", "Validation MSE vs solves: median and 25-75 % band over seeds")],
            ),
            Section(
                "Closed loop (paper Fig. 2 / Fig. 3 centre / Fig. 4)",
                [
                    f"Limited-lookahead MPC with {p.mpc_horizon} steps and each sampler's seed-0 network as terminal "
                    "cost, next to clipped LQR"
                    + (", PPO" if self.config.ppo_model else "")
                    + " and the full-horizon MPC (on a coarser grid: it solves the whole problem at every step). "
                    "Step times are per MPC solve inside the closed loop; fallback steps are steps whose action did "
                    "not come from a converged solve.",
                ],
                [
                    Table(
                        list(CLOSED_LOOP_COLUMNS),
                        [[row.get(c, "") for c in CLOSED_LOOP_COLUMNS] for row in closed_loop["rows"]],
                    )
                ],
                closed_loop["figures"],
            ),
            Section(
                "Solver failures",
                [
                    f"Failed training solves (counted against the budget, never trained on): "
                    f"adversarial {learning['failures']['adversarial']}, uniform {learning['failures']['uniform']}."
                ],
            ),
            Section(
                "Settings",
                [
                    f"Task `{self.task.name}`, preset `{self.config.preset}`, workers {self.config.workers}, "
                    f"backend `{self.config.backend}`. Run directory: `{self.out}`."
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
        return write_report(self.out, f"SEAGuL vs uniform sampling: {self.task.name}", sections)


def _train_one(config: Any, out: Path, cache: Path, workers: int = 1, backend: str = "local") -> None:
    """One training run behind the experiment's bit-exact solve cache (runs in a worker process)."""
    import torch

    from seagul_learn.solving import CachedBatchSolver, solver_key, trajopt_batch_solver
    from seagul_learn.training import train

    torch.set_num_threads(1)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    key = solver_key(None)
    solver = CachedBatchSolver(trajopt_batch_solver(config.task, workers=workers, backend=backend), cache, key)
    config = replace(config, workers=workers, backend=backend)
    train(config, out, resume=(out / "config.json").is_file(), batch_solver=solver, solver_name=key)


CLOSED_LOOP_COLUMNS = (
    "policy", "episodes", "success_rate", "median_final_distance", "mean_cost", "crashes",
    "median_step_ms", "p95_step_ms", "fallback_steps",
)  # fmt: skip


def closed_loop_headline(task_name: str, rows: list[dict[str, Any]]) -> str:
    """One sentence with every policy's success rate."""
    what = "reach the goal (||x(5 s) - x*|| < 0.05)" if task_name == "acrobot" else "perch"
    rates = ", ".join(f"{row['policy']} {row['success_rate']:.0%}" for row in rows)
    return f"Closed loop: fraction of grid starts from which each controller manages to {what}: {rates}."


def _relabel(spec: Any, suffix: str) -> Any:
    return replace(spec, label=spec.name + suffix)


def _heatmap_caption(task_name: str, grid: dict[str, Any]) -> str:
    n1, n2 = grid["shape"]
    if task_name == "acrobot":
        return f"Final distance to the goal after 5 s over a {n1} x {n2} grid of (th1, th2) at zero velocity (Fig. 2)"
    return f"Trajectory cost over a {n1} x {n2} grid of (x, z) starts (Fig. 4)"


def comparison_rows(learning: dict[str, Any]) -> list[list[Any]]:
    """Report table rows: metric, median adversarial, median uniform, ratio, wins, p."""
    rows = []
    for metric in METRICS:
        block = learning[metric]
        c = PairedComparison(**block["comparison"])
        rows.append(
            [
                metric,
                float(np.median(block["adversarial"])),
                float(np.median(block["uniform"])),
                c.ratio_median,
                f"{c.win_fraction:.0%}",
                c.p_value,
            ]
        )
    return rows
