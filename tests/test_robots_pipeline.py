"""Robots through the learning pipeline: batch solvers, the runner, caches, datasets, training
arrays, the Sobolev term in theta, and the uniform and adversarial samplers over ``X0 x Theta``."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from toy_problem import ToyRobotSolver, ToySolver

from seagul_control import LimitedLookaheadMPC
from seagul_control.mpc import MPCOptions
from seagul_envs import make_task
from seagul_learn.closed_loop import collect_queries
from seagul_learn.dataset import Dataset, DatasetError, SolveRecord, training_arrays
from seagul_learn.parallel import solve_many
from seagul_learn.samplers import AdversarialOptions, AdversarialSampler, StartPool, UniformSampler
from seagul_learn.solving import CachedBatchSolver, SolveRunner, trajopt_batch_solver
from seagul_learn.training import TrainConfig, train, training_loss, validation_robots
from seagul_learn.trajopt import TrajectoryOptimizer
from seagul_learn.value_network import ValueEnsemble, ValueNetwork

TASK = make_task("acrobot")


def _pool(n: int, seed: int = 0, robots: bool = True) -> StartPool:
    return StartPool.uniform(TASK, n, np.random.default_rng(seed), model_params=robots)


def test_a_pool_over_robots_keeps_the_starts_of_the_nominal_pool_and_draws_robots_inside_theta():
    plain, robots = _pool(50, robots=False), _pool(50)
    np.testing.assert_array_equal(plain.starts, robots.starts)
    assert plain.thetas is None and robots.thetas is not None
    space = TASK.parameters
    assert robots.thetas.shape == (50, space.size)
    assert np.all(robots.thetas >= space.low) and np.all(robots.thetas <= space.high)
    assert np.ptp(robots.thetas, axis=0).min() > 0.5 * (space.high - space.low).min()  # spread over the box
    shuffled = robots.shuffled(np.random.default_rng(1))
    _, _, ids = shuffled.take(5)
    np.testing.assert_array_equal(shuffled.thetas_of(ids), robots.thetas[ids])


def test_the_runner_stores_each_robot_and_refuses_a_record_of_another_robot(tmp_path):
    toy = ToyRobotSolver(TASK)
    pool = _pool(6)
    ds = Dataset.open(tmp_path / "ds", "acrobot")
    records = SolveRunner(toy, ds).solve(pool.starts, pool.taus, "uniform", thetas=pool.thetas)
    for rec, theta in zip(records, pool.thetas, strict=True):
        np.testing.assert_array_equal(rec.theta, theta)
        assert rec.grad_theta.shape == (TASK.parameters.size,) and rec.knot_grad_theta.shape == (11, 6)
    stored = ds.read(3)
    np.testing.assert_array_equal(stored.knot_grad_theta, records[3].knot_grad_theta)
    # a resumed run reuses the records of the same robots without solving ...
    again = SolveRunner(ToyRobotSolver(TASK), ds)
    again.solve(pool.starts, pool.taus, "uniform", thetas=pool.thetas)
    assert again.num_reused == 6 and again.num_solved == 0
    # ... and names the robot when the plan differs from what is stored
    other = pool.thetas.copy()
    other[2, 0] *= 1.01
    with pytest.raises(DatasetError, match=r"record 2 .*theta="):
        SolveRunner(ToyRobotSolver(TASK), ds).solve(pool.starts, pool.taus, "uniform", thetas=other)
    with pytest.raises(ValueError, match="one robot"):
        SolveRunner(toy).solve(pool.starts, pool.taus, "uniform", thetas=pool.thetas[:3])


def test_records_without_robots_read_as_zero_parameters_and_never_match_a_robot_request(tmp_path):
    toy = ToySolver(TASK)
    rec = SolveRecord.from_result(toy.solve(TASK.goal, TASK.tau_nominal), 0, "uniform")
    legacy = {k: v for k, v in rec.to_arrays().items() if k not in ("theta", "grad_theta", "knot_grad_theta")}
    back = SolveRecord.from_arrays(legacy)  # a file written before robots existed
    assert back.n_params == 0 and back.same_request(TASK.goal, TASK.tau_nominal)
    assert not back.same_request(TASK.goal, TASK.tau_nominal, TASK.theta)


def test_training_arrays_give_every_knot_its_robot_and_its_per_knot_label_and_refuse_a_mix():
    toy = ToyRobotSolver(TASK)
    pool = _pool(3)
    results = toy(pool.starts, pool.taus, pool.thetas)
    records = [SolveRecord.from_result(r, i, "uniform") for i, r in enumerate(results)]
    arrays = training_arrays(records)
    assert arrays.n_params == 6 and arrays.theta.shape == (33, 6)
    np.testing.assert_array_equal(arrays.theta[11:22], np.repeat(pool.thetas[1][None], 11, axis=0))
    np.testing.assert_allclose(arrays.grad_theta[11:22], results[1].knot_grad_theta)
    half = arrays.select(arrays.knot == 0)
    np.testing.assert_array_equal(half.theta, pool.thetas)
    assert arrays.concat(half).theta.shape == (36, 6)
    plain = SolveRecord.from_result(ToySolver(TASK).solve(TASK.goal, 5.0), 9, "uniform")
    with pytest.raises(ValueError, match="different numbers of physical parameters"):
        training_arrays([*records, plain])
    with pytest.raises(ValueError, match="cannot join"):
        arrays.concat(training_arrays([plain]))


def test_the_cache_keys_solves_by_robot(tmp_path):
    toy = ToyRobotSolver(TASK)
    cached = CachedBatchSolver(toy, tmp_path / "cache", "toy", task=TASK)
    pool = _pool(2)
    first = cached(pool.starts, pool.taus, pool.thetas)
    again = cached(pool.starts, pool.taus, pool.thetas)
    assert (cached.hits, cached.misses) == (2, 2) and toy.num_solves == 2
    np.testing.assert_array_equal(again[1].knot_grad_theta, first[1].knot_grad_theta)
    np.testing.assert_array_equal(again[0].theta, pool.thetas[0])
    cached(pool.starts, pool.taus, pool.thetas[::-1].copy())  # the same starts on each other's robots
    assert cached.misses == 4


def test_the_sobolev_term_in_theta_vanishes_at_the_networks_own_gradients_and_grows_away_from_them():
    net = ValueNetwork(TASK.nx, (16,), seed=0, n_params=6, theta=TASK.theta)
    pool = _pool(40)
    x, tau = torch.tensor(pool.starts), torch.tensor(pool.taus)
    th = torch.tensor(pool.thetas)
    net.set_normalization(pool.starts, pool.taus, np.linspace(1, 50, 40), pool.thetas)
    v, gx, _, gth = net.value_and_grads(pool.starts, pool.taus, pool.thetas)
    batch = {
        "x": x,
        "tau": tau,
        "theta": th,
        "value": torch.tensor(v),
        "grad_x": torch.tensor(gx),
        "grad_theta": torch.tensor(gth),
        "grad_ok": torch.ones(40, dtype=torch.bool),
    }
    assert float(training_loss(net, batch, 1.0).detach()) < 1e-20
    # A label off by 1 in every theta coordinate costs (1 * in_std_theta / out_std)^2, averaged over the nx + k
    # gradient coordinates: the gradient is compared in standardised units, like the x part.
    wrong = dict(batch, grad_theta=batch["grad_theta"] + 1.0)
    scale = net.in_std.numpy()[TASK.nx + 1 :] / float(net.out_std)
    expected = np.sum(scale**2) / (TASK.nx + 6)
    np.testing.assert_allclose(float(training_loss(net, wrong, 2.0).detach()), 2.0 * expected, rtol=1e-9)
    half = dict(wrong, grad_ok=torch.arange(40) < 20)  # masked knots do not enter the gradient term
    np.testing.assert_allclose(float(training_loss(net, half, 2.0).detach()), 2.0 * expected, rtol=1e-9)
    assert float(training_loss(net, wrong, 0.0).detach()) < 1e-20  # plain MSE ignores every gradient label


def test_the_uniform_sampler_solves_each_start_for_its_robot():
    toy = ToyRobotSolver(TASK)
    pool = _pool(8)
    records = UniformSampler(TASK, pool).sample(8, ValueNetwork(TASK.nx, (4,), n_params=6), SolveRunner(toy))
    np.testing.assert_array_equal(np.array([r.theta for r in records]), pool.thetas)


def test_the_adversarial_ascent_moves_theta_uphill_inside_theta():
    toy = ToyRobotSolver(TASK, bump=0.0)
    space = TASK.parameters
    net = ValueNetwork(TASK.nx, (4,), seed=0, n_params=6, theta=TASK.theta)  # an untrained network: V - Vhat large
    sampler = AdversarialSampler(TASK, _pool(20), AdversarialOptions(max_steps=4, step_fraction=0.2))
    records = sampler.sample(12, net, SolveRunner(toy))
    assert len(records) == 12
    thetas = np.array([r.theta for r in records])
    assert np.all(thetas >= space.low - 1e-12) and np.all(thetas <= space.high + 1e-12)
    moved = [r for r in records if r.step > 0]
    assert moved, "no chain took an ascent step"
    start_of = {r.chain: r for r in records if r.step == 0}
    assert any(not np.array_equal(r.theta, start_of[r.chain].theta) for r in moved)
    # each step raises the loss 1/2 (V - Vhat)^2 to first order along the chain
    first, second = start_of[moved[0].chain], next(r for r in moved if r.chain == moved[0].chain and r.step == 1)
    loss = [
        0.5 * (r.value - float(net.predict(r.x_init[None], [r.tau], r.theta[None])[0])) ** 2 for r in (first, second)
    ]
    assert loss[1] > loss[0]
    fixed = AdversarialSampler(TASK, _pool(20), AdversarialOptions(max_steps=4, ascend_theta=False))
    kept = fixed.sample(12, net, SolveRunner(ToyRobotSolver(TASK, bump=0.0)))
    start_fixed = {r.chain: r.theta for r in kept if r.step == 0}
    assert all(np.array_equal(r.theta, start_fixed[r.chain]) for r in kept)


def _robot_config(tmp_path, **overrides) -> TrainConfig:
    """A small run over robots; ``overrides`` name fields, or fields of a part as ``"part.field"`` (a sampler field
    the chosen sampler lacks is ignored, so the adversarial one's ``max_steps`` does not stop a closed-loop run)."""
    base = {
        "task": "acrobot",
        "sampler": "adversarial",
        "budget": 12,
        "schedule.solves_per_round": 6,
        "schedule.train_steps_per_round": 10,
        "schedule.batch_size": 32,
        "schedule.pretrain_solves": 4,
        "schedule.pretrain_steps": 10,
        "sampler.max_steps": 3,
        "loss.sobolev_weight": 1.0,
        "model_params": True,
        "seed": 0,
        "runtime.cache_dir": str(tmp_path / "cache"),
        "runtime.progress": False,
    }
    base.update(overrides)
    return TrainConfig(**base)


@pytest.mark.parametrize("sampler", ["uniform", "adversarial"])
def test_a_run_over_robots_trains_a_network_over_robots_and_resumes_exactly(tmp_path, sampler):
    cfg = _robot_config(tmp_path, sampler=sampler)
    ref = train(cfg, tmp_path / "ref", batch_solver=ToyRobotSolver(TASK), solver_name="toy")
    assert ref.network.n_params == 6
    np.testing.assert_array_equal(ref.network.theta, TASK.theta)  # conditioned on the task's own robot
    assert all(r.n_params == 6 for r in ref.dataset.records())
    loaded = ValueNetwork.load(tmp_path / "ref" / "network.pt")
    assert loaded.n_params == 6 and np.isfinite(ref.metrics[-1].mse_all_knots)
    crashing = ToyRobotSolver(TASK, raise_after=9)
    with pytest.raises(KeyboardInterrupt):
        train(cfg, tmp_path / "run", batch_solver=crashing, solver_name="toy")
    resumed_toy = ToyRobotSolver(TASK)
    resumed = train(cfg, tmp_path / "run", resume=True, batch_solver=resumed_toy, solver_name="toy")
    assert resumed_toy.num_solves == 16 - 9
    for a, b in zip(ref.dataset.records(), resumed.dataset.records(), strict=True):
        np.testing.assert_array_equal(a.theta, b.theta)
        np.testing.assert_array_equal(a.x_init, b.x_init)
    np.testing.assert_array_equal(ref.network.casadi_parameters(), resumed.network.casadi_parameters())


def test_uniform_and_adversarial_runs_over_robots_share_the_seeds_pretraining_and_validation(tmp_path):
    uni = train(_robot_config(tmp_path, sampler="uniform"), tmp_path / "u", batch_solver=ToyRobotSolver(TASK))
    adv = train(_robot_config(tmp_path), tmp_path / "a", batch_solver=ToyRobotSolver(TASK))
    for a, b in zip(uni.dataset.records()[:4], adv.dataset.records()[:4], strict=True):  # the pretraining solves
        np.testing.assert_array_equal(a.theta, b.theta)
    assert uni.metrics[0].mse_initial == adv.metrics[0].mse_initial
    robots = validation_robots(TASK, 5)
    np.testing.assert_array_equal(robots, validation_robots(TASK, 5))
    assert np.all((robots >= TASK.parameters.low) & (robots <= TASK.parameters.high))


def _cl_robot_config(tmp_path, **overrides) -> TrainConfig:
    base = {
        "sampler": "closed-loop",
        "budget": 12,
        "network.hidden": (8,),
        "sampler.episodes": 2,
        "sampler.horizon": 2,
        "sampler.jit": False,
        "sampler.uniform_fraction": 0.34,
        "sampler.uniform_solves": 0,
        "sampler.warmup_rounds": 0,
        "sampler.trust_region": "none",
        "validate": False,
    }
    base.update(overrides)
    return _robot_config(tmp_path, **base)


def test_the_closed_loop_sampler_over_robots_flies_each_episode_on_its_robot_and_solves_tails_for_the_plans_robot(
    tmp_path,
):
    cfg = _cl_robot_config(tmp_path)
    toy = ToyRobotSolver(TASK)
    ref = train(cfg, tmp_path / "ref", batch_solver=toy, solver_name="toy")
    budget = [r for r in ref.dataset.records() if r.sampler != "pretrain"]
    assert len(budget) == 12 == ref.num_solves
    tails = [r for r in budget if r.sampler == "closed-loop"]
    assert tails and len([r for r in budget if r.sampler == "uniform-mix"]) == 2 * round(0.34 * 6)
    space = TASK.parameters
    thetas = np.array([r.theta for r in tails])
    assert np.all((thetas >= space.low - 1e-12) & (thetas <= space.high + 1e-12))
    # the collecting MPC plans for its online estimate: past the first step, the plans' robots leave the model's
    assert np.any(np.abs(thetas - TASK.theta).max(axis=1) > 1e-6)
    assert ref.network.n_params == space.size
    # interrupted after 9 solves, the run resumes to the same records and network
    crashing = ToyRobotSolver(TASK, raise_after=9)
    with pytest.raises(KeyboardInterrupt):
        train(cfg, tmp_path / "run", batch_solver=crashing, solver_name="toy")
    resumed = train(cfg, tmp_path / "run", resume=True, batch_solver=ToyRobotSolver(TASK), solver_name="toy")
    for a, b in zip(ref.dataset.records(), resumed.dataset.records(), strict=True):
        np.testing.assert_array_equal(a.theta, b.theta)
        np.testing.assert_array_equal(a.x_init, b.x_init)
    np.testing.assert_array_equal(ref.network.casadi_parameters(), resumed.network.casadi_parameters())


def test_collect_queries_over_robots_records_the_robot_of_each_plan_and_needs_an_mpc_over_robots():
    starts = TASK.sample_x0(np.random.default_rng(3), 1)
    robots = TASK.parameters.sample(np.random.default_rng(4), 1).reshape(1, -1)
    net = ValueNetwork(TASK.nx, (8,), seed=3, n_params=TASK.parameters.size, theta=TASK.theta, task_name="acrobot")
    mpc = LimitedLookaheadMPC(
        TASK, net, 2, MPCOptions(jit=False), trust_region="none", model_params=True, estimate_robot=True
    )
    q = collect_queries(TASK, mpc, starts, robots=robots)
    assert q.theta is not None and q.theta.shape == (q.x.shape[0], TASK.parameters.size)
    np.testing.assert_allclose(q.theta[0], TASK.theta)  # the first plan: the estimate starts at the model
    assert np.abs(q.theta[-1] - TASK.theta).max() > 1e-6  # later ones: the estimate of the simulated robot
    plain = LimitedLookaheadMPC(
        TASK, ValueNetwork(TASK.nx, (8,), seed=3), 2, MPCOptions(jit=False), trust_region="none"
    )
    with pytest.raises(ValueError, match="needs an MPC that plans over robots"):
        collect_queries(TASK, plain, starts, robots=robots)


def test_model_params_needs_parameters_and_a_sampler_that_takes_robots():
    fixed = dataclasses.replace(TASK, parameters=None)
    with pytest.raises(ValueError, match="model_params needs a task with physical parameters"):
        TrainConfig(task=fixed, sampler="uniform", model_params=True)
    with pytest.raises(ValueError, match="declares no physical parameters"):
        StartPool.uniform(fixed, 3, np.random.default_rng(0), model_params=True)


def test_solve_many_solves_each_start_for_its_robot_like_the_optimizer_and_in_any_number_of_workers():
    pool = _pool(2, seed=4)
    options = {"codegen": False, "multi_start": "never"}
    one = solve_many(TASK, pool.starts, pool.taus, thetas=pool.thetas, progress=False, solver_options=options)
    two = solve_many(
        TASK, pool.starts, pool.taus, thetas=pool.thetas, workers=2, progress=False, solver_options=options
    )
    direct = TrajectoryOptimizer(TASK, model_params=True, **options)
    for a, b, x, theta in zip(one, two, pool.starts, pool.thetas, strict=True):
        ref = direct.solve(x, TASK.tau_nominal, theta=theta)
        assert a.success and ref.success
        np.testing.assert_array_equal(a.theta, theta)
        np.testing.assert_allclose(a.value, ref.value, rtol=1e-9)
        np.testing.assert_allclose(a.grad_theta, ref.grad_theta, rtol=1e-6, atol=1e-9)
        np.testing.assert_array_equal(a.knot_grad_theta, b.knot_grad_theta)  # workers never change results
    # the batch solver passes robots on, also to tail problems (their own horizon, the same parametric build)
    tail_tau = TASK.tau_nominal / 2
    batch = trajopt_batch_solver(TASK, solver_options=options)
    tails = batch(one[0].states[[25]], np.array([tail_tau]), pool.thetas[:1])
    assert tails[0].success and tails[0].knot_grad_theta.shape == (26, 6)
    np.testing.assert_allclose(tails[0].value, one[0].cost_to_go[25], rtol=1e-3, atol=1e-3)
    with pytest.raises(ValueError, match=r"thetas must have shape \(2, 6\)"):
        solve_many(TASK, pool.starts, thetas=pool.thetas[:, :2], progress=False)
    with pytest.raises(ValueError, match="NaN or inf"):
        solve_many(TASK, pool.starts, thetas=np.full((2, 6), np.nan), progress=False)


def test_an_ensemble_over_robots_measures_its_spread_at_the_robots_it_is_given():
    k = TASK.parameters.size
    ens = ValueEnsemble(TASK.nx, (8,), members=3, seed=1, n_params=k, theta=TASK.theta, task_name="acrobot")
    x = TASK.sample_x0(np.random.default_rng(0), 4)
    tau = np.full(4, 2.0)
    robots = TASK.parameters.sample(np.random.default_rng(1), 4).reshape(4, k)
    spread = ens.spread(x, tau, robots)
    by_hand = np.std([m.predict(x, tau, robots) for m in ens.members], axis=0)
    np.testing.assert_allclose(spread, by_hand, rtol=1e-10)
    assert not np.allclose(spread, ens.spread(x, tau, np.tile(TASK.theta, (4, 1))))


def test_param_bench_report_renders_the_committed_result(tmp_path: Path) -> None:
    """``bench_param_adversary --report-from``: the committed five-seed result as a report, one row per controller
    with its per-seed rates and their median; ``--dry-run``: the closed-loop sampler's settings on the benchmark
    config. The script runs as a user runs it, in its own process."""
    root = Path(__file__).resolve().parents[1]
    script = str(root / "benchmarks" / "bench_param_adversary.py")

    def run(*args: str) -> str:
        done = subprocess.run([sys.executable, script, *args], capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stderr
        return done.stdout

    plain = json.loads(run("--dry-run").splitlines()[-1])["acrobot"]
    assert "closed-loop" not in plain["methods"] and set(plain["methods"]) == {"adversarial", "uniform", "nominal"}
    config = json.loads(run("--dry-run", "--closed-loop").splitlines()[-1])["acrobot"]
    settings = config["methods"]["closed-loop"]
    assert settings["sampler.uniform_solves"] == config["budget"] // 3 == 100
    assert settings["loss.value_cap"] == 50.0
    stored = json.loads((root / "benchmarks" / "results" / "param_adversary.json").read_text())
    run("--report-from", str(root / "benchmarks" / "results" / "param_adversary.json"), "--out", str(tmp_path))
    text = (tmp_path / "report.md").read_text()
    block = stored["acrobot"]
    rates = [r["success_rate"] for r in block["per_seed"]["closed-loop"]]
    row = "| closed-loop sampler over robots, estimating MPC | " + " | ".join(f"{100 * r:.1f} %" for r in rates)
    assert row + f" | {100 * sorted(rates)[len(rates) // 2]:.1f} % |" in text
    assert f"| full-horizon MPC that knows the robot |{'  |' * block['seeds']} 100.0 % |" in text
    assert (tmp_path / "acrobot" / "robust.png").stat().st_size > 10_000
    assert "data:image/png;base64," in (tmp_path / "report.html").read_text()
