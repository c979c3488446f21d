"""The acrobot's learned 5-step MPC on each lookahead solver, side by side: the same network, starts and settings.

The condensed solver (``solver="shooting"``, ``seagul_control/shooting.py``) and fatrop solve the same NLP (the
lifted multiple-shooting transcription vs its inputs alone). This benchmark runs the shipped network
(``benchmarks/results/closed_loop.json``, deployed as there: unguarded, the task's goal blend, compiled) with each
solver in one process, one after the other, over the 20 x 20 grid and the 100 held-out starts, and reports each
one's success, fallback steps and step time (median, p95), and on how many grid starts the two agree.

    .venv/bin/python benchmarks/bench_mpc_solvers.py [--quick] [--solvers shooting,shooting:never,fatrop]
        [--network PATH]

A solver may carry the MPC's ``multistart`` mode after a colon (``shooting:never``, ``shooting:always``; plain
``shooting`` is the default, ``"rise"``: extra starts from the input bounds at a cold start and when the warm plan's
cost rose).

Last line: ``{"solvers": {NAME: {"success_rate", "heldout_success_rate", "median_ms", "p95_ms", "fallback_steps",
"multistart_steps", "steps", "wall_s"}}, "grid_agreement", "network", "grid", "heldout", "machine"}``
(``grid_agreement``: the fraction of grid starts on which the first two entries agree).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from _common import machine  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a 4 x 4 grid and 4 held-out starts")
    parser.add_argument(
        "--solvers",
        default="shooting,shooting:never,fatrop",
        help="comma-separated LimitedLookaheadMPC solvers, each optionally with ':<multistart mode>'",
    )
    parser.add_argument("--network", default=None, help="value network file (default: closed_loop.json's acrobot)")
    args = parser.parse_args(argv)

    from seagul_control.evaluation import PolicySpec, evaluate, heldout_starts, start_grid
    from seagul_envs import make_task

    shipped = json.loads((ROOT / "benchmarks" / "results" / "closed_loop.json").read_text())["acrobot"]
    network = args.network or str(ROOT / shipped["network"])
    task = make_task("acrobot")
    n_grid, n_held = (4, 4) if args.quick else (task.profile.grid.points, 100)
    grid, _ = start_grid(task, n_grid)
    starts = np.vstack([grid, heldout_starts("acrobot", n_held)])
    options: tuple[tuple[str, object], ...] = (
        ("horizon", int(shipped["horizon"])),
        ("trust_region", shipped["trust_region"]),
        ("goal_blend", float(shipped.get("goal_blend", task.profile.mpc.goal_blend))),
        ("jit", True),
    )
    rows: dict[str, dict[str, object]] = {}
    grid_success: dict[str, np.ndarray] = {}
    for entry in [s for s in args.solvers.split(",") if s]:
        solver, _, mode = entry.partition(":")
        chosen = (("solver", solver), *((("multistart", mode),) if mode else ()))
        spec = PolicySpec("mpc", entry, network, (*options, *chosen))
        t0 = time.perf_counter()
        results = evaluate("acrobot", [spec], starts, workers=1, progress=False)
        wall = time.perf_counter() - t0
        times = np.array([t for r in results for t in r.solve_times]) * 1e3
        on_grid, held = results[: len(grid)], results[len(grid) :]
        grid_success[entry] = np.array([r.success for r in on_grid])
        rows[entry] = {
            "success_rate": float(grid_success[entry].mean()),
            "heldout_success_rate": float(np.mean([r.success for r in held])),
            "median_ms": float(np.median(times)),
            "p95_ms": float(np.percentile(times, 95)),
            "fallback_steps": int(sum(r.fallbacks for r in results)),
            "multistart_steps": int(sum(r.multistart_steps for r in results)),
            "steps": int(times.size),
            "wall_s": round(wall, 1),
        }
        print(f"[bench] {entry}: {rows[entry]}", file=sys.stderr, flush=True)
    names = list(grid_success)
    agreement = float(np.mean(grid_success[names[0]] == grid_success[names[1]])) if len(names) >= 2 else float("nan")
    out = {
        "solvers": rows,
        "grid_agreement": agreement,
        "network": str(Path(network).resolve().relative_to(ROOT))
        if Path(network).resolve().is_relative_to(ROOT)
        else network,
        "grid": f"{n_grid}x{n_grid}",
        "heldout": n_held,
        "machine": machine(),
    }
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
