"""The shipped controller of a task: the value network the closed-loop benchmark selected, measured and ships, and
how it is deployed.

The closed-loop benchmark (``benchmarks/bench_closed_loop.py``, its pipeline
:mod:`seagul_learn.experiment.benchmark`: :func:`~seagul_learn.experiment.benchmark.shipped_block`) writes one block
per task into ``benchmarks/results/closed_loop.json`` (:data:`SHIPPED_RESULTS`): the shipped ``network`` (a path
relative to the repository), the deployment of the limited-lookahead MPC it was measured in (``horizon``,
``trust_region``, ``goal_blend``, ``jit``) and what it measured (``success_rate`` on its ``grid``,
``heldout_success_rate``, ``median_ms``/``p95_ms`` per step, ...).
:func:`shipped_network` reads that block for a task; :meth:`ShippedController.spec` deploys the network exactly as
the block says (``LimitedLookaheadMPC(task, ValueNetwork.load(network), horizon, trust_region=..., goal_blend=...,
jit=...)``). ``seagul reproduce`` opens its report with it
(:meth:`seagul_learn.experiment.Experiment.evaluate_shipped`).

A task has a shipped controller when the file holds a block with a ``network`` under the task's name and the task
is the registered task of that name (same :meth:`~seagul_envs.tasks.base.Task.fingerprint`): a variant with other
parameters, or a task made by a user's factory, has none.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from seagul_control.evaluation import PolicySpec
from seagul_envs import Task, available_tasks, make_task, resolve_task

REPO_ROOT = Path(__file__).resolve().parents[1]
"""The repository this package was installed from (editable install): relative network paths are resolved here."""

SHIPPED_RESULTS = REPO_ROOT / "benchmarks" / "results" / "closed_loop.json"
"""The closed-loop benchmark's committed results: one block per task with its shipped network and deployment."""

DEPLOYMENT_KEYS = ("network", "horizon", "trust_region", "goal_blend", "jit")
"""The keys of a task's block that say how its network is deployed (all must be present)."""

MEASURED_KEYS = (
    "method", "budget", "seeds", "success_rate", "heldout_success_rate", "full_horizon_success_rate",
    "full_horizon_heldout_success_rate", "median_ms", "p95_ms", "timed_steps", "grid", "heldout_starts",
)  # fmt: skip
"""The benchmark's measured figures kept with the controller (quoted by the report as the benchmark's, never as
this run's)."""


class ShippedNetworkMissing(FileNotFoundError):
    """The results file declares a shipped network whose file does not exist."""


@dataclass(frozen=True)
class ShippedController:
    """A task's shipped network and its deployment, as the closed-loop benchmark measured it."""

    task: str
    """Name of the task."""
    network: Path
    """The network file (absolute)."""
    declared: str
    """The network's path as the results file spells it (relative to the repository)."""
    horizon: int
    """Lookahead steps of the limited-lookahead MPC."""
    trust_region: str
    """Guard of the learned terminal cost (``"none"``, ``"lqr"`` or ``"box"``)."""
    goal_blend: float
    """``goal_blend`` of the MPC (0 = off)."""
    jit: bool
    """Whether the benchmark compiled the MPC (step times depend on it, the solves do not)."""
    measured: dict[str, Any] = field(default_factory=dict, compare=False)
    """The benchmark's figures (:data:`MEASURED_KEYS` present in the block)."""
    source: Path = SHIPPED_RESULTS
    """The results file the block was read from."""

    def options(self, jit: bool | None = None) -> tuple[tuple[str, Any], ...]:
        """``LimitedLookaheadMPC`` options of the deployment (``jit`` None: the benchmark's)."""
        return (
            ("horizon", self.horizon),
            ("trust_region", self.trust_region),
            ("goal_blend", self.goal_blend),
            ("jit", self.jit if jit is None else bool(jit)),
        )

    def spec(self, label: str = "shipped MPC", jit: bool | None = None) -> Any:
        """The deployed MPC as a :class:`~seagul_control.evaluation.PolicySpec` (built in the evaluation's workers)."""
        return PolicySpec("mpc", label, str(self.network), self.options(jit))

    def describe(self) -> str:
        """One line: the network and its deployment."""
        return (
            f"`{self.declared}` as the terminal cost of `LimitedLookaheadMPC(horizon={self.horizon}, "
            f"trust_region={self.trust_region!r}, goal_blend={self.goal_blend:g})`"
        )


def _block(results: Path, name: str) -> dict[str, Any] | None:
    if not results.is_file():
        return None
    try:
        data = json.loads(results.read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f"the shipped-controller results {str(results)!r} are unreadable ({exc})") from exc
    block = data.get(name) if isinstance(data, dict) else None
    return block if isinstance(block, dict) and block.get("network") else None


def shipped_network(task: Task | str, results: str | os.PathLike[str] | None = None) -> ShippedController | None:
    """The shipped controller of ``task``, or None if it has none (module docstring).

    Args:
        task: a Task or a registered name.
        results: the results file (default :data:`SHIPPED_RESULTS`); a relative ``network`` in it is resolved
            against :data:`REPO_ROOT` when ``results`` is the default, else against the file's grandparent (the
            layout ``<repo>/benchmarks/results/closed_loop.json``) and then the working directory.

    Raises:
        ShippedNetworkMissing: the block names a network file that does not exist (the message names the path).
        ValueError: the results file is unreadable, or the block lacks a deployment key (:data:`DEPLOYMENT_KEYS`).
    """
    task = resolve_task(task)
    path = SHIPPED_RESULTS if results is None else Path(results)
    block = _block(path, task.name)
    if block is None:
        return None
    if task.name not in available_tasks() or make_task(task.name).fingerprint() != task.fingerprint():
        return None  # another task of that name (a variant, a user's factory): the network was not trained for it
    missing = [k for k in DEPLOYMENT_KEYS if k not in block]
    if missing:
        raise ValueError(f"{str(path)!r}: the {task.name!r} block declares a network but lacks {missing}")
    declared = str(block["network"])
    network = Path(declared)
    if not network.is_absolute():
        roots = [REPO_ROOT] if results is None else [*path.resolve().parents[2:3], Path.cwd()]
        network = next((r / declared for r in roots if (r / declared).is_file()), roots[0] / declared)
    if not network.is_file():
        raise ShippedNetworkMissing(
            f"the shipped network of task {task.name!r} is missing: {str(path)!r} names {declared!r}, and "
            f"{str(network)!r} does not exist (restore it, e.g. `git checkout -- {declared}`)"
        )
    horizon = int(block["horizon"])
    blend = float(block["goal_blend"])
    if horizon < 1 or not math.isfinite(blend) or blend < 0:
        raise ValueError(f"{str(path)!r}: the {task.name!r} block has horizon {horizon} and goal_blend {blend}")
    return ShippedController(
        task=task.name,
        network=network.resolve(),
        declared=declared,
        horizon=horizon,
        trust_region=str(block["trust_region"]),
        goal_blend=blend,
        jit=bool(block["jit"]),
        measured={k: block[k] for k in MEASURED_KEYS if k in block},
        source=path,
    )
