"""The CasADi graphs of the learned value function: a network's (and an ensemble's) ``V(x, tau, theta)``.

``theta`` is the flat parameter vector of :meth:`seagul_learn.value_network.ValueNetwork.casadi_parameters`: the
input standardisation, every layer's weights and biases (torch's ``(out, in)`` row-major order), the output
statistics and, for a network over robots, its condition (the robot it plans for). The graph depends only on the
architecture, so it is built once per architecture and form and cached here; an MPC built on it accepts any newly
trained network of the same shape by its parameters alone.

A network built for a task with periodic angles (``periodic``: state indices of 2 pi-periodic coordinates,
:attr:`seagul_envs.tasks.base.Task.periodic`) feeds ``(cos q, sin q)`` of each such coordinate to its first layer in
place of the standardised ``q`` (:func:`periodic_features`), in every form alike, so its ``V`` is exactly 2 pi-periodic
there and an unbounded (spinning) angle never leaves the training data's range. The input statistics keep one entry per
raw input ``[x, tau, condition]`` (mean 0, std 1 at a periodic coordinate, unused), so ``theta`` differs from a plain
network's only in the first layer's width: ``nx + len(periodic) + 1 + n_params`` inputs.

Forms (:data:`CasadiForm`): ``"scalar"`` (SX), ``"matrix"`` (MX of dense products, for compiled code), and the
second-order model of the network in ``x`` the MPC's ``taylor`` terminal cost uses: ``"taylor"`` (value, gradient
and Hessian at ``x0`` by explicit forward and backward passes) and ``"taylor_model"`` (the quadratic they define).
An ensemble's graph (:func:`ensemble_network`) is the members' mean plus ``pessimism`` times their smoothed spread.

This module imports CasADi only (no torch): the networks' weights enter as the numbers ``theta``.
"""

from __future__ import annotations

import itertools
from typing import Any, Literal, TypeAlias, cast

import casadi as ca

__all__ = [
    "CasadiForm",
    "casadi_network",
    "check_form",
    "check_periodic",
    "ensemble_network",
    "num_parameters",
    "periodic_features",
]

CasadiForm: TypeAlias = Literal["scalar", "matrix", "taylor", "taylor_model"]
"""How a value function's CasADi graph is built: ``"scalar"`` (SX) or ``"matrix"`` (MX of dense products), or the
second-order model in ``x``: ``"taylor"`` (its coefficients at ``x0``) and ``"taylor_model"`` (the quadratic)."""


_ENSEMBLE_CACHE: dict[tuple[int, tuple[int, ...], int, str, int, tuple[int, ...]], ca.Function] = {}
_CASADI_CACHE: dict[tuple[int, tuple[int, ...], str, int, tuple[int, ...]], ca.Function] = {}


def check_periodic(nx: int, periodic: Any) -> tuple[int, ...]:
    """``periodic`` as a sorted tuple of distinct state indices in ``0..nx-1`` (ValueError otherwise)."""
    try:
        out = tuple(sorted(int(i) for i in periodic))
        valid = all(not isinstance(i, bool) and int(i) == i for i in periodic)
    except (TypeError, ValueError):
        valid, out = False, ()
    if not valid or len(set(out)) != len(out) or any(not 0 <= i < nx for i in out):
        raise ValueError(f"periodic must hold distinct state indices in 0..{nx - 1}, got {periodic!r}")
    return out


def periodic_features(x: Any, z: Any, periodic: tuple[int, ...], nx: int) -> Any:
    """The first layer's input: the standardised raw inputs ``z`` (a column, ``nx + 1 + n_params`` rows) with each
    periodic state coordinate ``i`` replaced by the two rows ``cos x_i, sin x_i`` (CasADi SX or MX)."""
    if not periodic:
        return z
    rows = []
    for i in range(nx):
        rows += [ca.cos(x[i]), ca.sin(x[i])] if i in periodic else [z[i]]
    return ca.vertcat(*rows, z[nx:])


def check_form(form: Any) -> CasadiForm:
    if form not in ("scalar", "matrix", "taylor", "taylor_model"):
        raise ValueError(f"casadi_function form must be 'scalar', 'matrix', 'taylor' or 'taylor_model', got {form!r}")
    return cast(CasadiForm, form)


def casadi_network(
    nx: int, hidden: tuple[int, ...], form: CasadiForm = "scalar", n_params: int = 0, periodic: tuple[int, ...] = ()
) -> ca.Function:
    """Build (once per architecture and form) the symbolic network with ``theta`` laid out as in
    ``casadi_parameters``; ``periodic``: the state indices fed as ``(cos, sin)`` (module docstring)."""
    periodic = check_periodic(nx, periodic)
    key = (nx, hidden, form, n_params, periodic)
    if key in _CASADI_CACHE:
        return _CASADI_CACHE[key]
    n_in = nx + 1 + n_params
    widths = [n_in + len(periodic), *hidden, 1]
    n_theta = num_parameters(nx, hidden, n_params, periodic)
    sym: Any = ca.SX if form == "scalar" else ca.MX
    x = sym.sym("x", nx)
    tau = sym.sym("tau", 1)
    theta = sym.sym("theta", n_theta)
    pos = 0

    def take(n: int) -> Any:
        nonlocal pos
        out = theta[pos : pos + n]
        pos += n
        return out

    in_mean, in_std = take(n_in), take(n_in)
    condition = theta[n_theta - n_params :]  # the robot (empty for a plain network), after the output statistics
    if form in ("taylor", "taylor_model"):
        fn = _taylor_network(x, tau, theta, condition, in_mean, in_std, take, widths, form, periodic)
        _CASADI_CACHE[key] = fn
        return fn
    h = periodic_features(x, (ca.vertcat(x, tau, condition) - in_mean) / in_std, periodic, nx)
    for i, (a, b) in enumerate(itertools.pairwise(widths)):
        # torch stores W as (out, in) row-major; CasADi reshapes column-major, hence the transpose.
        weight = ca.reshape(take(a * b), a, b).T
        bias = take(b)
        h = ca.mtimes(weight, h) + bias
        if i < len(widths) - 2:
            h = ca.tanh(h)
    out_mean, out_std = take(1), take(1)
    value = h * out_std + out_mean
    fn = ca.Function("value_network_theta", [x, tau, theta], [value], ["x", "tau", "theta"], ["V"])
    _CASADI_CACHE[key] = fn
    return fn


def _taylor_network(
    x: ca.MX,
    tau: ca.MX,
    theta: ca.MX,
    condition: ca.MX,
    in_mean: ca.MX,
    in_std: ca.MX,
    take: Any,
    widths: list[int],
    form: str,
    periodic: tuple[int, ...] = (),
) -> ca.Function:
    """The ``"taylor"`` and ``"taylor_model"`` forms (:meth:`ValueNetwork.casadi_function`): the network's value,
    gradient and Hessian in ``x`` at ``x0`` from explicit forward (``A_l = da_l/dx``) and backward
    (``delta_l = dV/dh_l``) passes of dense products, and the quadratic they define.

    With periodic coordinates the first layer's input ``z`` is no longer affine in ``x``: its Jacobian has the rows
    ``-sin x_i e_i'`` and ``cos x_i e_i'`` for coordinate ``i``, and the Hessian gains
    ``sum_j (dV/dz_j) d2z_j/dx2``, i.e. ``-(dV/dz_cos cos x_i + dV/dz_sin sin x_i)`` at ``(i, i)``."""
    nx = x.numel()
    if form == "taylor_model":
        return _taylor_quadratic(nx)
    n_raw = widths[0] - len(periodic)
    h = periodic_features(x, (ca.vertcat(x, tau, condition) - in_mean) / in_std, periodic, nx)
    if periodic:
        rows = []
        for i in range(nx):
            unit = ca.DM.zeros(1, nx)
            unit[i] = 1.0
            rows += [-ca.sin(x[i]) * unit, ca.cos(x[i]) * unit] if i in periodic else [unit / in_std[i]]
        jac = ca.vertcat(*rows, ca.MX.zeros(n_raw - nx, nx))  # dz/dx
    else:
        jac = ca.vertcat(ca.diag(1.0 / in_std[:nx]), ca.MX.zeros(n_raw - nx, nx))  # dz/dx
    layers = []
    for i, (a, b) in enumerate(itertools.pairwise(widths)):
        weight = ca.reshape(take(a * b), a, b).T
        bias = take(b)
        if i == len(widths) - 2:
            last_weight, last_bias = weight, bias
            break
        pre_jac = ca.mtimes(weight, jac)  # A_l
        h = ca.tanh(ca.mtimes(weight, h) + bias)
        slope = 1 - h**2  # tanh'
        jac = pre_jac * ca.repmat(slope, 1, nx)
        layers.append((weight, pre_jac, h, slope))
    out_mean, out_std = take(1), take(1)
    value = (ca.mtimes(last_weight, h) + last_bias) * out_std + out_mean
    grad = out_std * ca.mtimes(last_weight, jac)  # (1, nx)
    delta = out_std * last_weight.T  # dV/dh of the last hidden layer
    hess = ca.MX.zeros(nx, nx)
    for weight, pre_jac, act, slope in reversed(layers):
        curv = delta * (-2 * act * slope)  # dV/dh * tanh''(a)
        hess = hess + ca.mtimes(pre_jac.T, pre_jac * ca.repmat(curv, 1, nx))
        delta = ca.mtimes(weight.T, delta * slope)
    if periodic:  # delta is now dV/dz; the features' own curvature
        curv_x, row = [], 0
        for i in range(nx):
            if i in periodic:
                curv_x.append(-(delta[row] * ca.cos(x[i]) + delta[row + 1] * ca.sin(x[i])))
                row += 2
            else:
                curv_x.append(ca.MX(0))
                row += 1
        hess = hess + ca.diag(ca.vertcat(*curv_x))
    coeffs = ca.vertcat(value, grad.T, ca.vec(hess))
    return ca.Function("value_network_taylor", [x, tau, theta], [coeffs], ["x0", "tau", "theta"], ["c"])


def _taylor_quadratic(nx: int) -> ca.Function:
    """``(x, x0, c) -> c[0] + g (x - x0) + 1/2 (x - x0)' H (x - x0)`` with ``c = [V, g, vec(H)]``."""
    x, x0, c = ca.SX.sym("x", nx), ca.SX.sym("x0", nx), ca.SX.sym("c", 1 + nx + nx * nx)
    d = x - x0
    hess = ca.reshape(c[1 + nx :], nx, nx)
    model = c[0] + ca.dot(c[1 : 1 + nx], d) + 0.5 * ca.dot(d, ca.mtimes(hess, d))
    return ca.Function("value_taylor_model", [x, x0, c], [model], ["x", "x0", "c"], ["V"])


def _taylor_ensemble(one: ca.Function, nx: int, k: int, n: int, eps: float, form: str) -> ca.Function:
    """The ensemble's ``"taylor"`` (every member's coefficients, then the pessimism) and ``"taylor_model"`` (mean
    plus pessimism times spread of the members' quadratics: equal to the ensemble to second order at ``x0``)."""
    nc = 1 + nx + nx * nx
    if form == "taylor":
        x0, tau, theta = ca.MX.sym("x0", nx), ca.MX.sym("tau", 1), ca.MX.sym("theta", k * n + 1)
        coeffs = [one.call([x0, tau, theta[i * n : (i + 1) * n]], True, False)[0] for i in range(k)]
        out = ca.vertcat(*coeffs, theta[k * n])
        return ca.Function("value_ensemble_taylor", [x0, tau, theta], [out], ["x0", "tau", "theta"], ["c"])
    quad = _taylor_quadratic(nx)
    xs, x0s, c = ca.SX.sym("x", nx), ca.SX.sym("x0", nx), ca.SX.sym("c", k * nc + 1)
    values = [quad(xs, x0s, c[i * nc : (i + 1) * nc]) for i in range(k)]
    mean = sum(values) / k
    var = sum((v - mean) ** 2 for v in values) / k
    value = mean + c[k * nc] * (ca.sqrt(var + eps**2) - eps)
    return ca.Function("value_ensemble_taylor_model", [xs, x0s, c], [value], ["x", "x0", "c"], ["V"])


def num_parameters(nx: int, hidden: tuple[int, ...], n_params: int, periodic: tuple[int, ...] = ()) -> int:
    """Length of a network's CasADi parameter vector ``theta`` (the layout of
    :meth:`~seagul_learn.value_network.ValueNetwork.casadi_parameters`); each periodic coordinate adds one input
    to the first layer."""
    n_in = nx + 1 + n_params
    widths = [n_in + len(periodic), *hidden, 1]
    return 2 * n_in + sum(a * b + b for a, b in itertools.pairwise(widths)) + 2 + n_params


def ensemble_network(
    nx: int,
    hidden: tuple[int, ...],
    members: int,
    form: CasadiForm = "scalar",
    n_params: int = 0,
    eps: float = 1e-3,
    periodic: tuple[int, ...] = (),
) -> ca.Function:
    """The graph of an ensemble of ``members`` networks of one architecture (built once per architecture, size and
    form): ``(x, tau, theta) -> m + beta * s``, with ``theta`` every member's parameters in order then ``beta`` (the
    pessimism), ``m`` the members' mean and ``s = sqrt(mean_k (V_k - m)^2 + eps^2) - eps`` their smoothed spread
    (``eps`` in value units keeps ``sqrt`` differentiable where all members agree). The ``"taylor"`` forms are every
    member's coefficients then ``beta``, and the mean plus ``beta`` times the spread of the members' quadratics.
    ``periodic``: the members' periodic state indices (:func:`casadi_network`)."""
    form = check_form(form)
    periodic = check_periodic(nx, periodic)
    key = (nx, hidden, members, form, n_params, periodic)
    if key not in _ENSEMBLE_CACHE:
        one = casadi_network(nx, hidden, form, n_params, periodic)
        n = num_parameters(nx, hidden, n_params, periodic)
        k = members
        if form in ("taylor", "taylor_model"):
            _ENSEMBLE_CACHE[key] = _taylor_ensemble(one, nx, k, n, eps, form)
            return _ENSEMBLE_CACHE[key]
        sym: Any = ca.MX if form == "matrix" else ca.SX
        x, tau = sym.sym("x", nx), sym.sym("tau", 1)
        theta = sym.sym("theta", k * n + 1)
        # Members inlined in the matrix form: call nodes would carry zero weight sensitivities into the Hessian.
        values = [one.call([x, tau, theta[i * n : (i + 1) * n]], form == "matrix", False)[0] for i in range(k)]
        mean = sum(values) / k
        var = sum((v - mean) ** 2 for v in values) / k
        value = mean + theta[k * n] * (ca.sqrt(var + eps**2) - eps)
        _ENSEMBLE_CACHE[key] = ca.Function(
            "value_ensemble_theta", [x, tau, theta], [value], ["x", "tau", "theta"], ["V"]
        )
    return _ENSEMBLE_CACHE[key]
