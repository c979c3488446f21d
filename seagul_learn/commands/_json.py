"""JSON values on the command line: an argparse ``type`` (:func:`json_value`) and a tyro annotation
(:data:`JsonObject`) for the dict fields of a config whose flags tyro derives.

A dict of settings (SB3 constructor overrides, solver options) has no natural ``--key value`` form, so its flag takes
one JSON object: ``--algo-overrides '{"ent_coef": 0.01}'``. Both parsers refuse text that is not JSON, or JSON of the
wrong kind, with a message that names the flag and shows an example.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from typing import Annotated, Any

from tyro.constructors import PrimitiveConstructorSpec

__all__ = ["JsonObject", "json_value"]

_NAMES: dict[type, str] = {dict: "object", list: "array"}
_EXAMPLES: dict[type, str] = {dict: '{"max_iter": 500}', list: "[1, 2]"}


def _parse(value: str, kind: type) -> Any:
    """``value`` as JSON of ``kind``; a ValueError (argparse and tyro report it as a bad flag) otherwise."""
    try:
        data = json.loads(value)
    except json.JSONDecodeError as exc:
        raise ValueError(f"not valid JSON ({exc}): {value!r}") from None
    if not isinstance(data, kind):
        name = _NAMES.get(kind, kind.__name__)
        raise ValueError(f"expected a JSON {name} like '{_EXAMPLES.get(kind, '...')}', got {value!r}")
    return data


def json_value(kind: type) -> Callable[[str], Any]:
    """An argparse ``type``: parser of a JSON text whose value is a ``kind`` (``dict``: an object, ``list``: an
    array)."""
    name = _NAMES.get(kind, kind.__name__)

    def parse(value: str) -> Any:
        try:
            return _parse(value, kind)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    parse.__name__ = f"json_{name}"
    return parse


JsonObject = Annotated[
    dict[str, Any],
    PrimitiveConstructorSpec(
        nargs=1,
        metavar="JSON",
        instance_from_str=lambda args: _parse(args[0], dict),
        is_instance=lambda value: isinstance(value, dict),
        str_from_instance=lambda value: [json.dumps(value)],
    ),
]
"""A ``dict[str, Any]`` field whose tyro flag takes one JSON object (``--name '{"key": 1}'``); the annotation changes
nothing but the command line (the field is a plain dict)."""
