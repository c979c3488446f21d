"""Closed-loop success per solve: which way of spending NLP solves gives a learned MPC that controls.

Usage::

    .venv/bin/python benchmarks/bench_closed_loop.py [--quick] [--seeds N] [--workers 2] [--out DIR]
        [--tasks acrobot,glider]

For every learning method (uniform, adversarial = paper Alg. 1, each with and without Sobolev training, and the
closed-loop sampler with Sobolev training) and every seed, one training run to the largest budget saves a network
snapshot at each budget (``TrainConfig.snapshots``; a run's first ``b`` solves are exactly a budget-``b`` run's).
Every snapshot then drives the deployed controller — ``LimitedLookaheadMPC(task, network, horizon,
trust_region=...)`` — in closed loop in the task's Gymnasium env from

* the evaluation grid (the task's: acrobot 20 x 20 over ``(th1, th2)`` at zero velocity, glider 6 x 6 over
  ``(x, z)``; ``--quick`` 3 x 3), and
* 100 held-out starts drawn uniformly from X0 with their own seed (``--quick`` 20), never trained on,

next to the full-horizon MPC on the same starts. Reported per method and budget: success (median and
25-75 % band over seeds, every seed listed), the validation MSEs, the cumulative NLP solve time of the budget, and
the **planner-query error** ``|Vhat - V|`` at a sample of the MPC's planned terminal states (median, 95th
percentile, mean signed error) against re-solved tail problems. Paired Wilcoxon tests compare each method with the
closed-loop sampler at each budget, seed by seed. ``success_vs_solves.png`` plots success against solves and
against solve time.

Every stage stores its result under ``--out`` before the next starts (training runs checkpoint per round, every
evaluation is a JSON file), so an interrupted benchmark re-run with the same ``--out`` continues where it stopped.

The last line of stdout is one JSON object (the full run's is committed as ``benchmarks/results/closed_loop.json``)::

    {"acrobot": {"method", "budget", "seeds", "success_rate", "full_horizon_success_rate", "heldout_success_rate",
                 "network", "horizon", "trust_region", "median_ms", "p95_ms", "query_error_median", ...},
     "glider": {..., "perch_success_rate", "full_horizon_perch_success_rate", ...},
     "machine": {...}}

A task's own name of its success rate (the glider's ``perch_success_rate``, from its profile) is given beside
``success_rate``. ``--update FILE`` also writes the blocks of the tasks run into ``FILE``, keeping the others.

This script is the command line only: it says which tasks, methods, budgets and seeds and where to write, and
calls the library's pipeline, :mod:`seagul_learn.experiment.benchmark` (training through the experiment pipeline of
``seagul reproduce``, the methods of :mod:`seagul_learn.experiment.methods`, the paired test and the figure of
:mod:`seagul_learn.experiment.statistics` and :mod:`seagul_learn.experiment.figures`). Its names (``METHODS``,
``BenchConfig``, ``method_config``, ``evaluate_network``, ``train_all``, ...) are the library's, re-exported here for
the scripts and notes that use them from this module.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._common import machine  # noqa: E402
from seagul_control.evaluation import start_grid  # noqa: E402
from seagul_envs import make_task  # noqa: E402
from seagul_learn.experiment import benchmark as _pipeline  # noqa: E402
from seagul_learn.experiment.benchmark import (  # noqa: E402, F401  (re-exported: the benchmark's names)
    FULL_TRAIN,
    METHODS,
    SHIPPED,
    TASK_BUDGETS,
    TASK_SHIPPED,
    TASK_SHIPPED_NAME,
    TASK_TRAIN,
    BenchConfig,
    _named,
    _stored_rows,
    _train_one,
    budget_stats,
    evaluate_network,
    full_horizon,
    method_config,
    mpc_options,
    paired_test,
    parse_compare,
    plot,
    run_task,
    shipped_block,
    shipped_name,
    snapshot_path,
    summarize,
    timed_steps,
    train_all,
)


def aggregate_task(
    bench: BenchConfig,
    eval_dir: Path,
    network: Path,
    budget: int,
    figure: Path | None = None,
    compare: dict[str, tuple[Path, int | None]] | None = None,
    shipped_label: str | None = None,
    title: str | None = None,
) -> dict[str, Any]:
    """:func:`seagul_learn.experiment.benchmark.aggregate_task` with the shipped network timed by this module's
    :func:`timed_steps` (``--aggregate``)."""
    grid_starts, _ = start_grid(make_task(bench.task), bench.grid)
    timing = timed_steps(bench, network, grid_starts)
    return _pipeline.aggregate_task(
        bench, eval_dir, network, budget, figure, compare, shipped_label, title, timing=timing
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="a minutes-long check of the pipeline")
    parser.add_argument("--seeds", type=int, default=None, help="override the number of seeds")
    parser.add_argument("--seed-list", default=None, help="explicit comma-separated seeds (overrides --seeds)")
    parser.add_argument("--workers", type=int, default=2, help="parallel processes (training runs, episodes)")
    parser.add_argument("--out", default=None, help="work directory (default /tmp/seagul-bench-closed-loop[-quick])")
    parser.add_argument("--tasks", default="acrobot", help="comma-separated tasks (acrobot, glider)")
    parser.add_argument("--methods", default=None, help="comma-separated subset of " + ",".join(METHODS))
    parser.add_argument("--budgets", default=None, help="comma-separated budgets (override)")
    parser.add_argument("--trust-region", choices=("lqr", "none", "box"), default=None, help="the deployed guard")
    parser.add_argument("--goal-blend", type=float, default=None, help="the deployed MPC's goal_blend (0 = off)")
    parser.add_argument("--no-ship", action="store_true", help="do not copy the shipped network into the repository")
    parser.add_argument(
        "--aggregate",
        metavar="DIR",
        default=None,
        help="no training: rebuild the JSON from per-seed evaluations in DIR (seed<N>.json, full-horizon.json) and "
        "time --network again (one task, one budget: --budgets)",
    )
    parser.add_argument("--network", default=None, help="--aggregate: the shipped network file")
    parser.add_argument(
        "--ship-budget",
        type=int,
        default=None,
        help="--aggregate with several --budgets: the budget of the shipped network (default the largest)",
    )
    parser.add_argument("--figure", default=None, help="--aggregate: write success_vs_solves here (PNG)")
    parser.add_argument(
        "--compare",
        action="append",
        default=[],
        metavar="LABEL=DIR",
        help="--aggregate: another method's stored evaluations (DIR/b<B>/seed<N>.json; DIR@B: DIR/seed<N>.json or "
        "DIR/b<B>/seed<N>.json at budget B only, default the shipped budget), summarised and drawn beside",
    )
    parser.add_argument("--label", default=None, help="--aggregate: the shipped method's name in the figure")
    parser.add_argument("--title", default=None, help="--aggregate: the figure's title")
    parser.add_argument(
        "--update",
        default=None,
        metavar="JSON",
        help="also write the result into this JSON file, replacing only the blocks of the tasks run (e.g. "
        "benchmarks/results/closed_loop.json: the glider block added beside the acrobot's)",
    )
    args = parser.parse_args(argv)
    if args.aggregate and not (args.network and args.budgets and "," not in args.tasks):
        parser.error("--aggregate needs --network, --budgets and a single task")
    out = Path(args.out or f"/tmp/seagul-bench-closed-loop{'-quick' if args.quick else ''}")
    ship = None if (args.quick or args.no_ship) else ROOT / "benchmarks" / "results" / "networks"
    result: dict[str, Any] = {}
    t0 = time.perf_counter()
    for task in args.tasks.split(","):
        bench = BenchConfig.for_task(task, args.quick)
        if args.seeds is not None:
            bench.seeds = args.seeds
        if args.methods:
            bench.methods = tuple(m for m in args.methods.split(",") if m)
            unknown = set(bench.methods) - set(METHODS)
            if unknown or SHIPPED not in bench.methods:
                parser.error(f"--methods must name known methods including {SHIPPED}; unknown: {sorted(unknown)}")
        if args.seed_list:
            bench.seed_list = tuple(int(v) for v in args.seed_list.split(","))
            bench.seeds = len(bench.seed_list)
        if args.trust_region:
            bench.trust_region = args.trust_region
        if args.goal_blend is not None:
            bench.goal_blend = args.goal_blend
        if args.budgets:
            bench.budgets = tuple(int(b) for b in args.budgets.split(","))
        if args.aggregate:
            shipped_budget = args.ship_budget or max(bench.budgets)
            figure = Path(args.figure) if args.figure else None
            try:
                compare = dict(parse_compare(item) for item in args.compare)
            except ValueError as exc:
                parser.error(str(exc))
            result[task] = aggregate_task(
                bench,
                Path(args.aggregate),
                Path(args.network),
                shipped_budget,
                figure,
                compare,
                args.label,
                args.title,
            )
        else:
            result[task] = run_task(bench, out / task, args.workers, ship)
    result["machine"] = {**machine(), "wall_s": round(time.perf_counter() - t0, 1)}
    if args.update:
        path = Path(args.update)
        merged = json.loads(path.read_text()) if path.is_file() else {}
        merged.update({k: v for k, v in result.items() if k != "machine"})
        # "machine" stays the file's first run's; "machines" holds one record per run, keyed by the tasks it ran.
        merged.setdefault("machine", result["machine"])
        merged.setdefault("machines", {})[",".join(k for k in result if k != "machine")] = result["machine"]
        path.write_text(json.dumps(merged, indent=1) + "\n")
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
