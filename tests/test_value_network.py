"""ValueNetwork: torch <-> CasADi equivalence, save/load round trip, clear errors for bad files."""

from __future__ import annotations

import subprocess
import sys

import casadi as ca
import numpy as np
import pytest
import torch

from seagul_control.value_function import CasadiValueFunction
from seagul_learn.value_network import ValueNetwork, ValueNetworkFileError


def _trained_like_network(nx: int = 4, hidden: tuple[int, ...] = (32,), seed: int = 0) -> ValueNetwork:
    """A network with non-trivial weights and normalisation (so a layout mix-up cannot hide)."""
    rng = np.random.default_rng(seed)
    net = ValueNetwork(nx, hidden=hidden, task_name="acrobot", seed=seed)
    with torch.no_grad():
        for p in net.parameters():
            p.copy_(torch.tensor(rng.normal(scale=0.7, size=tuple(p.shape))))
    x = rng.normal(loc=3.0, scale=[0.1, 0.2, 0.5, 1.0][:nx] + [1.0] * max(0, nx - 4), size=(50, nx))
    net.set_normalization(x, rng.uniform(0, 5, size=50), rng.normal(40.0, 12.0, size=50))
    return net


@pytest.mark.parametrize("hidden", [(32,), (8, 5)])
def test_casadi_matches_torch_values_and_gradients(hidden):
    net = _trained_like_network(hidden=hidden)
    rng = np.random.default_rng(1)
    x = rng.normal(3.0, 0.5, size=(20, 4))
    tau = rng.uniform(0, 5, size=20)
    v, gx, gt = net.value_and_grad(x, tau)

    xs, ts = ca.SX.sym("x", 4), ca.SX.sym("t")
    embedded = net.to_casadi()
    grad_fn = ca.Function("g", [xs, ts], [ca.gradient(embedded(xs, ts), xs), ca.gradient(embedded(xs, ts), ts)])
    theta_fn = net.casadi_function()
    theta = net.casadi_parameters()
    assert theta.dtype == np.float64 and theta.shape == (net.num_casadi_parameters,)
    for i in range(20):
        assert float(embedded(x[i], tau[i])) == pytest.approx(v[i], abs=1e-10, rel=1e-12)
        assert float(theta_fn(x[i], tau[i], theta)) == pytest.approx(v[i], abs=1e-10, rel=1e-12)
        g_x, g_t = grad_fn(x[i], tau[i])
        np.testing.assert_allclose(np.asarray(g_x).ravel(), gx[i], rtol=1e-10, atol=1e-10)
        assert float(g_t) == pytest.approx(gt[i], abs=1e-10, rel=1e-10)


def test_autograd_gradient_matches_finite_differences():
    net = _trained_like_network()
    x = np.array([3.0, 2.9, 3.4, 2.5])
    _, gx, gt = net.value_and_grad(x, 2.0)
    eps = 1e-6
    for j in range(4):
        d = np.zeros(4)
        d[j] = eps
        fd = (net.predict(x + d, 2.0)[0] - net.predict(x - d, 2.0)[0]) / (2 * eps)
        assert gx[j] == pytest.approx(fd, rel=1e-6, abs=1e-6)
    assert gt == pytest.approx((net.predict(x, 2.0 + eps)[0] - net.predict(x, 2.0 - eps)[0]) / (2 * eps), rel=1e-6)


def test_casadi_function_is_architecture_only():
    a, b = _trained_like_network(seed=0), _trained_like_network(seed=1)
    assert a.casadi_function() is b.casadi_function()  # one structure: a new network never rebuilds an NLP
    assert not np.allclose(a.casadi_parameters(), b.casadi_parameters())
    x = np.array([3.1, 0.1, 0.2, -0.3])
    assert float(a.casadi_function()(x, 1.0, b.casadi_parameters())) == pytest.approx(b.predict(x, 1.0)[0], abs=1e-10)


def test_implements_the_mpc_protocol():
    assert isinstance(_trained_like_network(), CasadiValueFunction)


def test_save_load_round_trip(tmp_path):
    net = _trained_like_network(hidden=(16, 8))
    path = net.save(tmp_path / "sub" / "net.pt")
    loaded = ValueNetwork.load(path)
    assert loaded.task_name == "acrobot" and loaded.config == net.config
    np.testing.assert_array_equal(loaded.casadi_parameters(), net.casadi_parameters())
    x = np.random.default_rng(0).normal(3, 1, size=(7, 4))
    np.testing.assert_array_equal(loaded.predict(x, 1.5), net.predict(x, 1.5))
    assert list(tmp_path.joinpath("sub").iterdir()) == [path]  # no temp file left behind


def test_failed_save_keeps_the_previous_network(tmp_path, monkeypatch):
    from seagul_control import io as _io

    old, new = _trained_like_network(seed=0), _trained_like_network(seed=1)
    path = old.save(tmp_path / "net.pt")

    def full_disk(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(_io.os, "replace", full_disk)
    with pytest.raises(OSError, match="No space left"):
        new.save(path)
    monkeypatch.undo()
    np.testing.assert_array_equal(ValueNetwork.load(path).casadi_parameters(), old.casadi_parameters())
    assert list(tmp_path.iterdir()) == [path]


def test_load_missing_file(tmp_path):
    with pytest.raises(ValueNetworkFileError, match=r"nope\.pt.*does not exist"):
        ValueNetwork.load(tmp_path / "nope.pt")


def test_load_corrupt_file(tmp_path):
    path = _trained_like_network().save(tmp_path / "net.pt")
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueNetworkFileError, match=r"net\.pt.*(corrupt|unreadable)"):
        ValueNetwork.load(path)


def test_load_foreign_files(tmp_path):
    text = tmp_path / "notes.txt"
    text.write_text("hello")
    with pytest.raises(ValueNetworkFileError, match=r"notes\.txt"):
        ValueNetwork.load(text)
    other = tmp_path / "other.pt"
    torch.save({"weights": torch.zeros(3)}, other)
    with pytest.raises(ValueNetworkFileError, match=r"other\.pt.*not a seagul value network"):
        ValueNetwork.load(other)
    future = tmp_path / "future.pt"
    torch.save({"format": "seagul-value-network", "version": 99}, future)
    with pytest.raises(ValueNetworkFileError, match="version 99"):
        ValueNetwork.load(future)


def test_seeded_initialisation_is_reproducible_and_leaves_global_rng_alone():
    torch.manual_seed(123)
    before = torch.rand(1)
    torch.manual_seed(123)
    a = ValueNetwork(4, seed=5)
    after = torch.rand(1)
    assert torch.equal(before, after)
    np.testing.assert_array_equal(a.casadi_parameters(), ValueNetwork(4, seed=5).casadi_parameters())
    assert not np.array_equal(a.casadi_parameters(), ValueNetwork(4, seed=6).casadi_parameters())


def test_bad_inputs_are_named():
    net = ValueNetwork(4)
    with pytest.raises(ValueError, match=r"x must have shape \(batch, 4\)"):
        net(torch.zeros(3, 5), torch.zeros(3))
    with pytest.raises(ValueError, match="one entry per row"):
        net(torch.zeros(3, 4), torch.zeros(2))
    with pytest.raises(ValueError, match="hidden widths"):
        ValueNetwork(4, hidden=(0,))
    with pytest.raises(ValueError, match="NaN or inf"):
        net.set_normalization(np.full((2, 4), np.nan), np.zeros(2), np.zeros(2))


def test_normalisation_handles_constant_features():
    net = ValueNetwork(2)
    net.set_normalization(np.array([[1.0, 2.0], [3.0, 2.0]]), np.array([5.0, 5.0]), np.array([1.0, 3.0]))
    assert net.in_std.tolist() == [1.0, 1.0, 1.0]
    assert net.out_mean.item() == 2.0 and net.out_std.item() == 1.0


# ------------------------------------------------------------------------------- networks over robots (theta)
def _robot_net(seed: int = 0):
    from seagul_envs.tasks import make_task
    from seagul_learn.value_network import ValueNetwork

    task = make_task("acrobot")
    net = ValueNetwork(4, (16, 8), task_name="acrobot", seed=seed, n_params=6, theta=task.theta)
    rng = np.random.default_rng(seed)
    x, tau = task.sample_x0(rng, 64), rng.uniform(0.5, 5.0, 64)
    theta = task.parameters.sample(rng, 64)
    net.set_normalization(x, tau, rng.normal(20, 5, 64), theta)
    return task, net, rng


def test_network_over_robots_gradients_casadi_form_and_condition():
    import casadi as ca
    import torch

    task, net, rng = _robot_net()
    x, tau = task.sample_x0(rng, 5), rng.uniform(0.5, 5.0, 5)
    theta = task.parameters.sample(rng, 5)
    v, gx, gt, gp = net.value_and_grads(x, tau, theta)
    assert v.shape == (5,) and gx.shape == (5, 4) and gt.shape == (5,) and gp.shape == (5, 6)
    # Central differences in every parameter.
    for j in range(6):
        e = np.zeros(6)
        e[j] = 1e-6
        fd = (net.predict(x, tau, theta + e) - net.predict(x, tau, theta - e)) / 2e-6
        np.testing.assert_allclose(gp[:, j], fd, rtol=1e-6, atol=1e-8)
    # Without theta the network is at its condition (the task's robot) ...
    np.testing.assert_allclose(net.predict(x, tau), net.predict(x, tau, task.theta), rtol=1e-14)
    np.testing.assert_array_equal(net.theta, task.theta)
    # ... and so is its CasADi form, whose last parameters are the condition: re-conditioning re-plans.
    for form in ("scalar", "matrix"):
        fn = net.casadi_function(form)
        assert fn.nnz_in(2) == net.num_casadi_parameters == net.casadi_parameters().size
        got = np.array([float(fn(x[i], tau[i], net.casadi_parameters())) for i in range(5)])
        np.testing.assert_allclose(got, net.predict(x, tau), rtol=1e-12)
    net.condition(theta[0])
    fn = net.casadi_function()
    np.testing.assert_allclose(float(fn(x[0], tau[0], net.casadi_parameters())), net.predict(x[:1], tau[:1], theta[0]))
    # The state gradient of the CasADi form equals torch's at the condition.
    xs = ca.SX.sym("x", 4)
    jac = ca.Function("j", [xs], [ca.jacobian(fn(xs, tau[0], net.casadi_parameters()), xs)])
    np.testing.assert_allclose(np.asarray(jac(x[0])).ravel(), net.value_and_grads(x[0], tau[0])[1], rtol=1e-9)
    assert isinstance(net(torch.tensor(x), torch.tensor(tau)), torch.Tensor)


def test_network_over_robots_renormalizes_saves_and_names_bad_input(tmp_path):
    from seagul_learn.value_network import ValueEnsemble, ValueNetwork

    task, net, rng = _robot_net(1)
    x, tau = task.sample_x0(rng, 8), rng.uniform(0.5, 5.0, 8)
    theta = task.parameters.sample(rng, 8)
    before = net.predict(x, tau, theta)
    net.renormalize(x * 3, tau, rng.normal(500, 50, 8), theta * 1.1)
    np.testing.assert_allclose(net.predict(x, tau, theta), before, rtol=1e-10)
    loaded = ValueNetwork.load(net.save(tmp_path / "robot.pt"))
    assert loaded.n_params == 6
    np.testing.assert_array_equal(loaded.theta, net.theta)
    np.testing.assert_allclose(loaded.predict(x, tau, theta), before, rtol=1e-12)
    plain = ValueNetwork(4, (8,), task_name="acrobot", seed=0)
    assert plain.n_params == 0 and plain.theta.size == 0
    assert ValueNetwork.load(plain.save(tmp_path / "plain.pt")).n_params == 0
    with pytest.raises(ValueError, match="without physical parameters"):
        plain.predict(x, tau, theta)
    with pytest.raises(ValueError, match="needs a network over physical parameters"):
        plain.condition(task.theta)
    with pytest.raises(ValueError, match=r"theta must have shape \(6,\) or \(8, 6\)"):
        net.predict(x, tau, theta[:, :3])
    with pytest.raises(ValueError, match="theta must be 6 finite numbers"):
        net.condition([1.0, np.nan, 1, 1, 1, 1])
    ens = ValueEnsemble(4, (8,), members=2, pessimism=0.0, task_name="acrobot", seed=0, n_params=6, theta=task.theta)
    ens.set_normalization(x, tau, rng.normal(20, 5, 8), theta)
    fn = ens.casadi_function()  # pessimism 0: the CasADi form is the members' mean at their condition
    np.testing.assert_allclose(
        float(fn(x[0], tau[0], ens.casadi_parameters())), ens.predict(x[:1], tau[:1]), rtol=1e-12
    )
    ens.condition(theta[0])
    assert np.allclose(ens.theta, theta[0])
    again = ValueNetwork.load(ens.save(tmp_path / "ens.pt"))
    assert again.n_params == 6
    np.testing.assert_allclose(again.predict(x, tau, theta), ens.predict(x, tau, theta), rtol=1e-12)


def test_the_mpc_plans_with_a_network_over_robots_at_its_condition():
    from seagul_control.mpc import LimitedLookaheadMPC, MPCOptions

    task, net, _ = _robot_net(2)
    mpc = LimitedLookaheadMPC(task, net, 5, MPCOptions(jit=False))
    u, info = mpc.act(np.array([np.pi - 0.2, 0.1, 0.0, 0.0]), 5.0)
    assert info.success and np.all(np.abs(u) <= task.u_high)
    # The MPC evaluates the value at the robot it plans for (the task's own), whatever the network's condition ...
    net.condition(task.parameters.high)
    mpc.set_value_function(net)
    np.testing.assert_array_equal(mpc._vf_theta[-6:], task.theta)
    # ... and set_robot moves it to another robot: parameters only, no rebuild
    mpc.set_robot(task.parameters.high)
    np.testing.assert_array_equal(mpc._vf_theta[-6:], task.parameters.high)
    np.testing.assert_array_equal(net.theta, task.parameters.high)  # the caller's network is not touched


def test_the_ensemble_file_format_and_casadi_graphs_live_in_their_modules_and_still_import_from_value_network():
    """``ValueEnsemble``/``ValueModel`` (:mod:`seagul_learn.ensemble`), the file format
    (:mod:`seagul_learn.value_files`) and the CasADi forms (:mod:`seagul_learn.value_casadi`) are the same objects
    under their old names, without a warning; either module imports first (the ensemble's module imports the
    network's), and the CasADi graphs need no torch (an import of it fails in that interpreter)."""
    import warnings

    from seagul_learn import ensemble, value_casadi, value_files, value_network

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for module, names in {
            ensemble: ("ValueEnsemble", "ValueModel"),
            value_files: ("ValueNetworkFileError", "FORMAT_TAG", "ENSEMBLE_FORMAT_TAG", "FORMAT_VERSION"),
            value_casadi: ("CasadiForm",),
        }.items():
            for name in names:
                assert getattr(value_network, name) is getattr(module, name), name
                assert name in value_network.__all__, name
    with pytest.raises(AttributeError, match="no attribute 'not_a_name'"):
        value_network.not_a_name  # noqa: B018
    for first in ("seagul_learn.ensemble", "seagul_learn.value_network"):
        code = (
            f"import {first}; from seagul_learn.value_network import ValueEnsemble, ValueNetwork; "
            "from seagul_learn.ensemble import ValueEnsemble as E; assert E is ValueEnsemble; "
            "assert ValueEnsemble(2, (4,), 2).networks[0].__class__ is ValueNetwork"
        )
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stderr
    code = (
        "import sys; sys.modules['torch'] = None; from seagul_learn import value_casadi as vc; "
        "f = vc.casadi_network(2, (3,)); assert f.numel_in(2) == vc.num_parameters(2, (3,), 0) == 24"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr


def test_value_files_hold_the_documented_dict_and_refuse_what_is_not_one(tmp_path):
    """The file is one ``torch.save`` dict with the documented keys (read back with ``weights_only=True``); a
    directory, a file holding something other than a dict, and an ensemble file of a future version are refused by
    name."""
    from seagul_learn.ensemble import ValueEnsemble
    from seagul_learn.value_files import ENSEMBLE_FORMAT_TAG, FORMAT_TAG, read_value_file

    net = _trained_like_network()
    payload = read_value_file(net.save(tmp_path / "net.pt"))
    assert set(payload) == {"format", "version", "task_name", "task_fingerprint", "config", "state_dict"}
    assert (payload["format"], payload["version"], payload["config"]) == (
        FORMAT_TAG,
        1,
        {"nx": net.nx, "hidden": list(net.config.hidden), "n_params": 0},
    )
    ens = ValueEnsemble(2, (4,), 3, 0.5, task_name="t", seed=0)
    payload = read_value_file(ens.save(tmp_path / "ens.pt"))
    assert payload["format"] == ENSEMBLE_FORMAT_TAG and payload["config"]["members"] == 3
    assert payload["config"]["pessimism"] == 0.5 and isinstance(ValueNetwork.load(tmp_path / "ens.pt"), ValueEnsemble)
    with pytest.raises(ValueNetworkFileError, match="is a directory"):
        ValueNetwork.load(tmp_path)
    listed = tmp_path / "list.pt"
    torch.save([1, 2], listed)
    with pytest.raises(ValueNetworkFileError, match=r"list\.pt.*not a seagul value network"):
        ValueNetwork.load(listed)
    torch.save({**payload, "version": 2}, tmp_path / "future_ens.pt")
    with pytest.raises(ValueNetworkFileError, match="version 2"):
        ValueNetwork.load(tmp_path / "future_ens.pt")


def test_a_network_fed_the_robots_invariants_gives_identical_robots_one_value(tmp_path):
    """``theta_features``: the first layer sees ``log(theta) @ E.T``; robots with equal features get equal values
    and gradients that agree, in torch and in the CasADi form the MPC plans with (through the condition), and the
    features survive a save and load."""
    from seagul_envs.tasks import make_task

    task = make_task("glider")
    space = task.parameters
    exps = space.feature_exponents()
    net = ValueNetwork(task.nx, (16,), n_params=space.size, theta=task.theta, theta_features=exps, seed=0)
    rng = np.random.default_rng(0)
    x, tau, theta = rng.normal(size=(40, task.nx)), rng.uniform(0.5, 1.0, 40), space.sample(rng, 40)
    net.set_normalization(x, tau, rng.normal(size=40), theta)
    along = theta * np.array([1.0, 1 / 1.08, 1 / 1.08, 1.08])
    np.testing.assert_allclose(net.predict(x, tau, along), net.predict(x, tau, theta), rtol=1e-12, atol=1e-12)
    assert net.in_std[-1] == 1.0  # the zero row: a constant feature
    # The same network fed theta itself tells these robots apart.
    plain = ValueNetwork(task.nx, (16,), n_params=space.size, theta=task.theta, seed=0)
    plain.set_normalization(x, tau, rng.normal(size=40), theta)
    assert not np.allclose(plain.predict(x, tau, along), plain.predict(x, tau, theta))
    # dV/dtheta by finite differences, and zero along the direction the dynamics do not see.
    _, _, _, g = net.value_and_grads(x[:3], tau[:3], theta[:3])
    h = 1e-6
    for j in range(space.size):
        e = np.zeros(space.size)
        e[j] = h
        fd = (net.predict(x[:3], tau[:3], theta[:3] + e) - net.predict(x[:3], tau[:3], theta[:3] - e)) / (2 * h)
        np.testing.assert_allclose(g[:, j], fd, rtol=1e-6, atol=1e-8)
    direction = theta[:3] * np.array([0.0, -1.0, -1.0, 1.0])  # d/dc of theta * (1, 1/c, 1/c, c) at c = 1
    np.testing.assert_allclose(np.sum(g * direction, axis=1), 0.0, atol=1e-9)
    # The CasADi form at the condition equals torch, and the condition stays the robot itself.
    net.condition(theta[0])
    np.testing.assert_array_equal(net.theta, theta[0])
    fn = net.to_casadi()
    np.testing.assert_allclose(float(fn(x[0], tau[0])), net.predict(x[:1], tau[:1], theta[0])[0], rtol=1e-12)
    path = net.save(tmp_path / "inv.pt")
    back = ValueNetwork.load(path)
    assert back.config.theta_features == exps
    np.testing.assert_array_equal(back.predict(x, tau, theta), net.predict(x, tau, theta))
    with pytest.raises(ValueError, match="positive"):
        net.condition(np.array([1.0, -0.1, 0.02, 1.2]))
    with pytest.raises(ValueError, match="theta_features must be 4 rows"):
        ValueNetwork(task.nx, (16,), n_params=space.size, theta_features=[[1.0, 0.0]])
    with pytest.raises(ValueError, match="theta_features"):
        ValueNetwork(task.nx, (16,), theta_features=exps)
