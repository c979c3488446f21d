"""``benchmarks/bench_dmc_learned.py``'s training configurations: the closed-loop sampler on a suite task collects with
the deployment's lookahead deciding once per transcription interval, and the label-guess recipes are the pendulum's."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from benchmarks import bench_dmc_learned as bench
from seagul_learn.closed_loop import ClosedLoopSampler
from seagul_learn.config import ClosedLoopOptions, UniformOptions
from seagul_learn.samplers import StartPool


def test_the_cartpoles_closed_loop_collector_decides_once_per_interval_over_the_deployments_lookahead() -> None:
    config = bench.train_config("closed-loop", 2000, 0, "cartpole")
    task = config.task
    assert isinstance(config.sampler, ClosedLoopOptions)
    assert config.sampler.uniform_solves == 1000 and config.sampler.visited_fraction == 0.5
    assert config.sampler.horizon == bench.DOMAINS["cartpole"].deployment.horizon == 5
    assert task.control_period == task.step_bounds[0] == 0.05  # one decision per transcription interval
    np.testing.assert_array_equal(task.x0_low, bench.DOMAINS["cartpole"].train_box[0])
    # The sampler accepts the task: a plan's end is a tail of the task's problem. The suite's own control period
    # (0.01 s) is refused, which is why the training task's period is the interval.
    pool = StartPool.uniform(task, 4, np.random.default_rng(0))
    ClosedLoopSampler(task, pool, config.sampler)
    suite = bench.domain_task(bench.DOMAINS["cartpole"], training=True)
    with pytest.raises(ValueError, match="MPC step"):
        ClosedLoopSampler(suite, StartPool.uniform(suite, 4, np.random.default_rng(0)), config.sampler)
    # The uniform recipe keeps the suite's period.
    uniform = bench.train_config("uniform", 1000, 0, "cartpole")
    assert isinstance(uniform.sampler, UniformOptions) and uniform.task.control_period == suite.control_period


def test_label_guesses_are_the_pendulums_only(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="pendulum only"):
        bench.train("uniform", 10, 0, tmp_path / "run", guess="multistart", domain="cartpole")
