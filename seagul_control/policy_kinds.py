"""Policy kinds: how a :class:`PolicySpec` (a picklable description of a policy) becomes a predictor.

A spec names its kind; how a kind is built is looked up in a registry of policy kinds (:func:`register_policy_kind`):
kind -> the builder ``builder(task, spec) -> predictor``, named by its module path ``"package.module:function"``.
:func:`seagul_control.evaluation.evaluate` resolves each spec's builder path (:func:`builder_path`) in the calling
process and sends the path, not the function, to its workers, which import it by name; so joblib/loky workers (which
start with fresh registries) build every kind the caller could, a kind registered at run time included. Solvers are
not picklable, so every process builds its policies itself, once per task content and spec (:func:`build_policy`).

The control kinds are built here: ``"lqr"``, ``"full"`` (the full-horizon MPC), ``"mpc"`` without a file (a
limited-lookahead MPC with the task's own terminal cost; :func:`build_lookahead_policy` also takes a given value
function) and ``"do-mpc"`` (the peer MPC tool, ``seagul[anchors]``). The learned kinds, ``"mpc"`` with a saved value
network and ``"sb3"`` (a saved stable-baselines3 model), are built by :mod:`seagul_learn.policies`: their registry
entries name that module by path, so it (and torch) is imported only in a process that builds one, and never by
importing this module. ``seagul_control`` imports neither torch nor ``seagul_learn``.

Every name here is also importable from :mod:`seagul_control.evaluation`, where it lived first (the same objects,
no warning). Imports are at module level; the only import by name at run time is of a builder (by design, above).
"""

from __future__ import annotations

import importlib
import threading
from collections.abc import Callable
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from seagul_control.do_mpc_policy import DoMPCPolicy
from seagul_control.lqr import LQRPolicy
from seagul_control.mpc import FullHorizonMPC, FullHorizonOptions, LimitedLookaheadMPC, MPCOptions
from seagul_control.value_function import CasadiValueFunction
from seagul_envs.tasks import available_tasks, make_task
from seagul_envs.tasks.base import Task

__all__ = [
    "POLICY_KINDS",
    "PolicyKind",
    "PolicySpec",
    "build_do_mpc_policy",
    "build_full_horizon_policy",
    "build_lookahead_policy",
    "build_lqr_policy",
    "build_policy",
    "builder_path",
    "default_horizon",
    "policy_kinds",
    "register_policy_kind",
]

POLICY_KINDS = ("mpc", "full", "lqr", "sb3", "do-mpc")
"""The built-in policy kinds (:func:`policy_kinds` also lists those registered since)."""


@dataclass(frozen=True)
class PolicyKind:
    """How the policies of one kind are built: builders named by module path (``"package.module:function"``).

    A builder is called as ``builder(task, spec)`` with the :class:`~seagul_envs.tasks.base.Task` and the
    :class:`PolicySpec` and returns a predictor (``predict(observation, state, episode_start, deterministic)``, the
    stable-baselines3 protocol). Paths, not functions, so that a worker process imports the builder itself.
    """

    builder: str | None = None
    """Builds a spec without a file (``spec.path is None``); None: the kind needs a file."""
    file_builder: str | None = None
    """Builds a spec with a file (a saved network or model at ``spec.path``); None: the ``builder`` builds every spec
    of the kind (a file is ignored)."""


# The learned kinds' builders are named here, as strings, so that a spec of such a kind made by code that imported
# only this module still builds (in any process, workers included); the string is the whole dependency: this module
# imports nothing from seagul_learn, and a process that never builds a learned kind never imports it.
_KINDS: dict[str, PolicyKind] = {
    "mpc": PolicyKind(
        "seagul_control.policy_kinds:build_lookahead_policy", "seagul_learn.policies:build_network_mpc_policy"
    ),
    "full": PolicyKind("seagul_control.policy_kinds:build_full_horizon_policy"),
    "lqr": PolicyKind("seagul_control.policy_kinds:build_lqr_policy"),
    "sb3": PolicyKind(None, "seagul_learn.policies:build_sb3_policy"),
    "do-mpc": PolicyKind("seagul_control.policy_kinds:build_do_mpc_policy"),
}
_KINDS_LOCK = threading.Lock()


def register_policy_kind(
    kind: str, builder: str | None = None, file_builder: str | None = None, *, overwrite: bool = False
) -> None:
    """Add a policy kind that :class:`PolicySpec`, :func:`build_policy` and :func:`evaluate` accept.

    Args:
        kind: the name specs use (``PolicySpec(kind, ...)``).
        builder: ``"package.module:function"`` building a spec without a file: ``function(task, spec)``.
        file_builder: the same for a spec whose ``path`` names a file (a saved network or model).
        overwrite: replace a kind already registered (a built-in one included).

    The registration lives in this process; :func:`evaluate` sends the builder's path to its workers, which import
    the module by name, so a module-level function of an importable module is all a worker needs.

    Raises:
        ValueError: neither builder given, a path not of the form ``"module:function"``, or ``kind`` already
            registered differently and not ``overwrite``.
    """
    if builder is None and file_builder is None:
        raise ValueError(f"policy kind {kind!r} needs a builder, a file_builder or both")
    for path in (builder, file_builder):
        if path is not None:
            _split_path(path)
    new = PolicyKind(builder, file_builder)
    with _KINDS_LOCK:
        old = _KINDS.get(kind)
        if old is not None and old != new and not overwrite:
            raise ValueError(f"policy kind {kind!r} is already registered as {old}; pass overwrite=True to replace it")
        _KINDS[kind] = new


def policy_kinds() -> dict[str, PolicyKind]:
    """Every policy kind this process knows (the built-in :data:`POLICY_KINDS` and those registered since)."""
    with _KINDS_LOCK:
        return dict(_KINDS)


def builder_path(spec: PolicySpec) -> str:
    """The ``"module:function"`` that builds ``spec``: its kind's ``file_builder`` when it names a file, else its
    ``builder`` (a kind without a ``file_builder`` ignores the file)."""
    kind = policy_kinds()[spec.kind]
    path = kind.file_builder if spec.path is not None and kind.file_builder is not None else kind.builder
    assert path is not None  # PolicySpec.__post_init__ checked that a kind without a builder got a file
    return path


def _split_path(path: str) -> tuple[str, str]:
    module, sep, name = path.partition(":")
    if not sep or not module or not name:
        raise ValueError(f"a builder is named 'package.module:function', got {path!r}")
    return module, name


def _load_builder(path: str) -> Callable[[Task, PolicySpec], Any]:
    """The function ``path`` names, imported by module path (how a worker process finds a builder)."""
    module, name = _split_path(path)
    builder: Callable[[Task, PolicySpec], Any] = getattr(importlib.import_module(module), name)
    return builder


@dataclass(frozen=True)
class PolicySpec:
    """A policy to evaluate, by description (built in the worker)."""

    kind: str
    """``"mpc"``, ``"full"``, ``"lqr"``, ``"sb3"``, ``"do-mpc"`` (the peer MPC tool, ``seagul[anchors]``) or a kind
    added with :func:`register_policy_kind`."""
    label: str = ""
    """Name in tables and figures (default: the kind)."""
    path: str | None = None
    """Value network file (``"mpc"``) or SB3 model zip (``"sb3"``)."""
    options: tuple[tuple[str, Any], ...] = ()
    """Constructor options (e.g. ``(("horizon", 5), ("trust_region", "box"))``)."""
    knows_robot: bool = False
    """In an evaluation over robots (:func:`~seagul_control.evaluation.evaluate`'s ``robots``), build the policy for
    the episode's true robot (``task.with_params(theta)``: e.g. the full-horizon MPC that knows the true parameters)
    instead of the model."""

    def __post_init__(self) -> None:
        kinds = policy_kinds()
        if self.kind not in kinds:
            raise ValueError(f"unknown policy kind {self.kind!r}; use one of {list(kinds)}")
        kind = kinds[self.kind]
        if kind.builder is None and not self.path:
            raise ValueError(f"an {self.kind!r} policy needs the path of a saved model")
        if self.path is not None and not Path(self.path).is_file():
            raise FileNotFoundError(f"{self.kind} policy file {self.path!r} does not exist")

    @property
    def name(self) -> str:
        """The label, or the kind when no label was given."""
        return self.label or self.kind

    def option_dict(self) -> dict[str, Any]:
        """The options as a dict."""
        return dict(self.options)


def build_lqr_policy(task: Task, spec: PolicySpec) -> LQRPolicy:
    """``"lqr"``: :class:`~seagul_control.lqr.LQRPolicy` with the spec's options."""
    return LQRPolicy(task, **spec.option_dict())


def _split_options(options_class: Any, options: dict[str, Any]) -> tuple[Any, dict[str, Any]]:
    """A spec's flat options as ``(options_class(...), keywords)``: the fields of the options object (solver,
    terminal cost, ...) and the constructor's own keywords (``trust_region``, ``model_params``, ...)."""
    names = {f.name for f in fields(options_class)}
    return (
        options_class(**{k: v for k, v in options.items() if k in names}),
        {k: v for k, v in options.items() if k not in names},
    )


def build_full_horizon_policy(task: Task, spec: PolicySpec) -> FullHorizonMPC:
    """``"full"``: :class:`~seagul_control.mpc.FullHorizonMPC` with the spec's options."""
    options, keywords = _split_options(FullHorizonOptions, spec.option_dict())
    return FullHorizonMPC(task, options, **keywords)


def build_lookahead_policy(
    task: Task, spec: PolicySpec, value_function: CasadiValueFunction | None = None
) -> LimitedLookaheadMPC:
    """``"mpc"``: :class:`~seagul_control.mpc.LimitedLookaheadMPC` with ``value_function`` as its terminal cost (None:
    the task's own terminal cost) over the spec's ``horizon`` option (default :func:`default_horizon`).

    The builder of the learned kind (``"mpc"`` with a value network file, :mod:`seagul_learn.policies`) loads the
    network and calls this with it."""
    flat = spec.option_dict()
    horizon = int(flat.pop("horizon", default_horizon(task)))
    options, keywords = _split_options(MPCOptions, flat)
    return LimitedLookaheadMPC(task, value_function, horizon, options, **keywords)


def build_do_mpc_policy(task: Task, spec: PolicySpec) -> DoMPCPolicy:
    """``"do-mpc"``: :class:`~seagul_control.do_mpc_policy.DoMPCPolicy` (needs ``seagul[anchors]``) over the spec's
    ``horizon`` option (default :func:`default_horizon`)."""
    options = spec.option_dict()
    return DoMPCPolicy(task, int(options.pop("horizon", default_horizon(task))), **options)


_POLICIES: dict[tuple[str, PolicySpec], Any] = {}
_TASKS: dict[str, Task] = {}  # fingerprint -> the one Task object this process uses for it


def _canonical_task(task: Task | str) -> Task:
    """One Task object per content in this process: a name's shared task, or the first copy of a fingerprint seen.

    Workers receive a fresh unpickled copy with every chunk; mapping copies to one object keeps the per-task caches
    (simulators, built policies) warm, and a copy of a registered task maps to its shared object (so the env is
    exactly ``gym.make`` of its id).
    """
    if isinstance(task, str):
        return make_task(task)
    fp = task.fingerprint()
    known = _TASKS.get(fp)
    if known is None:
        known = task
        if task.name in available_tasks():
            shared = make_task(task.name)
            if shared.fingerprint() == fp:
                known = shared
        _TASKS[fp] = known
    return known


def build_policy(task: Task | str, spec: PolicySpec, builder: str | None = None) -> Any:
    """The predictor described by ``spec`` for ``task`` (a Task or a registered name; cached per process and task
    content: solvers are built once), built by ``builder`` (``"module:function"``; default :func:`builder_path`).

    Every registered kind is built, the learned ones by importing :mod:`seagul_learn.policies` by path (which
    re-exports this function as the one place that knows every kind)."""
    task = _canonical_task(task)
    key = (task.fingerprint(), spec)
    if key not in _POLICIES:
        _POLICIES[key] = _build(task, spec, builder)
    return _POLICIES[key]


def _build(task: Task, spec: PolicySpec, builder: str | None = None) -> Any:
    """A new predictor described by ``spec`` for ``task`` (uncached)."""
    return _load_builder(builder or builder_path(spec))(task, spec)


def default_horizon(task: Task) -> int:
    """The task's default MPC lookahead (``task.profile.default_horizon``). Paper §6: 5 steps (0.5 s) for the
    acrobot; about 250 ms (10 control periods) for the glider and, by default, for a new task."""
    return task.profile.default_horizon(task)
