"""The closed-loop benchmark's pipeline (``benchmarks/bench_closed_loop.py`` is its command line): closed-loop success
per solve, i.e. which way of spending NLP solves gives a learned MPC that controls, and the shipped network with its
block of ``benchmarks/results/closed_loop.json`` (read back by :mod:`seagul_learn.shipped`).

For every learning method (names of :data:`~seagul_learn.experiment.methods.METHODS`, the same table as ``seagul
reproduce``'s) and every seed, one training run to the largest budget saves a network snapshot at each budget
(``TrainConfig.snapshots``; a run's first ``b`` solves are exactly a budget-``b`` run's), trained by the experiment
pipeline's :func:`~seagul_learn.experiment.runs.train_runs`. Every snapshot then drives the deployed controller
(``LimitedLookaheadMPC(task, network, horizon, trust_region=...)``, :func:`mpc_options`) in closed loop in the task's
Gymnasium env from the task's evaluation grid and from held-out starts drawn uniformly from X0 with their own seed,
never trained on, next to the full-horizon MPC on the same starts (:func:`evaluate_network`, :func:`full_horizon`, both
through :func:`~seagul_learn.experiment.runs.evaluate_snapshot`, the evaluation ``seagul reproduce`` runs its final
networks with). :func:`summarize` reports per method and budget: success (median and 25-75 % band over seeds, every seed
listed), the validation MSEs, the cumulative NLP solve time of the budget, the planner-query error ``|Vhat - V|`` at a
sample of the MPC's planned terminal states, and the paired test of each method against the shipped one, seed by seed
(:func:`~seagul_learn.experiment.statistics.paired_test`, the library's one paired test with the benchmark's keys).
:func:`shipped_block` holds the contract's fields of the shipped method; :func:`aggregate_task` rebuilds a task's block
from stored per-seed evaluations.

The methods, shared settings and budgets are :mod:`seagul_learn.experiment.methods`' (:data:`FULL_TRAIN`,
:data:`TASK_TRAIN`, :data:`TASK_SHIPPED`, :data:`TASK_BUDGETS`), so :class:`BenchConfig` here and ``seagul reproduce
--methods`` train the same recipes.
"""

from __future__ import annotations

import json
import shutil
import sys
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from seagul_control.evaluation import PolicySpec, evaluate, heldout_starts, start_grid
from seagul_envs import make_task
from seagul_learn.experiment.figures import plot_success_vs_solves
from seagul_learn.experiment.methods import (
    FULL_TRAIN,
    METHODS,
    PAPER_METHODS,
    SHIPPED,
    TASK_BUDGETS,
    TASK_SHIPPED,
    TASK_SHIPPED_NAME,
    TASK_TRAIN,
    flat_settings,
    shipped_name,
    train_config,
)
from seagul_learn.experiment.runs import (
    deployment_options,
    evaluate_snapshot,
    network_spec,
    success_fields,
    train_one,
    train_runs,
)
from seagul_learn.experiment.statistics import paired_test
from seagul_learn.shipped import REPO_ROOT

__all__ = [
    "FULL_TRAIN",
    "METHODS",
    "SHIPPED",
    "TASK_BUDGETS",
    "TASK_SHIPPED",
    "TASK_SHIPPED_NAME",
    "TASK_TRAIN",
    "BenchConfig",
    "aggregate_task",
    "budget_stats",
    "evaluate_network",
    "full_horizon",
    "method_config",
    "mpc_options",
    "paired_test",
    "parse_compare",
    "plot",
    "run_task",
    "shipped_block",
    "shipped_name",
    "snapshot_path",
    "summarize",
    "timed_steps",
    "train_all",
]


BENCH_METHODS: tuple[str, ...] = tuple(m for m in METHODS if m not in PAPER_METHODS[2:])
"""The benchmark's methods (all of :data:`METHODS` but the paper's ``closed-loop``, which ``seagul reproduce``
compares at small budgets: the benchmark's closed-loop recipes are its ``closed-loop+...`` ones)."""


def _named(task: str, summary: dict[str, Any]) -> dict[str, Any]:
    """``summary`` with the shipped method under :func:`shipped_name`."""
    return {(shipped_name(task) if k == SHIPPED else k): v for k, v in summary.items()}


@dataclass
class BenchConfig:
    """Every number of one benchmark run (``--quick`` replaces some of them)."""

    task: str = "acrobot"
    budgets: tuple[int, ...] = (1000, 2000)
    seeds: int = 5
    seed_list: tuple[int, ...] | None = None
    """Explicit seeds (default ``range(seeds)``)."""
    grid: int = 20
    heldout: int = 100
    query_sample: int = 30
    horizon: int = 5
    trust_region: str = "none"
    jit: bool = True
    """Compile the deployed MPC: networks and ensembles enter it in their matrix form, compiled unexpanded in ~10 s
    (the scalar (SX) form of the 3-member ensemble expands to 30 MB of C, which gcc did not finish compiling)."""
    goal_blend: float = 1.0
    """``LimitedLookaheadMPC(goal_blend=...)`` of the deployed controller (0 = off; equilibrium goals only)."""
    methods: tuple[str, ...] = BENCH_METHODS
    train: dict[str, Any] = field(default_factory=dict)
    """TrainConfig fields shared by every method."""
    method_overrides: dict[str, dict[str, Any]] = field(default_factory=dict)
    """Per-method TrainConfig fields of this run on top of :data:`METHODS`."""

    @classmethod
    def for_task(cls, task: str, quick: bool) -> BenchConfig:
        from seagul_control.evaluation import default_horizon
        from seagul_learn.training import TrainConfig

        defaults = flat_settings(TrainConfig())
        task_obj = make_task(task)
        blend = float(task_obj.profile.mpc.goal_blend)
        horizon = default_horizon(task_obj)
        grid = task_obj.profile.grid.points
        if quick:
            common = {"hidden": tuple(defaults["hidden"]), "solves_per_round": defaults["solves_per_round"]}
            return cls(
                task=task,
                budgets=(20, 50),
                seeds=2,
                grid=3,
                heldout=4,
                query_sample=6,
                goal_blend=blend,
                horizon=horizon,
                methods=("uniform+sobolev", SHIPPED),
                train={**common, "train_steps_per_round": 100, "renormalize": True, "value_cap": 50.0},
                method_overrides={
                    SHIPPED: {
                        "cl_uniform_solves": 25,
                        "cl_episodes": 4,
                        "cl_warmup_rounds": 1,
                        "refit_steps": 300,
                        "refit_ensemble": 2,
                        "refit_candidates": 3,
                        "select_episodes": 4,
                        "select_jit": False,
                    }
                },
            )
        return cls(
            task=task,
            budgets=TASK_BUDGETS.get(task, cls.budgets),
            train={**FULL_TRAIN, **TASK_TRAIN.get(task, {})},
            goal_blend=blend,
            horizon=horizon,
            grid=grid,
            methods=("uniform+sobolev", SHIPPED),
            method_overrides={SHIPPED: dict(TASK_SHIPPED.get(task, {}))},
        )


# ------------------------------------------------------------------------------------------------ training
def _train_one(cfg: dict[str, Any], out: str) -> str:
    """One training run from TrainConfig fields ``cfg`` into ``out``: :func:`~seagul_learn.experiment.runs.train_one`
    without a solve cache (a finished run is left alone)."""
    return train_one(train_config(**cfg), out)


def method_config(bench: BenchConfig, method: str) -> dict[str, Any]:
    """The TrainConfig fields of ``method`` in this run (without budget, snapshots and seed): the shared settings,
    the method's, then this run's overrides of the method. Training and the reports' ``train_settings`` read it."""
    return {
        "task": bench.task,
        # By default the closed-loop sampler collects with the deployed guard; a method may choose another.
        "cl_trust_region": bench.trust_region,
        **bench.train,
        **METHODS[method],
        **bench.method_overrides.get(method, {}),
    }


def _settings(cfg: dict[str, Any]) -> dict[str, Any]:
    """``cfg`` for JSON (tuples as lists)."""
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in cfg.items()}


def train_all(bench: BenchConfig, out: Path, workers: int) -> dict[tuple[str, int], Path]:
    """One run per (method, seed) to the largest budget, snapshots at every budget."""
    jobs = {}
    for method in bench.methods:
        for seed in bench.seed_list or range(bench.seeds):
            cfg = {
                **method_config(bench, method),
                "budget": max(bench.budgets),
                "snapshots": tuple(bench.budgets),
                "seed": seed,
                "progress": False,
            }
            jobs[(method, seed)] = (cfg, str(out / "train" / f"{method}-seed{seed}"))
    # Closed-loop runs first: they are the longest (tail solves), so the pool stays busy to the end.
    order = sorted(jobs, key=lambda k: (k[0] != SHIPPED, k))
    t0 = time.perf_counter()
    train_runs([(train_config(**jobs[k][0]), jobs[k][1]) for k in order], workers=workers)
    print(f"[bench] training {len(jobs)} runs: {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    return {k: Path(v[1]) for k, v in jobs.items()}


def snapshot_path(run: Path, budget: int, final: int) -> Path:
    """The network of ``run`` after ``budget`` solves."""
    return run / ("network.pt" if budget == final else f"network_{budget}.pt")


def budget_stats(run: Path, budget: int, pretrain: int) -> dict[str, float]:
    """Validation MSEs at ``budget`` and the NLP solve time spent to get there (pretraining included)."""
    metrics = json.loads((run / "metrics.json").read_text())["metrics"]
    at = [m for m in metrics if int(m["solves"]) == budget]
    row = at[-1] if at else metrics[-1]
    solve_time, failures = 0.0, 0
    records_dir = run / "dataset" / "records"
    for path in sorted(records_dir.glob("solve-*.npz"))[: pretrain + budget]:
        with np.load(path, allow_pickle=False) as data:
            solve_time += float(data["solve_time"])
            failures += int(not bool(data["success"]))
    return {
        "mse_initial": float(row["mse_initial"]),
        "mse_all_knots": float(row["mse_all_knots"]),
        "solve_time_s": solve_time,
        "failures": failures,
    }


# ---------------------------------------------------------------------------------------------- evaluation
def mpc_options(bench: BenchConfig) -> tuple[tuple[str, Any], ...]:
    """Constructor options of the deployed ``LimitedLookaheadMPC`` (compiled if ``bench.jit``;
    :func:`~seagul_learn.experiment.runs.deployment_options`)."""
    return deployment_options(bench.horizon, bench.trust_region, bench.goal_blend, jit=bench.jit)


def evaluate_network(
    bench: BenchConfig, path: Path, starts: np.ndarray, n_grid: int, workers: int, out: Path, query_sample: int
) -> dict[str, Any]:
    """Closed loop of one snapshot on grid + held-out starts, with its planner-query error (cached as JSON)."""
    if out.is_file():
        return json.loads(out.read_text())
    from seagul_learn.closed_loop import query_errors
    from seagul_learn.solving import trajopt_batch_solver
    from seagul_learn.value_network import ValueNetwork

    spec = network_spec("mpc", path, mpc_options(bench))
    grid, held = evaluate_snapshot(bench.task, spec, starts[:n_grid], starts[n_grid:], workers, record_queries=True)
    results = grid + held
    queries = np.array([q for r in results for q in r.queries]).reshape(-1, make_task(bench.task).nx + 1)
    solver = trajopt_batch_solver(bench.task, workers=workers)
    qe = query_errors(make_task(bench.task), ValueNetwork.load(path), queries, solver, query_sample)
    times = np.array([t for r in results for t in r.solve_times])
    row = {
        **success_fields(grid, held),
        "fallback_steps": int(sum(r.fallbacks for r in results)),
        "multistart_steps": int(sum(r.multistart_steps for r in results)),
        "steps": int(sum(r.steps for r in results)),
        "median_ms": float(np.median(times) * 1e3),
        "p95_ms": float(np.percentile(times, 95) * 1e3),
        "query_error": qe.as_dict(),
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(row, indent=1))
    return row


def full_horizon(bench: BenchConfig, starts: np.ndarray, n_grid: int, workers: int, out: Path) -> dict[str, Any]:
    """The full-horizon MPC on the same starts (the upper reference; cached)."""
    if out.is_file():
        return json.loads(out.read_text())
    spec = PolicySpec("full", "full-horizon")
    row = success_fields(*evaluate_snapshot(bench.task, spec, starts[:n_grid], starts[n_grid:], workers))
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(row, indent=1))
    return row


def timed_steps(bench: BenchConfig, path: Path, starts: np.ndarray) -> dict[str, float]:
    """MPC solver step times of the shipped network in one process (no parallel episodes sharing the cores)."""
    spec = network_spec("timed", path, mpc_options(bench))
    results = evaluate(bench.task, [spec], starts, workers=1, progress=False)
    times = np.array([t for r in results for t in r.solve_times]) * 1e3
    return {
        "median_ms": float(np.median(times)),
        "p95_ms": float(np.percentile(times, 95)),
        "steps": int(times.size),
        "multistart_steps": int(sum(r.multistart_steps for r in results)),
        "success_rate": float(np.mean([r.success for r in results])),
    }


# ----------------------------------------------------------------------------------------------- statistics
def _median(rows: list[dict[str, Any]], key: str, sub: str | None = None) -> float:
    """Median of ``row[key]`` (``row[key][sub]``) over the rows that have it (NaN where none does: e.g. a grid-only
    evaluation has no held-out rate or query error, an aggregated one no training records)."""
    values = []
    for row in rows:
        value = row.get(key)
        if sub is not None:
            value = value.get(sub) if isinstance(value, dict) else None
        if value is not None and np.isfinite(float(value)):
            values.append(float(value))
    return float(np.median(values)) if values else float("nan")


def summarize(bench: BenchConfig, table: dict[str, dict[int, list[dict[str, Any]]]], full: dict[str, Any]) -> dict:
    """Per method and budget: medians, bands and per-seed lists; paired tests against the shipped method."""
    out: dict[str, Any] = {}
    target = 0.98 * full["success_rate"]
    for method, by_budget in table.items():
        rows = {}
        reached = None
        for budget in sorted(by_budget):
            seeds = by_budget[budget]
            succ = [s["success_rate"] for s in seeds]
            rows[str(budget)] = {
                "seeds": [s.get("seed") for s in seeds],
                "success_median": float(np.median(succ)),
                "success_q25": float(np.percentile(succ, 25)),
                "success_q75": float(np.percentile(succ, 75)),
                "success_per_seed": succ,
                "heldout_median": _median(seeds, "heldout_success_rate"),
                "heldout_per_seed": [s.get("heldout_success_rate", float("nan")) for s in seeds],
                "mse_initial_median": _median(seeds, "mse_initial"),
                "mse_all_knots_median": _median(seeds, "mse_all_knots"),
                "solve_time_s_median": _median(seeds, "solve_time_s"),
                "failures_median": _median(seeds, "failures"),
                "query_error_median": _median(seeds, "query_error", "median"),
                "query_error_p95": _median(seeds, "query_error", "p95"),
                "query_error_mean_signed": _median(seeds, "query_error", "mean_signed"),
                "fallback_steps_median": _median(seeds, "fallback_steps"),
            }
            # A representative network (the seed closest to the median; ties: the lower seed), when rows name theirs.
            named = [s for s in seeds if s.get("network")]
            if named:
                rep = min(named, key=lambda s: (abs(s["success_rate"] - np.median(succ)), s.get("seed", 0)))
                rows[str(budget)].update(network=str(rep["network"]), network_seed=rep.get("seed"))
            if method != SHIPPED and SHIPPED in table and budget in table[SHIPPED]:
                paired = {s.get("seed"): s["success_rate"] for s in table[SHIPPED][budget]}
                if Counter(list(paired)) == Counter(s.get("seed") for s in seeds):  # the same seeds: a paired test
                    shipped = [paired[s.get("seed")] for s in seeds]
                    rows[str(budget)]["vs_shipped"] = paired_test(shipped, succ)
            if reached is None and np.median(succ) >= target:
                reached = budget
        out[method] = {"budgets": rows, "smallest_budget_98pct_of_full_horizon": reached}
    return out


def plot(
    summary: dict[str, Any], full: dict[str, Any], path: Path, title: str, labels: dict[str, str] | None = None
) -> None:
    """``success_vs_solves.png`` of a summary (:func:`summarize`): success vs solves and vs cumulative solve time,
    median and quartile band over seeds, the full-horizon MPC and 98 % of it as lines; ``labels``: legend names of
    methods. Drawn by the library's one figure function,
    :func:`~seagul_learn.experiment.figures.plot_success_vs_solves`."""
    references = {"full-horizon MPC": full["success_rate"], "98 % of full horizon": 0.98 * full["success_rate"]}
    plot_success_vs_solves(summary, path, references, title, labels=labels, emphasize=(SHIPPED,))


# --------------------------------------------------------------------------------------------------- a task
def run_task(bench: BenchConfig, out: Path, workers: int, ship_dir: Path | None) -> dict[str, Any]:
    """The benchmark of one task: train every (method, seed) to the largest budget with snapshots, evaluate every
    snapshot on the grid and the held-out starts (the final budget's with its planner-query error) beside the
    full-horizon MPC, summarise per method and budget, draw ``success_vs_solves.png``, pick the shipped method's
    median seed (copied into ``ship_dir`` with the figure when given) and time its steps. Returns the task's block
    of ``closed_loop.json``. Every stage is stored under ``out`` first, so a re-run continues an interrupted one."""
    t_start = time.perf_counter()
    task = make_task(bench.task)
    grid_starts, _ = start_grid(task, bench.grid)
    starts = np.vstack([grid_starts, heldout_starts(bench.task, bench.heldout)])
    n_grid = grid_starts.shape[0]
    runs = train_all(bench, out, workers)
    full = full_horizon(bench, starts, n_grid, workers, out / "eval" / "full-horizon.json")
    print(f"[bench] full horizon: {full['success_rate']:.3f}", file=sys.stderr, flush=True)
    final = max(bench.budgets)
    pretrain = int(bench.train.get("pretrain_solves", 10))
    table: dict[str, dict[int, list[dict[str, Any]]]] = {}
    for (method, seed), run in sorted(runs.items()):
        for budget in bench.budgets:
            path = snapshot_path(run, budget, final)
            # The planner-query error (tail re-solves, the slow part) at the final budget of every seed.
            sample = bench.query_sample if budget == final else 0
            row = evaluate_network(
                bench, path, starts, n_grid, workers, out / "eval" / f"{method}-seed{seed}-b{budget}.json", sample
            )
            row = {**row, **budget_stats(run, budget, pretrain), "seed": seed, "network": str(path)}
            table.setdefault(method, {}).setdefault(budget, []).append(row)
            print(
                f"[bench] {method} seed {seed} budget {budget}: success {row['success_rate']:.3f} "
                f"held-out {row['heldout_success_rate']:.3f}",
                file=sys.stderr,
                flush=True,
            )
    summary = summarize(bench, table, full)
    plot(summary, full, out / "success_vs_solves.png", f"{bench.task}: {bench.horizon}-step MPC, {bench.seeds} seeds")
    shipped = table[SHIPPED][final]
    med = float(np.median([s["success_rate"] for s in shipped]))
    # The shipped network: the seed whose grid success is closest to the median (a representative one).
    rep = min(shipped, key=lambda s: (abs(s["success_rate"] - med), s["seed"]))
    network = Path(rep["network"])
    if ship_dir is not None:
        ship_dir.mkdir(parents=True, exist_ok=True)
        dest = ship_dir / f"{bench.task}_{shipped_name(bench.task).replace('+', '_')}_b{final}.pt"
        shutil.copyfile(network, dest)
        network = dest
        shutil.copyfile(out / "success_vs_solves.png", ship_dir.parent / f"success_vs_solves_{bench.task}.png")
    timing = timed_steps(bench, network, grid_starts)
    return {
        **shipped_block(bench, shipped, full, network, timing, final),
        "network_seed": rep["seed"],
        "budgets": list(bench.budgets),
        "methods": _named(bench.task, summary),
        "train_settings": _settings(method_config(bench, SHIPPED)),
        "wall_s": round(time.perf_counter() - t_start, 1),
    }


def shipped_block(
    bench: BenchConfig,
    shipped: list[dict[str, Any]],
    full: dict[str, Any],
    network: Path,
    timing: dict[str, Any],
    budget: int,
) -> dict[str, Any]:
    """The contract's fields for the shipped method: medians over its per-seed evaluations ``shipped`` at ``budget``,
    the full horizon on the same starts, the shipped ``network`` (relative to the repository) and its ``timing``."""
    try:
        net_rel = str(network.resolve().relative_to(REPO_ROOT))
    except ValueError:
        net_rel = str(network)
    return {
        "method": shipped_name(bench.task),
        "budget": budget,
        "seeds": len(shipped),
        "seed_list": [s["seed"] for s in shipped],
        "success_rate": float(np.median([s["success_rate"] for s in shipped])),
        "full_horizon_success_rate": full["success_rate"],
        "heldout_success_rate": _median(shipped, "heldout_success_rate"),
        "full_horizon_heldout_success_rate": full["heldout_success_rate"],
        "network": net_rel,
        "horizon": bench.horizon,
        "trust_region": bench.trust_region,
        "goal_blend": bench.goal_blend,
        "jit": bench.jit,
        "median_ms": timing["median_ms"],
        "p95_ms": timing["p95_ms"],
        "timed_steps": timing["steps"],
        "timed_success_rate": timing["success_rate"],
        # Steps whose solve also descended from extra starts (the MPC's multistart; its default, "rise", for the
        # condensed solver), as a fraction of the timed steps.
        "multistart_fraction": timing.get("multistart_steps", 0) / max(int(timing["steps"]), 1),
        "query_error_median": _median(shipped, "query_error", "median"),
        "query_error_p95": _median(shipped, "query_error", "p95"),
        "grid": f"{bench.grid}x{bench.grid}",
        "heldout_starts": bench.heldout,
        # The task's own name of the success rate (the glider's "perch_success_rate"), as the contract spells it.
        **_task_success_fields(bench, shipped, full),
    }


def _task_success_fields(bench: BenchConfig, shipped: list[dict[str, Any]], full: dict[str, Any]) -> dict[str, Any]:
    column = make_task(bench.task).profile.success_column
    if not column or column == "success_rate":
        return {}
    return {
        column: float(np.median([s["success_rate"] for s in shipped])),
        f"full_horizon_{column}": full["success_rate"],
    }


def _stored_rows(folder: Path, seeds: list[int], budgets: list[int] | None) -> dict[int, list[dict[str, Any]]]:
    """Per-seed evaluations stored in ``folder``: ``b<B>/seed<N>.json`` per budget (``budgets``, or every ``b<B>``
    folder there when None), or ``seed<N>.json`` directly for the single budget ``budgets[0]``."""
    if budgets is None:
        budgets = sorted(int(p.name[1:]) for p in folder.glob("b*") if p.is_dir() and p.name[1:].isdigit())
    table: dict[int, list[dict[str, Any]]] = {}
    for b in budgets:
        sub = folder / f"b{b}"
        where = sub if sub.is_dir() else folder
        rows = [
            {**json.loads((where / f"seed{seed}.json").read_text()), "seed": seed}
            for seed in seeds
            if (where / f"seed{seed}.json").is_file()
        ]
        if not rows:
            raise FileNotFoundError(f"--aggregate: no evaluation seed<N>.json for budget {b} in {where}")
        table[b] = rows
    return table


def aggregate_task(
    bench: BenchConfig,
    eval_dir: Path,
    network: Path,
    budget: int,
    figure: Path | None = None,
    compare: dict[str, tuple[Path, int | None]] | None = None,
    shipped_label: str | None = None,
    title: str | None = None,
    timing: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The JSON block of :func:`run_task` rebuilt from stored per-seed evaluations without the training runs:
    ``eval_dir/b<B>/seed<N>.json`` per budget of ``bench.budgets`` (or ``eval_dir/seed<N>.json`` for one budget; a
    budget may lack some seeds: each row lists its own), and ``full-horizon.json`` in ``eval_dir`` or its parent.
    The contract's fields are those of ``budget`` (the shipped one); the shipped ``network`` is timed again in this
    process. Rows may carry the training records' fields (validation MSEs, solve time) and may be grid-only (no
    held-out rate or query error: NaN). ``figure``: also draw ``success_vs_solves`` there. ``compare``: other
    methods' stored evaluations (label -> folder of ``b<B>/seed<N>.json``, or of ``seed<N>.json`` at ``budget``),
    summarised and drawn beside; a folder of ``seed<N>.json`` holds the budget given with it (``(folder, budget)``;
    None: the shipped ``budget``). ``title``: the figure's (default: task, horizon and seeds). ``timing``: the shipped
    network's step times (default: :func:`timed_steps` now)."""
    seeds = list(bench.seed_list or range(bench.seeds))
    budgets = sorted(bench.budgets)
    table = _stored_rows(eval_dir, seeds, budgets)
    if budget not in table:
        raise ValueError(f"--aggregate: the shipped budget {budget} is not among the budgets {budgets}")
    # The full horizon's evaluation beside the per-seed ones, or one level up (shared by several methods' folders).
    full_path = next(
        (d / "full-horizon.json" for d in (eval_dir, eval_dir.parent) if (d / "full-horizon.json").is_file()), None
    )
    if full_path is None:
        raise FileNotFoundError(f"--aggregate: no full-horizon.json in {eval_dir} or {eval_dir.parent}")
    full = json.loads(full_path.read_text())
    if timing is None:
        grid_starts, _ = start_grid(make_task(bench.task), bench.grid)
        timing = timed_steps(bench, network, grid_starts)
    block = shipped_block(bench, table[budget], full, network, timing, budget)
    tables = {SHIPPED: table}
    for label, (folder, at) in (compare or {}).items():
        # b<B>/seed<N>.json per budget, or seed<N>.json directly: the budget given with the folder (or the shipped)
        by_budget = any(p.is_dir() and p.name[1:].isdigit() for p in folder.glob("b*"))
        tables[label] = _stored_rows(folder, seeds, None if by_budget and at is None else [at or budget])
    summary = summarize(bench, tables, full)
    if figure is not None:
        title = title or f"{bench.task}: {bench.horizon}-step MPC, up to {len(seeds)} seeds (aggregated evaluations)"
        plot(summary, full, figure, title, {SHIPPED: shipped_label} if shipped_label else None)
    return {
        **block,
        "budgets": budgets,
        "methods": _named(bench.task, summary),
        "aggregated_from": str(eval_dir),
        "train_settings": _settings(method_config(bench, SHIPPED)),
    }


def parse_compare(item: str) -> tuple[str, tuple[Path, int | None]]:
    """``--compare LABEL=DIR`` or ``LABEL=DIR@BUDGET`` as ``(label, (folder, budget or None))``."""
    label, _, spec = item.partition("=")
    folder, at, given = spec.rpartition("@") if "@" in spec else (spec, "", "")
    if not label or not folder or (at and not given.isdigit()):
        raise ValueError(f"--compare {item!r}: expected LABEL=DIR or LABEL=DIR@BUDGET (BUDGET a number of solves)")
    return label, (Path(folder), int(given) if at else None)
