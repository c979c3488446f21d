"""The per-task blocks of ``benchmarks/results/dmc.json``: every controller on the suite's swing-ups in one place.

``benchmarks/bench_dmc.py`` runs the classical controllers itself and gathers the rest from the result files of the
runs too long to repeat there, each written by its own benchmark on the same reset seeds:

* ``learned_mpc`` from ``dmc_learned.json`` (``benchmarks/bench_dmc_learned.py``: seagul's learned short-horizon
  MPC, one network per training seed, each scored on the same reset seeds);
* ``full_horizon`` from ``dmc_reference.json`` (``benchmarks/bench_dmc_reference.py``: the whole-episode
  trajectory optimization with the true model, re-planned);
* ``optimum`` from ``dmc_optimum.json`` (``benchmarks/bench_dmc_optimum.py``: the pendulum's optimum by dynamic
  programming on a grid of its two-dimensional state; ``None`` for the other tasks);
* ``sac`` and ``ppo`` from ``dmc_rl.json`` when it exists (``None`` until those runs are made);
* ``published`` from ``dmc_published.json`` (each number's method, score, budget in environment steps, source).

A block whose source file does not exist, or has no entry for the env, is ``None``: nothing is filled in.

Each task's block (keys are the suite's short names, ``"pendulum-swingup"``)::

    {"env_id", "classical": [rows of bench_dmc.py], "learned_mpc": {...} | None, "full_horizon": {...} | None,
     "optimum": {...} | None, "sac": {...} | None, "ppo": {...} | None, "published": [...]}

``learned_mpc``: ``score_mean`` and ``score_std`` over every (network, reset seed) episode, ``seeds`` the number of
networks (training seeds), ``episodes`` the reset seeds per network, ``solves`` each network's trajectory-optimization
budget, ``horizon``, ``median_ms``/``p95_ms`` (the medians over the networks), ``network`` the first network's file
and ``networks`` every network's own row (file, solves, scores, mean); ``wide`` (or None) the same networks on a wider
set of reset seeds (``evaluate --wide-seeds``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"

__all__ = ["assemble", "learned_block", "published_block", "reference_block", "rl_block", "short_name"]


def short_name(env_id: str) -> str:
    """``"dm_control/pendulum-swingup-v0"`` -> ``"pendulum-swingup"``."""
    return env_id.removeprefix("dm_control/").removesuffix("-v0")


def _source(name: str) -> str:
    """The repository path of a result file, as a block's ``source``."""
    return f"benchmarks/results/{name}"


def _load(name: str, results: Path) -> dict[str, Any] | None:
    path = results / name
    return json.loads(path.read_text()) if path.exists() else None


def learned_block(env_id: str, results: Path = RESULTS) -> dict[str, Any] | None:
    """The learned MPC's block from ``dmc_learned.json`` (module docstring), or None."""
    data = _load("dmc_learned.json", results)
    block = (data or {}).get("tasks", {}).get(env_id) or {}
    rows = block.get("rows") or []
    if not rows:
        return None
    params = block.get("params", {})
    scores = [s for row in rows for s in row["scores"]]
    return {
        "score_mean": round(float(np.mean(scores)), 3),
        "score_std": round(float(np.std(scores)), 3),
        "score_std_over_seeds": round(float(np.std([row["mean"] for row in rows])), 3),
        "seeds": len(rows),
        "episodes": len(rows[0]["scores"]),
        "reset_seeds": rows[0]["seeds"],
        "solves": max(int(row["solves"]) for row in rows),
        "horizon": int(rows[0].get("horizon", params.get("horizon"))),
        "time_to_go": rows[0].get("time_to_go", params.get("tau_v")),
        "hold": rows[0].get("hold"),
        "dt": params.get("dt"),
        "path_bounds": params.get("path_bounds", "hard"),
        "median_ms": round(float(np.median([row["decision_ms_median"] for row in rows])), 4),
        "p95_ms": round(float(np.median([row["decision_ms_p95"] for row in rows])), 4),
        "network": rows[0]["network"],
        "networks": [
            {"network": row["network"], "solves": row["solves"], "mean": row["mean"], "scores": row["scores"]}
            for row in rows
        ],
        "wide": None
        if not block.get("wide")
        else {
            "score_mean": block["wide"]["score_mean"],
            "score_std": block["wide"]["score_std"],
            "episodes": len(block["wide"]["seeds"]),
            "reset_seeds": block["wide"]["seeds"],
            "networks": [{"network": r["network"], "mean": r["mean"]} for r in block["wide"]["rows"]],
        },
        "source": _source("dmc_learned.json"),
    }


def reference_block(env_id: str, results: Path = RESULTS) -> dict[str, Any] | None:
    """The full-horizon reference's block from ``dmc_reference.json``, or None."""
    data = _load("dmc_reference.json", results)
    entry = (data or {}).get("tasks", {}).get(env_id)
    if not entry:
        return None
    return {
        "score_mean": entry["mean"],
        "score_std": entry["std"],
        "episodes": len(entry["scores"]),
        "reset_seeds": entry["seeds"],
        "median_ms": entry.get("decision_ms_median"),
        "p95_ms": entry.get("decision_ms_p95"),
        "source": _source("dmc_reference.json"),
    }


def optimum_block(env_id: str, results: Path = RESULTS) -> dict[str, Any] | None:
    """The grid optimum's block from ``dmc_optimum.json`` (``score_mean``, ``score_std``, ``episodes`` and
    ``reset_seeds`` on the evaluation seeds; ``wide``: the same on the wider set, beside ``energy_wide``, the
    classical swing-up on those episodes; ``spec``: the grid), or None."""
    data = _load("dmc_optimum.json", results)
    entry = (data or {}).get("tasks", {}).get(env_id)
    if not entry:
        return None

    def summary(part: dict[str, Any]) -> dict[str, Any]:
        return {
            "score_mean": part["mean"],
            "score_std": part["std"],
            "episodes": len(part["scores"]),
            "reset_seeds": part["seeds"],
        }

    return {
        **summary(entry),
        "wide": summary(entry["wide"]),
        "energy_wide": summary(entry["energy_wide"]),
        "spec": entry["spec"],
        "median_ms": entry.get("decision_ms_median"),
        "source": _source("dmc_optimum.json"),
    }


def rl_block(env_id: str, algo: str, results: Path = RESULTS) -> dict[str, Any] | None:
    """An RL baseline's block (``score_mean``, ``score_std``, ``seeds``, ``env_steps``, and ``model`` where the
    selected model is committed) from ``dmc_rl.json``, or None when that run has not been made."""
    data = _load("dmc_rl.json", results)
    entry = ((data or {}).get("tasks", {}).get(env_id) or {}).get(algo.lower())
    if not entry:
        return None
    keys = ("score_mean", "score_std", "seeds", "env_steps", "model", "model_seed")
    return {key: entry[key] for key in keys if key in entry} | {"source": _source("dmc_rl.json")}


def published_block(env_id: str, results: Path = RESULTS) -> list[dict[str, Any]]:
    """The published scores of the env's task from ``dmc_published.json``: ``method``, ``score``, ``env_steps``,
    ``source`` (its pinned file) and ``url``."""
    data = _load("dmc_published.json", results)
    name = short_name(env_id)
    return [
        {key: p[key] for key in ("method", "score", "env_steps", "source", "url") if key in p}
        for p in (data or {}).get("scores", [])
        if p["task"] == name
    ]


def assemble(classical: dict[str, list[dict[str, Any]]], results: Path = RESULTS) -> dict[str, dict[str, Any]]:
    """One block per env of ``classical`` (env id -> its classical rows), keyed by the short name."""
    return {
        short_name(env_id): {
            "env_id": env_id,
            "classical": rows,
            "learned_mpc": learned_block(env_id, results),
            "full_horizon": reference_block(env_id, results),
            "optimum": optimum_block(env_id, results),
            "sac": rl_block(env_id, "sac", results),
            "ppo": rl_block(env_id, "ppo", results),
            "published": published_block(env_id, results),
        }
        for env_id, rows in classical.items()
    }
