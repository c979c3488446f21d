"""Paired-seed statistics and the band plot used by `seagul reproduce` and the sample-efficiency benchmark."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import wilcoxon

from seagul_learn.comparison import curves_by_solves, final_metric, paired_comparison, plot_curves_with_band


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
