"""Real solver failures are counted, stored with their status and never become training data.

On the REAL trajectory optimizer (tests/test_dataset.py, test_samplers.py and test_training.py
check the same bookkeeping with the toy solver's made-up failures). Failures are forced with IPOPT's own
iteration limit (``max_iter=1``), so the statuses, the NaN value and the last-iterate arrays are what a genuine
failure produces. Training runs the adversarial sampler with every ascent iterate failing: each chain must stop at
its failed iterate and keep its start, the dataset must store the failures with their status, the metrics must
count them, and the weights must not depend on the failed records' arrays at all (replacing them by garbage
leaves the trained network bit-identical).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from seagul_envs import make_task
from seagul_learn.dataset import training_arrays
from seagul_learn.results import SolveResult
from seagul_learn.solving import BatchSolver, trajopt_batch_solver
from seagul_learn.training import TrainConfig, TrainResult, _make_sampler, train
from seagul_learn.trajopt import TrajectoryOptimizer

IPOPT_LIMIT = "Maximum_Iterations_Exceeded"
# IPOPT for every attempt (whatever the default solver plan), stopped after one iteration: a certain failure.
FAIL = {"solver": "ipopt", "fallback_solver": "ipopt", "guesses": ("line", "goal"), "max_iter": 1}


def test_a_failed_solve_returns_its_status_and_never_raises() -> None:
    opt = TrajectoryOptimizer("acrobot", **FAIL)
    x = make_task("acrobot").sample_x0(np.random.default_rng(0))
    result = opt.solve(x)
    assert not result.success and result.status == IPOPT_LIMIT
    assert np.isnan(result.value)
    assert result.attempts == ["ipopt:line", "ipopt:goal"]  # the fallback guess is tried before giving up
    assert opt.counters.failures == 1 and opt.counters.statuses == {IPOPT_LIMIT: 1}


def _config(**overrides: object) -> TrainConfig:
    base: dict[str, object] = {
        "task": "acrobot",
        "sampler": "adversarial",
        "budget": 6,
        "schedule.solves_per_round": 3,
        "schedule.train_steps_per_round": 20,
        "schedule.batch_size": 32,
        "schedule.pretrain_solves": 3,
        "schedule.pretrain_steps": 10,
        "sampler.max_steps": 3,
        "seed": 2,
        "validate": False,
        "runtime.progress": False,
    }
    base.update(overrides)
    return TrainConfig(**base)  # type: ignore[arg-type]


def _iterates_fail(config: TrainConfig, garbage: float | None) -> BatchSolver:
    """The real solver, but every adversarial ascent iterate (a start not in the run's pool) hits max_iter=1.

    ``garbage`` replaces a failed result's arrays by absurd finite numbers (they must never reach training).
    """
    pool = {tuple(x) for x in _make_sampler(config, make_task(config.task)).pool.starts}
    good = trajopt_batch_solver(config.task)
    bad = trajopt_batch_solver(config.task, solver_options=FAIL)
    calls = [0]

    def solve(starts: np.ndarray, taus: np.ndarray) -> list[SolveResult]:
        out: list[SolveResult] = []
        for x, t in zip(starts, taus, strict=True):
            pretraining = calls[0] < config.schedule.pretrain_solves  # pretraining comes first (validation is off)
            calls[0] += 1
            (result,) = (good if pretraining or tuple(x) in pool else bad)(x[None], np.array([t]))
            if not result.success and garbage is not None:
                result = dataclasses.replace(
                    result,
                    states=np.full_like(result.states, garbage),
                    cost_to_go=np.full_like(result.cost_to_go, garbage),
                    knot_grads=np.full_like(result.knot_grads, garbage),
                    grad_x=np.full_like(result.grad_x, garbage),
                )
            out.append(result)
        return out

    return solve


def _train(tmp_path: Path, name: str, garbage: float | None) -> TrainResult:
    config = _config()
    return train(config, tmp_path / name, batch_solver=_iterates_fail(config, garbage), solver_name="failing")


def test_failures_are_stored_counted_and_never_trained_on(tmp_path: Path) -> None:
    result = _train(tmp_path, "run", garbage=None)
    records = result.dataset.records()
    failed = [r for r in records if not r.success]
    assert len(records) == 3 + 6
    assert failed and all(r.status == IPOPT_LIMIT and np.isnan(r.value) for r in failed)
    assert all(r.success for r in records if r.sampler == "pretrain")

    # every chain: a successful start, then the failed iterate, and nothing after it
    chains: dict[int, list] = {}
    for r in records:
        if r.sampler == "adversarial":
            chains.setdefault(r.chain, []).append(r)
    assert any(len(c) == 2 for c in chains.values()), "no chain reached an ascent iterate"
    for recs in chains.values():
        assert [r.step for r in recs] == list(range(len(recs)))
        assert recs[0].success
        assert all(not r.success for r in recs[1:]) and len(recs) <= 2  # stopped at its first failure

    # counted: the result, every metric row (cumulative, per round) and the files on disk
    assert result.num_failures == len(failed)
    assert [m.failures for m in result.metrics] == [0, sum(not r.success for r in records[3:6]), len(failed)]
    on_disk = json.loads((tmp_path / "run" / "metrics.json").read_text())["metrics"]
    assert on_disk[-1]["failures"] == len(failed)

    # never data: the training arrays hold exactly the knots of the successful solves
    arrays = training_arrays(records, nx=4)
    assert set(arrays.solve_index.tolist()) == {r.index for r in records if r.success}
    assert len(arrays) == sum(r.cost_to_go.size for r in records if r.success)


def test_failed_records_do_not_influence_the_weights(tmp_path: Path) -> None:
    plain = _train(tmp_path, "plain", garbage=None)
    poisoned = _train(tmp_path, "poisoned", garbage=1e9)
    assert poisoned.num_failures == plain.num_failures > 0
    stored = [r for r in poisoned.dataset.records() if not r.success]
    assert all(np.all(r.cost_to_go == 1e9) for r in stored)  # the garbage really is in the dataset
    np.testing.assert_array_equal(plain.network.casadi_parameters(), poisoned.network.casadi_parameters())

    # Guard (the comparison can fail): the same garbage in ONE successful record's labels changes the weights.
    config = _config()
    inner = _iterates_fail(config, None)
    calls = [0]

    def poison_first_budget_solve(starts: np.ndarray, taus: np.ndarray) -> list[SolveResult]:
        out = []
        for r in inner(starts, taus):
            calls[0] += 1
            if calls[0] == config.schedule.pretrain_solves + 1:
                assert r.success
                r = dataclasses.replace(r, cost_to_go=r.cost_to_go + 1e9)
            out.append(r)
        return out

    other = train(config, tmp_path / "other", batch_solver=poison_first_budget_solve, solver_name="failing")
    assert not np.array_equal(plain.network.casadi_parameters(), other.network.casadi_parameters())
