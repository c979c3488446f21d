"""Sample efficiency of SEAGuL vs the uniform baseline, with and without Sobolev training, over paired seeds.

Usage::

    .venv/bin/python benchmarks/bench_sample_efficiency.py [--quick] [--tasks acrobot glider] [--seeds N]
        [--budget B] [--train-steps-per-round S] [--workers N] [--out DIR]

For every task and seed it trains four variants from the SAME pretrained network (same seed) and the same baseline
starts: ``uniform``, ``adversarial``, ``uniform+sobolev`` and ``adversarial+sobolev`` (plus any ``--extra`` adversarial
variants), at equal budgets and training steps. Solves are cached on disk (bit-exact requests), so the uniform
starts, the shared pretraining set and the chains' first iterates are solved once per seed. Runs are resumable:
rerunning with the same ``--out`` skips finished runs.

Printed last: one JSON object ``{"acrobot": {...}, "glider": {...}}`` with, per task, ``seeds``, ``budget``,
``mse_adversarial`` and ``mse_uniform`` (``mse_initial`` per seed at the full budget), ``ratio_median`` (median
over seeds of the per-seed ratio adversarial/uniform on ``mse_initial``), ``adversarial_win_fraction``,
``ratio_median_all_knots`` (same on ``mse_all_knots``), ``sobolev_ratio_median`` (uniform+Sobolev / uniform on
``mse_all_knots``) and ``adversarial_sobolev_ratio_median`` (adversarial+Sobolev / uniform on ``mse_all_knots``),
each with a two-sided Wilcoxon signed-rank p-value on the paired log-MSEs (``*_p``), and the settings used.
A PNG per task shows both metrics vs solves (median over seeds, 25-75 % band).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from joblib import Parallel, delayed

from seagul_learn.comparison import paired_comparison, plot_curves_with_band
from seagul_learn.experiment.methods import METHODS, train_config
from seagul_learn.solving import BatchSolver, CachedBatchSolver, solver_key
from seagul_learn.training import TrainConfig, train, validation_dataset

# Variants: name -> overrides of the task's base TrainConfig (the four samplers are the library's methods, the same
# settings as in seagul reproduce and the closed-loop benchmark).
ADVERSARIAL_DEFAULT: dict[str, Any] = dict(METHODS["adversarial"])
VARIANTS: dict[str, dict[str, Any]] = {
    name: dict(METHODS[name]) for name in ("uniform", "adversarial", "uniform+sobolev", "adversarial+sobolev")
}
EXTRA_VARIANTS: dict[str, dict[str, Any]] = {
    "adversarial-reflect": {"sampler": "adversarial", "adv_projection": "reflect"},
    "adversarial-mix": {"sampler": "adversarial", "adv_projection": "reflect", "adv_uniform_fraction": 0.5},
    "adversarial-adam": {"sampler": "adversarial", "adv_optimizer": "adam"},
    "adversarial-short": {"sampler": "adversarial", "adv_max_steps": 2, "adv_step_fraction": 0.2},
    "adversarial-stop": {"sampler": "adversarial", "adv_projection": "reflect", "adv_stop_on_decrease": True},
    "adversarial-notau": {"sampler": "adversarial", "adv_ascend_tau": False},
    "adversarial-stopmix": {
        "sampler": "adversarial",
        "adv_projection": "reflect",
        "adv_stop_on_decrease": True,
        "adv_uniform_fraction": 0.3,
    },
}


@dataclass
class Settings:
    """Benchmark settings (one per invocation)."""

    tasks: list[str]
    seeds: int
    budget: int
    train_steps_per_round: int
    workers: int
    out: Path
    extra: list[str]
    sobolev_weight: float


def make_solver(task: str, cache: Path) -> BatchSolver:
    """The real solver behind a bit-exact result cache (one process solves; benchmark jobs run in parallel)."""
    try:
        from seagul_learn.solving import trajopt_batch_solver

        inner = trajopt_batch_solver(task, workers=1, backend="local", progress=False)
    except ImportError:  # parallel.py not available: solve sequentially in this process
        from seagul_learn.trajopt import TrajectoryOptimizer

        optimizer = TrajectoryOptimizer(task)

        def inner(starts: np.ndarray, taus: np.ndarray) -> list:
            return [optimizer.solve(x, t) for x, t in zip(starts, taus, strict=True)]

    return CachedBatchSolver(inner, cache / f"solves-{task}", solver_key(None))


def run_one(config: TrainConfig, out: Path, cache: Path) -> dict[str, Any]:
    """Train (or load a finished) run; returns its metrics rows."""
    metrics_file = out / "metrics.json"
    if metrics_file.is_file():
        return json.loads(metrics_file.read_text())
    import torch

    torch.set_num_threads(1)
    solver = make_solver(config.task, cache)
    train(config, out, resume=True, batch_solver=solver, solver_name=solver_key(config.solver_options))
    return json.loads(metrics_file.read_text())


def base_config(task: str, settings: Settings) -> TrainConfig:
    """The paper preset (10 solves and 500 training steps per round) with this benchmark's budget."""
    return train_config(
        task=task,
        budget=settings.budget,
        solves_per_round=10,
        train_steps_per_round=settings.train_steps_per_round,
        progress=False,
        cache_dir=str(settings.out / "cache"),
    )


def paired(num: list[float], den: list[float]) -> tuple[float, float, float]:
    """(median ratio, win fraction num < den, Wilcoxon p on log values) over paired seeds."""
    c = paired_comparison(num, den)
    return c.ratio_median, c.win_fraction, c.p_value


def summarise(task: str, settings: Settings, results: dict[str, list[dict[str, Any]]]) -> dict[str, Any]:
    """The JSON block of one task."""
    final = {name: [runs["metrics"][-1] for runs in rows] for name, rows in results.items()}

    def col(name: str, key: str) -> list[float]:
        return [m[key] for m in final[name]]

    ratio, wins, p = paired(col("adversarial", "mse_initial"), col("uniform", "mse_initial"))
    ratio_all, wins_all, p_all = paired(col("adversarial", "mse_all_knots"), col("uniform", "mse_all_knots"))
    sob, sob_wins, sob_p = paired(col("uniform+sobolev", "mse_all_knots"), col("uniform", "mse_all_knots"))
    adv_sob, adv_sob_wins, adv_sob_p = paired(
        col("adversarial+sobolev", "mse_all_knots"), col("uniform", "mse_all_knots")
    )
    block: dict[str, Any] = {
        "seeds": list(range(settings.seeds)),
        "budget": settings.budget,
        "mse_adversarial": col("adversarial", "mse_initial"),
        "mse_uniform": col("uniform", "mse_initial"),
        "ratio_median": ratio,
        "adversarial_win_fraction": wins,
        "ratio_median_all_knots": ratio_all,
        "sobolev_ratio_median": sob,
        "adversarial_sobolev_ratio_median": adv_sob,
        "ratio_median_p": p,
        "ratio_median_all_knots_p": p_all,
        "adversarial_win_fraction_all_knots": wins_all,
        "sobolev_ratio_median_p": sob_p,
        "sobolev_win_fraction": sob_wins,
        "adversarial_sobolev_ratio_median_p": adv_sob_p,
        "adversarial_sobolev_win_fraction": adv_sob_wins,
        "mse_all_knots_adversarial": col("adversarial", "mse_all_knots"),
        "mse_all_knots_uniform": col("uniform", "mse_all_knots"),
        "train_steps": final["uniform"][0]["train_steps"],
        "sobolev_weight": settings.sobolev_weight,
        "failures": {name: int(sum(m["failures"] for m in rows)) for name, rows in final.items()},
    }
    for name in settings.extra:
        r_i, w_i, p_i = paired(col(name, "mse_initial"), col("uniform", "mse_initial"))
        r_a, w_a, p_a = paired(col(name, "mse_all_knots"), col("uniform", "mse_all_knots"))
        block[f"extra:{name}"] = {
            "ratio_median": r_i, "win_fraction": w_i, "p": p_i,
            "ratio_median_all_knots": r_a, "win_fraction_all_knots": w_a, "p_all_knots": p_a,
        }  # fmt: skip
    return block


def plot(task: str, results: dict[str, list[dict[str, Any]]], path: Path) -> None:
    """Median and 25-75 % band over seeds of both metrics vs solves, per variant."""
    seeds = len(next(iter(results.values())))
    plot_curves_with_band(results, path, title=f"{task}: median and 25-75 % band over {seeds} seeds")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="acrobot only, 10 seeds")
    parser.add_argument("--tasks", nargs="+", choices=("acrobot", "glider"), default=None)
    parser.add_argument("--seeds", type=int, default=None, help="paired seeds (default 20; --quick 10)")
    parser.add_argument("--budget", type=int, default=100, help="solves per run (default 100, paper)")
    parser.add_argument("--train-steps-per-round", type=int, default=500, help="training steps per 10 solves")
    parser.add_argument("--sobolev-weight", type=float, default=1.0)
    parser.add_argument("--extra", nargs="*", default=[], choices=sorted(EXTRA_VARIANTS), help="more variants")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="parallel training runs")
    parser.add_argument("--out", type=Path, default=Path("runs/bench-sample-efficiency"))
    args = parser.parse_args(argv)
    if args.budget < 1 or args.workers < 1 or (args.seeds is not None and args.seeds < 1):
        parser.error("--budget, --workers and --seeds must be >= 1")
    settings = Settings(
        tasks=args.tasks or (["acrobot"] if args.quick else ["acrobot", "glider"]),
        seeds=args.seeds or (10 if args.quick else 20),
        budget=args.budget,
        train_steps_per_round=args.train_steps_per_round,
        workers=args.workers,
        out=args.out,
        extra=list(args.extra),
        sobolev_weight=args.sobolev_weight,
    )
    variants = dict(VARIANTS)
    variants["uniform+sobolev"] = {**variants["uniform+sobolev"], "sobolev_weight": settings.sobolev_weight}
    variants["adversarial+sobolev"] = {**variants["adversarial+sobolev"], "sobolev_weight": settings.sobolev_weight}
    variants.update({name: EXTRA_VARIANTS[name] for name in settings.extra})
    cache = settings.out / "cache"
    summary: dict[str, Any] = {}
    for task in settings.tasks:
        t0 = time.perf_counter()
        base = base_config(task, settings)
        from seagul_envs import make_task

        # the validation set first (one process), so parallel runs only read it
        validation_dataset(make_task(task), make_solver(task, cache), solver_key(None), cache, progress=True)
        jobs = [
            (name, seed, train_config(base, seed=seed, **overrides))
            for name, overrides in variants.items()
            for seed in range(settings.seeds)
        ]
        outputs = Parallel(n_jobs=settings.workers, verbose=5)(
            delayed(run_one)(cfg, settings.out / task / name / f"seed-{seed}", cache) for name, seed, cfg in jobs
        )
        results: dict[str, list[dict[str, Any]]] = {name: [] for name in variants}
        for (name, _, _), out in zip(jobs, outputs, strict=True):
            results[name].append(out)
        summary[task] = summarise(task, settings, results)
        summary[task]["wall_time_s"] = round(time.perf_counter() - t0, 1)
        png = settings.out / f"{task}-sample-efficiency.png"
        plot(task, results, png)
        print(f"{task}: figure {png}", file=sys.stderr)
    print(json.dumps(summary, allow_nan=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
