"""Physical parameters that may differ from the model: the box ``Theta`` and the parametric dynamics.

A task that declares a :class:`ParameterSpace` (``Task.parameters``) names the fields of its parameter dataclass
that may vary (the acrobot's masses, lengths and damping; the glider's mass, plate areas and air density:
docs/reference/spec.md §14), the box ``Theta = [low, high]`` of plausible values around the nominal ones, and the
dynamics as
a function of them, ``xdot = f(x, u, theta)``. Everything else of the task (costs, bounds, X0, the profile) belongs
to the objective, not to the robot, and does not change with ``theta``.

Three things read it:

* :meth:`Task.with_params` gives the task of another robot (the same objective, the dynamics at ``theta``): the
  envs simulate it (``gym.make(..., params=...)``, ``reset(options={"params": ...})``), the full-horizon MPC that
  knows the true robot plans with it.
* ``Transcription(model_params=True)`` / ``TrajOptConfig(model_params=True)`` take ``theta`` as a CasADi parameter
  of the NLP: one built solver serves every ``theta``, and ``SolveResult.grad_theta = dV/dtheta`` comes from the
  same multipliers as ``dV/dx`` (CasADi's ``lam_p``).
* The samplers draw ``theta`` in ``Theta`` (uniform) or ascend the network's error over it (the adversary).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np


@dataclass(frozen=True, eq=False)
class ParameterSpace:
    """Which physical parameters of a task may vary, their box ``Theta`` and the dynamics ``f(x, u, theta)``."""

    names: tuple[str, ...]
    """Fields of the task's parameter dataclass (``Task.params``) that may vary, in the order of ``theta``."""
    low: np.ndarray
    """Lower corner of ``Theta`` (same units as the fields)."""
    high: np.ndarray
    """Upper corner of ``Theta``."""
    units: tuple[str, ...]
    """Unit of each parameter (for tables and error messages)."""
    dynamics: ca.Function
    """``xdot = f(x, u, theta)`` (SX); at the nominal ``theta`` equal to the task's ``dynamics``."""
    extras: Callable[[Any], dict[str, Any]] | None = None
    """Optional: the task's physics ``extras`` for a parameter dataclass (e.g. the acrobot's mass matrix, which the
    MuJoCo test compares); :meth:`Task.with_params` replaces those entries."""
    invariants: np.ndarray | None = None
    """Optional: rows ``E_i`` of exponents such that ``f(x, u, theta)`` depends on ``theta`` only through the
    products ``prod_j theta_j ** E_ij`` (a scaling symmetry of the dynamics, as dimensional analysis finds them).
    Robots with equal products move identically, so no trajectory tells them apart and a value over robots need
    not either (``NetworkConfig.robot_invariants``). None: every parameter matters on its own."""
    estimator_prior: float = 1e-3
    """Default weight of an online estimate's pull towards the model's values, per squared box width
    (``seagul_control.estimation.ParameterEstimator``'s ``prior``). It keeps what the data do not determine at the
    model's values: an acrobot at rest says little about its masses."""
    estimator_min_transitions: int = 3
    """Default number of transitions an online estimate waits for before it leaves the model's values
    (``ParameterEstimator``'s ``min_transitions``). Three keep an acrobot near rest, whose first transitions say
    little, at the model; a task whose first transition already determines what its value sees may start at one."""

    @property
    def size(self) -> int:
        """Number of parameters."""
        return len(self.names)

    def values_of(self, params: Any) -> np.ndarray:
        """``theta`` of a parameter dataclass (its fields named by :attr:`names`)."""
        return np.array([float(getattr(params, n)) for n in self.names])

    def check(self, theta: Any, task_name: str = "task", inside: bool = False) -> np.ndarray:
        """``theta`` as a float vector, from an array of :attr:`size` numbers or a complete mapping
        ``{name: value}`` (:meth:`resolve` fills a partial one from a base vector).

        Raises:
            ValueError: a wrong length, an unknown or missing name, NaN/inf, a negative value (every parameter
                here is a mass, length, area, inertia, damping or density), or, with ``inside``, a value outside
                ``Theta``.
        """
        return self.resolve(theta, None, task_name, inside)

    def resolve(self, theta: Any, base: np.ndarray | None, task_name: str = "task", inside: bool = False) -> np.ndarray:
        """``theta`` as a float vector: an array of :attr:`size` numbers, or a mapping ``{name: value}`` whose missing
        names take their value from ``base`` (a complete vector; None: every name is required).

        Raises:
            ValueError: see :meth:`check`.
        """
        if isinstance(theta, Mapping):
            unknown = sorted(set(theta) - set(self.names))
            if unknown:
                raise ValueError(f"{task_name}: unknown parameter(s) {unknown}; this task varies {list(self.names)}")
            missing = [n for n in self.names if n not in theta]
            if missing and base is None:
                raise ValueError(f"{task_name}: parameter(s) {missing} missing; give all of {list(self.names)}")
            values = []
            for i, n in enumerate(self.names):
                if n in theta:
                    try:
                        values.append(float(theta[n]))
                    except (TypeError, ValueError):
                        raise ValueError(f"{task_name}: parameter {n} must be a number, got {theta[n]!r}") from None
                else:
                    values.append(float(base[i]))  # type: ignore[index]  # base is not None: checked above
            arr = np.array(values)
        else:
            try:
                arr = np.asarray(theta, dtype=np.float64)
            except (TypeError, ValueError):
                raise ValueError(
                    f"{task_name}: parameters must be {self.size} numbers {list(self.names)} or a dict, got {theta!r}"
                ) from None
            if arr.shape != (self.size,):
                raise ValueError(
                    f"{task_name}: parameters must have shape ({self.size},) {list(self.names)}, got shape {arr.shape}"
                )
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{task_name}: parameters contain NaN or inf: {self.as_dict(arr)}")
        bad = [n for n, v in zip(self.names, arr, strict=True) if v < 0]
        if bad:
            raise ValueError(f"{task_name}: parameter(s) {bad} must not be negative, got {arr.tolist()}")
        if inside:
            out = [
                f"{n} = {v:g} {u} not in [{lo:g}, {hi:g}]"
                for n, u, v, lo, hi in zip(self.names, self.units, arr, self.low, self.high, strict=True)
                if not (lo - 1e-12 * abs(lo) <= v <= hi + 1e-12 * abs(hi))
            ]
            if out:
                raise ValueError(f"{task_name}: parameters outside the box Theta: " + "; ".join(out))
        return arr

    def sample(self, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
        """Uniform draw(s) from ``Theta`` (shape ``(size,)`` or ``(n, size)``)."""
        return rng.uniform(self.low, self.high, size=None if n is None else (n, self.size))

    def as_dict(self, theta: np.ndarray) -> dict[str, float]:
        """``{name: value}`` of ``theta``."""
        return {n: float(v) for n, v in zip(self.names, np.asarray(theta, dtype=float), strict=True)}

    def box(self) -> dict[str, list[float]]:
        """``{name: [low, high]}`` (the JSON form of ``Theta``)."""
        return {n: [float(lo), float(hi)] for n, lo, hi in zip(self.names, self.low, self.high, strict=True)}

    def scaled(self, factor: float, nominal: Any) -> ParameterSpace:
        """The box ``factor`` times as wide about ``nominal`` in ratio: each side's ratio to the nominal value is
        raised to ``factor``, ``low' = nominal (low / nominal)^factor`` (and ``high'`` alike), so a box of +-20 %
        masses and half-to-twice damping becomes 0.64-1.44 and quarter-to-four-times at ``factor=2``; values stay
        positive. The dynamics are the same function (a box is where ``theta`` is drawn, not what it may be).

        Raises:
            ValueError: ``factor`` is not a positive number, or ``nominal`` is not a positive point of the box.
        """
        if not (np.isfinite(factor) and factor > 0):
            raise ValueError(f"scaled: factor must be a positive number, got {factor!r}")
        center = np.asarray(nominal, dtype=float).reshape(-1)
        if center.shape != (self.size,) or not np.all(center > 0):
            raise ValueError(f"scaled: nominal must be {self.size} positive values, got {nominal!r}")
        if np.any(center < self.low) or np.any(center > self.high):
            raise ValueError(f"scaled: nominal {center.tolist()} lies outside the box {self.box()}")
        return dataclasses.replace(
            self, low=center * (self.low / center) ** factor, high=center * (self.high / center) ** factor
        )

    def feature_exponents(self) -> tuple[tuple[float, ...], ...]:
        """:attr:`invariants` padded with zero rows to a square matrix (``ValueNetwork(theta_features=...)``).

        Raises:
            ValueError: the space declares no invariants.
        """
        if self.invariants is None:
            raise ValueError(f"parameters {list(self.names)} declare no invariants")
        rows = [tuple(float(v) for v in row) for row in np.asarray(self.invariants, dtype=float)]
        return tuple(rows + [(0.0,) * self.size] * (self.size - len(rows)))

    def problems(self, params: Any, nx: int, nu: int) -> list[str]:
        """What is wrong with this space for a task with these parameters and sizes (empty when well formed)."""
        out: list[str] = []
        if not (isinstance(self.names, tuple) and self.names and all(isinstance(n, str) for n in self.names)):
            return [f"parameters.names must be a non-empty tuple of str, got {self.names!r}"]
        if len(set(self.names)) != len(self.names):
            out.append(f"parameters.names repeat a name: {list(self.names)}")
        if not (dataclasses.is_dataclass(params) and not isinstance(params, type)):
            out.append(f"parameters need the task's params to be a dataclass instance, got {type(params).__name__}")
            return out
        missing = [n for n in self.names if not hasattr(params, n)]
        if missing:
            out.append(f"parameters.names {missing} are not fields of the task's params ({type(params).__name__})")
        k = len(self.names)
        for what, arr in (("low", self.low), ("high", self.high)):
            if not (isinstance(arr, np.ndarray) and arr.shape == (k,) and np.all(np.isfinite(arr))):
                out.append(f"parameters.{what} must be {k} finite numbers, got {arr!r}")
        if not out and np.any(self.low > self.high):
            out.append(f"parameters.low must be <= high, got {self.low.tolist()} and {self.high.tolist()}")
        inv = self.invariants
        if inv is not None and not (
            isinstance(inv, np.ndarray)
            and inv.ndim == 2
            and 1 <= inv.shape[0] <= k
            and inv.shape[1] == k
            and np.all(np.isfinite(inv))
        ):
            out.append(f"parameters.invariants must be 1 to {k} rows of {k} finite exponents, got {inv!r}")
        if not (isinstance(self.estimator_prior, (int, float)) and 0 < self.estimator_prior < np.inf):
            out.append(f"parameters.estimator_prior must be a positive number, got {self.estimator_prior!r}")
        n_min = self.estimator_min_transitions
        if not (isinstance(n_min, (int, np.integer)) and not isinstance(n_min, bool) and n_min >= 1):
            out.append(f"parameters.estimator_min_transitions must be an integer >= 1, got {n_min!r}")
        if not (isinstance(self.units, tuple) and len(self.units) == k):
            out.append(f"parameters.units must give one unit per name ({k}), got {self.units!r}")
        fn = self.dynamics
        if not isinstance(fn, ca.Function):
            out.append(f"parameters.dynamics must be a casadi.Function, got {type(fn).__name__}")
        else:
            sizes = tuple(fn.size_in(i) for i in range(fn.n_in()))
            if sizes != ((nx, 1), (nu, 1), (k, 1)) or fn.n_out() < 1 or fn.size_out(0) != (nx, 1):
                out.append(f"parameters.dynamics must map (x[{nx}], u[{nu}], theta[{k}]) -> xdot[{nx}], got {sizes}")
        return out


def log_features(theta: Any, exponents: Any) -> np.ndarray:
    """``log(theta) @ E.T`` for one robot or one per row: the logarithms of the products ``prod_j theta_j ** E_ij``
    (:attr:`ParameterSpace.invariants`, or their square padding :meth:`ParameterSpace.feature_exponents`).

    Raises:
        ValueError: a parameter is not positive (no logarithm).
    """
    arr = np.asarray(theta, dtype=np.float64)
    if not np.all(arr > 0):
        raise ValueError(f"theta must be positive to take its logarithms, got {arr.tolist()}")
    return np.log(arr) @ np.asarray(exponents, dtype=np.float64).T


def parametric_dynamics(
    name: str, nx: int, nu: int, names: tuple[str, ...], params: Any, xdot: Callable[[ca.SX, ca.SX, Any], ca.SX]
) -> ca.Function:
    """``f(x, u, theta)`` from the task's own model code ``xdot(x, u, p)``: ``p`` is ``params`` with the fields
    ``names`` replaced by the entries of an SX symbol ``theta``, so the parametric and the nominal dynamics are the
    same expressions (one home for the model)."""
    x = ca.SX.sym("x", nx)
    u = ca.SX.sym("u", nu)
    theta = ca.SX.sym("theta", len(names))
    symbolic = dataclasses.replace(params, **{n: theta[i] for i, n in enumerate(names)})
    return ca.Function(f"{name}_f_theta", [x, u, theta], [xdot(x, u, symbolic)], ["x", "u", "theta"], ["xdot"])
