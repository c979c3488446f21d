"""Options of :class:`~seagul_control.transcription.Transcription` and the solvers' default settings.

:class:`TranscriptionOptions` is a frozen, validated dataclass (as :class:`~seagul_control.mpc.MPCOptions`): every
field is checked on construction, a bad value raises a ValueError that names the field and its allowed values, and
``to_dict``/``from_dict`` give a JSON-ready round trip. The terminal cost, its Taylor model and the length of its
parameter vector are not options but parts of the problem (CasADi Functions); they stay keyword arguments of the
transcription.

Example::

    from seagul_control.transcription import Transcription, TranscriptionOptions

    trans = Transcription(task, 20, TranscriptionOptions(free_time=False, step=0.05, solver="fatrop"))
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

from seagul_control import _options as opt
from seagul_control._options import OptionsBase

TimeMode = Literal["equal", "at_most", "free"]
TranscriptionSolver = Literal["ipopt", "fatrop", "shooting"]


@dataclass(frozen=True)
class TranscriptionOptions(OptionsBase):
    """How the NLP is built and solved (module docstring of :mod:`seagul_control.transcription` for the mechanisms)."""

    free_time: bool | None = None
    """Steps are decision variables; None: ``not task.fixed_step``."""
    step: float | None = None
    """Fixed step (s) when not ``free_time``; None: ``tau / n``."""
    step_bounds: tuple[float, float] | None = None
    """Bounds of free steps (s); None: the task's."""
    time_mode: TimeMode = "equal"
    """How ``sum(h)`` meets ``tau`` with free steps: ``"equal"``, ``"at_most"`` or ``"free"``."""
    final_box: bool = True
    """Impose the task's terminal box ``x_final_low <= x_n <= x_final_high``."""
    soft_bounds_weight: float | None = None
    """None: hard state bounds on knots ``1..n``; a weight ``M > 0``: their exact L1 penalty (IPOPT only)."""
    model_params: bool = False
    """The task's varying physical parameters enter the NLP as parameters after ``theta``."""
    substeps: int | None = None
    """RK4 substeps per interval; None: the task's."""
    solver: TranscriptionSolver = "ipopt"
    """``"ipopt"``, ``"fatrop"`` or ``"shooting"`` (condensed; fixed steps and input bounds only)."""
    solver_options: dict[str, Any] = field(default_factory=dict)
    """Options merged over the solver's defaults (:func:`default_ipopt_options`, :func:`default_fatrop_options`)."""
    codegen: bool = False
    """Compile the NLP functions to C, cached on disk (:mod:`seagul_control.codegen`)."""
    codegen_dir: str | None = None
    """Cache directory of the compiled libraries; None: :func:`~seagul_control.codegen.codegen_cache_dir`."""
    codegen_flags: tuple[str, ...] | None = None
    """Compiler flags of the library; None: :data:`~seagul_control.codegen.CODEGEN_FLAGS`."""
    max_solve_time: float | None = None
    """Wall-time limit of one solve (s); None: none."""

    def __post_init__(self) -> None:
        owner = "TranscriptionOptions"
        opt.set_field(self, "free_time", opt.flag(owner, "free_time", self.free_time, optional=True))
        opt.set_field(self, "step", opt.number(owner, "step", self.step, positive=True, optional=True))
        if self.step_bounds is not None:
            try:
                lo, hi = (float(v) for v in self.step_bounds)
            except (TypeError, ValueError) as exc:
                raise opt.fail(
                    owner, "step_bounds", "None or (low, high) with 0 <= low <= high", self.step_bounds
                ) from exc
            if not (0 <= lo <= hi):
                raise opt.fail(owner, "step_bounds", "None or (low, high) with 0 <= low <= high", self.step_bounds)
            opt.set_field(self, "step_bounds", (lo, hi))
        opt.choice(owner, "time_mode", self.time_mode, ("equal", "at_most", "free"))
        opt.set_field(self, "final_box", opt.flag(owner, "final_box", self.final_box))
        weight = opt.number(owner, "soft_bounds_weight", self.soft_bounds_weight, positive=True, optional=True)
        opt.set_field(self, "soft_bounds_weight", weight)
        opt.set_field(self, "model_params", opt.flag(owner, "model_params", self.model_params))
        opt.set_field(self, "substeps", opt.integer(owner, "substeps", self.substeps, minimum=1, optional=True))
        opt.choice(owner, "solver", self.solver, ("ipopt", "fatrop", "shooting"))
        opt.set_field(self, "solver_options", opt.mapping(owner, "solver_options", self.solver_options))
        opt.set_field(self, "codegen", opt.flag(owner, "codegen", self.codegen))
        opt.set_field(self, "codegen_dir", opt.path(owner, "codegen_dir", self.codegen_dir))
        opt.set_field(self, "codegen_flags", opt.strings(owner, "codegen_flags", self.codegen_flags))
        limit = opt.number(owner, "max_solve_time", self.max_solve_time, positive=True, optional=True)
        opt.set_field(self, "max_solve_time", limit)
        if weight is not None and self.solver != "ipopt":
            raise ValueError(
                "TranscriptionOptions.soft_bounds_weight (soft state bounds) needs solver='ipopt': its slack variables "
                "are not stage-wise, as fatrop requires"
            )


def default_ipopt_options() -> dict[str, Any]:
    """Quiet, exact-Hessian IPOPT settings used unless the caller overrides them."""
    return {
        "ipopt.print_level": 0,
        "ipopt.sb": "yes",
        "ipopt.tol": 1e-8,
        "ipopt.acceptable_tol": 1e-6,
        "ipopt.max_iter": 500,
        "ipopt.mu_strategy": "adaptive",
        "print_time": False,
        # An exploratory iterate may overflow the dynamics (a NaN/Inf step is rejected and retried by the solver).
        "show_eval_warnings": False,
    }


def default_fatrop_options() -> dict[str, Any]:
    """Quiet fatrop settings (structure detected from the stage-wise variable and constraint order)."""
    return {
        "fatrop.print_level": 0,
        "print_time": False,
        "structure_detection": "auto",
        "fatrop.max_iter": 500,
        "show_eval_warnings": False,
    }


__all__ = ["TimeMode", "TranscriptionOptions", "default_fatrop_options", "default_ipopt_options"]
