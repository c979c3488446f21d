"""Bad input at every public entry point gets an error that NAMES the problem (and the accepted range, if any).

In one place: task and env names, env actions and reset options (hypothesis over shapes and
values), solver inputs ``TrajectoryOptimizer.solve`` / ``solve_many`` (hypothesis; every generated input is invalid
so no NLP is ever solved), MPC/LQR observations, ``tau``, horizons, budgets, network and dataset files, and the
CLI. Each check matches the message text, not only the exception type.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import seagul_envs
from seagul_control.lqr import LQRPolicy
from seagul_control.mpc import FullHorizonMPC, LimitedLookaheadMPC, MPCOptions
from seagul_envs import ENV_IDS, make_task
from seagul_learn.cli import main
from seagul_learn.dataset import Dataset, DatasetError
from seagul_learn.parallel import solve_many
from seagul_learn.training import TrainConfig
from seagul_learn.trajopt import GUESS_NAMES, TrajectoryOptimizer
from seagul_learn.value_network import ValueNetwork, ValueNetworkFileError

ALL_TASKS = r"\['acrobot', 'dmc_acrobot', 'dmc_cartpole', 'dmc_pendulum', 'glider'\]"
"""The message's list of every registered task (the built-ins, the suite's tasks included)."""

# Modest example counts: the whole file must stay well under 30 s on a loaded 2-core machine.
FEW = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
NON_FINITE = st.sampled_from([math.nan, math.inf, -math.inf])
FINITE = st.floats(allow_nan=False, allow_infinity=False, width=64)

_ENVS: dict[str, Any] = {}
_OPTIMIZERS: dict[str, Any] = {}


def _env(env_id: str, copy: int = 0) -> Any:
    """One unwrapped env per (id, copy), built once per process (hypothesis reuses it across examples)."""
    key = f"{env_id}#{copy}"
    if key not in _ENVS:
        # unwrapped: Gymnasium's passive checker would warn about a bad action before the env's own check
        _ENVS[key] = gym.make(env_id).unwrapped
    return _ENVS[key]


def _optimizer(task_name: str) -> Any:
    if task_name not in _OPTIMIZERS:
        _OPTIMIZERS[task_name] = TrajectoryOptimizer(task_name)
    return _OPTIMIZERS[task_name]


def _start(env: Any) -> np.ndarray:
    task = env.task
    return 0.5 * (task.x0_low + task.x0_high)


# ------------------------------------------------------------------------------------------ names of things
def test_unknown_task_name_lists_the_available_ones() -> None:
    for bad in ("acrobt", "", "Acrobot", 3):
        with pytest.raises(ValueError, match=r"unknown task .*; available tasks: " + ALL_TASKS):
            make_task(bad)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("env_id", "message"),
    [
        ("SeagulAcrobt-v0", r"`SeagulAcrobt` doesn't exist\. Did you mean: `SeagulAcrobot`"),
        ("seagul_envs:SeagulGlidr-v0", r"`SeagulGlidr` doesn't exist\. Did you mean: `SeagulGlider`"),
        ("SeagulAcrobot-v9", r"version `v9` .* doesn't exist\. It provides versioned environments: \[ `v0` \]"),
    ],
)
def test_misspelt_env_id_is_named_with_a_suggestion(env_id: str, message: str) -> None:
    assert seagul_envs.ENV_IDS  # registration happened on import
    with pytest.raises(gym.error.Error, match=message):
        gym.make(env_id)


# ------------------------------------------------------------------------------------------------- env actions
def _bad_action_shapes(nu: int) -> st.SearchStrategy[tuple[int, ...]]:
    valid = {(nu,)} | ({()} if nu == 1 else set())
    return hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=3).filter(lambda s: s not in valid)


@pytest.mark.parametrize("env_id", list(ENV_IDS))
@FEW
@given(data=st.data())
def test_env_action_of_wrong_shape_is_named_and_changes_nothing(env_id: str, data: st.DataObject) -> None:
    env = _env(env_id)
    nu = env.task.nu
    shape = data.draw(_bad_action_shapes(nu), label="shape")
    action = data.draw(hnp.arrays(np.float64, shape, elements=FINITE), label="action")
    env.reset(options={"state": _start(env)})
    before, ttg = env.state, env.time_to_go
    with pytest.raises(ValueError, match=rf"action must have shape \({nu},\) .*got shape {re.escape(str(shape))}"):
        env.step(action)
    np.testing.assert_array_equal(env.state, before)
    assert env.time_to_go == ttg


@pytest.mark.parametrize("env_id", list(ENV_IDS))
@FEW
@given(bad=NON_FINITE, scalar=st.booleans(), dtype=st.sampled_from([np.float32, np.float64]))
def test_env_action_with_nan_or_inf_is_named_and_changes_nothing(
    env_id: str, bad: float, scalar: bool, dtype: type
) -> None:
    env = _env(env_id)
    env.reset(options={"state": _start(env)})
    before, ttg = env.state, env.time_to_go
    action = np.array(bad, dtype=dtype) if scalar else np.full(env.task.nu, bad, dtype=dtype)
    with pytest.raises(ValueError, match=r"action contains NaN or inf"):
        env.step(action)
    np.testing.assert_array_equal(env.state, before)
    assert env.time_to_go == ttg


@pytest.mark.parametrize("env_id", list(ENV_IDS))
@FEW
@given(value=FINITE)
def test_any_finite_action_is_clipped_like_gymnasium(env_id: str, value: float) -> None:
    """The other side of the contract: finite actions of any size are accepted and act as their clipped value."""
    env, ref = _env(env_id), _env(env_id, copy=1)
    for e in (env, ref):
        e.reset(options={"state": _start(e)})
    obs, reward, *_ = env.step(np.full(env.task.nu, value))
    clipped = np.clip(np.full(env.task.nu, value), env.task.u_low, env.task.u_high)
    ref_obs, ref_reward, *_ = ref.step(clipped)
    np.testing.assert_array_equal(obs, ref_obs)
    assert reward == ref_reward and np.all(np.isfinite(obs))


# --------------------------------------------------------------------------------------------- reset options
@pytest.mark.parametrize("env_id", list(ENV_IDS))
@FEW
@given(data=st.data())
def test_reset_state_of_wrong_shape_or_non_finite_is_named(env_id: str, data: st.DataObject) -> None:
    env = _env(env_id)
    nx = env.task.nx
    env.reset(options={"state": _start(env)})
    before = env.state
    if data.draw(st.booleans(), label="wrong shape"):
        shape = data.draw(hnp.array_shapes(min_dims=0, max_dims=2, max_side=8).filter(lambda s: s != (nx,)))
        state = data.draw(hnp.arrays(np.float64, shape, elements=FINITE))
        message = rf"reset state must have shape \({nx},\) .*got shape {re.escape(str(shape))}"
    else:
        state = _start(env).copy()
        state[data.draw(st.integers(0, nx - 1), label="index")] = data.draw(NON_FINITE)
        message = "reset state contains NaN or inf"
    with pytest.raises(ValueError, match=message):
        env.reset(options={"state": state})
    np.testing.assert_array_equal(env.state, before)


@pytest.mark.parametrize("env_id", list(ENV_IDS))
def test_reset_time_to_go_and_keys_are_checked(env_id: str) -> None:
    env = _env(env_id)
    hi = env.task.tau_range[1]
    cases: list[tuple[dict[str, Any], str]] = [
        ({"time_to_go": math.nan}, "time to go must be finite, got nan"),
        ({"time_to_go": math.inf}, "time to go must be finite, got inf"),
        ({"time_to_go": -0.5}, rf"time to go -0\.5 outside \[0, {hi}\] s"),
        ({"time_to_go": 10 * hi}, rf"time to go {10 * hi} outside \[0, {hi}\] s"),
        ({"time_to_go": 0.0}, "time to go must be positive, got 0.0"),
        ({"time_to_go": "soon"}, "time to go must be a number, got 'soon'"),
        ({"stat": [0.0]}, r"unknown reset option\(s\) \['stat'\]; accepted: \['params', 'state', 'time_to_go'\]"),
        ({"params": {"mass": 1.0}}, r"unknown parameter\(s\) \['mass'\]; this task varies \["),
        ({"params": [1.0]}, r"parameters must have shape \("),
    ]
    for options, message in cases:
        with pytest.raises(ValueError, match=message):
            env.reset(options=options)
    far = _start(env) + 1e6
    if np.any(np.isfinite(env.task.x_high)):
        with pytest.raises(ValueError, match=r"outside the state bounds \[\["):
            env.reset(options={"state": far})


# ------------------------------------------------------------------------------------------- solver inputs
@FEW
@given(data=st.data())
def test_trajopt_solve_rejects_bad_x_init(data: st.DataObject) -> None:
    opt = _optimizer("acrobot")
    if data.draw(st.booleans(), label="wrong shape"):
        shape = data.draw(hnp.array_shapes(min_dims=0, max_dims=3, max_side=6).filter(lambda s: s != (4,)))
        x = data.draw(hnp.arrays(np.float64, shape, elements=FINITE))
        names = r"\['th1', 'th2', 'dth1', 'dth2'\]"
        message = rf"acrobot: x_init must have shape \(4,\) {names}, got shape {re.escape(str(shape))}"
    else:
        x = data.draw(
            hnp.arrays(np.float64, (4,), elements=st.one_of(FINITE, NON_FINITE)).filter(
                lambda a: not np.all(np.isfinite(a))
            )
        )
        message = r"acrobot: x_init contains NaN or inf"
    with pytest.raises(ValueError, match=message):
        opt.solve(x)


@FEW
@given(tau=st.one_of(FINITE.filter(lambda t: abs(t - 5.0) > 1e-6), NON_FINITE))
def test_trajopt_solve_rejects_tau_outside_T0(tau: float) -> None:
    opt = _optimizer("acrobot")
    x = make_task("acrobot").goal.copy()
    message = (
        r"acrobot: time to go must be finite"
        if not math.isfinite(tau)
        else r"acrobot: time to go .* outside the task's range T0 = \[5\.0, 5\.0\] s"
    )
    with pytest.raises(ValueError, match=message):
        opt.solve(x, tau)


def test_trajopt_options_are_checked() -> None:
    with pytest.raises(ValueError, match=r"horizon must be >= 1 interval, got 0"):
        TrajectoryOptimizer("acrobot", horizon=0)
    with pytest.raises(ValueError, match=r"max_iter must be >= 1"):
        TrajectoryOptimizer("acrobot", max_iter=0)
    with pytest.raises(ValueError, match=r"unknown solver 'snopt'; use 'ipopt' or 'fatrop'"):
        TrajectoryOptimizer("acrobot", solver="snopt")
    with pytest.raises(ValueError, match=rf"unknown guess 'lqr'; use one of {re.escape(str(GUESS_NAMES))}"):
        TrajectoryOptimizer("acrobot", guesses=("lqr",))
    with pytest.raises(ValueError, match=r"unknown TrajectoryOptimizer options \['tolerance'\]"):
        TrajectoryOptimizer("acrobot", tolerance=1e-3)
    with pytest.raises(ValueError, match=r"unknown task 'pendulum'; available tasks"):
        TrajectoryOptimizer("pendulum")


@FEW
@given(data=st.data())
def test_solve_many_rejects_bad_batches_before_solving(data: st.DataObject) -> None:
    kind = data.draw(st.sampled_from(["shape", "nan", "tau_count", "tau_range"]), label="kind")
    task_name = data.draw(st.sampled_from(["acrobot", "glider"]), label="task")
    task = make_task(task_name)
    nx, (lo, hi) = task.nx, task.tau_range
    n = data.draw(st.integers(1, 4), label="n")
    starts = np.tile(0.5 * (task.x0_low + task.x0_high), (n, 1))
    taus: np.ndarray | None = None
    if kind == "shape":
        shape = data.draw(
            hnp.array_shapes(min_dims=0, max_dims=3, max_side=5).filter(lambda s: not (len(s) == 2 and s[1] == nx))
        )
        starts = data.draw(hnp.arrays(np.float64, shape, elements=FINITE))
        message = rf"{task_name}: starts must have shape \(n, {nx}\), got {re.escape(str(shape))}"
    elif kind == "nan":
        row = data.draw(st.integers(0, n - 1))
        starts[row, data.draw(st.integers(0, nx - 1))] = data.draw(NON_FINITE)
        message = rf"{task_name}: starts contain NaN or inf \(rows \[{row}\]\)"
    elif kind == "tau_count":
        m = data.draw(st.integers(0, 6).filter(lambda k: k != n))
        taus = np.full(m, task.tau_nominal)
        message = rf"{task_name}: taus must have {n} entries, got {m}"
    else:
        taus = np.full(n, task.tau_nominal)
        taus[-1] = data.draw(st.one_of(FINITE.filter(lambda t: not lo - 1e-6 <= t <= hi + 1e-6), NON_FINITE))
        message = rf"{task_name}: time to go (must be finite|.* outside the task's range T0 = \[{lo}, {hi}\] s)"
    with pytest.raises(ValueError, match=message):
        solve_many(task_name, starts, taus, progress=False)


def test_solve_many_rejects_bad_workers_backend_and_options() -> None:
    starts = make_task("acrobot").goal[None]
    with pytest.raises(ValueError, match=r"workers must be >= 1, got 0"):
        solve_many("acrobot", starts, workers=0, progress=False)
    with pytest.raises(ValueError, match=r"unknown backend 'dask'; use 'local' or 'ray'"):
        solve_many("acrobot", starts, backend="dask", progress=False)
    with pytest.raises(ValueError, match=r"unknown solver 'knitro'"):
        solve_many("acrobot", starts, solver_options={"solver": "knitro"}, progress=False)
    with pytest.raises(ValueError, match=r"unknown task 'cartpole'; available tasks"):
        solve_many("cartpole", starts, progress=False)


# ------------------------------------------------------------------------------------ MPC and LQR observations
def _policies() -> list[Any]:
    task = make_task("acrobot")
    return [LQRPolicy(task), LimitedLookaheadMPC(task, None, 5, MPCOptions(jit=False))]


def test_policy_observations_are_checked() -> None:
    for policy in _policies():
        name = type(policy).__name__
        shape_msg = rf"{name}: observation must have shape \(5,\) or \(n_envs, 5\) = \[state \(4\), time to go\]"
        for obs in (np.zeros(4), np.zeros((2, 3)), np.zeros((1, 1, 5)), np.zeros(0)):
            with pytest.raises(ValueError, match=rf"{shape_msg}, got shape {re.escape(str(obs.shape))}"):
                policy.predict(obs)
        for bad in (math.nan, math.inf):
            obs = np.array([[np.pi, 0, 0, 0, 5.0], [np.pi, 0, bad, 0, 5.0]])
            with pytest.raises(ValueError, match=rf"{name}: observation contains NaN or inf \(rows \[1\]\)"):
                policy.predict(obs)
            with pytest.raises(ValueError, match=rf"{name}: observation contains NaN or inf \(rows \[0\]\)"):
                policy.predict(np.array([np.pi, 0, 0, 0, bad]))  # the time to go too


def test_mpc_horizon_must_be_at_least_one() -> None:
    task = make_task("acrobot")
    for horizon in (0, -3, 2.5):
        with pytest.raises(ValueError, match=rf"horizon must be an integer >= 1 step, got {horizon}"):
            LimitedLookaheadMPC(task, None, horizon, MPCOptions(jit=False))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"FullHorizonMPC: horizon must be >= 1, got 0"):
        FullHorizonMPC(task, horizon=0)


# ------------------------------------------------------------------------------------------ training config
@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("budget", 0, "budget must be >= 1, got 0"),
        ("budget", -5, "budget must be >= 1, got -5"),
        ("schedule.solves_per_round", 0, r"schedule\.solves_per_round must be >= 1, got 0"),
        ("schedule.pretrain_solves", 0, r"schedule\.pretrain_solves must be >= 1, got 0"),
        ("schedule.batch_size", 0, r"schedule\.batch_size must be >= 1, got 0"),
        ("runtime.workers", 0, r"runtime\.workers must be >= 1, got 0"),
        ("schedule.train_steps_per_round", -1, r"schedule\.train_steps_per_round must be >= 0, got -1"),
        ("schedule.newest_fraction", 1.5, r"schedule\.newest_fraction must be in \[0, 1\], got 1.5"),
        ("schedule.lr", math.nan, r"schedule\.lr must be a positive number, got nan"),
        ("loss.sobolev_weight", math.inf, r"loss\.sobolev_weight must be >= 0, got inf"),
        ("sampler.max_steps", 0, r"sampler: max_steps must be >= 1, got 0"),
        ("network.hidden", (0,), r"network\.hidden must be positive layer widths, got \(0,\)"),
        ("task", "pendulum", r"unknown task 'pendulum'; available tasks: " + ALL_TASKS),
    ],
)
def test_train_config_names_the_field_and_its_range(field: str, value: Any, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        TrainConfig(**{field: value})


# ------------------------------------------------------------------------------------------ files on disk
def _network_file(tmp_path: Path) -> Path:
    net = ValueNetwork(4, task_name="acrobot", seed=0)
    return net.save(tmp_path / "net.pt")


def test_network_files_missing_foreign_or_corrupt(tmp_path: Path) -> None:
    good = _network_file(tmp_path)
    assert ValueNetwork.load(good).task_name == "acrobot"  # the fixture itself is loadable
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(good.read_bytes()[:200])
    text = tmp_path / "notes.pt"
    text.write_text("not a network")
    empty = tmp_path / "empty.pt"
    empty.write_bytes(b"")
    foreign = tmp_path / "foreign.pt"
    torch.save({"model": torch.zeros(2)}, foreign)
    old = tmp_path / "old.pt"
    torch.save({"format": "seagul-value-network", "version": 0}, old)
    inconsistent = tmp_path / "inconsistent.pt"
    payload = torch.load(good, weights_only=True)
    payload["config"]["hidden"] = [7]  # weights of a 32-unit network under a 7-unit architecture
    torch.save(payload, inconsistent)
    cases = [
        (tmp_path / "missing.pt", r"missing\.pt' does not exist"),
        (truncated, r"truncated\.pt' is unreadable or corrupt"),
        (text, r"notes\.pt' is unreadable or corrupt"),
        (empty, r"empty\.pt' is unreadable or corrupt"),
        (foreign, r"foreign\.pt' is not a seagul value network file"),
        (old, r"old\.pt' has value-network format version 0; this seagul reads version 1"),
        (inconsistent, r"inconsistent\.pt' is inconsistent"),
        (tmp_path, r"is a directory, not a value network file"),
    ]
    for path, message in cases:
        with pytest.raises(ValueNetworkFileError, match=message):
            ValueNetwork.load(path)


def test_dataset_dirs_and_records_missing_foreign_or_corrupt(tmp_path: Path) -> None:
    (tmp_path / "foreign").mkdir()
    (tmp_path / "foreign" / "dataset.json").write_text('{"format": "something-else"}')
    (tmp_path / "broken").mkdir()
    (tmp_path / "broken" / "dataset.json").write_text("{truncated")
    (tmp_path / "future").mkdir()
    (tmp_path / "future" / "dataset.json").write_text('{"format": "seagul-dataset", "version": 7, "task": "acrobot"}')
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    cases: list[tuple[tuple[Any, ...], str]] = [
        ((tmp_path / "missing",), r"missing' is not a seagul dataset \(no dataset\.json\)"),
        ((tmp_path / "foreign",), r"foreign' is not a seagul dataset \(no 'seagul-dataset' tag"),
        ((tmp_path / "broken",), r"broken/dataset\.json' is unreadable or corrupt"),
        ((tmp_path / "future",), r"future' has dataset format version 7"),
        ((a_file, "acrobot"), r"a_file'.*not a directory"),
    ]
    for args, message in cases:
        with pytest.raises(DatasetError, match=message):
            Dataset.open(*args)

    ds = Dataset.open(tmp_path / "d", "acrobot")
    with pytest.raises(DatasetError, match=r"holds task 'acrobot', not 'glider'"):
        Dataset.open(tmp_path / "d", "glider")
    with pytest.raises(DatasetError, match=r"record 3 does not exist in"):
        ds.read(3)
    ds.record_path(1).write_bytes(b"PK\x03\x04 half a zip")  # a torn record under a final name
    np.savez(ds.record_path(2), x_init=np.zeros(4))  # an npz from someone else: keys missing
    for index in (1, 2):
        with pytest.raises(DatasetError, match=rf"record file '.*solve-00000{index}\.npz' is corrupt"):
            ds.read(index)


# ------------------------------------------------------------------------------------------------------- CLI
def _cli_error(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """Run the CLI expecting an argument error: exit status 2 and the message on stderr."""
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    return capsys.readouterr().err


def _one_line(text: str) -> str:
    """An error message as one line: the frame and wrapping of tyro's error box removed."""
    return " ".join(text.replace("\u2502", " ").split())


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (
            ["--task", "nope"],
            "argument --task: unknown task 'nope'; available tasks: "
            "acrobot, dmc_acrobot, dmc_cartpole, dmc_pendulum, glider",
        ),
        (["--budget", "0"], "budget must be >= 1, got 0"),
        (["--budget", "1.5"], "Error parsing --budget: invalid literal for int() with base 10: '1.5'"),
        (["--runtime.workers", "0"], "runtime.workers must be >= 1, got 0"),
        (["--schedule.solves-per-round", "-2"], "schedule.solves_per_round must be >= 1, got -2"),
        (["--schedule.pretrain-solves", "0"], "schedule.pretrain_solves must be >= 1, got 0"),
        (["--schedule.train-steps-per-round", "-1"], "schedule.train_steps_per_round must be >= 0, got -1"),
        (["--schedule.lr", "0"], "schedule.lr must be a positive number, got 0.0"),
        (["--schedule.lr", "nan"], "schedule.lr must be a positive number, got nan"),
        (["--schedule.newest-fraction", "2"], "schedule.newest_fraction must be in [0, 1], got 2.0"),
        (["--solver-options", "{bad"], "argument --solver-options: not valid JSON"),
        # a flat flag of earlier versions: read as its nested spelling, with a note, and checked the same way
        (["--solves-per-round", "-2"], "--solves-per-round -2 -> --schedule.solves-per-round -2"),
        (["--solves-per-round", "-2"], "schedule.solves_per_round must be >= 1, got -2"),
    ],
)
def test_cli_train_arguments(extra: list[str], message: str, capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["train", "--task", "acrobot", "--out", "unused", *extra]
    assert message in _one_line(_cli_error(argv, capsys))


def test_cli_missing_required_arguments(capsys: pytest.CaptureFixture[str]) -> None:
    assert "the following arguments are required: --out" in _cli_error(["train", "--task", "acrobot"], capsys)
    assert "the following arguments are required: --task" in _cli_error(["train", "--out", "x"], capsys)
    err = _cli_error(["generate", "--task", "glider", "--num", "0"], capsys)
    assert "argument --num: must be >= 1, got 0" in err


def test_cli_errors_raised_by_the_command_are_named_without_traceback(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Errors found after parsing (paths, files) exit 2 with ``seagul <cmd>: error: ...``, not a traceback."""
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    assert main(["train", "--task", "acrobot", "--out", str(a_file), "--no-progress"]) == 2
    assert re.search(r"seagul train: error: .*a_file'.*not a directory", capsys.readouterr().err)
    assert main(["generate", "--task", "acrobot", "--num", "2", "--out", str(a_file), "--no-progress"]) == 2
    assert re.search(r"seagul generate: error: .*a_file'.*not a directory", capsys.readouterr().err)
    assert main(["generate", "--task", "acrobot", "--num", "2", "--no-progress"]) == 2
    assert "seagul generate: error: --out is required with --num" in capsys.readouterr().err
