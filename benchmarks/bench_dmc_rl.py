"""SAC and PPO on the DeepMind Control Suite swing-ups, set up as their reference implementations: trained over seeds,
each seed's selected model scored on dm_control's own episodes (reset seeds 0-9), as every seagul controller is.

Usage::

    .venv/bin/python benchmarks/bench_dmc_rl.py [--tasks pendulum-swingup,cartpole-swingup,...] [--algos PPO,SAC]
        [--seeds 5] [--steps 1000000 | --steps PPO=1000000,SAC=1000000] [--out runs/dmc_rl]
        [--json FILE] [--ship]
    .venv/bin/python benchmarks/bench_dmc_rl.py --tasks pendulum-swingup --algos PPO --json FILE --ship-only
    .venv/bin/python benchmarks/bench_dmc_rl.py --throughput 120 [--tasks pendulum-swingup] [--algos PPO,SAC]

Every run is :func:`seagul_learn.dmc_rl.train_dmc_sb3` with the settings of ``seagul_learn/hyperparams/dmc.yml``
(CleanRL's ``ppo_continuous_action.py`` for PPO, ``denisyarats/pytorch_sac`` for SAC, each value sourced there),
in ``<out>/<task>/<algo>/seed<k>``: a finished run is reused, an interrupted one resumes from its last validation
checkpoint. The model of each seed selected on the validation episodes (reset seeds 1000+) is scored by
:func:`seagul_learn.dmc_rl.evaluate_sb3_dmc` on reset seeds 0-9. ``--steps`` defaults to each entry's
``n_timesteps`` (1,000,000 for both). ``--ship`` copies, per task and algorithm, the selected model of the seed with
the best validation point to ``benchmarks/results/models/dmc/<task>_<algo>/`` (:func:`ship`; the block records it
as ``model`` and ``model_seed``): ``seagul_learn.dmc_rl.load_sb3_dmc`` loads it, and
``benchmarks/animate_dmc.py`` animates it. ``--ship-only`` does the same for the blocks already in ``--json FILE``
without training or scoring anything; only the shipped seed's run must be in ``--out``.

The last line of stdout is the JSON written to ``--json`` (omit ``--json`` to write nothing; the benchmark's file
is ``dmc_rl.json`` in the results directory)::

    {"tasks": {env_id: {"ppo": {"score_mean", "score_std", "seeds", "env_steps", "per_seed": [...], "settings",
                                "train_wall_s", "curves"}, "sac": {...}}},
     "eval_seeds", "machine", "command"}

``score_mean`` is the mean over training seeds of each seed's mean over the 10 episodes, ``score_std`` the standard
deviation (ddof 0) of those per-seed means; ``per_seed`` holds each seed's ``seed``, ``scores``, ``mean``,
``selected_at`` (the validation point of the selected model), ``env_steps`` and ``train_wall_s``;
``train_wall_s`` is the sum over seeds (validation excluded); each block also keeps the ``command`` and ``machine``
of the run that wrote it. ``--json`` merges into an existing file: the blocks of the tasks and algorithms run
replace theirs, every other block stays, so tasks may be run one invocation at a time.

Throughput (``--throughput SECONDS``: one process, one torch thread, the full settings, no validation), measured
on pendulum-swingup with ``nice -n 5 .venv/bin/python benchmarks/bench_dmc_rl.py --throughput 120 --tasks
pendulum-swingup [--algos SAC]`` on the 2-core development machine ("Intel(R) Xeon(R) Processor", torch 2.13.0+cpu,
shared with two other jobs: load average 2.5-3.3):

* PPO: 569 environment steps/s (68,338 steps in 120 s). 1 M steps take 29 min; 1 M steps x 5 seeds x 4 tasks (20
  runs) 9.8 h on one core. CleanRL's own dm_control benchmark budget, 8 M steps, would take 78 h for the 20 runs.
* SAC: 2.0 environment steps/s once learning starts (239 steps with their gradient steps in 118 s, after the 5,000
  random steps, which took 1.75 s): 1024 x 1024 networks and batches of 1,024 cost about 0.5 s per gradient step
  on one CPU thread. 1 M steps take about 137 h (5.7 days); the 20 runs 114 days on one core. The SAC runs need a
  GPU or a many-core machine (one run per core); this machine cannot make them.

``benchmarks/dmc_contract.py`` reads ``score_mean``, ``score_std``, ``seeds`` and ``env_steps`` from the results
directory's ``dmc_rl.json``, when that file exists.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._common import machine  # noqa: E402
from seagul_control.dmc import DMC_ENV_IDS, dmc_env_id  # noqa: E402
from seagul_control.io import atomic_write_bytes, atomic_write_json  # noqa: E402
from seagul_learn.dmc_rl import (  # noqa: E402
    ALGOS,
    dmc_settings,
    evaluate_sb3_dmc,
    measure_throughput,
    train_dmc_sb3,
)

#: The scoring episodes: reset seeds 0-9, the same for every controller on these tasks.
EVAL_SEEDS = tuple(range(10))


def short_name(env_id: str) -> str:
    """``"dm_control/pendulum-swingup-v0"`` -> ``"pendulum-swingup"``."""
    return env_id.removeprefix("dm_control/").removesuffix("-v0")


def parse_steps(text: str | None, algos: list[str]) -> dict[str, int | None]:
    """``"1000000"`` (every algo) or ``"PPO=1000000,SAC=200000"`` -> {algo: steps}; None: the entry's n_timesteps."""
    if not text:
        return {a: None for a in algos}
    if "=" not in text:
        return {a: int(text) for a in algos}
    out: dict[str, int | None] = {a: None for a in algos}
    for part in text.split(","):
        key, value = part.split("=")
        algo = key.strip().lower()
        if algo not in algos:
            raise ValueError(f"--steps names {key!r}, not one of --algos {algos}")
        out[algo] = int(value)
    return out


def run_algo(env_id: str, algo: str, seeds: list[int], steps: int | None, out: Path) -> dict[str, Any]:
    """Train (or reuse) every seed, score each selected model on :data:`EVAL_SEEDS`; the task's block for ``algo``."""
    settings = dmc_settings(algo, env_id)
    budget = int(steps or settings["n_timesteps"])
    per_seed, curves = [], []
    for seed in seeds:
        run_dir = out / short_name(env_id) / algo / f"seed{seed}"
        summary = train_dmc_sb3(algo, env_id, seed, budget, run_dir)
        result = evaluate_sb3_dmc(run_dir / "best", env_id, EVAL_SEEDS)
        per_seed.append(
            {
                "seed": seed,
                "scores": [round(s, 3) for s in result["scores"]],
                "mean": round(result["mean"], 3),
                "selected_at": summary["best"],
                "env_steps": summary["env_steps"],
                "train_wall_s": summary["train_wall_s"],
                "run": str(run_dir.relative_to(ROOT)) if run_dir.resolve().is_relative_to(ROOT) else str(run_dir),
            }
        )
        curves.append(summary["curve"])
        print(f"{short_name(env_id)} {algo} seed {seed}: {result['mean']:.1f} ({summary['env_steps']} steps)")
    means = [row["mean"] for row in per_seed]
    return {
        "score_mean": round(float(np.mean(means)), 3),
        "score_std": round(float(np.std(means)), 3),
        "seeds": len(seeds),
        "env_steps": max(int(row["env_steps"]) for row in per_seed),
        "per_seed": per_seed,
        "settings": {**settings, "n_timesteps": budget},
        "train_wall_s": round(float(sum(row["train_wall_s"] for row in per_seed)), 1),
        "curves": curves,
    }


#: Where ``--ship`` puts each task's selected model: ``<SHIP_DIR>/<task>_<algo>/``.
SHIP_DIR = ROOT / "benchmarks" / "results" / "models" / "dmc"

#: The files of a saved model directory (``best/`` of a run), as :func:`seagul_learn.dmc_rl.load_sb3_dmc` reads them.
MODEL_FILES = ("model.zip", "policy.json", "vecnormalize.pkl")


def ship(env_id: str, algo: str, block: dict[str, Any], out: Path, dest: Path | None = None) -> dict[str, Any]:
    """Copy the selected model of the seed with the best validation point (its ``selected_at`` mean; ties: the
    lower seed) from its run in ``out`` to ``dest/<task>_<algo>/`` (default :data:`SHIP_DIR`) and record it in
    ``block``: ``model`` (the directory, relative to the repository when inside it) and ``model_seed`` (its scores
    are that seed's row of ``per_seed``). A file of a previously shipped model that this run does not have is
    removed. Raises when the run's ``best/`` is missing or was trained in another env or seed."""
    best = max(block["per_seed"], key=lambda row: (row["selected_at"]["mean"], -row["seed"]))
    source = out / short_name(env_id) / algo / f"seed{best['seed']}" / "best"
    meta_path = source / "policy.json"
    if not meta_path.is_file():
        raise FileNotFoundError(f"cannot ship {short_name(env_id)} {algo}: {source} holds no saved model")
    meta = json.loads(meta_path.read_text())
    if meta["env_id"] != env_id or meta["seed"] != best["seed"]:
        raise ValueError(f"{source} holds {meta['env_id']} seed {meta['seed']}, not {env_id} seed {best['seed']}")
    target = (SHIP_DIR if dest is None else dest) / f"{short_name(env_id)}_{algo}"
    target.mkdir(parents=True, exist_ok=True)
    for name in MODEL_FILES:
        if (source / name).is_file():
            atomic_write_bytes(target / name, (source / name).read_bytes())
        else:
            (target / name).unlink(missing_ok=True)  # e.g. statistics of a normalised model shipped before
    shown = target.resolve()
    block.update(
        model=str(shown.relative_to(ROOT)) if shown.is_relative_to(ROOT) else str(shown),
        model_seed=best["seed"],
    )
    return block


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tasks", default=",".join(short_name(e) for e in DMC_ENV_IDS), help="comma-separated")
    parser.add_argument("--algos", default="PPO,SAC", help="comma-separated: PPO, SAC")
    parser.add_argument("--seeds", type=int, default=5, help="training seeds 0..N-1")
    parser.add_argument("--steps", default=None, help="N or PPO=N,SAC=M (default: the settings' n_timesteps)")
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "dmc_rl")
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--throughput", type=float, default=None, metavar="SECONDS")
    shipping = parser.add_mutually_exclusive_group()
    shipping.add_argument(
        "--ship",
        action="store_true",
        help="copy each task's selected model (the seed with the best validation point) to "
        "benchmarks/results/models/dmc/<task>_<algo>/ and record it in the block",
    )
    shipping.add_argument(
        "--ship-only",
        action="store_true",
        help="ship the models of the blocks already in --json FILE without training or scoring (only the shipped "
        "seed's run must be in --out)",
    )
    args = parser.parse_args(argv)
    env_ids = [dmc_env_id(t.strip()) for t in args.tasks.split(",") if t.strip()]
    algos = [a.strip().lower() for a in args.algos.split(",") if a.strip()]
    for algo in algos:
        if algo not in ALGOS:
            raise ValueError(f"unknown algo {algo!r}; choose from {[a.upper() for a in ALGOS]}")
    if args.seeds < 1:
        raise ValueError(f"--seeds must be >= 1, got {args.seeds}")
    command = " ".join(["benchmarks/bench_dmc_rl.py", *(argv if argv is not None else sys.argv[1:])])
    if args.ship_only:
        if args.json is None or not args.json.is_file():
            raise ValueError("--ship-only ships the blocks of an existing --json FILE: name it")
        result = json.loads(args.json.read_text())
        for env_id in env_ids:
            for algo in algos:
                block = result["tasks"].get(env_id, {}).get(algo)
                if block is None:
                    raise ValueError(f"{args.json} holds no {algo} block for {env_id}: run it first")
                ship(env_id, algo, block, args.out)
        atomic_write_json(args.json, result, indent=1)
    elif args.throughput is not None:
        rows = [measure_throughput(a, e, args.throughput) for e in env_ids for a in algos]
        result = {"throughput": rows, "command": command, "machine": machine("torch")}
    else:
        steps = parse_steps(args.steps, algos)
        tasks = {e: {a: run_algo(e, a, list(range(args.seeds)), steps[a], args.out) for a in algos} for e in env_ids}
        if args.ship:
            for env_id, blocks in tasks.items():
                for algo, block in blocks.items():
                    ship(env_id, algo, block, args.out)
        host = machine("mujoco", "shimmy", "gymnasium", "torch", "stable_baselines3")
        for blocks in tasks.values():
            for block in blocks.values():
                block.update(command=command, machine=host)
        result = {"tasks": tasks, "eval_seeds": list(EVAL_SEEDS), "command": command, "machine": host}
        if args.json is not None:
            # a task or algorithm run on its own replaces its block only: the file keeps every other one
            merged = json.loads(args.json.read_text()) if args.json.is_file() else {"tasks": {}}
            for env_id, blocks in tasks.items():
                merged["tasks"].setdefault(env_id, {}).update(blocks)
            atomic_write_json(args.json, {**merged, **{k: v for k, v in result.items() if k != "tasks"}}, indent=1)
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
