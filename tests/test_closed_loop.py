"""The closed-loop sampler: queries come from the deployed MPC, tails are solved, budgets exact, resume exact."""

from __future__ import annotations

import json

import numpy as np
import pytest
from toy_problem import ToySolver

from seagul_control.mpc import LimitedLookaheadMPC
from seagul_envs import make_task
from seagul_learn.closed_loop import ClosedLoopOptions, collect_queries, farthest_first, snap_tau
from seagul_learn.solving import tail_horizon
from seagul_learn.training import TrainConfig, train
from seagul_learn.value_network import ValueNetwork


def test_tail_horizon_of_fixed_step_task():
    task = make_task("acrobot")
    assert tail_horizon(task, 5.0) is None  # the full problem
    assert tail_horizon(task, 4.5) == 45
    assert tail_horizon(task, 0.1) == 1
    with pytest.raises(ValueError, match="not a tail"):
        tail_horizon(task, 0.05)
    with pytest.raises(ValueError, match="not a tail"):
        tail_horizon(task, 7.0)
    glider = make_task("glider")  # free steps: k = round(tau / 20 ms) steps in [15, 30] ms with sum(h) = tau
    assert tail_horizon(glider, glider.tau_nominal) is None
    assert tail_horizon(glider, 0.55) == round(0.55 / 0.02)
    with pytest.raises(ValueError, match="not a tail"):
        tail_horizon(glider, 0.001)


def test_snap_tau_rounds_float32_times_to_the_step_grid():
    task = make_task("acrobot")
    assert snap_tau(task, float(np.float32(4.5) - np.float32(0.5))) == pytest.approx(4.0, abs=0)
    assert tail_horizon(task, snap_tau(task, 1.2000001)) == 12


def test_farthest_first_is_greedy_k_center():
    known = np.zeros((1, 2))
    cand = np.array([[0.1, 0.0], [5.0, 0.0], [5.1, 0.0], [0.0, 3.0]])
    picks = farthest_first(cand, known, 3)
    # farthest from the origin first, then the point farthest from {origin, pick 1}, ...
    assert picks.tolist() == [2, 3, 0] or picks.tolist() == [2, 3, 1]
    assert picks[0] == 2 and picks[1] == 3
    assert farthest_first(cand, np.zeros((0, 2)), 2).size == 2
    assert farthest_first(cand, known, 0).size == 0


def test_options_reject_bad_values():
    with pytest.raises(ValueError, match="episodes"):
        ClosedLoopOptions(episodes=0)
    with pytest.raises(ValueError, match="selection"):
        ClosedLoopOptions(selection="best")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="trust_region"):
        ClosedLoopOptions(trust_region="wall")
    with pytest.raises(ValueError, match="tail_stride"):
        TrainConfig(sampler="closed-loop", cl_tail_stride=0)
    with pytest.raises(ValueError, match="value_cap"):
        TrainConfig(value_cap=-1.0)
    with pytest.raises(ValueError, match="round boundaries"):
        TrainConfig(budget=50, solves_per_round=10, snapshots=(25,))
    TrainConfig(budget=55, solves_per_round=10, snapshots=(20, 55))  # multiples of the round, and the budget


def _net(task, seed=0):
    net = ValueNetwork(task.nx, (8,), task_name=task.name, seed=seed)
    rng = np.random.default_rng(0)
    x = task.sample_x0(rng, 50)
    net.set_normalization(x, rng.uniform(0, 5, 50), rng.uniform(0, 50, 50))
    return net


def test_collect_queries_are_the_planned_terminal_states():
    task = make_task("acrobot")
    net = _net(task)
    mpc = LimitedLookaheadMPC(task, net, 3, trust_region="none", jit=False)
    starts = task.sample_x0(np.random.default_rng(1), 1)
    q = collect_queries(task, mpc, starts)
    assert q.episodes == 1 and q.steps == 50
    assert q.x.shape[1] == task.nx and q.x.shape[0] == q.tau.shape[0] > 0
    # the learned terminal cost is used while tau_now > 3 dt: queries at tau = 5 - 0.3, 4.9 - 0.3, ...
    assert q.tau.max() == pytest.approx(4.7)
    assert np.all(q.tau > 0)
    for t in q.tau:
        assert tail_horizon(task, float(t)) is not None
    # the first query is the first step's planned x_3 from the start (re-solve and compare)
    mpc.reset()
    obs = np.append(starts[0], task.tau_nominal).astype(np.float32)
    mpc.predict(obs, episode_start=np.array([True]))
    np.testing.assert_allclose(q.x[0], mpc.last_info[0].terminal_state, atol=1e-6)


def _cl_config(tmp_path, **overrides) -> TrainConfig:
    base = dict(
        task="acrobot",
        sampler="closed-loop",
        budget=18,
        solves_per_round=6,
        train_steps_per_round=10,
        batch_size=32,
        pretrain_solves=4,
        pretrain_steps=10,
        hidden=(8,),
        cl_episodes=1,
        cl_horizon=2,
        cl_jit=False,
        cl_uniform_fraction=0.34,
        cl_uniform_solves=6,
        cl_warmup_rounds=1,
        cl_trust_region="none",
        seed=0,
        cache_dir=str(tmp_path / "cache"),
        progress=False,
        validate=False,
    )
    base.update(overrides)
    return TrainConfig(**base)


@pytest.fixture(scope="module")
def closed_loop_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("cl")
    toy = ToySolver(make_task("acrobot"))
    result = train(_cl_config(tmp, snapshots=(6,)), tmp / "run", batch_solver=toy, solver_name="toy")
    return tmp, toy, result


def test_closed_loop_training_spends_the_budget_on_tail_queries(closed_loop_run):
    tmp, _toy, result = closed_loop_run
    records = result.dataset.records()
    budget = [r for r in records if r.sampler != "pretrain"]
    assert len(budget) == 18 == result.num_solves
    # round 0: the uniform warm-up (6 solves); rounds 1-2: 2 uniform + 4 tails each
    assert [r.sampler for r in budget[:6]] == ["uniform-mix"] * 6
    tails = [r for r in budget if r.sampler == "closed-loop"]
    uniform = [r for r in budget if r.sampler == "uniform-mix"]
    assert len(uniform) == 6 + 2 * round(0.34 * 6) and len(tails) == 18 - len(uniform)
    # every tail request is a tail of the full problem from an MPC query (tau below the full 5 s)
    assert all(0 < r.tau < 5.0 and tail_horizon(make_task("acrobot"), r.tau) for r in tails)
    metrics = json.loads((tmp / "run" / "metrics.json").read_text())
    log = metrics["sampler_log"]
    assert "collector" not in log[0]  # the uniform warm-up round runs no episodes
    assert [e["collector"] for e in log[1:]] == ["lqr", "none"]  # first loop round with the guarded MPC
    assert all(e["episodes"] == 1 and e["queries"] >= e["tails"] for e in log[1:])
    assert (tmp / "run" / "network_6.pt").is_file()


def test_closed_loop_training_resumes_exactly(closed_loop_run, tmp_path):
    _, _, full = closed_loop_run

    class Interrupt(ToySolver):
        def __call__(self, starts, taus):
            if self.num_solves >= 15:
                raise KeyboardInterrupt
            return super().__call__(starts, taus)

    task = make_task("acrobot")
    with pytest.raises(KeyboardInterrupt):
        train(_cl_config(tmp_path, snapshots=(6,)), tmp_path / "run", batch_solver=Interrupt(task), solver_name="toy")
    toy = ToySolver(task)
    resumed = train(
        _cl_config(tmp_path, snapshots=(6,)), tmp_path / "run", resume=True, batch_solver=toy, solver_name="toy"
    )
    assert toy.num_solves < 18  # stored records were reused
    np.testing.assert_array_equal(resumed.network.casadi_parameters(), full.network.casadi_parameters())
    a = [(r.sampler, r.x_init.tolist(), r.tau) for r in resumed.dataset.records()]
    b = [(r.sampler, r.x_init.tolist(), r.tau) for r in full.dataset.records()]
    assert a == b


def test_collect_refit_collects_with_a_deterministic_refit(tmp_path):
    """``cl_collect_refit``: the collecting MPC runs a refit of the buffer (other queries than the loop network's),
    the same refit on every run and after an interruption."""
    task = make_task("acrobot")
    with pytest.raises(ValueError, match="refit_steps"):
        _cl_config(tmp_path, cl_collect_refit=True)

    def run(name, solver=None, resume=False, **overrides):
        cfg = _cl_config(tmp_path / name, refit_steps=30, **overrides)
        return train(
            cfg, tmp_path / name / "run", resume=resume, batch_solver=solver or ToySolver(task), solver_name="toy"
        )

    def tails(result):
        return [r.x_init.tolist() for r in result.dataset.records() if r.sampler == "closed-loop"]

    first = run("a", cl_collect_refit=True)
    assert len(tails(first)) == 8  # two closed-loop rounds of 4 tails, as without the option
    assert tails(run("plain")) != tails(first)  # the loop network plans elsewhere than its refit

    class Interrupt(ToySolver):
        def __call__(self, starts, taus):
            if self.num_solves >= 15:
                raise KeyboardInterrupt
            return super().__call__(starts, taus)

    with pytest.raises(KeyboardInterrupt):
        run("b", Interrupt(task), cl_collect_refit=True)
    resumed = run("b", resume=True, cl_collect_refit=True)
    assert tails(resumed) == tails(first)
    np.testing.assert_array_equal(resumed.network.casadi_parameters(), first.network.casadi_parameters())


def test_batch_solver_routes_tail_times_to_tail_problems_bellman_consistent():
    """A request with tau below T0 is the tail problem: its value equals the full solve's cost to go at that knot."""
    from seagul_learn.solving import trajopt_batch_solver
    from seagul_learn.trajopt import TrajectoryOptimizer

    task = make_task("acrobot")
    full = TrajectoryOptimizer(task, codegen=False).solve(task.goal + np.array([0.2, -0.2, 0.3, 0.0]))
    assert full.success
    k = 30  # knot 30 of 50: 2.0 s to go
    solver = trajopt_batch_solver("acrobot", solver_options={"codegen": False})
    (tail,) = solver(full.states[k][None], np.array([full.time_to_go[k]]))
    assert tail.success and tail.states.shape[0] == 51 - k
    assert tail.value == pytest.approx(full.cost_to_go[k], rel=1e-6, abs=1e-8)
    np.testing.assert_allclose(tail.grad_x, full.knot_grads[k], rtol=1e-4, atol=1e-6)


def test_bench_glider_block_carries_the_contract_fields_and_update_keeps_other_tasks(tmp_path, monkeypatch):
    """The benchmark's glider settings come from the task (horizon, grid), its block names the perch rate as the
    contract spells it, and ``--update`` writes one task's block beside the others already in the file."""
    import importlib
    import json
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    monkeypatch.syspath_prepend(str(root / "benchmarks"))
    bench_mod = importlib.import_module("bench_closed_loop")
    glider = bench_mod.BenchConfig.for_task("glider", quick=False)
    assert (glider.horizon, glider.grid, glider.goal_blend) == (10, 6, 0.0)
    assert glider.train["value_cap"] == 1500.0 and glider.train["refit_steps"] == 0
    # What the shipped method trains with (and what the reports' train_settings show) is the task's recipe.
    recipe = bench_mod.method_config(glider, bench_mod.SHIPPED)
    assert (recipe["cl_warmup_rounds"], recipe["cl_collect_refit"], recipe["refit_ensemble"]) == (0, False, 1)
    assert recipe["cl_keep_best"] is True
    assert recipe["value_cap"] == 1500.0 and recipe["task"] == "glider"
    rows = [
        {"seed": s, "success_rate": r, "heldout_success_rate": r, "query_error": {"median": 1.0, "p95": 2.0}}
        for s, r in enumerate([0.5, 0.9, 0.7])
    ]
    full = {"success_rate": 1.0, "heldout_success_rate": float("nan")}
    timing = {"median_ms": 5.0, "p95_ms": 30.0, "steps": 10, "success_rate": 0.7}
    block = bench_mod.shipped_block(glider, rows, full, Path("net.pt"), timing, 2000)
    assert block["perch_success_rate"] == block["success_rate"] == 0.7
    assert block["full_horizon_perch_success_rate"] == 1.0 and block["seeds"] == 3 and block["horizon"] == 10
    assert "perch_success_rate" not in bench_mod.shipped_block(
        bench_mod.BenchConfig.for_task("acrobot", quick=False), rows, full, Path("net.pt"), timing, 2000
    )
    target = tmp_path / "closed_loop.json"
    target.write_text(json.dumps({"acrobot": {"success_rate": 0.9}, "machine": {"cpu": "old"}}))
    monkeypatch.setattr(bench_mod, "aggregate_task", lambda bench, *a: {"task": bench.task, "success_rate": 0.7})
    monkeypatch.setattr(sys, "argv", ["bench_closed_loop.py"])
    bench_mod.main(
        [
            "--aggregate",
            str(tmp_path),
            "--network",
            "net.pt",
            "--budgets",
            "2000",
            "--tasks",
            "glider",
            "--update",
            str(target),
        ]
    )
    merged = json.loads(target.read_text())
    assert merged["acrobot"] == {"success_rate": 0.9} and merged["glider"]["success_rate"] == 0.7
    assert "glider" in merged["machines"]


def test_bench_aggregates_several_budgets_with_grid_only_rows_and_draws_the_curve(tmp_path, monkeypatch):
    """``--aggregate`` over budgets: per-budget folders, a budget may lack seeds or held-out rates; the contract's
    fields are the shipped budget's; the figure is written."""
    import importlib
    import json
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    monkeypatch.syspath_prepend(str(root / "benchmarks"))
    bench_mod = importlib.import_module("bench_closed_loop")
    glider = bench_mod.BenchConfig.for_task("glider", quick=False)
    glider.budgets = (2000, 3000)
    glider.seed_list = (0, 1)
    (tmp_path / "b2000").mkdir()
    (tmp_path / "b3000").mkdir()
    grid_only = {"success_rate": 0.5, "fallback_steps": 3}
    (tmp_path / "b2000" / "seed0.json").write_text(json.dumps(grid_only))
    (tmp_path / "b2000" / "seed1.json").write_text(json.dumps({**grid_only, "success_rate": 0.7}))
    full_row = {"success_rate": 0.9, "heldout_success_rate": 0.8, "fallback_steps": 1, "solve_time_s": 600.0}
    full_row["query_error"] = {"median": 5.0, "p95": 50.0, "mean_signed": -1.0}
    (tmp_path / "b3000" / "seed0.json").write_text(json.dumps(full_row))  # seed 1 not evaluated at 3000
    (tmp_path / "full-horizon.json").write_text(json.dumps({"success_rate": 1.0, "heldout_success_rate": None}))
    timing = {"median_ms": 5.0, "p95_ms": 9.0, "steps": 3, "success_rate": 1.0}
    monkeypatch.setattr(bench_mod, "timed_steps", lambda *a: timing)
    figure = tmp_path / "curve.png"
    other = tmp_path / "other" / "b2000"
    other.mkdir(parents=True)
    for seed, rate in ((0, 0.25), (1, 0.5)):
        (other / f"seed{seed}.json").write_text(json.dumps({**grid_only, "success_rate": rate}))
    flat = tmp_path / "flat"  # one budget's seed<N>.json directly in the folder: the budget comes with it
    flat.mkdir()
    (flat / "seed1.json").write_text(json.dumps({**grid_only, "success_rate": 0.1}))
    label, spec = bench_mod.parse_compare(f"closed-loop+rest-2000={flat}@2000")
    assert (label, spec) == ("closed-loop+rest-2000", (flat, 2000))
    assert bench_mod.parse_compare("x=a/b")[1] == (Path("a/b"), None)
    for bad in ("no-label", "=dir", "x=dir@many"):
        with pytest.raises(ValueError, match="LABEL=DIR"):
            bench_mod.parse_compare(bad)
    compare = {"last": (tmp_path / "other", None), label: spec}
    block = bench_mod.aggregate_task(glider, tmp_path, Path("net.pt"), 3000, figure, compare)
    assert list(block["methods"][label]["budgets"]) == ["2000"]  # not the shipped budget, 3000
    assert block["methods"][label]["budgets"]["2000"]["success_median"] == 0.1
    versus = block["methods"]["last"]["budgets"]["2000"]
    assert versus["success_median"] == 0.375 and versus["vs_shipped"]["wins"] == 2  # the shipped method, seed by seed
    assert versus["vs_shipped"]["median_difference"] == pytest.approx(0.225)
    assert block["budget"] == 3000 and block["perch_success_rate"] == 0.9 and block["heldout_success_rate"] == 0.8
    # the glider's shipped method under its own name (its overrides turn off what "+rest" adds)
    assert block["method"] == "closed-loop+sobolev" and bench_mod.SHIPPED not in block["methods"]
    rows = block["methods"]["closed-loop+sobolev"]["budgets"]
    assert rows["2000"]["success_median"] == 0.6 and rows["2000"]["seeds"] == [0, 1]
    assert np.isnan(rows["2000"]["heldout_median"]) and rows["3000"]["seeds"] == [0]
    assert block["train_settings"]["value_cap"] == 1500.0 and figure.stat().st_size > 0
    assert "network" not in versus  # no row names its network


def test_the_controller_table_has_a_row_per_learning_method_with_its_representative_network(tmp_path, monkeypatch):
    """A method whose rows name their networks gets the median seed's (ties: the lower seed) in the summary, and
    ``bench_controllers`` lists every other method of ``closed_loop.json`` beside it, each at its largest budget."""
    import importlib
    import json
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    monkeypatch.syspath_prepend(str(root / "benchmarks"))
    bench_mod = importlib.import_module("bench_closed_loop")
    controllers = importlib.import_module("bench_controllers")
    bench = bench_mod.BenchConfig.for_task("acrobot", quick=False)
    rows = [
        {"seed": s, "success_rate": r, "heldout_success_rate": h, "network": f"net{s}.pt"}
        for s, r, h in ((0, 0.1, 0.2), (1, 0.3, 0.1), (2, 0.2, 0.3), (3, 0.25, 0.3))
    ]
    summary = bench_mod.summarize(bench, {"uniform": {2000: rows}}, {"success_rate": 1.0})
    at = summary["uniform"]["budgets"]["2000"]
    assert at["success_median"] == pytest.approx(0.225) and at["network_seed"] == 2 and at["network"] == "net2.pt"
    results = tmp_path / "results"
    results.mkdir()
    shipped = {"method": bench_mod.SHIPPED, "budget": 1000, "horizon": 5, "trust_region": "none"}
    low = {**at, "success_median": 0.05, "heldout_median": float("nan")}
    methods = {
        bench_mod.SHIPPED: {"budgets": {"1000": at}},
        "uniform": {"budgets": {"300": low, **summary["uniform"]["budgets"]}},
    }
    methods["adversarial"] = {"budgets": {"300": low}}  # run to 300 solves only: its row is there
    methods["closed-loop+select"] = summary["uniform"]  # another closed-loop recipe, not a sampler's row
    (results / "closed_loop.json").write_text(json.dumps({"acrobot": {**shipped, "methods": methods}}))
    monkeypatch.setattr(controllers, "RESULTS", results)
    row, other = controllers.sampler_rows("acrobot")
    # the largest budget a sampler was run to (not the shipped one, and not its first row)
    assert row["method"] == "learned 5-step MPC (uniform, 4 seeds)" and row["nlp_solves"] == 2000
    assert row["grid_success"] == pytest.approx(0.225) and row["heldout_success"] == pytest.approx(0.25)
    assert row["median_ms"] is None  # no latency starts: not timed
    assert other["method"].startswith("learned 5-step MPC (adversarial") and other["nlp_solves"] == 300
    assert other["grid_success"] == pytest.approx(0.05)
    assert controllers.sampler_rows("glider") == []


def test_keep_best_deploys_the_network_the_best_collector_flew(tmp_path):
    """``cl_keep_best``: only deployed collectors count, ties go to the later round, ``network.pt`` is the kept one
    (``network_last.pt`` the loop's), and the choice follows the sampler log."""
    from seagul_learn.training import _keep_best
    from seagul_learn.value_network import ValueNetwork

    config = _cl_config(tmp_path, cl_keep_best=True)
    rates = [("lqr", 2), ("none", 1), ("none", 3), ("none", 2), ("none", 3), ("none", 0)]
    log: list[dict] = []
    saved = []
    for r, (collector, wins) in enumerate(rates):
        log.append({"round": r, "collector": collector, "episodes": 4, "episode_successes": wins})
        net = ValueNetwork(4, (4,), task_name="acrobot", seed=r)
        _keep_best(tmp_path, config, log, net, 100 + r)
        info = (
            json.loads((tmp_path / "network_best.json").read_text())
            if (tmp_path / "network_best.json").is_file()
            else None
        )
        saved.append(None if info is None else info["round"])
    assert saved == [None, 1, 2, 2, 4, 4]
    kept = ValueNetwork.load(tmp_path / "network_best.pt")
    np.testing.assert_array_equal(
        kept.casadi_parameters(), ValueNetwork(4, (4,), task_name="acrobot", seed=4).casadi_parameters()
    )
    with pytest.raises(ValueError, match="cl_keep_best needs sampler='closed-loop' and refit_steps=0"):
        _cl_config(tmp_path, cl_keep_best=True, refit_steps=10)
    # In a run: network.pt is the kept network, the loop's last is network_last.pt.
    toy = ToySolver(make_task("acrobot"))
    run = tmp_path / "run"
    result = train(
        _cl_config(tmp_path, cl_keep_best=True, cl_warmup_rounds=0, cl_episodes=2, snapshots=(12,)),
        run,
        batch_solver=toy,
        solver_name="toy",
    )
    best = json.loads((run / "network_best.json").read_text())
    log = json.loads((run / "metrics.json").read_text())["sampler_log"]
    deployed = [e for e in log if e.get("collector") == "none"]
    top = max(e["episode_successes"] for e in deployed)
    assert best["round"] == max(e["round"] for e in deployed if e["episode_successes"] == top)
    np.testing.assert_array_equal(
        ValueNetwork.load(run / "network.pt").casadi_parameters(),
        ValueNetwork.load(run / "network_best.pt").casadi_parameters(),
    )
    assert (run / "network_last.pt").is_file() and (run / "network_12.pt").is_file()
    np.testing.assert_array_equal(
        result.network.casadi_parameters(), ValueNetwork.load(run / "network.pt").casadi_parameters()
    )


def test_visited_fraction_solves_tails_from_the_states_the_episodes_visited(tmp_path):
    """``cl_visited_fraction``: that share of a closed-loop round's tails starts at states the collecting episode
    visited (with their times to go on the step grid), the rest at planner queries; the budget is spent exactly and
    a re-run asks for the same problems."""
    task = make_task("acrobot")
    with pytest.raises(ValueError, match="visited_fraction"):
        ClosedLoopOptions(visited_fraction=1.5)

    def run(name):
        cfg = _cl_config(tmp_path / name, cl_visited_fraction=0.5, cl_uniform_fraction=0.0, cl_tail_stride=1)
        return train(cfg, tmp_path / name / "run", batch_solver=ToySolver(task), solver_name="toy")

    result = run("a")
    budget = [r for r in result.dataset.records() if r.sampler != "pretrain"]
    assert len(budget) == 18
    visited = [r for r in budget if r.sampler == "closed-loop-visited"]
    planned = [r for r in budget if r.sampler == "closed-loop"]
    assert len(visited) == len(planned) == 6  # two loop rounds of 6 tails, half each
    h = task.control_period
    for r in visited:
        steps = (task.tau_nominal - r.tau) / h
        assert 0 < r.tau <= task.tau_nominal and abs(steps - round(steps)) < 1e-9
    log = json.loads((tmp_path / "a" / "run" / "metrics.json").read_text())["sampler_log"]
    assert [e.get("visited_tails") for e in log[1:]] == [3, 3]
    again = run("b")
    assert [(r.sampler, r.x_init.tolist(), r.tau) for r in again.dataset.records()] == [
        (r.sampler, r.x_init.tolist(), r.tau) for r in result.dataset.records()
    ]


def test_collect_queries_records_the_visited_states_in_order():
    task = make_task("acrobot")
    mpc = LimitedLookaheadMPC(task, _net(task), 2, trust_region="none", jit=False)
    starts = task.sample_x0(np.random.default_rng(3), 1)
    q = collect_queries(task, mpc, starts, record_visited=True)
    assert q.visited_x is not None and q.visited_tau is not None and q.visited_failed is not None
    assert q.visited_x.shape == (50, task.nx)
    np.testing.assert_allclose(q.visited_x[0], starts[0])
    np.testing.assert_allclose(q.visited_tau, task.tau_nominal - 0.1 * np.arange(50), atol=1e-12)
    assert bool(q.visited_failed.all()) == (q.successes == 0)
    with pytest.raises(ValueError, match="fixed-step"):
        collect_queries(make_task("glider"), mpc, starts, record_visited=True)


def test_select_members_scores_every_subset_on_training_starts_and_keeps_the_best(monkeypatch):
    """Every subset of the candidates flies the same seeded training starts; the best wins, the first of ties."""
    import seagul_control.evaluation as evaluation
    from seagul_learn.closed_loop import select_members
    from seagul_learn.value_network import ValueEnsemble

    task = make_task("acrobot")
    cands = ValueEnsemble(4, (8,), 4, 0.0, task_name="acrobot", seed=0)
    rng = np.random.default_rng(0)
    for net in cands.networks:
        net.set_normalization(task.sample_x0(rng, 32), rng.uniform(0, 5, 32), rng.uniform(0, 30, 32))
    seen: list[tuple[float, tuple[float, ...]]] = []
    real = evaluation.run_policy_episode

    def fake(task_, policy, x0, **kw):
        # success iff member 3's weights are in the MPC's ensemble (identified by its first output weight)
        episode, infos = real(task_, policy, x0, **kw)
        members = policy._vf_theta
        mark = float(cands.members[3].casadi_parameters()[-3])
        seen.append((float(x0[0]), tuple(np.round(x0, 12))))
        episode.success = bool(np.any(np.isclose(members, mark)))
        return episode, infos

    monkeypatch.setattr(evaluation, "run_policy_episode", fake)
    sel = select_members(task, cands, 2, 2, seed=5, jit=False)
    assert set(sel.scores) == {(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)}
    assert sel.members == (0, 3) and sel.success == 1.0 and sel.episodes == 2  # the first of the three ties
    assert {s for s, v in sel.scores.items() if v == 1.0} == {(0, 3), (1, 3), (2, 3)}
    starts = {x for _, x in seen}
    assert len(starts) == 2  # every subset flew the same two starts
    assert sel.as_dict()["scores"]["0,3"] == 1.0
    with pytest.raises(ValueError, match="size"):
        select_members(task, cands, 5, 2, seed=5, jit=False)
    # a second stage: the two best subsets fly 3 more (other) starts, ranked on all 5 episodes
    seen.clear()
    two = select_members(task, cands, 2, 2, seed=5, finalists=2, final_episodes=3, jit=False)
    assert set(two.finalists) == {(0, 3), (1, 3)} and two.final_episodes == 3
    assert two.members == (0, 3) and two.success == 1.0
    assert len({x for _, x in seen}) == 5  # 2 first-stage starts + 3 second-stage starts
    # half of each stage's starts on the grid's slice (at rest): recorded, and refused outside [0, 1]
    seen.clear()
    half = select_members(task, cands, 2, 2, seed=5, finalists=2, final_episodes=2, jit=False, slice_fraction=0.5)
    assert half.slice_fraction == 0.5 and half.as_dict()["slice_fraction"] == 0.5
    at_rest = {x for _, x in seen if x[2] == 0.0 and x[3] == 0.0}
    assert len(at_rest) == 2 and len({x for _, x in seen}) == 4  # one at rest per stage
    with pytest.raises(ValueError, match="slice_fraction"):
        select_members(task, cands, 2, 2, seed=5, jit=False, slice_fraction=1.5)


def test_grid_slice_starts_lie_on_the_evaluation_grids_slice_of_x0():
    """``sample_grid_slice``: the grid's two coordinates uniform over X0's range (spread over it), the others where
    the grid holds them (acrobot at rest, glider at X0's centre); seeded draws repeat."""
    from seagul_control.evaluation import sample_grid_slice, start_grid
    from seagul_learn.closed_loop import _selection_starts

    for name in ("acrobot", "glider"):
        task = make_task(name)
        grid, _ = start_grid(task, 4)
        draws = sample_grid_slice(task, 400, np.random.default_rng(3))
        dims = list(task.profile.grid.resolved_coords(task))
        others = [i for i in range(task.nx) if i not in dims]
        np.testing.assert_allclose(draws[:, others], np.repeat(grid[:1, others], 400, axis=0))
        assert all(task.in_x0(x) for x in draws)
        low, high = task.x0_low[dims], task.x0_high[dims]
        assert np.all(draws[:, dims].min(axis=0) < low + 0.05 * (high - low))
        assert np.all(draws[:, dims].max(axis=0) > high - 0.05 * (high - low))
        np.testing.assert_array_equal(draws, sample_grid_slice(task, 400, np.random.default_rng(3)))
    task = make_task("acrobot")
    mixed = _selection_starts(task, 10, 4, 16, 18, 0.3)
    assert np.count_nonzero(np.all(mixed[:, 2:] == 0.0, axis=1)) == 3  # three on the slice, at rest
    # fraction 0 draws exactly the uniform stream's starts
    np.testing.assert_array_equal(
        _selection_starts(task, 10, 4, 16, 18, 0.0), task.sample_x0(np.random.default_rng([4, 16]), 10)
    )


def test_refit_candidates_deploys_the_selected_members(tmp_path):
    """``refit_candidates``: the final refit fits that many members, the selection's subset becomes network.pt, the
    candidates and the scores are kept."""
    from seagul_learn.value_network import ValueEnsemble

    task = make_task("acrobot")
    with pytest.raises(ValueError, match="refit_candidates"):
        _cl_config(tmp_path, refit_steps=20, refit_ensemble=2, refit_candidates=2)
    with pytest.raises(ValueError, match="select_slice_fraction"):
        _cl_config(tmp_path, refit_steps=20, refit_ensemble=2, refit_candidates=3, select_slice_fraction=-0.1)
    cfg = _cl_config(
        tmp_path,
        refit_steps=20,
        refit_ensemble=2,
        refit_candidates=3,
        select_episodes=1,
        select_jit=False,
        budget=6,
        cl_uniform_solves=6,
    )
    result = train(cfg, tmp_path / "run", batch_solver=ToySolver(task), solver_name="toy")
    run = tmp_path / "run"
    info = json.loads((run / "network_selection.json").read_text())
    # the candidates' refit is stored with what it depends on, and reused by a selection of the same run
    from seagul_learn.dataset import training_arrays
    from seagul_learn.training import _Trainer, make_network, refit_and_select

    key = json.loads((run / "network_candidates.json").read_text())
    assert key["candidates"] == 3 and key["refit"]["refit_steps"] == 20
    buffer = training_arrays(result.dataset.records())
    again = refit_and_select(cfg, task, buffer, _Trainer(cfg, make_network(cfg, task), None), run)
    x0, t0 = task.sample_x0(np.random.default_rng(1), 2), np.full(2, 3.0)
    np.testing.assert_allclose(again.predict(x0, t0), result.network.predict(x0, t0))
    assert len(info["scores"]) == 3 and info["candidates"] == 3 and len(info["members"]) == 2
    assert info["slice_fraction"] == 0.0
    cands = ValueNetwork.load(run / "network_candidates.pt")
    deployed = ValueNetwork.load(run / "network.pt")
    assert isinstance(cands, ValueEnsemble) and isinstance(deployed, ValueEnsemble)
    x, tau = task.sample_x0(np.random.default_rng(0), 3), np.full(3, 4.0)
    for k, i in enumerate(info["members"]):
        np.testing.assert_allclose(deployed.members[k].predict(x, tau), cands.members[i].predict(x, tau))
    np.testing.assert_allclose(result.network.predict(x, tau), deployed.predict(x, tau))


def test_slice_fraction_starts_that_share_of_each_rounds_episodes_at_rest():
    """``cl_slice_fraction``: that share of a round's episode starts lies on the grid's slice of X0 (the acrobot at
    rest, inside X0's angle box, never the grid's points), the rest are exactly the uniform starts drawn without the
    option; each round draws new ones, reproducibly; outside [0, 1] is refused."""
    from seagul_control.evaluation import start_grid
    from seagul_learn.closed_loop import ClosedLoopSampler
    from seagul_learn.samplers import StartPool

    task = make_task("acrobot")
    with pytest.raises(ValueError, match="slice_fraction"):
        ClosedLoopOptions(slice_fraction=-0.1)
    assert TrainConfig(task="acrobot", cl_slice_fraction=0.25).closed_loop_options().slice_fraction == 0.25
    pool = StartPool(np.zeros((1, task.nx)), np.zeros(1), np.zeros(1, dtype=int))

    def starts(fraction, round_index, seed=3):
        sampler = ClosedLoopSampler(task, pool, ClosedLoopOptions(episodes=8, slice_fraction=fraction), seed=seed)
        sampler.round = round_index
        return sampler.episode_starts()

    plain, half = starts(0.0, 2), starts(0.5, 2)
    assert half.shape == plain.shape == (8, task.nx)
    np.testing.assert_array_equal(half[:4], plain[:4])  # the uniform share: the first draws of the same stream
    rest = half[4:]
    np.testing.assert_array_equal(rest[:, 2:], 0.0)  # at rest
    assert np.all(rest[:, :2] >= task.x0_low[:2]) and np.all(rest[:, :2] <= task.x0_high[:2])
    assert np.abs(plain[:, 2:]).min() > 0  # uniform draws over X0 are never at rest
    grid, _ = start_grid(task, 20)
    assert not any(np.any(np.all(np.isclose(grid, s), axis=1)) for s in rest)
    np.testing.assert_array_equal(half, starts(0.5, 2))
    assert not np.array_equal(rest, starts(0.5, 3)[4:])
    assert starts(1.0, 0).shape == (8, task.nx) and np.all(starts(1.0, 0)[:, 2:] == 0.0)


def test_the_collector_deploys_the_tasks_guard_unless_told_otherwise(tmp_path):
    """``cl_trust_region=None`` (the default): after the warm-up the sampler collects, and ``cl_keep_best`` ranks,
    with the guard the task deploys (``profile.mpc_trust_region``: the acrobot's "none", a new task's "lqr");
    an explicit guard wins; the CLI spells it ``--cl-trust-region``."""
    import dataclasses

    from seagul_learn.closed_loop import ClosedLoopSampler
    from seagul_learn.samplers import StartPool
    from seagul_learn.training import _keep_best
    from seagul_learn.value_network import ValueNetwork

    acrobot = make_task("acrobot")
    guarded = dataclasses.replace(acrobot, profile=dataclasses.replace(acrobot.profile, mpc_trust_region="lqr"))
    pool = StartPool(np.zeros((1, acrobot.nx)), np.zeros(1), np.zeros(1, dtype=int))
    assert TrainConfig().cl_trust_region is None and ClosedLoopOptions().trust_region is None
    assert ClosedLoopSampler(acrobot, pool).deployed_guard == "none"
    assert ClosedLoopSampler(guarded, pool).deployed_guard == "lqr"
    assert ClosedLoopSampler(acrobot, pool, ClosedLoopOptions(trust_region="box")).deployed_guard == "box"
    assert TrainConfig(task="acrobot", cl_trust_region="lqr").closed_loop_options().trust_region == "lqr"
    # keep-best counts the rounds of the resolved guard only
    log = [
        {"round": 0, "collector": "lqr", "episodes": 4, "episode_successes": 4},
        {"round": 1, "collector": "none", "episodes": 4, "episode_successes": 1},
    ]
    net = ValueNetwork(4, (4,), task_name="acrobot", seed=0)
    for task, saved in ((acrobot, True), (guarded, False)):
        out = tmp_path / task.profile.mpc_trust_region
        out.mkdir()
        config = _cl_config(tmp_path, task=task, cl_keep_best=True, cl_trust_region=None)
        _keep_best(out, config, log, net, 100)
        assert (out / "network_best.pt").is_file() is saved


@pytest.mark.parametrize("task_name", ["acrobot", "glider"])
def test_the_tasks_recipe_is_what_the_benchmark_ships(monkeypatch, task_name):
    """``TrainConfig.recipe(task)`` (``seagul train``'s default) trains exactly what ``bench_closed_loop.py``
    measured and ships for the task (its full run: the largest budget, the shipped method's settings)."""
    import importlib
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    monkeypatch.syspath_prepend(str(root / "benchmarks"))
    bench_mod = importlib.import_module("bench_closed_loop")
    bench = bench_mod.BenchConfig.for_task(task_name, quick=False)
    shipped = {**bench_mod.method_config(bench, bench_mod.SHIPPED), "budget": max(bench.budgets)}
    assert TrainConfig.recipe(task_name) == TrainConfig(**shipped)
    assert TrainConfig.recipe(task_name) != TrainConfig(task=task_name)  # not the paper's defaults


def test_the_shipped_recipe_is_the_2000_solve_one_with_its_budget_split_halved(monkeypatch):
    """The shipped ``closed-loop+rest-1000`` differs from the 2,000-solve ``closed-loop+rest`` it scales down only in
    how its 1,000 solves split: the same fractions of uniform draws, guarded and deployed-collector rounds."""
    import importlib
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    monkeypatch.syspath_prepend(str(root / "benchmarks"))
    bench_mod = importlib.import_module("bench_closed_loop")
    bench = bench_mod.BenchConfig.for_task("acrobot", quick=False)
    assert bench_mod.SHIPPED == "closed-loop+rest-1000" and max(bench.budgets) == 1000
    shipped = TrainConfig(**bench_mod.method_config(bench, "closed-loop+rest"), budget=2000)
    scaled = TrainConfig(**bench_mod.method_config(bench, bench_mod.SHIPPED), budget=1000)

    def split(c: TrainConfig) -> tuple[float, float]:
        rounds = (c.budget - c.cl_uniform_solves) / c.solves_per_round
        return c.cl_uniform_solves / c.budget, c.cl_warmup_rounds / rounds

    assert split(scaled) == split(shipped) == (0.5, 0.5)
    differs = {f for f in shipped.__dataclass_fields__ if getattr(shipped, f) != getattr(scaled, f)}
    assert differs == {"budget", "cl_uniform_solves", "cl_warmup_rounds"}
