"""Paired-seed comparison of training variants: ratios, win fractions, Wilcoxon tests, curves with bands.

Single-seed ratios between two samplers range over an order of magnitude (0.14 to 3.7 in a trial), so every
comparison here is *paired* (same seed, same initial network, same baseline starts) and summarised by the median of
the per-seed ratios, the fraction of seeds the first variant wins, and a two-sided Wilcoxon signed-rank test on the
paired log-errors: the library's one paired test, :func:`seagul_learn.experiment.statistics.paired_wilcoxon`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

#: The two validation metrics every training run records.
METRICS = ("mse_initial", "mse_all_knots")


@dataclass(frozen=True)
class PairedComparison:
    """``variant`` against ``baseline`` over paired seeds on one metric."""

    ratio_median: float
    """Median over seeds of ``variant / baseline``."""
    win_fraction: float
    """Fraction of seeds where the variant's error is lower."""
    p_value: float
    """Two-sided Wilcoxon signed-rank p-value on paired log-errors (NaN with < 2 seeds or all ties)."""
    seeds: int
    """Number of paired seeds."""


def paired_comparison(variant: Sequence[float], baseline: Sequence[float]) -> PairedComparison:
    """Compare paired per-seed errors (lower is better): the one paired test,
    :func:`seagul_learn.experiment.statistics.paired_wilcoxon` on the log errors, as a :class:`PairedComparison`
    (the keys of ``learning.json`` and of the sample-efficiency benchmark's results)."""
    from seagul_learn.experiment.statistics import paired_wilcoxon

    a = np.asarray(variant, dtype=float)
    b = np.asarray(baseline, dtype=float)
    if a.shape != b.shape or a.ndim != 1 or a.size == 0:
        raise ValueError(f"need two equally long, non-empty lists of per-seed errors, got {a.shape} and {b.shape}")
    if np.any(~np.isfinite(a)) or np.any(~np.isfinite(b)) or np.any(a <= 0) or np.any(b <= 0):
        raise ValueError("per-seed errors must be finite and positive")
    result = paired_wilcoxon(a, b, log=True, lower_is_better=True)
    return PairedComparison(
        result["median_ratio"], result["wins"] / result["seeds"], result["p_value"], result["seeds"]
    )


def final_metric(runs: Sequence[Mapping[str, Any]], key: str) -> list[float]:
    """The last recorded value of ``key`` of each run's ``metrics`` list (one run per seed)."""
    return [float(run["metrics"][-1][key]) for run in runs]


def curves_by_solves(runs: Sequence[Mapping[str, Any]], key: str) -> tuple[np.ndarray, np.ndarray]:
    """``(solves, values[seed, point])`` at the solve counts every run recorded (last value per count)."""
    series = []
    for run in runs:
        by_solves: dict[int, float] = {}
        for m in run["metrics"]:
            by_solves[int(m["solves"])] = float(m[key])
        series.append(by_solves)
    xs = sorted(set.intersection(*(set(s) for s in series)))
    return np.asarray(xs), np.array([[s[x] for x in xs] for s in series])


def plot_curves_with_band(
    results: Mapping[str, Sequence[Mapping[str, Any]]], path: str | Path, title: str = ""
) -> None:
    """Both validation metrics vs solves: median over seeds and 25-75 % band, one line per variant."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
    for ax, key in zip(axes, METRICS, strict=True):
        for name, runs in results.items():
            xs, values = curves_by_solves(runs, key)
            median = np.median(values, axis=0)
            lo, hi = np.percentile(values, [25, 75], axis=0)
            (line,) = ax.plot(xs, median, marker="o", ms=3, label=name)
            ax.fill_between(xs, lo, hi, color=line.get_color(), alpha=0.15)
        ax.set_yscale("log")
        ax.set_xlabel("solves")
        ax.set_ylabel(f"validation {key}")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=8)
    seeds = len(next(iter(results.values())))
    fig.suptitle(title or f"median and 25-75 % band over {seeds} seeds")
    fig.savefig(path, dpi=110)
    plt.close(fig)
