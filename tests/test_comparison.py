"""Paired-seed statistics and the figures used by `seagul reproduce` and the benchmarks: the one paired test
(``seagul_learn.experiment.statistics.paired_wilcoxon``) against ``scipy.stats.wilcoxon``, the older entry points
that keep their keys, the band plot and the success-vs-solves figure."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import wilcoxon

from seagul_learn.comparison import curves_by_solves, final_metric, paired_comparison, plot_curves_with_band
from seagul_learn.experiment.figures import plot_success_vs_solves, success_curve
from seagul_learn.experiment.statistics import (
    PAIRED_KEYS,
    paired_success_comparison,
    paired_test,
    paired_wilcoxon,
)


def test_paired_wilcoxon_is_scipys_test_on_a_worked_example() -> None:
    """Differences 1.5, -0.5, 2, 3, -1, 4, 2.5, 0.2: the ranks of the negative ones are 2 and 3, so T = 5; of the
    2^8 sign patterns 10 have a rank sum <= 5, so the exact two-sided p is 2 * 10 / 256."""
    b = [10.0, 10.0, 10.0, 10.0, 10.0, 10.0, 10.0, 10.0]
    diff = [1.5, -0.5, 2.0, 3.0, -1.0, 4.0, 2.5, 0.2]
    a = [x + y for x, y in zip(b, diff, strict=True)]
    result = paired_wilcoxon(a, b)
    reference = wilcoxon(np.subtract(a, b))
    assert result["statistic"] == pytest.approx(float(reference.statistic)) == pytest.approx(5.0)
    assert result["p_value"] == pytest.approx(float(reference.pvalue)) == pytest.approx(20 / 256)
    assert (result["wins"], result["losses"], result["ties"], result["seeds"]) == (6, 2, 0, 8)
    assert result["median_difference"] == pytest.approx(np.median(diff))
    assert set(result) == set(PAIRED_KEYS)


def test_paired_wilcoxon_drops_ties_and_says_nothing_about_equal_pairs() -> None:
    a, b = [0.5, 0.75, 0.5, 1.0, 0.25], [0.5, 0.5, 0.25, 0.5, 0.5]  # one tie, three wins, one loss
    result = paired_wilcoxon(a, b)
    assert (result["wins"], result["losses"], result["ties"]) == (3, 1, 1)
    assert result["p_value"] == pytest.approx(float(wilcoxon(np.subtract(a, b)).pvalue))  # zeros dropped ("wilcox")
    same = paired_wilcoxon([0.5, 0.5, 1.0], [0.5, 0.5, 1.0])
    assert math.isnan(same["p_value"]) and math.isnan(same["statistic"])  # nothing to rank
    assert (same["wins"], same["losses"], same["ties"], same["median_difference"]) == (0, 0, 3, 0.0)
    assert math.isnan(paired_wilcoxon([1.0], [0.0])["p_value"])  # one seed: no test
    assert math.isnan(paired_wilcoxon([1.0, 2.0], [0.0, 1.0])["median_ratio"])  # a zero reference: no ratio
    with pytest.raises(ValueError, match="equally long"):
        paired_wilcoxon([1.0, 2.0], [1.0])
    with pytest.raises(ValueError, match="finite and positive"):
        paired_wilcoxon([1.0, 0.0], [1.0, 2.0], log=True)


def test_errors_are_tested_on_log_values_and_lower_wins() -> None:
    a, b = [1.0, 2.0, 0.5, 4.0, 3.0], [2.0, 2.5, 1.0, 3.0, 6.0]
    result = paired_wilcoxon(a, b, log=True, lower_is_better=True)
    assert result["p_value"] == pytest.approx(float(wilcoxon(np.log(a) - np.log(b)).pvalue))
    assert (result["wins"], result["losses"]) == (4, 1)
    assert result["median_ratio"] == pytest.approx(np.median(np.divide(a, b)))


def test_the_older_entry_points_are_the_one_test_with_their_keys() -> None:
    """``learning.json``, ``closed_loop/summary.json`` and ``closed_loop.json`` keep their keys; the numbers are
    :func:`paired_wilcoxon`'s."""
    a, b = [0.9, 0.8, 1.0, 0.7], [0.6, 0.8, 0.9, 0.75]
    one = paired_wilcoxon(a, b)
    success = paired_success_comparison(a, b)
    assert list(success) == ["median_difference", "wins", "losses", "ties", "p_value", "seeds"]
    assert success == {k: one[k] for k in success}
    bench = paired_test(a, b)
    assert list(bench) == ["median_difference", "wins", "losses", "p"]
    assert bench["p"] == one["p_value"] and bench["wins"] == one["wins"] == 2 and bench["losses"] == 1
    errors = paired_comparison(a, b)
    log = paired_wilcoxon(a, b, log=True, lower_is_better=True)
    assert (errors.ratio_median, errors.p_value, errors.seeds) == (log["median_ratio"], log["p_value"], 4)
    assert errors.win_fraction == pytest.approx(log["wins"] / 4)


def test_one_success_vs_solves_figure_draws_both_pipelines_statistics(tmp_path: Path) -> None:
    """Per-method statistics of ``seagul reproduce`` (a ``curve``) and a method of the benchmark's summary
    (per-budget rows, with solve times: a second panel) give the same curve."""
    experiment = {
        "policy": "uniform MPC",
        "curve": {"budgets": [2, 4], "median": [0.25, 0.5], "q25": [0.0, 0.25], "q75": [0.5, 0.75],
                  "per_seed": [[0.0, 0.25], [0.5, 0.75]]},
    }  # fmt: skip
    rows = {
        str(b): {"success_median": m, "success_q25": lo, "success_q75": hi, "success_per_seed": [lo, hi],
                 "solve_time_s_median": 10.0 * b}
        for b, m, lo, hi in ((2, 0.25, 0.0, 0.5), (4, 0.5, 0.25, 0.75))
    }  # fmt: skip
    bench = {"budgets": rows}
    ours, theirs = success_curve(experiment), success_curve(bench)
    for key in ("budgets", "median", "q25", "q75", "seeds"):
        assert ours[key] == theirs[key], key
    assert ours["solve_time_s"] is None and theirs["solve_time_s"] == [20.0, 40.0]
    assert ours["label"] == "uniform MPC"
    path = tmp_path / "success_vs_solves.png"
    plot_success_vs_solves({"uniform": experiment}, path, {"LQR": 0.5, "none": math.nan}, "t")
    two = tmp_path / "two_panels.png"
    plot_success_vs_solves({"shipped": bench, "uniform": experiment}, two, {"full": 1.0}, "t", emphasize=("shipped",))
    from PIL import Image

    with Image.open(path) as one_panel, Image.open(two) as both:
        assert both.size[0] > one_panel.size[0]  # the solve-time panel


def test_paired_comparison_matches_its_definition() -> None:
    variant = [1.0, 2.0, 0.5, 4.0, 3.0]
    baseline = [2.0, 2.5, 1.0, 3.0, 6.0]
    c = paired_comparison(variant, baseline)
    assert c.ratio_median == pytest.approx(np.median(np.divide(variant, baseline)))
    assert c.win_fraction == pytest.approx(4 / 5)
    assert c.p_value == pytest.approx(wilcoxon(np.log(variant) - np.log(baseline)).pvalue)
    assert c.seeds == 5


def test_paired_comparison_edge_cases() -> None:
    assert math.isnan(paired_comparison([1.0], [2.0]).p_value)  # one seed: no test
    assert math.isnan(paired_comparison([1.0, 2.0], [1.0, 2.0]).p_value)  # all ties
    with pytest.raises(ValueError, match="equally long"):
        paired_comparison([1.0, 2.0], [1.0])
    with pytest.raises(ValueError, match="finite and positive"):
        paired_comparison([1.0, float("nan")], [1.0, 2.0])


def _run(values: list[float]) -> dict:
    return {"metrics": [{"solves": 10 * i, "mse_initial": v, "mse_all_knots": v / 2} for i, v in enumerate(values)]}


def test_curves_and_plot(tmp_path: Path) -> None:
    runs = {"uniform": [_run([4, 3, 2]), _run([5, 4, 3])], "adversarial": [_run([4, 2, 1]), _run([5, 3, 1])]}
    xs, values = curves_by_solves(runs["uniform"], "mse_initial")
    assert xs.tolist() == [0, 10, 20] and values.tolist() == [[4, 3, 2], [5, 4, 3]]
    assert final_metric(runs["adversarial"], "mse_all_knots") == [0.5, 0.5]
    path = tmp_path / "curves.png"
    plot_curves_with_band(runs, path)
    assert path.stat().st_size > 5000
