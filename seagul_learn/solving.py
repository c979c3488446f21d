"""How learning code asks for solves: an injected batch solver, wrapped by a runner that numbers and stores them.

A *batch solver* is any callable ``(starts (n, nx), taus (n,)) -> list[SolveResult]`` in input order (the real
one is :func:`trajopt_batch_solver`, built on ``seagul_learn.parallel.solve_many``; tests inject a toy with a known
value function). :class:`SolveRunner` gives every requested solve the next deterministic index, reuses the record
already on disk for that index (an interrupted run resumes without re-solving or duplicating), writes each new
record atomically as soon as its chunk finishes, and counts solves and failures.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from seagul_learn.dataset import Dataset, DatasetError, SolveRecord
from seagul_learn.results import SolveResult

BatchSolver = Callable[[np.ndarray, np.ndarray], list[SolveResult]]
"""``(starts (n, nx), taus (n,)) -> list[SolveResult]`` in input order; never raises for an infeasible start."""


def trajopt_batch_solver(
    task_name: str,
    *,
    workers: int = 1,
    backend: str = "local",
    progress: bool = False,
    solver_options: dict[str, Any] | None = None,
) -> BatchSolver:
    """The real solver: ``solve_many`` on the full-horizon trajectory optimizer (imported lazily)."""
    from seagul_learn.parallel import solve_many  # the optimizer stack is only needed when actually solving

    def solve(starts: np.ndarray, taus: np.ndarray) -> list[SolveResult]:
        return solve_many(
            task_name,
            np.atleast_2d(np.asarray(starts, dtype=np.float64)),
            np.asarray(taus, dtype=np.float64).reshape(-1),
            workers=workers,
            backend=backend,
            progress=progress,
            solver_options=solver_options,
        )

    return solve


def solver_key(solver_options: dict[str, Any] | None) -> str:
    """A stable text key of the real solver's settings (caches of solved sets are keyed by it)."""
    return "trajopt:" + json.dumps(solver_options or {}, sort_keys=True, default=str)


class SolveRunner:
    """Numbers solves deterministically, reuses stored records, stores new ones atomically, counts failures."""

    def __init__(
        self,
        batch_solver: BatchSolver,
        dataset: Dataset | None = None,
        next_index: int = 0,
        chunk_size: int = 1,
        on_record: Callable[[SolveRecord], None] | None = None,
    ) -> None:
        """``chunk_size`` solves go to the batch solver at once (use the worker count: parallel, yet each
        finished chunk is on disk before the next starts)."""
        if chunk_size < 1:
            raise ValueError(f"chunk_size must be >= 1, got {chunk_size}")
        self.batch_solver = batch_solver
        self.dataset = dataset
        self.next_index = int(next_index)
        self.chunk_size = int(chunk_size)
        self.on_record = on_record
        self.num_solved = 0
        """Solves actually run by this runner (excludes reused records)."""
        self.num_reused = 0
        """Records taken from disk instead of solving again."""

    def solve(
        self,
        starts: np.ndarray,
        taus: np.ndarray,
        sampler: str,
        chains: Sequence[int] | None = None,
        steps: Sequence[int] | None = None,
    ) -> list[SolveRecord]:
        """Solve (or reuse) one record per row of ``starts``, in order, with consecutive indices."""
        starts = np.atleast_2d(np.asarray(starts, dtype=np.float64))
        taus = np.asarray(taus, dtype=np.float64).reshape(-1)
        n = starts.shape[0]
        if taus.shape[0] != n:
            raise ValueError(f"need one tau per start: {n} starts, {taus.shape[0]} taus")
        chains = [-1] * n if chains is None else [int(c) for c in chains]
        steps = [0] * n if steps is None else [int(s) for s in steps]
        records: list[SolveRecord | None] = [None] * n
        pending: list[int] = []
        for i in range(n):
            index = self.next_index + i
            if self.dataset is not None and index in self.dataset:
                rec = self.dataset.read(index)
                if not rec.same_request(starts[i], taus[i]) or rec.sampler != sampler:
                    raise DatasetError(
                        f"record {index} in {str(self.dataset.path)!r} answers another request "
                        f"({rec.sampler} x={rec.x_init.tolist()} tau={rec.tau}) than this run plans "
                        f"({sampler} x={starts[i].tolist()} tau={taus[i]}): the dataset belongs to another "
                        "configuration or seed"
                    )
                records[i] = rec
                self.num_reused += 1
            else:
                pending.append(i)
        for lo in range(0, len(pending), self.chunk_size):
            chunk = pending[lo : lo + self.chunk_size]
            results = self.batch_solver(starts[chunk], taus[chunk])
            if len(results) != len(chunk):
                raise RuntimeError(f"batch solver returned {len(results)} results for {len(chunk)} starts")
            for i, result in zip(chunk, results, strict=True):
                rec = SolveRecord.from_result(result, self.next_index + i, sampler, chains[i], steps[i])
                if self.dataset is not None:
                    self.dataset.write(rec)
                records[i] = rec
                self.num_solved += 1
        self.next_index += n
        out = [r for r in records if r is not None]
        if self.on_record is not None:
            for rec in out:
                self.on_record(rec)
        return out
