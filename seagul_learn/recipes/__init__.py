"""Training recipes and experiment presets as data: one YAML file per task (``acrobot.yml``, ``glider.yml``; a task
without one gets ``default.yml``), the way rl-zoo keeps its ``hyperparams/*.yml`` (and this package its RL
baselines', :mod:`seagul_learn.baselines`).

A file holds two mappings::

    recipes:            # name -> TrainConfig fields, nested as TrainConfig.to_dict (fields left out: the defaults)
      default: {...}    # the task's measured best: TrainConfig.recipe(task), `seagul train`
      paper: {}         # the paper's settings (the dataclass defaults)
      shipped:          # the run behind the shipped network (benchmarks/bench_closed_loop.py)
        extends: default
        runtime: {snapshots: [1000], progress: false}
    presets:            # name -> seagul_learn.experiment.Preset fields (`seagul reproduce --preset NAME`)
      smoke: {...}
      quick: {...}
      paper: {...}

:func:`recipe` and :func:`preset` return validated plain dicts (a recipe is checked by building its
:class:`~seagul_learn.config.TrainConfig`; ``extends`` is resolved, parts merged field by field). A task of your own
gets its recipes from a file you :func:`register` for its name, or pass as ``path``; a task whose profile still sets
the deprecated ``TaskProfile.train_recipe`` / ``presets`` gets those as its ``default`` recipe and its presets.
"""

from __future__ import annotations

import copy
import functools
import os
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from seagul_envs import Task, resolve_task

RECIPES_DIR = Path(__file__).resolve().parent
"""The package's recipe files."""

_REGISTERED: dict[str, Path] = {}


def register(task_name: str, path: str | os.PathLike[str]) -> None:
    """Use the YAML file ``path`` for the task named ``task_name`` (a task of your own, or other recipes for a
    built-in one); it must read as a recipe book (checked now)."""
    path = Path(path)
    _load(path)  # fails now, naming the file, if it is not a recipe book
    _REGISTERED[task_name] = path


def book_path(task: str | Task) -> Path:
    """The recipe file of ``task``: registered (:func:`register`), else ``<name>.yml`` of this package, else
    ``default.yml``."""
    name = task.name if isinstance(task, Task) else str(task)
    if name in _REGISTERED:
        return _REGISTERED[name]
    own = RECIPES_DIR / f"{name}.yml"
    return own if own.is_file() else RECIPES_DIR / "default.yml"


@functools.cache
def _load_cached(path: str, mtime: float) -> dict[str, Any]:
    import yaml  # type: ignore[import-untyped]

    try:
        data = yaml.safe_load(Path(path).read_text())
    except yaml.YAMLError as exc:
        raise ValueError(f"recipe file {path!r} is not valid YAML: {exc}") from None
    data = data or {}
    if not isinstance(data, dict) or set(data) - {"recipes", "presets"}:
        raise ValueError(f"recipe file {path!r} must be a mapping with 'recipes' and 'presets' (got {sorted(data)})")
    for section in ("recipes", "presets"):
        entries = data.setdefault(section, {}) or {}
        data[section] = entries
        if not isinstance(entries, dict) or not all(isinstance(v, dict) for v in entries.values()):
            raise ValueError(f"recipe file {path!r}: {section} must map names to mappings")
    return data


def _load(path: Path) -> dict[str, Any]:
    return copy.deepcopy(_load_cached(str(path), path.stat().st_mtime))


def recipe_book(task: str | Task, path: str | os.PathLike[str] | None = None) -> dict[str, Any]:
    """The whole file of ``task`` (or ``path``): ``{"recipes": {name: fields}, "presets": {name: fields}}``, the
    recipes with ``extends`` resolved and a deprecated ``TaskProfile.train_recipe`` / ``presets`` of the task in
    place of the file's ``default`` recipe / presets."""
    book = _load(Path(path) if path is not None else book_path(task))
    recipes = book["recipes"]
    resolved = {name: _resolve(recipes, name, ()) for name in recipes}
    presets = {name: _preset_fields(fields) for name, fields in book["presets"].items()}
    if isinstance(task, Task) and path is None:
        given = task.profile.__dict__.get("_given_train_recipe")
        if given is not None:
            resolved["default"] = dict(given)
        given_presets = task.profile.__dict__.get("_given_presets")
        if given_presets is not None:
            presets = {str(k): dict(v) for k, v in given_presets.items()}
    return {"recipes": resolved, "presets": presets}


def _resolve(recipes: Mapping[str, Any], name: str, seen: tuple[str, ...]) -> dict[str, Any]:
    if name in seen:
        raise ValueError(f"recipe {name!r} extends itself ({' -> '.join((*seen, name))})")
    fields = dict(recipes[name])
    parent = fields.pop("extends", None)
    if parent is None:
        return fields
    if parent not in recipes:
        raise ValueError(f"recipe {name!r} extends unknown recipe {parent!r}; the file has {sorted(recipes)}")
    base = _resolve(recipes, parent, (*seen, name))
    for key, value in fields.items():
        if isinstance(value, Mapping) and isinstance(base.get(key), Mapping):
            base[key] = {**base[key], **value}  # a part merges field by field
        else:
            base[key] = value
    return base


def _preset_fields(fields: Mapping[str, Any]) -> dict[str, Any]:
    """A preset as the experiment takes it: lists as tuples, ``train_overrides`` as ``(("key", value), ...)``."""
    out: dict[str, Any] = {}
    for key, value in fields.items():
        if key == "train_overrides":
            if not isinstance(value, Mapping):
                raise ValueError(f"preset train_overrides must be a mapping of TrainConfig fields, got {value!r}")
            out[key] = tuple((str(k), tuple(v) if isinstance(v, list) else v) for k, v in value.items())
        else:
            out[key] = tuple(value) if isinstance(value, list) else value
    return out


def recipe_names(task: str | Task, path: str | os.PathLike[str] | None = None) -> list[str]:
    """The recipes of ``task`` (or of the file ``path``)."""
    return sorted(recipe_book(task, path)["recipes"])


def recipe(task: str | Task, name: str = "default", path: str | os.PathLike[str] | None = None) -> dict[str, Any]:
    """The TrainConfig fields of recipe ``name`` of ``task`` (nested as :meth:`TrainConfig.to_dict`, only the fields
    the recipe sets; a deprecated ``TaskProfile.train_recipe`` in its flat form), checked by building the config.

    Raises:
        ValueError: no such recipe, or it names a field :class:`~seagul_learn.config.TrainConfig` does not have (or
            a bad value), naming the file.
    """
    from seagul_learn.config import TrainConfig

    resolved = resolve_task(task) if isinstance(task, str) else task
    book = recipe_book(resolved, path)
    where = str(path) if path is not None else str(book_path(resolved))
    if name not in book["recipes"]:
        raise ValueError(f"unknown recipe {name!r} for task {resolved.name!r}; {where} has {sorted(book['recipes'])}")
    fields = book["recipes"][name]
    if "task" in fields:
        raise ValueError(f"recipe {name!r} of {where} may not set the task")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            TrainConfig.from_dict({**fields, "task": resolved})
    except (TypeError, ValueError) as exc:
        raise ValueError(f"recipe {name!r} of {resolved.name!r} ({where}): {exc}") from None
    return fields


def preset(task: str | Task, name: str, path: str | os.PathLike[str] | None = None) -> dict[str, Any]:
    """The experiment preset ``name`` of ``task``: :class:`~seagul_learn.experiment.Preset` field -> value (lists as
    tuples, ``train_overrides`` as ``(("field", value), ...)`` with ``"method:field"`` for one method and dotted
    TrainConfig fields such as ``"sampler.episodes"``).

    Raises:
        ValueError: no such preset (naming the file and its presets).
    """
    resolved = resolve_task(task) if isinstance(task, str) else task
    presets = recipe_book(resolved, path)["presets"]
    if name not in presets:
        where = str(path) if path is not None else str(book_path(resolved))
        raise ValueError(f"unknown preset {name!r} for task {resolved.name!r}; {where} has {sorted(presets)}")
    return presets[name]


def presets(task: str | Task, path: str | os.PathLike[str] | None = None) -> dict[str, dict[str, Any]]:
    """Every experiment preset of ``task``: name -> :func:`preset`."""
    resolved = resolve_task(task) if isinstance(task, str) else task
    return recipe_book(resolved, path)["presets"]


def legacy_profile_data(book: str, field: str) -> dict[str, Any]:
    """What the deprecated ``TaskProfile.presets`` / ``train_recipe`` of a built-in task read as (the recipe file
    ``book``'s presets / default recipe in the flat TrainConfig names they had): for code that still reads them."""
    from seagul_learn.config import flat_fields, flat_name

    data = recipe_book(book, RECIPES_DIR / f"{book}.yml")
    if field == "train_recipe":
        return flat_fields(data["recipes"].get("default", {}))
    out: dict[str, Any] = {}
    for name, fields in data["presets"].items():
        fields = dict(fields)
        if "train_overrides" in fields:
            renamed = []
            for key, value in fields["train_overrides"]:
                method, colon, field_name = key.rpartition(":")
                renamed.append((f"{method}{colon}{flat_name(field_name)}", value))
            fields["train_overrides"] = tuple(renamed)
        out[name] = fields
    return out
