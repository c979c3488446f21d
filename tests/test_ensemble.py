"""ValueEnsemble: the pessimistic CasADi form equals mean + beta * spread, files round-trip, training trains all."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from toy_problem import ToySolver

from seagul_control.mpc import LimitedLookaheadMPC, MPCOptions
from seagul_envs import make_task
from seagul_learn.training import NetworkConfig, RuntimeConfig, ScheduleConfig, TrainConfig, train
from seagul_learn.value_network import ValueEnsemble, ValueNetwork, ValueNetworkFileError


def _ensemble(pessimism: float = 2.0) -> tuple[ValueEnsemble, np.ndarray, np.ndarray]:
    ens = ValueEnsemble(4, (8,), members=3, pessimism=pessimism, task_name="acrobot", seed=0)
    rng = np.random.default_rng(0)
    x, tau = rng.normal(size=(7, 4)), rng.uniform(0, 5, 7)
    ens.set_normalization(x, tau, rng.normal(size=7))
    return ens, x, tau


def test_casadi_form_is_mean_plus_pessimism_times_spread():
    ens, x, tau = _ensemble()
    fn, theta = ens.casadi_function(), ens.casadi_parameters()
    got = np.array([float(fn(xi, ti, theta)) for xi, ti in zip(x, tau, strict=True)])
    members = np.array([m.predict(x, tau) for m in ens.members])
    mean, std = members.mean(axis=0), members.std(axis=0)
    eps = ValueEnsemble.SPREAD_EPS
    np.testing.assert_allclose(got, mean + 2.0 * (np.sqrt(std**2 + eps**2) - eps), atol=1e-12)
    np.testing.assert_allclose(ens.predict(x, tau), mean, atol=1e-12)
    np.testing.assert_allclose(ens.spread(x, tau), std, atol=1e-12)
    assert len({tuple(m.casadi_parameters()[:20]) for m in ens.members}) == 3  # members differ


def test_gradient_of_the_mean_matches_finite_differences():
    ens, x, tau = _ensemble()
    v, g, _ = ens.value_and_grad(x[0], tau[0])
    h = 1e-6
    fd = np.array(
        [(ens.predict(x[0] + h * e, tau[0]) - ens.predict(x[0] - h * e, tau[0]))[0] / (2 * h) for e in np.eye(4)]
    )
    np.testing.assert_allclose(g, fd, rtol=1e-6, atol=1e-8)
    assert v == pytest.approx(ens.predict(x[0], tau[0])[0])


def test_file_round_trip_through_value_network_load(tmp_path):
    ens, _, _ = _ensemble()
    ens.save(tmp_path / "e.pt")
    back = ValueNetwork.load(tmp_path / "e.pt")
    assert isinstance(back, ValueEnsemble) and back.pessimism == 2.0 and len(back.members) == 3
    np.testing.assert_array_equal(back.casadi_parameters(), ens.casadi_parameters())
    data = torch.load(tmp_path / "e.pt", weights_only=True)
    data["config"]["members"] = 4
    torch.save(data, tmp_path / "bad.pt")
    with pytest.raises(ValueNetworkFileError, match="inconsistent"):
        ValueNetwork.load(tmp_path / "bad.pt")


def test_bad_arguments_are_named():
    with pytest.raises(ValueError, match="members"):
        ValueEnsemble(4, (8,), members=1)
    with pytest.raises(ValueError, match="pessimism"):
        ValueEnsemble(4, (8,), members=2, pessimism=-1.0)
    with pytest.raises(ValueError, match="ensemble"):
        NetworkConfig(ensemble=0)


def test_the_mpc_uses_the_pessimistic_value_and_swaps_weights_without_rebuild():
    task = make_task("acrobot")
    ens, _, _ = _ensemble(pessimism=0.0)
    options = MPCOptions(clamp=False, anchor_goal=False, goal_blend=0.0, jit=False)
    mpc = LimitedLookaheadMPC(task, ens, 2, options, trust_region="none")
    x = task.goal + np.array([0.1, -0.1, 0.0, 0.0])
    mean = mpc.terminal_cost_value(x, 3.0)
    assert mean == pytest.approx(float(ens.predict(x, 3.0)[0]))
    solver = mpc._lookahead.trans._solver
    pessimistic, _, _ = _ensemble(pessimism=5.0)
    mpc.set_value_function(pessimistic)
    assert mpc._lookahead.trans._solver is solver
    assert mpc.terminal_cost_value(x, 3.0) >= mean


def test_training_an_ensemble_trains_every_member(tmp_path):
    task = make_task("acrobot")
    cfg = TrainConfig(
        task="acrobot",
        sampler="uniform",
        budget=8,
        schedule=ScheduleConfig(
            solves_per_round=4, train_steps_per_round=20, batch_size=16, pretrain_solves=4, pretrain_steps=5
        ),
        network=NetworkConfig(hidden=(8,), ensemble=3),
        seed=0,
        runtime=RuntimeConfig(cache_dir=str(tmp_path / "cache"), progress=False),
    )
    result = train(cfg, tmp_path / "run", batch_solver=ToySolver(task), solver_name="toy")
    assert isinstance(result.network, ValueEnsemble)
    fresh = ValueEnsemble(task.nx, (8,), 3, task_name="acrobot", seed=0)
    for trained, init in zip(result.network.members, fresh.members, strict=True):
        assert not np.allclose(trained.casadi_parameters()[12:], init.casadi_parameters()[12:])
    loaded = ValueNetwork.load(tmp_path / "run" / "network.pt")
    np.testing.assert_array_equal(loaded.casadi_parameters(), result.network.casadi_parameters())
    # resume of a finished run gives the same ensemble
    again = train(cfg, tmp_path / "run", resume=True, batch_solver=ToySolver(task), solver_name="toy")
    np.testing.assert_array_equal(again.network.casadi_parameters(), result.network.casadi_parameters())


def test_subset_copies_the_chosen_members_in_order():
    from seagul_learn.value_network import ValueEnsemble

    ens = ValueEnsemble(4, (8,), 4, 0.5, task_name="acrobot", seed=3)
    rng = np.random.default_rng(0)
    x, tau = rng.normal(size=(5, 4)), rng.uniform(0, 5, 5)
    sub = ens.subset([2, 0])
    assert len(sub.members) == 2 and sub.pessimism == 0.5 and sub.task_name == "acrobot"
    np.testing.assert_allclose(sub.members[0].predict(x, tau), ens.members[2].predict(x, tau))
    np.testing.assert_allclose(sub.members[1].predict(x, tau), ens.members[0].predict(x, tau))
    assert ens.subset([1, 3], pessimism=0.0).pessimism == 0.0
    sub.members[0].out_mean.add_(1.0)  # a copy: the candidates are untouched
    assert not np.allclose(sub.members[0].predict(x, tau), ens.members[2].predict(x, tau))
    for bad in ([1], [1, 1], [0, 4]):
        with pytest.raises(ValueError, match="subset"):
            ens.subset(bad)
