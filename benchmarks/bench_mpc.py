"""Closed-loop benchmark of the limited-lookahead MPC against LQR and the full-horizon MPC.

Usage::

    .venv/bin/python benchmarks/bench_mpc.py [--quick] [--workers 2] [--network-acrobot PATH] [--network-glider PATH]

Without ``--network-*`` a value network is trained first with :func:`seagul_learn.training.train` (SEAGuL
adversarial sampling; ``--quick``: a small budget and no validation set, full run: the paper's 100 solves), cached
under ``--work-dir`` so a second run reuses it. Then, through the Gymnasium envs:

* acrobot: every policy from an ``n x n`` grid of ``(th1, th2)`` in X0 at zero velocity (``--quick`` 6, else 20),
  5 s, success ``||x(5 s) - x*|| < 0.05``;
* glider: an ``n x n`` grid of ``(x, z)`` in X0 (``--quick`` 2, else 6), 0.8 s, trajectory cost and perch success.

Step times are the solver wall times of every MPC step inside those closed loops, measured in one process
(``workers=1``) for the timed MPC so that parallel episodes do not share its cores; the slow references run on
``--workers`` processes. The MPC with each trust-region guard (``lqr``, ``box``, ``none``) is reported
under ``"trust_region"``; only the ``lqr`` one is JIT-compiled (the other two run interpreted: their step times are
not comparable, their success rates are). The last line of stdout is one JSON object::

    {"acrobot": {"median_ms", "p95_ms", "success_rate", "lqr_success_rate", "full_horizon_success_rate", ...},
     "glider": {"median_ms", "p95_ms", "perch_success_rate", "mean_cost", "full_horizon_mean_cost", ...},
     "machine": {...}}
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._common import machine
from seagul_control.evaluation import PolicySpec, evaluate, start_grid
from seagul_envs import make_task
from seagul_learn.report import summarize, write_outputs

GUARDS = ("lqr", "box", "none")


def train_network(task: str, budget: int, quick: bool, work_dir: Path) -> Path:
    """Train (or reuse) a SEAGuL value network; returns the ``network.pt`` path."""
    from seagul_learn import RuntimeConfig
    from seagul_learn.training import TrainConfig, train

    out = work_dir / f"{task}_adv{budget}{'_quick' if quick else ''}"
    network = out / "network.pt"
    if network.is_file():
        return network
    config = TrainConfig(
        task=task,
        sampler="adversarial",
        budget=budget,
        validate=not quick,
        runtime=RuntimeConfig(progress=False, workers=1),
    )
    train(config, out, resume=(out / "checkpoint.pt").is_file())
    return network


def run_task(
    task_name: str, network: Path, grid_n: int, workers: int, out_dir: Path, full_horizon: bool
) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """Evaluate the MPC variants and references on one task; returns the JSON block and the summary rows."""
    task = make_task(task_name)
    starts, grid = start_grid(task, grid_n)
    record = task.profile.trajectory_plot is not None  # the report draws this task's recorded trajectories
    main = PolicySpec("mpc", "seagul-mpc", str(network), (("trust_region", "lqr"), ("jit", True)))
    variants = [
        PolicySpec("mpc", f"seagul-mpc[{g}]", str(network), (("trust_region", g), ("jit", False))) for g in GUARDS[1:]
    ]
    # LQR at an equilibrium goal, time-varying LQR along a nominal trajectory otherwise (LQRPolicy decides).
    ref_name = "lqr" if task.goal_is_equilibrium() else "tvlqr"
    refs = [PolicySpec("lqr", ref_name)]
    if full_horizon:
        refs.append(PolicySpec("full", "full-horizon"))
    t0 = time.perf_counter()
    results = evaluate(task_name, [main], starts, workers=1, progress=False, record=record)
    timed = time.perf_counter() - t0
    results += evaluate(task_name, variants + refs, starts, workers=workers, progress=False, record=record)
    write_outputs(out_dir / task_name, task_name, results, grid)
    rows = {r["policy"]: r for r in summarize(task_name, results)}
    m = rows["seagul-mpc"]
    block: dict[str, Any] = {
        "median_ms": round(m["median_step_ms"], 4),
        "p95_ms": round(m["p95_step_ms"], 4),
        "max_ms": round(m["max_step_ms"], 4),
        "fallback_steps": m["fallback_steps"],
        "steps": m["steps"],
        "grid": f"{grid_n}x{grid_n}",
        "network": str(network),
        "timed_wall_s": round(timed, 2),
    }
    if task.goal_is_equilibrium():  # swing up and balance (acrobot); else reach a region (glider: perch)
        block["success_rate"] = m["success_rate"]
        block["lqr_success_rate"] = rows[ref_name]["success_rate"]
        block["full_horizon_success_rate"] = rows["full-horizon"]["success_rate"] if full_horizon else None
    else:
        block["perch_success_rate"] = m["success_rate"]
        block["mean_cost"] = round(m["mean_cost"], 4)
        block["full_horizon_mean_cost"] = round(rows["full-horizon"]["mean_cost"], 4) if full_horizon else None
        block["full_horizon_perch_success_rate"] = rows["full-horizon"]["success_rate"] if full_horizon else None
        block["tvlqr_mean_cost"] = round(rows[ref_name]["mean_cost"], 4)
        block["tvlqr_perch_success_rate"] = rows[ref_name]["success_rate"]
    block["trust_region"] = {
        "lqr": {"success_rate": m["success_rate"], "mean_cost": round(m["mean_cost"], 4)},
        **{
            g: {
                "success_rate": rows[f"seagul-mpc[{g}]"]["success_rate"],
                "mean_cost": round(rows[f"seagul-mpc[{g}]"]["mean_cost"], 4),
                "crashes": rows[f"seagul-mpc[{g}]"]["crashes"],
            }
            for g in GUARDS[1:]
        },
    }
    return block, list(rows.values())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="coarse grids and small training budgets (~15 min)")
    parser.add_argument("--workers", type=int, default=2, help="processes for the reference policies")
    parser.add_argument("--network-acrobot", type=Path, default=None, help="use this acrobot network (no training)")
    parser.add_argument("--network-glider", type=Path, default=None, help="use this glider network (no training)")
    parser.add_argument("--work-dir", type=Path, default=Path("runs/bench_mpc"), help="networks and outputs")
    parser.add_argument("--tasks", default="acrobot,glider", help="comma-separated subset of acrobot,glider")
    parser.add_argument("--no-full-horizon", action="store_true", help="skip the (slow) full-horizon reference")
    args = parser.parse_args(argv)
    if args.workers < 1:
        parser.error(f"--workers must be >= 1, got {args.workers}")
    tasks = [t.strip() for t in args.tasks.split(",") if t.strip()]
    if not set(tasks) <= {"acrobot", "glider"}:
        parser.error(f"--tasks must name acrobot and/or glider, got {args.tasks!r}")
    args.work_dir.mkdir(parents=True, exist_ok=True)
    # This benchmark's own settings per built-in task (the paper's 100 solves; --quick shrinks them); the full grid
    # is the task's evaluation grid (profile), --quick a third of it.
    budgets = {"acrobot": 40 if args.quick else 100, "glider": 30 if args.quick else 100}
    grids = {t: max(2, make_task(t).profile.grid.points // (3 if args.quick else 1)) for t in tasks}
    given = {"acrobot": args.network_acrobot, "glider": args.network_glider}
    out: dict[str, Any] = {}
    for task in tasks:
        t0 = time.perf_counter()
        network = given[task] or train_network(task, budgets[task], args.quick, args.work_dir)
        trained = time.perf_counter() - t0
        block, rows = run_task(
            task,
            network,
            grids[task],
            args.workers,
            args.work_dir / ("quick" if args.quick else "full"),
            not args.no_full_horizon,
        )
        block["training_s"] = round(trained, 1)
        block["budget_solves"] = None if given[task] else budgets[task]
        block["wall_s"] = round(time.perf_counter() - t0, 1)
        for row in rows:
            print(
                f"{task} {row['policy']}: success {row['success_rate']:.1%}, mean cost {row['mean_cost']:.4g}, "
                f"mean final distance {row['mean_final_distance']:.4g}, step median {row['median_step_ms']:.3g} ms "
                f"p95 {row['p95_step_ms']:.3g} ms, fallbacks {row['fallback_steps']}/{row['steps']}",
                flush=True,
            )
        out[task] = block
    out["machine"] = machine()
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
