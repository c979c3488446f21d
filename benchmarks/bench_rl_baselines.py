"""RL baselines on the MPCs' starts: SB3 PPO and SAC, learning curves over seeds, a small sweep.

Usage::

    .venv/bin/python benchmarks/bench_rl_baselines.py [--quick] [--tasks acrobot,glider] [--algos PPO,SAC]
        [--seeds 3] [--workers 2] [--out DIR] [--steps acrobot:PPO=2000000,...] [--sweep] [--no-ship]
        [--update benchmarks/results/rl_baselines.json] [--set acrobot:SAC:net_arch=64,64 ...]

For every task, algorithm and seed one run of :func:`seagul_learn.baselines.train_sb3` (zoo-derived settings, see
that module) records its learning curve: success on the task's evaluation grid (acrobot 20 x 20 over
``(th1, th2)`` at rest, glider 6 x 6) and mean return against environment steps. The saved final model is then
evaluated as a user loads it (``SB3Policy``: model + observation statistics) on the grid and on the 100 held-out
X0 starts every benchmark shares (seed 20211231). The zero-input policy on the same starts is the curves' floor.

``--sweep`` first runs a small grid (learning rate x discount x network size, one seed, a fifth of the budget or
``--sweep-steps``) per task and algorithm, keeps its table in ``sweep.json`` (committed as
``benchmarks/results/rl_sweep.json`` by the full run), and trains the seeds with each algorithm's best setting by
final grid success (ties: mean return).

Every run writes its directory before the next starts, so a re-run with the same ``--out`` skips what is done.
Figures: ``rl_curves_<task>.png`` (median and 25-75 % band over seeds: success, return and the final state's miss
of the success rule in units of its tolerances against steps, the zero-input policy's level beside each).

The last line of stdout is one JSON object (the full run's is committed as ``benchmarks/results/rl_baselines.json``;
the best seed's model and statistics are copied to ``benchmarks/results/models/``)::

    {"acrobot": {"ppo": {"env_steps", "seeds", "success_rate", "heldout_success_rate", "train_wall_s", "model",
                         "algo", ...}, "sac": {...}}, "glider": {...}, "machine": {...}}

``success_rate`` is the median over seeds on the grid, ``heldout_success_rate`` likewise on the held-out starts.
"""

from __future__ import annotations

import argparse
import itertools
import json
import shutil
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._common import machine  # noqa: E402
from seagul_control.evaluation import heldout_starts  # noqa: E402
from seagul_learn.baselines import ALGOS, SB3Config, ZeroPolicy, episode_stats, train_sb3  # noqa: E402

#: What each point of a stored learning curve keeps (the final distance and the miss let a later --update redraw it).
CURVE_KEYS = ("env_steps", "wall_s", "success_rate", "mean_return", "mean_final_distance", "mean_miss")

#: Environment steps of the full run per task and algorithm.
FULL_STEPS: dict[str, dict[str, int]] = {
    "acrobot": {"PPO": 2_000_000, "SAC": 300_000},
    "glider": {"PPO": 1_200_000, "SAC": 300_000},
}
QUICK_STEPS: dict[str, dict[str, int]] = {
    "acrobot": {"PPO": 8_192, "SAC": 3_000},
    "glider": {"PPO": 8_192, "SAC": 3_000},
}
TASKS = tuple(FULL_STEPS)
"""The tasks this benchmark trains on; each one's env is its ``task.profile.env_id``."""


def env_id_of(task: str) -> str:
    """The Gymnasium id of the task's own env (``profile.env_id``: ``SeagulAcrobot-v0``, ``SeagulGlider-v0``)."""
    from seagul_envs import make_task

    env_id = make_task(task).profile.env_id
    if not env_id:
        raise ValueError(f"task {task!r} has no registered env (profile.env_id)")
    return str(env_id)


#: The sweep's grid (per algorithm): the settings that matter most for these small continuous-control tasks.
SWEEP: dict[str, dict[str, list[Any]]] = {
    "PPO": {"learning_rate": [3e-4, 1e-3], "gamma": [0.98, 0.995], "net_arch": [(64, 64), (256, 256)]},
    # SAC's network is fixed at 256 x 256 (the zoo's 400 x 300 costs ~2x per gradient step); reward normalisation
    # is swept instead (the zoo leaves it off for SAC; PPO always has it). Listed first, it varies slowest: the
    # first four settings (combo0-3) are those without it, the same combos as a sweep without this axis.
    "SAC": {
        "normalize_reward": [False, True],
        "learning_rate": [3e-4, 7.3e-4],
        "gamma": [0.98, 0.995],
        "net_arch": [(256, 256)],
    },
}


def _run(config: SB3Config, out: Path, n_grid: int = 0, n_heldout: int = 100) -> dict[str, Any]:
    """Train (or reuse) one run, then evaluate its saved model on the grid (``n_grid`` per axis, 0 = the task's)
    and the held-out starts."""
    from seagul_learn.baselines import extends

    done = out / "result.json"
    extend = False
    if done.is_file():
        stored = json.loads(done.read_text())
        if config.describes(stored.get("config", {})):
            return stored
        if extends(config, stored.get("config", {})):
            # The same run with fewer steps: continue it to this budget (its curve goes on).
            before = stored["config"]["total_timesteps"]
            print(f"{out}: extending its run of {before} steps to {config.total_timesteps}", file=sys.stderr)
            extend = True
        else:
            # Another config's run in this directory: train this one afresh.
            print(f"{out}: holds a run of another config; training this one in its place", file=sys.stderr)
            shutil.rmtree(out)
    from seagul_control.evaluation import SB3Policy, start_grid
    from seagul_learn.baselines import task_of_env

    summary = train_sb3(config, out, extend=extend)
    task = task_of_env(config.env_id)
    policy = SB3Policy(task, summary["model"], algo=config.algo)
    grid, _ = start_grid(task, n_grid or task.profile.grid.points)
    result = {
        **summary,
        "grid": episode_stats(task, policy, grid),
        "heldout": episode_stats(task, policy, heldout_starts(task, n_heldout)),
    }
    done.write_text(json.dumps(result, indent=1))
    return result


def _jobs(workers: int, jobs: list[tuple[SB3Config, Path]], quick: bool = False) -> list[dict[str, Any]]:
    sizes = (3, 20) if quick else (0, 100)
    if workers <= 1 or len(jobs) <= 1:
        return [_run(c, o, *sizes) for c, o in jobs]
    from joblib import Parallel, delayed

    return list(Parallel(n_jobs=workers)(delayed(_run)(c, o, *sizes) for c, o in jobs))


def sweep(task: str, algo: str, budget: int, out: Path, workers: int, quick: bool) -> dict[str, Any]:
    """The sweep's table for one task and algorithm (``budget`` environment steps per setting); returns it with the
    best setting."""
    grid = SWEEP[algo]
    combos = [dict(zip(grid, values, strict=True)) for values in itertools.product(*grid.values())]
    if quick:
        combos = combos[:2]
    jobs = []
    for k, combo in enumerate(combos):
        config = SB3Config(algo=algo, env_id=env_id_of(task), total_timesteps=budget, seed=100, eval_every=0, **combo)
        if quick:
            config = replace(config, eval_grid=3)
        jobs.append((config, out / f"combo{k}"))
    rows = []
    for combo, result in zip(combos, _jobs(workers, jobs, quick), strict=True):
        rows.append(
            {
                **{k: list(v) if isinstance(v, tuple) else v for k, v in combo.items()},
                "env_steps": result["env_steps"],
                "grid_success_rate": result["grid"]["success_rate"],
                "grid_mean_return": result["grid"]["mean_return"],
                "train_wall_s": result["train_wall_s"],
            }
        )
    best = max(range(len(rows)), key=lambda i: (rows[i]["grid_success_rate"], rows[i]["grid_mean_return"]))
    return {"budget": budget, "seed": 100, "rows": rows, "best": combos[best]}


def plot(task: str, per_algo: dict[str, list[dict[str, Any]]], floor: dict[str, float], path: Path) -> None:
    """Median and 25-75 % band over seeds of grid success, mean return and mean miss of the success rule (in units
    of its tolerances, :func:`seagul_learn.baselines.episode_stats`) against environment steps, the zero-input
    policy's level beside each. Curves whose points lack the miss are left out of the miss panel, which is not
    drawn when no curve has it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [
        ("success_rate", "grid success"),
        ("mean_return", "mean return (trajectory cost, negated)"),
        ("mean_miss", "mean miss of the success rule (tolerances)"),
    ]
    if not any("mean_miss" in p for runs in per_algo.values() for r in runs for p in r["curve"]):
        panels.pop()  # no curve has the miss: no empty panel
    fig, axes = plt.subplots(1, len(panels), figsize=(5.3 * len(panels), 4), sharex=True)
    colors = {algo: f"C{i}" for i, algo in enumerate(sorted(per_algo))}  # one colour per algorithm in every panel
    for algo, runs in per_algo.items():
        n = min(len(r["curve"]) for r in runs)
        steps = np.array([p["env_steps"] for p in runs[0]["curve"][:n]])
        for ax, (key, _) in zip(axes, panels, strict=True):
            if not all(key in p for r in runs for p in r["curve"][:n]):
                continue
            vals = np.array([[p[key] for p in r["curve"][:n]] for r in runs])
            ax.plot(steps, np.median(vals, axis=0), color=colors[algo], label=f"{algo} (median of {len(runs)})")
            ax.fill_between(steps, *np.percentile(vals, [25, 75], axis=0), color=colors[algo], alpha=0.25)
    for ax, (key, label) in zip(axes, panels, strict=True):
        if key in floor:
            ax.axhline(floor[key], color="k", ls=":", label="zero input")
        ax.set_xlabel("environment steps (log scale)")
        ax.set_xscale("log")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[1].set_yscale("symlog")
    axes[1].set_ylim(top=min(axes[1].get_ylim()[1], 0.0))  # returns are negated costs: nothing above 0
    axes[0].set_ylim(-0.02, 1.02)
    if len(panels) == 3:
        axes[2].set_yscale("symlog", linthresh=1.0)  # 0 = success; zero input misses by tens of tolerances
        axes[2].set_ylim(0.0, max(axes[2].get_ylim()[1], 1.0))
    axes[0].legend()
    fig.suptitle(f"{task}: SB3 baselines on the evaluation grid")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def run_task(task: str, algos: list[str], args: argparse.Namespace, out: Path, ship: Path | None) -> dict[str, Any]:
    from seagul_control.evaluation import start_grid
    from seagul_learn.baselines import task_of_env

    env_id = env_id_of(task)
    task_obj = task_of_env(env_id)
    steps_table = QUICK_STEPS if args.quick else FULL_STEPS
    grid, _ = start_grid(task_obj, 3 if args.quick else task_obj.profile.grid.points)
    zero = ZeroPolicy(task_obj.nu)
    floor = episode_stats(task_obj, zero, grid)
    floor_heldout = episode_stats(task_obj, zero, heldout_starts(task_obj, 20 if args.quick else 100))
    result: dict[str, Any] = {"zero_input": {"grid": floor, "heldout": floor_heldout}}
    per_algo: dict[str, list[dict[str, Any]]] = {}
    sweeps: dict[str, Any] = {}
    for algo in algos:
        steps = args.steps.get((task, algo), steps_table[task][algo])
        best: dict[str, Any] = {}
        if args.settings_from:
            best = _stored_best(Path(args.settings_from), task, algo)
        elif args.sweep:
            budget = args.sweep_steps.get((task, algo), max(steps // 5, 1))
            sweeps[algo] = sweep(task, algo, budget, out / task / algo / "sweep", args.workers, args.quick)
            best = sweeps[algo]["best"]
        best = {**best, **args.set.get((task, algo), {})}
        eval_every = max(steps // 20, 1)
        jobs = []
        for seed in range(args.seeds):
            config = SB3Config(
                algo=algo, env_id=env_id, total_timesteps=steps, seed=seed, eval_every=eval_every, **best
            )
            if args.quick:
                config = replace(config, eval_grid=3)
            jobs.append((config, out / task / algo / f"seed{seed}"))
        runs = _jobs(args.workers, jobs, args.quick)
        per_algo[algo] = runs
        grid_rates = [r["grid"]["success_rate"] for r in runs]
        held_rates = [r["heldout"]["success_rate"] for r in runs]
        best_seed = max(range(len(runs)), key=lambda i: (grid_rates[i], runs[i]["grid"]["mean_return"]))
        model = runs[best_seed]["model"]
        if ship is not None:
            dest = ship / f"{task}_{algo.lower()}"
            dest.mkdir(parents=True, exist_ok=True)
            src = Path(model).parent
            for name in ("model.zip", "vecnormalize.pkl"):
                if (src / name).is_file():
                    shutil.copy2(src / name, dest / name)
            model = str((dest / "model.zip").relative_to(ROOT))
        result[algo.lower()] = {
            "algo": algo,
            "env_steps": int(runs[0]["env_steps"]),
            "seeds": len(runs),
            "success_rate": float(np.median(grid_rates)),
            "heldout_success_rate": float(np.median(held_rates)),
            "train_wall_s": float(np.median([r["train_wall_s"] for r in runs])),
            "model": model,
            "per_seed_success": grid_rates,
            "per_seed_heldout": held_rates,
            "mean_final_distance": float(np.median([r["grid"]["mean_final_distance"] for r in runs])),
            "mean_miss": float(np.median([r["grid"].get("mean_miss", np.nan) for r in runs])),
            "settings": runs[0]["resolved"] | {"gamma": runs[0]["config"]["gamma"]},
            # Per seed, so that a later --update of another algorithm can redraw this one's curve.
            "curves": [[{k: p[k] for k in CURVE_KEYS if k in p} for p in r["curve"]] for r in runs],
        }
        if args.settings_from:
            result[algo.lower()]["settings_from"] = str(args.settings_from)
        if (task, algo) in args.set:
            result[algo.lower()]["settings_set"] = {
                k: list(v) if isinstance(v, tuple) else v for k, v in args.set[(task, algo)].items()
            }
    if sweeps:
        (out / task / "sweep.json").write_text(json.dumps(sweeps, indent=1))
        result["sweep"] = sweeps
    stored = _stored_curves(args.update, task, algos)
    update = Path(args.update) if args.update else None
    kept = json.loads(update.read_text()).get(task, {}) if update is not None and update.is_file() else {}
    # An update that keeps an algorithm whose curves were not stored draws this run's alone, under its own name.
    uncurved = [a for a in ALGOS if a not in algos and a not in stored and a.lower() in kept]
    suffix = "_" + "_".join(a.lower() for a in algos) if uncurved else ""
    figure = out / task / f"rl_curves_{task}{suffix}.png"
    figure.parent.mkdir(parents=True, exist_ok=True)
    plot(task, {**stored, **per_algo}, floor, figure)
    result["figure"] = str(figure)
    if ship is not None:  # the full run's figure goes beside its JSON
        shipped = ship.parent / figure.name
        shutil.copy2(figure, shipped)
        result["figure"] = str(shipped.relative_to(ROOT))
    return result


def _stored_curves(update: str | None, task: str, algos: list[str]) -> dict[str, list[dict[str, Any]]]:
    """The curves of the algorithms an ``--update`` keeps (those of ``task`` in the file that this run does not
    train), in ``plot``'s form; an algorithm stored without curves is left out."""
    if not update or not Path(update).is_file():
        return {}
    return _curves_of(json.loads(Path(update).read_text()).get(task, {}), skip=algos)


def _curves_of(block: dict[str, Any], skip: list[str] | tuple[str, ...] = ()) -> dict[str, list[dict[str, Any]]]:
    """The per-seed curves stored in one task's result block, in ``plot``'s form, for every algorithm not in
    ``skip``; an algorithm stored without curves is left out."""
    return {
        a: [{"curve": c} for c in block[a.lower()]["curves"]]
        for a in ALGOS
        if a not in skip and block.get(a.lower(), {}).get("curves")
    }


def replot(path: Path, tasks: list[str]) -> int:
    """Redraw the figures of a stored result (``--replot``) from its per-seed curves and zero-input levels, into the
    paths it names (relative to the repository root); a task without stored curves is skipped with a message."""
    try:
        stored = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise SystemExit(f"--replot {path}: not a readable result JSON ({exc!r})") from exc
    drawn = {}
    for task in tasks:
        block = stored.get(task, {})
        curves = _curves_of(block)
        if not curves or "figure" not in block:
            print(f"{task}: no stored curves in {path}, nothing drawn", file=sys.stderr)
            continue
        figure = Path(block["figure"])
        figure = figure if figure.is_absolute() else ROOT / figure
        plot(task, curves, block.get("zero_input", {}).get("grid", {}), figure)
        drawn[task] = str(block["figure"])
    print(json.dumps({"replotted": drawn}))
    return 0


def _stored_best(path: Path, task: str, algo: str) -> dict[str, Any]:
    """The best setting of a committed sweep (``rl_sweep.json``: ``{task: {algo: {"best": {...}}}}``)."""
    try:
        best = dict(json.loads(path.read_text())[task][algo]["best"])
    except (OSError, KeyError, TypeError, json.JSONDecodeError) as exc:
        raise SystemExit(f"--settings-from {path}: no sweep result for {task} {algo} ({exc!r})") from exc
    return {k: tuple(v) if isinstance(v, list) else v for k, v in best.items()}


def _parse_steps(text: str) -> dict[tuple[str, str], int]:
    table: dict[tuple[str, str], int] = {}
    for item in filter(None, text.split(",")):
        key, _, value = item.partition("=")
        task, _, algo = key.partition(":")
        if not value or algo not in ALGOS or task not in TASKS:
            raise argparse.ArgumentTypeError(f"--steps entries look like acrobot:PPO=2000000, got {item!r}")
        table[(task, algo)] = int(value)
    return table


def _parse_set(text: str) -> tuple[tuple[str, str], str, Any]:
    """``acrobot:SAC:net_arch=64,64`` -> ``(("acrobot", "SAC"), "net_arch", (64, 64))``; the field must be one of
    :class:`SB3Config`'s settings and the value is read as that field's type."""
    from dataclasses import fields

    key, sep, value = text.partition("=")
    parts = key.split(":")
    if not sep or len(parts) != 3 or parts[0] not in TASKS or parts[1] not in ALGOS:
        raise argparse.ArgumentTypeError(f"--set entries look like acrobot:SAC:net_arch=64,64, got {text!r}")
    task, algo, name = parts
    settable = {f.name: str(f.type) for f in fields(SB3Config)}
    for fixed in ("algo", "env_id", "seed", "total_timesteps"):  # the benchmark's own axes
        del settable[fixed]
    if name not in settable:
        raise argparse.ArgumentTypeError(f"--set: {name!r} is not a setting; choose from {sorted(settable)}")
    default = getattr(SB3Config(), name)
    try:
        if isinstance(default, tuple):
            parsed: Any = tuple(int(w) for w in value.split(",") if w)
        elif settable[name].startswith("bool"):  # bool, or bool | None
            if value.lower() not in ("true", "false", "none"):
                raise ValueError(value)
            parsed = {"true": True, "false": False, "none": None}[value.lower()]
        elif isinstance(default, dict):
            parsed = json.loads(value)
        else:
            parsed = type(default)(value)
        replace(SB3Config(algo=algo), **{name: parsed})  # the config's own checks
    except (ValueError, TypeError, json.JSONDecodeError) as exc:
        raise argparse.ArgumentTypeError(f"--set {text!r}: bad value for {name} ({exc})") from exc
    return (task, algo), name, parsed


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="a minutes-long check of the pipeline")
    parser.add_argument("--tasks", default="acrobot,glider", help="comma-separated tasks")
    parser.add_argument("--algos", default="PPO,SAC", help="comma-separated algorithms")
    parser.add_argument("--seeds", type=int, default=None, help="seeds per algorithm (default 3; --quick 2)")
    parser.add_argument("--workers", type=int, default=2, help="parallel training runs")
    parser.add_argument("--steps", type=_parse_steps, default={}, help="budgets, e.g. acrobot:SAC=100000")
    parser.add_argument("--sweep", action="store_true", help="run the hyperparameter sweep first")
    parser.add_argument(
        "--sweep-steps", type=_parse_steps, default={}, help="sweep budgets per setting (default a fifth of --steps)"
    )
    parser.add_argument(
        "--settings-from",
        default=None,
        help="train with the best settings of a stored sweep (e.g. benchmarks/results/rl_sweep.json), no sweep",
    )
    parser.add_argument(
        "--set",
        type=_parse_set,
        action="append",
        default=[],
        metavar="TASK:ALGO:FIELD=VALUE",
        help="a setting over the sweep's (or the zoo's), e.g. acrobot:SAC:net_arch=64,64; repeatable",
    )
    parser.add_argument("--out", default=None, help="work directory (default /tmp/seagul-bench-rl[-quick])")
    parser.add_argument("--no-ship", action="store_true", help="do not copy the best models into the repository")
    parser.add_argument(
        "--update",
        default=None,
        help="merge this run's tasks into this result JSON (its other tasks kept) and print the merged object",
    )
    parser.add_argument(
        "--replot",
        default=None,
        metavar="JSON",
        help="no training: redraw each task's figure from the curves stored in this result JSON, print it",
    )
    args = parser.parse_args(argv)
    if args.replot:
        return replot(Path(args.replot), [t for t in args.tasks.split(",") if t])
    overrides: dict[tuple[str, str], dict[str, Any]] = {}
    for key, name, value in args.set:
        overrides.setdefault(key, {})[name] = value
    args.set = overrides
    if args.seeds is None:
        args.seeds = 2 if args.quick else 3
    algos = [a for a in args.algos.split(",") if a]
    tasks = [t for t in args.tasks.split(",") if t]
    if set(algos) - set(ALGOS) or set(tasks) - set(TASKS):
        parser.error(f"--algos from {list(ALGOS)}, --tasks from {list(TASKS)}")
    out = Path(args.out or f"/tmp/seagul-bench-rl{'-quick' if args.quick else ''}")
    ship = None if (args.quick or args.no_ship) else ROOT / "benchmarks" / "results" / "models"
    t0 = time.perf_counter()
    result: dict[str, Any] = {}
    for task in tasks:
        result[task] = run_task(task, algos, args, out, ship)
        print(f"{task}: " + ", ".join(f"{a}: {result[task][a.lower()]['success_rate']:.1%}" for a in algos), flush=True)
    result["machine"] = {**machine(), "wall_s": round(time.perf_counter() - t0, 1)}
    if args.update:
        path = Path(args.update)
        merged = json.loads(path.read_text()) if path.is_file() else {}
        kept = [t for t in merged if t in TASKS and t not in tasks]
        # Each task keeps the machine record of the run that made it.
        for t in kept:
            merged[t].setdefault("machine", merged.get("machine", {}))
        for t in tasks:
            # The algorithms this run trained replace theirs; the task's others (and their sweep rows) are kept,
            # each with the machine record of the run that made it.
            old = merged.get(t, {})
            for a in ALGOS:
                if a not in algos and a.lower() in old:
                    old[a.lower()].setdefault("machine", old.get("machine", merged.get("machine", {})))
            sweeps = {**old.get("sweep", {}), **result[t].get("sweep", {})}
            merged[t] = {**old, **result[t], "machine": result["machine"]}
            for a in algos:
                merged[t][a.lower()]["machine"] = result["machine"]
            if sweeps:
                merged[t]["sweep"] = sweeps
        merged["machine"] = result["machine"]
        merged["updated_tasks"] = tasks
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(merged, indent=1) + "\n")
        tmp.replace(path)
        result = merged
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
