"""Reporting: tables and figures of closed-loop evaluations, and a report a person can open.

Closed-loop evaluation tables and figures (the episodes themselves are run by :mod:`seagul_control.evaluation`,
which returns plain :class:`~seagul_control.evaluation.EpisodeResult` data): :func:`summarize` (one row per policy)
and :func:`write_outputs`, which writes ``results.json`` (every episode), ``summary.json`` / ``summary.csv`` (one row
per policy), ``heatmap.png`` (:func:`plot_heatmaps`; the task's ``profile.heatmap_metric``: acrobot final distance
over the ``(th1, th2)`` grid at zero velocity, like Fig. 2; glider trajectory cost over the ``(x, z)`` grid, like
Fig. 4) and, for a task with a ``profile.trajectory_plot`` (the glider), ``trajectories.png``
(:func:`plot_trajectories`; x-z paths, Fig. 3 centre). Every function takes a Task or a registered task name.
matplotlib is imported only inside the figure functions (Agg backend, headless).

:func:`controller_animation` draws one closed-loop episode per controller side by side as an animated GIF, from a
given start such as :func:`hard_start` (the corner of X0 farthest from the goal).

The report (Markdown with embedded figures, plus a self-contained HTML copy) is assembled from plain data (sections
of text with a heading level, tables as lists of rows, PNG or GIF figure paths), so every stage of an experiment can
add to it without knowing how it is rendered.
"""

from __future__ import annotations

import base64
import csv
import html
import importlib.metadata
import io
import json
import math
import os
import platform
import re
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, ImageDraw

from seagul_control._io import atomic_write_bytes, atomic_write_text
from seagul_control.evaluation import EpisodeResult, run_policy_episode
from seagul_envs.tasks import resolve_task
from seagul_envs.tasks.base import Task
from seagul_envs.tasks.profile import TrajectoryPlot

GLIDER_TRAJECTORY_PLOT = TrajectoryPlot(
    axes=(0, 1), labels=("x (m)", "z (m)"), goal_label="perch", title="glider trajectories (o = perched, x = missed)"
)
"""The glider's x-z figure (:func:`plot_glider_trajectories`, paper Fig. 3 centre)."""


# ------------------------------------------------------------------------------------------------ evaluation tables
def summarize(task: Task | str, results: Sequence[EpisodeResult]) -> list[dict[str, Any]]:
    """One row per policy: success rate, mean distance and cost, solver step times and fallbacks (and the success
    rate again under the task's ``profile.success_column``, e.g. the glider's ``perch_success_rate``)."""
    column = resolve_task(task).profile.success_column
    rows = []
    for name in dict.fromkeys(r.policy for r in results):
        rs = [r for r in results if r.policy == name]
        times = np.concatenate([np.asarray(r.solve_times) for r in rs]) if rs else np.zeros(0)
        iters = np.concatenate([np.asarray(r.iterations, dtype=float) for r in rs]) if rs else np.zeros(0)
        row: dict[str, Any] = {
            "policy": name,
            "episodes": len(rs),
            "success_rate": float(np.mean([r.success for r in rs])),
            "mean_final_distance": float(np.mean([r.final_distance for r in rs])),
            "median_final_distance": float(np.median([r.final_distance for r in rs])),
            "mean_cost": float(np.mean([r.cost for r in rs])),
            "median_cost": float(np.median([r.cost for r in rs])),
            "crashes": int(sum(r.terminated for r in rs)),
            "median_step_ms": float(np.median(times) * 1e3) if times.size else math.nan,
            "p95_step_ms": float(np.percentile(times, 95) * 1e3) if times.size else math.nan,
            "max_step_ms": float(np.max(times) * 1e3) if times.size else math.nan,
            "mean_iterations": float(np.mean(iters)) if iters.size else math.nan,
            "fallback_steps": int(sum(r.fallbacks for r in rs)),
            "steps": int(sum(r.steps for r in rs)),
        }
        if column:
            row[column] = row["success_rate"]
        rows.append(row)
    return rows


def write_outputs(
    out_dir: str | os.PathLike[str],
    task: Task | str,
    results: Sequence[EpisodeResult],
    grid: dict[str, Any] | None = None,
    extra: dict[str, Any] | None = None,
) -> dict[str, Path]:
    """Write the JSON/CSV tables and the PNG figures; returns their paths by name."""
    task = resolve_task(task)
    task_name = task.name
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows = summarize(task, results)
    paths = {
        "results": out / "results.json",
        "summary_json": out / "summary.json",
        "summary_csv": out / "summary.csv",
    }
    payload = {"task": task_name, "grid": grid, "episodes": [asdict(r) for r in results], **(extra or {})}
    paths["results"].write_text(json.dumps(payload, allow_nan=True))
    paths["summary_json"].write_text(json.dumps({"task": task_name, "policies": rows, **(extra or {})}, indent=2))
    with paths["summary_csv"].open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    if grid is not None:
        paths["heatmap"] = plot_heatmaps(task, results, grid, out / "heatmap.png")
    figure = task.profile.trajectory_plot
    if figure is not None and any(r.states for r in results):
        paths["trajectories"] = plot_trajectories(results, out / "trajectories.png", figure, task)
    return paths


# ------------------------------------------------------------------------------------------------ animations
def hard_start(task: Task | str) -> np.ndarray:
    """The corner of X0 farthest from the goal in the evaluation grid's coordinates (``task.profile.grid``; every
    coordinate when it names none), the others at X0's centre: acrobot ``(th1, th2) = (pi - 0.3, -0.3)`` at rest."""
    task = resolve_task(task)
    x = 0.5 * (np.asarray(task.x0_low, dtype=float) + np.asarray(task.x0_high, dtype=float))
    for i in task.profile.grid.coords or range(task.nx):
        lo, hi = float(task.x0_low[i]), float(task.x0_high[i])
        x[i] = lo if abs(lo - task.goal[i]) >= abs(hi - task.goal[i]) else hi
    return x


def controller_animation(
    task: Task | str,
    policies: Sequence[tuple[str, Any]],
    x0: np.ndarray,
    path: Path,
    *,
    env_id: str | None = None,
    fps: float | None = None,
    max_width: int = 320,
) -> tuple[Path, list[EpisodeResult]]:
    """One closed-loop episode per controller from the same start ``x0``, side by side, as an animated GIF.

    ``policies`` are ``(label, predictor)`` pairs (anything with SB3's ``predict``: the MPCs, LQR, an
    :class:`~seagul_control.evaluation.SB3Policy`). Each runs in the task's env (or ``gym.make(env_id)``) with
    ``render_mode="rgb_array"``; its frames are scaled to ``max_width`` pixels, a label strip above each panel
    names the controller and, once its episode ends, whether it succeeded and its cost; an episode that ends
    early holds its last frame. ``fps`` defaults to the env's control rate (real time). Written atomically.
    Returns the path and the episodes (for captions and tables).
    """
    task = resolve_task(task)
    if not policies:
        raise ValueError("controller_animation needs at least one (label, policy) pair")
    panels: list[list[Image.Image]] = []
    episodes: list[EpisodeResult] = []
    for label, policy in policies:
        frames: list[np.ndarray] = []
        episode, _ = run_policy_episode(
            task, policy, np.asarray(x0, dtype=float), label=label, env_id=env_id, frames=frames
        )
        episodes.append(episode)
        images = []
        for frame in frames:
            img = Image.fromarray(np.asarray(frame, dtype=np.uint8))
            if img.width > max_width:
                img = img.resize((max_width, round(img.height * max_width / img.width)), Image.Resampling.LANCZOS)
            images.append(img)
        panels.append(images)
    n = max(len(p) for p in panels)
    strip = 34
    width = sum(p[0].width for p in panels)
    height = max(p[0].height for p in panels) + strip
    out: list[Image.Image] = []
    for k in range(n):
        canvas = Image.new("RGB", (width, height), "white")
        draw = ImageDraw.Draw(canvas)
        x = 0
        for images, episode in zip(panels, episodes, strict=True):
            img = images[min(k, len(images) - 1)]
            canvas.paste(img, (x, strip))
            status = ""
            if k >= len(images) - 1:
                status = f"{'success' if episode.success else 'failure'}, cost {episode.cost:.1f}"
            draw.text((x + 6, 3), episode.policy, fill="black")
            draw.text((x + 6, 18), status, fill="darkgreen" if episode.success else "darkred")
            x += img.width
        out.append(canvas.convert("P", palette=Image.Palette.ADAPTIVE, colors=128))
    rate = fps if fps is not None else 1.0 / float(task.control_period)
    buffer = io.BytesIO()
    durations = [round(1000.0 / rate)] * (n - 1) + [1500]  # hold the final frame before the loop restarts
    out[0].save(buffer, format="GIF", save_all=True, append_images=out[1:], duration=durations, loop=0)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, buffer.getvalue())
    return path, episodes


# ------------------------------------------------------------------------------------------------ evaluation figures
def plot_heatmaps(task: Task | str, results: Sequence[EpisodeResult], grid: dict[str, Any], path: Path) -> Path:
    """One panel per policy: the task's ``profile.heatmap_metric`` over the grid, log colour (final distance for the
    acrobot, trajectory cost for the glider)."""
    task = resolve_task(task)
    task_name = task.name
    # matplotlib only when a figure is drawn: it is slow to import and selects its backend (Agg) on first use.
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    names = list(dict.fromkeys(r.policy for r in results))
    n1, n2 = grid["shape"]
    ax1, ax2 = (np.asarray(a) for a in grid["axes"])
    metric = task.profile.heatmap_metric
    values = {name: np.full((n1, n2), np.nan) for name in names}
    success = {name: np.zeros((n1, n2), dtype=bool) for name in names}
    for r in results:
        i, j = divmod(r.index, n2)
        values[r.policy][i, j] = getattr(r, metric)
        success[r.policy][i, j] = r.success
    finite = np.concatenate([v[np.isfinite(v)].ravel() for v in values.values()])
    vmin = max(float(np.min(finite)), 1e-4) if finite.size else 1e-4
    vmax = max(float(np.max(finite)), vmin * 10) if finite.size else 1.0
    fig, axes = plt.subplots(1, len(names), figsize=(3.6 * len(names) + 0.8, 3.4), squeeze=False)
    image = None
    for ax, name in zip(axes[0], names, strict=True):
        # Cells centred on the grid points.
        d1 = (ax1[-1] - ax1[0]) / (n1 - 1) if n1 > 1 else 1.0
        d2 = (ax2[-1] - ax2[0]) / (n2 - 1) if n2 > 1 else 1.0
        extent = (ax2[0] - d2 / 2, ax2[-1] + d2 / 2, ax1[0] - d1 / 2, ax1[-1] + d1 / 2)
        image = ax.imshow(
            values[name], origin="lower", extent=extent, aspect="auto", cmap="viridis", norm=LogNorm(vmin, vmax)
        )
        fail = np.argwhere(~success[name])
        if fail.size:
            ax.scatter(ax2[fail[:, 1]], ax1[fail[:, 0]], marker="x", s=10, c="white", linewidths=0.6)
        ax.set_title(f"{name}\nsuccess {success[name].mean():.0%}", fontsize=9)
        ax.set_xlabel(grid["dims"][1])
        ax.set_ylabel(grid["dims"][0])
    label = "||x(T) - x*||" if metric == "final_distance" else "trajectory cost"
    if image is not None:
        fig.colorbar(image, ax=list(axes[0]), label=label + " (log)")
    fig.suptitle(f"{task_name}: {label} over the start grid (x = failure)", fontsize=10, y=1.08)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return path


def plot_glider_trajectories(results: Sequence[EpisodeResult], path: Path, max_per_policy: int = 9) -> Path:
    """x-z paths of recorded glider episodes, one colour per policy; the perch at the origin (Fig. 3 centre)."""
    return plot_trajectories(results, path, GLIDER_TRAJECTORY_PLOT, None, max_per_policy)


def plot_trajectories(
    results: Sequence[EpisodeResult],
    path: Path,
    figure: TrajectoryPlot,
    task: Task | None = None,
    max_per_policy: int = 9,
) -> Path:
    """Paths of recorded episodes in the plane of ``figure.axes``, one colour per policy, the goal marked (``o``:
    success, ``x``: failure). Without ``task`` the goal is the origin and the axis labels must be given."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(dict.fromkeys(r.policy for r in results))
    fig, ax = plt.subplots(figsize=(7, 3.6))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    i, j = figure.axes
    labels = figure.labels or (
        (task.state_names[i], task.state_names[j]) if task is not None else (f"x[{i}]", f"x[{j}]")
    )
    goal = (float(task.goal[i]), float(task.goal[j])) if task is not None else (0.0, 0.0)
    for k, name in enumerate(names):
        recorded = [r for r in results if r.policy == name and r.states]
        picks = recorded[:: max(1, len(recorded) // max_per_policy)][:max_per_policy]
        for m, r in enumerate(picks):
            s = np.asarray(r.states)
            ax.plot(s[:, i], s[:, j], color=colors[k % len(colors)], lw=1, alpha=0.8, label=name if m == 0 else None)
            ax.plot(s[-1, i], s[-1, j], "o" if r.success else "x", color=colors[k % len(colors)], ms=4)
    ax.plot([goal[0]], [goal[1]], marker="*", ms=12, color="k", label=figure.goal_label)
    ax.set_xlabel(labels[0])
    ax.set_ylabel(labels[1])
    ax.set_title(figure.title)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return path


# ------------------------------------------------------------------------------------------------ the report
#: Libraries whose versions every report records.
REPORTED_PACKAGES = ("seagul", "numpy", "scipy", "casadi", "torch", "gymnasium", "mujoco", "stable-baselines3")


@dataclass
class Table:
    """A table: a header row and data rows (cells are rendered with ``str`` unless floats)."""

    header: Sequence[str]
    """Column names."""
    rows: Sequence[Sequence[Any]]
    """Data rows, one sequence of cells each."""


@dataclass
class Section:
    """A titled part of the report: paragraphs, tables and figures in that order."""

    title: str
    """Heading text."""
    paragraphs: list[str] = field(default_factory=list)
    """Markdown paragraphs."""
    tables: list[Table] = field(default_factory=list)
    """Tables."""
    figures: list[tuple[str, str]] = field(default_factory=list)
    """``(path relative to the report, caption)`` pairs (PNG or GIF)."""
    level: int = 2
    """Heading level (2: a part of the report, 3: a subsection of the part before it)."""


def library_versions() -> dict[str, str]:
    """Installed versions of the libraries that shape the results."""
    versions = {"python": platform.python_version()}
    for name in REPORTED_PACKAGES:
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return versions


def machine_description() -> str:
    """One line naming the machine (CPU model, cores, OS)."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, {platform.system()} {platform.release()}"


def _cell(value: Any) -> str:
    if isinstance(value, float):
        if value != value:  # NaN
            return "n/a"
        return f"{value:.4g}"
    return str(value)


def render_markdown(title: str, sections: Sequence[Section]) -> str:
    """Markdown text of the report (figures referenced by relative path)."""
    lines = [f"# {title}", ""]
    for section in sections:
        lines += [f"{'#' * section.level} {section.title}", ""]
        for paragraph in section.paragraphs:
            lines += [paragraph, ""]
        for table in section.tables:
            lines.append("| " + " | ".join(table.header) + " |")
            lines.append("|" + "---|" * len(table.header))
            for row in table.rows:
                lines.append("| " + " | ".join(_cell(c) for c in row) + " |")
            lines.append("")
        for path, caption in section.figures:
            lines += [f"![{caption}]({path})", "", f"*{caption}*", ""]
    return "\n".join(lines).rstrip() + "\n"


def _inline_markdown(text: str) -> str:
    """The little inline Markdown the report uses (code, bold) as HTML."""
    text = html.escape(text)
    text = re.sub(r"`([^`]+)`", r"<code>\1</code>", text)
    return re.sub(r"\*\*(.+?)\*\*", r"<b>\1</b>", text)  # bold may hold a lone * (``x*``, the goal)


_IMAGE_TYPES = {".png": "image/png", ".gif": "image/gif", ".jpg": "image/jpeg", ".jpeg": "image/jpeg"}


def render_html(title: str, sections: Sequence[Section], base_dir: Path) -> str:
    """Self-contained HTML (figures, PNG or animated GIF, embedded as base64) that opens in any browser."""
    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'>",
        f"<title>{html.escape(title)}</title>",
        "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto;line-height:1.45}"
        "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;padding:3px 8px;text-align:right}"
        "th{background:#eee}img{max-width:100%}figcaption{font-style:italic;color:#444}"
        "code{background:#f4f4f4;padding:0 3px}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>",
    ]
    for section in sections:
        parts.append(f"<h{section.level}>{html.escape(section.title)}</h{section.level}>")
        parts += [f"<p>{_inline_markdown(p)}</p>" for p in section.paragraphs]
        for table in section.tables:
            parts.append("<table><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in table.header) + "</tr>")
            for row in table.rows:
                parts.append("<tr>" + "".join(f"<td>{html.escape(_cell(c))}</td>" for c in row) + "</tr>")
            parts.append("</table>")
        for path, caption in section.figures:
            figure = base_dir / path
            if figure.exists():
                data = base64.b64encode(figure.read_bytes()).decode("ascii")
                src = f"data:{_IMAGE_TYPES.get(figure.suffix.lower(), 'image/png')};base64,{data}"
            else:
                src = html.escape(path)
            parts.append(f"<figure><img src='{src}' alt='{html.escape(caption)}'>")
            parts.append(f"<figcaption>{html.escape(caption)}</figcaption></figure>")
    parts.append("</body></html>")
    return "\n".join(parts)


def write_report(out_dir: Path, title: str, sections: Sequence[Section]) -> Path:
    """Write ``report.md`` and ``report.html`` into ``out_dir`` atomically; return the Markdown path."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    md_path = out_dir / "report.md"
    atomic_write_text(md_path, render_markdown(title, sections))
    atomic_write_text(out_dir / "report.html", render_html(title, sections, out_dir))
    return md_path
