"""Samplers: the adversarial step ascends the true loss, budgets are exact, chains stop on failure, options work."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from toy_problem import ToySolver

from seagul_envs import make_task
from seagul_learn.dataset import Dataset, DatasetError
from seagul_learn.samplers import AdversarialOptions, AdversarialSampler, StartPool, UniformSampler
from seagul_learn.solving import SolveRunner
from seagul_learn.value_network import ValueNetwork


def _network(task, seed: int = 0) -> ValueNetwork:
    net = ValueNetwork(task.nx, task_name=task.name, seed=seed)
    rng = np.random.default_rng(seed)
    x = task.sample_x0(rng, 50)
    net.set_normalization(x, np.full(50, task.tau_nominal), rng.normal(5, 2, 50))
    return net


def _true_loss(toy: ToySolver, net: ValueNetwork, x: np.ndarray, tau: float) -> float:
    return 0.5 * (toy.value(x, tau) - float(net.predict(x, tau)[0])) ** 2


@pytest.mark.parametrize("task_name", ["acrobot", "glider"])
@pytest.mark.parametrize("optimizer", ["pga", "adam"])
def test_adversarial_step_increases_the_loss(task_name, optimizer):
    task = make_task(task_name)
    toy = ToySolver(task)
    net = _network(task)
    rng = np.random.default_rng(3)
    # interior starts, so the projection does not interfere with the first-order increase
    starts = task.x0_low + (task.x0_high - task.x0_low) * rng.uniform(0.2, 0.8, size=(20, task.nx))
    pool = StartPool(starts, np.full(20, task.tau_nominal), np.arange(20))
    sampler = AdversarialSampler(task, pool, AdversarialOptions(step_fraction=0.02, optimizer=optimizer))
    runner = SolveRunner(toy)
    increased = 0
    for i in range(20):
        rec = runner.solve(starts[i : i + 1], [task.tau_nominal], "adversarial")[0]
        loss, g_u = sampler.loss_gradient(rec, net)
        assert loss == pytest.approx(_true_loss(toy, net, starts[i], task.tau_nominal), rel=1e-12)
        from seagul_learn.samplers import _Chain

        chain = _Chain(i, sampler._to_u(starts[i], task.tau_nominal))
        x_new, tau_new, _ = sampler._from_u(sampler.ascent_step(chain, g_u), starts[i], task.tau_nominal)
        assert task.in_x0(x_new) and task.tau_range[0] <= tau_new <= task.tau_range[1]
        increased += _true_loss(toy, net, x_new, tau_new) > loss
    assert increased == 20


def test_a_descent_step_would_decrease_it():
    """Guard against a test that cannot fail: flipping the sign of the step must lower the loss."""
    task = make_task("acrobot")
    toy, net = ToySolver(task), _network(task)
    x = task.x0_low + 0.5 * (task.x0_high - task.x0_low) + 0.01
    sampler = AdversarialSampler(task, StartPool(x[None], np.array([5.0]), np.arange(1)), AdversarialOptions())
    rec = SolveRunner(toy).solve(x[None], [5.0], "adversarial")[0]
    loss, g_u = sampler.loss_gradient(rec, net)
    x_down, _, _ = sampler._from_u(sampler._to_u(x, 5.0) - 0.01 * g_u / np.abs(g_u).max(), x, 5.0)
    assert _true_loss(toy, net, x_down, 5.0) < loss


def test_pga_step_size_rule():
    task = make_task("glider")
    sampler = AdversarialSampler(task, StartPool(np.zeros((1, 7)), np.ones(1), np.arange(1)), AdversarialOptions())
    from seagul_learn.samplers import _Chain

    chain = _Chain(0, np.full(8, 0.5) * sampler._free)
    g_u = np.array([2.0, -1.0, 5.0, 5.0, 0.5, 5.0, 5.0, -4.0]) * sampler._free
    du = sampler.ascent_step(chain, g_u) - chain.u
    # x, z, dx and tau move; th, phi, dz, dth have zero-width X0 and stay put
    np.testing.assert_allclose(du, 0.1 * g_u / 4.0)
    assert du[7] == pytest.approx(-0.1)  # the largest normalised component moves step_fraction of its width


@pytest.mark.parametrize("projection", ["clip", "reflect"])
def test_projection(projection):
    task = make_task("acrobot")
    sampler = AdversarialSampler(
        task, StartPool(np.zeros((1, 4)), np.ones(1), np.arange(1)), AdversarialOptions(projection=projection)
    )
    u = sampler._project(np.array([1.2, -0.05, 0.5, 1.0]))
    expected = [1.0, 0.0, 0.5, 1.0] if projection == "clip" else [0.8, 0.05, 0.5, 1.0]
    np.testing.assert_allclose(u, expected)


@pytest.mark.parametrize("options", [AdversarialOptions(), AdversarialOptions(max_steps=3, uniform_fraction=0.3)])
@pytest.mark.parametrize("budget", [1, 7, 10, 23])
def test_budget_is_exact_and_failures_are_counted(options, budget):
    task = make_task("acrobot")
    toy = ToySolver(task, fail_above=np.pi + 0.15)
    pool = StartPool.uniform(task, 100, np.random.default_rng(0)).shuffled(np.random.default_rng(1))
    records = AdversarialSampler(task, pool, options).sample(budget, _network(task), SolveRunner(toy))
    assert len(records) == budget == toy.num_solves
    assert [r.index for r in records] == list(range(budget))
    assert sum(not r.success for r in records) == sum(x[0] > np.pi + 0.15 for x, _ in toy.calls)
    # chains: steps count up from 0 and a failed iterate is always the last of its chain
    by_chain: dict[int, list] = {}
    for r in records:
        by_chain.setdefault(r.chain, []).append(r)
    for chain_id, recs in by_chain.items():
        if chain_id < 0:
            assert all(r.sampler == "uniform-mix" for r in recs)
            continue
        assert [r.step for r in recs] == list(range(len(recs))) and len(recs) <= options.max_steps
        assert all(r.success for r in recs[:-1])
        assert all(task.in_x0(r.x_init) for r in recs)


def test_uniform_sampler_uses_pool_in_order_with_nominal_tau():
    task = make_task("glider")
    toy = ToySolver(task)
    pool = StartPool.uniform(task, 12, np.random.default_rng(0))
    sampler = UniformSampler(task, pool)
    runner = SolveRunner(toy)
    recs = sampler.sample(5, _network(task), runner) + sampler.sample(7, _network(task), runner)
    np.testing.assert_array_equal(np.array([r.x_init for r in recs]), pool.starts)
    assert all(r.tau == task.tau_nominal for r in recs) and pool.position == 12
    with pytest.raises(RuntimeError, match="start pool exhausted"):
        sampler.sample(1, _network(task), runner)


def test_glider_chains_move_tau_inside_T0():
    task = make_task("glider")
    toy = ToySolver(task)
    pool = StartPool.uniform(task, 10, np.random.default_rng(0))
    recs = AdversarialSampler(task, pool, AdversarialOptions(step_fraction=0.3)).sample(
        10, _network(task), SolveRunner(toy)
    )
    taus = np.array([r.tau for r in recs])
    assert np.any(taus != task.tau_nominal)
    assert np.all((taus >= 0.75 - 1e-12) & (taus <= 0.85 + 1e-12))
    # fixed coordinates of X0 (th, phi, dz, dth) never move
    assert np.all(np.array([r.x_init[[2, 3, 5, 6]] for r in recs]) == 0.0)


def test_chain_stops_when_the_step_vanishes():
    task = make_task("acrobot")
    toy = ToySolver(task)
    pool = StartPool.uniform(task, 10, np.random.default_rng(0))
    sampler = AdversarialSampler(task, pool, AdversarialOptions(step_fraction=1e-6, eps=1e-3))
    recs = sampler.sample(4, _network(task), SolveRunner(toy))
    assert [r.step for r in recs] == [0, 0, 0, 0] and len({r.chain for r in recs}) == 4


def test_runner_reuses_records_and_rejects_foreign_ones(tmp_path):
    task = make_task("acrobot")
    ds = Dataset.open(tmp_path / "d", "acrobot")
    starts = task.sample_x0(np.random.default_rng(0), 3)
    first = SolveRunner(ToySolver(task), ds).solve(starts, np.full(3, 5.0), "uniform")
    again_toy = ToySolver(task)
    again = SolveRunner(again_toy, ds).solve(starts, np.full(3, 5.0), "uniform")
    assert again_toy.num_solves == 0 and [r.value for r in again] == [r.value for r in first]
    with pytest.raises(DatasetError, match="answers another request"):
        SolveRunner(ToySolver(task), ds).solve(starts + 0.01, np.full(3, 5.0), "uniform")


def test_cached_batch_solver_reuses_bit_identical_requests(tmp_path):
    from seagul_learn.solving import CachedBatchSolver

    task = make_task("glider")
    toy = ToySolver(task, fail_above=-3.5)
    cached = CachedBatchSolver(toy, tmp_path / "c", "toy")
    starts = task.sample_x0(np.random.default_rng(0), 6)
    taus = np.full(6, 0.8)
    first = cached(starts, taus)
    again = cached(starts[::-1], taus)
    assert toy.num_solves == 6 and cached.hits == 6
    for a, b in zip(first, again[::-1], strict=True):
        assert a.success == b.success and a.status == b.status
        np.testing.assert_array_equal(a.knot_grads, b.knot_grads)
        np.testing.assert_array_equal(a.cost_to_go, b.cost_to_go)
    cached(starts + 1e-12, taus)  # a different request is solved
    assert toy.num_solves == 12
    other = CachedBatchSolver(toy, tmp_path / "c", "toy-v2")  # another solver never shares entries
    other(starts, taus)
    assert toy.num_solves == 18


def test_stop_on_decrease_ends_chains_that_overshoot():
    task = make_task("acrobot")
    toy = ToySolver(task)
    net = _network(task)
    pool = StartPool.uniform(task, 40, np.random.default_rng(0))
    opts = AdversarialOptions(step_fraction=0.6, stop_on_decrease=True, max_steps=5)
    recs = AdversarialSampler(task, pool, opts).sample(30, net, SolveRunner(toy))
    by_chain: dict[int, list] = {}
    for r in recs:
        by_chain.setdefault(r.chain, []).append(r)

    def loss(r):
        return 0.5 * (r.value - float(net.predict(r.x_init, r.tau)[0])) ** 2

    overshoots = 0
    for chain in by_chain.values():
        losses = [loss(r) for r in chain]
        # every iterate but the last had a loss at least its predecessor's (else the chain would have ended)
        assert all(b >= a for a, b in itertools.pairwise(losses[:-1]))
        overshoots += len(losses) >= 2 and losses[-1] < losses[-2]
    assert overshoots > 0  # big steps overshoot, and those chains end there
