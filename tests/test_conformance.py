"""Conformance battery: every registered task and env id, and custom tasks, through one set of checks.

After dm_control's ``suite_test.py``: the checks are written once and parametrised over the registries, so a task
added with ``register_task`` or to ``seagul_envs.tasks`` is covered without editing this file, and a check added
here runs on every task. Two parametrisations:

**Tasks** (``TASKS``): every name of ``available_tasks()``, plus two tasks defined the way a user defines one
(docs/tutorials/custom-system.md): the free-time pendulum below and the cart-pole of ``examples/custom_system.py``,
loaded from the file and shrunk to a 1 s problem (``test_custom_system.make_small_cartpole``). For each task:

* ``validate_task`` accepts it; its goal, start box X0, time range and sampled starts are consistent, the dynamics
  are finite at a start and the terminal cost is 0 at the goal;
* ``pickle`` and ``cloudpickle`` copies (what workers and Ray actors receive) have the same fields, functions,
  simulator and fingerprint;
* the CasADi derivatives of the dynamics ``f(x, u)``, the stage cost ``l(x, u)`` and the terminal cost ``l_f(x)``
  (what the NLP solvers and the value labels ``grad_x`` are built on) equal central finite differences at starts
  drawn from X0 and inputs drawn from the input box;
* ``make_env(task)`` passes Gymnasium's env checker, with observations ``[x, time to go]`` of shape ``(nx + 1,)``;
* the MPC protocol of SB3 predictors, ``predict(obs, state=None, episode_start=None, deterministic=True) ->
  (actions, state)``, on one observation and on a batch, for the limited-lookahead MPC (interpreted, 3 steps, the
  task's terminal cost) and the LQR reference: action shapes, bounds, the state passed through, and the same
  action again after ``episode_start``;
* ``solve_many`` gives bit-identical results with 1 and 2 local workers, in input order (interpreted solvers, times
  to go at both ends of T0), equal to a ``TrajectoryOptimizer``'s own solve, and on Ray (marked ``ray``) the same
  as locally.

**Env ids** (``IDS``): every id of Gymnasium's registry starting with ``Seagul``, so an env registered at import
time is covered, plus ``REGISTERED_TASK``, an id made by ``register_task`` (the pendulum, registered for the
duration of each test), which covers the generic ``TaskEnv``. For each id:

* ``gymnasium.utils.env_checker.check_env`` passes on the unwrapped env;
* ``spec.max_episode_steps`` is the task's longest admissible episode, ``ceil(max T0 / control_period)``, and
  ``gym.make`` wraps the env in a ``TimeLimit`` of that many steps;
* an episode ends by truncation exactly at ``max_episode_steps`` (time to go 0) unless it terminated earlier, and
  a nominal episode ends by the env's own truncation, never cut short by the ``TimeLimit``;
* ``reset(seed=...)`` is deterministic: same seed, same observation and same trajectory under the same actions;
* observations stay inside ``observation_space`` and rewards are finite over whole episodes;
* the env class's docstring has the sections of Gymnasium's env documentation, and each value it names after a
  field of the task's parameter dataclass (``u_max = 20.0``) is that field's value.
"""

from __future__ import annotations

import ast
import dataclasses
import math
import pickle
import re
import sys
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import casadi as ca
import cloudpickle
import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from result_checks import assert_same_results

import seagul_envs
from seagul_control.lqr import LQRPolicy
from seagul_control.mpc import LimitedLookaheadMPC, MPCOptions
from seagul_envs import Task, available_tasks, make_env, make_task, register_task, unregister_task, validate_task
from seagul_learn.parallel import solve_many
from seagul_learn.trajopt import TrajectoryOptimizer

REGISTERED_TASK = "<register_task>"
"""Stands for the id that ``register_task`` gives the pendulum below (registered only while a test uses it)."""

SEAGUL_IDS = sorted(env_id for env_id in gym.registry if env_id.startswith("Seagul"))
IDS = [*SEAGUL_IDS, REGISTERED_TASK]

SECTIONS = (
    "Description",
    "Action Space",
    "Observation Space",
    "Rewards",
    "Starting State",
    "Episode End",
    "Arguments",
    "Version History",
    "References",
)
"""The sections of a Gymnasium env's documentation, as bold headings on lines of their own, in this order."""

# Gymnasium recommends normalised [-1, 1] action boxes; the seagul envs keep physical units (docs/reference/spec.md
# §7.2), so this one recommendation is expected and any other warning of the checker fails the test.
_ACTION_SCALE_RECOMMENDATION = re.compile(r"we recommend using a symmetric and normalized space")


# ------------------------------------------------------------------------------------------- the registered task
@dataclass(frozen=True)
class _PendulumParams:
    u_max: float = 2.0
    dth_max: float = 8.0  # a path bound on the speed, so the env can terminate
    tau_min: float = 1.0
    tau_nominal: float = 1.5
    tau_max: float = 2.05  # not a multiple of the control period: the longest episode ends on a shortened step
    control_period: float = 0.1


def _make_pendulum_task() -> Task:
    p = _PendulumParams()
    x, u = ca.SX.sym("x", 2), ca.SX.sym("u", 1)
    xdot = ca.vertcat(x[1], u[0] - 0.1 * x[1] - 9.81 * ca.sin(x[0]))
    goal = np.array([np.pi, 0.0])
    err = x - goal
    return Task(
        name="conformance_pendulum",
        state_names=("th", "dth"),
        control_names=("torque",),
        dynamics=ca.Function("conformance_pendulum_f", [x, u], [xdot], ["x", "u"], ["xdot"]),
        stage_cost=ca.Function(
            "conformance_pendulum_l", [x, u], [ca.sumsqr(err) + 0.01 * u[0] ** 2], ["x", "u"], ["l"]
        ),
        terminal_cost=ca.Function("conformance_pendulum_lf", [x], [10 * ca.sumsqr(err)], ["x"], ["lf"]),
        goal=goal,
        u_low=np.array([-p.u_max]),
        u_high=np.array([p.u_max]),
        x_low=np.array([-np.inf, -p.dth_max]),
        x_high=np.array([np.inf, p.dth_max]),
        x_final_low=np.full(2, -np.inf),
        x_final_high=np.full(2, np.inf),
        x0_low=np.array([-0.2, -0.5]),
        x0_high=np.array([0.2, 0.5]),
        tau_range=(p.tau_min, p.tau_max),
        tau_nominal=p.tau_nominal,
        num_steps=20,
        step_bounds=(0.04, 0.12),
        fixed_step=False,
        rk4_substeps=2,
        control_period=p.control_period,
        params=p,
    )


@pytest.fixture(params=IDS)
def env_id(request: pytest.FixtureRequest) -> Iterator[str]:
    if request.param != REGISTERED_TASK:
        yield request.param
        return
    registered = register_task("conformance_pendulum", _make_pendulum_task)
    try:
        yield registered
    finally:
        unregister_task("conformance_pendulum")


# ------------------------------------------------------------------------------------------------------- helpers
def _task(env: gym.Env) -> Task:
    return env.unwrapped.task  # type: ignore[attr-defined]


def _steps(tau: float, dt: float) -> int:
    """Control steps of an episode of time to go ``tau`` (docs/reference/spec.md §7.4), written out here."""
    return max(1, math.ceil(tau / dt - 1e-9))


def _random_actions(env: gym.Env, n: int, seed: int) -> list[np.ndarray]:
    """Uniform in 1.5 times the action box: about a third of the entries outside it (exercising the clipping)."""
    rng = np.random.default_rng(seed)
    space = env.action_space
    assert isinstance(space, gym.spaces.Box)
    return [(rng.uniform(-1.5, 1.5, size=space.shape) * space.high).astype(np.float32) for _ in range(n)]


@dataclass
class _Episode:
    observations: list[np.ndarray]
    rewards: list[float]
    states: list[np.ndarray]
    time_to_go: list[float]
    terminated: bool
    truncated: bool
    flags_before_end: list[tuple[bool, bool]]

    @property
    def steps(self) -> int:
        return len(self.rewards)


def _run(env: gym.Env, actions: list[np.ndarray], **reset: object) -> _Episode:
    """Reset with ``reset`` and step through ``actions`` until the episode ends (an error if it does not)."""
    obs, info = env.reset(**reset)  # type: ignore[arg-type]
    episode = _Episode([obs], [], [info["state"]], [info["time_to_go"]], False, False, [])
    for action in actions:
        obs, reward, terminated, truncated, info = env.step(action)
        episode.observations.append(obs)
        episode.rewards.append(reward)  # type: ignore[arg-type]
        episode.states.append(info["state"])
        episode.time_to_go.append(info["time_to_go"])
        if terminated or truncated:
            episode.terminated, episode.truncated = bool(terminated), bool(truncated)
            return episode
        episode.flags_before_end.append((bool(terminated), bool(truncated)))
    raise AssertionError(f"no end after {len(actions)} steps")


def _assert_ends_at_its_time(episode: _Episode, tau: float, dt: float, limit: int) -> None:
    """Ended by truncation on the step where the time to go reaches 0 (that step count, ``<= limit``), or by a
    termination before; never two ends, never an end before either."""
    expected = _steps(tau, dt)
    assert expected <= limit, f"an episode of {tau} s has {expected} steps, more than max_episode_steps = {limit}"
    assert episode.flags_before_end == [(False, False)] * (episode.steps - 1)
    if episode.terminated:
        assert not episode.truncated and episode.steps <= expected
    else:
        assert episode.truncated, "the episode ended neither by termination nor by truncation"
        assert episode.steps == expected, f"truncated after {episode.steps} steps, the time to go ends at {expected}"
        assert episode.time_to_go[-1] == 0.0 and episode.observations[-1][-1] == 0.0


def _time_limit(env: gym.Env) -> gym.wrappers.TimeLimit | None:
    while isinstance(env, gym.Wrapper):
        if isinstance(env, gym.wrappers.TimeLimit):
            return env
        env = env.env
    return None


# --------------------------------------------------------------------------------------------------------- tests
def test_every_builtin_id_is_covered() -> None:
    assert set(seagul_envs.ENV_IDS) <= set(SEAGUL_IDS)


def test_check_env_passes_on_the_unwrapped_env(env_id: str) -> None:
    env = gym.make(env_id)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)  # unwrapped: the checker warns about wrappers
    unexpected = [str(w.message) for w in caught if not _ACTION_SCALE_RECOMMENDATION.search(str(w.message))]
    assert unexpected == []
    env.close()


def test_spec_max_episode_steps_is_the_longest_episode_of_the_task(env_id: str) -> None:
    spec = gym.spec(env_id)
    env = gym.make(env_id)
    task = _task(env)
    assert env.unwrapped.dt == task.control_period  # type: ignore[attr-defined]
    longest = _steps(task.tau_range[1], task.control_period)
    assert spec.max_episode_steps == longest
    assert longest >= _steps(task.tau_nominal, task.control_period)
    # Success is a rule on the final state, not a return level: no threshold is registered.
    assert spec.reward_threshold is None
    limit = _time_limit(env)
    assert limit is not None and limit._max_episode_steps == longest
    assert env.spec is not None and env.spec.max_episode_steps == longest
    env.close()


def test_a_random_episode_ends_by_truncation_at_max_episode_steps_unless_terminated(env_id: str) -> None:
    env = gym.make(env_id)
    task, limit = _task(env), gym.spec(env_id).max_episode_steps
    assert limit is not None
    tau = float(task.tau_range[1])
    for seed in range(3):
        episode = _run(env, _random_actions(env, limit + 5, seed), seed=seed, options={"time_to_go": tau})
        _assert_ends_at_its_time(episode, tau, task.control_period, limit)
    env.close()


def test_the_time_limit_and_the_env_end_an_episode_on_the_same_step(env_id: str) -> None:
    """An episode of the longest time to go that does not terminate is truncated by both on step
    ``max_episode_steps``; a nominal one ends by the env's own truncation, not cut short. Constant actions from X0's
    corners and centre are tried until one flies to the end (random inputs crash the glider)."""
    env = gym.make(env_id)
    task, limit = _task(env), gym.spec(env_id).max_episode_steps
    assert limit is not None
    high = np.asarray(env.action_space.high, dtype=np.float64)
    fractions = sorted(np.linspace(-1.0, 1.0, 27), key=abs)  # zero first
    starts = (0.5 * (task.x0_low + task.x0_high), task.x0_low, task.x0_high)
    reached = []
    for x0 in starts:
        for fraction in fractions:
            actions = [(fraction * high).astype(np.float32)] * (limit + 5)
            for tau in (float(task.tau_range[1]), float(task.tau_nominal)):
                episode = _run(env, actions, options={"state": x0, "time_to_go": tau})
                _assert_ends_at_its_time(episode, tau, task.control_period, limit)
                if episode.truncated:
                    reached.append((tau, episode.steps))
            if len(reached) >= 2:
                break
        if len(reached) >= 2:
            break
    assert (float(task.tau_range[1]), limit) in reached, f"no constant action reached the end of a {env_id} episode"
    env.close()


def test_reset_with_a_seed_is_deterministic(env_id: str) -> None:
    a, b = gym.make(env_id), gym.make(env_id)
    actions = _random_actions(a, 400, seed=11)
    first = _run(a, actions, seed=5)
    second = _run(b, actions, seed=5)
    again = _run(a, actions, seed=5)  # the same env reseeded after an episode
    for other in (second, again):
        assert other.steps == first.steps > 1
        assert (other.terminated, other.truncated) == (first.terminated, first.truncated)
        for x, y in zip(first.observations, other.observations, strict=True):
            np.testing.assert_array_equal(x, y)
        for x, y in zip(first.states, other.states, strict=True):
            np.testing.assert_array_equal(x, y)
        assert other.rewards == first.rewards
    assert not np.array_equal(a.reset(seed=6)[0], first.observations[0])  # another seed, another start
    a.close()
    b.close()


def test_observations_stay_in_the_observation_space_and_rewards_are_finite(env_id: str) -> None:
    env = gym.make(env_id)
    task, limit = _task(env), gym.spec(env_id).max_episode_steps
    assert limit is not None
    for seed, options in ((0, None), (1, {"time_to_go": float(task.tau_range[1])}), (2, {"state": task.x0_high})):
        episode = _run(env, _random_actions(env, limit + 5, seed + 100), seed=seed, options=options)
        for obs in episode.observations:
            assert obs.dtype == np.float32 and env.observation_space.contains(obs), obs
        for reward in episode.rewards:
            assert isinstance(reward, float) and math.isfinite(reward)
        assert all(np.isfinite(x).all() for x in episode.states)
    env.close()


def test_the_env_class_docstring_has_the_gymnasium_sections(env_id: str) -> None:
    env = gym.make(env_id)
    cls = type(env.unwrapped)
    env.close()
    doc = cls.__doc__ or ""
    headings = re.findall(r"^\s*\*\*([A-Z][A-Za-z ]+)\*\*\s*$", doc, flags=re.MULTILINE)
    assert tuple(headings) == SECTIONS, f"{cls.__name__}'s docstring has the sections {headings}"
    bodies = re.split(r"^\s*\*\*[A-Z][A-Za-z ]+\*\*\s*$", doc, flags=re.MULTILINE)[1:]
    for name, body in zip(SECTIONS, bodies, strict=True):
        assert body.strip(), f"{cls.__name__}: the section {name} is empty"
    history, references = bodies[-2], bodies[-1]
    assert re.search(r"\bv0\b", history)
    assert "2107.08893" in references  # the SEAGuL paper
    assert not re.search(r"\bsessions?\b|\bissue \d", doc, flags=re.IGNORECASE)
    # Any episode length the docstring states is the registered one.
    stated = {int(n) for n in re.findall(r"max_episode_steps = (\d+)", doc)}
    assert stated <= {gym.spec(env_id).max_episode_steps}


def _named_values(doc: str) -> list[tuple[str, object]]:
    """``(name, value)`` of every code span ``name = value`` (or ``a = b = value``) with a Python literal value."""
    named = []
    for span in re.findall(r"``([^`]+)``", doc):
        *names, literal = (part.strip() for part in span.split(" = "))
        try:
            value = ast.literal_eval(literal)
        except (ValueError, SyntaxError):
            continue
        named += [(name, value) for name in names if name.isidentifier() or name == "Task.max_sim_substep"]
    return named


def test_the_values_a_docstring_names_are_the_code_s(env_id: str) -> None:
    env = gym.make(env_id)
    task = _task(env)
    doc = type(env.unwrapped).__doc__ or ""
    env.close()
    fields = {f.name for f in dataclasses.fields(task.params)} if dataclasses.is_dataclass(task.params) else set()
    checked = []
    for name, value in _named_values(doc):
        if name == "Task.max_sim_substep":
            actual: object = task.max_sim_substep
        elif name == "max_episode_steps":
            actual = gym.spec(env_id).max_episode_steps
        elif name in fields:
            actual = getattr(task.params, name)
        else:
            continue
        assert np.array_equal(np.asarray(actual, dtype=float), np.asarray(value, dtype=float)), (name, value, actual)
        checked.append(name)
    if env_id in seagul_envs.ENV_IDS:  # the built-ins name their parameters
        assert len(checked) >= 10, checked


# ================================================================================================ the task battery
def _builtin(name: str) -> Callable[[], Task]:
    return lambda: make_task(name)


def _small_cartpole() -> Task:
    from test_custom_system import make_small_cartpole  # the tutorial's task, loaded from examples/ as --task does

    return make_small_cartpole()


TASKS: dict[str, Callable[[], Task]] = {
    **{name: _builtin(name) for name in available_tasks()},
    "custom-pendulum": _make_pendulum_task,
    "custom-cartpole": _small_cartpole,
}
"""Every registered task by its name, and the two custom ones (by a label that no registered name can take)."""

SOLVER: dict[str, Any] = {"codegen": False, "plan": ("ipopt:line",), "multi_start": "never", "max_solve_time": None}
"""One interpreted IPOPT attempt per solve: the battery compiles nothing (the compiled libraries and the tasks'
solve plans have tests of their own), and the contract checked here, the same result whatever the workers, holds
for any solver. No wall-time limit: with one, a loaded machine stopped a glider solve on a Ray actor (IPOPT's
``max_wall_time``) that succeeded in this process, and the results differed by the machine's load."""


@pytest.fixture(params=list(TASKS))
def task(request: pytest.FixtureRequest) -> Task:
    return TASKS[request.param]()


def test_every_registered_task_is_in_the_battery() -> None:
    assert set(available_tasks()) <= set(TASKS)
    assert not set(TASKS) - set(available_tasks()) & set(available_tasks())


def test_the_task_is_valid_and_its_sets_are_consistent(task: Task) -> None:
    assert validate_task(task) is task
    if task.name in available_tasks():
        assert make_task(task.name) is make_task(task.name)  # the registry builds a task once
    assert task.goal.shape == (task.nx,)
    assert task.x0_low.shape == task.x0_high.shape == (task.nx,)
    assert np.all(task.x0_low <= task.x0_high)
    lo, hi = task.tau_range
    assert 0 < lo <= task.tau_nominal <= hi
    x = task.sample_x0(np.random.default_rng(0))
    assert task.in_x0(x)
    xdot = np.asarray(task.dynamics(x, np.zeros(task.nu))).ravel()
    assert xdot.shape == (task.nx,) and np.all(np.isfinite(xdot))
    assert task.terminal_cost_value(task.goal) == pytest.approx(0.0)


@pytest.mark.parametrize("dumps", [pickle.dumps, cloudpickle.dumps], ids=["pickle", "cloudpickle"])
def test_the_task_pickles_to_an_equivalent_task(task: Task, dumps: Callable[[Any], bytes]) -> None:
    """What the local workers and the Ray actors receive: the same fields, functions and fingerprint."""
    copy = pickle.loads(dumps(task))
    assert isinstance(copy, Task) and copy is not task
    assert (copy.name, copy.state_names, copy.control_names, copy.params) == (
        task.name,
        task.state_names,
        task.control_names,
        task.params,
    )
    for f in dataclasses.fields(Task):
        value = getattr(task, f.name)
        if isinstance(value, np.ndarray):
            np.testing.assert_array_equal(getattr(copy, f.name), value)
    rng = np.random.default_rng(8)
    x = rng.uniform(task.x0_low, task.x0_high)
    u = rng.uniform(task.u_low, task.u_high)
    np.testing.assert_array_equal(np.asarray(copy.dynamics(x, u)), np.asarray(task.dynamics(x, u)))
    assert copy.stage_cost_value(x, u) == task.stage_cost_value(x, u)
    assert copy.terminal_cost_value(x) == task.terminal_cost_value(x)
    dt = task.control_period
    np.testing.assert_array_equal(np.asarray(copy.simulator(dt)(x, u)), np.asarray(task.simulator(dt)(x, u)))
    assert validate_task(copy) is copy
    assert copy.fingerprint() == task.fingerprint()


def _points(task: Task, n: int, seed: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """``n`` pairs (start in X0, input in the input box)."""
    rng = np.random.default_rng(seed)
    xs = task.sample_x0(rng, n)
    us = rng.uniform(task.u_low, task.u_high, size=(n, task.nu))
    return list(zip(xs, us, strict=True))


def _central_difference(fun: Callable[[np.ndarray], np.ndarray], z: np.ndarray) -> np.ndarray:
    """Jacobian of ``fun`` at ``z`` by central differences, step ``1e-6 max(1, |z_i|)`` (error O(h^2) ~ 1e-12
    relative, rounding ~1e-10 relative: far below the tolerance of the comparison)."""
    columns = []
    for i in range(z.size):
        h = 1e-6 * max(1.0, abs(float(z[i])))
        dz = np.zeros_like(z)
        dz[i] = h
        columns.append((fun(z + dz) - fun(z - dz)) / (2 * h))
    return np.stack(columns, axis=-1)


def _assert_jacobian(name: str, exact: np.ndarray, fd: np.ndarray) -> None:
    scale = 1.0 + float(np.abs(exact).max())
    np.testing.assert_allclose(exact, fd, rtol=1e-5, atol=1e-6 * scale, err_msg=name)


def test_dynamics_and_cost_derivatives_match_central_differences(task: Task) -> None:
    """The solvers and the value labels use CasADi's derivatives of the task's functions; they must be the
    derivatives of the functions the env simulates (a kink, a branch or a stale hand-written Jacobian shows here)."""
    x, u = ca.SX.sym("x", task.nx), ca.SX.sym("u", task.nu)
    f, l, lf = task.dynamics(x, u), task.stage_cost(x, u), task.terminal_cost(x)
    exact = ca.Function(
        "derivatives",
        [x, u],
        [ca.jacobian(f, x), ca.jacobian(f, u), ca.gradient(l, x), ca.gradient(l, u), ca.gradient(lf, x)],
    )

    for x0, u0 in _points(task, 4, seed=21):
        fx, fu, lx, lu, lfx = (np.asarray(m, dtype=float) for m in exact(x0, u0))
        assert np.all(np.isfinite(fx)) and np.all(np.isfinite(fu))
        fd = _finite_differences(task, x0, u0)
        _assert_jacobian("df/dx", fx, fd["df/dx"])
        _assert_jacobian("df/du", fu, fd["df/du"])
        _assert_jacobian("dl/dx", lx.ravel(), fd["dl/dx"].ravel())
        _assert_jacobian("dl/du", lu.ravel(), fd["dl/du"].ravel())
        _assert_jacobian("dlf/dx", lfx.ravel(), fd["dlf/dx"].ravel())


def _finite_differences(task: Task, x0: np.ndarray, u0: np.ndarray) -> dict[str, np.ndarray]:
    """The same five derivatives as central differences of the numeric functions at ``(x0, u0)``."""

    def num(fun: ca.Function, *args: np.ndarray) -> np.ndarray:
        return np.asarray(fun(*args), dtype=float).ravel()

    return {
        "df/dx": _central_difference(lambda z: num(task.dynamics, z, u0), x0),
        "df/du": _central_difference(lambda z: num(task.dynamics, x0, z), u0),
        "dl/dx": _central_difference(lambda z: num(task.stage_cost, z, u0), x0),
        "dl/du": _central_difference(lambda z: num(task.stage_cost, x0, z), u0),
        "dlf/dx": _central_difference(lambda z: num(task.terminal_cost, z), x0),
    }


def test_the_comparison_catches_a_wrong_derivative() -> None:
    """Guard: a Jacobian off by 1e-4 relative in one entry fails the comparison above."""
    exact = np.array([[2.0, -1.0], [0.5, 3.0]])
    wrong = exact.copy()
    wrong[1, 0] *= 1 + 1e-4
    with pytest.raises(AssertionError, match="df/dx"):
        _assert_jacobian("df/dx", wrong, exact)


def test_make_env_passes_the_env_checker(task: Task) -> None:
    env = make_env(task)
    assert env.unwrapped.task is task  # type: ignore[attr-defined]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
    unexpected = [str(w.message) for w in caught if not _ACTION_SCALE_RECOMMENDATION.search(str(w.message))]
    assert unexpected == []
    assert env.observation_space.shape == (task.nx + 1,)
    obs, info = env.reset(options={"state": task.x0_low})
    assert obs.shape == (task.nx + 1,) and info["time_to_go"] == task.tau_nominal
    np.testing.assert_array_equal(info["state"], task.x0_low)
    env.close()


def _observations(task: Task, n: int) -> np.ndarray:
    """``n`` observations of the env after seeded resets (float32 ``[x, time to go]``, what a policy is given)."""
    env = make_env(task)
    obs = np.stack([env.reset(seed=seed)[0] for seed in range(n)])
    env.close()
    return obs


def _assert_predict_protocol(policy: Any, task: Task) -> None:
    observations = _observations(task, 2)
    state = object()  # a recurrent policy's state: passed through untouched
    action, out_state = policy.predict(observations[0], state=state, episode_start=np.array([True]))
    assert out_state is state
    assert isinstance(action, np.ndarray) and action.shape == (task.nu,) and np.all(np.isfinite(action))
    assert np.all(task.u_low <= action) and np.all(action <= task.u_high)

    actions, out_state = policy.predict(observations, episode_start=np.array([True, True]), deterministic=True)
    assert out_state is None and actions.shape == (2, task.nu) and np.all(np.isfinite(actions))
    assert np.all(task.u_low <= actions) and np.all(actions <= task.u_high)
    # A new episode from the same observation: the same action (no state kept across episode starts).
    np.testing.assert_array_equal(actions[0], action)
    again, _ = policy.predict(observations, episode_start=np.array([True, True]))
    np.testing.assert_array_equal(again, actions)
    # Continuing without episode starts (warm starts, where kept) still answers every env.
    cont, _ = policy.predict(observations, episode_start=np.array([False, False]))
    assert cont.shape == (2, task.nu) and np.all(np.isfinite(cont))


def test_the_lookahead_mpc_follows_the_predict_protocol(task: Task) -> None:
    mpc = LimitedLookaheadMPC(task, None, 3, MPCOptions(jit=False))
    _assert_predict_protocol(mpc, task)
    assert len(mpc.last_info) == 2


def test_the_lqr_reference_follows_the_predict_protocol(task: Task) -> None:
    _assert_predict_protocol(LQRPolicy(task), task)


NEAR_GOAL = frozenset(name for name in available_tasks() if make_task(name).extras.get("suite"))
"""Tasks whose solves from X0 are global swing-up searches (the DeepMind Control Suite's: minutes each, and the
weak motors' local optima): the battery checks determinism across workers and backends, not the search, so their
batch starts within 0.01 of the goal. Building their optimizer takes 5-20 s per process (5 RK4 substeps of MuJoCo's
own timestep in every interval), so their solve_many case is ``slow``: the contract is the library's, and the
default suite checks it on every other task (``test_solve_many_on_ray_equals_the_local_backend`` too)."""


def _batch(task: Task) -> tuple[np.ndarray, np.ndarray]:
    """Two starts in X0 with times to go at both ends of T0 (a free final time's range): one chunk per worker."""
    rng = np.random.default_rng(11)
    if task.name in NEAR_GOAL:
        starts = task.goal + rng.uniform(-0.01, 0.01, (2, task.nx))
    else:
        starts = task.sample_x0(rng, 2)
    return starts, np.array(task.tau_range, dtype=float)


@pytest.mark.parametrize(
    "label", [pytest.param(label, marks=pytest.mark.slow) if label in NEAR_GOAL else label for label in TASKS]
)
def test_solve_many_is_bit_identical_for_one_and_two_workers(label: str) -> None:
    task = TASKS[label]()
    starts, taus = _batch(task)
    serial = solve_many(task, starts, taus, workers=1, progress=False, solver_options=SOLVER)
    parallel = solve_many(task, starts, taus, workers=2, progress=False, solver_options=SOLVER)
    assert all(r.success for r in serial)  # compare real solutions, not only failures
    assert_same_results(serial, parallel)
    for r, x, t in zip(parallel, starts, taus, strict=True):  # input order is kept
        np.testing.assert_array_equal(r.x_init, x)
        assert r.tau == t
    # One optimizer of the user's own: the batch's first result, with finite value gradients.
    one = TrajectoryOptimizer(task, **SOLVER).solve(starts[0], taus[0])
    assert_same_results([one], serial[:1])
    assert not one.success or (np.isfinite(one.grad_x).all() and np.isfinite(one.grad_tau))


RAY_ELSEWHERE = frozenset({"acrobot", "glider"})
"""Built-in tasks whose Ray results are compared with the local backend's in ``tests/test_ray.py``
(``test_ray_backend_equals_local_backend``, five solves each with the tasks' own solver plans): here the custom
tasks, whose modules Ray must send by value."""


@pytest.mark.ray
def test_solve_many_on_ray_equals_the_local_backend() -> None:
    """Every task of the battery but ``NEAR_GOAL`` and ``RAY_ELSEWHERE`` in one private Ray session (starting Ray
    costs more than the solves)."""
    ray = pytest.importorskip("ray")
    import os

    from seagul_learn import parallel

    if ray.is_initialized():
        ray.shutdown()
    address = os.environ.pop("RAY_ADDRESS", None)
    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
    # The pendulum's parameter dataclass lives in this test module, which no Ray worker can import (a task loaded
    # with load_task from a file is sent by value by the library itself).
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    try:
        for label, factory in TASKS.items():
            if label in NEAR_GOAL:  # see NEAR_GOAL: the backends' contract does not depend on the task
                continue
            if label in RAY_ELSEWHERE:
                continue
            task = factory()
            starts, taus = _batch(task)
            local = solve_many(task, starts, taus, workers=1, progress=False, solver_options=SOLVER)
            remote = solve_many(task, starts, taus, workers=2, backend="ray", progress=False, solver_options=SOLVER)
            try:
                assert_same_results(local, remote)
            except AssertionError as err:
                raise AssertionError(f"{label}: {err}") from err
    finally:
        ray.cloudpickle.unregister_pickle_by_value(sys.modules[__name__])
        parallel.shutdown_ray_pool()
        ray.shutdown()
        if address is not None:
            os.environ["RAY_ADDRESS"] = address
