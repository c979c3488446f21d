"""``benchmarks/bench_rl_near_goal.py``: the hand-over predictor and the committed result it wrote."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from benchmarks.bench_rl_near_goal import TOLERANCES, Catch, main
from seagul_envs import make_task

ROOT = Path(__file__).resolve().parents[1]
RESULT = ROOT / "benchmarks" / "results" / "rl_near_goal_acrobot.json"


class Constant:
    def __init__(self, value: float) -> None:
        self.value = value

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None, deterministic: bool = True):
        return np.array([self.value]), None


def test_the_catch_hands_over_once_within_the_radius_stays_and_resets_with_a_new_episode() -> None:
    task = make_task("acrobot")
    catch = Catch(task, Constant(1.0), Constant(-1.0), radius=0.2)
    far, near = np.append(task.goal + 0.5, 5.0), np.append(task.goal + 0.01, 4.9)
    assert catch.predict(far)[0][0] == 1.0
    assert catch.predict(near)[0][0] == -1.0  # within 0.2: LQR's turn
    assert catch.predict(np.append(task.goal + 0.5, 4.8))[0][0] == -1.0  # latched, though far again
    assert catch.predict(np.append(task.goal + 0.5, 5.0))[0][0] == 1.0  # the time to go rose: a new episode


def test_bad_radii_and_a_missing_model_are_named(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["--radii", "0,-1"])
    assert "--radii" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--model", "no/such/model.zip"])
    assert "--model" in capsys.readouterr().err


def test_the_committed_result_is_consistent() -> None:
    result = json.loads(RESULT.read_text())
    rows = {row["controller"]: row for row in result["rows"]}
    assert result["starts"] == 400 and {"PPO", "LQR"} <= set(rows)
    for row in result["rows"]:
        within = [row["closest_within"][f"{t:g}"] for t in TOLERANCES]
        assert within == sorted(within)  # a wider tolerance holds at least as many episodes
        assert row["success"] <= row["closest_within"]["0.05"]  # a success ends within 0.05, so it came that close
    assert Path(ROOT / result["model"]).is_file()
