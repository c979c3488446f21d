"""Closed-loop evaluation: run policies from a grid of starts through the Gymnasium envs and return the results.

Policies are described by :class:`~seagul_control.policy_kinds.PolicySpec` (picklable) and built inside each worker
process (solvers are not picklable), once per process and reused for every episode there; how each kind is built,
and the registry that names the builders by module path, is :mod:`seagul_control.policy_kinds`. :func:`evaluate`
resolves each spec's builder path in the calling process and sends the path, not the function, to the workers, so
joblib/loky workers build every kind the caller could, a kind registered at run time included. The starts (the
evaluation grid, the held-out starts) are :mod:`seagul_control.starts`. Both modules' names are also importable
from here, where they lived first (the same objects, no warning). ``seagul_control`` imports neither torch nor
``seagul_learn``.

Metrics per episode (paper §6): the final distance to the goal ``||x(T) - x*||``, the trajectory cost (minus the
episode return: running plus terminal cost, paper Fig. 4) and success by the task's rule (``task.profile.success``:
acrobot ``||x(T) - x*|| < 0.05``, glider perched, ``|x|, |z| < 0.05`` and ``|dx|, |dz| <= 2`` at the end), plus the
solver statistics of MPC policies. Episodes run in ``seagul_envs.make_env(task)`` and the start grid, the default
MPC horizon and the success rule come from the task's profile, so any Task (not only a registered name) can be
evaluated; the Task object itself is sent to the worker processes. Episodes are independent and every policy is
deterministic, so results do not depend on the number of worker processes.

This module only runs episodes and returns :class:`EpisodeResult` data; it never imports matplotlib. The tables and
figures made from the results (``summarize``, ``write_outputs``, ``plot_heatmaps``, ``plot_glider_trajectories``)
live in :mod:`seagul_learn.report` and ``SB3Policy`` in :mod:`seagul_learn.policies`; their old names here still
work, with a ``DeprecationWarning``, until the next release.

Imports are at module level; the only imports by name at run time are the builders of the registry (by design,
above) and the deprecated names (which live in ``seagul_learn``).
"""

from __future__ import annotations

import importlib
import warnings
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np
from cloudpickle import register_pickle_by_value
from joblib import Parallel, delayed
from tqdm.auto import tqdm

import seagul_envs
from seagul_control.policy_kinds import (
    _KINDS,  # noqa: F401  (the registry, where callers that registered a kind here reach it)
    POLICY_KINDS,
    PolicyKind,
    PolicySpec,
    _build,
    _canonical_task,
    build_do_mpc_policy,
    build_full_horizon_policy,
    build_lookahead_policy,
    build_lqr_policy,
    build_policy,
    builder_path,
    default_horizon,
    policy_kinds,
    register_policy_kind,
)
from seagul_control.starts import HELDOUT_SEED, heldout_starts, sample_grid_slice, start_grid
from seagul_envs.tasks import BUILTIN_TASKS, file_task_modules, make_task, resolve_task
from seagul_envs.tasks.acrobot import SUCCESS_DISTANCE as ACROBOT_SUCCESS_DISTANCE
from seagul_envs.tasks.base import Task
from seagul_envs.tasks.glider import PERCH_POSITION_TOL, PERCH_SPEED_TOL
from seagul_envs.tasks.profile import SuccessRule

__all__ = [
    "ACROBOT_SUCCESS_DISTANCE",
    "HELDOUT_SEED",
    "PERCH_POSITION_TOL",
    "PERCH_SPEED_TOL",
    "POLICY_KINDS",
    "REFERENCE_TOLERANCE",
    "SUCCESS_TOLERANCES",
    "EpisodeResult",
    "PolicyKind",
    "PolicySpec",
    "build_do_mpc_policy",
    "build_full_horizon_policy",
    "build_lookahead_policy",
    "build_lqr_policy",
    "build_policy",
    "builder_path",
    "check_env_task",
    "default_horizon",
    "episode_env",
    "evaluate",
    "heldout_starts",
    "is_success",
    "policy_kinds",
    "register_policy_kind",
    "run_episode",
    "run_policy_episode",
    "sample_grid_slice",
    "start_grid",
    "success_at",
    "tolerance_reached",
]


@dataclass
class EpisodeResult:
    """One closed-loop episode."""

    policy: str
    index: int
    start: list[float]
    final_state: list[float]
    final_distance: float
    cost: float
    success: bool
    """The task's success rule (``task.profile.success``; acrobot: final distance < 0.05; glider: perched)."""
    terminated: bool
    """Left the task's state bounds (glider crash)."""
    steps: int
    solve_times: list[float] = field(default_factory=list)
    """Solver wall time per step (s), MPC policies only."""
    iterations: list[int] = field(default_factory=list)
    """Solver iterations per step, MPC policies only."""
    fallbacks: int = 0
    """Steps whose action did not come from a converged solve."""
    multistart_steps: int = 0
    """Steps whose solve also descended from extra starts (``LimitedLookaheadMPC(multistart=...)``)."""
    states: list[list[float]] = field(default_factory=list)
    """The visited states (first to last) when recorded."""
    queries: list[list[float]] = field(default_factory=list)
    """The MPC's planned terminal states and their times to go, ``[*x_n, tau_n]`` per step whose terminal cost was
    the learned value (the planner's queries of ``Vhat``), when recorded."""
    robot: list[float] = field(default_factory=list)
    """The simulated robot's parameters ``theta`` (``task.parameters.names`` order) in an evaluation over robots;
    empty when the episode ran on the model."""


def episode_env(task: Task, **kwargs: Any) -> Any:
    """The Gymnasium env the task's episodes run in: ``seagul_envs.make_env(task, **kwargs)`` (a registered task's
    shared object gives exactly ``gym.make`` of its id; any other Task, a variant included, is simulated as given)."""
    return seagul_envs.make_env(task, **kwargs)


# ------------------------------------------------------------------------------------------------ episodes
def run_episode(
    task: Task | str,
    spec: PolicySpec,
    x0: np.ndarray,
    index: int = 0,
    record: bool = False,
    record_queries: bool = False,
    env_id: str | None = None,
    robot: np.ndarray | None = None,
    builder: str | None = None,
) -> EpisodeResult:
    """One episode of the policy ``spec`` describes from ``x0`` at the nominal time to go (``task``: a Task or a
    registered name), in ``gym.make(env_id)`` if given (another simulator of the task), else the task's env; with
    ``robot``, the env simulates the robot with those parameters (the policy plans with the model unless
    ``spec.knows_robot``: then a policy whose solvers take the parameters, ``FullHorizonMPC(model_params=True)``,
    is re-targeted with ``set_robot``; any other is built for that robot, once per episode, and not cached).
    ``builder``: the ``"module:function"`` that builds the policy (default :func:`builder_path`)."""
    task = _canonical_task(task)
    policy = build_policy(task, spec, builder)
    if getattr(policy, "model_params", False):
        # Its solvers take the robot's parameters: the oracle re-targets the one built policy (None: the model).
        policy.set_robot(robot if spec.knows_robot else None)
    elif robot is not None and spec.knows_robot:
        policy = _build(task.with_params(robot), spec, builder)
    episode, infos = run_policy_episode(
        task, policy, x0, index=index, record=record, label=spec.name, env_id=env_id, robot=robot
    )
    if record_queries:
        episode.queries = [
            [*info.terminal_state, float(info.terminal_tau)] for info in infos if info.terminal_state is not None
        ]
    return episode


def run_policy_episode(
    task: Task,
    policy: Any,
    x0: np.ndarray,
    *,
    index: int = 0,
    record: bool = False,
    label: str = "",
    env_id: str | None = None,
    frames: list[np.ndarray] | None = None,
    robot: np.ndarray | None = None,
) -> tuple[EpisodeResult, list[Any]]:
    """One episode of a predictor object from ``x0`` in the task's env; also returns its per-step solver infos.

    The env is ``gym.make(env_id)`` if given, else :func:`episode_env` (``make_env(task)``). The infos are the
    MPC's :class:`~seagul_control.mpc.MPCStepInfo` of each step (empty for policies without ``stats``); they carry
    the planned terminal states (the planner's queries of the value function). With a list as ``frames``, the env
    runs with ``render_mode="rgb_array"`` and every frame (the start, then one per step) is appended to it. With
    ``robot`` the env simulates the robot with those parameters (``reset(options={"params": robot})``); success and
    cost are judged by the task's rule as always.
    """
    render: dict[str, Any] = {} if frames is None else {"render_mode": "rgb_array"}
    env = gym.make(env_id, **render) if env_id else episode_env(task, **render)
    reset: dict[str, Any] = {"state": np.asarray(x0, dtype=float)}
    if robot is not None:
        reset["params"] = np.asarray(robot, dtype=float)
    obs, info = env.reset(options=reset)
    if frames is not None:
        frames.append(np.asarray(env.render()))
    stats = getattr(policy, "stats", None)
    first_stat = len(stats) if stats is not None else 0
    states = [info["state"].tolist()] if record else []
    total, steps, start, done, terminated = 0.0, 0, True, False, False
    while not done:
        action, _ = policy.predict(obs, episode_start=np.array([start]), deterministic=True)
        start = False
        obs, reward, terminated, truncated, info = env.step(action)
        total += float(reward)
        steps += 1
        done = terminated or truncated
        if record:
            states.append(info["state"].tolist())
        if frames is not None:
            frames.append(np.asarray(env.render()))
    env.close()
    x = np.asarray(info["state"], dtype=float)
    distance = float(np.linalg.norm(x - task.goal))
    episode = [] if stats is None else list(stats[first_stat:])
    if stats is not None:
        del stats[first_stat:]  # keep memory flat over many episodes
    result = EpisodeResult(
        policy=label or getattr(policy, "name", type(policy).__name__),
        index=index,
        start=np.asarray(x0, dtype=float).tolist(),
        final_state=x.tolist(),
        final_distance=distance,
        cost=-total,
        success=is_success(task, x, bool(terminated)),
        terminated=bool(terminated),
        steps=steps,
        solve_times=[float(s.solve_time) for s in episode],
        iterations=[int(s.iterations) for s in episode],
        fallbacks=sum(1 for s in episode if s.source != "solver"),
        multistart_steps=sum(1 for s in episode if getattr(s, "extra_starts", 0)),
        states=states,
        robot=[] if robot is None else np.asarray(robot, dtype=float).tolist(),
    )
    return result, episode


def check_env_task(task: Task, env_id: str) -> None:
    """Raise a ValueError unless ``gym.make(env_id)`` simulates ``task`` (same name, state and input sizes)."""
    try:
        env = gym.make(env_id)
    except gym.error.Error as exc:
        raise ValueError(f"unknown env id {env_id!r}: {exc}") from exc
    other = getattr(env.unwrapped, "task", None)
    env.close()
    if other is None or other.name != task.name or (other.nx, other.nu) != (task.nx, task.nu):
        found = "no seagul task" if other is None else f"task {other.name!r}"
        raise ValueError(f"env {env_id!r} simulates {found}, not {task.name!r}; pick an env of the evaluated task")


def is_success(task: Task, x: np.ndarray, terminated: bool = False) -> bool:
    """The task's success rule (``task.profile.success``) on an episode's final state. Acrobot:
    ``||x - x*|| < 0.05``; glider: perched (position and speed tolerances) without crashing."""
    return task.profile.is_success(task, x, terminated)


#: The tolerances :func:`success_at` re-judges episodes at (keys of its result; the committed baselines table's).
SUCCESS_TOLERANCES = ("0.05", "0.1", "0.2", "0.5")
#: The tolerance the built-in rules use (acrobot: its distance; glider: its position tolerance, speeds 40 times it).
REFERENCE_TOLERANCE = 0.05


def tolerance_reached(task: Task, final_state: Any, terminated: bool = False) -> float:
    """The smallest ``tol`` at which an episode's final state meets the task's success rule with every tolerance
    scaled by ``tol / 0.05`` (:data:`REFERENCE_TOLERANCE`): ``0.05 * SuccessRule.scale_needed``. For the acrobot it
    is the final distance ``||x(T) - x*||``; for the glider the perch position tolerance met (m, speeds within 40
    times it); infinite for an episode the rule fails outright (a glider crash).

    Raises:
        ValueError: the task's rule is not a :class:`~seagul_envs.tasks.profile.SuccessRule` (a custom callable has
            no tolerances to scale).
    """
    rule = task.profile.success
    if not isinstance(rule, SuccessRule):
        raise ValueError(f"{task.name}: tolerances need a SuccessRule, got {type(rule).__name__}")
    return REFERENCE_TOLERANCE * rule.scale_needed(task, final_state, terminated)


def success_at(
    task: Task, episodes: Sequence[EpisodeResult | Mapping[str, Any]], tolerances: Sequence[str] = SUCCESS_TOLERANCES
) -> dict[str, float]:
    """Success rate of ``episodes`` (:class:`EpisodeResult` or dicts with ``"final_state"`` and ``"terminated"``)
    at each tolerance (``"0.1"`` -> the task's rule scaled by ``0.1 / 0.05``, :meth:`SuccessRule.scaled
    <seagul_envs.tasks.profile.SuccessRule.scaled>`): how the comparison of controllers changes when the goal is
    looser than the paper's."""
    rule = task.profile.success
    if not isinstance(rule, SuccessRule):
        raise ValueError(f"{task.name}: tolerances need a SuccessRule, got {type(rule).__name__}")
    finals = [
        (e.final_state, e.terminated) if isinstance(e, EpisodeResult) else (e["final_state"], e["terminated"])
        for e in episodes
    ]
    out = {}
    for tol in tolerances:
        scaled = rule.scaled(float(tol) / REFERENCE_TOLERANCE)
        out[tol] = float(np.mean([scaled(task, x, bool(terminated)) for x, terminated in finals]))
    return out


def _run_chunk(
    task: Task | str,
    spec: PolicySpec,
    starts: np.ndarray,
    indices: Sequence[int],
    record: bool,
    record_queries: bool = False,
    env_id: str | None = None,
    robots: np.ndarray | None = None,
    builder: str | None = None,
) -> list[EpisodeResult]:
    return [
        run_episode(task, spec, x0, i, record, record_queries, env_id, None if robots is None else robots[k], builder)
        for k, (x0, i) in enumerate(zip(starts, indices, strict=True))
    ]


def evaluate(
    task: Task | str,
    specs: Sequence[PolicySpec],
    starts: np.ndarray,
    workers: int = 1,
    progress: bool = True,
    record: bool = False,
    chunk_size: int = 4,
    record_queries: bool = False,
    env_id: str | None = None,
    robots: np.ndarray | None = None,
) -> list[EpisodeResult]:
    """Every policy from every start (joblib processes when ``workers > 1``); results ordered by policy, start.

    ``robots`` (one row of ``task.parameters`` values per start): episode ``i`` runs on the robot ``robots[i]``
    (robust control, domain randomisation); the policies plan with the model task unless their spec
    ``knows_robot`` (the oracle that plans with the true parameters).

    ``task`` is a Task object or a registered name, resolved once here; the Task itself is what the worker
    processes receive (nothing is looked up by name there), with each spec's builder path (:func:`builder_path`,
    resolved here, so a kind registered in this process builds in the workers too). ``record`` keeps every visited
    state, ``record_queries`` the MPCs' planned terminal states (for the planner-query error,
    :func:`seagul_learn.closed_loop.query_errors`). ``env_id`` runs the episodes in another registered env of the
    same task (e.g. ``"SeagulAcrobotMujoco-v0"``: the MuJoCo physics under the analytic model's policies).
    """
    task = _canonical_task(resolve_task(task))
    task_name = task.name
    starts = np.asarray(starts, dtype=float)
    if starts.ndim != 2 or starts.shape[1] != task.nx:
        raise ValueError(f"starts must have shape (n, {task.nx}), got {starts.shape}")
    if int(workers) < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    if env_id is not None:
        check_env_task(task, env_id)
    if robots is not None:
        if task.parameters is None:
            raise ValueError(f"{task_name}: robots need a task that declares which parameters vary (Task.parameters)")
        robots = np.asarray(robots, dtype=float)
        if robots.shape != (starts.shape[0], task.parameters.size):
            raise ValueError(
                f"robots must have one row of {task.parameters.size} parameters {list(task.parameters.names)} per "
                f"start, shape ({starts.shape[0]}, {task.parameters.size}), got {robots.shape}"
            )
        for row in robots:
            task.parameters.check(row, task_name)
    names = [s.name for s in specs]
    if len(set(names)) != len(names):
        raise ValueError(f"policy labels must be unique, got {names}")
    builders = {spec: builder_path(spec) for spec in specs}
    # Build each policy here first: a JIT compile then happens once and the workers load the cached object code.
    for spec in specs:
        if not (robots is not None and spec.knows_robot):
            build_policy(task, spec, builders[spec])
    jobs = []
    for spec in specs:
        for lo in range(0, len(starts), chunk_size):
            idx = list(range(lo, min(lo + chunk_size, len(starts))))
            jobs.append((spec, idx))
    bar = tqdm(total=len(specs) * len(starts), desc=f"evaluate {task_name}", disable=not progress)
    results: list[EpisodeResult] = []
    if workers == 1:
        outputs: Iterator[list[EpisodeResult]] = (
            _run_chunk(task, spec, starts[idx], idx, record, record_queries, env_id, _rows(robots, idx), builders[spec])
            for spec, idx in jobs
        )
    else:
        # A task read from a file (``--task path/file.py:factory``) lives in a module that joblib's reused worker
        # processes cannot import (they started before it was loaded): its classes travel by value.
        for module in file_task_modules():
            register_pickle_by_value(module)
        outputs = Parallel(n_jobs=int(workers), return_as="generator")(
            delayed(_run_chunk)(
                task, spec, starts[idx], idx, record, record_queries, env_id, _rows(robots, idx), builders[spec]
            )
            for spec, idx in jobs
        )
    for chunk in outputs:
        results.extend(chunk)
        bar.update(len(chunk))
    bar.close()
    order = {name: k for k, name in enumerate(names)}
    results.sort(key=lambda r: (order[r.policy], r.index))
    return results


def _rows(robots: np.ndarray | None, idx: list[int]) -> np.ndarray | None:
    return None if robots is None else robots[idx]


# ------------------------------------------------------------------------------------------------ moved names
_MOVED: dict[str, str] = {
    "summarize": "seagul_learn.report",
    "write_outputs": "seagul_learn.report",
    "plot_heatmaps": "seagul_learn.report",
    "plot_glider_trajectories": "seagul_learn.report",
    "SB3Policy": "seagul_learn.policies",
}
"""Names that moved up to ``seagul_learn`` -> their module (old names kept for one release, imported by module path
on first use: this module never imports ``seagul_learn``)."""


def __getattr__(name: str) -> Any:
    """The names that moved to ``seagul_learn`` (:data:`_MOVED`), imported lazily with a deprecation warning;
    ``ENV_IDS``, a deprecated name-keyed view of the built-in tasks' ``profile.env_id``."""
    if name == "ENV_IDS":
        warnings.warn(
            "seagul_control.evaluation.ENV_IDS is deprecated; episodes run in episode_env(task) "
            "(seagul_envs.make_env), the id is task.profile.env_id",
            DeprecationWarning,
            stacklevel=2,
        )
        return {n: make_task(n).profile.env_id for n in sorted(BUILTIN_TASKS)}
    if name in _MOVED:
        module = _MOVED[name]
        warnings.warn(
            f"seagul_control.evaluation.{name} is deprecated and will be removed in the next release; "
            f"use {module}.{name}",
            DeprecationWarning,
            stacklevel=2,
        )
        return getattr(importlib.import_module(module), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
