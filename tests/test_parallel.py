"""solve_many: input order, bit-identical results whatever the worker count, input checks."""

from __future__ import annotations

import numpy as np
import pytest
from result_checks import assert_same_results

from seagul_envs.tasks import make_task
from seagul_learn.parallel import solve_many
from seagul_learn.results import SolveResult


@pytest.fixture(scope="module")
def acrobot_starts() -> np.ndarray:
    return make_task("acrobot").sample_x0(np.random.default_rng(11), 8)


@pytest.fixture(scope="module")
def serial(acrobot_starts: np.ndarray) -> list[SolveResult]:
    return solve_many("acrobot", acrobot_starts, progress=False)


def test_serial_results_in_input_order(acrobot_starts: np.ndarray, serial: list[SolveResult]) -> None:
    assert len(serial) == len(acrobot_starts)
    for x, r in zip(acrobot_starts, serial, strict=True):
        np.testing.assert_array_equal(r.x_init, x)
        assert r.tau == 5.0 and r.success


def test_two_workers_identical_to_serial(acrobot_starts: np.ndarray, serial: list[SolveResult]) -> None:
    parallel = solve_many("acrobot", acrobot_starts, workers=2, progress=False)
    assert_same_results(serial, parallel)


def test_reversed_input_gives_reversed_output(acrobot_starts: np.ndarray, serial: list[SolveResult]) -> None:
    """A result depends on its own input only (no warm start carried between solves)."""
    back = solve_many("acrobot", acrobot_starts[::-1], workers=2, progress=False)
    assert_same_results(serial[::-1], back)


def test_glider_with_taus_and_options() -> None:
    task = make_task("glider")
    starts = task.sample_x0(np.random.default_rng(5), 2)
    taus = np.array([0.78, 0.82])
    # Interpreted: the options' path to the workers is tested here; compiling the glider's solver took 20 s cold.
    res = solve_many("glider", starts, taus, progress=False, solver_options={"solver": "ipopt", "codegen": False})
    assert [r.tau for r in res] == [0.78, 0.82]
    assert all(r.success and r.attempts[0].startswith("ipopt") for r in res)


def test_empty_batch() -> None:
    assert solve_many("acrobot", np.zeros((0, 4)), progress=False) == []


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"starts": np.zeros((2, 3))}, "shape"),
        ({"starts": np.full((2, 4), np.nan)}, "NaN"),
        ({"taus": np.array([5.0])}, "entries"),
        ({"taus": np.array([5.0, 4.0])}, "outside"),
        ({"workers": 0}, "workers"),
        ({"backend": "dask"}, "backend"),
        ({"solver_options": {"solver": "knitro"}}, "unknown solver"),
        ({"solver_options": {"nonsense": 1}}, "nonsense"),
    ],
)
def test_bad_batches_raise(kwargs: dict, match: str) -> None:
    args = {"starts": np.tile(make_task("acrobot").goal, (2, 1)), **kwargs}
    with pytest.raises(ValueError, match=match):
        solve_many("acrobot", progress=False, **args)


def test_ray_missing_gives_a_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    import builtins

    real_import = builtins.__import__

    def fake_import(name: str, *args, **kwargs):
        if name == "ray":
            raise ImportError("no ray here")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", fake_import)
    with pytest.raises(ImportError, match=r"seagul\[ray\]"):
        solve_many("acrobot", np.tile(make_task("acrobot").goal, (1, 1)), backend="ray", progress=False)


def test_local_pool_coexists_with_joblib_parallel() -> None:
    """solve_many's process pool must not break (or be broken by) joblib.Parallel in the same process: the
    experiment solves its validation set, then trains and evaluates through joblib."""
    from joblib import Parallel, delayed

    task = make_task("acrobot")
    starts = task.sample_x0(np.random.default_rng(3), 4)
    first = solve_many("acrobot", starts, workers=2, progress=False)
    assert Parallel(n_jobs=2)(delayed(abs)(-i) for i in range(4)) == [0, 1, 2, 3]
    again = solve_many("acrobot", starts, workers=2, progress=False)
    assert [r.value for r in first] == [r.value for r in again]


def test_guided_chunks_cover_every_start_once_and_shrink_at_the_end():
    from seagul_learn.parallel import _chunks

    for n, workers in [(1, 1), (7, 2), (200, 2), (1000, 8)]:
        chunks = _chunks(n, workers, None)
        assert np.array_equal(np.concatenate(chunks), np.arange(n))
        sizes = [len(c) for c in chunks]
        assert max(sizes) <= 16 and sizes == sorted(sizes, reverse=True)
        assert sizes[-1] == 1  # the tail shrinks to single solves, so the workers finish together
    assert [len(c) for c in _chunks(10, 2, 3)] == [3, 3, 3, 1]
