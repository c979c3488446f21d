"""Stage access of a built :class:`~seagul_control.transcription.Transcription`, in the style of acados'
``solver.set(stage, field, value)``.

After the build, the bounds of each stage's variables and the stored initial guess are read and written per stage:
:meth:`StageAccessMixin.set`, :meth:`StageAccessMixin.get` (fields in :data:`STAGE_FIELDS`) and
:meth:`StageAccessMixin.set_guess`. They persist across solves: the MPC pins its first step to the control period
this way, and a caller can tighten a knot's box or seed a guess without rebuilding the solver. The methods live on
:class:`StageAccessMixin`, a base class of the transcription; they read its index maps and bound vectors.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from seagul_envs.tasks.base import Task

#: Fields of :meth:`Transcription.set` / :meth:`Transcription.get`: name -> (variable, role). Variables: ``"x"`` the
#: knot state ``x_k`` (stages ``0..n``), ``"u"`` the input ``u_k`` and ``"h"`` the free step ``h_k`` (stages
#: ``0..n-1``; ``"h"`` only with ``free_time``). Roles: ``"guess"`` the stored initial guess, ``"lb"``/``"ub"`` the
#: variable's bounds.
STAGE_FIELDS: dict[str, tuple[str, str]] = {
    "x": ("x", "guess"),
    "u": ("u", "guess"),
    "h": ("h", "guess"),
    "lbx": ("x", "lb"),
    "ubx": ("x", "ub"),
    "lbu": ("u", "lb"),
    "ubu": ("u", "ub"),
    "lbh": ("h", "lb"),
    "ubh": ("h", "ub"),
}


class StageAccessMixin:
    """Per-stage reads and writes of bounds and the stored initial guess (see the module docstring)."""

    # Set by Transcription.__init__.
    task: Task
    horizon: int
    free_time: bool
    _x_idx: list[np.ndarray]
    _u_idx: list[np.ndarray]
    _h_idx: list[int]
    _t_idx: list[int]
    _lbw: np.ndarray
    _ubw: np.ndarray
    _guess: np.ndarray | None

    @property
    def num_variables(self) -> int:
        raise NotImplementedError  # Transcription's

    def pack_guess(self, states: np.ndarray, controls: np.ndarray, steps: np.ndarray | None = None) -> np.ndarray:
        raise NotImplementedError  # Transcription's

    def _stage_positions(self, stage: Any, field: str, caller: str) -> tuple[np.ndarray, str]:
        """Primal positions of ``field`` at ``stage`` and the field's role; ValueErrors name the problem."""
        if not isinstance(field, str) or field not in STAGE_FIELDS:
            raise ValueError(f"Transcription.{caller}: unknown field {field!r}; use one of {sorted(STAGE_FIELDS)}")
        var, role = STAGE_FIELDS[field]
        if var == "h" and not self.free_time:
            raise ValueError(
                f"Transcription.{caller}: field {field!r} needs free steps, but this transcription has fixed steps "
                "(free_time=False)"
            )
        last = self.horizon if var == "x" else self.horizon - 1
        if isinstance(stage, bool) or not isinstance(stage, int | np.integer) or not 0 <= int(stage) <= last:
            raise ValueError(
                f"Transcription.{caller}: stage of field {field!r} must be an integer in 0..{last} "
                f"(horizon {self.horizon}), got {stage!r}"
            )
        k = int(stage)
        if var == "x":
            return self._x_idx[k], role
        if var == "u":
            return self._u_idx[k], role
        return np.array([self._h_idx[k]]), role

    def set(self, stage: int, field: str, value: Any) -> None:
        """Set ``field`` of ``stage`` (acados' ``solver.set(stage, field, value)``); kept for every later solve.

        Fields (:data:`STAGE_FIELDS`): ``"lbx"``/``"ubx"`` bounds of ``x_k`` (stages ``0..n``), ``"lbu"``/``"ubu"``
        of ``u_k`` and ``"lbh"``/``"ubh"`` of the free step ``h_k`` (stages ``0..n-1``); ``"x"``, ``"u"``, ``"h"``
        the same entries of the stored initial guess, which :meth:`solve` uses when called without ``guess`` (it
        starts as the zero guess of :meth:`pack_guess` on the first such set; :meth:`set_guess` replaces it whole;
        elapsed-time states follow the steps). Bounds may be infinite; a box with ``lb > ub`` is the solver's to
        report (set both sides of a changed box).

        Args:
            stage: the stage ``k``.
            field: the field name.
            value: ``(nx,)``, ``(nu,)`` or ``(1,)`` numbers, or a number for a one-entry field.

        Raises:
            ValueError: unknown field, a step field of a fixed-step transcription, a stage outside the field's
                range, a value of the wrong shape, a NaN, or a non-finite guess.
        """
        pos, role = self._stage_positions(stage, field, "set")
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError) as exc:
            msg = f"Transcription.set: field {field!r} at stage {stage} needs numbers, got {value!r}"
            raise ValueError(msg) from exc
        if arr.shape != (pos.size,) and not (arr.ndim == 0 and pos.size == 1):
            raise ValueError(
                f"Transcription.set: field {field!r} at stage {stage} needs shape ({pos.size},), got {arr.shape}"
            )
        if np.any(np.isnan(arr)):
            raise ValueError(f"Transcription.set: field {field!r} at stage {stage} contains NaN: {arr}")
        if role == "lb":
            self._lbw[pos] = arr
        elif role == "ub":
            self._ubw[pos] = arr
        else:
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"Transcription.set: guess {field!r} at stage {stage} must be finite, got {arr}")
            if self._guess is None:
                zeros = (np.zeros((self.horizon + 1, self.task.nx)), np.zeros((self.horizon, self.task.nu)))
                self._guess = self.pack_guess(*zeros)
            self._guess[pos] = arr
            if STAGE_FIELDS[field][0] == "h":
                self._guess[self._t_idx] = np.concatenate([[0.0], np.cumsum(self._guess[self._h_idx])])

    def get(self, stage: int, field: str) -> np.ndarray:
        """A copy of ``field`` of ``stage`` (fields as for :meth:`set`; always an array, ``(1,)`` for steps).

        Raises:
            ValueError: as for :meth:`set`, or a guess field while no guess is stored.
        """
        pos, role = self._stage_positions(stage, field, "get")
        if role == "lb":
            return self._lbw[pos].copy()
        if role == "ub":
            return self._ubw[pos].copy()
        if self._guess is None:
            raise ValueError(f"Transcription.get: no initial guess is stored (field {field!r}); use set or set_guess")
        return self._guess[pos].copy()

    def set_guess(self, primal: np.ndarray | None) -> None:
        """Store a whole initial guess (a primal vector, e.g. from :meth:`pack_guess`) for solves without ``guess``;
        None goes back to the default straight line of :meth:`line_guess`.

        Raises:
            ValueError: not ``num_variables`` finite numbers.
        """
        if primal is None:
            self._guess = None
            return
        arr = np.asarray(primal, dtype=float)
        if arr.shape != (self.num_variables,):
            raise ValueError(f"Transcription.set_guess: needs shape ({self.num_variables},), got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError("Transcription.set_guess: the guess must be finite")
        self._guess = arr.copy()

    def get_guess(self) -> np.ndarray | None:
        """A copy of the stored initial guess, or None (solves then start from :meth:`line_guess`)."""
        return None if self._guess is None else self._guess.copy()


__all__ = ["STAGE_FIELDS", "StageAccessMixin"]
