"""Shared machinery of the typed option objects (:class:`~seagul_control.mpc.MPCOptions`,
:class:`~seagul_control.mpc.FullHorizonOptions`, :class:`~seagul_control.transcription_options.TranscriptionOptions`).

In the spirit of acados' ``AcadosOcpOptions``: one frozen dataclass per configurable object, every field typed,
documented and checked in ``__post_init__`` (an error names the field and its allowed values), JSON-ready through
:meth:`OptionsBase.to_dict` / :meth:`OptionsBase.from_dict` (the MPC file format stores them), and changed with
:meth:`OptionsBase.replace` (a validated copy). The old keyword arguments of the controllers still work through
:func:`merge_deprecated`, which moves them into the options with a :class:`DeprecationWarning`.
"""

from __future__ import annotations

import dataclasses
import math
import os
import warnings
from collections.abc import Iterable, Mapping
from typing import Any, TypeVar

import numpy as np

_O = TypeVar("_O", bound="OptionsBase")


class OptionsBase:
    """Mixin of the frozen option dataclasses: JSON round trip and validated copies."""

    def to_dict(self) -> dict[str, Any]:
        """The options as JSON-ready builtins (tuples become lists, paths strings); :meth:`from_dict` inverts it."""
        return {f.name: _jsonable(getattr(self, f.name)) for f in dataclasses.fields(self)}  # type: ignore[arg-type]

    @classmethod
    def from_dict(cls: type[_O], data: Mapping[str, Any]) -> _O:
        """Options from :meth:`to_dict`'s output; missing keys keep their defaults.

        Raises:
            ValueError: ``data`` is not a mapping, has a key that is not a field (the message lists the fields), or
                a value fails validation.
        """
        if not isinstance(data, Mapping):
            raise ValueError(f"{cls.__name__}.from_dict needs a mapping, got {type(data).__name__}")
        names = [f.name for f in dataclasses.fields(cls)]  # type: ignore[arg-type]
        unknown = sorted(str(k) for k in data if k not in names)
        if unknown:
            raise ValueError(f"{cls.__name__}.from_dict: unknown option(s) {unknown}; the options are {names}")
        return cls(**dict(data))

    def replace(self: _O, **changes: Any) -> _O:
        """A copy with ``changes`` applied and validated again (``dataclasses.replace``)."""
        return dataclasses.replace(self, **changes)  # type: ignore[type-var]


def _jsonable(value: Any) -> Any:
    if isinstance(value, OptionsBase):
        return value.to_dict()
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (tuple, list)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    return value


# ------------------------------------------------------------------------------------------------ validation
def fail(owner: str, name: str, allowed: str, value: Any) -> ValueError:
    """``ValueError("<owner>.<name> must be <allowed>, got <value>")``."""
    return ValueError(f"{owner}.{name} must be {allowed}, got {value!r}")


def choice(owner: str, name: str, value: Any, allowed: Iterable[Any]) -> Any:
    """``value`` if it is one of ``allowed`` (None included when listed), else a ValueError listing them."""
    allowed = tuple(allowed)
    if not any(value is a or (a is not None and value == a and type(value) is type(a)) for a in allowed):
        names = ", ".join(repr(a) for a in allowed)
        raise fail(owner, name, f"one of {names}", value)
    return value


def flag(owner: str, name: str, value: Any, optional: bool = False) -> bool | None:
    """A bool (numpy bools accepted), or None when ``optional``."""
    if value is None and optional:
        return None
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    raise fail(owner, name, "True or False" + (" or None" if optional else ""), value)


def number(
    owner: str,
    name: str,
    value: Any,
    *,
    positive: bool = False,
    nonnegative: bool = False,
    optional: bool = False,
    finite: bool = True,
) -> float | None:
    """A real number (float), checked; None when ``optional``."""
    if value is None and optional:
        return None
    what = "a positive number" if positive else "a finite number >= 0" if nonnegative else "a finite number"
    what += " or None" if optional else ""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise fail(owner, name, what, value)
    out = float(value)
    if math.isnan(out) or (finite and not math.isfinite(out)):
        raise fail(owner, name, what, value)
    if (positive and not out > 0) or (nonnegative and not out >= 0):
        raise fail(owner, name, what, value)
    return out


def integer(owner: str, name: str, value: Any, *, minimum: int, optional: bool = False) -> int | None:
    """An int ``>= minimum`` (numpy ints accepted, bools not); None when ``optional``."""
    if value is None and optional:
        return None
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or int(value) < minimum:
        raise fail(owner, name, f"an integer >= {minimum}" + (" or None" if optional else ""), value)
    return int(value)


def strings(owner: str, name: str, value: Any, optional: bool = True) -> tuple[str, ...] | None:
    """A tuple of strings (from any sequence of strings); None when ``optional``."""
    if value is None and optional:
        return None
    if isinstance(value, str) or not isinstance(value, (tuple, list)) or not all(isinstance(v, str) for v in value):
        raise fail(owner, name, "a sequence of strings" + (" or None" if optional else ""), value)
    return tuple(value)


def path(owner: str, name: str, value: Any) -> str | None:
    """A directory path as a string, or None."""
    if value is None:
        return None
    if not isinstance(value, (str, os.PathLike)):
        raise fail(owner, name, "a path (str or os.PathLike) or None", value)
    return os.fspath(value)


def mapping(owner: str, name: str, value: Any) -> dict[str, Any]:
    """A copy of a str-keyed mapping (None: empty)."""
    if value is None:
        return {}
    if not isinstance(value, Mapping) or not all(isinstance(k, str) for k in value):
        raise fail(owner, name, "a mapping with string keys", value)
    return dict(value)


def set_field(obj: Any, name: str, value: Any) -> None:
    """Write a normalised value into a frozen dataclass (from its ``__post_init__`` only)."""
    object.__setattr__(obj, name, value)


# ------------------------------------------------------------------------------------- deprecated keywords
def merge_deprecated(
    owner: str, options_cls: type[_O], options: _O | None, deprecated: Mapping[str, Any], stacklevel: int = 3
) -> _O:
    """``options`` (default ``options_cls()``) with the old keyword arguments ``deprecated`` moved into it.

    One :class:`DeprecationWarning` names the old keywords and their new place; a name that is not a field of
    ``options_cls`` raises a TypeError, as for any unknown keyword argument.
    """
    if options is None:
        options = options_cls()
    elif not isinstance(options, options_cls):
        raise TypeError(f"{owner}: options must be a {options_cls.__name__}, got {type(options).__name__}")
    if not deprecated:
        return options
    names = {f.name for f in dataclasses.fields(options_cls)}  # type: ignore[arg-type]
    unknown = sorted(k for k in deprecated if k not in names)
    if unknown:
        raise TypeError(f"{owner}() got unexpected keyword argument(s) {unknown}")
    given = ", ".join(f"{key}=..." for key in deprecated)
    warnings.warn(
        f"{owner}(..., {given}) is deprecated; pass {options_cls.__name__}({given}) as options",
        DeprecationWarning,
        stacklevel=stacklevel,
    )
    return options.replace(**deprecated)
