"""The learned value function ``Vhat(x, tau)``: a small tanh MLP with its standardisation stored inside.

The network maps ``z = ([x, tau] - in_mean) / in_std`` through ``tanh`` hidden layers to ``y`` and returns
``V = y * out_std + out_mean``; the four statistics are buffers (set once from data with
:meth:`ValueNetwork.set_normalization`), so a saved file is self-contained. Everything is float64: the MPC and the
gradient checks need it.

A network over robots, ``Vhat(x, tau, theta)`` (``n_params > 0``: the task's varying physical parameters,
docs/reference/spec.md §14), takes ``[x, tau, theta]``. Where ``theta`` is not given it uses its *condition*
(:meth:`ValueNetwork.condition`, default the values it was built for): the robot an MPC plans for. The condition is the
last entry block of the CasADi parameters, so an MPC built once re-plans for another robot (an estimate) with
``set_value_function`` alone. A network with ``theta_features`` (:class:`ValueNetworkConfig`) sees, instead of
``theta``, the logarithms of the products of parameters the dynamics depend on: the glider's forces depend on the air
density and the two plate areas only through ``rho * S_w`` and ``rho * S_e``, so robots along the remaining direction
fly identically and get one value. The condition stays the robot itself; the CasADi parameters carry its features.

A network for a task with periodic angles (``periodic``, :attr:`seagul_envs.tasks.base.Task.periodic`; the trainer
passes the task's) feeds ``(cos q, sin q)`` of each periodic coordinate ``q`` to its first layer instead of the
standardised ``q``: ``Vhat`` is then exactly 2 pi-periodic in ``q``, as the problem's value is, and an angle that has
spun several turns is as well inside the training data as its wrapped self. The features are bounded, so they are not
standardised (the statistics' entries of a periodic coordinate stay mean 0, std 1, so gradient losses and distances
measured in standardised units see the angle in radians). The CasADi forms compute the same features.

For NLPs the same network is available as a CasADi expression (:meth:`casadi_function`) whose parameters
``theta`` are the flattened normalisation and weights in a layout fixed by the architecture, so an MPC built once
accepts any newly trained network of the same shape (it implements
:class:`seagul_control.value_function.CasadiValueFunction`).

``save``/``load`` read and write the file format of :mod:`seagul_learn.value_files` (one ``torch.save`` dict that
loads with ``weights_only=True``, tagged with the trained task's fingerprint). The CasADi graphs are built by
:mod:`seagul_learn.value_casadi`, the ensemble of networks is :class:`seagul_learn.ensemble.ValueEnsemble`; their
names used to live here and still import from here (``ValueEnsemble``, ``ValueModel``, ``ValueNetworkFileError``,
``FORMAT_TAG``, ``ENSEMBLE_FORMAT_TAG``, ``FORMAT_VERSION``, ``CasadiForm``: the same objects, no warning).
"""

from __future__ import annotations

import itertools
import os
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeAlias, cast

import casadi as ca
import numpy as np
import torch
from torch import nn

from seagul_envs.tasks.parameters import log_features
from seagul_learn.value_casadi import CasadiForm, casadi_network, check_form, check_periodic, num_parameters
from seagul_learn.value_files import (
    ENSEMBLE_FORMAT_TAG,
    FORMAT_TAG,
    FORMAT_VERSION,
    ValueNetworkFileError,
    check_version,
    read_value_file,
    write_value_file,
)

if TYPE_CHECKING:
    from seagul_learn.ensemble import ValueEnsemble, ValueModel

__all__ = [
    "DTYPE",
    "ENSEMBLE_FORMAT_TAG",
    "FORMAT_TAG",
    "FORMAT_VERSION",
    "CasadiForm",
    "ValueEnsemble",
    "ValueModel",
    "ValueNetwork",
    "ValueNetworkConfig",
    "ValueNetworkFileError",
]

DTYPE = torch.float64
_MIN_STD = 1e-8


@dataclass(frozen=True)
class ValueNetworkConfig:
    """Architecture of a :class:`ValueNetwork` (everything needed to rebuild it)."""

    nx: int
    """State dimension (the input is ``[x, tau]``, so ``nx + 1`` features)."""
    hidden: tuple[int, ...] = (32,)
    """Widths of the tanh hidden layers (paper: one layer of 32)."""
    n_params: int = 0
    """Physical parameters ``theta`` among the inputs (``[x, tau, theta]``); 0: ``Vhat(x, tau)``."""
    periodic: tuple[int, ...] = ()
    """State indices of 2 pi-periodic angles, fed as ``(cos q, sin q)`` (sorted; () for none)."""
    theta_features: tuple[tuple[float, ...], ...] = ()
    """The robot's features instead of ``theta`` itself (``n_params`` rows of ``n_params`` exponents ``E``; ()
    feeds ``theta``): feature ``i`` is ``sum_j E_ij log theta_j``, the logarithm of a product of powers of the
    parameters. The task's :attr:`~seagul_envs.tasks.parameters.ParameterSpace.invariants` give the products
    the dynamics depend on, so robots that move identically get the same value (zero rows: unused inputs)."""

    @property
    def n_features(self) -> int:
        """Width of the first layer's input: ``nx + len(periodic) + 1 + n_params``."""
        return self.nx + len(self.periodic) + 1 + self.n_params


def _check_features(rows: Sequence[Sequence[float]], n_params: int) -> tuple[tuple[float, ...], ...]:
    """``theta_features`` as a tuple of rows; raises ValueError unless () or ``n_params`` rows of ``n_params``
    finite exponents."""
    out = tuple(tuple(float(v) for v in row) for row in rows)
    if not out:
        return ()
    arr = np.array(out, dtype=float) if all(len(r) == len(out[0]) for r in out) else None
    if n_params < 1 or arr is None or arr.shape != (n_params, n_params) or not np.all(np.isfinite(arr)):
        raise ValueError(
            f"theta_features must be {n_params} rows of {n_params} finite exponents (a network over robots), got {out}"
        )
    return out


_Forward: TypeAlias = Callable[..., torch.Tensor]


def _predict(forward: _Forward, x: Any, tau: Any, theta: Any = None) -> np.ndarray:
    """NumPy values of ``forward`` for a batch (``theta``: None, one vector or one row per state)."""
    x_arr = np.atleast_2d(np.asarray(x, dtype=np.float64))
    tau_arr = np.broadcast_to(np.asarray(tau, dtype=np.float64).reshape(-1), (x_arr.shape[0],))
    extra = () if theta is None else (torch.as_tensor(np.asarray(theta, dtype=np.float64)),)
    with torch.no_grad():
        return forward(torch.tensor(x_arr), torch.tensor(np.array(tau_arr)), *extra).numpy()


def _derivatives(forward: _Forward, x: Any, tau: Any, theta: Any = None) -> tuple[np.ndarray, ...]:
    """``(V, dV/dx, dV/dtau)`` of ``forward`` for a batch (or a single ``x`` of shape ``(nx,)``), as NumPy; with
    ``theta`` (one vector or one row per state) also ``dV/dtheta``."""
    x_arr = np.asarray(x, dtype=np.float64)
    single = x_arr.ndim == 1
    x_arr = np.atleast_2d(x_arr)
    n = x_arr.shape[0]
    tau_arr = np.broadcast_to(np.asarray(tau, dtype=np.float64).reshape(-1), (n,))
    inputs = [torch.tensor(x_arr, dtype=DTYPE, requires_grad=True)]
    inputs.append(torch.tensor(np.array(tau_arr), dtype=DTYPE, requires_grad=True))
    if theta is not None:
        th_arr = np.asarray(theta, dtype=np.float64)
        th_arr = np.broadcast_to(th_arr, (n, th_arr.shape[-1])) if th_arr.ndim <= 1 else th_arr
        inputs.append(torch.tensor(np.array(th_arr), dtype=DTYPE, requires_grad=True))
    with torch.enable_grad():
        v = forward(*inputs)
        grads = torch.autograd.grad(v.sum(), inputs)
    out = (v.detach().numpy(), *(g.numpy() for g in grads))
    return tuple(o[0] for o in out) if single else out


def _value_and_grad(forward: _Forward, x: Any, tau: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(V, dV/dx, dV/dtau)`` of ``forward`` for a batch (or a single ``x`` of shape ``(nx,)``), as NumPy."""
    v, gx, gt = _derivatives(forward, x, tau)
    return v, gx, gt


def _value_and_grads(model: Any, x: Any, tau: Any, theta: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(V, dV/dx, dV/dtau, dV/dtheta)`` of a network (ensemble) over robots at ``theta`` (None: its condition)."""
    if not model.n_params:
        raise ValueError("value_and_grads needs a network over physical parameters (n_params > 0)")
    v, gx, gt, gp = _derivatives(model.forward, x, tau, model.theta if theta is None else theta)
    return v, gx, gt, gp


class ValueNetwork(nn.Module):
    """``Vhat(x, tau)``: standardised inputs, tanh hidden layers, a linear output, de-standardised value."""

    # Buffers registered in ``__init__`` (declared for the type checker: ``nn.Module.__getattr__`` is untyped).
    in_mean: torch.Tensor
    in_std: torch.Tensor
    out_mean: torch.Tensor
    out_std: torch.Tensor
    theta_condition: torch.Tensor  # networks over robots only (n_params > 0)

    def __init__(
        self,
        nx: int,
        hidden: Sequence[int] = (32,),
        task_name: str = "",
        seed: int | None = None,
        n_params: int = 0,
        theta: Any = None,
        task_fingerprint: str = "",
        periodic: Sequence[int] = (),
        theta_features: Sequence[Sequence[float]] = (),
    ) -> None:
        """Build the network; ``seed`` makes the initial weights reproducible without touching global RNG state.
        ``periodic``: state indices of 2 pi-periodic angles (the task's :attr:`~seagul_envs.tasks.base.Task.periodic`),
        fed as ``(cos q, sin q)``.
        ``n_params > 0`` adds the physical parameters to the inputs; ``theta`` is the initial condition (default
        zeros; the trainer sets the task's values). ``task_fingerprint``: the
        :meth:`~seagul_envs.tasks.base.Task.fingerprint` of the task the network is trained for ("" if unknown): an
        MPC then refuses the network for a same-named variant of that task. ``theta_features``: the exponent rows
        of :attr:`ValueNetworkConfig.theta_features` (a network over robots only)."""
        super().__init__()
        if int(nx) < 1:
            raise ValueError(f"nx must be >= 1, got {nx}")
        if int(n_params) < 0:
            raise ValueError(f"n_params must be >= 0, got {n_params}")
        hidden = tuple(int(h) for h in hidden)
        if not hidden or any(h < 1 for h in hidden):
            raise ValueError(f"hidden widths must be a non-empty sequence of positive integers, got {hidden}")
        self.config = ValueNetworkConfig(
            nx=int(nx),
            hidden=hidden,
            n_params=int(n_params),
            periodic=check_periodic(int(nx), periodic),
            theta_features=_check_features(theta_features, int(n_params)),
        )
        k = self.config.n_params
        self._exponents = (
            torch.tensor(self.config.theta_features, dtype=DTYPE)
            if self.config.theta_features
            else torch.zeros((k, k), dtype=DTYPE)
        )
        self.task_name = str(task_name)
        self.task_fingerprint = str(task_fingerprint)
        """Fingerprint of the task the network is trained for ("" if unknown; stored in its file)."""
        n_in = self.config.nx + 1 + self.config.n_params
        widths = [self.config.n_features, *hidden, 1]
        with torch.random.fork_rng(devices=[]):
            if seed is not None:
                torch.manual_seed(int(seed))
            self.layers = nn.ModuleList(nn.Linear(a, b, dtype=DTYPE) for a, b in itertools.pairwise(widths))
        self.register_buffer("in_mean", torch.zeros(n_in, dtype=DTYPE))
        self.register_buffer("in_std", torch.ones(n_in, dtype=DTYPE))
        self.register_buffer("out_mean", torch.zeros(1, dtype=DTYPE))
        self.register_buffer("out_std", torch.ones(1, dtype=DTYPE))
        if self.config.n_params:
            # Only networks over robots carry it, so files of plain networks keep their layout.
            self.register_buffer("theta_condition", torch.zeros(self.config.n_params, dtype=DTYPE))
            if theta is not None:
                self.condition(theta)
        elif theta is not None:
            raise ValueError("theta given to a network without physical parameters (n_params=0)")

    # ------------------------------------------------------------------ torch
    @property
    def nx(self) -> int:
        """State dimension."""
        return self.config.nx

    @property
    def n_params(self) -> int:
        """Number of physical parameters among the inputs (0: ``Vhat(x, tau)``)."""
        return self.config.n_params

    @property
    def periodic(self) -> tuple[int, ...]:
        """State indices fed as ``(cos q, sin q)`` (() for none)."""
        return self.config.periodic

    @torch.no_grad()
    def condition(self, theta: Any) -> None:
        """Set the robot ``theta`` used wherever none is given (``forward`` without ``theta``, the CasADi
        parameters an MPC plans with). Raises ValueError for a network without parameters or a malformed vector."""
        if not self.n_params:
            raise ValueError("condition() needs a network over physical parameters (n_params > 0)")
        arr = np.asarray(theta, dtype=np.float64)
        if arr.shape != (self.n_params,) or not np.all(np.isfinite(arr)):
            raise ValueError(f"theta must be {self.n_params} finite numbers, got {np.asarray(theta).tolist()}")
        self.robot_features(arr)  # refuses a robot a network fed its logarithms cannot take
        self.theta_condition.copy_(torch.tensor(arr))

    def robot_features(self, theta: Any) -> np.ndarray:
        """What the first layer sees of the robot(s) ``theta`` (one vector or one row each): ``theta`` itself, or
        with :attr:`ValueNetworkConfig.theta_features` ``log(theta) @ E.T`` (``theta`` must be positive)."""
        if not self.config.theta_features:
            return np.asarray(theta, dtype=np.float64)
        return log_features(theta, self.config.theta_features)

    @property
    def theta(self) -> np.ndarray:
        """The condition (:meth:`condition`); empty without physical parameters."""
        if not self.n_params:
            return np.zeros(0)
        return self.theta_condition.detach().numpy().copy()

    def _inputs(self, x: torch.Tensor, tau: torch.Tensor, theta: torch.Tensor | None = None) -> torch.Tensor:
        x = torch.as_tensor(x, dtype=DTYPE)
        tau = torch.as_tensor(tau, dtype=DTYPE)
        if x.ndim != 2 or x.shape[1] != self.nx:
            raise ValueError(f"x must have shape (batch, {self.nx}), got {tuple(x.shape)}")
        tau = tau.reshape(-1)
        if tau.shape[0] != x.shape[0]:
            raise ValueError(f"tau must have one entry per row of x ({x.shape[0]}), got shape {tuple(tau.shape)}")
        if not self.n_params:
            if theta is not None:
                raise ValueError("theta given to a network without physical parameters (n_params=0)")
            return torch.cat([x, tau[:, None]], dim=1)
        th = self.theta_condition if theta is None else torch.as_tensor(theta, dtype=DTYPE)
        if th.ndim == 1:
            th = th[None, :].expand(x.shape[0], -1)
        if th.shape != (x.shape[0], self.n_params):
            raise ValueError(
                f"theta must have shape ({self.n_params},) or ({x.shape[0]}, {self.n_params}), got {tuple(th.shape)}"
            )
        if self.config.theta_features:
            th = torch.log(th) @ self._exponents.T  # NaN for a non-positive theta, refused where theta enters
        return torch.cat([x, tau[:, None], th], dim=1)

    def forward_standardized(
        self, x: torch.Tensor, tau: torch.Tensor, theta: torch.Tensor | None = None
    ) -> torch.Tensor:
        """The standardised output ``y = (Vhat - out_mean) / out_std``, shape ``(batch,)`` (the training target)."""
        raw = self._inputs(x, tau, theta)
        h = (raw - self.in_mean) / self.in_std
        if self.periodic:
            cols: list[torch.Tensor] = []
            for i in range(self.nx):
                cols += [torch.cos(raw[:, i]), torch.sin(raw[:, i])] if i in self.periodic else [h[:, i]]
            h = torch.cat([torch.stack(cols, dim=1), h[:, self.nx :]], dim=1)
        layers = self.linear_layers
        for layer in layers[:-1]:
            h = torch.tanh(layer(h))
        return layers[-1](h)[:, 0]

    @property
    def linear_layers(self) -> list[nn.Linear]:
        """The affine layers in order (``self.layers`` typed: ``nn.ModuleList`` yields plain modules)."""
        return cast("list[nn.Linear]", list(self.layers))

    def forward(self, x: torch.Tensor, tau: torch.Tensor, theta: torch.Tensor | None = None) -> torch.Tensor:
        """``Vhat`` for a batch: ``x`` of shape ``(batch, nx)``, ``tau`` of shape ``(batch,)``, ``theta`` (networks
        over robots) ``(n_params,)`` or ``(batch, n_params)``, default the condition; returns ``(batch,)``."""
        return self.forward_standardized(x, tau, theta) * self.out_std + self.out_mean

    def value_and_grad(self, x: Any, tau: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """NumPy helper: ``(Vhat, dVhat/dx, dVhat/dtau)`` for a batch (or a single ``x`` of shape ``(nx,)``); a
        network over robots at its condition."""
        return _value_and_grad(self.forward, x, tau)

    def value_and_grads(
        self, x: Any, tau: Any, theta: Any = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """NumPy helper: ``(Vhat, dVhat/dx, dVhat/dtau, dVhat/dtheta)`` at ``theta`` (default the condition)."""
        return _value_and_grads(self, x, tau, theta)

    def predict(self, x: Any, tau: Any, theta: Any = None) -> np.ndarray:
        """NumPy values ``Vhat(x, tau)`` (``Vhat(x, tau, theta)``) for a batch."""
        return _predict(self.forward, x, tau, theta)

    def _feature_rows(self, x: np.ndarray, tau: np.ndarray, theta: np.ndarray | None) -> np.ndarray:
        rows = [np.asarray(x, dtype=np.float64), np.asarray(tau, dtype=np.float64).reshape(-1, 1)]
        if self.n_params:
            th = self.robot_features(self.theta if theta is None else theta)
            rows.append(np.broadcast_to(th, (rows[0].shape[0], self.n_params)) if th.ndim == 1 else th)
        elif theta is not None:
            raise ValueError("theta given to a network without physical parameters (n_params=0)")
        try:
            return np.column_stack(rows)
        except ValueError:
            raise ValueError(
                f"normalisation data must be x (n, {self.nx}), tau (n,), theta (n, {self.n_params}) with one row each"
            ) from None

    @torch.no_grad()
    def set_normalization(
        self, x: np.ndarray, tau: np.ndarray, value: np.ndarray, theta: np.ndarray | None = None
    ) -> None:
        """Set the input/output standardisation from data (constant features get std 1, not 0); ``theta`` one row
        per sample for a network over robots (default: its condition, a constant feature)."""
        inputs = self._feature_rows(x, tau, theta)
        value = np.asarray(value, dtype=np.float64).reshape(-1)
        n_in = self.nx + 1 + self.n_params
        if inputs.shape[1] != n_in or inputs.shape[0] != value.shape[0] or value.size == 0:
            raise ValueError(f"normalisation data must be x (n, {self.nx}), tau (n,), value (n,) with n >= 1")
        if not (np.all(np.isfinite(inputs)) and np.all(np.isfinite(value))):
            raise ValueError("normalisation data contains NaN or inf")
        in_std = inputs.std(axis=0)
        out_std = value.std()
        in_mean = inputs.mean(axis=0)
        in_std = np.where(in_std > _MIN_STD, in_std, 1.0)
        periodic = list(self.periodic)
        in_mean[periodic], in_std[periodic] = 0.0, 1.0  # fed as (cos, sin): unused, and radians in gradient losses
        self.in_mean.copy_(torch.tensor(in_mean))
        self.in_std.copy_(torch.tensor(in_std))
        self.out_mean.fill_(float(value.mean()))
        self.out_std.fill_(float(out_std) if out_std > _MIN_STD else 1.0)

    @torch.no_grad()
    def renormalize(self, x: np.ndarray, tau: np.ndarray, value: np.ndarray, theta: np.ndarray | None = None) -> None:
        """Move the standardisation to new data **without changing the function** ``Vhat`` (PopArt's "preserving
        outputs precisely", van Hasselt et al. 2016, applied to both ends).

        With old statistics ``(m, s)`` and new ones ``(m', s')`` of the inputs, the first layer ``W z + b`` with
        ``z = (u - m) / s`` becomes ``W' = W diag(s' / s)``, ``b' = b + W ((m' - m) / s)``; with ``(mu, sigma)`` and
        ``(mu', sigma')`` of the value, the last layer becomes ``W' = W sigma / sigma'``,
        ``b' = (b sigma + mu - mu') / sigma'``. Training then sees targets in the new units, so labels far outside
        the range of the data the statistics first came from (closed-loop tails) no longer sit tens of standard
        deviations out, and the network keeps everything it has learned. The ``(cos, sin)`` inputs of periodic
        coordinates are not standardised, so their columns stay as they are.
        """
        old_in_mean, old_in_std = self.in_mean.clone(), self.in_std.clone()
        old_out_mean, old_out_std = self.out_mean.clone(), self.out_std.clone()
        self.set_normalization(x, tau, value, theta)
        first, last = self.linear_layers[0], self.linear_layers[-1]
        shift, ratio = (self.in_mean - old_in_mean) / old_in_std, self.in_std / old_in_std
        if self.periodic:  # one column per raw input, two per periodic coordinate (whose statistics are unused)
            cols = [j for i in range(self.nx) for j in ((i, i) if i in self.periodic else (i,))]
            index = torch.tensor(cols + list(range(self.nx, self.nx + 1 + self.n_params)))
            standardised = torch.tensor([i not in self.periodic for i in index.tolist()])
            shift = torch.where(standardised, shift[index], torch.zeros((), dtype=DTYPE))
            ratio = torch.where(standardised, ratio[index], torch.ones((), dtype=DTYPE))
        first.bias.add_(first.weight @ shift)
        first.weight.mul_(ratio[None, :])
        last.weight.mul_(old_out_std / self.out_std)
        last.bias.copy_((last.bias * old_out_std + old_out_mean - self.out_mean) / self.out_std)

    # ----------------------------------------------------------------- casadi
    def casadi_parameters(self) -> np.ndarray:
        """``theta``: normalisation then each layer's weight (row-major) and bias, as one float64 vector (then the
        condition's features (:meth:`robot_features`, the condition itself by default), for a network over robots)."""
        parts = [self.in_mean, self.in_std]
        for layer in self.linear_layers:
            parts += [layer.weight.reshape(-1), layer.bias]
        parts += [self.out_mean, self.out_std]
        if self.n_params:
            parts.append(torch.as_tensor(self.robot_features(self.theta), dtype=DTYPE))
        return torch.cat([p.detach().reshape(-1) for p in parts]).numpy().astype(np.float64)

    @property
    def num_casadi_parameters(self) -> int:
        """Length of ``theta``."""
        return num_parameters(self.nx, self.config.hidden, self.n_params, self.periodic)

    def casadi_function(self, form: CasadiForm = "scalar") -> ca.Function:
        """CasADi ``(x[nx], tau[1], theta[n]) -> V[1]``; depends only on the architecture, not on the weights.

        ``form="scalar"`` (default) is an SX graph, what an interpreted, expanded NLP wants; ``form="matrix"`` is
        the same function as an MX graph of matrix-vector products, what compiled code wants: its exact Hessian is
        a few dozen dense products (the MPC's compiled lookahead, 46 kB of C for a 3 x (2 x 64) ensemble, where
        the scalar form's expansion was 30 MB that gcc did not finish in 21 CPU-minutes).

        Two forms serve the condensed MPC solver (``seagul_control.shooting``), which needs the value's derivatives
        in ``x`` only, where CasADi's own Hessian of the matrix form costs tens of evaluations of the network:
        ``form="taylor"`` is ``(x0, tau, theta) -> c`` with ``c = [V, dV/dx, vec(d2V/dx2)]`` at ``(x0, tau)`` from
        hand-derived formulas (MX; for a tanh MLP ``a_l = W_l h_{l-1} + b_l``, ``h_l = tanh(a_l)``, with
        ``A_l = da_l/dx`` forward and the adjoints ``delta_l = dV/dh_l`` backward,
        ``d2V/dx2 = sum_l A_l' diag(delta_l * tanh''(a_l)) A_l``), and ``form="taylor_model"`` is
        ``(x, x0, c) -> V0 + g (x - x0) + 1/2 (x - x0)' H (x - x0)``: together equal to ``V`` to second order in
        ``x`` at ``x = x0``."""
        return casadi_network(self.nx, self.config.hidden, check_form(form), self.n_params, self.periodic)

    def to_casadi(self) -> ca.Function:
        """CasADi ``(x[nx], tau[1]) -> V[1]`` with the current weights embedded as constants."""
        x = ca.SX.sym("x", self.nx)
        tau = ca.SX.sym("tau", 1)
        value = self.casadi_function()(x, tau, ca.DM(self.casadi_parameters()))
        return ca.Function("value_network", [x, tau], [value], ["x", "tau"], ["V"])

    # -------------------------------------------------------------------- i/o
    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the network to ``path`` atomically (temp file + rename); returns the path. The config records
        ``periodic`` only for a network that has periodic coordinates (other files keep their layout)."""
        config: dict[str, Any] = {"nx": self.config.nx, "hidden": list(self.config.hidden), "n_params": self.n_params}
        if self.periodic:
            config["periodic"] = list(self.periodic)
        if self.config.theta_features:  # likewise
            config["theta_features"] = [list(row) for row in self.config.theta_features]
        return write_value_file(path, FORMAT_TAG, self.task_name, config, self, self.task_fingerprint)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> ValueNetwork:
        """Read a file written by :meth:`save` (or :meth:`ValueEnsemble.save
        <seagul_learn.ensemble.ValueEnsemble.save>`, which returns the ensemble); raises
        :class:`~seagul_learn.value_files.ValueNetworkFileError` naming the file and problem."""
        path = Path(path)
        payload = read_value_file(path)
        if payload.get("format") == ENSEMBLE_FORMAT_TAG:
            # Imported here: the ensemble is made of this module's networks (seagul_learn.ensemble imports it).
            from seagul_learn.ensemble import ValueEnsemble

            return ValueEnsemble._from_payload(payload, path)  # type: ignore[return-value]
        if payload.get("format") != FORMAT_TAG:
            raise ValueNetworkFileError(f"{str(path)!r} is not a seagul value network file (no {FORMAT_TAG!r} tag)")
        check_version(payload, path)
        try:
            config = payload["config"]
            net = cls(
                nx=int(config["nx"]),
                hidden=tuple(config["hidden"]),
                task_name=str(payload["task_name"]),
                n_params=int(config.get("n_params", 0)),  # files of networks without robot parameters have none
                task_fingerprint=str(payload.get("task_fingerprint", "")),  # older files have none
                periodic=tuple(config.get("periodic", ())),  # files of networks without periodic angles have none
                theta_features=config.get("theta_features", ()),  # files of networks fed theta itself have none
            )
            net.load_state_dict(payload["state_dict"])
        except Exception as exc:
            raise ValueNetworkFileError(
                f"value network file {str(path)!r} is inconsistent ({type(exc).__name__}: {exc})"
            ) from exc
        return net

    def extra_repr(self) -> str:
        return f"task={self.task_name!r}, config={asdict(self.config)}" + (
            f", fingerprint={self.task_fingerprint}" if self.task_fingerprint else ""
        )


def __getattr__(name: str) -> Any:
    """``ValueEnsemble`` and ``ValueModel``, which live in :mod:`seagul_learn.ensemble` (imported on first use:
    that module imports this one, so it cannot be imported at the top of it)."""
    if name in ("ValueEnsemble", "ValueModel"):
        from seagul_learn import ensemble

        return getattr(ensemble, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
