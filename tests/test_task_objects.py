"""A Task object everywhere a name is accepted; caches keyed by the task's content.

``solve_many`` and ``trajopt_batch_solver`` take a :class:`Task` (or a registered name, resolved once in the caller)
and send the object itself to the workers, so a variant of the acrobot that keeps the name ``"acrobot"`` is solved
as given instead of silently as the built-in one. :meth:`Task.fingerprint` is the content key of every cache: the
per-worker optimizers, the cached solves (``CachedBatchSolver``, ``solver_key``) and the compiled solvers.

The variant changes one physical parameter (the mass of link 2). To keep the tests fast, solves are of the 1 s tail
problem (10 intervals) with one interpreted IPOPT attempt (:data:`FAST`): no test compiles a library for the acrobot.
"""

from __future__ import annotations

import dataclasses
import os
import pickle
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np
import pytest
from result_checks import assert_same_results

from seagul_control import transcription as tr_mod
from seagul_control.transcription import Transcription, TranscriptionOptions, compile_nlp_library
from seagul_envs import make_task
from seagul_envs.tasks import available_tasks, resolve_task
from seagul_envs.tasks.acrobot import AcrobotParams, make_acrobot_task
from seagul_envs.tasks.base import FINGERPRINT_LENGTH, Task
from seagul_learn import parallel
from seagul_learn.parallel import solve_many
from seagul_learn.results import SolveResult
from seagul_learn.solving import CachedBatchSolver, solver_fingerprint, solver_key, trajopt_batch_solver
from seagul_learn.trajopt import TrajectoryOptimizer

FAST: dict[str, Any] = {"codegen": False, "horizon": 10, "plan": ("ipopt:line",), "multi_start": "never"}
"""Options of every acrobot solve here: the interpreted solver on the 10-interval (1 s) problem, one attempt."""
TAU = 1.0
VARIANT = AcrobotParams(m2=1.3)


@pytest.fixture(scope="module")
def variant() -> Task:
    return make_acrobot_task(VARIANT)


@pytest.fixture(scope="module")
def starts() -> np.ndarray:
    """Three starts in X0, near the goal (quick solves)."""
    task = make_task("acrobot")
    return task.goal + 0.5 * (task.sample_x0(np.random.default_rng(3), 3) - task.goal)


# ------------------------------------------------------------------------------------------------- (a) fingerprints
_PRINT_FINGERPRINTS = (
    "from seagul_envs.tasks.acrobot import AcrobotParams, make_acrobot_task\n"
    "from seagul_envs.tasks.glider import make_glider_task\n"
    "print(make_acrobot_task().fingerprint(), make_acrobot_task(AcrobotParams(m2=1.3)).fingerprint(),"
    " make_glider_task().fingerprint())\n"
)


def test_fingerprint_follows_the_content_not_the_object(variant: Task) -> None:
    a, b = make_acrobot_task(), make_acrobot_task()
    fp = a.fingerprint()
    assert len(fp) == FINGERPRINT_LENGTH and int(fp, 16) >= 0
    assert b.fingerprint() == fp and make_task("acrobot").fingerprint() == fp  # independent builds
    assert a.fingerprint() is fp  # memoised
    assert variant.name == "acrobot" and variant.fingerprint() != fp  # one physical parameter
    assert make_acrobot_task(AcrobotParams(m2=1.0 + 1e-15)).fingerprint() != fp  # to the bit
    assert make_task("glider").fingerprint() != fp
    # Fields outside the CasADi functions count too: a bound, the start box, a step setting, the name.
    for change in (
        {"u_high": a.u_high * 0.5},
        {"x0_high": a.x0_high + 0.1},
        {"rk4_substeps": 2},
        {"max_sim_substep": 0.001},
        {"name": "acrobot2"},
    ):
        assert dataclasses.replace(a, **change).fingerprint() != fp, change
    assert dataclasses.replace(a).fingerprint() == fp
    # A pickled copy computes its own fingerprint (the memo does not travel) and gets the same one.
    copy = pickle.loads(pickle.dumps(a))
    assert "_fingerprint" not in copy.__dict__ and copy.fingerprint() == fp


def test_fingerprint_is_the_same_in_another_process(variant: Task) -> None:
    done = subprocess.run(
        [sys.executable, "-c", _PRINT_FINGERPRINTS], capture_output=True, text=True, timeout=120, check=True
    )
    here = [make_acrobot_task().fingerprint(), variant.fingerprint(), make_task("glider").fingerprint()]
    assert done.stdout.split() == here


# ------------------------------------------------------------------------------------ (b) a variant in solve_many
@pytest.fixture(scope="module")
def default_results(starts: np.ndarray) -> list[SolveResult]:
    return solve_many("acrobot", starts, _taus(starts), progress=False, solver_options=FAST)


def _taus(starts: np.ndarray) -> np.ndarray:
    return np.full(starts.shape[0], TAU)


def test_a_variant_is_solved_as_given_by_two_workers(
    variant: Task, starts: np.ndarray, default_results: list[SolveResult]
) -> None:
    expected = [TrajectoryOptimizer(variant, **FAST).solve(x, TAU) for x in starts]
    remote = solve_many(variant, starts, _taus(starts), workers=2, progress=False, solver_options=FAST)
    assert all(r.success for r in expected)
    assert_same_results(expected, remote)
    # Not the built-in acrobot's values (what a name looked up in the workers would have solved).
    assert all(r.success for r in default_results)
    for mine, builtin in zip(remote, default_results, strict=True):
        assert abs(mine.value - builtin.value) > 1e-3 * abs(builtin.value)


def test_trajopt_batch_solver_takes_the_task_object(
    variant: Task, starts: np.ndarray, default_results: list[SolveResult]
) -> None:
    solver = trajopt_batch_solver(variant, solver_options=FAST)
    assert solver.task is variant and resolve_task(variant) is variant
    by_name = trajopt_batch_solver("acrobot", solver_options=FAST)
    assert by_name.task is make_task("acrobot")  # a name is resolved once, in the caller
    direct = solve_many(variant, starts[:1], _taus(starts[:1]), progress=False, solver_options=FAST)
    assert_same_results(direct, solver(starts[:1], _taus(starts[:1])))
    # In this process, too, optimizers are kept per task fingerprint and options, not per name.
    keys = {fp for fp, frozen in parallel._OPTIMIZERS if frozen == parallel._freeze(FAST)}
    assert {variant.fingerprint(), make_task("acrobot").fingerprint()} <= keys


# --------------------------------------------------------------------------------------------- (c) cache keys
def _toy_result(x: np.ndarray, tau: float) -> SolveResult:
    nx = x.shape[0]
    return SolveResult(
        x_init=x.copy(),
        tau=tau,
        success=True,
        status="Solve_Succeeded",
        value=float(x @ x),
        grad_x=2 * x,
        grad_tau=0.0,
        states=np.stack([x, np.zeros(nx)]),
        controls=np.zeros((1, 1)),
        steps=np.array([tau]),
        time_to_go=np.array([tau, 0.0]),
        cost_to_go=np.array([float(x @ x), 0.0]),
        knot_grads=np.stack([2 * x, np.zeros(nx)]),
        iterations=1,
        solve_time=0.0,
    )


def test_solve_cache_keys_differ_between_the_variant_and_the_default(variant: Task, tmp_path: Path) -> None:
    default = make_task("acrobot")
    assert solver_key(None, variant) != solver_key(None, default)
    assert solver_key(None, "acrobot") == solver_key(None, default)  # a name stands for its registered task
    assert solver_key({"max_iter": 9}, variant) != solver_key(None, variant)
    assert solver_key(None) == solver_key(None, None)  # without a task: the code's key alone
    assert solver_fingerprint(variant) != solver_fingerprint(default) != solver_fingerprint()

    # The real batch solver carries its task, and the result cache keys by its fingerprint.
    x, tau = default.goal, default.tau_nominal
    key = solver_key(None)
    cached_default = CachedBatchSolver(trajopt_batch_solver(default), tmp_path, key)
    cached_variant = CachedBatchSolver(trajopt_batch_solver(variant), tmp_path, key)
    assert cached_default.task_fingerprint == default.fingerprint()
    assert cached_variant.task_fingerprint == variant.fingerprint()
    assert cached_default._path(x, tau) != cached_variant._path(x, tau)

    # End to end with a counting toy: a hit for the same task, a miss for the variant.
    calls: list[int] = []

    def toy(xs: np.ndarray, taus: np.ndarray) -> list[SolveResult]:
        calls.append(len(xs))
        return [_toy_result(xi, float(t)) for xi, t in zip(xs, taus, strict=True)]

    CachedBatchSolver(toy, tmp_path / "toy", "toy", task=default)(x[None], np.array([tau]))
    again = CachedBatchSolver(toy, tmp_path / "toy", "toy", task=make_acrobot_task())
    again(x[None], np.array([tau]))
    assert again.hits == 1 and calls == [1]
    other = CachedBatchSolver(toy, tmp_path / "toy", "toy", task=variant)
    other(x[None], np.array([tau]))
    assert other.misses == 1 and calls == [1, 1]

    class Described:  # a batch solver whose ``task`` attribute is not a Task: keyed by its name alone
        task = "a description"

        def __call__(self, xs: np.ndarray, taus: np.ndarray) -> list[SolveResult]:
            return toy(xs, taus)

    assert CachedBatchSolver(Described(), tmp_path / "toy", "toy").task_fingerprint is None


def test_the_transcription_hands_the_task_fingerprint_to_the_compiled_solver_cache(
    variant: Task, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The acrobot's libraries take long to compile: record what would be compiled, then solve interpreted."""
    seen: list[tuple[str, str | None]] = []

    def record(
        solver: ca.Function, name: str, cache_dir: Any = None, fingerprint: str | None = None, flags: Any = None
    ) -> Path:
        seen.append((name, fingerprint))
        raise RuntimeError("not compiled in this test")

    monkeypatch.setattr(tr_mod, "compile_nlp_library", record)
    for task in (make_task("acrobot"), variant):
        with pytest.warns(UserWarning, match="not compiled in this test"):
            Transcription(
                task, 1, TranscriptionOptions(free_time=False, step=0.1, codegen=True, codegen_dir=str(tmp_path))
            )
    name = "acrobot_ipopt_n1"
    assert seen == [(name, make_task("acrobot").fingerprint()), (name, variant.fingerprint())]


def test_compiled_solver_file_names_differ_between_two_variants(tmp_path: Path) -> None:
    """End to end on a small task (it compiles in well under a second): one library per fingerprint."""
    if tr_mod.find_c_compiler() is None:
        pytest.skip("no C compiler")
    kwargs: dict[str, Any] = {"free_time": False, "step": 0.1, "codegen": True, "codegen_dir": tmp_path}
    light, heavy = make_point_mass(1.0), make_point_mass(2.0)
    a, b = (
        Transcription(light, 1, TranscriptionOptions(**kwargs)),
        Transcription(heavy, 1, TranscriptionOptions(**kwargs)),
    )
    assert a.codegen_library is not None and b.codegen_library is not None
    assert a.codegen_library.name.startswith(f"point_mass_ipopt_n1_{light.fingerprint()}_")
    assert b.codegen_library.name.startswith(f"point_mass_ipopt_n1_{heavy.fingerprint()}_")
    x = np.array([0.5, 0.0])
    assert a.solve(x, 0.1).objective != pytest.approx(b.solve(x, 0.1).objective)


def test_an_unfingerprinted_library_is_linked_not_recompiled(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    if tr_mod.find_c_compiler() is None:
        pytest.skip("no C compiler")
    x = ca.MX.sym("x")
    solver = ca.nlpsol("tiny", "ipopt", {"x": x, "f": (x - 1) ** 2})
    legacy = compile_nlp_library(solver, "tiny", tmp_path)  # no fingerprint in the file name
    assert legacy.name.startswith("tiny_") and legacy.name.count("_") == 1

    def no_compiler(*args: Any, **kwargs: Any) -> Any:
        raise AssertionError("compiled again")

    monkeypatch.setattr(tr_mod.subprocess, "run", no_compiler)
    lib = compile_nlp_library(solver, "tiny", tmp_path, fingerprint="0123abcd")
    assert lib.name == legacy.name.replace("tiny_", "tiny_0123abcd_") and lib.is_file()
    assert os.path.samefile(lib, legacy)
    with pytest.raises(ValueError, match="fingerprint"):
        compile_nlp_library(solver, "tiny", tmp_path, fingerprint="../evil")


# ---------------------------------------------------------------------------------------- (d) an unregistered task
def make_point_mass(mass: float = 1.0) -> Task:
    """A task no registry knows: a 1-D point mass pushed to the origin in 1 s (10 intervals)."""
    x, u = ca.SX.sym("x", 2), ca.SX.sym("u", 1)
    dynamics = ca.Function("point_mass_f", [x, u], [ca.vertcat(x[1], u[0] / mass)], ["x", "u"], ["xdot"])
    stage = ca.Function("point_mass_l", [x, u], [ca.sumsqr(x) + 0.1 * u[0] ** 2], ["x", "u"], ["l"])
    terminal = ca.Function("point_mass_lf", [x], [10 * ca.sumsqr(x)], ["x"], ["lf"])
    inf = np.full(2, np.inf)
    return Task(
        name="point_mass",
        state_names=("p", "v"),
        control_names=("force",),
        dynamics=dynamics,
        stage_cost=stage,
        terminal_cost=terminal,
        goal=np.zeros(2),
        u_low=np.array([-2.0]),
        u_high=np.array([2.0]),
        x_low=-inf,
        x_high=inf,
        x_final_low=-inf,
        x_final_high=inf,
        x0_low=np.array([-1.0, -1.0]),
        x0_high=np.array([1.0, 1.0]),
        tau_range=(1.0, 1.0),
        tau_nominal=1.0,
        num_steps=10,
        step_bounds=(0.1, 0.1),
        fixed_step=True,
        rk4_substeps=1,
        control_period=0.1,
        params={"mass": mass},
    )


def test_an_unregistered_task_goes_through_two_local_workers() -> None:
    task = make_point_mass()
    assert task.name not in available_tasks()
    starts = task.sample_x0(np.random.default_rng(0), 4)
    expected = [TrajectoryOptimizer(task, codegen=False).solve(x) for x in starts]
    remote = solve_many(task, starts, workers=2, progress=False, solver_options={"codegen": False})
    assert all(r.success for r in expected)
    assert_same_results(expected, remote)
    heavy = solve_many(make_point_mass(2.0), starts, workers=2, progress=False, solver_options={"codegen": False})
    assert all(h.value != r.value for h, r in zip(heavy, remote, strict=True))


@pytest.mark.parametrize("bad", [42, None, object(), make_acrobot_task, AcrobotParams()])
def test_neither_a_task_nor_a_name_is_a_clear_error(bad: Any) -> None:
    message = f"Task or a registered task name .*got {type(bad).__name__}"
    cached_message = message if bad is not None else "got float: 0.5"  # task=None means "the solver's task"
    with pytest.raises(TypeError, match=message):
        solve_many(bad, np.zeros((1, 4)), progress=False)
    with pytest.raises(TypeError, match=message):
        trajopt_batch_solver(bad)
    with pytest.raises(TypeError, match=cached_message):
        CachedBatchSolver(lambda xs, taus: [], "unused", "toy", task=bad if bad is not None else 0.5)


def test_unknown_names_and_malformed_tasks_are_clear_errors() -> None:
    with pytest.raises(ValueError, match="unknown task 'cartpole'; available tasks"):
        solve_many("cartpole", np.zeros((1, 4)), progress=False)
    with pytest.raises(ValueError, match="unknown task 'cartpole'"):
        solver_key(None, "cartpole")
    with pytest.raises(ValueError, match="unknown task 'cartpole'"):
        resolve_task("cartpole")
    assert resolve_task("acrobot") is make_task("acrobot")
    with pytest.raises(ValueError, match="malformed task 'point_mass': num_steps must be a positive int"):
        solve_many(dataclasses.replace(make_point_mass(), num_steps=0), np.zeros((1, 2)), progress=False)


# ---------------------------------------------------------------------------------------------------------- Ray
# Starting a private Ray costs about 10-15 s on a loaded 2-core machine, more than the rest of this file: the test is
# marked ``slow`` too (run it with ``pytest -m ray tests/test_task_objects.py``).
@pytest.fixture
def private_ray() -> Iterator[Any]:
    ray = pytest.importorskip("ray")
    if ray.is_initialized():
        ray.shutdown()
    address = os.environ.pop("RAY_ADDRESS", None)
    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        yield ray
    finally:
        parallel.shutdown_ray_pool()
        ray.shutdown()
        if address is not None:
            os.environ["RAY_ADDRESS"] = address


@pytest.mark.ray
@pytest.mark.slow
def test_a_variant_on_ray_actors(private_ray: Any, variant: Task, starts: np.ndarray) -> None:
    local = solve_many(variant, starts[:2], _taus(starts[:2]), progress=False, solver_options=FAST)
    remote = solve_many(
        variant, starts[:2], _taus(starts[:2]), workers=2, backend="ray", progress=False, solver_options=FAST
    )
    assert_same_results(local, remote)


def test_the_mpc_defaults_are_one_typed_part_and_the_flat_names_still_work() -> None:
    """``TaskProfile.mpc`` (:class:`MPCDefaults`) replaced four flat ``mpc_*`` fields: the old names construct and
    read with a DeprecationWarning, bad values name the field the caller gave, and the built-in tasks' values."""
    from seagul_envs import MPCDefaults, TaskProfile

    acrobot, glider = make_task("acrobot"), make_task("glider")
    assert acrobot.profile.mpc == MPCDefaults(horizon=5, trust_region="none", goal_blend=1.0)
    assert glider.profile.mpc.final_soft_weight == 1e4 and glider.profile.default_horizon(glider) == 10
    with pytest.warns(DeprecationWarning, match=r"mpc_horizon -> mpc\.horizon"):
        old = TaskProfile(mpc_horizon=3, mpc_trust_region="box")  # type: ignore[call-arg]
    assert old.mpc == MPCDefaults(horizon=3, trust_region="box")
    with pytest.warns(DeprecationWarning, match=r"use TaskProfile\.mpc\.goal_blend"):
        assert acrobot.profile.mpc_goal_blend == 1.0
    # dataclasses.replace keeps the part and never resurrects a flat value.
    assert dataclasses.replace(old, mpc=MPCDefaults(horizon=7)).mpc == MPCDefaults(horizon=7)
    wall = r"TaskProfile.mpc_trust_region must be one of \['lqr', 'box', 'none'\]"
    with pytest.warns(DeprecationWarning), pytest.raises(ValueError, match=wall):
        TaskProfile(mpc_trust_region="wall")  # type: ignore[call-arg]
    for bad, match in (
        ({"horizon": 0}, "horizon must be an integer >= 1"),
        ({"horizon": 2.5}, "horizon must be an integer >= 1"),
        ({"goal_blend": -1.0}, "goal_blend must be a finite number >= 0"),
        ({"final_soft_weight": 0.0}, "final_soft_weight must be a finite number > 0"),
    ):
        with pytest.raises(ValueError, match=match):
            MPCDefaults(**bad)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"TaskProfile\.mpc must be an MPCDefaults"):
        TaskProfile(mpc={"horizon": 3})  # type: ignore[arg-type]


def test_periodic_angles_are_validated_wrapped_and_fingerprinted_only_when_declared() -> None:
    """``Task.periodic``: the wrapped error ``state_error``, the LQR that does not care about full turns, the
    fingerprint that an empty declaration leaves as it was, and the checks of ``validate_task``."""
    from seagul_control.lqr import LQRPolicy
    from seagul_envs import validate_task

    spinning = make_task("dmc_pendulum")
    assert spinning.periodic == (0,)  # the suite's hinge spins
    plain = dataclasses.replace(spinning, periodic=())
    assert plain.fingerprint() != spinning.fingerprint()
    # An empty declaration does not enter the digest: fingerprints of tasks that declare none stay as they were.
    skip = {f.name: f for f in dataclasses.fields(plain)}["periodic"].metadata["fingerprint_skip"]
    assert skip(plain) and not skip(spinning)
    x = np.array([0.3 + 4 * np.pi, -1.0])
    np.testing.assert_allclose(spinning.state_error(x), [0.3, -1.0], atol=1e-12)
    np.testing.assert_allclose(plain.state_error(x), x - plain.goal)
    batch = np.stack([x, x + np.array([2 * np.pi, 0.0])])
    np.testing.assert_allclose(spinning.state_error(batch), [[0.3, -1.0]] * 2, atol=1e-12)
    lqr = LQRPolicy(spinning)
    np.testing.assert_allclose(lqr.action(x, 1.0), lqr.action(np.array([0.3, -1.0]), 1.0), atol=1e-12)
    validate_task(spinning)
    for bad in ((2,), (0, 0), ("0",), (True,)):
        with pytest.raises(ValueError, match="periodic must"):
            validate_task(dataclasses.replace(plain, periodic=bad))  # type: ignore[arg-type]
