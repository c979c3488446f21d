"""ValueNetwork: torch <-> CasADi equivalence, save/load round trip, clear errors for bad files."""

from __future__ import annotations

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
    from seagul_control import _io

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
