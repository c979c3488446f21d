"""The closed-loop sampler: queries come from the deployed MPC, tails are solved, budgets exact, resume exact."""

from __future__ import annotations

import json

import numpy as np
import pytest
from toy_problem import ToySolver

from seagul_control.mpc import LimitedLookaheadMPC, MPCOptions
from seagul_envs import MPCDefaults, make_task
from seagul_learn.closed_loop import ClosedLoopOptions, collect_queries, farthest_first, snap_tau
from seagul_learn.solving import tail_horizon
from seagul_learn.training import (
    LossConfig,
    NetworkConfig,
    RuntimeConfig,
    ScheduleConfig,
    TrainConfig,
    train,
)
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
        TrainConfig(sampler=ClosedLoopOptions(tail_stride=0))
    with pytest.raises(ValueError, match=r"loss\.value_cap"):
        TrainConfig(loss=LossConfig(value_cap=-1.0))
    with pytest.raises(ValueError, match="round boundaries"):
        TrainConfig(budget=50, runtime=RuntimeConfig(snapshots=(25,)))
    TrainConfig(budget=55, runtime=RuntimeConfig(snapshots=(20, 55)))  # multiples of the round, and the budget


def _net(task, seed=0):
    net = ValueNetwork(task.nx, (8,), task_name=task.name, seed=seed)
    rng = np.random.default_rng(0)
    x = task.sample_x0(rng, 50)
    net.set_normalization(x, rng.uniform(0, 5, 50), rng.uniform(0, 50, 50))
    return net


def test_collect_queries_are_the_planned_terminal_states():
    task = make_task("acrobot")
    net = _net(task)
    mpc = LimitedLookaheadMPC(task, net, 3, MPCOptions(jit=False), trust_region="none")
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
    """A small closed-loop run; ``overrides`` name fields, or fields of a part as ``part__field``."""
    base = TrainConfig(
        task="acrobot",
        sampler=ClosedLoopOptions(
            episodes=1,
            horizon=2,
            jit=False,
            uniform_fraction=0.34,
            uniform_solves=6,
            warmup_rounds=1,
            trust_region="none",
        ),
        budget=18,
        schedule=ScheduleConfig(
            solves_per_round=6, train_steps_per_round=10, batch_size=32, pretrain_solves=4, pretrain_steps=10
        ),
        network=NetworkConfig(hidden=(8,)),
        seed=0,
        runtime=RuntimeConfig(cache_dir=str(tmp_path / "cache"), progress=False),
        validate=False,
    )
    return base.replaced(**{k.replace("__", "."): v for k, v in overrides.items()})


@pytest.fixture(scope="module")
def closed_loop_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("cl")
    toy = ToySolver(make_task("acrobot"))
    result = train(_cl_config(tmp, runtime__snapshots=(6,)), tmp / "run", batch_solver=toy, solver_name="toy")
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
        train(
            _cl_config(tmp_path, runtime__snapshots=(6,)),
            tmp_path / "run",
            batch_solver=Interrupt(task),
            solver_name="toy",
        )
    toy = ToySolver(task)
    resumed = train(
        _cl_config(tmp_path, runtime__snapshots=(6,)),
        tmp_path / "run",
        resume=True,
        batch_solver=toy,
        solver_name="toy",
    )
    assert toy.num_solves < 18  # stored records were reused
    np.testing.assert_array_equal(resumed.network.casadi_parameters(), full.network.casadi_parameters())
    a = [(r.sampler, r.x_init.tolist(), r.tau) for r in resumed.dataset.records()]
    b = [(r.sampler, r.x_init.tolist(), r.tau) for r in full.dataset.records()]
    assert a == b


def test_collect_refit_collects_with_a_deterministic_refit(tmp_path):
    """``sampler.collect_refit``: the collecting MPC runs a refit of the buffer (other queries than the loop network's),
    the same refit on every run and after an interruption."""
    task = make_task("acrobot")
    with pytest.raises(ValueError, match=r"sampler\.collect_refit needs refit\.steps > 0"):
        _cl_config(tmp_path, sampler__collect_refit=True)

    def run(name, solver=None, resume=False, **overrides):
        cfg = _cl_config(tmp_path / name, refit__steps=30, **overrides)
        return train(
            cfg, tmp_path / name / "run", resume=resume, batch_solver=solver or ToySolver(task), solver_name="toy"
        )

    def tails(result):
        return [r.x_init.tolist() for r in result.dataset.records() if r.sampler == "closed-loop"]

    first = run("a", sampler__collect_refit=True)
    assert len(tails(first)) == 8  # two closed-loop rounds of 4 tails, as without the option
    assert tails(run("plain")) != tails(first)  # the loop network plans elsewhere than its refit

    class Interrupt(ToySolver):
        def __call__(self, starts, taus):
            if self.num_solves >= 15:
                raise KeyboardInterrupt
            return super().__call__(starts, taus)

    with pytest.raises(KeyboardInterrupt):
        run("b", Interrupt(task), sampler__collect_refit=True)
    resumed = run("b", resume=True, sampler__collect_refit=True)
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


def test_keep_best_deploys_the_network_the_best_collector_flew(tmp_path):
    """``sampler.keep_best``: only deployed collectors count, ties go to the later round, ``network.pt`` is the kept one
    (``network_last.pt`` the loop's), and the choice follows the sampler log."""
    from seagul_learn.training import _keep_best
    from seagul_learn.value_network import ValueNetwork

    config = _cl_config(tmp_path, sampler__keep_best=True)
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
    with pytest.raises(ValueError, match=r"sampler\.keep_best needs refit\.steps = 0"):
        _cl_config(tmp_path, sampler__keep_best=True, refit__steps=10)
    # In a run: network.pt is the kept network, the loop's last is network_last.pt.
    toy = ToySolver(make_task("acrobot"))
    run = tmp_path / "run"
    result = train(
        _cl_config(
            tmp_path, sampler__keep_best=True, sampler__warmup_rounds=0, sampler__episodes=2, runtime__snapshots=(12,)
        ),
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
    """``sampler.visited_fraction``: that share of a closed-loop round's tails starts at states the collecting episode
    visited (with their times to go on the step grid), the rest at planner queries; the budget is spent exactly and
    a re-run asks for the same problems."""
    task = make_task("acrobot")
    with pytest.raises(ValueError, match="visited_fraction"):
        ClosedLoopOptions(visited_fraction=1.5)

    def run(name):
        cfg = _cl_config(
            tmp_path / name, sampler__visited_fraction=0.5, sampler__uniform_fraction=0.0, sampler__tail_stride=1
        )
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
    mpc = LimitedLookaheadMPC(task, _net(task), 2, MPCOptions(jit=False), trust_region="none")
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
    from seagul_learn.member_selection import select_members
    from seagul_learn.value_network import ValueEnsemble

    task = make_task("acrobot")
    cands = ValueEnsemble(4, (8,), 4, 0.0, task_name="acrobot", seed=0)
    rng = np.random.default_rng(0)
    for net in cands.networks:
        net.set_normalization(task.sample_x0(rng, 32), rng.uniform(0, 5, 32), rng.uniform(0, 30, 32))
    seen: list[tuple[float, tuple[float, ...]]] = []

    def fake(task_, policy, x0, **kw):
        # No episode is flown (the selection reads only its success): success iff member 3's weights are in the
        # MPC's ensemble (identified by its first output weight), i.e. in the terminal cost the MPC was given.
        members = policy._vf_theta
        mark = float(cands.members[3].casadi_parameters()[-3])
        seen.append((float(x0[0]), tuple(np.round(x0, 12))))
        success = bool(np.any(np.isclose(members, mark)))
        start = [float(v) for v in x0]
        episode = evaluation.EpisodeResult("selection", 0, start, start, 0.0, 0.0, success, False, 0)
        return episode, []

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
    from seagul_learn.member_selection import _selection_starts

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
    """``refit.candidates``: the final refit fits that many members, the selection's subset becomes network.pt, the
    candidates and the scores are kept."""
    from seagul_learn.value_network import ValueEnsemble

    task = make_task("acrobot")
    with pytest.raises(ValueError, match=r"refit\.candidates must exceed refit\.ensemble"):
        _cl_config(tmp_path, refit__steps=20, refit__ensemble=2, refit__candidates=2)
    with pytest.raises(ValueError, match=r"selection\.slice_fraction must be in \[0, 1\]"):
        _cl_config(tmp_path, refit__steps=20, refit__ensemble=2, refit__candidates=3, selection__slice_fraction=-0.1)
    cfg = _cl_config(
        tmp_path,
        refit__steps=20,
        refit__ensemble=2,
        refit__candidates=3,
        selection__episodes=1,
        selection__jit=False,
        budget=6,
        sampler__uniform_solves=6,
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
    """``sampler.slice_fraction``: that share of a round's episode starts lies on the grid's slice of X0 (the acrobot at
    rest, inside X0's angle box, never the grid's points), the rest are exactly the uniform starts drawn without the
    option; each round draws new ones, reproducibly; outside [0, 1] is refused."""
    from seagul_control.evaluation import start_grid
    from seagul_learn.closed_loop import ClosedLoopSampler
    from seagul_learn.samplers import StartPool

    task = make_task("acrobot")
    with pytest.raises(ValueError, match="slice_fraction"):
        ClosedLoopOptions(slice_fraction=-0.1)
    config = TrainConfig(task="acrobot", sampler=ClosedLoopOptions(slice_fraction=0.25))
    assert config.closed_loop_options().slice_fraction == 0.25
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
    """``sampler.trust_region=None`` (the default): after the warm-up the sampler collects, and
    ``sampler.keep_best`` ranks, with the guard the task deploys (``profile.mpc.trust_region``: the acrobot's "none",
    a new task's "lqr"); an explicit guard wins; the CLI spells it ``--sampler.trust-region``."""
    import dataclasses

    from seagul_learn.closed_loop import ClosedLoopSampler
    from seagul_learn.samplers import StartPool
    from seagul_learn.training import _keep_best
    from seagul_learn.value_network import ValueNetwork

    acrobot = make_task("acrobot")
    lqr_guard = MPCDefaults(horizon=5, trust_region="lqr", goal_blend=1.0)
    guarded = dataclasses.replace(acrobot, profile=dataclasses.replace(acrobot.profile, mpc=lqr_guard))
    pool = StartPool(np.zeros((1, acrobot.nx)), np.zeros(1), np.zeros(1, dtype=int))
    assert ClosedLoopOptions().trust_region is None
    assert ClosedLoopSampler(acrobot, pool).deployed_guard == "none"
    assert ClosedLoopSampler(guarded, pool).deployed_guard == "lqr"
    assert ClosedLoopSampler(acrobot, pool, ClosedLoopOptions(trust_region="box")).deployed_guard == "box"
    config = TrainConfig(task="acrobot", sampler=ClosedLoopOptions(trust_region="lqr"))
    assert config.closed_loop_options().trust_region == "lqr"
    # keep-best counts the rounds of the resolved guard only
    log = [
        {"round": 0, "collector": "lqr", "episodes": 4, "episode_successes": 4},
        {"round": 1, "collector": "none", "episodes": 4, "episode_successes": 1},
    ]
    net = ValueNetwork(4, (4,), task_name="acrobot", seed=0)
    for task, saved in ((acrobot, True), (guarded, False)):
        out = tmp_path / task.profile.mpc.trust_region
        out.mkdir()
        config = _cl_config(tmp_path, task=task, sampler__keep_best=True, sampler__trust_region=None)
        _keep_best(out, config, log, net, 100)
        assert (out / "network_best.pt").is_file() is saved


def _glider_sampler(replay: float, seed: int = 3):
    from seagul_learn.closed_loop import ClosedLoopSampler
    from seagul_learn.samplers import StartPool

    task = make_task("glider")
    pool = StartPool.uniform(task, 20, np.random.default_rng(0), model_params=True)
    return task, ClosedLoopSampler(task, pool, ClosedLoopOptions(episodes=8, replay_failed=replay), seed=seed)


def test_replay_failed_flies_earlier_rounds_failed_robots_again(monkeypatch, tmp_path):
    """``sampler.replay_failed``: with an empty pool every robot is the uniform draw; after a round, its failed robots
    join the pool, and the next round's first ``round(share x episodes)`` episodes fly pool robots (the rest are the
    uniform draws made without the option); a replayed robot that perches leaves the pool, one that fails again stays
    once; the pool survives a resume; the round's log counts the replayed episodes, and the collector rate that ranks
    rounds leaves them out."""
    import seagul_learn.closed_loop as cl
    from seagul_learn.checkpoint import keep_best
    from seagul_learn.round_selection import collector_rate

    with pytest.raises(ValueError, match="replay_failed"):
        ClosedLoopOptions(replay_failed=1.0)
    # recorded only when on: the settings of runs made without it stay as they were
    assert "replay_failed" not in ClosedLoopOptions().to_dict()
    assert ClosedLoopOptions(replay_failed=0.25).to_dict()["replay_failed"] == 0.25
    acrobot = make_task("acrobot")
    no_robots = cl.StartPool(np.zeros((1, acrobot.nx)), np.zeros(1), np.zeros(1, dtype=int))
    with pytest.raises(ValueError, match="over robots"):
        cl.ClosedLoopSampler(acrobot, no_robots, ClosedLoopOptions(replay_failed=0.25))

    task, sampler = _glider_sampler(0.25)
    _, plain = _glider_sampler(0.0)
    assert sampler.replayed() == 0
    np.testing.assert_array_equal(sampler.episode_robots(), plain.episode_robots())

    # one round through sample(): the episodes and the solves are faked, the bookkeeping is the sampler's
    flown: list[np.ndarray] = []
    outcome = {0: np.array([True, False, True, True, False, True, True, True])}

    def fake_collect(task_, mpc, starts, robots=None, record_visited=False):
        flown.append(robots.copy())
        ok = outcome[len(flown) - 1]
        q = cl.Queries(np.zeros((0, task.nx)), np.zeros(0), np.zeros((0, 4)), len(starts), int(ok.sum()), 0, 8)
        q.episode_success = ok
        return q

    class Runner:
        def solve(self, starts, taus, name, thetas=None):
            return []

    monkeypatch.setattr(cl, "collect_queries", fake_collect)
    collector = type("Collector", (), {"trust_region": "none"})
    monkeypatch.setattr(cl.ClosedLoopSampler, "collector", lambda self, network: collector)
    monkeypatch.setattr(cl.ClosedLoopSampler, "_split", lambda self, n: (0, n))
    sampler.sample(4, None, Runner())
    first = flown[0]
    assert sampler.log[-1]["replayed"] == 0 and sampler.log[-1]["replay_pool"] == 2
    assert sorted(map(tuple, sampler.replay_pool)) == sorted([tuple(first[1]), tuple(first[4])])

    # round 1: two of eight episodes replay the two failed robots (in a seeded order), the rest are uniform draws
    plain.round = 1
    assert sampler.replayed() == 2
    robots = sampler.episode_robots()
    assert {tuple(r) for r in robots[:2]} == {tuple(first[1]), tuple(first[4])}
    np.testing.assert_array_equal(robots[2:], plain.episode_robots()[2:])
    np.testing.assert_array_equal(robots, sampler.episode_robots())  # reproducible
    state = json.loads(json.dumps(sampler.state_dict()))
    _, resumed = _glider_sampler(0.25)
    resumed.load_state_dict(state)
    np.testing.assert_array_equal(resumed.episode_robots(), robots)

    # the first replayed robot perches, the second fails again; a new robot fails too
    outcome[1] = np.array([True, False, True, True, True, True, False, True])
    sampler.sample(4, None, Runner())
    entry = sampler.log[-1]
    assert entry["replayed"] == 2 and entry["replayed_successes"] == 1 and entry["episode_successes"] == 6
    pool = [tuple(r) for r in sampler.replay_pool]
    assert len(pool) == len(set(pool)) == 2
    assert tuple(robots[0]) not in pool and tuple(robots[1]) in pool and tuple(flown[1][6]) in pool

    # the rate that ranks rounds: 5 of the 6 new robots' episodes, not 6 of 8
    assert collector_rate(entry) == pytest.approx(5 / 6)
    assert collector_rate({"episodes": 2, "episode_successes": 0, "replayed": 2, "replayed_successes": 0}) is None
    assert collector_rate({"episodes": 4, "episode_successes": 3}) == 0.75

    # keep_best prefers a round whose new robots did better, whatever its replayed ones did
    log = [
        {"round": 0, "collector": "none", "episodes": 8, "episode_successes": 7},
        {
            "round": 1,
            "collector": "none",
            "episodes": 8,
            "episode_successes": 6,
            "replayed": 4,
            "replayed_successes": 0,
        },
    ]
    out = tmp_path
    config = TrainConfig.recipe("glider", "robust-replay", seed=0)
    keep_best(out, config, log[:1], ValueNetwork(4, (4,), task_name="acrobot", seed=0), 100)
    keep_best(out, config, log, ValueNetwork(4, (4,), task_name="acrobot", seed=1), 150)
    saved = json.loads((out / "network_best.json").read_text())
    assert saved["round"] == 1 and saved["replayed"] == 4 and saved["replayed_successes"] == 0
