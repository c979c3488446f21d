"""Reporting: the closed-loop evaluation tables and figures, and the Markdown / self-contained HTML report."""

import json
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pytest

from seagul_control.evaluation import EpisodeResult
from seagul_learn.report import (
    Section,
    Table,
    library_versions,
    plot_glider_trajectories,
    plot_heatmaps,
    summarize,
    write_outputs,
    write_report,
)

# The summary table of `_episodes()`.
EXPECTED_CSV = """\
policy,episodes,success_rate,mean_final_distance,median_final_distance,mean_cost,median_cost,crashes,\
median_step_ms,p95_step_ms,max_step_ms,mean_iterations,fallback_steps,steps
mpc,2,0.5,0.76,0.76,26.25,26.25,0,2.5,8.949999999999998,10.0,6.0,1,100
lqr,2,0.5,1.27,1.27,45.0,45.0,1,nan,nan,nan,nan,0,70
"""
GRID = {"dims": ["th1", "th2"], "axes": [[0.0], [0.0, 1.0]], "shape": [1, 2]}


def _episodes() -> list[EpisodeResult]:
    """Two acrobot policies, two starts each: an MPC with solver statistics and an LQR (one crash)."""
    return [
        EpisodeResult(
            "mpc", 0, [0.1, 0.2, 0, 0], [3.14, 0.01, 0, 0], 0.02, 12.5, True, False, 50, [0.001, 0.003], [4, 6]
        ),
        EpisodeResult(
            "mpc", 1, [0.3, 0.4, 0, 0], [2.0, 1.0, 0, 0], 1.5, 40.0, False, False, 50, [0.002, 0.01], [5, 9], 1
        ),
        EpisodeResult("lqr", 0, [0.1, 0.2, 0, 0], [3.1, 0.0, 0, 0], 0.04, 10.0, True, False, 50),
        EpisodeResult("lqr", 1, [0.3, 0.4, 0, 0], [1.0, 1.0, 0, 0], 2.5, 80.0, False, True, 20),
    ]


def test_summarize_gives_one_row_per_policy():
    rows = summarize("acrobot", _episodes())
    assert [r["policy"] for r in rows] == ["mpc", "lqr"]
    mpc, lqr = rows
    assert mpc == {
        "policy": "mpc",
        "episodes": 2,
        "success_rate": 0.5,
        "mean_final_distance": pytest.approx(0.76),
        "median_final_distance": pytest.approx(0.76),
        "mean_cost": 26.25,
        "median_cost": 26.25,
        "crashes": 0,
        "median_step_ms": pytest.approx(2.5),
        "p95_step_ms": pytest.approx(8.95),
        "max_step_ms": pytest.approx(10.0),
        "mean_iterations": 6.0,
        "fallback_steps": 1,
        "steps": 100,
    }
    assert lqr["crashes"] == 1 and lqr["steps"] == 70 and lqr["fallback_steps"] == 0
    assert all(math.isnan(lqr[k]) for k in ("median_step_ms", "p95_step_ms", "max_step_ms", "mean_iterations"))
    glider = summarize("glider", _episodes())
    assert [r["perch_success_rate"] for r in glider] == [0.5, 0.5]
    assert list(glider[0])[:-1] == list(mpc)


def test_write_outputs_writes_the_tables_and_figures(tmp_path: Path):
    episodes = _episodes()
    paths = write_outputs(tmp_path, "acrobot", episodes, GRID, {"note": 1})
    assert set(paths) == {"results", "summary_json", "summary_csv", "heatmap"}
    assert paths["summary_csv"].read_text() == EXPECTED_CSV
    results = json.loads(paths["results"].read_text())
    assert results["task"] == "acrobot" and results["grid"] == GRID and results["note"] == 1
    assert [EpisodeResult(**e) for e in results["episodes"]] == episodes
    summary = json.loads(paths["summary_json"].read_text())
    assert summary["task"] == "acrobot" and summary["note"] == 1
    assert [r["policy"] for r in summary["policies"]] == ["mpc", "lqr"]
    assert summary["policies"][0]["p95_step_ms"] == pytest.approx(8.95)
    assert paths["heatmap"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # No grid: tables only; acrobot episodes never get a trajectory figure.
    assert set(write_outputs(tmp_path / "nogrid", "acrobot", episodes)) == {"results", "summary_json", "summary_csv"}


def test_glider_figures(tmp_path: Path):
    states = np.linspace([-3.0, 1.0, 0, 0, 7.0, 0, 0], [0.01, 0.02, 0, 0, 1.0, 0, 0], 5).tolist()
    episodes = [
        EpisodeResult("tvlqr", 0, states[0], states[-1], 0.1, 300.0, True, False, 4, states=states),
        EpisodeResult("mpc", 0, states[0], states[-1], 0.2, 350.0, False, False, 4, [0.01] * 4, [3] * 4, states=states),
    ]
    grid = {"dims": ["x", "z"], "axes": [[-3.0], [1.0]], "shape": [1, 1]}
    paths = write_outputs(tmp_path, "glider", episodes, grid)
    assert paths["trajectories"] == tmp_path / "trajectories.png" and paths["trajectories"].stat().st_size > 0
    assert plot_heatmaps("glider", episodes, grid, tmp_path / "h.png") == tmp_path / "h.png"
    assert plot_glider_trajectories(episodes, tmp_path / "t.png", max_per_policy=1).stat().st_size > 0


def test_write_report_embeds_figures_and_tables(tmp_path: Path):
    fig, ax = plt.subplots()
    ax.plot([0, 1], [1, 0])
    fig.savefig(tmp_path / "curve.png")
    plt.close(fig)
    sections = [
        Section(
            "Results",
            ["Adversarial beats **uniform** on `mse_initial`.", "**Success (||x - x*|| < 0.05) from 99%** of starts."],
            [Table(["a", "b"], [[1, 0.123456]])],
        ),
        Section("Figures", figures=[("curve.png", "A curve"), ("missing.png", "Not there")]),
    ]
    md = write_report(tmp_path, "Test report", sections)
    text = md.read_text()
    assert md.name == "report.md"
    assert "| a | b |" in text and "| 1 | 0.1235 |" in text
    assert "![A curve](curve.png)" in text
    page = (tmp_path / "report.html").read_text()
    assert "data:image/png;base64," in page  # the existing figure is embedded
    assert "src='missing.png'" in page  # a missing one stays a link instead of failing
    assert "<b>uniform</b>" in page and "<code>mse_initial</code>" in page
    assert "<b>Success (||x - x*|| &lt; 0.05) from 99%</b>" in page  # bold around the goal's lone *
    assert not list(tmp_path.glob("*.tmp"))


def test_report_parts_and_subsections_and_an_embedded_gif(tmp_path: Path):
    """A section's ``level`` sets its heading (part or subsection); a GIF figure is linked in Markdown and embedded
    as ``image/gif`` in HTML, a PNG as ``image/png``."""
    from PIL import Image

    frames = [Image.new("RGB", (8, 8), c) for c in ("red", "blue")]
    frames[0].save(tmp_path / "anim.gif", save_all=True, append_images=frames[1:], duration=100, loop=0)
    frames[0].save(tmp_path / "still.png")
    sections = [
        Section("Product", ["first"], figures=[("anim.gif", "An animation")]),
        Section("Comparison"),
        Section("Detail", ["inside"], figures=[("still.png", "A still")], level=3),
    ]
    text = write_report(tmp_path, "Levels", sections).read_text()
    assert [line for line in text.splitlines() if line.startswith("#")] == [
        "# Levels",
        "## Product",
        "## Comparison",
        "### Detail",
    ]
    assert "![An animation](anim.gif)" in text
    page = (tmp_path / "report.html").read_text()
    assert "<h2>Product</h2>" in page and "<h3>Detail</h3>" in page
    assert page.index("data:image/gif;base64,") < page.index("<h2>Comparison</h2>") < page.index("data:image/png")


def test_library_versions_names_core_libraries():
    versions = library_versions()
    for name in ("python", "casadi", "torch", "gymnasium", "numpy"):
        assert versions[name] and versions[name] != "not installed"


def test_controller_animation_is_one_panel_per_controller_from_the_same_start(tmp_path) -> None:
    """The GIF has a frame per step (plus the start) and one panel per controller; each panel is its own episode."""
    from PIL import Image

    from seagul_control.lqr import LQRPolicy
    from seagul_envs import make_task
    from seagul_learn.baselines import ZeroPolicy
    from seagul_learn.report import controller_animation

    task = make_task("acrobot")
    x0 = task.goal + np.array([0.05, -0.05, 0.0, 0.0])
    path, episodes = controller_animation(
        task, [("LQR", LQRPolicy(task)), ("zero", ZeroPolicy(task.nu))], x0, tmp_path / "a.gif", max_width=200
    )
    with Image.open(path) as im:
        assert im.format == "GIF" and im.n_frames == episodes[0].steps + 1
        assert im.size[0] == 400
    assert [e.policy for e in episodes] == ["LQR", "zero"]
    assert episodes[0].success and not episodes[1].success  # LQR balances from near the top; doing nothing falls
    with pytest.raises(ValueError, match="at least one"):
        controller_animation(task, [], x0, tmp_path / "b.gif")
