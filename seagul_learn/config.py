"""The configuration of a training run (:func:`seagul_learn.training.train`): :class:`TrainConfig` and its parts.

One frozen dataclass per concern, each validated when made (errors name the field), nested in one
:class:`TrainConfig` of 14 fields::

    TrainConfig(
        task="acrobot", seed=0, budget=1000,
        sampler=ClosedLoopOptions(episodes=20, uniform_solves=500, ...),   # or UniformOptions() / AdversarialOptions()
        network=NetworkConfig(hidden=(64, 64)),
        schedule=ScheduleConfig(solves_per_round=50, train_steps_per_round=1000),
        loss=LossConfig(sobolev_weight=1.0, value_cap=50.0),
        refit=RefitConfig(steps=20000, ensemble=3, candidates=6),
        selection=SelectionConfig(episodes=100, finalists=4, final_episodes=300),
        runtime=RuntimeConfig(workers=4),
    )

The sampler is chosen by the class of ``sampler`` (its options travel with it, so the adversarial settings cannot
be set on a closed-loop run by mistake). :meth:`TrainConfig.to_dict` / :meth:`TrainConfig.from_dict` give and take
nested JSON-ready data (the form of a run's ``config.json`` and of the recipe files, ``seagul_learn/recipes/*.yml``),
:meth:`TrainConfig.save` / :meth:`TrainConfig.load` a YAML or JSON file, :meth:`TrainConfig.recipe` a task's named
recipe (:mod:`seagul_learn.recipes`). ``seagul train`` derives its flags from these dataclasses with tyro
(``--sampler.episodes 20``, help from the field docstrings).

**The flat names of earlier versions keep working.** Until 0.x the config was one flat dataclass of 59 fields
(``cl_episodes``, ``adv_max_steps``, ``refit_steps``, ``select_episodes``, ``hidden``, ``sobolev_weight``, ...). They
are still accepted as keyword arguments, attributes (read and written) and keys of a stored flat ``config.json``
(read silently: a run made before resumes); keywords and attributes emit a ``DeprecationWarning`` naming the new
place (``cl_episodes -> sampler.episodes``). :data:`LEGACY_NAMES` holds the map. ``sampler="closed-loop"`` (a string)
still selects the options class, and an options object compares equal to its sampler's name.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Annotated, Any, ClassVar, Union

import tyro

from seagul_envs import Task, available_tasks, resolve_task, validate_task
from seagul_learn.config_legacy import LEGACY_NAMES, _legacy_value, flat_fields, flat_name, new_name
from seagul_learn.config_parts import (
    SECTIONS,
    LossConfig,
    NetworkConfig,
    RefitConfig,
    RuntimeConfig,
    ScheduleConfig,
    SelectionConfig,
    _check,
    omitted,
)
from seagul_learn.sampler_options import AdversarialOptions, ClosedLoopOptions, SamplerOptions, UniformOptions

__all__ = [
    "LEGACY_NAMES",
    "SAMPLERS",
    "SAMPLER_OPTIONS",
    "SECTIONS",
    "AdversarialOptions",
    "ClosedLoopOptions",
    "LossConfig",
    "NetworkConfig",
    "RefitConfig",
    "RuntimeConfig",
    "SamplerOptions",
    "ScheduleConfig",
    "SelectionConfig",
    "TrainConfig",
    "UniformOptions",
    "accepted_names",
    "flat_fields",
    "flat_name",
    "new_name",
]

SAMPLERS = ("uniform", "adversarial", "closed-loop")
"""The samplers' names, in the order of :data:`SAMPLER_OPTIONS`."""

SAMPLER_OPTIONS: dict[str, type[SamplerOptions]] = {
    "uniform": UniformOptions,
    "adversarial": AdversarialOptions,
    "closed-loop": ClosedLoopOptions,
}
"""Sampler name -> its options class (the value of ``TrainConfig.sampler``)."""

SamplerChoice = Union[  # noqa: UP007 (tyro reads the Annotated members of a typing.Union)
    Annotated[UniformOptions, tyro.conf.subcommand("uniform")],
    Annotated[AdversarialOptions, tyro.conf.subcommand("adversarial")],
    Annotated[ClosedLoopOptions, tyro.conf.subcommand("closed-loop")],
]
"""The type of ``TrainConfig.sampler``: one options class; ``seagul train`` offers them as ``sampler:uniform``,
``sampler:adversarial`` and ``sampler:closed-loop``."""


def _warn(message: str, stacklevel: int) -> None:
    warnings.warn(message, DeprecationWarning, stacklevel=stacklevel + 1)


def _sampler_options(value: Any) -> SamplerOptions:
    """``value`` as a sampler options object: an object, a sampler name, or ``{"name": ..., **fields}``."""
    if isinstance(value, SamplerOptions):
        return value
    if isinstance(value, str):
        if value not in SAMPLER_OPTIONS:
            raise ValueError(f"unknown sampler {value!r}; choose one of {list(SAMPLERS)}")
        return SAMPLER_OPTIONS[value]()
    if isinstance(value, Mapping):
        data = dict(value)
        name = data.pop("name", None)
        if name not in SAMPLER_OPTIONS:
            raise ValueError(f"sampler: unknown or missing name {name!r}; choose one of {list(SAMPLERS)}")
        return _make(SAMPLER_OPTIONS[name], data, "sampler")
    raise ValueError(
        f"sampler must be one of {[c.__name__ for c in SAMPLER_OPTIONS.values()]} or a sampler name, "
        f"got {type(value).__name__}"
    )


def _make(cls: type, data: Mapping[str, Any], where: str) -> Any:
    """``cls(**data)`` with unknown keys named (``where.key``) and tuples made from lists."""
    known = {f.name: f for f in fields(cls)}
    unknown = sorted(set(data) - set(known))
    if unknown:
        raise ValueError(f"unknown {where} fields {[f'{where}.{k}' for k in unknown]}; known: {sorted(known)}")
    values = {k: tuple(v) if isinstance(v, list) else v for k, v in data.items()}
    try:
        return cls(**values)
    except ValueError as exc:
        message = str(exc)
        raise ValueError(message if f"{where}." in message else f"{where}: {message}") from None


def _translate(kwargs: dict[str, Any], warn: bool, stacklevel: int) -> dict[str, Any]:
    """Keyword arguments with the flat names of earlier versions and the dotted names (``"sampler.episodes"``) moved
    into their parts. A sampler field applies when the chosen sampler has it and is ignored otherwise (as the flat
    ``cl_*`` fields were ignored by the other samplers), so one set of overrides serves runs of every sampler."""
    legacy = {k: kwargs.pop(k) for k in list(kwargs) if k in LEGACY_NAMES}
    dotted = {k: kwargs.pop(k) for k in list(kwargs) if "." in k}
    if "sampler" in kwargs and not isinstance(kwargs["sampler"], SamplerOptions):
        kwargs["sampler"] = _sampler_options(kwargs["sampler"])
    if not legacy and not dotted:
        return kwargs
    if warn and legacy:
        moved = ", ".join(f"{k} -> {new_name(k)}" for k in legacy)
        _warn(f"TrainConfig's flat field names are deprecated: {moved}", stacklevel + 1)
    updates: dict[str, dict[str, Any]] = {}
    sampler = kwargs.get("sampler", AdversarialOptions())
    for key, value in legacy.items():
        part, name, owner = LEGACY_NAMES[key]
        if owner is not None and owner != sampler.name:
            continue
        updates.setdefault(part or "", {})[name] = _legacy_value(key, value)
    for key, value in dotted.items():
        part, _, name = key.partition(".")
        if part == "sampler":
            if name not in {f.name for f in fields(sampler)}:
                if any(name in {f.name for f in fields(c)} for c in SAMPLER_OPTIONS.values()):  # type: ignore[arg-type]
                    continue
                raise ValueError(f"unknown TrainConfig field {key!r}: no sampler has a field {name!r}")
        elif part not in SECTIONS or name not in {f.name for f in fields(SECTIONS[part])}:
            raise ValueError(f"unknown TrainConfig field {key!r}")
        updates.setdefault(part, {})[name] = tuple(value) if isinstance(value, list) else value
    for part, values in updates.items():
        if part == "sampler":
            kwargs["sampler"] = _replace(sampler, values, "sampler")
        else:
            base = kwargs.get(part, SECTIONS[part]())
            kwargs[part] = _replace(_as_section(part, base), values, part)
    return kwargs


def _replace(obj: Any, values: Mapping[str, Any], where: str) -> Any:
    try:
        return replace(obj, **values)
    except ValueError as exc:
        message = str(exc)
        raise ValueError(message if f"{where}." in message else f"{where}: {message}") from None


def _as_section(part: str, value: Any) -> Any:
    cls = SECTIONS[part]
    if isinstance(value, cls):
        return value
    if isinstance(value, Mapping):
        return _make(cls, value, part)
    raise ValueError(f"{part} must be a {cls.__name__} (or a mapping of its fields), got {type(value).__name__}")


@dataclass
class TrainConfig:
    """Everything that defines a training run: the task, the seed, the budget, the sampler with its options, and
    one part per concern (module docstring). ``TrainConfig(task="acrobot")`` alone gives the paper's settings
    (adversarial sampler, 1 x 32 tanh, 100 solves); :meth:`recipe` a task's measured best."""

    task: Annotated[str | Task, tyro.conf.Suppress] = "acrobot"
    """A registered task name (``seagul_envs.available_tasks()``) or a Task object (a custom task, or a variant of a
    built-in one); ``config.json`` stores its name and fingerprint, and a resumed run must have the same task."""
    seed: int = 0
    """Seed of every random stream (starts, initial weights, minibatches)."""
    budget: int = 100
    """Solves spent by the sampler (pretraining solves not included)."""
    sampler: SamplerChoice = field(default_factory=AdversarialOptions)
    """The sampler and its options (:mod:`seagul_learn.sampler_options`): :class:`UniformOptions` (the baseline),
    :class:`AdversarialOptions` (paper Alg. 1) or :class:`ClosedLoopOptions` (the deployed MPC's queries)."""
    network: NetworkConfig = field(default_factory=NetworkConfig)
    """The value function's architecture."""
    schedule: ScheduleConfig = field(default_factory=ScheduleConfig)
    """Pretraining, rounds and the optimiser."""
    loss: LossConfig = field(default_factory=LossConfig)
    """The loss and its labels (Sobolev weight, caps, standardisation)."""
    refit: RefitConfig = field(default_factory=RefitConfig)
    """The final refit of a fresh network to the whole buffer."""
    selection: SelectionConfig = field(default_factory=SelectionConfig)
    """The closed-loop selection of the refit's members (``refit.candidates``)."""
    model_params: bool = False
    """Learn ``V(x, tau, theta)`` over robots (docs/reference/spec.md §14): every start gets a robot ``theta`` drawn
    uniformly from the task's box Theta (``Task.parameters``), each solve takes it as NLP parameters (one built
    optimizer for all robots, with ``dV/dtheta`` from the duals), the network takes ``theta`` as inputs and is
    conditioned on the task's own values, and the Sobolev term covers x and theta. The uniform sampler is then
    uniform over ``X0 x Theta`` and the adversarial one ascends in theta as well (``sampler.ascend_theta``); the
    validation set draws its robots from Theta with a fixed seed. The closed-loop sampler then flies every episode on
    its own robot from Theta with the deployed robust MPC and solves each tail for the robot its plan was made for."""
    uniform_tau: bool = False
    """Draw uniform starts' ``tau`` from T0 instead of using the nominal value."""
    validate: bool = True
    """Solve (or load) the validation set and record validation metrics."""
    solver_options: Annotated[dict[str, Any] | None, tyro.conf.Suppress] = None
    """Options of the trajectory optimizer (part of the validation-cache key)."""
    runtime: RuntimeConfig = field(default_factory=RuntimeConfig)
    """How the run is executed (workers, backend, cache, progress bars, snapshots, torch threads)."""

    # The flat ``RUNTIME_FIELDS`` of earlier versions, for code that reads them.
    RUNTIME_FIELDS: ClassVar[tuple[str, ...]] = RuntimeConfig.RESUMABLE

    def __post_init__(self) -> None:
        if not isinstance(self.sampler, SamplerOptions):
            self.sampler = _sampler_options(self.sampler)
        for part in SECTIONS:
            object.__setattr__(self, part, _as_section(part, getattr(self, part)))
        self.validate_values()

    # ---------------------------------------------------------------------------------------------- validation
    def validate_values(self) -> None:
        """Raise a ValueError naming the first bad field and its accepted range (the parts validate themselves
        when made; this checks the task and what spans parts)."""
        if isinstance(self.task, Task):
            validate_task(self.task)
        elif not isinstance(self.task, str):
            raise ValueError(
                f"task must be a registered task name ({available_tasks()}) or a seagul_envs Task, "
                f"got {type(self.task).__name__}"
            )
        elif self.task not in available_tasks():
            raise ValueError(f"unknown task {self.task!r}; available tasks: {available_tasks()}")
        if not isinstance(self.sampler, SamplerOptions):
            raise ValueError(f"sampler must be one of {list(SAMPLERS)}' options, got {self.sampler!r}")
        _check(int(self.budget) >= 1, f"budget must be >= 1, got {self.budget}")
        closed_loop = isinstance(self.sampler, ClosedLoopOptions)
        if closed_loop and self.sampler.collect_refit and not self.refit.steps:  # type: ignore[union-attr]
            raise ValueError("sampler.collect_refit needs refit.steps > 0 (the collecting network is a refit)")
        if closed_loop and self.sampler.keep_best and self.refit.steps:  # type: ignore[union-attr]
            raise ValueError(
                "sampler.keep_best needs refit.steps = 0 (it deploys a network a collector flew; "
                f"got refit.steps={self.refit.steps})"
            )
        if self.selection.rounds and not (closed_loop and self.sampler.keep_best):  # type: ignore[union-attr]
            raise ValueError(
                "selection.rounds chooses among the rounds sampler.keep_best keeps: it needs the closed-loop sampler "
                f"with keep_best (got sampler {self.sampler.name!r})"
            )
        if self.model_params:
            task = self.resolve_task()
            if task.parameters is None:
                raise ValueError(
                    f"model_params needs a task with physical parameters (Task.parameters); {task.name} has none"
                )
        per_round = self.schedule.solves_per_round
        unreachable = [b for b in self.runtime.snapshots if b != self.budget and (b % per_round or b > self.budget)]
        if unreachable:
            raise ValueError(
                f"runtime.snapshots {unreachable} are not round boundaries: a snapshot is taken after a round, so it "
                f"must be a multiple of schedule.solves_per_round ({per_round}) up to the budget ({self.budget})"
            )

    # ------------------------------------------------------------------------------------------------ derived
    @property
    def num_rounds(self) -> int:
        """Rounds of solves (the last one may be partial)."""
        return math.ceil(self.budget / self.schedule.solves_per_round)

    @property
    def task_name(self) -> str:
        """The task's name (of the Task object, or the registered name given)."""
        return self.task.name if isinstance(self.task, Task) else str(self.task)

    def resolve_task(self) -> Task:
        """The Task of the run: the object given, or the registered name's shared task."""
        return resolve_task(self.task)

    def final_refit_config(self) -> TrainConfig:
        """The config the final refit is made with (``network.ensemble = refit.ensemble`` when that asks for
        members)."""
        if self.refit.ensemble >= 2:
            return replace(self, network=replace(self.network, ensemble=self.refit.ensemble))
        return self

    def closed_loop_options(self) -> ClosedLoopOptions:
        """The closed-loop options (``sampler`` when it is one, else the defaults)."""
        return self.sampler if isinstance(self.sampler, ClosedLoopOptions) else ClosedLoopOptions()

    def adversarial_options(self) -> AdversarialOptions:
        """The adversarial options (``sampler`` when it is one, else the defaults)."""
        return self.sampler if isinstance(self.sampler, AdversarialOptions) else AdversarialOptions()

    # ----------------------------------------------------------------------------------------- data and files
    def to_dict(self) -> dict[str, Any]:
        """Nested JSON-ready dict (a Task object as its name: :meth:`from_dict` needs it registered, or ``task=``);
        the sampler as ``{"name": ..., **options}``."""
        out: dict[str, Any] = {
            "task": self.task_name,
            "seed": int(self.seed),
            "budget": int(self.budget),
            "sampler": self.sampler.to_dict(),
        }
        for f in fields(self):
            if f.name in out:
                continue
            value = getattr(self, f.name)
            if f.name in SECTIONS:
                value = {
                    k: list(v) if isinstance(v, tuple) else v
                    for k, v in dataclasses.asdict(value).items()
                    if not omitted(value, k)
                }
            elif isinstance(value, dict):
                value = dict(value)
            out[f.name] = value
        return out

    def flat_dict(self) -> dict[str, Any]:
        """The config in the flat form of earlier versions (``cl_episodes``, ``refit_steps``, ...; JSON-ready), for
        readers of old ``config.json`` files: the fields of the samplers not chosen take their defaults."""
        nested = self.to_dict()
        out: dict[str, Any] = {k: v for k, v in nested.items() if k not in SECTIONS and k != "sampler"}
        out["sampler"] = self.sampler.name
        for legacy, (part, name, owner) in LEGACY_NAMES.items():
            if part == "sampler":
                options = self.sampler if self.sampler.name == owner else SAMPLER_OPTIONS[str(owner)]()
                value = getattr(options, name)
                value = 0 if legacy == "cl_horizon" and value is None else value
            else:
                value = nested[str(part)][name]
            out[legacy] = list(value) if isinstance(value, tuple) else value
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], task: Task | None = None) -> TrainConfig:
        """Inverse of :meth:`to_dict`; also reads the flat form of earlier versions (a run's old ``config.json``).
        Unknown keys are an error naming them. ``task``: the Task object to use for the stored name (a task that is
        not registered in this process); it must have that name."""
        data = dict(data)
        data.pop("task_fingerprint", None)
        if task is not None:
            if data.get("task") != task.name:
                raise ValueError(f"the stored task is {data.get('task')!r}, not {task.name!r}")
            data["task"] = task
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known - set(LEGACY_NAMES))
        if unknown:
            raise ValueError(f"unknown TrainConfig fields {unknown}")
        kwargs: dict[str, Any] = {}
        for key, value in data.items():
            if key in SECTIONS and isinstance(value, Mapping):
                kwargs[key] = _make(SECTIONS[key], value, key)
            elif key == "sampler":
                kwargs[key] = _sampler_options(value)
            elif key == "hidden" or key == "snapshots":
                kwargs[key] = tuple(value)
            else:
                kwargs[key] = value
        return cls._from_kwargs(_translate(kwargs, warn=False, stacklevel=2))

    @classmethod
    def _from_kwargs(cls, kwargs: dict[str, Any]) -> TrainConfig:
        return _DATACLASS_NEW(cls, kwargs)

    @classmethod
    def from_run(cls, run_dir: str | Path, task: Task | None = None) -> TrainConfig:
        """The config of a run directory (its ``config.json``, which also stores the task's fingerprint); with a
        ``task``, that fingerprint must match (same check as a resume)."""
        data = json.loads((Path(run_dir) / "config.json").read_text())
        stored = data.pop("task_fingerprint", None)
        if task is not None and stored is not None and stored != task.fingerprint():
            raise ValueError(
                f"run {str(run_dir)!r} was trained on a task {task.name!r} with fingerprint {stored}, not "
                f"{task.fingerprint()} (same name, other content)"
            )
        return cls.from_dict(data, task)

    def save(self, path: str | Path) -> Path:
        """Write the config (:meth:`to_dict`) as YAML (``.yml``/``.yaml``) or JSON (any other suffix)."""
        path = Path(path)
        data = self.to_dict()
        if path.suffix.lower() in (".yml", ".yaml"):
            import yaml  # type: ignore[import-untyped]

            text = yaml.safe_dump(data, sort_keys=False)
        else:
            text = json.dumps(data, indent=2) + "\n"
        path.write_text(text)
        return path

    @classmethod
    def load(cls, path: str | Path, task: Task | None = None) -> TrainConfig:
        """Read a config written by :meth:`save` (or a run's ``config.json``, nested or flat), by suffix."""
        path = Path(path)
        text = path.read_text()
        if path.suffix.lower() in (".yml", ".yaml"):
            import yaml

            data = yaml.safe_load(text) or {}
        else:
            data = json.loads(text)
        if not isinstance(data, Mapping):
            raise ValueError(f"{str(path)!r} holds no TrainConfig mapping")
        return cls.from_dict(data, task)

    @classmethod
    def recipe(cls, task: str | Task, name: str = "default", **overrides: Any) -> TrainConfig:
        """The task's recipe ``name`` (:func:`seagul_learn.recipes.recipe`: ``"default"`` the task's measured best
        settings, ``"paper"`` the paper's, ``"shipped"`` the shipped network's), then ``overrides`` (new or flat
        names); what ``seagul train`` uses. ``TrainConfig(task=...)`` alone keeps the paper's settings. An override
        naming another sampler than the recipe's starts from the dataclass defaults (a recipe's settings belong to its
        sampler: the glider's ``keep_best`` means nothing to the adversarial one).

        Raises:
            ValueError: an unknown recipe, or the recipe or ``overrides`` name a field :class:`TrainConfig` does not
                have.
        """
        from seagul_learn.recipes import recipe as recipe_data

        resolved = resolve_task(task)
        unknown = sorted(set(overrides) - accepted_names())
        if unknown:
            raise ValueError(f"TrainConfig.recipe({resolved.name!r}): overrides name unknown fields {unknown}")
        base = recipe_data(resolved, name)
        if "sampler" in overrides and "sampler" in base:
            wanted = _sampler_options(overrides["sampler"]).name
            if wanted != _sampler_options(base["sampler"]).name:
                base = {}
        config = cls.from_dict({**base, "task": task})
        return config.replaced(**overrides) if overrides else config

    def replaced(self, **changes: Any) -> TrainConfig:
        """A copy with ``changes``: fields, whole parts, or the flat names of earlier versions (with their warning),
        which update their part."""
        return _replace_config(self, changes)

    def result_fields(self) -> dict[str, Any]:
        """The fields that determine the results (everything but ``runtime``'s resumable fields; the task by its
        name, whose content :func:`~seagul_learn.training.train` checks by fingerprint)."""
        out = self.to_dict()
        out["runtime"] = {k: v for k, v in out["runtime"].items() if k not in RuntimeConfig.RESUMABLE}
        return out

    # ------------------------------------------------------------------------------------- the flat names
    def __getattr__(self, name: str) -> Any:
        # Only called when normal lookup fails: the flat names of earlier versions.
        if name in LEGACY_NAMES:
            _warn(f"TrainConfig.{name} is deprecated; use TrainConfig.{new_name(name)}", 2)
            part, field_name, owner = LEGACY_NAMES[name]
            if part == "sampler":
                sampler = self.__dict__.get("sampler")
                options = sampler if getattr(sampler, "name", None) == owner else SAMPLER_OPTIONS[str(owner)]()
                value = getattr(options, field_name)
                return 0 if name == "cl_horizon" and value is None else value
            return getattr(self.__dict__[str(part)], field_name)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    def __setattr__(self, name: str, value: Any) -> None:
        if name in LEGACY_NAMES:
            _warn(f"TrainConfig.{name} is deprecated; set TrainConfig.{new_name(name)}", 2)
            kwargs = _translate(
                {"sampler": self.sampler, **{p: getattr(self, p) for p in SECTIONS}, name: value}, False, 2
            )
            for key, new in kwargs.items():
                object.__setattr__(self, key, new)
            return
        object.__setattr__(self, name, value)


_DATACLASS_INIT = TrainConfig.__init__


def _DATACLASS_NEW(cls: type[TrainConfig], kwargs: dict[str, Any]) -> TrainConfig:
    obj = cls.__new__(cls)
    _DATACLASS_INIT(obj, **kwargs)
    return obj


@functools.wraps(_DATACLASS_INIT)
def _init(self: TrainConfig, *args: Any, **kwargs: Any) -> None:
    _DATACLASS_INIT(self, *args, **_translate(kwargs, warn=True, stacklevel=2))


TrainConfig.__init__ = _init  # type: ignore[method-assign]


def _replace_config(config: TrainConfig, changes: Mapping[str, Any]) -> TrainConfig:
    changes = dict(changes)
    if any(k in LEGACY_NAMES for k in changes):
        moved = ", ".join(f"{k} -> {new_name(k)}" for k in changes if k in LEGACY_NAMES)
        _warn(f"TrainConfig's flat field names are deprecated: {moved}", 3)
    current = {f.name: getattr(config, f.name) for f in fields(config)}
    if "sampler" in changes:
        current["sampler"] = _sampler_options(changes.pop("sampler"))
    current.update(changes)
    return TrainConfig._from_kwargs(_translate(current, warn=False, stacklevel=2))


def accepted_names() -> frozenset[str]:
    """Every keyword :class:`TrainConfig` (and :meth:`TrainConfig.replaced`) accepts: its fields, the dotted fields of
    its parts (``"sampler.episodes"``, ``"loss.sobolev_weight"``: ``TrainConfig(**{"sampler.episodes": 5})`` sets
    one field of a part) and the flat names of earlier versions; a check of user-given overrides, e.g. an experiment
    preset's ``train_overrides``."""
    dotted = {f"{part}.{f.name}" for part, cls in SECTIONS.items() for f in fields(cls)}
    dotted |= {f"sampler.{f.name}" for cls in SAMPLER_OPTIONS.values() for f in fields(cls)}  # type: ignore[arg-type]
    return frozenset({f.name for f in fields(TrainConfig)} | dotted | set(LEGACY_NAMES))
