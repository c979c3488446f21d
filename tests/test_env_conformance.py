"""Conformance battery of every registered seagul Gymnasium id (in the spirit of dm_control's ``suite_test.py``).

The ids are read from Gymnasium's registry (every id starting with ``Seagul``), so an env registered at import time
is covered without editing this file; ``REGISTERED_TASK`` adds an id made by ``register_task`` (a small pendulum
registered for the duration of each test), which covers the generic ``TaskEnv``. For each id:

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
import re
import warnings
from collections.abc import Iterator
from dataclasses import dataclass

import casadi as ca
import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import seagul_envs
from seagul_envs import Task, register_task, unregister_task

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
