"""Learning code on the real trajectory optimizer (skipped when it is not available)."""

from __future__ import annotations

import numpy as np
import pytest

from seagul_envs import make_task
from seagul_learn.samplers import AdversarialOptions, AdversarialSampler, StartPool, _Chain
from seagul_learn.solving import SolveRunner
from seagul_learn.training import RuntimeConfig, ScheduleConfig, TrainConfig, train
from seagul_learn.value_network import ValueNetwork

trajopt = pytest.importorskip("seagul_learn.trajopt")


def _batch_solver(task_name: str):
    optimizer = trajopt.TrajectoryOptimizer(make_task(task_name))

    def solve(starts: np.ndarray, taus: np.ndarray) -> list:
        return [optimizer.solve(x, t) for x, t in zip(starts, taus, strict=True)]

    return solve


def test_adversarial_step_increases_the_true_loss_on_the_acrobot():
    """The dual gradient (docs/reference/spec.md §6.2 sign convention) and autograd make Alg. 1 climb the real loss."""
    task = make_task("acrobot")
    solve = _batch_solver("acrobot")
    rng = np.random.default_rng(0)
    net = ValueNetwork(4, task_name="acrobot", seed=0)
    net.set_normalization(task.sample_x0(rng, 20), np.full(20, 5.0), rng.normal(15, 5, 20))
    starts = task.x0_low + (task.x0_high - task.x0_low) * rng.uniform(0.25, 0.75, size=(4, 4))
    sampler = AdversarialSampler(
        task, StartPool(starts, np.full(4, 5.0), np.arange(4)), AdversarialOptions(step_fraction=0.005)
    )
    runner = SolveRunner(solve)
    increased = 0
    for x in starts:
        rec = runner.solve(x[None], [5.0], "adversarial")[0]
        assert rec.success, rec.status
        loss, g_u = sampler.loss_gradient(rec, net)
        x_new, _, _ = sampler._from_u(sampler.ascent_step(_Chain(0, sampler._to_u(x, 5.0)), g_u), x, 5.0)
        new = runner.solve(x_new[None], [5.0], "adversarial")[0]
        increased += 0.5 * (new.value - float(net.predict(x_new, 5.0)[0])) ** 2 > loss
    assert increased >= 3  # first-order ascent; a start near a switch between local optima may not follow


@pytest.mark.parametrize("sampler", ["uniform", "adversarial"])
def test_train_runs_on_the_real_solver(tmp_path, sampler):
    config = TrainConfig(
        task="acrobot",
        sampler=AdversarialOptions(max_steps=2) if sampler == "adversarial" else sampler,
        budget=4,
        schedule=ScheduleConfig(solves_per_round=2, train_steps_per_round=5, pretrain_solves=2, pretrain_steps=5),
        validate=False,
        runtime=RuntimeConfig(progress=False, cache_dir=str(tmp_path / "cache")),
    )
    result = train(config, tmp_path / "run", batch_solver=_batch_solver("acrobot"), solver_name="trajopt-test")
    records = result.dataset.records()
    assert len(records) == 6 and result.num_solves == 4
    assert all(r.states.shape == (51, 4) and r.cost_to_go[0] == pytest.approx(r.value) for r in records if r.success)
    assert (tmp_path / "run" / "network.pt").is_file()


@pytest.mark.slow
def test_glider_adversarial_training_with_validation(tmp_path):
    config = TrainConfig(
        task="glider",
        budget=10,
        schedule=ScheduleConfig(solves_per_round=5, train_steps_per_round=50, pretrain_solves=3),
        runtime=RuntimeConfig(progress=False, cache_dir=str(tmp_path / "cache")),
    )
    result = train(config, tmp_path / "run", batch_solver=_batch_solver("glider"), solver_name="trajopt-test")
    assert np.isfinite(result.metrics[-1].mse_initial)
    assert all(0.75 <= r.tau <= 0.85 for r in result.dataset.records())
