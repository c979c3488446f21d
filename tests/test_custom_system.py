"""A task that is not built in, through every layer: the profile, the env checker, one solve, solve_many
with 1 and 2 workers (and Ray), training and its exact resume, the MPC in closed loop, the closed-loop evaluation
(API with 1 and 2 workers, and ``seagul evaluate --task file.py:factory``), the ``module:factory`` loader's errors;
and a parameter variant of the acrobot that gets a validation set of its own.

The task is the cart-pole of ``examples/custom_system.py`` (loaded from the file, as ``--task`` does), shrunk to a
1 s problem of 10 intervals of 0.1 s so that every solve is ~0.1 s interpreted: the layers are what is tested here,
the swing-up itself is the example's.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from toy_problem import ToySolver

from seagul_control.evaluation import EpisodeResult, PolicySpec, evaluate, is_success, start_grid
from seagul_control.mpc import LimitedLookaheadMPC, MPCOptions
from seagul_envs import (
    EvaluationGrid,
    SuccessRule,
    Task,
    TaskProfile,
    available_tasks,
    load_task,
    make_env,
    make_task,
    validate_task,
)
from seagul_envs.tasks.acrobot import AcrobotParams, make_acrobot_task
from seagul_learn.cli import main
from seagul_learn.parallel import solve_many
from seagul_learn.solving import solver_key, trajopt_batch_solver
from seagul_learn.training import TrainConfig, train, validation_dataset
from seagul_learn.trajopt import TrajOptConfig
from seagul_learn.value_network import ValueNetwork

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "custom_system.py"
THIS = Path(__file__).resolve()
SOLVER = {"codegen": False}
"""Interpreted solvers: no test here compiles anything."""


def _example() -> Any:
    load_task(f"{EXAMPLE}:make_cartpole")  # loads the file as the module "custom_system"
    return sys.modules["custom_system"]


def small_params() -> Any:
    return _example().CartPoleParams(
        tau=1.0, horizon_steps=10, control_period=0.1, mpc_horizon=3, validation_grid=2, validation_draws=2
    )


def make_small_cartpole() -> Task:
    """The factory ``--task tests/test_custom_system.py:make_small_cartpole`` names."""
    return _example().make_cartpole(small_params())


def not_a_task() -> int:
    return 42


def broken_factory() -> Task:
    raise RuntimeError("no model today")


@pytest.fixture(scope="module")
def task() -> Task:
    return make_small_cartpole()


@pytest.fixture(scope="module")
def starts(task: Task) -> np.ndarray:
    return task.sample_x0(np.random.default_rng(5), 3)


def _same_results(a: list[Any], b: list[Any]) -> None:
    assert len(a) == len(b)
    for ra, rb in zip(a, b, strict=True):
        for f in dataclasses.fields(ra):
            if f.name in ("solve_time", "solve_times"):
                continue
            va, vb = getattr(ra, f.name), getattr(rb, f.name)
            if isinstance(va, np.ndarray | float):
                np.testing.assert_array_equal(va, vb, err_msg=f.name)
            else:
                assert va == vb, f.name


# ------------------------------------------------------------------------------------------------- the profile
def test_the_task_is_not_built_in_and_carries_its_profile(task: Task) -> None:
    assert task.name == "cartpole" and task.name not in available_tasks()
    profile = task.profile
    assert profile.default_horizon(task) == 3 and profile.validation_spec(task).grid_points == 2
    assert start_grid(task, 2)[1]["dims"] == ["x", "th"]
    up = task.goal.copy()
    assert is_success(task, up) and not is_success(task, up, terminated=True)
    assert not is_success(task, up + np.array([0, 0.2, 0, 0]))  # |th - pi| = 0.2 > 0.1
    assert is_success(task, up + np.array([1.0, 0.05, 3.0, 0.4]))  # the rule looks at the pole only


def test_the_built_in_profiles_keep_the_former_tables() -> None:
    acrobot, glider = make_task("acrobot"), make_task("glider")
    assert TrajOptConfig().resolved(acrobot).plan == ("fatrop:line", "ipopt_fast:line", "ipopt:line", "ipopt:goal")
    assert TrajOptConfig().resolved(acrobot).suspect_value == 30.0
    assert TrajOptConfig().resolved(glider).plan[0] == "ipopt_fast:kinematic"
    assert glider.profile.solver.kinematic_pairs == ((0, 4), (1, 5))
    assert acrobot.profile.default_horizon(acrobot) == 5 and glider.profile.default_horizon(glider) == 10
    spec = acrobot.profile.validation_spec(acrobot)
    assert (spec.grid_coords, spec.grid_points, spec.num_random) == ((0, 1), 10, 100)
    spec = glider.profile.validation_spec(glider)
    assert (spec.grid_coords, spec.grid_points, spec.num_random) == ((0, 1, 4), 6, 250)
    assert acrobot.profile.env_id == "SeagulAcrobot-v0" and glider.profile.env_id == "SeagulGlider-v0"
    with pytest.warns(DeprecationWarning, match="profile"):
        from seagul_learn.training import VALIDATION_SPECS
    assert VALIDATION_SPECS["glider"] == glider.profile.validation
    with pytest.warns(DeprecationWarning):
        from seagul_learn.experiment import PRESETS
    assert PRESETS["acrobot"]["paper"].grid_points == 20 and PRESETS["glider"]["quick"].mpc_horizon == 10


def test_a_new_task_gets_working_defaults(task: Task) -> None:
    bare = dataclasses.replace(task, profile=TaskProfile())
    assert bare.profile.default_horizon(bare) == round(0.25 / 0.1)
    spec = bare.profile.validation_spec(bare)
    assert spec.grid_coords == (0, 1) and len(spec.starts(bare)) == 200
    assert TrajOptConfig().resolved(bare).plan == ("ipopt:line", "ipopt:goal")
    assert isinstance(bare.profile.success, SuccessRule) and bare.profile.describe_success(bare).startswith("||x(T)")
    assert bare.fingerprint() != task.fingerprint()  # the profile is part of the content
    bad = dataclasses.replace(task, profile=TaskProfile(grid=EvaluationGrid(coords=(0, 7))))
    with pytest.raises(ValueError, match=r"profile\.grid\.coords: state index 7 outside 0\.\.3"):
        validate_task(bad)


# ----------------------------------------------------------------------------------------- env, solve, parallel
# make_env and the env checker, solve_many with 1 and 2 workers and a single solve equal to the batch's first: the
# conformance battery runs them on this task (tests/test_conformance.py, "custom-cartpole").


@pytest.mark.ray
@pytest.mark.slow
def test_ray_gives_the_same_results(task: Task, starts: np.ndarray) -> None:
    ray = pytest.importorskip("ray")
    from seagul_learn.parallel import shutdown_ray_pool

    serial = solve_many(task, starts, workers=1, progress=False, solver_options=SOLVER)
    try:
        on_ray = solve_many(task, starts, workers=2, backend="ray", progress=False, solver_options=SOLVER)
    finally:
        shutdown_ray_pool()
        ray.shutdown()
    _same_results(serial, on_ray)


# ------------------------------------------------------------------------------------------------ train, resume
def _config(task: Any, tmp_path: Path, **overrides: Any) -> TrainConfig:
    base: dict[str, Any] = {
        "task": task,
        "sampler": "adversarial",
        "budget": 4,
        "schedule.solves_per_round": 2,
        "schedule.train_steps_per_round": 5,
        "schedule.batch_size": 16,
        "schedule.pretrain_solves": 2,
        "schedule.pretrain_steps": 5,
        "sampler.max_steps": 2,
        "solver_options": SOLVER,
        "runtime.cache_dir": str(tmp_path / "cache"),
        "runtime.progress": False,
    }
    return TrainConfig(**{**base, **overrides})


class _Interrupt:
    """The real batch solver, interrupted (like Ctrl-C) when a call would take it past ``after`` solves."""

    def __init__(self, task: Task, after: int) -> None:
        self.inner = trajopt_batch_solver(task, solver_options=SOLVER)
        self.task = task
        self.solves, self.after = 0, after

    def __call__(self, starts: np.ndarray, taus: np.ndarray) -> list[Any]:
        self.solves += len(starts)
        if self.solves > self.after:
            raise KeyboardInterrupt("interrupted")
        return self.inner(starts, taus)


@pytest.fixture(scope="module")
def trained(task: Task, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Any]:
    """One run through the command line: ``seagul train --task tests/test_custom_system.py:make_small_cartpole``."""
    tmp = tmp_path_factory.mktemp("train")
    argv = ["train", "--task", f"{THIS}:make_small_cartpole", "--out", str(tmp / "cli"), "--budget", "4"]
    argv += ["--solves-per-round", "2", "--train-steps-per-round", "5", "--batch-size", "16", "--pretrain-solves", "2"]
    argv += ["--pretrain-steps", "5", "--adv-max-steps", "2", "--solver-options", '{"codegen": false}']
    argv += ["--cache-dir", str(tmp / "cache"), "--no-progress"]
    assert main(argv) == 0
    return tmp, ValueNetwork.load(tmp / "cli" / "network.pt")


def test_training_stores_the_task_and_resumes_to_the_same_weights(
    task: Task, trained: tuple[Path, Any], tmp_path: Path
) -> None:
    tmp, network = trained
    stored = json.loads((tmp / "cli" / "config.json").read_text())
    assert stored["task"] == "cartpole" and stored["task_fingerprint"] == task.fingerprint()
    assert network.task_name == "cartpole"
    config = _config(task, tmp)
    out = tmp_path / "interrupted"
    # The validation set is cached by the run above (same task, key and cache); 2 pretraining solves, round 1 (2
    # solves), then one solve into round 2.
    solver = _Interrupt(task, after=5)
    with pytest.raises(KeyboardInterrupt):
        train(config, out, batch_solver=solver, solver_name=solver_key(SOLVER, task))
    resumed = train(config, out, resume=True)  # the real solver, the same key: the stored records are reused
    np.testing.assert_array_equal(resumed.network.casadi_parameters(), network.casadi_parameters())
    # A task with the same name and other content is refused by its fingerprint.
    heavier = _example().make_cartpole(dataclasses.replace(small_params(), pole_mass=0.2))
    with pytest.raises(ValueError, match="fingerprint"):
        train(_config(heavier, tmp), out, resume=True)


# --------------------------------------------------------------------------------------------- MPC and evaluation
def test_the_learned_mpc_runs_in_closed_loop(task: Task, trained: tuple[Path, Any]) -> None:
    _, network = trained
    policy = LimitedLookaheadMPC(task, network, task.profile.default_horizon(task), MPCOptions(jit=False))
    env = make_env(task)
    obs, _ = env.reset(options={"state": np.zeros(4)})
    done, steps = False, 0
    while not done:
        action, _ = policy.predict(obs, deterministic=True)
        assert action.shape == (1,) and abs(float(action[0])) <= 10.0
        obs, _, terminated, truncated, _ = env.step(action)
        done, steps = terminated or truncated, steps + 1
    assert steps == len(policy.stats) == 10 and all(
        np.isfinite(s.objective) or s.source != "solver" for s in policy.stats
    )


def test_evaluation_sends_the_task_to_two_workers_and_the_cli_loads_it(
    task: Task, trained: tuple[Path, Any], tmp_path: Path
) -> None:
    """``seagul evaluate --task file.py:factory --workers 2`` (the Task object goes to the two worker processes) gives
    the episodes of the in-process evaluation with one worker."""
    tmp, _ = trained
    network = str(tmp / "cli" / "network.pt")
    # The specs the command builds from its arguments below, so both runs evaluate the same policies.
    mpc = PolicySpec("mpc", "learned", network, (("jit", False), ("trust_region", "lqr")))
    starts, _ = start_grid(task, 2)
    one = evaluate(task, [mpc, PolicySpec("lqr", "lqr")], starts, workers=1, progress=False)
    assert len(one) == 8
    out = tmp_path / "eval"
    argv = ["evaluate", "--task", f"{THIS}:make_small_cartpole", "--network", network, "--label", "learned"]
    assert main([*argv, "--lqr", "--no-jit", "--grid", "2", "--workers", "2", "--no-progress", "--out", str(out)]) == 0
    two = [EpisodeResult(**e) for e in json.loads((out / "results.json").read_text())["episodes"]]
    _same_results(one, two)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["task"] == "cartpole" and [p["policy"] for p in summary["policies"]] == ["learned", "lqr"]
    assert (out / "heatmap.png").is_file()


# ------------------------------------------------------------------------------------------------ bad --task
@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("no_such_module_xyz:make", "no module named 'no_such_module_xyz'"),
        ("json:no_such_factory", "module 'json' has no attribute 'no_such_factory'"),
        (f"{THIS}:not_a_task", "returned a int, not a seagul_envs Task"),
        (f"{THIS}:broken_factory", "raised RuntimeError: no model today"),
        (f"{THIS}:EXAMPLE", "not a factory"),
        ("/no/such/file.py:make", "no Python file"),
        ("pendulum", "unknown task 'pendulum'"),
        (":make", "write module:factory"),
    ],
)
def test_bad_task_specs_are_clear_errors(spec: str, message: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(ValueError) as info:
        load_task(spec)
    assert message in str(info.value)
    with pytest.raises(SystemExit) as exit_info:
        main(["evaluate", "--task", spec, "--lqr", "--out", "never"])
    assert exit_info.value.code == 2 and message in capsys.readouterr().err


# ------------------------------------------------------------------------------- a variant of a built-in task
def test_a_parameter_variant_of_the_acrobot_gets_its_own_validation_set(tmp_path: Path) -> None:
    default, variant = make_task("acrobot"), make_acrobot_task(AcrobotParams(m2=1.3))
    assert variant.name == default.name and solver_key(None, variant) != solver_key(None, default)
    toy = ToySolver(default)
    validation_dataset(default, toy, "toy", tmp_path)
    assert toy.num_solves == 200
    again = ToySolver(variant)
    records = validation_dataset(variant, again, "toy", tmp_path)  # same solver name: the fingerprint keeps them apart
    assert again.num_solves == 200 and len(records) == 200
    assert len(list(tmp_path.glob("validation-acrobot-*"))) == 2
    # Through train(): a TrainConfig holding the variant object validates on the variant's set.
    config = _config(variant, tmp_path, validate=True, solver_options=None, **{"runtime.cache_dir": str(tmp_path)})
    third = ToySolver(variant)
    train(config, tmp_path / "run", batch_solver=third, solver_name="toy")
    assert third.num_solves == 2 + 4  # pretraining and budget only: the variant's validation set was cached


# ------------------------------------------------------------------------------------------------ seagul reproduce
@pytest.mark.slow
def test_reproduce_runs_the_smoke_preset_on_the_custom_task(tmp_path: Path) -> None:
    """``seagul reproduce file.py:factory --preset smoke`` (the task's default presets) writes a report; a resume
    needs the same task again."""
    out = tmp_path / "run"
    spec = f"{THIS}:make_small_cartpole"
    argv = ["reproduce", spec, "--preset", "smoke", "--workers", "1", "--no-progress", "--out", str(out)]
    assert main(argv) == 0
    assert "cartpole" in (out / "report.md").read_text()
    stored = json.loads((out / "experiment.json").read_text())
    assert stored["config"]["task"] == "cartpole" and stored["task_fingerprint"] == make_small_cartpole().fingerprint()
    assert main(["reproduce", spec, "--resume", str(out), "--no-progress"]) == 0
    assert main(["reproduce", "acrobot", "--resume", str(out), "--no-progress"]) == 2  # another task
