"""Custom tasks: make_env(task) for any Task, register_task(name, factory), and Task pickling.

The custom task is a torque-limited simple pendulum swing-up, built from CasADi functions the way the acrobot task is.
"""

from __future__ import annotations

import dataclasses
import pickle
import threading
import warnings
from dataclasses import dataclass

import casadi as ca
import cloudpickle
import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import seagul_envs
from seagul_envs import Task, TaskEnv, make_env, make_task, register_task, unregister_task
from seagul_envs.tasks.acrobot import make_acrobot_task


# ---------------------------------------------------------------------------------------------------- the custom task
@dataclass(frozen=True)
class PendulumParams:
    m: float = 1.0
    l: float = 1.0
    b: float = 0.1
    g: float = 9.81
    u_max: float = 1.0  # m g l = 9.81 N m: the swing-up needs pumping
    dth_max: float = 10.0  # path bound on the speed: leaving it ends the episode
    Q: tuple[float, float] = (1.0, 0.1)
    R: float = 0.01
    Qf: tuple[float, float] = (10.0, 1.0)
    tau: float = 3.0
    horizon_steps: int = 30
    rk4_substeps: int = 2
    control_period: float = 0.1


def make_pendulum_task(params: PendulumParams | None = None, name: str = "pendulum") -> Task:
    p = params or PendulumParams()
    x = ca.SX.sym("x", 2)
    u = ca.SX.sym("u", 1)
    ddth = (u[0] - p.b * x[1] - p.m * p.g * p.l * ca.sin(x[0])) / (p.m * p.l**2)
    dynamics = ca.Function("pendulum_f", [x, u], [ca.vertcat(x[1], ddth)], ["x", "u"], ["xdot"])
    goal = np.array([np.pi, 0.0])
    err = x - goal
    stage_cost = ca.Function(
        "pendulum_l", [x, u], [ca.bilin(np.diag(p.Q), err, err) + p.R * u[0] ** 2], ["x", "u"], ["l"]
    )
    terminal_cost = ca.Function("pendulum_lf", [x], [ca.bilin(np.diag(p.Qf), err, err)], ["x"], ["lf"])
    h = p.tau / p.horizon_steps
    return Task(
        name=name,
        state_names=("th", "dth"),
        control_names=("torque",),
        dynamics=dynamics,
        stage_cost=stage_cost,
        terminal_cost=terminal_cost,
        goal=goal,
        u_low=np.array([-p.u_max]),
        u_high=np.array([p.u_max]),
        x_low=np.array([-np.inf, -p.dth_max]),
        x_high=np.array([np.inf, p.dth_max]),
        x_final_low=np.full(2, -np.inf),
        x_final_high=np.full(2, np.inf),
        x0_low=np.array([-0.2, -0.5]),
        x0_high=np.array([0.2, 0.5]),
        tau_range=(p.tau, p.tau),
        tau_nominal=p.tau,
        num_steps=p.horizon_steps,
        step_bounds=(h, h),
        fixed_step=True,
        rk4_substeps=p.rk4_substeps,
        control_period=p.control_period,
        params=p,
    )


def make_heavy_pendulum_task() -> Task:
    return make_pendulum_task(PendulumParams(m=2.0))


def draw_pendulum(task: Task, x: np.ndarray, u: np.ndarray, time_to_go: float) -> np.ndarray:
    """A 32x32 frame: a dark dot where the bob is."""
    frame = np.full((32, 32, 3), 255, dtype=np.uint8)
    col = round(16 + 12 * float(np.sin(x[0])))
    row = round(16 + 12 * float(np.cos(x[0])))
    frame[max(row - 2, 0) : row + 3, max(col - 2, 0) : col + 3] = (40, 40, 40)
    return frame


class _Unpicklable:
    """A callable factory holding a lock: neither pickle nor cloudpickle can send it."""

    def __init__(self) -> None:
        self.lock = threading.Lock()

    def __call__(self) -> Task:
        return make_pendulum_task()


@pytest.fixture
def pendulum() -> Task:
    return make_pendulum_task()


@pytest.fixture
def registered():
    """``pendulum`` registered for the test, removed afterwards (xdist workers run other test files too)."""
    env_id = register_task("pendulum", make_pendulum_task)
    yield env_id
    unregister_task("pendulum")


def _checked(env: gym.Env) -> list[str]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
    return [str(w.message) for w in caught]


def _rollout(env: gym.Env, actions: list[np.ndarray]) -> list[tuple]:
    out = []
    for a in actions:
        obs, reward, terminated, truncated, info = env.step(a)
        out.append((obs, reward, terminated, truncated, info["state"], info["time_to_go"]))
        if terminated or truncated:
            break
    return out


def _assert_same(a: list[tuple], b: list[tuple]) -> None:
    assert len(a) == len(b) > 1
    for ra, rb in zip(a, b, strict=True):
        np.testing.assert_array_equal(ra[0], rb[0])
        np.testing.assert_array_equal(ra[4], rb[4])
        assert (ra[1], ra[2], ra[3], ra[5]) == (rb[1], rb[2], rb[3], rb[5])


def _actions(high: np.ndarray, n: int, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [(rng.uniform(-1.5, 1.5, size=high.shape) * high).astype(np.float32) for _ in range(n)]


# ---------------------------------------------------------------------------------------------------------- make_env
def test_make_env_is_check_env_clean_and_has_no_render_mode(pendulum: Task) -> None:
    env = make_env(pendulum)
    assert isinstance(env.unwrapped, TaskEnv) and env.unwrapped.task is pendulum
    assert env.spec is not None and env.spec.id == "SeagulPendulum-v0"
    assert _checked(env) == []
    assert env.unwrapped.metadata["render_modes"] == []
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="without specifying any render mode"):
        assert env.render() is None
    for mode in ("rgb_array", "human"):
        with pytest.raises(ValueError, match="needs a renderer"):
            make_env(pendulum, render_mode=mode)


def test_make_env_with_a_renderer(pendulum: Task, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)  # check_env also makes a "human" env: draw, show nothing
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    drawn = dataclasses.replace(pendulum, extras={"renderer": draw_pendulum})
    assert _checked(make_env(drawn)) == []
    env = make_env(drawn, render_mode="rgb_array")
    env.reset(seed=0, options={"state": [0.0, 0.0]})
    frame = env.render()
    assert frame.shape == (32, 32, 3) and frame.dtype == np.uint8
    env.reset(options={"state": [np.pi / 2, 0.0]})
    assert not np.array_equal(frame, env.render())
    # The renderer may also be given to make_env; a bad frame is a clear error.
    env = make_env(pendulum, render_mode="rgb_array", renderer=lambda *_: np.zeros((4, 4), np.uint8))
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"\(H, W, 3\) uint8"):
        env.render()


def test_spaces_and_reset_with_a_given_state(pendulum: Task) -> None:
    env = make_env(pendulum)
    assert env.observation_space.shape == (3,) and env.observation_space.dtype == np.float32
    np.testing.assert_array_equal(env.action_space.low, [-1.0])
    np.testing.assert_array_equal(env.action_space.high, [1.0])
    obs, info = env.reset(seed=1)
    assert pendulum.in_x0(info["state"]) and info["time_to_go"] == 3.0
    obs, info = env.reset(options={"state": [0.1, -0.2], "time_to_go": 1.25})
    np.testing.assert_array_equal(info["state"], [0.1, -0.2])
    np.testing.assert_array_equal(obs, np.array([0.1, -0.2, 1.25], np.float32))
    assert info["time_to_go"] == 1.25 and env.unwrapped.max_episode_steps == 13
    for options, message in (
        ({"state": [0.0, 11.0]}, "outside the state bounds"),
        ({"state": [0.0]}, "shape"),
        ({"time_to_go": 4.0}, "outside"),
        ({"speed": 1.0}, "unknown reset option"),
    ):
        with pytest.raises(ValueError, match=message):
            env.reset(options=options)


def test_steps_match_the_task_simulator(pendulum: Task) -> None:
    env = make_env(pendulum)
    _, info = env.reset(seed=2)
    sim = pendulum.simulator(env.unwrapped.dt)
    x = info["state"]
    for a in _actions(pendulum.u_high, 20, seed=3):
        u = np.clip(a.astype(np.float64), pendulum.u_low, pendulum.u_high)
        expected = np.asarray(sim(x, u)).ravel()
        obs, _, terminated, truncated, info = env.step(a)
        np.testing.assert_allclose(info["state"], expected, rtol=1e-13, atol=1e-13)
        np.testing.assert_array_equal(obs[:2], info["state"].astype(np.float32))
        assert not (terminated or truncated)
        x = info["state"]


@pytest.mark.parametrize("tau", [None, 1.25])
def test_return_is_minus_the_episode_cost(pendulum: Task, tau: float | None) -> None:
    env = make_env(pendulum)
    _, info = env.reset(seed=4, options=None if tau is None else {"time_to_go": tau})
    states, ttgs, inputs, total = [info["state"]], [info["time_to_go"]], [], 0.0
    for a in _actions(pendulum.u_high, 100, seed=5):
        _, reward, terminated, truncated, info = env.step(a)
        inputs.append(np.clip(a.astype(np.float64), pendulum.u_low, pendulum.u_high))
        states.append(info["state"])
        ttgs.append(info["time_to_go"])
        total += reward
        if terminated or truncated:
            break
    assert truncated and not terminated and ttgs[-1] == 0.0
    h = -np.diff(ttgs)
    expected_h = np.full(len(inputs), 0.1)
    if tau is not None:
        expected_h[-1] = 0.05
    np.testing.assert_allclose(h, expected_h, rtol=0, atol=1e-12)
    cost = sum(h[k] * pendulum.stage_cost_value(states[k], inputs[k]) for k in range(len(inputs)))
    cost += pendulum.terminal_cost_value(states[-1])
    assert total == pytest.approx(-cost, rel=1e-12, abs=1e-12)


def test_leaving_the_state_bounds_terminates_with_the_terminal_cost(pendulum: Task) -> None:
    env = make_env(pendulum)
    start = np.array([np.pi / 2, -9.9])  # horizontal, falling: gravity drives the speed past -10 rad/s
    env.reset(options={"state": start})
    _, reward, terminated, truncated, info = env.step(np.zeros(1, np.float32))
    assert terminated and not truncated and info["state"][1] < -10.0
    expected = -0.1 * pendulum.stage_cost_value(start, np.zeros(1)) - pendulum.terminal_cost_value(info["state"])
    assert reward == pytest.approx(expected, rel=1e-12)


def test_custom_env_pickles_and_continues_identically(pendulum: Task) -> None:
    env = make_env(pendulum)
    env.reset(seed=6)
    actions = _actions(pendulum.u_high, 30, seed=7)
    for a in actions[:5]:
        env.step(a)
    clones = [pickle.loads(dumps(env.unwrapped)) for dumps in (pickle.dumps, cloudpickle.dumps)]
    assert all(clone.task is not pendulum for clone in clones)  # a custom task travels by value
    original = _rollout(env, actions[5:])
    for clone in clones:
        _assert_same(original, _rollout(clone, actions[5:]))


def test_malformed_tasks_are_clear_errors(pendulum: Task) -> None:
    with pytest.raises(TypeError, match="needs a seagul_envs Task"):
        make_env(object())
    with pytest.raises(ValueError, match="unknown task"):
        make_env("no_such_task")
    with pytest.raises(ValueError, match=r"u_high must have shape \(1,\)"):
        make_env(dataclasses.replace(pendulum, u_high=np.array([1.0, 2.0])))
    with pytest.raises(ValueError, match="dynamics must map"):
        make_env(dataclasses.replace(pendulum, dynamics=pendulum.stage_cost))
    with pytest.raises(ValueError, match="X0"):
        make_env(dataclasses.replace(pendulum, x0_high=np.array([0.2, 11.0])))


def test_a_two_input_task_with_a_time_to_go_range() -> None:
    """A planar double integrator: two inputs, free final time (T0 = [1, 2] s), unbounded state."""
    x, u = ca.SX.sym("x", 4), ca.SX.sym("u", 2)
    inf = np.full(4, np.inf)
    task = Task(
        name="double_integrator",
        state_names=("px", "py", "vx", "vy"),
        control_names=("ax", "ay"),
        dynamics=ca.Function("di_f", [x, u], [ca.vertcat(x[2], x[3], u)]),
        stage_cost=ca.Function("di_l", [x, u], [ca.sumsqr(x) + ca.sumsqr(u)]),
        terminal_cost=ca.Function("di_lf", [x], [10 * ca.sumsqr(x)]),
        goal=np.zeros(4),
        u_low=-np.ones(2),
        u_high=np.ones(2),
        x_low=-inf,
        x_high=inf,
        x_final_low=-inf,
        x_final_high=inf,
        x0_low=-np.ones(4),
        x0_high=np.ones(4),
        tau_range=(1.0, 2.0),
        tau_nominal=1.5,
        num_steps=10,
        step_bounds=(0.1, 0.2),
        fixed_step=False,
        rk4_substeps=1,
        control_period=0.07,
    )
    env = make_env(task)
    assert env.spec.id == "SeagulDoubleIntegrator-v0" and env.action_space.shape == (2,)
    assert _checked(env) == []
    _, info = env.reset(seed=0)
    x0 = info["state"]
    assert info["time_to_go"] == 1.5 and env.unwrapped.max_episode_steps == 22  # ceil(1.5 / 0.07)
    _, reward, _, _, info = env.step(np.array([0.5, 2.0], np.float32))  # the second input is clipped to 1
    u = np.array([0.5, 1.0])
    np.testing.assert_allclose(info["state"], np.asarray(task.simulator(0.07)(x0, u)).ravel(), rtol=1e-13, atol=1e-13)
    assert reward == pytest.approx(-0.07 * task.stage_cost_value(x0, u), rel=1e-13)
    with pytest.raises(ValueError, match=r"action must have shape \(2,\)"):
        env.step(np.ones(1, np.float32))
    with pytest.raises(ValueError, match="single underscores"):
        make_env(dataclasses.replace(task, name="double integrator"))


# Pickling a Task (pickle and cloudpickle) to an equivalent task: the conformance battery's, on every task
# (tests/test_conformance.py).


# ------------------------------------------------------------------------------------------------------ register_task
def test_register_task_makes_make_task_and_gym_make_work(registered: str) -> None:
    assert registered == "SeagulPendulum-v0" == seagul_envs.task_env_id("pendulum")
    task = make_task("pendulum")
    assert task is make_task("pendulum") and task.name == "pendulum"
    assert "pendulum" in seagul_envs.available_tasks()
    env = gym.make(registered)
    assert isinstance(env.unwrapped, TaskEnv) and env.unwrapped.task is task
    assert _checked(env) == []
    # make_env of the shared task is gym.make of the id; of an equal fresh task, the same episode.
    assert make_env(task).spec.id == registered and make_env("pendulum").unwrapped.task is task
    actions = _actions(task.u_high, 40, seed=9)
    runs = []
    for e in (env, make_env(task), make_env(make_pendulum_task()), gym.make(registered, task=make_pendulum_task())):
        e.reset(seed=10)
        runs.append(_rollout(e, actions))
    for run in runs[1:]:
        _assert_same(runs[0], run)
    with pytest.raises(ValueError, match="needs a pendulum task"):
        gym.make(registered, task=make_pendulum_task(name="other"))


def test_registered_env_pickles_and_runs_in_spawned_vector_workers(registered: str) -> None:
    """A spawn worker never imported this module's register_task call: the id's entry point carries the factory."""
    actions = _actions(np.array([1.0]), 5, seed=11)
    traces = {}
    for mode, kwargs in (("sync", {}), ("async", {"context": "spawn"})):
        venv = gym.make_vec(registered, num_envs=2, vectorization_mode=mode, vector_kwargs=kwargs)
        try:
            obs, _ = venv.reset(seed=[1, 2])
            trace = [obs]
            for a in actions:
                obs, reward, terminated, truncated, _ = venv.step(np.stack([a, -a]))
                trace += [obs, reward, terminated, truncated]
            traces[mode] = trace
        finally:
            venv.close()
    for s, a in zip(traces["sync"], traces["async"], strict=True):
        np.testing.assert_array_equal(s, a)


def test_duplicate_registration(registered: str) -> None:
    first = make_task("pendulum")
    assert register_task("pendulum", make_pendulum_task) == registered  # the same factory again: a no-op
    assert make_task("pendulum") is first
    with pytest.raises(ValueError, match="already registered with a different factory"):
        register_task("pendulum", make_heavy_pendulum_task)
    with pytest.raises(ValueError, match="already registered with a different factory"):
        register_task("pendulum", lambda: make_pendulum_task())
    assert make_task("pendulum") is first  # a refused registration changes nothing
    assert register_task("pendulum", make_heavy_pendulum_task, overwrite=True) == registered
    heavy = make_task("pendulum")
    assert heavy.params.m == 2.0 and gym.make(registered).unwrapped.task is heavy


def test_register_task_errors() -> None:
    for name in ("Pendulum", "1pendulum", "pend__ulum", "pendulum_", "", "my pendulum", 3):
        with pytest.raises(ValueError, match="bad task name"):
            register_task(name, make_pendulum_task)
    for name in ("acrobot", "glider"):
        with pytest.raises(ValueError, match="built-in task"):
            register_task(name, make_acrobot_task, overwrite=True)
    with pytest.raises(ValueError, match="already registered"):  # its id would be the built-in SeagulAcrobotMujoco-v0
        register_task("acrobot_mujoco", lambda: make_pendulum_task(name="acrobot_mujoco"))
    with pytest.raises(TypeError, match="must return a seagul_envs Task"):
        register_task("not_a_task", lambda: 42)
    with pytest.raises(ValueError, match="returned a task named 'pendulum'"):
        register_task("wrong_name", make_pendulum_task)
    with pytest.raises(TypeError, match="not the Task itself"):
        register_task("pendulum", make_pendulum_task())
    with pytest.raises(TypeError, match="callable"):
        register_task("pendulum", "make_pendulum_task")
    with pytest.raises(TypeError, match="picklable"):
        register_task("pendulum", _Unpicklable())
    with pytest.raises(ValueError, match="not registered"):
        unregister_task("pendulum")
    with pytest.raises(ValueError, match="built-in"):
        unregister_task("acrobot")
    # None of the refused registrations left anything behind.
    assert seagul_envs.available_tasks() == ["acrobot", "dmc_acrobot", "dmc_cartpole", "dmc_pendulum", "glider"]
    assert not any(i in gym.registry for i in ("SeagulNotATask-v0", "SeagulWrongName-v0", "SeagulPendulum-v0"))


def test_unregister_task(registered: str) -> None:
    unregister_task("pendulum")
    assert "pendulum" not in seagul_envs.available_tasks() and registered not in gym.registry
    with pytest.raises(ValueError, match="unknown task"):
        make_task("pendulum")
    register_task("pendulum", make_pendulum_task)  # the fixture unregisters it again


# -------------------------------------------------------------------------------------------------- built-in tasks
@pytest.mark.parametrize(
    ("env_id", "task"),
    [
        ("SeagulAcrobot-v0", lambda: make_task("acrobot")),
        ("SeagulAcrobot-v0", make_acrobot_task),  # a fresh acrobot task: the same system, another object
        ("SeagulGlider-v0", lambda: make_task("glider")),
    ],
    ids=["acrobot-shared", "acrobot-fresh", "glider-shared"],
)
def test_builtin_task_through_make_env_equals_gym_make(env_id: str, task) -> None:
    task = task()
    ours, theirs = make_env(task), gym.make(env_id)
    assert type(ours.unwrapped) is type(theirs.unwrapped) and ours.spec.id == env_id
    assert ours.observation_space == theirs.observation_space and ours.action_space == theirs.action_space
    obs_a, _ = ours.reset(seed=12)
    obs_b, _ = theirs.reset(seed=12)
    np.testing.assert_array_equal(obs_a, obs_b)
    actions = _actions(task.u_high, 60, seed=13)
    _assert_same(_rollout(ours, actions), _rollout(theirs, actions))
