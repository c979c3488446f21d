"""The success-vs-solves figure (``success_vs_solves.png``) of ``seagul reproduce`` and of the closed-loop benchmark
(``benchmarks/results/success_vs_solves_<task>.png``): closed-loop success on the grid against the NLP solves spent
on each network, median and 25-75 % band over seeds per method, with reference controllers as horizontal lines.

Both pipelines draw it with :func:`plot_success_vs_solves`; it reads either per-method statistics of
``seagul reproduce`` (:func:`~seagul_learn.experiment.statistics.method_statistics`: a ``curve``) or a method of
the benchmark's summary (:func:`~seagul_learn.experiment.benchmark.summarize`: per-budget rows, which may carry the
cumulative solve time, drawn in a second panel).
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping
from pathlib import Path
from typing import Any

import numpy as np


def success_curve(entry: Mapping[str, Any]) -> dict[str, Any]:
    """One method's curve: ``budgets``, ``median``, ``q25``, ``q75`` (rates in [0, 1]), ``seeds`` (per budget),
    ``solve_time_s`` (median cumulative solve time per budget, or None when some budget lacks it) and ``label``.

    ``entry`` is a :func:`~seagul_learn.experiment.statistics.method_statistics` dict (``curve``, ``policy``) or a
    method of the benchmark's summary (``budgets``: budget -> row with ``success_median``, ``success_q25``,
    ``success_q75``, ``success_per_seed`` and ``solve_time_s_median``).
    """
    if "curve" in entry:
        curve = entry["curve"]
        seeds = len(curve.get("per_seed", [])) or 1
        return {
            "budgets": [int(b) for b in curve["budgets"]],
            "median": list(curve["median"]),
            "q25": list(curve["q25"]),
            "q75": list(curve["q75"]),
            "seeds": [seeds] * len(curve["budgets"]),
            "solve_time_s": None,
            "label": entry.get("policy", entry.get("label", "")),
        }
    budgets = sorted(int(b) for b in entry["budgets"])
    rows = [entry["budgets"][str(b)] for b in budgets]
    times = [float(r.get("solve_time_s_median", math.nan)) for r in rows]
    timed = all(math.isfinite(t) and t > 0 for t in times)
    return {
        "budgets": budgets,
        "median": [r["success_median"] for r in rows],
        "q25": [r["success_q25"] for r in rows],
        "q75": [r["success_q75"] for r in rows],
        "seeds": [len(r["success_per_seed"]) for r in rows],
        "solve_time_s": times if timed else None,
        "label": "",
    }


def plot_success_vs_solves(
    methods: Mapping[str, Mapping[str, Any]],
    path: str | Path,
    references: Mapping[str, float] | None = None,
    title: str = "",
    labels: Mapping[str, str] | None = None,
    emphasize: Collection[str] = (),
) -> None:
    """Grid success (%) vs solves per network, and vs cumulative NLP solve time when some method recorded it.

    Args:
        methods: method name -> its statistics (either form of :func:`success_curve`).
        path: the PNG to write (matplotlib Agg).
        references: controller name -> success rate, one horizontal line each (NaN: left out).
        title: the figure's title.
        labels: legend names of methods (default: the statistics' ``policy``, else the method's name).
        emphasize: methods drawn with a thicker line (the shipped one).

    The median and the 25-75 % band over seeds per method; a point with fewer seeds than the method's most is marked
    ``n=<seeds>``. The solve axis is logarithmic when the budgets span a factor of 10 or more.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curves = {m: success_curve(entry) for m, entry in methods.items()}
    with_times = any(c["solve_time_s"] is not None for c in curves.values())
    rows_of_legend = (len(curves) + len(references or {}) + 2) // 3
    size = (12 if with_times else 7.5, 4.5 + 0.25 * rows_of_legend)
    fig, axes_arr = plt.subplots(1, 2 if with_times else 1, figsize=size, squeeze=False)
    axes = list(axes_arr[0])
    budgets = sorted({b for c in curves.values() for b in c["budgets"]})
    for method, c in curves.items():
        name = (labels or {}).get(method) or c["label"] or method
        panels = [c["budgets"]] + ([c["solve_time_s"]] if c["solve_time_s"] is not None else [])
        for ax, xs in zip(axes, panels, strict=False):
            (line,) = ax.plot(
                xs, 100 * np.asarray(c["median"]), marker="o", ms=4, label=name, lw=2.5 if method in emphasize else 1.5
            )
            ax.fill_between(
                xs, 100 * np.asarray(c["q25"]), 100 * np.asarray(c["q75"]), color=line.get_color(), alpha=0.15
            )
            for x, y, n in zip(xs, c["median"], c["seeds"], strict=True):
                if n < max(c["seeds"]):
                    ax.annotate(f"n={n}", (x, 100 * y), textcoords="offset points", xytext=(4, 6), fontsize=7)
    log_x = bool(budgets) and budgets[-1] >= 10 * budgets[0]
    for k, ax in enumerate(axes):
        for (name, rate), style in zip((references or {}).items(), ("--", ":", "-.", (0, (1, 3))), strict=False):
            if math.isfinite(rate):
                ax.axhline(
                    100 * rate, color="k", ls=style, lw=1, label=f"{name}: {100 * rate:.4g} %" if k == 0 else None
                )
        if k == 0:
            ax.set_xlabel("NLP solves per network")
            if log_x:
                ax.set_xscale("log")
            else:
                ax.set_xticks(budgets)
        else:
            ax.set_xlabel("NLP solve time per network (s)")
            ax.set_xscale("log")
        ax.set_ylabel("closed-loop success on the grid (%)")
        ax.set_ylim(-3, 103)
        ax.grid(True, which="both", alpha=0.3)
    handles, names = axes[0].get_legend_handles_labels()
    bottom = 0.07 * rows_of_legend * 4.5 / size[1]
    fig.legend(handles, names, loc="lower center", ncol=3, fontsize=8, frameon=False)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout(rect=(0, bottom, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)
