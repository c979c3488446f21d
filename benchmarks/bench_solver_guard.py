"""What the solve wall-time guard costs per MPC step: the shipped acrobot MPC with and without ``max_solve_time``.

fatrop cannot stop itself inside one iteration (``seagul_control._watchdog``), so a guarded fatrop solve runs in a
forked child and its arguments and results cross a pipe. This benchmark runs the shipped learned 5-step MPC
(``benchmarks/results/closed_loop.json``) with the guard (``MPCOptions(max_solve_time=5)``, the default) and without it
(``max_solve_time=None``) on the same held-out starts, the two controllers interleaved episode by episode so both
see the same machine load, and reports each one's step time (median, p95) and their ratio. Both must take the same
actions (the guard only moves where the solve runs).

    .venv/bin/python benchmarks/bench_solver_guard.py [--quick]

Last line: ``{"guarded": {"median_ms", "p95_ms"}, "unguarded": {...}, "median_ratio", "p95_ratio",
"max_action_difference", "steps", "episodes", "machine"}``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from _common import machine  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="3 episodes instead of 20")
    parser.add_argument("--episodes", type=int, default=None)
    args = parser.parse_args(argv)
    n_ep = args.episodes or (3 if args.quick else 20)

    from seagul_control import LimitedLookaheadMPC
    from seagul_control.evaluation import heldout_starts
    from seagul_control.mpc import MPCOptions
    from seagul_envs import make_task
    from seagul_learn import ValueNetwork

    shipped = json.loads((ROOT / "benchmarks" / "results" / "closed_loop.json").read_text())["acrobot"]
    task = make_task("acrobot")
    network = ValueNetwork.load(ROOT / shipped["network"])
    # fatrop: the guard's forked child exists for it (the condensed solver, the acrobot's default, needs none).
    horizon, guard = int(shipped["horizon"]), shipped["trust_region"]
    mpcs = {
        name: LimitedLookaheadMPC(
            task, network, horizon, MPCOptions(solver="fatrop", max_solve_time=limit), trust_region=guard
        )
        for name, limit in (("guarded", 5.0), ("unguarded", None))
    }
    times: dict[str, list[float]] = {k: [] for k in mpcs}
    diff = 0.0
    starts = heldout_starts(task, n_ep)
    steps = task.num_steps
    dt = task.control_period
    step_fn = task.rk4_step(task.rk4_substeps)
    for x0 in starts:
        for mpc in mpcs.values():
            mpc.reset()
        x = np.asarray(x0, dtype=float)
        for k in range(steps):
            tau = (steps - k) * dt
            actions = {}
            for name, mpc in mpcs.items():
                t0 = time.perf_counter()
                actions[name], _ = mpc.act(x, tau)
                times[name].append(time.perf_counter() - t0)
            diff = max(diff, float(np.max(np.abs(actions["guarded"] - actions["unguarded"]))))
            x = np.asarray(step_fn(x, actions["unguarded"], dt)).ravel()
    out: dict = {}
    for name, ts in times.items():
        arr = np.array(ts[1:]) * 1e3  # the first step of a fresh MPC includes the fork
        out[name] = {"median_ms": round(float(np.median(arr)), 4), "p95_ms": round(float(np.percentile(arr, 95)), 4)}
    out["median_ratio"] = round(out["guarded"]["median_ms"] / out["unguarded"]["median_ms"], 4)
    out["p95_ratio"] = round(out["guarded"]["p95_ms"] / out["unguarded"]["p95_ms"], 4)
    out["max_action_difference"] = diff
    out["steps"] = len(times["guarded"])
    out["episodes"] = n_ep
    out["network"] = shipped["network"]
    out["machine"] = machine()
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
