"""The deprecated parts of :class:`~seagul_envs.tasks.profile.TaskProfile`, kept working for users' tasks.

* ``presets`` and ``train_recipe`` moved to ``seagul_learn/recipes/<task>.yml``: given, they still count (with a
  ``DeprecationWarning``); read, they return the recipe file's data in the old flat form.
* the flat ``mpc_horizon``, ``mpc_trust_region``, ``mpc_goal_blend`` and ``mpc_final_soft_weight`` became
  ``TaskProfile.mpc`` (:class:`~seagul_envs.tasks.mpc_defaults.MPCDefaults`): as keywords they fill it in.
* the module constants ``DEFAULT_PRESETS`` and ``SMOKE_TRAIN_OVERRIDES`` moved to ``seagul_learn/recipes/default.yml``.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from seagul_envs.tasks.mpc_defaults import LEGACY_NAMES as _MPC_LEGACY
from seagul_envs.tasks.mpc_defaults import MPCDefaults

if TYPE_CHECKING:
    from seagul_envs.tasks.profile import TaskProfile


_MOVED = {
    "presets": "seagul_learn.recipes.preset(task, name) (seagul_learn/recipes/<task>.yml)",
    "train_recipe": "seagul_learn.recipes.recipe(task) / TrainConfig.recipe(task) (seagul_learn/recipes/<task>.yml)",
}


class _MovedToRecipes:
    """A deprecated :class:`TaskProfile` field whose data moved to ``seagul_learn/recipes/*.yml``.

    Given (``TaskProfile(presets=...)`` in a task of your own) it still counts, with a ``DeprecationWarning``: it is
    the task's presets or default recipe, and part of the fingerprint. Not given, reading it warns and returns the
    recipe file's data in the form the field had (flat TrainConfig names), for code that still reads it."""

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name
        self.private = f"_given_{name}"

    def __get__(self, obj: Any, objtype: type | None = None) -> Any:
        if obj is None:
            return None  # the dataclass default: not given
        given = obj.__dict__.get(self.private)
        if given is not None:
            return given
        return _RecipeView(obj.__dict__.get("_recipe_book", "default"), self.name)

    def __set__(self, obj: Any, value: Any) -> None:
        if isinstance(value, _RecipeView):  # dataclasses.replace of a profile: still not given, same recipe file
            obj.__dict__.pop(self.private, None)
            obj.__dict__["_recipe_book"] = value.book
            return
        if value is None or isinstance(value, _MovedToRecipes):  # not given (the dataclass passes its default)
            obj.__dict__.pop(self.private, None)
            return
        warnings.warn(
            f"TaskProfile({self.name}=...) is deprecated; put the task's {self.name} in a recipe file "
            f"(seagul_learn.recipes.register) and use {_MOVED[self.name]}",
            DeprecationWarning,
            stacklevel=4,
        )
        if self.name == "presets":
            value = {str(k): dict(v) for k, v in dict(value).items()}
        else:
            value = {str(k): v for k, v in dict(value).items()}
        obj.__dict__[self.private] = value


class _RecipeView(Mapping[str, Any]):
    """What a profile's deprecated ``presets`` / ``train_recipe`` read as when not given: the recipe file's data
    (:func:`seagul_learn.recipes.legacy_profile_data`), loaded, with a ``DeprecationWarning``, when first looked
    into, so copying a profile (``dataclasses.replace``) neither warns nor turns the data into given data."""

    def __init__(self, book: str, name: str) -> None:
        self.book = book
        self.name = name
        self._data: dict[str, Any] | None = None

    def _load(self) -> dict[str, Any]:
        if self._data is None:
            warnings.warn(
                f"TaskProfile.{self.name} is deprecated (the data moved out of the task profile); use "
                f"{_MOVED[self.name]}",
                DeprecationWarning,
                stacklevel=3,
            )
            # The upper layer's data, for the deprecated path only: seagul_envs must import without seagul_learn.
            from seagul_learn.recipes import legacy_profile_data

            self._data = legacy_profile_data(self.book, self.name)
        return self._data

    def __getitem__(self, key: str) -> Any:
        return self._load()[key]

    def __iter__(self) -> Any:
        return iter(self._load())

    def __len__(self) -> int:
        return len(self._load())

    def __repr__(self) -> str:
        return f"<TaskProfile.{self.name} of seagul_learn/recipes/{self.book}.yml (deprecated)>"


def _given_only(name: str) -> Any:
    """Fingerprint rule of a deprecated field: it enters only when given (:meth:`Task.fingerprint`)."""
    return lambda profile: profile.__dict__.get(f"_given_{name}") is None


def _accept_flat_mpc_names(init: Callable[..., None]) -> Callable[..., None]:
    """Wrap the dataclass ``__init__`` so ``TaskProfile(mpc_horizon=5, ...)`` keeps working: the former flat names
    become :attr:`TaskProfile.mpc`'s fields, with a ``DeprecationWarning``."""

    def __init__(self: TaskProfile, *args: Any, **kwargs: Any) -> None:
        flat = {name: kwargs.pop(name) for name in _MPC_LEGACY if name in kwargs}
        if flat:
            moved = ", ".join(f"{name} -> mpc.{_MPC_LEGACY[name]}" for name in flat)
            warnings.warn(
                f"TaskProfile's flat MPC defaults are deprecated ({moved}); pass mpc=MPCDefaults(...) "
                "(seagul_envs.tasks.mpc_defaults)",
                DeprecationWarning,
                stacklevel=2,
            )
            base = kwargs.get("mpc", MPCDefaults())
            for name, value in flat.items():  # each error names the field the caller gave
                try:
                    base = replace(base, **{_MPC_LEGACY[name]: value})
                except ValueError as exc:
                    message = str(exc).replace(f"MPCDefaults.{_MPC_LEGACY[name]}", f"TaskProfile.{name}")
                    raise ValueError(message) from None
            kwargs["mpc"] = base
        init(self, *args, **kwargs)

    __init__.__doc__ = init.__doc__
    __init__.__wrapped__ = init  # type: ignore[attr-defined]
    return __init__


def legacy_module_attribute(name: str, module: str) -> Any:
    """``DEFAULT_PRESETS`` and ``SMOKE_TRAIN_OVERRIDES``: deprecated, the data is in
    ``seagul_learn/recipes/default.yml``."""
    if name in ("DEFAULT_PRESETS", "SMOKE_TRAIN_OVERRIDES"):
        from seagul_learn.recipes import legacy_profile_data  # the deprecated path only

        warnings.warn(
            f"seagul_envs.tasks.profile.{name} is deprecated; use seagul_learn.recipes.preset(task, name) "
            "(seagul_learn/recipes/default.yml)",
            DeprecationWarning,
            stacklevel=3,
        )
        presets = legacy_profile_data("default", "presets")
        return presets if name == "DEFAULT_PRESETS" else presets["smoke"]["train_overrides"]
    raise AttributeError(f"module {module!r} has no attribute {name!r}")
