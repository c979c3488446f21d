"""Choosing the deployed closed-loop round by selection episodes (``SelectionConfig.rounds``,
:mod:`seagul_learn.round_selection`)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_closed_loop import _cl_config
from toy_problem import ToySolver

from seagul_envs import make_task
from seagul_learn.round_selection import deploy_selected, kept_rounds, save_round, select_round
from seagul_learn.training import train
from seagul_learn.value_network import ValueNetwork

TASK = make_task("acrobot")


def _keep(tmp_path, collector_wins: list[int], over_robots: bool = False) -> list[ValueNetwork]:
    nets = []
    for r, wins in enumerate(collector_wins):
        kw = {"n_params": TASK.parameters.size, "theta": TASK.theta} if over_robots else {}
        net = ValueNetwork(4, (4,), task_name="acrobot", seed=r, **kw)
        save_round(tmp_path, net, {"round": r, "episode_successes": wins, "episodes": 4, "solves_before_round": 10 * r})
        nets.append(net)
    return nets


def _select(run, **kw):
    """``select_round`` on the acrobot with a 2-step interpreted MPC; ``kw`` replaces the defaults."""
    args = {
        "rounds": 3,
        "episodes": 8,
        "finalists": 0,
        "final_episodes": 0,
        "seed": 2,
        "over_robots": False,
        "trust_region": "none",
        "horizon": 2,
        "jit": False,
    }
    return select_round(TASK, run, **{**args, **kw})


def _fake_episodes(monkeypatch, nets, rate_of: dict[int, float], seen: list):
    """No episode is flown: the MPC's value parameters name the network, whose ``rate_of`` decides success by the
    start (a start's first coordinate maps to [0, 1))."""
    import seagul_control.evaluation as evaluation

    marks = {i: float(n.casadi_parameters()[-3 - n.n_params]) for i, n in enumerate(nets)}

    def fake(task_, policy, x0, robot=None, **kw):
        who = [i for i, m in marks.items() if np.any(np.isclose(policy._vf_theta, m))]
        assert len(who) == 1
        seen.append((who[0], tuple(np.round(x0, 12)), None if robot is None else tuple(robot)))
        u = (float(x0[0]) - TASK.x0_low[0]) / (TASK.x0_high[0] - TASK.x0_low[0])
        start = [float(v) for v in x0]
        ok = bool(u < rate_of[who[0]])
        return evaluation.EpisodeResult("selection", 0, start, start, 0.0, 0.0, ok, False, 0), []

    monkeypatch.setattr(evaluation, "run_policy_episode", fake)


def test_select_round_flies_the_best_collecting_rounds_and_deploys_the_most_successful(tmp_path, monkeypatch):
    """Only the ``rounds`` best collectors fly (ties: the later round), all the same seeded starts; finalists fly
    more; the winner is copied to network_best.pt with its record."""
    nets = _keep(tmp_path, [1, 3, 2, 3, 0])
    assert [rec["round"] for _, rec in kept_rounds(tmp_path)] == [0, 1, 2, 3, 4]
    seen: list = []
    # the collectors' favourites (rounds 3 and 1) are not the best flyers: round 2 is
    _fake_episodes(monkeypatch, nets, {0: 0.9, 1: 0.3, 2: 0.95, 3: 0.5, 4: 1.0}, seen)
    sel = _select(tmp_path)
    assert set(sel.candidates) == {"10", "20", "30"}  # rounds 1, 2, 3; not 0 or 4 (collectors 1 and 0 wins)
    assert {who for who, _, _ in seen} == {1, 2, 3}
    starts = {who: {x for w, x, _ in seen if w == who} for who in (1, 2, 3)}
    assert starts[1] == starts[2] == starts[3] and len(starts[1]) == 8
    assert sel.round == 2 and sel.solves_before_round == 20 and sel.selection_episodes == 8
    assert sel.selection_success == sel.candidates["20"] and sel.episode_successes == 2 and sel.episodes == 4
    # a second stage on other starts, ranked over all episodes
    seen.clear()
    two = _select(tmp_path, finalists=2, final_episodes=5)
    assert set(two.finalists) == {"20", "30"} and two.selection_episodes == 13
    assert len({x for w, x, _ in seen if w == 2}) == 13 and len({x for w, x, _ in seen if w == 1}) == 8
    path = deploy_selected(tmp_path, two)
    np.testing.assert_array_equal(ValueNetwork.load(path).casadi_parameters(), nets[two.round].casadi_parameters())
    info = json.loads((tmp_path / "network_best.json").read_text())
    assert info["round"] == two.round and info["selection_episodes"] == 13 and "20" in info["candidates"]
    with pytest.raises(ValueError, match="rounds >= 1"):
        _select(tmp_path, rounds=0)
    with pytest.raises(ValueError, match="holds no kept round"):
        _select(tmp_path / "empty", rounds=1, episodes=1)


def test_select_round_over_robots_flies_every_candidate_on_the_same_robots_from_theta(tmp_path, monkeypatch):
    nets = _keep(tmp_path, [2, 3], over_robots=True)
    seen: list = []
    _fake_episodes(monkeypatch, nets, {0: 0.5, 1: 0.5}, seen)
    sel = _select(tmp_path, rounds=2, episodes=4, seed=0, over_robots=True)
    robots = {who: [r for w, _, r in seen if w == who] for who in (0, 1)}
    assert robots[0] == robots[1] and len(set(robots[0])) == 4
    space = TASK.parameters
    assert all(np.all((space.low <= r) & (r <= space.high)) for r in np.array(robots[0]))
    assert sel.round == 1  # equal flights: the later round


def test_selection_rounds_needs_keep_best_and_is_written_only_when_set(tmp_path):
    with pytest.raises(ValueError, match=r"selection\.rounds .* needs the closed-loop sampler with keep_best"):
        _cl_config(tmp_path, selection__rounds=3)
    with pytest.raises(ValueError, match=r"selection\.rounds must be >= 0"):
        _cl_config(tmp_path, sampler__keep_best=True, selection__rounds=-1)
    assert "rounds" not in _cl_config(tmp_path, sampler__keep_best=True).to_dict()["selection"]
    assert _cl_config(tmp_path, sampler__keep_best=True, selection__rounds=2).to_dict()["selection"]["rounds"] == 2


def _selecting_run(tmp_path, **overrides):
    """A toy closed-loop run that keeps every round and selects among 2 of them (``overrides`` as ``_cl_config``'s)."""
    run = tmp_path / "run"
    keep_two = {"sampler__keep_best": True, "sampler__warmup_rounds": 0, "sampler__episodes": 1, "selection__rounds": 2}
    config = _cl_config(tmp_path, **keep_two, **overrides)
    train(config, run, batch_solver=ToySolver(TASK), solver_name="toy")
    return run


def test_a_run_with_selection_rounds_keeps_every_round_and_deploys_the_selected_one(tmp_path):
    run = _selecting_run(tmp_path, selection__episodes=1, selection__jit=False)
    log = [e for e in json.loads((run / "metrics.json").read_text())["sampler_log"] if e.get("episodes")]
    kept = kept_rounds(run)
    assert [rec["round"] for _, rec in kept] == [e["round"] for e in log]
    best = json.loads((run / "network_best.json").read_text())
    assert len(best["candidates"]) == 2 and best["selection_episodes"] == 1
    chosen = run / "rounds" / f"network_{best['solves_before_round']}.pt"
    np.testing.assert_array_equal(
        ValueNetwork.load(run / "network.pt").casadi_parameters(), ValueNetwork.load(chosen).casadi_parameters()
    )


def test_a_selection_other_than_the_best_collector_becomes_network_pt_and_the_full_budget_snapshot(
    tmp_path, monkeypatch
):
    """Whatever round the selection returns is deployed: network.pt and the full budget's snapshot are that round's
    network, not the best collector's that the loop kept meanwhile."""
    import seagul_learn.training as training
    from seagul_learn.round_selection import RoundSelection

    def other(config, task, out):
        best = ValueNetwork.load(out / "network_best.pt").casadi_parameters()
        for path, rec in kept_rounds(out):
            if not np.array_equal(ValueNetwork.load(path).casadi_parameters(), best):
                keys = ("round", "solves_before_round", "episode_successes", "episodes")
                return RoundSelection(**{k: rec[k] for k in keys}, selection_success=0.0, selection_episodes=1)
        pytest.fail("every kept round is the best collector's network")

    monkeypatch.setattr(training, "select_kept_round", other)
    run = _selecting_run(tmp_path, runtime__snapshots=(18,))
    best = json.loads((run / "network_best.json").read_text())
    chosen = ValueNetwork.load(run / "rounds" / f"network_{best['solves_before_round']}.pt").casadi_parameters()
    for name in ("network.pt", "network_18.pt", "network_best.pt"):
        np.testing.assert_array_equal(ValueNetwork.load(run / name).casadi_parameters(), chosen)
