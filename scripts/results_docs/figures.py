"""The figures under ``docs/figures/results/``, drawn from the result files."""

from __future__ import annotations

import math
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from .common import FIGURES, ROOT, load
from .controllers import KIND_LABEL, is_rl, short_name
from .robust import robust_tasks


def plot_horizon_sweep(task: str, rows: Sequence[Mapping[str, Any]], path: Path) -> None:
    """Grid success and median step time against the horizon, per MPC kind, the full horizon and LQR as lines."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8), constrained_layout=True)
    for kind, style in (("learned-mpc", "o-"), ("quadratic-mpc", "s--"), ("do-mpc", "^:")):
        pts = sorted((r["horizon"], r) for r in rows if r["kind"] == kind)
        if not pts:
            continue
        xs = [n for n, _ in pts]
        axes[0].plot(xs, [r["success"] for _, r in pts], style, label=KIND_LABEL[kind])
        axes[1].plot(xs, [r["median_ms"] for _, r in pts], style, label=KIND_LABEL[kind])
    for kind, color in (("full-horizon", "k"), ("lqr", "0.5")):
        ref = next((r for r in rows if r["kind"] == kind), None)
        if ref is not None:
            axes[0].axhline(ref["success"], color=color, ls="--", lw=1, label=ref["controller"])
            axes[1].axhline(ref["median_ms"], color=color, ls="--", lw=1, label=ref["controller"])
    axes[0].set_ylabel("grid success")
    axes[0].set_ylim(-0.02, 1.02)
    axes[1].set_ylabel("median step time (ms)")
    axes[1].set_yscale("log")
    for ax in axes:
        ax.set_xlabel("horizon N (control steps)")
        ax.set_xscale("log")
        ax.set_xticks(sorted({r["horizon"] for r in rows if r["horizon"]}))
        ax.get_xaxis().set_major_formatter(plt.ScalarFormatter())
        ax.get_xaxis().set_minor_formatter(plt.NullFormatter())
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle(f"{task}: MPC horizon sweep (learned value vs quadratic terminal cost)")
    fig.savefig(path, dpi=100)
    plt.close(fig)


def draw_figures() -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    FIGURES.mkdir(parents=True, exist_ok=True)
    drawn = []
    closed = load("closed_loop.json")
    for task in ("acrobot", "glider"):
        block = closed[task]
        fig, ax = plt.subplots(figsize=(7.5, 4.2), constrained_layout=True)
        for name, m in block["methods"].items():
            pts = sorted((int(b), c) for b, c in m["budgets"].items())
            xs = [b for b, _ in pts]
            ax.plot(xs, [c["success_median"] for _, c in pts], "o-", lw=2.5 if name == block["method"] else 1.2,
                    label=name + (" (shipped)" if name == block["method"] else ""))
            ax.fill_between(xs, [c.get("success_q25", math.nan) for _, c in pts],
                            [c.get("success_q75", math.nan) for _, c in pts], alpha=0.12)
        ax.axhline(block["full_horizon_success_rate"], color="k", ls="--", lw=1, label="full-horizon MPC")
        ax.set_xscale("log")
        ax.set_xlabel("NLP solves per network")
        ax.set_ylabel(f"grid success (median of seeds, {block['grid']})")
        ax.set_ylim(-0.02, 1.02)
        ax.set_title(f"{task}: closed-loop success per solve")
        ax.legend(fontsize=7, loc="center right")
        path = FIGURES / f"success_vs_solves_{task}.png"
        fig.savefig(path, dpi=100)
        plt.close(fig)
        drawn.append(path)

    fig, axes = plt.subplots(1, 2, figsize=(15, 4.4), constrained_layout=True)
    for ax, task in zip(axes, ("acrobot", "glider"), strict=True):
        for r in (r for r in load(f"controllers_{task}.json")["rows"] if not is_rl(r)):
            ax.scatter(r["median_ms"], r["heldout_success"], s=45, label=short_name(r["method"]),
                       marker="*" if short_name(r["method"]).startswith("learned") else "o")
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
        ax.set_xscale("log")
        ax.set_xlabel("median step time (ms)")
        ax.set_ylabel("held-out success")
        ax.set_ylim(-0.05, 1.08)
        ax.set_title(task)
    path = FIGURES / "controllers.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    drawn.append(path)

    sys.path.insert(0, str(ROOT))
    from benchmarks import bench_baselines, bench_param_adversary, bench_rl_baselines, bench_robust

    rl = load("rl_baselines.json")
    base = load("baselines.json")
    for task in ("acrobot", "glider"):
        path = FIGURES / f"rl_curves_{task}.png"
        bench_rl_baselines.plot(task, rl[task], path)
        drawn.append(path)
        path = FIGURES / f"baselines_cdf_{task}.png"
        bench_baselines.plot_cdf(task, base[task]["rows"], path)
        drawn.append(path)
        path = FIGURES / f"horizon_sweep_{task}.png"
        plot_horizon_sweep(task, base[task]["rows"], path)
        drawn.append(path)
    path = FIGURES / "robust_acrobot.png"
    bench_param_adversary.plot(load("param_adversary.json")["acrobot"], path, "acrobot")
    drawn.append(path)
    for task in robust_tasks():
        path = FIGURES / f"robust_shipped_{task}.png"
        bench_robust.plot(task, load("param_adversary.json")[task], path)
        drawn.append(path)
    return drawn
