"""The on-disk dataset of trajectory-optimization solves: one atomic ``.npz`` file per solve.

Layout of a dataset directory::

    DIR/dataset.json             {"format": "seagul-dataset", "version": 1, "task": "acrobot", "meta": {...}}
    DIR/records/solve-000000.npz one record per solve, named by its deterministic index (6+ digits)

Each record is a plain NumPy ``.npz`` (readable without seagul; no pickles) with the keys

===================  ==============  ===============================================================
key                  shape / dtype   meaning
===================  ==============  ===============================================================
``index``            () int64        deterministic solve index (the file name)
``x_init``           (nx,) float64   start state
``tau``              () float64      time to go of the solve (s)
``success``          () bool         solver reported an optimal, feasible solution
``status``           () str          solver status text
``value``            () float64      ``V(x_init, tau)`` (NaN when failed)
``grad_x``           (nx,) float64   ``dV/dx_init`` (dual of ``x_0 = x_init``)
``grad_tau``         () float64      ``dV/dtau``
``states``           (m+1, nx)       knot states
``time_to_go``       (m+1,)          time to go at each knot
``cost_to_go``       (m+1,)          cost to go from each knot (the per-knot value labels)
``knot_grads``       (m+1, nx)       ``dV_k/dx_k`` per knot
``iterations``       () int64        solver iterations
``solve_time``       () float64      wall time (s)
``sampler``          () str          who asked for the solve (``"pretrain"``, ``"uniform"``, ``"adversarial"``, ...)
``chain``            () int64        adversarial chain id (-1 for independent draws)
``step``             () int64        iterate number within the chain (0 for the chain's start)
``theta``            (k,) float64    the robot's physical parameters (``task.parameters.names``; ``k = 0``: the
                                     task's own robot, not an NLP parameter)
``grad_theta``       (k,) float64    ``dV/dtheta`` (from the duals)
``knot_grad_theta``  (m+1, k)        ``dV_k/dtheta`` per knot
===================  ==============  ===============================================================

Records without ``theta*`` keys (files written by versions without robot parameters) read as ``k = 0``.

Writes are atomic (:func:`seagul_control._io.atomic_write_bytes`): a record goes to a hidden temp file in
``records/``, is flushed and fsynced, then renamed over its final name (``os.replace``) and the directory is
fsynced. A crash therefore leaves either a complete record or a stray ``.tmp-*`` file, which readers ignore and
:meth:`Dataset.open` deletes. Failed solves are stored with their status (they count against budgets) but
:func:`training_arrays` never turns them into training samples.
"""

from __future__ import annotations

import io
import json
import os
import re
import shutil
import uuid
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

# The one atomic writer (torch-free, shared by every package); re-exported here for existing importers.
from seagul_control._io import atomic_write_bytes as atomic_write_bytes
from seagul_control._io import atomic_write_text as atomic_write_text
from seagul_learn.results import SolveResult

FORMAT_TAG = "seagul-dataset"
FORMAT_VERSION = 1
_RECORD_RE = re.compile(r"^solve-(\d{6,})\.npz$")
_OPTIONAL_KEYS = ("theta", "grad_theta", "knot_grad_theta")
"""Record keys that files written by versions without robot parameters do not have."""


class DatasetError(ValueError):
    """A dataset directory or record is missing, corrupt, foreign, or inconsistent with what was asked."""


@dataclass
class SolveRecord:
    """One stored solve (see the module docstring for the meaning of each field)."""

    index: int
    x_init: np.ndarray
    tau: float
    success: bool
    status: str
    value: float
    grad_x: np.ndarray
    grad_tau: float
    states: np.ndarray
    time_to_go: np.ndarray
    cost_to_go: np.ndarray
    knot_grads: np.ndarray
    iterations: int
    solve_time: float
    sampler: str
    chain: int = -1
    step: int = 0
    theta: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """The robot's parameters of the solve, ``(k,)``; ``k = 0`` when the robot was the task's own (no NLP
    parameters)."""
    grad_theta: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """``dV/dtheta`` at the start, ``(k,)``."""
    knot_grad_theta: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    """``dV_k/dtheta`` per knot, ``(m + 1, k)`` (``(0, 0)`` when ``k = 0``)."""

    @property
    def n_params(self) -> int:
        """``k``: the number of physical parameters the solve took as NLP parameters (0: none)."""
        return int(self.theta.size)

    @classmethod
    def from_result(cls, result: SolveResult, index: int, sampler: str, chain: int = -1, step: int = 0) -> SolveRecord:
        """Wrap a :class:`SolveResult` with its bookkeeping."""
        k = 0 if result.theta is None else int(np.asarray(result.theta).size)
        m1 = int(np.asarray(result.states).shape[0])

        def params(value: np.ndarray | None, shape: tuple[int, ...]) -> np.ndarray:
            if value is None:
                return np.full(shape, np.nan) if k else np.zeros(shape)
            return np.asarray(value, dtype=np.float64).reshape(shape).copy()

        return cls(
            index=int(index),
            x_init=np.asarray(result.x_init, dtype=np.float64).copy(),
            tau=float(result.tau),
            success=bool(result.success),
            status=str(result.status),
            value=float(result.value),
            grad_x=np.asarray(result.grad_x, dtype=np.float64).copy(),
            grad_tau=float(result.grad_tau),
            states=np.asarray(result.states, dtype=np.float64).copy(),
            time_to_go=np.asarray(result.time_to_go, dtype=np.float64).copy(),
            cost_to_go=np.asarray(result.cost_to_go, dtype=np.float64).copy(),
            knot_grads=np.asarray(result.knot_grads, dtype=np.float64).copy(),
            iterations=int(result.iterations),
            solve_time=float(result.solve_time),
            sampler=str(sampler),
            chain=int(chain),
            step=int(step),
            theta=params(result.theta, (k,)),
            grad_theta=params(result.grad_theta, (k,)),
            knot_grad_theta=params(result.knot_grad_theta, (m1, k) if k else (0, 0)),
        )

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The ``.npz`` payload."""
        out: dict[str, np.ndarray] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, str):
                out[f.name] = np.array(value, dtype=np.str_)
            elif isinstance(value, bool):
                out[f.name] = np.array(value, dtype=np.bool_)
            elif isinstance(value, int):
                out[f.name] = np.array(value, dtype=np.int64)
            else:
                out[f.name] = np.asarray(value, dtype=np.float64)
        return out

    @classmethod
    def from_arrays(cls, data: Any) -> SolveRecord:
        """Inverse of :meth:`to_arrays` (``data`` maps key -> array, e.g. an open ``NpzFile``)."""
        kwargs: dict[str, Any] = {}
        for f in fields(cls):
            if f.name in _OPTIONAL_KEYS and f.name not in data:
                continue  # a record without robot parameters: the task's own robot
            arr = data[f.name]
            if f.name in ("status", "sampler"):
                kwargs[f.name] = str(arr[()])
            elif f.name == "success":
                kwargs[f.name] = bool(arr[()])
            elif f.name in ("index", "iterations", "chain", "step"):
                kwargs[f.name] = int(arr[()])
            elif f.name in ("tau", "value", "grad_tau", "solve_time"):
                kwargs[f.name] = float(arr[()])
            else:
                kwargs[f.name] = np.array(arr, dtype=np.float64)
        return cls(**kwargs)

    def same_request(self, x_init: np.ndarray, tau: float, theta: np.ndarray | None = None) -> bool:
        """True if this record answers a solve from exactly ``(x_init, tau)`` for the robot ``theta`` (None: the
        task's own, no NLP parameters); bitwise, as plans are deterministic."""
        want = np.zeros(0) if theta is None else np.asarray(theta, dtype=np.float64).reshape(-1)
        return bool(
            np.array_equal(self.x_init, np.asarray(x_init, dtype=np.float64))
            and self.tau == float(tau)
            and np.array_equal(self.theta, want)
        )


class Dataset:
    """A directory of solve records (see the module docstring); open or create it with :meth:`open`."""

    def __init__(self, path: Path, task_name: str, meta: dict[str, Any]) -> None:
        self.path = Path(path)
        self.task_name = task_name
        self.meta = meta

    @property
    def records_dir(self) -> Path:
        """Where the ``solve-*.npz`` files live."""
        return self.path / "records"

    @classmethod
    def open(
        cls, path: str | os.PathLike[str], task_name: str | None = None, meta: dict[str, Any] | None = None
    ) -> Dataset:
        """Open the dataset at ``path``, creating it when ``task_name`` is given and it does not exist yet.

        Raises:
            DatasetError: the directory is not a dataset, is of another task, or its ``meta`` differs from ``meta``.
        """
        path = Path(path)
        header = path / "dataset.json"
        if header.is_file():
            try:
                info = json.loads(header.read_text())
            except (OSError, json.JSONDecodeError) as exc:
                raise DatasetError(f"dataset header {str(header)!r} is unreadable or corrupt ({exc})") from exc
            if not isinstance(info, dict) or info.get("format") != FORMAT_TAG:
                raise DatasetError(f"{str(path)!r} is not a seagul dataset (no {FORMAT_TAG!r} tag in dataset.json)")
            if info.get("version") != FORMAT_VERSION:
                raise DatasetError(f"{str(path)!r} has dataset format version {info.get('version')!r}")
            if task_name is not None and info.get("task") != task_name:
                raise DatasetError(f"dataset {str(path)!r} holds task {info.get('task')!r}, not {task_name!r}")
            if meta is not None and info.get("meta") != _jsonable(meta):
                raise DatasetError(
                    f"dataset {str(path)!r} was made with other settings: {info.get('meta')} != {_jsonable(meta)}"
                )
            dataset = cls(path, str(info["task"]), dict(info.get("meta") or {}))
            for stray in dataset.records_dir.glob(".tmp-*"):  # half-written records of an interrupted run
                stray.unlink(missing_ok=True)
            return dataset
        if task_name is None:
            raise DatasetError(f"{str(path)!r} is not a seagul dataset (no dataset.json)")
        if path.exists() and not path.is_dir():
            raise DatasetError(f"cannot create a dataset at {str(path)!r}: it is a file, not a directory")
        if path.exists() and any(path.iterdir()):
            if header.is_file():  # another process created it since the check above
                return cls.open(path, task_name, meta)
            raise DatasetError(f"cannot create a dataset in {str(path)!r}: the directory exists and is not empty")
        # Created whole beside its place and renamed into it, so that processes creating the same dataset at once
        # (workers filling a shared validation cache) never see a half-made one: the first rename wins, the others
        # open the winner's (a rename onto a non-empty directory fails).
        info = {"format": FORMAT_TAG, "version": FORMAT_VERSION, "task": task_name, "meta": _jsonable(meta or {})}
        path.parent.mkdir(parents=True, exist_ok=True)
        staging = path.parent / f".tmp-{path.name}-{os.getpid()}-{uuid.uuid4().hex}"
        (staging / "records").mkdir(parents=True)
        try:
            atomic_write_bytes(staging / "dataset.json", json.dumps(info, indent=2, sort_keys=True).encode())
            os.rename(staging, path)
        except OSError:
            shutil.rmtree(staging, ignore_errors=True)
            if header.is_file():  # another process created it first
                return cls.open(path, task_name, meta)
            raise
        return cls(path, task_name, info["meta"])

    def record_path(self, index: int) -> Path:
        """File of record ``index``."""
        return self.records_dir / f"solve-{int(index):06d}.npz"

    def indices(self) -> list[int]:
        """Sorted indices of the complete records."""
        if not self.records_dir.is_dir():
            return []
        found = (_RECORD_RE.match(p.name) for p in self.records_dir.iterdir())
        return sorted(int(m.group(1)) for m in found if m)

    def __len__(self) -> int:
        return len(self.indices())

    def __contains__(self, index: object) -> bool:
        return isinstance(index, int | np.integer) and self.record_path(int(index)).is_file()

    def write(self, record: SolveRecord, exist_ok: bool = False) -> None:
        """Store ``record`` atomically; an existing index is an error unless ``exist_ok`` (then it is kept)."""
        path = self.record_path(record.index)
        if path.is_file():
            if exist_ok:
                return
            raise DatasetError(f"record {record.index} already exists in {str(self.path)!r}")
        buffer = io.BytesIO()
        # Typed ``Any`` for numpy's stub: mypy lets a ``**`` mapping of arrays bind ``savez``'s ``allow_pickle``.
        arrays: dict[str, Any] = record.to_arrays()
        np.savez(buffer, **arrays)
        atomic_write_bytes(path, buffer.getvalue())

    def read(self, index: int) -> SolveRecord:
        """Load record ``index``; raises :class:`DatasetError` naming the file if it is missing or corrupt."""
        path = self.record_path(index)
        if not path.is_file():
            raise DatasetError(f"record {index} does not exist in {str(self.path)!r}")
        try:
            with np.load(path, allow_pickle=False) as data:
                return SolveRecord.from_arrays(data)
        except Exception as exc:
            raise DatasetError(f"record file {str(path)!r} is corrupt ({type(exc).__name__}: {exc})") from exc

    def records(self) -> list[SolveRecord]:
        """All complete records, by index."""
        return [self.read(i) for i in self.indices()]


@dataclass
class TrainingArrays:
    """Per-knot samples of successful solves: the training (or validation) set in arrays."""

    x: np.ndarray
    """Knot states, ``(n, nx)``."""
    tau: np.ndarray
    """Time to go at each knot, ``(n,)``."""
    value: np.ndarray
    """Cost-to-go labels, ``(n,)``."""
    grad_x: np.ndarray
    """``dV/dx`` labels, ``(n, nx)`` (rows may be non-finite when a solver gave no multiplier; mask them)."""
    solve_index: np.ndarray
    """Index of the solve each sample came from, ``(n,)``."""
    knot: np.ndarray
    """Knot number within its solve (0 = the solve's start at its full ``tau``), ``(n,)``."""
    theta: np.ndarray | None = None
    """The robot of each sample, ``(n, k)``, when the solves took physical parameters (else None)."""
    grad_theta: np.ndarray | None = None
    """``dV/dtheta`` labels, ``(n, k)`` (with :attr:`theta`)."""

    @property
    def n_params(self) -> int:
        """``k``: physical parameters per sample (0 without)."""
        return 0 if self.theta is None else int(self.theta.shape[1])

    def __len__(self) -> int:
        return int(self.value.shape[0])

    def initial(self) -> TrainingArrays:
        """Only the knot-0 samples (the starts at their full time to go)."""
        return self.select(self.knot == 0)

    def select(self, mask: np.ndarray) -> TrainingArrays:
        """The samples where ``mask`` (bool or index array) selects."""
        return TrainingArrays(
            self.x[mask],
            self.tau[mask],
            self.value[mask],
            self.grad_x[mask],
            self.solve_index[mask],
            self.knot[mask],
            None if self.theta is None else self.theta[mask],
            None if self.grad_theta is None else self.grad_theta[mask],
        )

    def concat(self, other: TrainingArrays) -> TrainingArrays:
        """These samples followed by ``other``'s (both with physical parameters, or neither; an empty side adopts
        the other's)."""
        if len(self) == 0 and self.n_params != other.n_params:
            return other
        if len(other) == 0 and self.n_params != other.n_params:
            return self
        if (self.theta is None) != (other.theta is None) or self.n_params != other.n_params:
            raise ValueError(
                f"cannot join samples over {self.n_params} physical parameters with samples over {other.n_params}"
            )

        def cat(a: np.ndarray | None, b: np.ndarray | None) -> np.ndarray | None:
            return None if a is None or b is None else np.concatenate([a, b])

        return TrainingArrays(
            np.concatenate([self.x, other.x]),
            np.concatenate([self.tau, other.tau]),
            np.concatenate([self.value, other.value]),
            np.concatenate([self.grad_x, other.grad_x]),
            np.concatenate([self.solve_index, other.solve_index]),
            np.concatenate([self.knot, other.knot]),
            cat(self.theta, other.theta),
            cat(self.grad_theta, other.grad_theta),
        )


def training_arrays(records: Iterable[SolveRecord], nx: int | None = None) -> TrainingArrays:
    """Every knot of every *successful* record as training samples (failed solves are never data).

    Records over robots (``theta`` of ``k > 0`` parameters) give each knot its solve's ``theta`` and the per-knot
    ``dV_k/dtheta`` labels; mixing records with and without robots (or with other ``k``) is an error.

    Raises:
        ValueError: the records disagree on their number of physical parameters.
    """
    good = [r for r in records if r.success and np.isfinite(r.value) and np.all(np.isfinite(r.cost_to_go))]
    if not good:
        n = nx if nx is not None else 0
        empty = np.zeros(0)
        return TrainingArrays(np.zeros((0, n)), empty, empty, np.zeros((0, n)), empty.astype(np.int64), empty)
    ks = sorted({r.n_params for r in good})
    if len(ks) > 1:
        raise ValueError(f"records over different numbers of physical parameters {ks} cannot be one training set")
    k = ks[0]
    theta = grad_theta = None
    if k:
        theta = np.concatenate([np.repeat(r.theta[None, :], r.cost_to_go.shape[0], axis=0) for r in good])
        grad_theta = np.concatenate([r.knot_grad_theta for r in good])
    return TrainingArrays(
        x=np.concatenate([r.states for r in good]),
        tau=np.concatenate([r.time_to_go for r in good]),
        value=np.concatenate([r.cost_to_go for r in good]),
        grad_x=np.concatenate([r.knot_grads for r in good]),
        solve_index=np.concatenate([np.full(r.cost_to_go.shape[0], r.index, dtype=np.int64) for r in good]),
        knot=np.concatenate([np.arange(r.cost_to_go.shape[0]) for r in good]),
        theta=theta,
        grad_theta=grad_theta,
    )


def count_failures(records: Sequence[SolveRecord]) -> int:
    """Number of failed solves among ``records``."""
    return sum(1 for r in records if not r.success)


def _jsonable(obj: Any) -> Any:
    """Round-trip through JSON so comparisons with a stored header are like for like."""
    return json.loads(json.dumps(obj, sort_keys=True, default=str))
