"""The Gymnasium envs: API conformance, determinism, pickling, vector envs, rewards, rendering, input validation."""

from __future__ import annotations

import ast
import dataclasses
import pickle
import re
import warnings
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import seagul_envs
from seagul_envs import ENV_IDS, registration
from seagul_envs.envs import task_env
from seagul_envs.envs.acrobot import AcrobotEnv
from seagul_envs.envs.task_env import TaskEnv
from seagul_envs.registration import env_class_for
from seagul_envs.tasks import AcrobotParams, make_acrobot_task

IDS = list(ENV_IDS)

# Gymnasium recommends normalised [-1, 1] action boxes; docs/reference/spec.md §7.2 asks for physical units (N m,
# rad/s), so this
# one recommendation is expected and every other warning fails the test.
_ACTION_SCALE_RECOMMENDATION = re.compile(r"we recommend using a symmetric and normalized space")


def _make(env_id: str, **kwargs: Any) -> gym.Env:
    return gym.make(env_id, **kwargs)


def _actions(env: gym.Env | gym.vector.VectorEnv, n: int, seed: int) -> list[np.ndarray]:
    """Random actions, about a third of them outside the box (exercising the clipping)."""
    rng = np.random.default_rng(seed)
    high = getattr(env, "single_action_space", env.action_space).high
    return [(rng.uniform(-1.5, 1.5, size=high.shape) * high).astype(np.float32) for _ in range(n)]


def _rollout(env: gym.Env, actions: list[np.ndarray]) -> list[tuple[np.ndarray, float, bool, bool, np.ndarray]]:
    out = []
    for a in actions:
        obs, reward, terminated, truncated, info = env.step(a)
        out.append((obs, reward, terminated, truncated, info["state"]))
        if terminated or truncated:
            break
    return out


@pytest.mark.parametrize("env_id", IDS)
def test_check_env_has_no_unexpected_warnings(env_id: str) -> None:
    env = _make(env_id)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)  # unwrapped: the checker warns about wrappers; spec is kept, so all modes are made
    unexpected = [str(w.message) for w in caught if not _ACTION_SCALE_RECOMMENDATION.search(str(w.message))]
    assert unexpected == []
    env.close()


@pytest.mark.parametrize("env_id", IDS)
def test_spaces_reset_and_info(env_id: str) -> None:
    env = _make(env_id)
    task = env.unwrapped.task
    obs, info = env.reset(seed=3)
    assert obs.dtype == np.float32 and obs.shape == (task.nx + 1,)
    assert env.observation_space.contains(obs)
    assert info["state"].dtype == np.float64 and info["state"].shape == (task.nx,)
    assert task.in_x0(info["state"])
    assert info["time_to_go"] == task.tau_nominal == pytest.approx(float(obs[-1]))
    np.testing.assert_array_equal(obs[:-1], info["state"].astype(np.float32))
    assert env.unwrapped.dt == task.control_period
    np.testing.assert_array_equal(env.action_space.high, task.u_high.astype(np.float32))
    # The info's state is a copy: mutating it must not move the env.
    info["state"][:] = 123.0
    assert not np.any(env.unwrapped.state == 123.0)


@pytest.mark.parametrize("env_id", IDS)
def test_seeded_determinism(env_id: str) -> None:
    a, b = _make(env_id), _make(env_id)
    obs_a, _ = a.reset(seed=7)
    obs_b, _ = b.reset(seed=7)
    np.testing.assert_array_equal(obs_a, obs_b)
    actions = _actions(a, 60, seed=1)
    ra, rb = _rollout(a, actions), _rollout(b, actions)
    assert len(ra) == len(rb) > 1
    for (oa, wa, ta, ua, sa), (ob, wb, tb, ub, sb) in zip(ra, rb, strict=True):
        np.testing.assert_array_equal(oa, ob)
        np.testing.assert_array_equal(sa, sb)
        assert (wa, ta, ua) == (wb, tb, ub)
    obs_c, _ = a.reset(seed=8)
    assert not np.array_equal(obs_a, obs_c)


@pytest.mark.parametrize("env_id", IDS)
def test_pickle_round_trip_continues_identically(env_id: str) -> None:
    env = _make(env_id)
    env.reset(seed=11)
    actions = _actions(env, 40, seed=2)
    for a in actions[:5]:
        env.step(a)
    clone = pickle.loads(pickle.dumps(env))
    rest = actions[5:]
    original, copied = _rollout(env, rest), _rollout(clone, rest)
    assert len(original) == len(copied) > 1
    for (o1, r1, t1, u1, s1), (o2, r2, t2, u2, s2) in zip(original, copied, strict=True):
        np.testing.assert_array_equal(o1, o2)
        np.testing.assert_array_equal(s1, s2)
        assert (r1, t1, u1) == (r2, t2, u2)
    # The clone has its own RNG state: the next seedless reset matches too.
    np.testing.assert_array_equal(env.reset()[0], clone.reset()[0])


@pytest.mark.parametrize("env_id", IDS)
def test_make_vec_sync_and_async_agree(env_id: str) -> None:
    results = {}
    for mode in ("sync", "async"):
        venv = gym.make_vec(f"seagul_envs:{env_id}", num_envs=2, vectorization_mode=mode)
        try:
            obs, info = venv.reset(seed=[1, 2])
            assert obs.shape == (2, venv.single_observation_space.shape[0]) and obs.dtype == np.float32
            assert info["state"].shape == (2, venv.unwrapped.single_observation_space.shape[0] - 1)
            trace = [obs]
            for a in _actions(venv, 6, seed=3):
                obs, reward, terminated, truncated, info = venv.step(np.stack([a, -a]))
                trace += [obs, reward, terminated, truncated, info["state"]]
            results[mode] = trace
        finally:
            venv.close()
    for s, a in zip(results["sync"], results["async"], strict=True):
        np.testing.assert_array_equal(s, a)


def _cost_weights(task: seagul_envs.Task) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """Running/terminal weights written from docs/reference/spec.md §3.4/§4.4 (not read from the Task's CasADi
    functions)."""
    if task.name == "acrobot":
        # Qf is the task's DARE solution (its own test checks it is the Riccati fixed point).
        return np.diag([1.0, 1.0, 0.1, 0.1]), np.array([np.pi, 0, 0, 0]), 0.01, task.extras["Qf"]
    return np.zeros((7, 7)), np.array([0, 0, np.pi / 4, 0, 0, 0, 0]), 100.0, np.diag([10.0, 10, 1, 10, 1, 1, 1])


@pytest.mark.parametrize("env_id", IDS)
@pytest.mark.parametrize("tau_steps", [None, 2.5])
def test_episode_return_is_minus_trajectory_cost(env_id: str, tau_steps: float | None) -> None:
    """Return = -(sum_k h_k l(x_k, u_k) + l_f(x_end)), with the last step shortened when tau is not a multiple of dt."""
    env = _make(env_id)
    task, dt = env.unwrapped.task, env.unwrapped.dt
    options = None if tau_steps is None else {"time_to_go": tau_steps * dt}
    _, info = env.reset(seed=5, options=options)
    tau = info["time_to_go"]
    Q, goal, R, Qf = _cost_weights(task)
    states, ttgs, inputs, total = [info["state"]], [tau], [], 0.0
    actions = _actions(env, 200, seed=4)
    for a in actions:
        obs, reward, terminated, truncated, info = env.step(a)
        if task.name == "glider":
            # The applied elevator rate, recovered from the state (dphi = u exactly): it may be below the clipped
            # action when the elevator reaches its stop.
            u_applied = (info["state"][3] - states[-1][3]) / (ttgs[-1] - info["time_to_go"])
            assert abs(u_applied) <= task.u_high[0] + 1e-9
            inputs.append(np.array([u_applied]))
        else:
            inputs.append(np.clip(a.astype(np.float64), task.u_low, task.u_high))
        states.append(info["state"])
        ttgs.append(info["time_to_go"])
        total += reward
        assert obs[-1] == np.float32(info["time_to_go"])
        if terminated or truncated:
            break
    assert terminated or truncated
    n = len(inputs)
    if truncated:
        assert n == int(np.ceil(tau / dt - 1e-9)) and ttgs[-1] == 0.0
    h = -np.diff(ttgs)  # step lengths from the time to go
    expected_h = np.full(n, dt)
    if truncated and tau_steps is not None:
        expected_h[-1] = dt / 2
    np.testing.assert_allclose(h, expected_h[:n], rtol=0, atol=1e-12)
    cost = 0.0
    for k in range(n):
        e = states[k] - goal
        cost += h[k] * (e @ Q @ e + R * float(inputs[k][0]) ** 2)
    e = states[-1] - goal
    cost += e @ Qf @ e
    assert total == pytest.approx(-cost, rel=1e-12, abs=1e-12)


@pytest.mark.parametrize("env_id", IDS)
def test_dt_override_and_exact_step_count(env_id: str) -> None:
    # max_episode_steps=-1: no TimeLimit (the registered one counts default control periods); the env alone ends it.
    env = _make(env_id, dt=0.005, max_episode_steps=-1)
    assert env.unwrapped.dt == 0.005
    _, info = env.reset(seed=0)
    n = round(info["time_to_go"] / 0.005)
    zero = np.zeros(env.action_space.shape, np.float32)
    for k in range(1, n + 1):
        _, _, terminated, truncated, info = env.step(zero)
        if terminated:
            break
        # No float accumulation: the episode ends on exactly the n-th step.
        assert truncated == (k == n)
    with pytest.raises(ValueError, match="dt must be a positive"):
        _make(env_id, dt=-0.1)


@pytest.mark.parametrize(("name", "u"), [("acrobot", 0.0), ("glider", -1.0)])  # the glider flies 0.85 s at -1 rad/s
def test_make_env_fits_the_time_limit_to_dt(name: str, u: float) -> None:
    """``make_env`` counts the ``TimeLimit`` in the env's own control periods; ``gym.make`` keeps the registered one
    (default periods), and a caller's ``max_episode_steps`` wins."""
    task = seagul_envs.make_task(name)
    env_id = str(task.profile.env_id)
    registered = gym.spec(env_id).max_episode_steps
    assert registered == int(np.ceil(task.tau_range[1] / task.control_period - 1e-9))
    assert seagul_envs.make_env(task).spec.max_episode_steps == registered  # exactly gym.make(env_id)
    dt = task.control_period / 4
    env = seagul_envs.make_env(task, dt=dt)
    assert env.spec.max_episode_steps == 4 * registered and _make(env_id, dt=dt).spec.max_episode_steps == registered
    assert seagul_envs.make_env(task, dt=dt, max_episode_steps=7).spec.max_episode_steps == 7
    # The longest episode at the finer period runs to its end: truncated by the env and the TimeLimit together.
    env.reset(seed=0, options={"state": task.x0_low, "time_to_go": task.tau_range[1]})
    action = np.full(env.action_space.shape, u, np.float32)
    for k in range(1, 4 * registered + 1):
        _, _, terminated, truncated, info = env.step(action)
        assert not terminated and truncated == (k == 4 * registered)
    assert info["time_to_go"] == 0.0


@pytest.mark.parametrize("env_id", IDS)
@pytest.mark.parametrize(
    ("action", "message"),
    [
        (np.array([np.nan], np.float32), "NaN or inf"),
        (np.array([np.inf], np.float32), "NaN or inf"),
        (np.zeros(2, np.float32), r"shape \(1,\)"),
        (np.zeros((1, 1), np.float32), r"shape \(1,\)"),
    ],
)
def test_bad_action_raises_and_leaves_state(env_id: str, action: np.ndarray, message: str) -> None:
    env, ref = _make(env_id).unwrapped, _make(env_id).unwrapped  # unwrapped: the passive checker would warn first
    env.reset(seed=9)
    ref.reset(seed=9)
    good = np.array([0.5], np.float32)
    env.step(good)
    ref.step(good)
    before = env.state
    with pytest.raises(ValueError, match=message):
        env.step(action)
    np.testing.assert_array_equal(env.state, before)
    assert env.time_to_go == ref.time_to_go
    np.testing.assert_array_equal(env.step(good)[0], ref.step(good)[0])


@pytest.mark.parametrize("env_id", IDS)
def test_actions_are_clipped(env_id: str) -> None:
    env, ref = _make(env_id).unwrapped, _make(env_id).unwrapped
    env.reset(seed=1)
    ref.reset(seed=1)
    high = env.action_space.high
    out = env.step(10 * high)
    inside = ref.step(high)
    np.testing.assert_array_equal(out[0], inside[0])
    assert out[1] == inside[1]
    assert env.step(np.float64(-1e6))[0] is not None  # a scalar action is accepted for a 1-D input


@pytest.mark.parametrize("env_id", IDS)
@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"state": [0.0, 1.0]}, "reset state must have shape"),
        ({"state": "nan-state"}, "could not convert|must have shape"),
        ({"time_to_go": -0.1}, "outside"),
        ({"time_to_go": 0.0}, "must be positive"),
        ({"time_to_go": float("nan")}, "finite"),
        ({"time_to_go": 99.0}, "outside"),
        ({"x0": [0.0]}, "unknown reset option"),
        ({"state": {"th1": 0.0}}, "must be"),
    ],
)
def test_bad_reset_options(env_id: str, options: dict, message: str) -> None:
    env = _make(env_id).unwrapped
    env.reset(seed=2)
    before, ttg = env.state, env.time_to_go
    with pytest.raises(ValueError, match=message):
        env.reset(options=options)
    np.testing.assert_array_equal(env.state, before)
    assert env.time_to_go == ttg


@pytest.mark.parametrize("env_id", IDS)
def test_reset_state_option_and_nan_state(env_id: str) -> None:
    env = _make(env_id)
    task = env.unwrapped.task
    x0 = 0.5 * (task.x0_low + task.x0_high)
    obs, info = env.reset(options={"state": x0, "time_to_go": 0.5 * task.tau_nominal})
    np.testing.assert_array_equal(info["state"], x0)
    assert obs[-1] == np.float32(0.5 * task.tau_nominal)
    assert info["time_to_go"] == 0.5 * task.tau_nominal
    bad = x0.copy()
    bad[1] = np.nan
    with pytest.raises(ValueError, match="NaN or inf"):
        env.reset(options={"state": bad})


def test_glider_crash_terminates_with_terminal_cost() -> None:
    env = _make("SeagulGlider-v0")
    task = env.unwrapped.task
    x0 = np.array([0.9, 0.0, 0.0, 0.0, 7.0, 0.0, 0.0])  # 0.1 m before the x bound at 7 m/s
    env.reset(options={"state": x0})
    _, reward, terminated, truncated, info = env.step(np.zeros(1, np.float32))
    assert terminated and not truncated and info["state"][0] > task.x_high[0]
    assert reward == pytest.approx(-task.terminal_cost_value(info["state"]), rel=1e-12)
    with pytest.raises(ValueError, match="outside the state bounds"):
        env.reset(options={"state": x0 + np.array([0.2, 0, 0, 0, 0, 0, 0])})


def test_glider_elevator_stop_clips_the_rate() -> None:
    env = _make("SeagulGlider-v0")
    task, dt = env.unwrapped.task, env.unwrapped.dt
    _, info = env.reset(seed=0)
    phis, rewards = [info["state"][3]], []
    for _ in range(4):  # 4 x 25 ms at 13 rad/s would take phi to 1.3 rad, past its 0.4463 rad stop
        _, reward, terminated, truncated, info = env.step(np.array([13.0], np.float32))
        assert not (terminated or truncated)
        phis.append(info["state"][3])
        rewards.append(reward)
    assert phis[-1] == pytest.approx(task.x_high[3], abs=1e-12) and phis[-2] == pytest.approx(task.x_high[3], abs=1e-12)
    applied = np.diff(phis) / dt
    np.testing.assert_allclose(applied[0], 13.0, rtol=1e-12)
    assert 0 < applied[1] < 13.0 and applied[-1] == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(rewards, -dt * 100.0 * applied**2, rtol=1e-9, atol=1e-12)  # charges the applied rate


def test_acrobot_never_terminates_before_time_runs_out() -> None:
    env = _make("SeagulAcrobot-v0")
    env.reset(seed=0, options={"state": [0.0, 0.0, 40.0, -40.0]})  # violent start: still only truncation
    flags = [env.step(np.array([20.0], np.float32))[2:4] for _ in range(50)]
    assert [t for t, _ in flags] == [False] * 50 and [u for _, u in flags] == [False] * 49 + [True]


@pytest.mark.parametrize("env_id", IDS)
def test_step_after_episode_end_warns_and_freezes(env_id: str) -> None:
    env = _make(env_id).unwrapped
    env.reset(seed=0, options={"time_to_go": env.dt})
    obs, _, _, truncated, _ = env.step(np.zeros(1, np.float32))
    assert truncated
    with pytest.warns(UserWarning, match="already returned terminated = True"):
        again = env.step(np.ones(1, np.float32))
    np.testing.assert_array_equal(again[0], obs)
    assert again[1] == 0.0 and again[3] is True


@pytest.mark.parametrize("env_id", IDS)
def test_render_rgb_array(env_id: str) -> None:
    env = _make(env_id, render_mode="rgb_array")
    env.reset(seed=0, options={"state": env.unwrapped.task.x0_low})
    frame = env.render()
    assert isinstance(frame, np.ndarray) and frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    assert frame.min() < 100 < frame.max()  # something is drawn on the white background
    for _ in range(3):
        assert not any(env.step(0.3 * env.action_space.high)[2:4])
    assert not np.array_equal(frame, env.render())  # the picture follows the state
    env.close()


def test_human_mode_without_display_does_not_crash(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    env = _make("SeagulAcrobot-v0", render_mode="human")
    env.reset(seed=0)
    assert env.render() is None
    env.step(np.zeros(1, np.float32))
    env.close()


def test_registration_is_idempotent() -> None:
    before = {k: gym.spec(k).entry_point for k in ENV_IDS}
    seagul_envs.register_envs()
    assert {k: gym.spec(k).entry_point for k in ENV_IDS} == before


@pytest.mark.parametrize("env_id", IDS)
def test_time_to_go_from_a_float32_observation_is_accepted(env_id: str) -> None:
    env = _make(env_id)
    hi = env.unwrapped.task.tau_range[1]
    _, info = env.reset(seed=0, options={"time_to_go": np.float32(hi)})  # e.g. an observation's last entry
    assert info["time_to_go"] == hi


def test_custom_task_must_match_the_env() -> None:
    with pytest.raises(ValueError, match="AcrobotEnv simulates AcrobotParams systems; task 'glider'"):
        AcrobotEnv(task=seagul_envs.make_task("glider"))


def test_a_renamed_variant_of_a_builtin_system_gets_its_env_by_parameter_class() -> None:
    """The built-in env is chosen by the task's ``profile.env_id`` and parameter class, never by its name."""
    heavy = dataclasses.replace(make_acrobot_task(AcrobotParams(m2=1.5)), name="acrobot_heavy")
    assert env_class_for(heavy) is AcrobotEnv
    env = seagul_envs.make_env(heavy)
    assert isinstance(env.unwrapped, AcrobotEnv) and env.unwrapped.task is heavy
    env.reset(seed=0)
    # Without the env id the same task is simulated by the generic env.
    plain = dataclasses.replace(heavy, profile=dataclasses.replace(heavy.profile, env_id=None))
    assert env_class_for(plain) is TaskEnv


@pytest.mark.parametrize("env_id", IDS)
def test_step_before_reset_raises(env_id: str) -> None:
    with pytest.raises(gym.error.ResetNeeded):
        _make(env_id).unwrapped.step(np.zeros(1, np.float32))


# ------------------------------------------------------------------------------------------------ the one registry
def test_one_registry_module_and_no_env_module_imports_it() -> None:
    """``seagul_envs.registration`` holds the ids, ``register_task`` and the task -> env lookup (``make_env``,
    ``env_class_for``); the env modules never import it, so there is no import cycle to break with a local import."""
    assert seagul_envs.make_env is registration.make_env and seagul_envs.register_task is registration.register_task
    envs_dir = Path(seagul_envs.__file__).parent / "envs"
    for path in sorted(envs_dir.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            if isinstance(node, ast.ImportFrom):
                names = [node.module or ""]
            assert not any(n.startswith("seagul_envs.registration") for n in names), path.name
    # What make_env gives, through either name: a registered task's env is gym.make of its id.
    env = registration.make_env("acrobot")
    assert env.spec is not None and env.spec.id == "SeagulAcrobot-v0"
    env.close()


@pytest.mark.parametrize("name", ["make_env", "env_class_for"])
def test_the_moved_task_env_names_still_work_with_a_warning(name: str) -> None:
    with pytest.warns(DeprecationWarning, match=rf"seagul_envs\.envs\.task_env\.{name} is deprecated"):
        old = getattr(task_env, name)
    assert old is getattr(registration, name)
    with pytest.raises(AttributeError, match="no attribute 'not_a_name'"):
        task_env.not_a_name  # noqa: B018
