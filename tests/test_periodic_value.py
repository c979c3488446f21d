"""Value networks over periodic angles: ``(cos q, sin q)`` inputs in torch and in every CasADi form.

A network built with ``periodic`` (the task's :attr:`~seagul_envs.tasks.base.Task.periodic`) must be exactly
2 pi-periodic in those coordinates, its CasADi forms must equal its torch forward (float64) at angles far outside
``[-pi, pi)``, its gradients must match finite differences, and its file must record the indices while files without
the key keep loading as plain networks.
"""

from __future__ import annotations

import dataclasses

import casadi as ca
import numpy as np
import pytest
import torch

from seagul_envs import make_task
from seagul_learn.ensemble import ValueEnsemble
from seagul_learn.value_casadi import num_parameters
from seagul_learn.value_files import read_value_file
from seagul_learn.value_network import ValueNetwork

NX = 4
PERIODIC = (0, 2)


def _trained_like(net: ValueNetwork | ValueEnsemble, seed: int = 0) -> None:
    """Non-trivial statistics and weights (random, not the initial ones), so every term of the forms is exercised."""
    rng = np.random.default_rng(seed)
    n = 200
    x = rng.normal(size=(n, NX)) * [3.0, 2.0, 5.0, 0.5] + [0.3, -1.0, 2.0, 0.1]
    tau = rng.uniform(0.5, 3.0, n)
    net.set_normalization(x, tau, rng.normal(size=n) * 4 + 10)
    with torch.no_grad():
        for p in net.parameters():
            p.add_(torch.tensor(rng.normal(size=tuple(p.shape)) * 0.3))


def _net(hidden: tuple[int, ...] = (7, 5), seed: int = 1) -> ValueNetwork:
    net = ValueNetwork(NX, hidden, task_name="t", seed=seed, periodic=PERIODIC)
    _trained_like(net)
    return net


def _random_inputs(rng: np.random.Generator, n: int = 20) -> tuple[np.ndarray, np.ndarray]:
    x = rng.uniform(-25.0, 25.0, size=(n, NX))  # angles up to four turns either way
    return x, rng.uniform(0.2, 4.0, n)


def test_config_features_and_parameter_count() -> None:
    net = _net()
    assert net.periodic == PERIODIC and net.config.n_features == NX + 2 + 1
    assert net.linear_layers[0].in_features == NX + 2 + 1
    # The statistics keep one entry per raw input; a periodic coordinate's are mean 0, std 1.
    assert net.in_mean.shape == (NX + 1,)
    assert net.in_mean[list(PERIODIC)].tolist() == [0.0, 0.0] and net.in_std[list(PERIODIC)].tolist() == [1.0, 1.0]
    assert net.num_casadi_parameters == net.casadi_parameters().size == num_parameters(NX, (7, 5), 0, PERIODIC)
    assert num_parameters(NX, (7, 5), 0, PERIODIC) == num_parameters(NX, (7, 5), 0) + 2 * 7
    assert ValueNetwork(NX, (3,), periodic=[2, 0]).periodic == (0, 2)
    for bad in ([4], [0, 0], [-1], ["a"], [True]):
        with pytest.raises(ValueError, match="periodic"):
            ValueNetwork(NX, (3,), periodic=bad)


def test_torch_value_is_periodic_and_nontrivial() -> None:
    net = _net()
    rng = np.random.default_rng(2)
    x, tau = _random_inputs(rng)
    v = net.predict(x, tau)
    for k in (-3, -1, 1, 2, 5):
        shifted = x.copy()
        shifted[:, 0] += 2 * np.pi * k
        shifted[:, 2] -= 2 * np.pi * (k + 1)
        np.testing.assert_allclose(net.predict(shifted, tau), v, rtol=0, atol=1e-9)
    # Not periodic in the other coordinates, and not constant in the periodic ones.
    moved = x.copy()
    moved[:, 1] += 2 * np.pi
    assert np.max(np.abs(net.predict(moved, tau) - v)) > 1e-3
    half = x.copy()
    half[:, 0] += np.pi
    assert np.max(np.abs(net.predict(half, tau) - v)) > 1e-3


@pytest.mark.parametrize("form", ["scalar", "matrix"])
def test_casadi_forms_match_torch_far_from_zero(form: str) -> None:
    net = _net()
    fn = net.casadi_function(form)  # type: ignore[arg-type]
    theta = net.casadi_parameters()
    rng = np.random.default_rng(3)
    x, tau = _random_inputs(rng)
    assert np.max(np.abs(x[:, list(PERIODIC)])) > 10
    v = net.predict(x, tau)
    got = np.array([float(fn(x[i], tau[i], theta)) for i in range(x.shape[0])])
    np.testing.assert_allclose(got, v, rtol=0, atol=1e-9)
    # periodic in CasADi too
    shifted = x.copy()
    shifted[:, 2] += 6 * np.pi
    got_shifted = np.array([float(fn(shifted[i], tau[i], theta)) for i in range(x.shape[0])])
    np.testing.assert_allclose(got_shifted, v, rtol=0, atol=1e-9)


def test_gradients_match_finite_differences_and_casadi() -> None:
    net = _net()
    rng = np.random.default_rng(4)
    x, tau = _random_inputs(rng, 6)
    _, gx, gt = net.value_and_grad(x, tau)
    h = 1e-6
    for i in range(NX):
        e = np.zeros(NX)
        e[i] = h
        fd = (net.predict(x + e, tau) - net.predict(x - e, tau)) / (2 * h)
        np.testing.assert_allclose(gx[:, i], fd, rtol=1e-6, atol=1e-6)
    fd_tau = (net.predict(x, tau + h) - net.predict(x, tau - h)) / (2 * h)
    np.testing.assert_allclose(gt, fd_tau, rtol=1e-6, atol=1e-6)
    xs, ts = ca.SX.sym("x", NX), ca.SX.sym("tau")
    v = net.casadi_function("scalar")(xs, ts, ca.DM(net.casadi_parameters()))
    grad = ca.Function("g", [xs, ts], [ca.gradient(v, xs)])
    for k in range(x.shape[0]):
        np.testing.assert_allclose(np.asarray(grad(x[k], tau[k])).ravel(), gx[k], rtol=0, atol=1e-9)


def test_taylor_form_equals_value_gradient_and_hessian() -> None:
    net = _net()
    theta = ca.DM(net.casadi_parameters())
    taylor = net.casadi_function("taylor")
    model = net.casadi_function("taylor_model")
    xs, ts = ca.SX.sym("x", NX), ca.SX.sym("tau")
    v = net.casadi_function("scalar")(xs, ts, theta)
    hess, grad = ca.hessian(v, xs)
    exact = ca.Function("e", [xs, ts], [v, grad, hess])
    rng = np.random.default_rng(5)
    x, tau = _random_inputs(rng, 8)
    for k in range(x.shape[0]):
        c = np.asarray(taylor(x[k], tau[k], theta)).ravel()
        v_ref, g_ref, h_ref = (np.asarray(a) for a in exact(x[k], tau[k]))
        np.testing.assert_allclose(c[0], v_ref, rtol=0, atol=1e-9)
        np.testing.assert_allclose(c[1 : 1 + NX], g_ref.ravel(), rtol=0, atol=1e-9)
        np.testing.assert_allclose(c[1 + NX :].reshape(NX, NX, order="F"), h_ref, rtol=0, atol=1e-8)
        # the quadratic model equals V at x0 and to second order nearby
        assert abs(float(model(x[k], x[k], c)) - v_ref) < 1e-9
        d = rng.normal(size=NX) * 1e-3
        near = float(net.predict((x[k] + d)[None], tau[k])[0])
        assert abs(float(model(x[k] + d, x[k], c)) - near) < 1e-6


def test_save_load_round_trip_records_periodic(tmp_path) -> None:
    net = _net()
    path = net.save(tmp_path / "p.pt")
    assert read_value_file(path)["config"]["periodic"] == list(PERIODIC)
    back = ValueNetwork.load(path)
    assert isinstance(back, ValueNetwork) and back.periodic == PERIODIC
    x, tau = _random_inputs(np.random.default_rng(6))
    np.testing.assert_array_equal(back.predict(x, tau), net.predict(x, tau))
    np.testing.assert_array_equal(back.casadi_parameters(), net.casadi_parameters())


def test_file_without_periodic_key_loads_as_plain_network(tmp_path) -> None:
    plain = ValueNetwork(NX, (5,), task_name="t", seed=3)
    _trained_like(plain)
    path = plain.save(tmp_path / "plain.pt")
    payload = read_value_file(path)
    assert "periodic" not in payload["config"]  # files of plain networks keep their layout
    back = ValueNetwork.load(path)
    assert back.periodic == () and back.linear_layers[0].in_features == NX + 1
    x, tau = _random_inputs(np.random.default_rng(7))
    np.testing.assert_array_equal(back.predict(x, tau), plain.predict(x, tau))


def test_renormalize_keeps_the_function() -> None:
    net = _net()
    rng = np.random.default_rng(8)
    x, tau = _random_inputs(rng, 50)
    before = net.predict(x, tau)
    net.renormalize(x * 0.5 + 1.0, tau + 1.0, rng.normal(size=50) * 10 - 3)
    assert net.in_mean[list(PERIODIC)].tolist() == [0.0, 0.0] and net.in_std[list(PERIODIC)].tolist() == [1.0, 1.0]
    np.testing.assert_allclose(net.predict(x, tau), before, rtol=0, atol=1e-9)


def test_ensemble_members_share_periodic_inputs(tmp_path) -> None:
    ens = ValueEnsemble(NX, (6,), members=3, pessimism=0.7, task_name="t", seed=2, periodic=PERIODIC)
    _trained_like(ens)
    assert ens.periodic == PERIODIC and all(m.periodic == PERIODIC for m in ens.networks)
    rng = np.random.default_rng(9)
    x, tau = _random_inputs(rng, 10)
    shifted = x.copy()
    shifted[:, 0] -= 4 * np.pi
    np.testing.assert_allclose(ens.predict(shifted, tau), ens.predict(x, tau), rtol=0, atol=1e-9)
    theta = ens.casadi_parameters()
    fn = ens.casadi_function("matrix")
    members = np.stack([m.predict(x, tau) for m in ens.networks])
    expected = members.mean(0) + 0.7 * (np.sqrt(members.var(0) + ens.SPREAD_EPS**2) - ens.SPREAD_EPS)
    got = np.array([float(fn(x[i], tau[i], theta)) for i in range(x.shape[0])])
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)
    back = ValueNetwork.load(ens.save(tmp_path / "e.pt"))
    assert isinstance(back, ValueEnsemble) and back.periodic == PERIODIC
    np.testing.assert_array_equal(back.predict(x, tau), ens.predict(x, tau))
    assert ens.subset([0, 2]).periodic == PERIODIC


def test_trainer_builds_the_network_with_the_task_periodic_angles() -> None:
    from seagul_learn.config import TrainConfig
    from seagul_learn.fitting import make_network

    task = make_task("dmc_pendulum")
    if not task.periodic:  # the suite tasks declare their hinge angles; older checkouts may not yet
        task = dataclasses.replace(task, periodic=(0,))
    net = make_network(TrainConfig(task=task), task)
    assert isinstance(net, ValueNetwork) and net.periodic == task.periodic == (0,)
    acrobot = make_task("acrobot")
    assert make_network(TrainConfig(task=acrobot), acrobot).periodic == acrobot.periodic
