"""The typed output of one full-horizon trajectory-optimization solve."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class SolveResult:
    """One solve of paper Eq. 1 from ``(x_init, tau)``, with the value, its dual gradients and per-knot labels.

    Arrays index knots ``k = 0..m`` (states, time to go, cost to go, per-knot gradients) or intervals
    ``k = 0..m-1`` (controls, steps). When ``success`` is False the arrays hold the solver's last iterate and must
    never be used as training data.
    """

    x_init: np.ndarray
    """Start state (``nx``)."""
    tau: float
    """Time to go of the solve (s)."""
    success: bool
    """True iff the solver reported a (locally) optimal, feasible solution."""
    status: str
    """The solver's own return status (e.g. ``"Solve_Succeeded"``)."""
    value: float
    """Optimal cost ``V(x_init, tau)`` (NaN if the solve failed)."""
    grad_x: np.ndarray
    """``dV/dx_init`` from the multiplier of ``x_0 = x_init`` (``nx``)."""
    grad_tau: float
    """``dV/dtau`` from the multiplier of ``sum(h) = tau`` (parametric sensitivity for fixed-step tasks)."""
    states: np.ndarray
    """Knot states ``x_0..x_m``, shape ``(m + 1, nx)``."""
    controls: np.ndarray
    """Inputs ``u_0..u_{m-1}``, shape ``(m, nu)``."""
    steps: np.ndarray
    """Steps ``h_0..h_{m-1}``, shape ``(m,)``."""
    time_to_go: np.ndarray
    """``tau_k = sum_{i>=k} h_i`` per knot, shape ``(m + 1,)``: ``tau`` at knot 0, 0 at knot m."""
    cost_to_go: np.ndarray
    """Cost to go from each knot, shape ``(m + 1,)``; ``cost_to_go[0] == value``, ``cost_to_go[m] = l_f(x_m)``."""
    knot_grads: np.ndarray
    """``dV_k/dx_k`` per knot from the defect multipliers (row 0 equals ``grad_x``), shape ``(m + 1, nx)``."""
    iterations: int
    """Solver iterations (summed over fallback attempts)."""
    solve_time: float
    """Wall time of the solve including fallbacks (s)."""
    attempts: list[str] = field(default_factory=list)
    """Which strategies were tried, in order (e.g. ``["fatrop:line", "ipopt:goal"]``)."""
    theta: np.ndarray | None = None
    """The robot's physical parameters of the solve (``task.parameters.names`` order), when the optimizer takes them
    as NLP parameters (``TrajOptConfig(model_params=True)``); None otherwise."""
    grad_theta: np.ndarray | None = None
    """``dV/dtheta`` from the multipliers (minus CasADi's ``lam_p`` of the parameters; verified against central
    finite differences of re-solved values in ``tests/test_parameters.py``); None without ``model_params``."""
    knot_grad_theta: np.ndarray | None = None
    """``dV_k/dtheta`` per knot, shape ``(m + 1, k)``: ``sum_{j >= k} (dV_{j+1}/dx_{j+1})' dF_j/dtheta`` (the tail's
    envelope theorem; row 0 equals ``grad_theta``, row ``m`` is 0); None without ``model_params``."""

    @property
    def num_knots(self) -> int:
        """``m + 1``."""
        return int(self.states.shape[0])
