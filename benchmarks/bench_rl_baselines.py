"""RL baselines by the book: SB3 PPO and SAC on the seagul envs, learning curves over seeds, selected models shipped.

Usage::

    .venv/bin/python benchmarks/bench_rl_baselines.py [--tasks acrobot,glider] [--algos PPO,SAC] [--seeds 5]
        [--steps acrobot:PPO=2000000,acrobot:SAC=40000,...] [--out runs/rl] [--quick] [--no-ship]
        [--json benchmarks/results/rl_baselines.json] [--plot-only]
    .venv/bin/python benchmarks/bench_rl_baselines.py --sweep 1000000 [--reuse-only] --json ...   # the PPO sweep

Every run is :func:`seagul_learn.baselines.train_sb3` with the tuned entry of the task's env id in
``seagul_learn/hyperparams/{ppo,sac}.yml`` (the learner's view, a bounded success-aware reward, rl-zoo sizes): its
learning curve is measured on the validation starts (``validation_starts``: their own stream, never the grid or
the held-out starts) and its checkpoint is selected on them. Each seed's selected model is then evaluated as a user
loads it (``SB3Policy``: model + statistics + view) on the task's evaluation grid and on the 100 held-out starts.
The shipped model of a task and algorithm is the seed with the best validation point (ties: the lower median
miss), copied with its statistics and view to ``benchmarks/results/models/<task>_<algo>/``.

A run directory with a ``curve.json`` of the same config is reused, so an interrupted benchmark resumes at the
run it was in; a larger ``--steps`` budget extends the stored runs from their final models
(:func:`seagul_learn.baselines.extendable_run`) instead of training them again.

Figure: ``rl_curves_<task>.png`` (validation success and median miss of the success rule against environment
steps: median and range over seeds). The last line of stdout is the JSON written to ``--json``::

    {"acrobot": {"ppo": {"algo", "env_steps", "seeds", "success_rate", "heldout_success_rate", "per_seed": [...],
                         "curves": [[...], ...], "model", "settings", "train_wall_s"}, "sac": {...}},
     "glider": {...}, "machine": {...}}

``success_rate`` and ``heldout_success_rate`` are medians over seeds of the selected models.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._common import machine  # noqa: E402
from seagul_control.evaluation import heldout_starts, start_grid  # noqa: E402
from seagul_control.io import atomic_write_json, atomic_write_text  # noqa: E402
from seagul_learn.baselines import (  # noqa: E402
    ALGOS,
    SB3Config,
    episode_stats,
    extendable_run,
    smoke_config,
    task_of_env,
    train_sb3,
)
from seagul_learn.policies import SB3Policy  # noqa: E402

#: Environment steps per task and algorithm of the committed run (see the docs' results page for why not more). The
#: acrobot's PPO seeds were trained to 2 M steps and then extended from their final models in steps of 2 M
#: (``--steps acrobot:PPO=4000000``, then 6 M, 8 M): the same runs, continued.
FULL_STEPS: dict[str, dict[str, int]] = {
    "acrobot": {"PPO": 8_000_000, "SAC": 40_000},
    "glider": {"PPO": 500_000, "SAC": 20_000},
}
QUICK_STEPS: dict[str, dict[str, int]] = {"acrobot": {"PPO": 4_096, "SAC": 400}, "glider": {"PPO": 4_096, "SAC": 400}}
TASKS = tuple(FULL_STEPS)
#: One-seed variations of the tuned PPO acrobot entry (``--sweep``): what might close the gap to the 0.05 rule. The
#: tuned entry itself is seed 0 of the main run (the same run up to the sweep's budget: constant learning rate).
SWEEP: dict[str, dict[str, Any]] = {
    "end_scale=2": {"view_overrides": {"end_scale": 2.0}},
    "sharp (step_scale=1, end_scale=2, success_bonus=2)": {
        "view_overrides": {"step_scale": 1.0, "end_scale": 2.0, "success_bonus": 2.0}
    },
    "ent_coef=0": {"algo_overrides": {"ent_coef": 0.0}},
}
ENV_IDS = {"acrobot": "SeagulAcrobot-v0", "glider": "SeagulGlider-v0"}
SHIP_DIR = ROOT / "benchmarks" / "results" / "models"


def config_of(task: str, algo: str, seed: int, steps: int, quick: bool) -> SB3Config:
    """The run of ``algo`` on ``task``'s env with ``seed`` and ``steps`` (``quick``: tiny networks and batches)."""
    config = SB3Config(algo=algo, env_id=ENV_IDS[task], total_timesteps=steps, seed=seed)
    if quick:
        config = smoke_config(config)
        config = SB3Config(**{**config.to_dict(), "total_timesteps": steps, "eval_every": max(steps // 2, 1)})
    return config


def run_seed(config: SB3Config, out: Path, n_heldout: int = 100) -> dict[str, Any]:
    """Train (or reuse) one run, then evaluate its selected model on the grid and the held-out starts."""
    done = out / "result.json"
    if done.is_file():
        stored = json.loads(done.read_text())
        if stored.get("config") == config.to_dict():
            return stored
        if extendable_run(config, out) is None:
            shutil.rmtree(out)  # another config's run: train this one in its place
        # else: the same run with a smaller budget; train_sb3 continues it from its final model
    summary = train_sb3(config, out, on_point=lambda row: print(f"{out}: {row}", file=sys.stderr, flush=True))
    task = task_of_env(config.env_id)
    policy = SB3Policy(task, summary["model"], algo=config.algo)
    grid, _ = start_grid(task, task.profile.grid.points)
    result = {
        **summary,
        "grid": episode_stats(task, policy, grid),
        "heldout": episode_stats(task, policy, heldout_starts(task, n_heldout)),
    }
    atomic_write_json(done, result, indent=1)
    return result


def best_run(runs: list[dict[str, Any]]) -> int:
    """The index of the run shipped among seeds: the best validation point (ties: the lower median miss)."""
    return max(range(len(runs)), key=lambda i: (runs[i]["best"]["success_rate"], -runs[i]["best"]["median_miss"]))


def summarise(task: str, algo: str, runs: list[dict[str, Any]], ship: bool) -> dict[str, Any]:
    """The block of one task and algorithm: medians over seeds, per-seed rows, curves, the shipped model."""
    best = best_run(runs)
    model = runs[best]["model"]
    if ship:
        target = SHIP_DIR / f"{task}_{algo.lower()}"
        if target.exists():
            shutil.rmtree(target)
        shutil.copytree(Path(model).parent, target)
        model = str((target / "model.zip").relative_to(ROOT))
    return {
        "algo": algo,
        "env_id": ENV_IDS[task],
        "env_steps": int(runs[0]["env_steps"]),
        "seeds": len(runs),
        "success_rate": float(np.median([r["grid"]["success_rate"] for r in runs])),
        "heldout_success_rate": float(np.median([r["heldout"]["success_rate"] for r in runs])),
        "median_final_distance": float(np.median([r["heldout"]["median_final_distance"] for r in runs])),
        "train_wall_s": float(np.median([r["train_wall_s"] for r in runs])),
        "shipped_seed": int(runs[best]["config"]["seed"]),
        "model": model,
        "settings": runs[0]["resolved"],
        "per_seed": [
            {
                "seed": r["config"]["seed"],
                "selected_at": r["best"]["env_steps"],
                "validation": r["best"],
                "grid": r["grid"],
                "heldout": r["heldout"],
            }
            for r in runs
        ],
        "curves": [r["curve"] for r in runs],
    }


def plot(task: str, block: dict[str, Any], path: Path) -> None:
    """Validation success and median miss against environment steps, median and range over seeds."""
    import matplotlib  # here, not at the top: only a run that writes --json draws

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    for key, color in (("ppo", "C0"), ("sac", "C3")):
        if key not in block:
            continue
        curves = block[key]["curves"]
        n = min(len(c) for c in curves)
        steps = np.array([p["env_steps"] for p in curves[0][:n]])
        for ax, metric in zip(axes, ("success_rate", "median_miss"), strict=True):
            values = np.array([[p[metric] for p in c[:n]] for c in curves])
            ax.plot(steps, np.median(values, axis=0), color=color, label=f"{key.upper()} ({len(curves)} seeds)")
            ax.fill_between(steps, values.min(axis=0), values.max(axis=0), color=color, alpha=0.2)
    axes[0].set_ylabel("validation success")
    axes[0].set_ylim(-0.02, 1.02)
    axes[1].set_ylabel("median miss of the rule (tolerances)")
    axes[1].set_yscale("symlog", linthresh=0.1)  # a miss of 0 is success
    for ax in axes:
        ax.set_xlabel("environment steps")
        ax.set_xscale("log")
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.suptitle(f"{task}: RL learning curves on the validation starts (median, range over seeds)")
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def sweep(args: argparse.Namespace) -> int:
    """One seed (0) of each :data:`SWEEP` variation of the acrobot PPO entry at ``--sweep`` steps."""
    rows = {}
    for name, change in SWEEP.items():
        config = SB3Config(algo="PPO", env_id=ENV_IDS["acrobot"], total_timesteps=args.sweep, seed=0, **change)
        out = args.out / "sweep" / name.split(" ")[0].replace("=", "_")
        if args.reuse_only and not (out / "result.json").is_file():
            partial = out / "curve.partial.json"
            curve = json.loads(partial.read_text())["curve"] if partial.is_file() else []
            rows[name] = {"change": change, "complete": False, "curve": curve}
            print(f"sweep {name}: not finished ({len(curve)} curve points kept)", file=sys.stderr)
            continue
        run = run_seed(config, out)
        rows[name] = {
            "change": change,
            "complete": True,
            "env_steps": run["env_steps"],
            "selected_at": run["best"]["env_steps"],
            "validation": run["best"],
            "grid": run["grid"],
            "heldout": run["heldout"],
            "curve": run["curve"],
        }
        print(
            f"sweep {name}: grid {run['grid']['success_rate']:.1%}, median final distance "
            f"{run['grid']['median_final_distance']:.3g}",
            file=sys.stderr,
            flush=True,
        )
    if args.json is not None:
        stored = json.loads(args.json.read_text()) if args.json.is_file() else {}
        stored.setdefault("acrobot", {})["sweep"] = rows
        atomic_write_json(args.json, stored, indent=1)
    print(json.dumps(rows))
    return 0


def _parse_steps(text: str) -> dict[tuple[str, str], int]:
    """``acrobot:PPO=2000000,glider:SAC=30000`` -> ``{("acrobot", "PPO"): 2000000, ...}``."""
    out: dict[tuple[str, str], int] = {}
    for item in filter(None, text.split(",")):
        try:
            key, value = item.split("=")
            task, algo = key.split(":")
            out[(task, algo.upper())] = int(float(value))
        except ValueError:
            raise SystemExit(f"--steps: cannot read {item!r} (expected task:ALGO=steps)") from None
        if task not in TASKS or algo.upper() not in ALGOS or out[(task, algo.upper())] < 1:
            raise SystemExit(f"--steps: {item!r} names an unknown task/algorithm or a budget < 1")
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", default=",".join(TASKS))
    parser.add_argument("--algos", default=",".join(ALGOS))
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--steps", default="", help="budgets, e.g. acrobot:PPO=2000000,glider:SAC=30000")
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "rl")
    parser.add_argument("--quick", action="store_true", help="seconds-long runs (a smoke test of the benchmark)")
    parser.add_argument("--no-ship", action="store_true", help="do not copy the selected models to results/models")
    parser.add_argument("--json", type=Path, default=None, help="write the result JSON here (and the figures beside)")
    parser.add_argument("--plot-only", action="store_true", help="redraw the figures of --json without training")
    parser.add_argument(
        "--reuse-only", action="store_true", help="--sweep: record unfinished variations' curves, train nothing"
    )
    parser.add_argument(
        "--sweep",
        type=int,
        default=0,
        metavar="STEPS",
        help="instead: one seed of each SWEEP variation of the acrobot's PPO entry at STEPS, into --json's 'sweep'",
    )
    args = parser.parse_args(argv)
    tasks = [t for t in args.tasks.split(",") if t]
    algos = [a.upper() for a in args.algos.split(",") if a]
    for t in tasks:
        if t not in TASKS:
            parser.error(f"unknown task {t!r}; choose from {list(TASKS)}")
    for a in algos:
        if a not in ALGOS:
            parser.error(f"unknown algo {a!r}; choose from {list(ALGOS)}")
    if args.seeds < 1:
        parser.error("--seeds must be >= 1")
    if args.plot_only:
        if args.json is None or not args.json.is_file():
            parser.error("--plot-only needs --json with a stored result")
        stored = json.loads(args.json.read_text())
        for t in tasks:
            plot(t, stored[t], args.json.with_name(f"rl_curves_{t}.png"))
        return 0
    if args.sweep:
        return sweep(args)
    budgets = QUICK_STEPS if args.quick else FULL_STEPS
    steps = {(t, a): budgets[t][a] for t in tasks for a in algos} | _parse_steps(args.steps)
    result: dict[str, Any] = json.loads(args.json.read_text()) if args.json and args.json.is_file() else {}
    for t in tasks:
        block = result.setdefault(t, {})
        for a in algos:
            runs = [
                run_seed(config_of(t, a, s, steps[(t, a)], args.quick), args.out / t / a.lower() / f"seed{s}")
                for s in range(args.seeds)
            ]
            block[a.lower()] = summarise(t, a, runs, ship=not (args.no_ship or args.quick))
        if args.json is not None:
            plot(t, block, args.json.with_name(f"rl_curves_{t}.png"))
    result["machine"] = machine("torch", "stable_baselines3", "gymnasium")
    text = json.dumps(result, indent=1)
    if args.json is not None:
        atomic_write_text(args.json, text)
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
