"""Command-line options derived from a flat config dataclass with plain :mod:`argparse` (``seagul reproduce`` from
``ExperimentConfig``, the SB3 baselines' script from ``SB3Config``). ``seagul train``, whose config is nested, derives
its flags with tyro instead (:mod:`seagul_learn.commands.train`).

:func:`add_dataclass_arguments` declares one option per field of a dataclass:

* the flag is ``--field-name`` (underscores become dashes) and its ``dest`` the field name, so
  :func:`dataclass_from_args` rebuilds the config from the parsed namespace;
* the value type comes from the annotation: ``int``, ``float``, ``str``, ``Path``, ``Literal[...]`` (choices),
  ``bool`` as ``--flag/--no-flag`` (:class:`argparse.BooleanOptionalAction`), ``tuple[int, ...]`` (or of floats,
  strings; also ``list``) as a comma-separated list (``--hidden 32,32``; an empty string is the empty tuple), ``dict``
  as a JSON object; ``X | None`` is parsed as ``X`` with ``None`` as the default;
* the default is the field's default, and the help text is the string literal right below the field in the class
  source (its docstring, read with :mod:`ast`), with reST markup removed and the default appended.

A field added to the dataclass is therefore reachable from the command line without any edit here or in the
command. Per-field :class:`Option` entries only refine what the dataclass cannot say: a validating ``type`` (e.g.
:func:`~seagul_learn.commands._args.positive_int`, whose errors name the accepted range), ``choices``, extra
spellings kept for compatibility (``aliases``, e.g. ``--ppo`` for ``ppo_model``), a CLI-specific default,
``required``, a positional argument.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import inspect
import json
import re
import textwrap
import types
import typing
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

_UNSET: Any = object()


@dataclasses.dataclass(frozen=True)
class Option:
    """How the option of one field differs from what its annotation, default and docstring give."""

    aliases: tuple[str, ...] = ()
    """Further spellings (``"--sobolev"``); each is a hidden option of its own, so an error names the one typed."""
    type: Callable[[str], Any] | None = None
    """Parser of the value (replaces the annotation's); raise :class:`argparse.ArgumentTypeError` on bad input."""
    choices: Sequence[Any] | None = None
    """Accepted values."""
    default: Any = _UNSET
    """Default of the command line when it differs from the dataclass's."""
    required: bool = False
    """The option must be given (no default shown)."""
    positional: bool = False
    """A positional argument named after the field instead of ``--field-name``."""
    metavar: str | None = None
    """Placeholder of the value in the usage line."""
    help: str | None = None
    """Help text replacing the field's docstring."""
    note: str | None = None
    """Text appended to the docstring help (e.g. the accepted values when ``type`` checks them)."""


# ------------------------------------------------------------------------------------------------ docstrings
def field_docstrings(cls: type) -> dict[str, str]:
    """The string literal right below each annotated field in the source of ``cls`` (and its dataclass bases).

    Returns the literals cleaned by :func:`inspect.cleandoc`; fields without one (or classes without source) are
    missing from the result.
    """
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if klass is object or not dataclasses.is_dataclass(klass):
            continue
        try:
            source = textwrap.dedent(inspect.getsource(klass))
        except (OSError, TypeError):
            continue
        tree = ast.parse(source)
        node = next((n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == klass.__name__), None)
        if node is None:
            continue
        for stmt, following in zip(node.body, node.body[1:], strict=False):
            if (
                isinstance(stmt, ast.AnnAssign)
                and isinstance(stmt.target, ast.Name)
                and isinstance(following, ast.Expr)
                and isinstance(following.value, ast.Constant)
                and isinstance(following.value.value, str)
            ):
                docs[stmt.target.id] = inspect.cleandoc(following.value.value)
    return docs


_ROLE = re.compile(r":[\w:.-]+:`([^`]+)`")  # :class:`~a.b.C`, :mod:`a.b`, :data:`title <a.b>`
_LITERAL = re.compile(r"``(.+?)``")


def _role_text(match: re.Match[str]) -> str:
    content = match.group(1)
    if "<" in content:
        return content.split("<", 1)[0].strip()
    return content[1:].rsplit(".", 1)[-1] if content.startswith("~") else content


def plain_text(doc: str) -> str:
    """A docstring as one line of plain text: reST roles and literals unwrapped, whitespace collapsed."""
    text = _LITERAL.sub(r"\1", _ROLE.sub(_role_text, doc))
    return " ".join(text.split())


# ------------------------------------------------------------------------------------------------ value parsers
def integer(value: str) -> int:
    """An integer."""
    try:
        return int(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {value!r}") from None


def number(value: str) -> float:
    """A (floating-point) number."""
    try:
        return float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {value!r}") from None


_SCALARS: dict[Any, tuple[Callable[[str], Any], str]] = {
    int: (integer, "integers"),
    float: (number, "numbers"),
    str: (str, "strings"),
    Path: (Path, "paths"),
}


def comma_list(item: Callable[[str], Any], what: str, container: type = tuple, length: int | None = None) -> Any:
    """Parser of ``"a,b,c"`` into a ``container`` of ``item(a), ...`` (the empty string gives an empty one)."""

    def parse(value: str) -> Any:
        parts = [p.strip() for p in value.split(",")] if value.strip() else []
        try:
            out = container(item(p) for p in parts)
        except (ValueError, argparse.ArgumentTypeError):
            raise argparse.ArgumentTypeError(f"expected comma-separated {what} like 32,32, got {value!r}") from None
        if length is not None and len(out) != length:
            raise argparse.ArgumentTypeError(f"expected {length} comma-separated {what}, got {value!r}")
        return out

    parse.__name__ = f"comma_separated_{what}"
    return parse


def json_value(kind: type) -> Callable[[str], Any]:
    """Parser of a JSON text whose value is a ``kind`` (``dict``: an object, ``list``: an array)."""
    names: dict[type, str] = {dict: "object", list: "array"}
    examples: dict[type, str] = {dict: '{"max_iter": 500}', list: "[1, 2]"}
    name = names.get(kind, kind.__name__)
    example = examples.get(kind, "...")

    def parse(value: str) -> Any:
        try:
            data = json.loads(value)
        except json.JSONDecodeError as exc:
            raise argparse.ArgumentTypeError(f"not valid JSON ({exc}): {value!r}") from None
        if not isinstance(data, kind):
            raise argparse.ArgumentTypeError(f"expected a JSON {name} like '{example}', got {value!r}")
        return data

    parse.__name__ = f"json_{name}"
    return parse


def _strip_optional(annotation: Any) -> Any:
    """``X`` of ``X | None`` / ``Optional[X]``; other annotations unchanged."""
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(annotation) if a is not type(None)]
        if len(args) == 1:
            return args[0]
    return annotation


def value_parser(annotation: Any) -> tuple[Callable[[str], Any] | None, Sequence[Any] | None, str | None]:
    """``(type, choices, metavar)`` of a non-bool annotation; a :class:`TypeError` for one this cannot parse."""
    annotation = _strip_optional(annotation)
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if annotation in _SCALARS:
        return _SCALARS[annotation][0], None, None
    if origin is typing.Literal:
        kinds = {type(a) for a in args}
        if len(kinds) == 1 and next(iter(kinds)) in _SCALARS:
            return _SCALARS[next(iter(kinds))][0], args, None
    item, length = None, None
    if origin is list and len(args) == 1:
        item = args[0]
    elif origin is tuple and len(args) == 2 and args[1] is Ellipsis:
        item = args[0]
    elif origin is tuple and args and Ellipsis not in args and len(set(args)) == 1:
        item, length = args[0], len(args)
    if item in _SCALARS:
        parse, what = _SCALARS[item]
        metavar = "A,B,..." if length is None or length > 8 else ",".join("ABCDEFGH"[:length])
        return comma_list(parse, what, origin, length), None, metavar
    if annotation in (dict, list) or origin in (dict, list, Mapping):
        kind = list if list in (annotation, origin) else dict
        return json_value(kind), None, "JSON"
    raise TypeError(f"no command-line parser for annotation {annotation!r}")


def _is_bool(annotation: Any) -> bool:
    return _strip_optional(annotation) is bool


def _show_default(value: Any) -> str | None:
    """The default as typed on the command line (``None``: nothing to show)."""
    if value is None:
        return None
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (tuple, list)):
        return ",".join(str(v) for v in value) if value else "none"
    if isinstance(value, dict):
        return json.dumps(value)
    return str(value)


def _field_default(field: dataclasses.Field[Any]) -> Any:
    if field.default is not dataclasses.MISSING:
        return field.default
    if field.default_factory is not dataclasses.MISSING:
        return field.default_factory()
    return _UNSET


def option_name(field_name: str) -> str:
    """``--field-name`` of ``field_name``."""
    return "--" + field_name.replace("_", "-")


# ------------------------------------------------------------------------------------------------ the options
def add_dataclass_arguments(
    parser: argparse.ArgumentParser | argparse._ArgumentGroup,
    cls: type,
    options: Mapping[str, Option] | None = None,
    exclude: Iterable[str] = (),
) -> list[argparse.Action]:
    """Declare one option per init field of the dataclass ``cls`` (see the module docstring); returns the actions.

    ``options`` refines fields by name (a name that is not a field is an error, so a renamed field cannot silently
    lose its refinement); ``exclude`` names fields left off the command line (they keep the dataclass default).
    """
    options = dict(options or {})
    excluded = set(exclude)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted((set(options) | excluded) - names)
    if unknown:
        raise ValueError(f"{cls.__name__} has no fields {unknown}")
    hints = typing.get_type_hints(cls)
    docs = field_docstrings(cls)
    actions: list[argparse.Action] = []
    for field in dataclasses.fields(cls):
        if not field.init or field.name in excluded:
            continue
        option = options.get(field.name, Option())
        actions.append(_add_field(parser, cls, field, hints[field.name], docs.get(field.name), option))
    return actions


def _add_field(
    parser: argparse.ArgumentParser | argparse._ArgumentGroup,
    cls: type,
    field: dataclasses.Field[Any],
    annotation: Any,
    doc: str | None,
    option: Option,
) -> argparse.Action:
    default = option.default if option.default is not _UNSET else _field_default(field)
    required = option.required or (default is _UNSET and not option.positional)
    if option.aliases and (required or option.positional):
        raise ValueError(f"{cls.__name__}.{field.name}: aliases of a required or positional argument")
    kwargs: dict[str, Any] = {}
    if _is_bool(annotation) and option.type is None and not option.positional:
        kwargs["action"] = argparse.BooleanOptionalAction
    else:
        parse, choices, metavar = value_parser(annotation) if option.type is None else (option.type, None, None)
        kwargs["type"] = parse
        if option.choices is not None or choices is not None:
            kwargs["choices"] = option.choices if option.choices is not None else choices
        if option.metavar or (metavar and "choices" not in kwargs):
            kwargs["metavar"] = option.metavar or metavar
    if option.positional:
        flags: tuple[str, ...] = (field.name,)
    else:
        flags = (option_name(field.name),)
        kwargs["dest"] = field.name
        if required:
            kwargs["required"] = True
        else:
            kwargs["default"] = default
    action = parser.add_argument(*flags, **kwargs)
    # Set after construction: BooleanOptionalAction (Python < 3.14) would append its own "(default: ...)".
    action.help = _help(option, doc, None if required or option.positional else default)
    for alias in option.aliases:
        parser.add_argument(alias, **kwargs).help = argparse.SUPPRESS
    return action


def _help(option: Option, doc: str | None, default: Any) -> str:
    text = option.help if option.help is not None else plain_text(doc or "")
    if option.note:
        text = f"{text} ({option.note})" if text else option.note
    if option.aliases:
        text = f"{text} (also: {', '.join(option.aliases)})"
    shown = _show_default(default)
    if shown is not None:
        text = f"{text} (default: {shown})" if text else f"default: {shown}"
    return text.replace("%", "%%")  # argparse %-formats help strings


def dataclass_from_args(cls: type, args: argparse.Namespace, **overrides: Any) -> Any:
    """An instance of ``cls`` from the options :func:`add_dataclass_arguments` declared (and ``overrides``).

    Fields absent from ``args`` (excluded ones) keep their dataclass default.
    """
    values = {f.name: getattr(args, f.name) for f in dataclasses.fields(cls) if f.init and hasattr(args, f.name)}
    return cls(**{**values, **overrides})
