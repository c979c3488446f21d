"""The controller a task is evaluated with: the defaults of its limited-lookahead MPC (:class:`MPCDefaults`).

A task's benchmark is partly the controller it is scored with: the paper measures the acrobot with a 5-step (0.5 s)
lookahead and the glider with about 250 ms. :class:`MPCDefaults` is that part of the
:class:`~seagul_envs.tasks.profile.TaskProfile` (``profile.mpc``), one typed and checked object instead of loose
fields, read by ``seagul_control.mpc.LimitedLookaheadMPC`` for whatever its
:class:`~seagul_control.mpc.MPCOptions` leave at None. It is plain data (this layer knows nothing of the MPC's
code): the MPC's own options class documents what each setting does to the NLP.

The profile's former flat fields map one to one: ``mpc_horizon`` -> ``mpc.horizon``, ``mpc_trust_region`` ->
``mpc.trust_region``, ``mpc_goal_blend`` -> ``mpc.goal_blend``, ``mpc_final_soft_weight`` ->
``mpc.final_soft_weight`` (the old names still work, with a ``DeprecationWarning``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

TRUST_REGIONS = ("lqr", "box", "none")
"""Values of :attr:`MPCDefaults.trust_region`."""

LEGACY_NAMES = {
    "mpc_horizon": "horizon",
    "mpc_trust_region": "trust_region",
    "mpc_goal_blend": "goal_blend",
    "mpc_final_soft_weight": "final_soft_weight",
}
"""The profile's former flat field -> the :class:`MPCDefaults` field that replaced it."""


@dataclass(frozen=True)
class MPCDefaults:
    """Defaults of the task's limited-lookahead MPC (``TaskProfile.mpc``; see the module docstring).

    Raises:
        ValueError: a horizon below 1, an unknown trust region, a negative or non-finite goal blend, a final soft
            weight that is not a positive finite number.
    """

    horizon: int | None = None
    """Lookahead steps (None: about 250 ms, ``max(1, round(0.25 / task.control_period))``)."""
    trust_region: Literal["lqr", "box", "none"] = "lqr"
    """Guard of the learned terminal cost (``"lqr"``, ``"box"`` or ``"none"``; ``seagul_control.mpc``): ``"lqr"``
    until a task's learned values are measured to work on their own."""
    goal_blend: float = 0.0
    """Value units (0 = off): below about this value of ``l_f`` the task's terminal quadratic is the value
    (equilibrium goals only; docs/experiments/closed-loop.md)."""
    final_soft_weight: float | None = None
    """Weight of the final phase's (the last ``horizon`` steps, which end at the episode end inside the terminal box)
    exact L1 penalty on the box and path bounds (IPOPT). None imposes them as bounds; a weight makes the final phase
    return the plan that ends closest to the box instead of failing when the box is out of exact reach (glider:
    1e4; docs/experiments/closed-loop.md)."""

    def __post_init__(self) -> None:
        if self.horizon is not None and (isinstance(self.horizon, bool) or int(self.horizon) != self.horizon):
            raise ValueError(f"MPCDefaults.horizon must be an integer >= 1 or None, got {self.horizon!r}")
        if self.horizon is not None and int(self.horizon) < 1:
            raise ValueError(f"MPCDefaults.horizon must be an integer >= 1 or None, got {self.horizon!r}")
        if self.trust_region not in TRUST_REGIONS:
            raise ValueError(
                f"MPCDefaults.trust_region must be one of {list(TRUST_REGIONS)}, got {self.trust_region!r}"
            )
        if not (math.isfinite(float(self.goal_blend)) and float(self.goal_blend) >= 0.0):
            raise ValueError(f"MPCDefaults.goal_blend must be a finite number >= 0, got {self.goal_blend!r}")
        weight = self.final_soft_weight
        if weight is not None and not (math.isfinite(float(weight)) and float(weight) > 0.0):
            raise ValueError(f"MPCDefaults.final_soft_weight must be a finite number > 0 or None, got {weight!r}")

    def horizon_for(self, control_period: float) -> int:
        """:attr:`horizon`, or ``max(1, round(0.25 / control_period))`` steps (about 250 ms)."""
        return int(self.horizon) if self.horizon is not None else max(1, round(0.25 / control_period))
