"""Every controller against the baselines a reviewer asks for, on the same starts, in one run per task.

Usage::

    .venv/bin/python benchmarks/bench_baselines.py [--tasks acrobot,glider] [--horizons 3,5,10,20]
        [--do-mpc-horizons 5,10,20] [--latency-starts 20] [--workers 2] [--out runs/baselines] [--quick]
        [--json benchmarks/results/baselines.json]

Rows per task (``kind``):

* ``learned-mpc``: the shipped value network (``benchmarks/results/closed_loop.json``) as the terminal cost of the
  project's MPC, at every horizon of ``--horizons`` (the network is trained once; only the lookahead changes).
* ``quadratic-mpc``: the same MPC with the task's quadratic (LQR) terminal cost ``(x - x*)' Qf (x - x*)``, the
  controller a control engineer writes first, at the same horizons.
* ``do-mpc``: do-mpc (IPOPT) on the same discrete model, stage cost and quadratic terminal cost, at
  ``--do-mpc-horizons`` (the optional extra ``pip install 'seagul[anchors]'``; skipped with a message without it).
* ``full-horizon``: the MPC that re-solves the whole remaining horizon every step (the reference).
* ``lqr``: the task's discrete-time LQR at the goal, torque clipped to the actuator's range.
* ``ppo``, ``sac``: the models of ``benchmarks/bench_rl_baselines.py`` (``rl_baselines.json``), loaded as a user
  loads them (``SB3Policy``: the model, its observation statistics and its learner view).

Every row is evaluated on the task's evaluation grid (acrobot 20 x 20 over ``(th1, th2)`` at rest, glider 6 x 6)
and on the 100 held-out X0 starts (seed 20211231); the full horizon on the grid only, its held-out success from the
committed closed-loop benchmark's evaluation of the same starts (it takes 40 ms a step on the acrobot, 0.6 s on the
glider). ``success_at`` re-judges the grid episodes at other tolerances: the acrobot's rule
``||x(T) - x*|| < tol``; the glider's perch rule with every tolerance scaled by ``tol / 0.05`` (position within
``tol`` m, speeds within ``40 tol`` m/s: at 0.05, the task's rule). ``tolerance_reached`` is, per grid episode, the
smallest such ``tol`` it meets (the acrobot's final distance; infinite for a glider crash): the CDF figure draws it.
Both are library functions (:func:`seagul_control.evaluation.success_at`,
:func:`seagul_control.evaluation.tolerance_reached`). Step time is each controller's own computation per step
(``predict``), measured in this process on ``--latency-starts`` grid starts, one controller after the other, so the
ratios are side by side; the machine record has the load.

Each row's episodes are kept in ``--out`` (a re-run reuses them, so an interrupted run resumes); ``--kinds ppo,sac``
with an existing ``--json`` re-measures those rows and keeps the others (``machine`` stays the earlier run's; the
refresh's is under ``refreshed``). The last line of stdout is the JSON written to ``--json``:
``{"acrobot": {"rows": [...]}, "glider": {"rows": [...]}, "machine"}``, each row ``{"controller", "kind",
"horizon", "success", "heldout_success", "success_at", "median_final_distance", "median_ms", "p95_ms", "seeds",
"env_steps", "solves", "model", ...}``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._common import machine  # noqa: E402
from benchmarks.bench_controllers import _Timed, learned_spec, training_env_steps  # noqa: E402
from seagul_control.evaluation import (  # noqa: E402
    SUCCESS_TOLERANCES,
    PolicySpec,
    build_policy,
    evaluate,
    heldout_starts,
    run_policy_episode,
    start_grid,
    success_at,
    tolerance_reached,
)
from seagul_control.io import atomic_write_json  # noqa: E402
from seagul_envs import make_task  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
KINDS = ("learned-mpc", "quadratic-mpc", "do-mpc", "full-horizon", "lqr", "ppo", "sac")
#: Where the committed closed-loop benchmark keeps the full horizon's held-out evaluation of the same starts.
STORED_FULL = {
    "acrobot": "closed_loop_b1000_rest/full-horizon.json",
    "glider": "closed_loop_glider/full-horizon.json",
}


@dataclass
class Row:
    """One controller of the table: how to build it and what it cost to make."""

    controller: str
    kind: str
    spec: PolicySpec | None
    horizon: int | None = None
    seeds: int = 1
    env_steps: int = 0
    solves: int = 0
    model: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)


# ------------------------------------------------------------------------------------------------ rows
def shipped_block(task_name: str) -> dict[str, Any]:
    block = json.loads((RESULTS / "closed_loop.json").read_text())[task_name]
    return dict(block)


def rows_of(task_name: str, horizons: list[int], do_mpc_horizons: list[int], rl: dict[str, Any]) -> list[Row]:
    """Every row of a task (module docstring)."""
    block = shipped_block(task_name)
    collection, selection = training_env_steps(task_name, block)
    rows = []
    for n in horizons:
        rows.append(
            Row(
                f"learned {n}-step MPC",
                "learned-mpc",
                replace(learned_spec({**block, "horizon": n}), label=f"learned-{n}"),
                horizon=n,
                seeds=int(block["seeds"]),
                env_steps=collection + selection,
                solves=int(block["budget"]),
                model=block["network"],
                extra={"trained_for_horizon": int(block["horizon"]), "recipe": block["method"]},
            )
        )
    for n in horizons:
        spec = PolicySpec("mpc", f"quadratic-{n}", None, (("horizon", n),))
        rows.append(Row(f"quadratic-terminal {n}-step MPC", "quadratic-mpc", spec, horizon=n, seeds=0))
    for n in do_mpc_horizons:
        spec = PolicySpec("do-mpc", f"do-mpc-{n}", None, (("horizon", n),))
        rows.append(Row(f"do-mpc {n}-step MPC (IPOPT)", "do-mpc", spec, horizon=n, seeds=0))
    rows.append(Row("full-horizon MPC", "full-horizon", PolicySpec("full", "full"), seeds=0))
    rows.append(Row("LQR", "lqr", PolicySpec("lqr", "lqr"), seeds=0))
    for algo in ("ppo", "sac"):
        entry = rl.get(task_name, {}).get(algo)
        if not entry or not (ROOT / entry["model"]).is_file():
            print(f"{task_name}: no {algo.upper()} model (run benchmarks/bench_rl_baselines.py)", file=sys.stderr)
            continue
        spec = PolicySpec("sb3", algo, str(ROOT / entry["model"]), (("algo", entry["algo"]),))
        rows.append(
            Row(
                f"{algo.upper()} (shipped seed of {entry['seeds']})",
                algo,
                spec,
                seeds=int(entry["seeds"]),
                env_steps=int(entry["env_steps"]),
                model=entry["model"],
                extra={
                    "seed_median_success": entry["success_rate"],
                    "seed_median_heldout_success": entry["heldout_success_rate"],
                    "train_wall_s": entry["train_wall_s"],
                },
            )
        )
    return rows


def _episode(result: Any) -> dict[str, Any]:
    return {
        "final_state": [float(v) for v in result.final_state],
        "final_distance": float(result.final_distance),
        "success": bool(result.success),
        "terminated": bool(result.terminated),
        "fallbacks": int(result.fallbacks),
    }


def episodes_of(task: Any, row: Row, starts: np.ndarray, out: Path, workers: int) -> list[dict[str, Any]]:
    """The row's episodes from ``starts`` (stored in ``out`` for the same starts, else run and stored)."""
    path = out / f"{row.spec.label}.json"  # type: ignore[union-attr]
    key = {"spec": repr(row.spec), "starts": np.round(starts, 12).tolist()}
    if path.is_file():
        stored = json.loads(path.read_text())
        if stored.get("key") == key:
            return list(stored["episodes"])
    t = time.perf_counter()
    results = evaluate(task, [row.spec], starts, workers=workers, progress=False)  # type: ignore[list-item]
    episodes = [_episode(r) for r in results]
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(path, {"key": key, "episodes": episodes, "wall_s": time.perf_counter() - t})
    return episodes


def step_times(task: Any, spec: PolicySpec, starts: np.ndarray) -> dict[str, float]:
    """Median and p95 (ms) of the controller's computation per step over episodes from ``starts``."""
    timed = _Timed(build_policy(task, spec))
    for x0 in starts:
        run_policy_episode(task, timed, x0)
    ms = np.asarray(timed.times) * 1e3
    return {"median_ms": float(np.median(ms)), "p95_ms": float(np.percentile(ms, 95)), "timed_steps": int(ms.size)}


def measure(task: Any, row: Row, grid: np.ndarray, held: np.ndarray, lat: np.ndarray, out: Path, workers: int):
    """The JSON row of ``row``: episodes on the grid and held-out starts, success at the tolerances, step times."""
    assert row.spec is not None
    grid_eps = episodes_of(task, row, grid, out / "grid", workers)
    stored_held = STORED_FULL.get(task.name) if row.kind == "full-horizon" else None
    if stored_held is not None:
        held_success = float(json.loads((RESULTS / stored_held).read_text())["heldout_success_rate"])
        held_source: str | None = f"benchmarks/results/{stored_held}"
    else:
        held_eps = episodes_of(task, row, held, out / "heldout", workers)
        held_success, held_source = float(np.mean([e["success"] for e in held_eps])), None
    reached = sorted(tolerance_reached(task, e["final_state"], e["terminated"]) for e in grid_eps)
    payload = {
        "controller": row.controller,
        "kind": row.kind,
        "horizon": row.horizon,
        "success": float(np.mean([e["success"] for e in grid_eps])),
        "heldout_success": held_success,
        "success_at": success_at(task, grid_eps),
        "median_final_distance": float(np.median([e["final_distance"] for e in grid_eps])),
        **step_times(task, row.spec, lat),
        "seeds": row.seeds,
        "env_steps": row.env_steps,
        "solves": row.solves,
        "model": row.model,
        "fallback_steps": int(sum(e["fallbacks"] for e in grid_eps)),
        "crash_rate": float(np.mean([e["terminated"] for e in grid_eps])),
        "tolerance_reached": [round(v, 5) if np.isfinite(v) else None for v in reached],
        **row.extra,
    }
    if held_source:
        payload["heldout_source"] = held_source
    return payload


def markdown(rows: list[dict[str, Any]]) -> str:
    lines = [
        "| controller | N | success | held-out | @0.1 | @0.2 | @0.5 | median final dist. | step ms median / p95 |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        at = r["success_at"]
        lines.append(
            f"| {r['controller']} | {r['horizon'] or '—'} | {r['success']:.1%} | {r['heldout_success']:.1%} | "
            f"{at['0.1']:.1%} | {at['0.2']:.1%} | {at['0.5']:.1%} | {r['median_final_distance']:.3g} | "
            f"{r['median_ms']:.3g} / {r['p95_ms']:.3g} |"
        )
    return "\n".join(lines)


def plot_cdf(task_name: str, rows: list[dict[str, Any]], path: Path) -> None:
    """CDF of the tolerance reached per controller (acrobot: the final distance), one line per controller.

    matplotlib is imported here, not at the top: only a run that writes ``--json`` draws (the module's one
    function-level import besides the optional do-mpc check in :func:`main`)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    styles = {"learned-mpc": "-", "quadratic-mpc": "--", "do-mpc": ":", "full-horizon": "-", "lqr": "-."}
    fig, ax = plt.subplots(figsize=(10, 4.5))
    for r in rows:
        reached = np.array([np.inf if v is None else v for v in r["tolerance_reached"]])
        xs = np.sort(reached[np.isfinite(reached)])
        ys = np.arange(1, xs.size + 1) / reached.size
        label = r["controller"]
        width = 2.2 if r["kind"] in ("full-horizon",) else 1.4
        ax.step(xs, ys, where="post", ls=styles.get(r["kind"], "-"), lw=width, label=label)
    for tol in SUCCESS_TOLERANCES:
        ax.axvline(float(tol), color="0.8", lw=0.8, zorder=0)
    ax.set_xscale("log")
    ax.set_xlim(1e-3, 20)
    ax.set_ylim(0, 1.02)
    what = "final distance ||x(T) - x*||" if task_name == "acrobot" else "perch tolerance met (m; speeds x 40)"
    ax.set_xlabel(what)
    ax.set_ylabel("fraction of grid starts")
    ax.set_title(f"{task_name}: closed-loop final state, every controller (grid starts)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _ints(text: str, name: str) -> list[int]:
    try:
        values = [int(v) for v in text.split(",") if v]
    except ValueError:
        raise SystemExit(f"{name}: expected comma-separated integers, got {text!r}") from None
    if any(v < 1 for v in values):
        raise SystemExit(f"{name}: horizons must be >= 1, got {values}")
    return values


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", default="acrobot,glider")
    parser.add_argument("--horizons", default="3,5,10,20")
    parser.add_argument("--do-mpc-horizons", default="5,10,20")
    parser.add_argument("--latency-starts", type=int, default=20)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "baselines")
    parser.add_argument("--quick", action="store_true", help="a 3 x 3 grid, 4 held-out starts, 2 timed starts")
    parser.add_argument("--json", type=Path, default=None, help="write the result JSON here (CDF figures beside)")
    parser.add_argument(
        "--kinds", default=",".join(KINDS), help="only these kinds (with --json: they replace its rows of those kinds)"
    )
    args = parser.parse_args(argv)
    horizons = _ints(args.horizons, "--horizons")
    do_mpc_horizons = _ints(args.do_mpc_horizons, "--do-mpc-horizons")
    kinds = [k for k in args.kinds.split(",") if k]
    unknown = sorted(set(kinds) - set(KINDS))
    if unknown:
        parser.error(f"unknown kinds {unknown}; choose from {list(KINDS)}")
    if "do-mpc" in kinds:
        try:
            import do_mpc  # noqa: F401
        except ImportError:
            print("do-mpc rows skipped: do-mpc is not installed (pip install 'seagul[anchors]')", file=sys.stderr)
            kinds.remove("do-mpc")
    rl_path = RESULTS / "rl_baselines.json"
    rl = json.loads(rl_path.read_text()) if rl_path.is_file() else {}
    result: dict[str, Any] = json.loads(args.json.read_text()) if args.json and args.json.is_file() else {}
    for task_name in [t for t in args.tasks.split(",") if t]:
        task = make_task(task_name)
        grid, _ = start_grid(task, 3 if args.quick else task.profile.grid.points)
        held = heldout_starts(task, 4 if args.quick else 100)
        lat = grid[:: max(1, len(grid) // max(1, args.latency_starts))][: 2 if args.quick else args.latency_starts]
        rows = [r for r in rows_of(task_name, horizons, do_mpc_horizons, rl) if r.kind in kinds]
        if args.quick:
            rows = [r for r in rows if r.kind != "full-horizon"]
        out = args.out / ("quick" if args.quick else "full") / task_name
        measured = []
        for row in rows:
            t = time.perf_counter()
            measured.append(measure(task, row, grid, held, lat, out, args.workers))
            print(
                f"{task_name}: {row.controller}: {measured[-1]['success']:.1%} ({time.perf_counter() - t:.0f} s)",
                file=sys.stderr,
                flush=True,
            )
        print(markdown(measured), file=sys.stderr)
        stored_rows = result.get(task_name, {}).get("rows", [])
        if set(kinds) != set(KINDS) and stored_rows:
            # A refresh of some kinds: their rows replace the stored ones of the same kind, the others stay.
            fresh = {r["kind"] for r in measured}
            merged = [r for r in stored_rows if r["kind"] not in fresh]
            order = {k: i for i, k in enumerate(KINDS)}
            measured = sorted([*merged, *measured], key=lambda r: (order[r["kind"]], r["horizon"] or 0))
        result[task_name] = {"rows": measured, "grid_starts": len(grid), "heldout_starts": len(held)}
        if args.json is not None:
            plot_cdf(task_name, measured, args.json.with_name(f"baselines_cdf_{task_name}.png"))
    if set(kinds) != set(KINDS) and "machine" in result:
        result["refreshed"] = {"kinds": sorted(kinds), "machine": machine("torch", "stable_baselines3")}
    else:
        result["machine"] = machine("torch", "stable_baselines3")
        result.pop("refreshed", None)
    if args.json is not None:
        atomic_write_json(args.json, result, indent=1)
    print(json.dumps({k: v for k, v in result.items()}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
