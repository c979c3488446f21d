"""Every controller of a task on the same starts, in one table: what each cost to make and how it controls.

Usage::

    .venv/bin/python benchmarks/bench_controllers.py [--task acrobot] [--latency-starts 20] [--quick] [--env ENV_ID]

Rows: the learned limited-lookahead MPC of the closed-loop benchmark (``benchmarks/results/closed_loop.json``: its
NLP solves, median success over seeds on the grid and the held-out starts, its step latency), the other learning
methods of that file at the same budget (uniform, SEAGuL, with and without Sobolev; their representative networks'
latency measured here), LQR and the
full-horizon MPC (measured here on the same 20 x 20 grid and 100 held-out X0 starts, seed 20211231), and PPO/SAC
from ``benchmarks/results/rl_baselines.json`` when that file exists (environment steps, training wall time, median
success over seeds). A row whose source has not been run says so (``null`` in the JSON, "not run" in the table);
nothing is filled in by hand.

``--env SeagulAcrobotMujoco-v0`` runs every row in that simulator of the task instead (the MuJoCo acrobot): the
learned row is then the shipped network and the RL rows the shipped models, each evaluated here.

Latency is the controller's own computation per step (the MPCs' solver wall time; LQR's and SB3's ``predict``),
median and 95th percentile, measured in this process on the first ``--latency-starts`` grid starts with nothing
else running in it. The table is printed as Markdown on stderr; the last line of stdout is one JSON object
``{"task", "env", "rows": [{"method", "nlp_solves", "env_steps", "train_wall_s", "grid_success", "heldout_success",
"median_ms", "p95_ms", "source"}], "machine"}``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._common import machine  # noqa: E402
from seagul_control.evaluation import (  # noqa: E402
    PolicySpec,
    build_policy,
    evaluate,
    heldout_starts,
    run_policy_episode,
    start_grid,
)
from seagul_envs import make_task  # noqa: E402
from seagul_learn import recipes  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"


class _Timed:
    """A predictor that records the wall time of each ``predict`` of the one it wraps (other attributes pass)."""

    def __init__(self, policy: Any) -> None:
        self.policy = policy
        self.times: list[float] = []

    def predict(self, *args: Any, **kwargs: Any) -> Any:
        t = time.perf_counter()
        out = self.policy.predict(*args, **kwargs)
        self.times.append(time.perf_counter() - t)
        return out

    def __getattr__(self, name: str) -> Any:
        return getattr(self.policy, name)


def latency(task: Any, spec: PolicySpec, starts: np.ndarray, env_id: str | None = None) -> dict[str, float]:
    """Median and p95 of the per-step computation time of ``spec``'s controller over episodes from ``starts``."""
    timed = _Timed(build_policy(task, spec))
    for x0 in starts:
        run_policy_episode(task, timed, x0, env_id=env_id)
    ms = np.asarray(timed.times) * 1e3
    return {"median_ms": float(np.median(ms)), "p95_ms": float(np.percentile(ms, 95)), "steps": int(ms.size)}


def measured_row(
    task: Any,
    method: str,
    spec: PolicySpec,
    starts: np.ndarray,
    n_grid: int,
    lat: np.ndarray,
    stored: Path | None,
    env_id: str | None = None,
) -> dict:
    """Success on the grid and held-out starts (or, if ``stored`` exists, the stored evaluation of exactly these
    starts), and latency measured here; ``env_id`` runs the episodes in that env of the task."""
    if stored is not None and stored.is_file():
        row = json.loads(stored.read_text())
        grid_success, held_success = row["success_rate"], row["heldout_success_rate"]
        source = f"success: {stored.relative_to(ROOT)}; latency: measured here"
    else:
        results = evaluate(task, [spec], starts, workers=2, progress=False, env_id=env_id)
        grid, held = results[:n_grid], results[n_grid:]
        grid_success = float(np.mean([r.success for r in grid]))
        held_success = float(np.mean([r.success for r in held]))
        source = "measured here"
    return {
        "method": method,
        "nlp_solves": 0,
        "env_steps": 0,
        "train_wall_s": 0.0,
        "grid_success": grid_success,
        "heldout_success": held_success,
        **latency(task, spec, lat, env_id),
        "source": source,
    }


def learned_row(task_name: str) -> dict[str, Any]:
    path = RESULTS / "closed_loop.json"
    if not path.is_file():
        return {"method": "learned MPC", "source": "not run (benchmarks/bench_closed_loop.py)"}
    block = json.loads(path.read_text()).get(task_name)
    if not block:
        return {"method": "learned MPC", "source": f"not run for {task_name}"}
    collection, selection = training_env_steps(task_name, block)
    return {
        "method": f"learned {block['horizon']}-step MPC ({block['method']}, {block['seeds']} seeds)",
        "nlp_solves": int(block["budget"]),
        "env_steps": collection + selection,
        "collection_env_steps": collection,
        "selection_env_steps": selection,
        "train_wall_s": block.get("wall_s"),
        "grid_success": block["success_rate"],
        "heldout_success": block["heldout_success_rate"],
        "median_ms": block["median_ms"],
        "p95_ms": block["p95_ms"],
        "source": "benchmarks/results/closed_loop.json",
    }


def training_env_steps(task_name: str, block: dict[str, Any]) -> tuple[int, int]:
    """Environment steps spent making a ``closed_loop.json`` block's network: the closed-loop sampler's collection
    episodes (from the block's ``train_settings``, stored under the flat names ``cl_uniform_solves``,
    ``solves_per_round``, ``cl_episodes``), and the episodes its refit selection flies (every ``refit.ensemble``-subset
    of the ``refit.candidates`` refits ``selection.episodes`` starts, the best ``selection.finalists`` subsets
    ``selection.final_episodes`` more; the selection settings are the task's default recipe,
    ``seagul_learn/recipes/<task>.yml``, which the block's method trains)."""
    task = make_task(task_name)
    steps_per_episode = round(task.tau_nominal / task.control_period)
    train = block.get("train_settings", {})
    if not block["method"].startswith("closed-loop"):
        return 0, 0
    tail_solves = int(block["budget"]) - int(train.get("cl_uniform_solves", 0))
    rounds = max(0, tail_solves // int(train.get("solves_per_round", 50)))
    collection = rounds * int(train.get("cl_episodes", 0)) * steps_per_episode
    recipe = recipes.recipe(task, "default")  # nested as TrainConfig.to_dict; parts left out take no selection
    refit, select = recipe.get("refit", {}), recipe.get("selection", {})
    candidates, size = int(refit.get("candidates", 0)), int(refit.get("ensemble", 1))
    if candidates <= size or int(refit.get("steps", 0)) <= 0:
        return collection, 0
    subsets = math.comb(candidates, size)
    finalists = min(int(select.get("finalists", 0)), subsets)
    episodes = subsets * int(select.get("episodes", 0)) + finalists * int(select.get("final_episodes", 0))
    return collection, episodes * steps_per_episode


def sampler_rows(task_name: str, lat: np.ndarray | None = None) -> list[dict[str, Any]]:
    """One learned-MPC row per other sampler of ``closed_loop.json`` (uniform, SEAGuL, each with and without
    Sobolev training; not the other closed-loop recipes compared there) at the largest budget it was run to: its
    median success over seeds, and with ``lat`` the step latency of its representative network
    (``methods[m]["budgets"][b]["network"]``, the seed closest to the median) measured here, deployed as the
    shipped one."""
    path = RESULTS / "closed_loop.json"
    block = json.loads(path.read_text()).get(task_name) if path.is_file() else None
    if not block:
        return []
    rows = []
    for method, entry in block.get("methods", {}).items():
        # each sampler at the largest budget it was run to (the paper's samplers: 2,000 solves, twice the acrobot's
        # shipped budget), where its seeds were evaluated on the whole grid and the held-out starts
        budgets = entry.get("budgets", {})
        # the shipped method has its own row; the other closed-loop recipes are its variants
        # (docs/experiments/closed-loop.md)
        if method == block["method"] or method.startswith("closed-loop") or not budgets:
            continue
        budget = max(budgets, key=int)
        row = budgets[budget]
        timing: dict[str, Any] = {"median_ms": None, "p95_ms": None}
        network = ROOT / str(row.get("network", ""))
        if lat is not None and row.get("network") and network.is_file():
            spec = learned_spec({**block, "network": str(network.relative_to(ROOT))})
            timing = latency(make_task(task_name), spec, lat)
        rows.append(
            {
                "method": f"learned {block['horizon']}-step MPC ({method}, {len(row['success_per_seed'])} seeds)",
                "nlp_solves": int(budget),
                "env_steps": 0,
                "train_wall_s": None,
                "grid_success": row["success_median"],
                "heldout_success": row["heldout_median"],
                "median_ms": timing["median_ms"],
                "p95_ms": timing["p95_ms"],
                "source": "benchmarks/results/closed_loop.json (methods)",
            }
        )
    return rows


def rl_rows(task_name: str, lat: np.ndarray | None = None) -> list[dict[str, Any]]:
    """PPO/SAC rows from ``rl_baselines.json``; with ``lat`` (starts), the shipped model's ``predict`` latency is
    measured here, side by side with the other rows."""
    path = RESULTS / "rl_baselines.json"
    data = json.loads(path.read_text()).get(task_name, {}) if path.is_file() else {}
    rows = []
    for algo in ("ppo", "sac"):
        block = data.get(algo)
        if not block:
            rows.append({"method": algo.upper(), "source": "not run (benchmarks/bench_rl_baselines.py)"})
            continue
        timing = {"median_ms": block.get("median_ms"), "p95_ms": block.get("p95_ms")}
        model = ROOT / str(block.get("model", ""))
        if lat is not None and model.is_file():
            spec = PolicySpec("sb3", algo, str(model), (("algo", block["algo"]),))
            timing = latency(make_task(task_name), spec, lat)
        rows.append(
            {
                "method": f"{algo.upper()} ({block['seeds']} seeds)",
                "nlp_solves": 0,
                "env_steps": block["env_steps"],
                "train_wall_s": block["train_wall_s"],
                "grid_success": block["success_rate"],
                "heldout_success": block["heldout_success_rate"],
                "median_ms": timing["median_ms"],
                "p95_ms": timing["p95_ms"],
                "source": "benchmarks/results/rl_baselines.json",
            }
        )
    return rows


def markdown(rows: list[dict[str, Any]]) -> str:
    def cell(row: dict[str, Any], key: str, fmt: str) -> str:
        value = row.get(key)
        if value is None:
            return "not run" if key == "grid_success" else "—"
        return format(value, fmt)

    lines = [
        "| method | NLP solves | env steps | training wall time (s) | grid success | held-out success "
        "| step latency median / p95 (ms) |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lat = "—" if r.get("median_ms") is None else f"{r['median_ms']:.3g} / {r['p95_ms']:.3g}"
        lines.append(
            f"| {r['method']} | {cell(r, 'nlp_solves', ',')} | {cell(r, 'env_steps', ',')} | "
            f"{cell(r, 'train_wall_s', '.0f')} | {cell(r, 'grid_success', '.1%')} | "
            f"{cell(r, 'heldout_success', '.1%')} | {lat} |"
        )
    return "\n".join(lines)


def learned_spec(block: dict[str, Any]) -> PolicySpec:
    """The shipped network of a ``closed_loop.json`` block, deployed as that benchmark deploys it."""
    options: list[tuple[str, Any]] = [("horizon", int(block["horizon"])), ("trust_region", block["trust_region"])]
    if "goal_blend" in block:
        options.append(("goal_blend", float(block["goal_blend"])))
    return PolicySpec("mpc", "learned", str(ROOT / block["network"]), tuple(options))


def rows_in_env(
    task: Any, env_id: str, starts: np.ndarray, n_grid: int, lat: np.ndarray, quick: bool
) -> list[dict[str, Any]]:
    """Every controller measured in ``env_id`` (another simulator of the task, e.g. the MuJoCo acrobot): the
    shipped learned network and RL models (one each, not a median over seeds), LQR and the full horizon."""
    rows = []
    path = RESULTS / "closed_loop.json"
    block = json.loads(path.read_text()).get(task.name) if path.is_file() else None
    if block:
        row = measured_row(task, "learned", learned_spec(block), starts, n_grid, lat, None, env_id)
        collection, selection = training_env_steps(task.name, block)
        row.update(
            method=f"learned {block['horizon']}-step MPC (shipped network)",
            nlp_solves=int(block["budget"]),
            env_steps=collection + selection,
            collection_env_steps=collection,
            selection_env_steps=selection,
        )
        rows.append(row)
    rows.append(measured_row(task, "LQR", PolicySpec("lqr", "lqr"), starts, n_grid, lat, None, env_id))
    if not quick:
        rows.append(
            measured_row(task, "full-horizon MPC", PolicySpec("full", "full"), starts, n_grid, lat, None, env_id)
        )
    rl = RESULTS / "rl_baselines.json"
    data = json.loads(rl.read_text()).get(task.name, {}) if rl.is_file() else {}
    for algo in ("ppo", "sac"):
        entry = data.get(algo)
        model = ROOT / str(entry.get("model", "")) if entry else None
        if model is None or not model.is_file():
            continue
        spec = PolicySpec("sb3", algo, str(model), (("algo", entry["algo"]),))
        row = measured_row(task, f"{algo.upper()} (shipped model)", spec, starts, n_grid, lat, None, env_id)
        row.update(env_steps=entry["env_steps"], train_wall_s=entry["train_wall_s"])
        rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", default="acrobot")
    parser.add_argument("--latency-starts", type=int, default=20, help="grid starts whose steps are timed")
    parser.add_argument("--quick", action="store_true", help="a 3 x 3 grid, 5 held-out starts, no full horizon")
    parser.add_argument(
        "--env",
        default=None,
        help="run every controller in this env of the task (e.g. SeagulAcrobotMujoco-v0: the MuJoCo physics); "
        "the learned and RL rows are then the shipped network and models, measured here",
    )
    args = parser.parse_args(argv)
    task = make_task(args.task)
    grid_starts, _ = start_grid(task, 3 if args.quick else task.profile.grid.points)
    starts = np.vstack([grid_starts, heldout_starts(task, 5 if args.quick else 100)])
    n_grid = grid_starts.shape[0]
    lat = grid_starts[:: max(1, n_grid // max(1, args.latency_starts))][: args.latency_starts]
    if args.env:
        rows = rows_in_env(task, args.env, starts, n_grid, lat, args.quick)
    else:
        rows = [learned_row(args.task), *sampler_rows(args.task, None if args.quick else lat)]
        rows.append(measured_row(task, "LQR", PolicySpec("lqr", "lqr"), starts, n_grid, lat, None))
        if not args.quick:
            # The closed-loop benchmark's evaluation of the full horizon on these very starts, when committed
            # (the grid and the held-out starts; the glider's took 52 min).
            stored = {"acrobot": "closed_loop_b1000_rest", "glider": "closed_loop_glider"}.get(args.task)
            stored_path = RESULTS / stored / "full-horizon.json" if stored else None
            spec = PolicySpec("full", "full")
            rows.append(measured_row(task, "full-horizon MPC", spec, starts, n_grid, lat, stored_path))
        rows += rl_rows(args.task, lat)
    print(markdown(rows), file=sys.stderr)
    print(json.dumps({"task": args.task, "env": args.env or task.profile.env_id, "rows": rows, "machine": machine()}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
