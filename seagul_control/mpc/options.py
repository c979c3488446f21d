"""Typed, validated options of the two MPCs: :class:`MPCOptions` (limited lookahead) and :class:`FullHorizonOptions`.

Both are frozen dataclasses (change one with ``options.replace(max_iter=100)``), checked on construction (a bad
value raises a ValueError that names the field and its allowed values) and JSON-ready (``to_dict``/``from_dict``,
the form the MPC file stores). A field whose default depends on the task is ``None`` here and resolved when the
controller is built; the controller's ``options`` attribute holds the resolved values.

Example::

    from seagul_control.mpc import LimitedLookaheadMPC, MPCOptions

    options = MPCOptions(solver="fatrop", max_iter=100, jit=False)
    mpc = LimitedLookaheadMPC(task, network, horizon=5, options=options)
    mpc.options.cold_guess  # "best": resolved for the fixed-step lookahead
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from seagul_control import _options as opt
from seagul_control._options import OptionsBase

TrustRegion = Literal["box", "lqr", "none"]
SolverName = Literal["fatrop", "ipopt", "shooting"]
Multistart = Literal["never", "rise", "always"]
ColdGuess = Literal["rollout", "line", "best"]

SOLVERS: tuple[SolverName, ...] = ("fatrop", "ipopt", "shooting")


def _check_solver_fields(self: Any, owner: str) -> None:
    """The solver fields both option classes share (``dt`` ... ``cold_guess``)."""
    opt.set_field(self, "dt", opt.number(owner, "dt", self.dt, positive=True, optional=True))
    opt.set_field(self, "substeps", opt.integer(owner, "substeps", self.substeps, minimum=1, optional=True))
    opt.choice(owner, "solver", self.solver, (*SOLVERS, None))
    opt.set_field(self, "jit", opt.flag(owner, "jit", self.jit))
    opt.set_field(self, "jit_cache_dir", opt.path(owner, "jit_cache_dir", self.jit_cache_dir))
    opt.set_field(self, "jit_flags", opt.strings(owner, "jit_flags", self.jit_flags))
    opt.set_field(self, "max_iter", opt.integer(owner, "max_iter", self.max_iter, minimum=0))
    opt.set_field(self, "tol", opt.number(owner, "tol", self.tol, positive=True))
    limit = opt.number(owner, "max_solve_time", self.max_solve_time, positive=True, optional=True)
    opt.set_field(self, "max_solve_time", limit)
    opt.set_field(self, "solver_options", opt.mapping(owner, "solver_options", self.solver_options))
    opt.set_field(self, "warm_start", opt.flag(owner, "warm_start", self.warm_start))
    opt.choice(owner, "cold_guess", self.cold_guess, ("rollout", "line", "best", None))


@dataclass(frozen=True)
class MPCOptions(OptionsBase):
    """Options of :class:`~seagul_control.mpc.LimitedLookaheadMPC` (paper Eq. 3); ``None`` = the task's default.

    The fields come in four groups: time discretisation (``dt``, ``substeps``, ``steps``), the solver (``solver``
    ... ``multistart_starts``), the learned terminal cost (``trust_region`` ... ``goal_blend``) and the end of the
    episode (``end_phase`` ... ``final_soft_weight``). The module docstring of :mod:`seagul_control.mpc` explains
    each mechanism and where its default was measured.
    """

    # ----- time
    dt: float | None = None
    """Control period (s); None: the task's ``control_period``."""
    substeps: int | None = None
    """RK4 substeps per step; None: the task's."""
    steps: Literal["fixed", "free"] = "fixed"
    """``"fixed"``: every step is ``dt``; ``"free"``: ``h_k`` in the task's step bounds, ``sum(h) <= tau_now``."""
    # ----- solver
    solver: SolverName | None = None
    """``"shooting"`` (condensed; fixed steps, input bounds only), ``"fatrop"`` or ``"ipopt"``. None:
    ``"shooting"`` where it applies and the horizon is <= 10 steps (the acrobot), else fatrop (IPOPT with free
    steps)."""
    jit: bool = True
    """Compile the NLP functions to C (cached on disk) when a C compiler exists."""
    jit_cache_dir: str | None = None
    """Cache directory of compiled code; None: ``$SEAGUL_CACHE_DIR`` or ``~/.cache/seagul/casadi``."""
    jit_flags: tuple[str, ...] | None = None
    """Compiler flags; None: ``-O1`` for the scalar JIT, ``-O3`` for a matrix-form value function."""
    max_iter: int = 50
    """Solver iteration limit per step."""
    tol: float = 1e-6
    """Solver tolerance."""
    max_solve_time: float | None = 5.0
    """Wall-time limit of one solve (s; None: none); a solve that hits it fails and the step falls back."""
    solver_options: dict[str, Any] = field(default_factory=dict)
    """Extra nlpsol options, e.g. ``{"fatrop.mu_init": 1e-2}``."""
    warm_start: bool = True
    """Warm-start each env from its previous solution, shifted by one step."""
    cold_guess: ColdGuess | None = None
    """First guess without a warm start: ``"rollout"``, ``"line"`` or ``"best"`` (both, the lower plan kept).
    None: ``"best"`` with fixed steps, ``"rollout"`` with free steps."""
    multistart: Multistart | None = None
    """When the condensed solver also descends from extra constant-input starts: ``"rise"``, ``"always"`` or
    ``"never"``. None: ``"rise"`` with ``solver="shooting"``, else ``"never"`` (the only choice there)."""
    multistart_starts: int = 2
    """How many extra starts (2: both input bounds)."""
    # ----- learned terminal cost
    trust_region: TrustRegion | None = None
    """``"lqr"``, ``"box"`` or ``"none"``; None: the task's ``profile.mpc.trust_region``."""
    trust_box: tuple[tuple[float, ...], tuple[float, ...]] | None = None
    """``(low, high)`` state box of ``"box"``; None: from the value function (its training box)."""
    trust_weight: float = 100.0
    """Weight of the box penalty (value units per squared box width)."""
    clamp: bool = True
    """Use the smooth ``max(Vhat, 0)`` as the learned cost (a cost-to-go is never negative)."""
    anchor_goal: bool | None = None
    """Subtract the value function's value and gradient at the goal; None: on for a zero-cost equilibrium goal."""
    goal_blend: float | None = None
    """Scale ``c`` of the blend ``b l_f + (1 - b) Vhat``, ``b = exp(-l_f / c)`` (0: off); None: the task's
    ``profile.mpc.goal_blend`` at an equilibrium goal, else 0."""
    # ----- end of the episode
    end_phase: Literal["switch", "shrink"] | None = None
    """``"switch"`` (keep the horizon, ``l_f`` past the episode end) or ``"shrink"`` (steps that end exactly at
    the episode end); None: ``"shrink"`` for tasks with a terminal box, else ``"switch"``."""
    final_box: bool = True
    """Impose the task's terminal box in the final-phase problems."""
    final_solver: SolverName | None = None
    """Solver of the final phase; None: ``solver`` (IPOPT with ``final_soft_weight``, fatrop where the condensed
    solver cannot impose the terminal box)."""
    final_soft_weight: float | None = None
    """Weight of the final phase's exact L1 penalty on the terminal box and path bounds (IPOPT); 0: hard bounds;
    None: the task's ``profile.mpc.final_soft_weight``."""

    def __post_init__(self) -> None:
        owner = "MPCOptions"
        _check_solver_fields(self, owner)
        opt.choice(owner, "steps", self.steps, ("fixed", "free"))
        opt.choice(owner, "multistart", self.multistart, ("never", "rise", "always", None))
        opt.set_field(
            self, "multistart_starts", opt.integer(owner, "multistart_starts", self.multistart_starts, minimum=1)
        )
        opt.choice(owner, "trust_region", self.trust_region, ("box", "lqr", "none", None))
        opt.set_field(self, "trust_box", _box(owner, self.trust_box))
        opt.set_field(self, "trust_weight", opt.number(owner, "trust_weight", self.trust_weight, nonnegative=True))
        opt.set_field(self, "clamp", opt.flag(owner, "clamp", self.clamp))
        opt.set_field(self, "anchor_goal", opt.flag(owner, "anchor_goal", self.anchor_goal, optional=True))
        blend = opt.number(owner, "goal_blend", self.goal_blend, nonnegative=True, optional=True)
        opt.set_field(self, "goal_blend", blend)
        opt.choice(owner, "end_phase", self.end_phase, ("switch", "shrink", None))
        opt.set_field(self, "final_box", opt.flag(owner, "final_box", self.final_box))
        opt.choice(owner, "final_solver", self.final_solver, (*SOLVERS, None))
        soft = opt.number(owner, "final_soft_weight", self.final_soft_weight, nonnegative=True, optional=True)
        opt.set_field(self, "final_soft_weight", soft)
        if self.multistart not in (None, "never") and self.solver not in (None, "shooting"):
            raise ValueError(
                f"MPCOptions.multistart={self.multistart!r} needs solver='shooting' (or None), not {self.solver!r}"
            )
        if soft and self.final_solver not in (None, "ipopt"):
            raise ValueError(f"MPCOptions.final_soft_weight needs final_solver='ipopt', got {self.final_solver!r}")


def _box(owner: str, value: Any) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
    """``(low, high)`` as two tuples of floats of equal length with ``high >= low``, or None."""
    if value is None:
        return None
    allowed = "None or (low, high): two equally long sequences of numbers with high >= low"
    try:
        low, high = (np.asarray(v, dtype=float).reshape(-1) for v in value)
    except (TypeError, ValueError) as exc:
        raise opt.fail(owner, "trust_box", allowed, value) from exc
    if low.shape != high.shape or np.any(np.isnan(low)) or np.any(np.isnan(high)) or np.any(high < low):
        raise opt.fail(owner, "trust_box", allowed, value)
    return tuple(float(v) for v in low), tuple(float(v) for v in high)


@dataclass(frozen=True)
class FullHorizonOptions(OptionsBase):
    """Options of :class:`~seagul_control.mpc.FullHorizonMPC`: the solver fields of :class:`MPCOptions` with the
    reference's defaults (no JIT: compiling the long problem takes minutes; 500 iterations; a 60 s limit that only
    stops a hung solve, since a limit a loaded machine reaches made its episodes depend on the load)."""

    dt: float | None = None
    """Control period (s); None: the task's ``control_period``."""
    substeps: int | None = None
    """RK4 substeps per step; None: the task's."""
    solver: SolverName | None = None
    """``"fatrop"``, ``"ipopt"`` or ``"shooting"``; None: fatrop for fixed steps, IPOPT for free time."""
    jit: bool = False
    """Compile the NLP functions to C (cached on disk) when a C compiler exists."""
    jit_cache_dir: str | None = None
    """Cache directory of compiled code; None: ``$SEAGUL_CACHE_DIR`` or ``~/.cache/seagul/casadi``."""
    jit_flags: tuple[str, ...] | None = None
    """Compiler flags; None: ``-O1``."""
    max_iter: int = 500
    """Solver iteration limit per step."""
    tol: float = 1e-6
    """Solver tolerance."""
    max_solve_time: float | None = 60.0
    """Wall-time limit of one solve (s; None: none)."""
    solver_options: dict[str, Any] = field(default_factory=dict)
    """Extra nlpsol options."""
    warm_start: bool = True
    """Warm-start each env from its previous solution, shifted by one step."""
    cold_guess: ColdGuess = "line"
    """First guess without a warm start: ``"line"`` (to the goal), ``"rollout"`` or ``"best"``."""

    def __post_init__(self) -> None:
        _check_solver_fields(self, "FullHorizonOptions")
        if self.cold_guess is None:
            raise opt.fail("FullHorizonOptions", "cold_guess", "one of 'rollout', 'line', 'best'", None)


__all__ = ["ColdGuess", "FullHorizonOptions", "MPCOptions", "Multistart", "SolverName", "TrustRegion"]
