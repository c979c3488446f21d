"""The :class:`Task`: one symbolic model per system, the single source of truth.

A task bundles the CasADi continuous dynamics ``f(x, u)``, the running and terminal costs, the bounds, the goal,
the admissible start box ``X0`` and time-to-go range ``T0``, and the transcription settings. The Gymnasium
simulators, the trajectory optimizer and the MPC all read the same object; numeric fast paths are *generated* from
the CasADi expressions (never retyped).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any

import casadi as ca
import numpy as np


@dataclass(frozen=True, eq=False)
class Task:
    """An optimal-control task: dynamics, costs, bounds and the sets learning samples from."""

    name: str
    """Registry name (``"acrobot"``, ``"glider"``)."""
    state_names: tuple[str, ...]
    """One name per state coordinate."""
    control_names: tuple[str, ...]
    """One name per input coordinate."""
    dynamics: ca.Function
    """Continuous dynamics ``xdot = f(x, u)`` (SX-based, expandable)."""
    stage_cost: ca.Function
    """Running cost rate ``l(x, u)``; the transcription charges ``h * l(x_k, u_k)``."""
    terminal_cost: ca.Function
    """Terminal cost ``l_f(x)``; ``V(x, 0) = l_f(x)``."""
    goal: np.ndarray
    """Goal state ``x*``."""
    u_low: np.ndarray
    """Input lower bounds (physical units)."""
    u_high: np.ndarray
    """Input upper bounds."""
    x_low: np.ndarray
    """Path-state lower bounds (``-inf`` where free); leaving them ends an episode."""
    x_high: np.ndarray
    """Path-state upper bounds (``+inf`` where free)."""
    x_final_low: np.ndarray
    """Terminal-state box lower bounds of the full-horizon problem (``-inf`` where free)."""
    x_final_high: np.ndarray
    """Terminal-state box upper bounds."""
    x0_low: np.ndarray
    """Lower corner of the admissible start box X0."""
    x0_high: np.ndarray
    """Upper corner of X0."""
    tau_range: tuple[float, float]
    """Admissible time-to-go range T0 (seconds) for full-horizon solves."""
    tau_nominal: float
    """Nominal time to go (uniform samples, validation and episodes use it)."""
    num_steps: int
    """Number of transcription intervals ``m`` of the full-horizon problem."""
    step_bounds: tuple[float, float]
    """Bounds on each step ``h_k``; ignored when ``fixed_step``."""
    fixed_step: bool
    """If True every step is ``tau / m`` (no free time); otherwise ``h_k`` are decision variables."""
    rk4_substeps: int
    """RK4 substeps per transcription interval (accuracy of the defects; see the task's docstring)."""
    control_period: float
    """Default control period of the Gymnasium env (seconds)."""
    max_sim_substep: float = 0.005
    """Largest RK4 substep of the simulator inside one control period (seconds)."""
    params: Any = None
    """The task's physical parameter dataclass (for reference, rendering and tests)."""
    extras: dict[str, Any] = field(default_factory=dict)
    """Task-specific symbolic helpers (e.g. the acrobot's mass matrix for the MuJoCo test)."""

    # ------------------------------------------------------------------ sizes
    @property
    def nx(self) -> int:
        """State dimension."""
        return len(self.state_names)

    @property
    def nu(self) -> int:
        """Input dimension."""
        return len(self.control_names)

    @property
    def tau_is_fixed(self) -> bool:
        """True when T0 is a single value (the acrobot)."""
        return self.tau_range[0] == self.tau_range[1]

    # ------------------------------------------------------------ integrators
    def rk4_step(self, substeps: int | None = None) -> ca.Function:
        """Symbolic RK4 map ``F(x, u, h) -> x(h)`` with ``substeps`` equal substeps, input held constant.

        Used by the transcription (as defect ``x_{k+1} - F(x_k, u_k, h_k) = 0``) and, numerically, by the simulator.
        """
        return _rk4_step(self, self.rk4_substeps if substeps is None else int(substeps))

    def simulator(self, dt: float, max_substep: float | None = None) -> ca.Function:
        """Numeric one-control-period map ``(x, u) -> x(t + dt)`` (zero-order hold, RK4 substeps <= max_substep)."""
        max_substep = self.max_sim_substep if max_substep is None else max_substep
        substeps = max(1, int(np.ceil(dt / max_substep - 1e-9)))
        return _simulator(self, float(dt), substeps)

    def stage_cost_value(self, x: np.ndarray, u: np.ndarray) -> float:
        """``l(x, u)`` as a float."""
        return float(self.stage_cost(x, u))

    def terminal_cost_value(self, x: np.ndarray) -> float:
        """``l_f(x)`` as a float."""
        return float(self.terminal_cost(x))

    # ---------------------------------------------------------------- checks
    def check_state(self, x: Any, what: str = "state") -> np.ndarray:
        """Return ``x`` as a float64 vector of length ``nx`` or raise a ValueError that names the problem."""
        arr = np.asarray(x, dtype=np.float64)
        if arr.shape != (self.nx,):
            raise ValueError(
                f"{self.name}: {what} must have shape ({self.nx},) {list(self.state_names)}, got shape {arr.shape}"
            )
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{self.name}: {what} contains NaN or inf: {arr.tolist()}")
        return arr

    def check_control(self, u: Any, what: str = "action") -> np.ndarray:
        """Return ``u`` as a float64 vector of length ``nu`` or raise a ValueError that names the problem."""
        arr = np.asarray(u, dtype=np.float64)
        if arr.shape == () and self.nu == 1:
            arr = arr.reshape(1)
        if arr.shape != (self.nu,):
            raise ValueError(
                f"{self.name}: {what} must have shape ({self.nu},) {list(self.control_names)}, got shape {arr.shape}"
            )
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{self.name}: {what} contains NaN or inf: {arr.tolist()}")
        return arr

    def check_tau(self, tau: Any, allow_shorter: bool = False) -> float:
        """Validate a time to go: finite, positive, inside ``tau_range`` (or below it if ``allow_shorter``)."""
        try:
            value = float(tau)
        except (TypeError, ValueError):
            raise ValueError(f"{self.name}: time to go must be a number, got {tau!r}") from None
        lo, hi = self.tau_range
        if not np.isfinite(value):
            raise ValueError(f"{self.name}: time to go must be finite, got {value}")
        tol = 1e-9
        if allow_shorter:
            if not (0.0 <= value <= hi + tol):
                raise ValueError(f"{self.name}: time to go {value} outside [0, {hi}] s")
        elif not (lo - tol <= value <= hi + tol):
            raise ValueError(f"{self.name}: time to go {value} outside the task's range T0 = [{lo}, {hi}] s")
        return value

    def in_x0(self, x: np.ndarray, tol: float = 1e-9) -> bool:
        """True if ``x`` lies in the start box X0."""
        x = np.asarray(x, dtype=np.float64)
        return bool(np.all(x >= self.x0_low - tol) and np.all(x <= self.x0_high + tol))

    def sample_x0(self, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
        """Uniform draw(s) from X0 (shape ``(nx,)`` or ``(n, nx)``)."""
        size = None if n is None else (n, self.nx)
        return rng.uniform(self.x0_low, self.x0_high, size=size)

    def __repr__(self) -> str:
        return f"Task({self.name!r}, nx={self.nx}, nu={self.nu}, m={self.num_steps}, tau={self.tau_range})"


def rk4_map(dynamics: ca.Function, nx: int, nu: int, substeps: int, name: str = "rk4") -> ca.Function:
    """``F(x, u, h)``: ``substeps`` equal RK4 substeps of ``dynamics`` over ``h`` with ``u`` held constant."""
    x = ca.SX.sym("x", nx)
    u = ca.SX.sym("u", nu)
    h = ca.SX.sym("h")
    dt = h / substeps
    xs = x
    for _ in range(substeps):
        k1 = dynamics(xs, u)
        k2 = dynamics(xs + dt / 2 * k1, u)
        k3 = dynamics(xs + dt / 2 * k2, u)
        k4 = dynamics(xs + dt * k3, u)
        xs = xs + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return ca.Function(name, [x, u, h], [xs], ["x", "u", "h"], ["x_next"])


@functools.cache
def _rk4_step(task: Task, substeps: int) -> ca.Function:
    return rk4_map(task.dynamics, task.nx, task.nu, substeps, f"{task.name}_rk4_{substeps}")


@functools.cache
def _simulator(task: Task, dt: float, substeps: int) -> ca.Function:
    step = _rk4_step(task, substeps)
    x = ca.SX.sym("x", task.nx)
    u = ca.SX.sym("u", task.nu)
    return ca.Function(f"{task.name}_sim", [x, u], [step(x, u, dt)], ["x", "u"], ["x_next"])
