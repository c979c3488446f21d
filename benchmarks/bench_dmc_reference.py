"""The full-horizon reference (:class:`seagul_control.dmc_reference.FullHorizonReference`) scored by dm_control's own
reward on the DeepMind Control Suite swing-ups' own episodes.

Usage::

    nice -n 5 .venv/bin/python benchmarks/bench_dmc_reference.py [--tasks acrobot-swingup,pendulum-swingup,...]
        [--seeds 0-9] [--json benchmarks/results/dmc_reference.json]

Per env (default, in this order: acrobot-swingup, pendulum-swingup, cartpole-swingup, cartpole-swingup_sparse) and
reset seed (default 0-9: the evaluation seeds of ``benchmarks/bench_dmc.py``), one episode of the reference with the
env's :data:`~seagul_control.dmc_reference.DEFAULT_SETTINGS` through
:func:`seagul_control.dmc.run_dmc_episode` (``hold`` 1: the reference is asked at every control step; it searches
at the start, re-solves every ``resolve_every`` steps, and otherwise reads its plan). Single process, one env and
one reference (one built solver) per task.

Resumable: every finished episode is appended as one JSON line to ``<json>.partial.jsonl`` beside the result; a
re-run skips the (env, seed) pairs found there, and the result JSON is rewritten from the partial file after every
episode, so an interrupted run leaves a valid (shorter) result and continues where it stopped. Delete the partial
file to measure again.

Writes ``{"tasks": {env_id: {"controller": "full-horizon reference", "settings", "scores", "seeds", "mean", "std",
"decision_ms_median", "decision_ms_p95", "failed_solves", "search_s_median", "search_s_max", "episodes"}},
"machine", "command"}``: ``decision_ms_*`` are over the re-solve decisions of all the task's episodes (the calls
between re-solves only read the plan, ~0.01 ms, and would make the median meaningless), the start's global search is
``search_s_*`` (wall s per episode), ``failed_solves`` counts re-solves that fell back to the shifted previous plan,
``episodes`` has per seed the score, the search's chosen guess and plan return, and the re-solve statistics.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._common import machine, parse_seeds  # noqa: E402
from seagul_control.dmc import dmc_env_id, run_dmc_episode  # noqa: E402
from seagul_control.dmc_reference import DEFAULT_SETTINGS, FullHorizonReference  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
DEFAULT_TASKS = "acrobot-swingup,pendulum-swingup,cartpole-swingup,cartpole-swingup_sparse"


def partial_path(json_path: Path) -> Path:
    """The partial-results file beside ``json_path`` (one JSON line per finished episode)."""
    return json_path.with_name(json_path.name + ".partial.jsonl")


def read_partial(path: Path) -> list[dict[str, Any]]:
    """The finished episodes in ``path`` (a torn last line from an interrupted write is ignored)."""
    if not path.exists():
        return []
    rows = []
    for line in path.read_text().splitlines():
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return rows


def episode_row(env_id: str, seed: int, ref: FullHorizonReference) -> dict[str, Any]:
    """One episode of ``ref`` on ``env_id`` from ``seed``: score and the solves' statistics."""
    episode = run_dmc_episode(env_id, ref, seed)
    resolve_ms = [1e3 * r.solve_s for r in ref.records if r.kind == "resolve"]
    return {
        "env_id": env_id,
        "seed": seed,
        "score": episode.score,
        "wall_s": episode.wall_s,
        **ref.summary(),
        "resolve_ms": resolve_ms,
    }


def task_entry(env_id: str, rows: list[dict[str, Any]], seeds: list[int]) -> dict[str, Any]:
    """The result of one env from its finished episodes (in ``seeds`` order)."""
    by_seed = {r["seed"]: r for r in rows if r["env_id"] == env_id}
    done = [by_seed[s] for s in seeds if s in by_seed]
    scores = [r["score"] for r in done]
    ms = np.array([m for r in done for m in r["resolve_ms"]])
    search = np.array([r["search_s"] for r in done])
    return {
        "controller": "full-horizon reference",
        "settings": dataclasses.asdict(DEFAULT_SETTINGS[env_id]),
        "scores": scores,
        "seeds": [r["seed"] for r in done],
        "mean": float(np.mean(scores)) if scores else None,
        "std": float(np.std(scores)) if scores else None,
        "decision_ms_median": float(np.median(ms)) if ms.size else None,
        "decision_ms_p95": float(np.percentile(ms, 95)) if ms.size else None,
        "failed_solves": int(sum(r["failed_solves"] for r in done)),
        "search_s_median": float(np.median(search)) if search.size else None,
        "search_s_max": float(np.max(search)) if search.size else None,
        "episodes": [{k: v for k, v in r.items() if k not in ("resolve_ms", "env_id")} for r in done],
    }


def write_result(json_path: Path, tasks: list[str], seeds: list[int], rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Rewrite the result JSON from the finished episodes (``tasks`` first, then any other env in the partial file,
    so runs of single tasks add up)."""
    ordered = [*tasks, *dict.fromkeys(r["env_id"] for r in rows if r["env_id"] not in tasks)]
    result = {
        "tasks": {t: task_entry(t, rows, seeds) for t in ordered if any(r["env_id"] == t for r in rows)},
        "seeds": seeds,
        "command": " ".join(sys.argv),
        "machine": machine("mujoco", "gymnasium", "shimmy"),
    }
    json_path.parent.mkdir(parents=True, exist_ok=True)
    json_path.write_text(json.dumps(result, indent=1) + "\n")
    return result


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", default=DEFAULT_TASKS, help="comma-separated env ids or short names, in order")
    parser.add_argument("--seeds", default="0-9", help="reset seeds, e.g. 0-9 or 0,3,5")
    parser.add_argument("--json", type=Path, default=RESULTS / "dmc_reference.json")
    args = parser.parse_args(argv)
    tasks = [dmc_env_id(t) for t in args.tasks.split(",") if t]
    seeds = parse_seeds(args.seeds)
    part = partial_path(args.json)
    rows = read_partial(part)
    todo = [(t, s) for t in tasks for s in seeds if not any(r["env_id"] == t and r["seed"] == s for r in rows)]
    bar = tqdm(total=len(todo), desc="episodes", unit="ep")
    refs: dict[str, FullHorizonReference] = {}
    for env_id, seed in todo:
        if env_id not in refs:
            refs.clear()  # one built solver at a time
            refs[env_id] = FullHorizonReference(env_id)
        tic = time.perf_counter()
        row = episode_row(env_id, seed, refs[env_id])
        with part.open("a") as f:
            f.write(json.dumps(row) + "\n")
        rows.append(row)
        write_result(args.json, tasks, seeds, rows)
        bar.set_postfix_str(f"{env_id.removeprefix('dm_control/')} seed {seed}: {row['score']:.0f}")
        bar.update(1)
        tqdm.write(
            f"{env_id} seed {seed}: score {row['score']:.1f}, search {row['search_s']:.1f} s "
            f"({row['best_guess']}), {row['resolves']} re-solves (median {row['resolve_ms_median']:.0f} ms, "
            f"{row['failed_solves']} failed), {time.perf_counter() - tic:.0f} s"
        )
    bar.close()
    result = write_result(args.json, tasks, seeds, rows)
    print("| env | mean | std | scores |", file=sys.stderr)
    print("|---|---|---|---|", file=sys.stderr)
    for env_id, entry in result["tasks"].items():
        scores = ", ".join(f"{s:.0f}" for s in entry["scores"])
        print(f"| {env_id} | {entry['mean']:.1f} | {entry['std']:.1f} | {scores} |", file=sys.stderr)


if __name__ == "__main__":
    main()
