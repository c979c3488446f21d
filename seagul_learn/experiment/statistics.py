"""Paired statistics over seeds: ONE paired test (:func:`paired_wilcoxon`) behind every comparison of the
library, the experiment and the benchmarks, and the per-method closed-loop statistics of ``seagul reproduce``.

Single-seed results of two ways of training range over an order of magnitude (validation-error ratios of 0.14 to 3.7
between two samplers in a trial), so every comparison is *paired*: seed ``k`` of one method against seed ``k`` of
the other (same initial network, same baseline starts), summarised by the median paired difference (or ratio), the
wins and losses, and a two-sided Wilcoxon signed-rank test on the paired differences (on log values for errors).

The older entry points keep their output keys, which committed results and reports use: :func:`paired_comparison`
(validation errors: ``ratio_median``, ``win_fraction``, ``p_value``, ``seeds``; ``learning.json``),
:func:`paired_success_comparison` (success rates: ``median_difference``, ``wins``, ``losses``, ``ties``,
``p_value``, ``seeds``; ``closed_loop/summary.json``) and :func:`paired_test` (the closed-loop benchmark's
``vs_shipped``: ``median_difference``, ``wins``, ``losses``, ``p``; ``benchmarks/results/closed_loop.json``). Each
is :func:`paired_wilcoxon` with its keys picked.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from seagul_learn.experiment.config import method_label

PAIRED_KEYS = ("seeds", "median_difference", "median_ratio", "wins", "losses", "ties", "statistic", "p_value")
"""The keys of :func:`paired_wilcoxon`'s result."""


def paired_wilcoxon(
    a: Sequence[float] | np.ndarray,
    b: Sequence[float] | np.ndarray,
    *,
    log: bool = False,
    lower_is_better: bool = False,
) -> dict[str, Any]:
    """Seed-paired comparison of ``a`` with ``b`` (``a[k]`` and ``b[k]`` are the same seed's).

    Args:
        a: the method's per-seed values.
        b: the reference's per-seed values, as many.
        log: test the log values (positive errors, whose ratios matter: ``log a - log b``); else ``a - b``.
        lower_is_better: errors (a win is ``a < b``); else success rates (a win is ``a > b``).

    Returns:
        ``seeds``; ``median_difference`` (median of ``a - b``); ``median_ratio`` (median of ``a / b``, NaN when some
        ``b`` is 0); ``wins``/``losses``/``ties`` (seeds where ``a`` is better/worse/equal); ``statistic`` and
        ``p_value``: the two-sided Wilcoxon signed-rank test (``scipy.stats.wilcoxon``: the smaller rank sum T, zero
        differences dropped by its ``"wilcox"`` method, exact p for small samples) on the paired differences, NaN
        with fewer than 2 seeds or when every difference is 0 (nothing to rank).

    Raises:
        ValueError: the lists differ in length or are empty; ``log`` with a value that is not finite and positive.
    """
    x = np.asarray(a, dtype=float)
    y = np.asarray(b, dtype=float)
    if x.shape != y.shape or x.ndim != 1 or x.size == 0:
        raise ValueError(f"need two equally long, non-empty lists of per-seed values, got {x.shape} and {y.shape}")
    if log and (np.any(~np.isfinite(x)) or np.any(~np.isfinite(y)) or np.any(x <= 0) or np.any(y <= 0)):
        raise ValueError("paired log values must be finite and positive")
    tested = np.log(x) - np.log(y) if log else x - y
    statistic = p = math.nan
    if x.size >= 2 and np.any(tested != 0):
        from scipy.stats import wilcoxon

        test = wilcoxon(tested)
        statistic, p = float(test.statistic), float(test.pvalue)
    diff = x - y
    better, worse = (diff < 0, diff > 0) if lower_is_better else (diff > 0, diff < 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = float(np.median(x / y)) if np.all(y != 0) else math.nan
    return {
        "seeds": int(x.size),
        "median_difference": float(np.median(diff)),
        "median_ratio": ratio,
        "wins": int(np.sum(better)),
        "losses": int(np.sum(worse)),
        "ties": int(np.sum(diff == 0)),
        "statistic": statistic,
        "p_value": p,
    }


def paired_success_comparison(method: Sequence[float], reference: Sequence[float]) -> dict[str, Any]:
    """Paired per-seed success rates (higher is better) of a method against a reference method: the keys of
    ``closed_loop/summary.json`` (``median_difference``, ``wins``, ``losses``, ``ties``, ``p_value``, ``seeds``) of
    :func:`paired_wilcoxon`."""
    result = paired_wilcoxon(method, reference)
    return {k: result[k] for k in ("median_difference", "wins", "losses", "ties", "p_value", "seeds")}


def paired_test(a: Sequence[float], b: Sequence[float]) -> dict[str, float]:
    """Seed-paired comparison of success rates (``a`` minus ``b``) with the closed-loop benchmark's keys
    (``vs_shipped`` in ``benchmarks/results/closed_loop.json``): ``median_difference``, ``wins``, ``losses`` and the
    Wilcoxon ``p`` of :func:`paired_wilcoxon`."""
    result = paired_wilcoxon(a, b)
    return {
        "median_difference": result["median_difference"],
        "wins": result["wins"],
        "losses": result["losses"],
        "p": result["p_value"],
    }


def success_rate(episodes: Sequence[Any]) -> float:
    """Fraction of successful episodes (NaN for none)."""
    return float(np.mean([e.success for e in episodes])) if episodes else math.nan


def nanmedian(values: Sequence[float | None]) -> float:
    """Median of the finite values (NaN when there is none)."""
    finite = [float(v) for v in values if v is not None and math.isfinite(float(v))]
    return float(np.median(finite)) if finite else math.nan


def method_statistics(
    method: str,
    success: Mapping[tuple[int, int], float],
    reference_success: Mapping[int, float],
    query_errors: Sequence[Mapping[str, Any]],
    seeds: int,
    budgets: Sequence[int],
    heldout_success: Mapping[int, float] | None = None,
) -> dict[str, Any]:
    """One method's closed-loop statistics over seeds (an entry of ``closed_loop/summary.json``'s ``methods``).

    ``success`` maps ``(seed, budget)`` to the main-grid success rate, ``reference_success`` a seed to its final
    network's rate on the reference grid; ``query_errors`` are the per-seed
    :class:`~seagul_learn.closed_loop.QueryError` dicts. Keys: ``label``, ``policy``, ``success`` (per seed, full
    budget), ``success_median``/``success_q25``/``success_q75``/``success_min``/``success_max``,
    ``reference_success`` (per seed), ``curve`` (``budgets``, ``median``, ``q25``, ``q75``, ``per_seed``
    ``[seed][budget]``) and ``query_error`` (``median`` and ``p95``: medians over seeds of the per-seed values;
    ``per_seed``). ``heldout_success`` maps a seed to its final network's success rate from the held-out starts
    (:func:`~seagul_learn.experiment.runs.evaluate_snapshot`): keys ``heldout_success`` (per seed) and
    ``heldout_success_rate`` (their median; NaN when the run has no held-out starts).
    """
    held = [float(heldout_success[s]) for s in range(seeds)] if heldout_success else [math.nan] * seeds
    per_seed = np.array([[success[(s, b)] for b in budgets] for s in range(seeds)], dtype=float)
    final = per_seed[:, -1]
    q25, q75 = np.percentile(final, [25, 75])
    lo, hi = np.percentile(per_seed, [25, 75], axis=0)
    return {
        "label": method_label(method),
        "policy": f"{method_label(method)} MPC",
        "success": final.tolist(),
        "success_median": float(np.median(final)),
        "success_q25": float(q25),
        "success_q75": float(q75),
        "success_min": float(np.min(final)),
        "success_max": float(np.max(final)),
        "reference_success": [float(reference_success[s]) for s in range(seeds)],
        "heldout_success": held,
        "heldout_success_rate": nanmedian(held),
        "curve": {
            "budgets": [int(b) for b in budgets],
            "median": np.median(per_seed, axis=0).tolist(),
            "q25": lo.tolist(),
            "q75": hi.tolist(),
            "per_seed": per_seed.tolist(),
        },
        "query_error": {
            "median": nanmedian([e["median"] for e in query_errors]),
            "p95": nanmedian([e["p95"] for e in query_errors]),
            "per_seed": [dict(e) for e in query_errors],
        },
    }
