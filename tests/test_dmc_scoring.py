"""Scoring in the DeepMind Control Suite's own episodes (seagul_control.dmc) and the classical swing-ups
(seagul_control.spong): the runner's score is dm_control's return stepped by hand, ``hold`` holds, bad input is
refused, and the classical controllers beat doing nothing by margins measured on these seeds."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

pytest.importorskip("dm_control.suite", reason="dm_control is optional: pip install 'seagul[dmc]'")
pytest.importorskip("shimmy", reason="shimmy wraps dm_control for Gymnasium: pip install 'seagul[dmc]'")

from seagul_control import spong
from seagul_control.dmc import (
    ACTION_TOLERANCE,
    DMC_ENV_IDS,
    DMC_TASKS,
    EPISODE_STEPS,
    PredictController,
    dmc_env_id,
    make_dmc_env,
    physics_state,
    run_dmc_episode,
)


def _fixed_actions(seed: int, n: int = EPISODE_STEPS) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1.0, 1.0, size=(n, 1))


def _by_hand(env_id: str, seed: int, actions: np.ndarray) -> list[float]:
    """dm_control's rewards of ``actions`` from reset ``seed``, stepped through gym.make without the runner."""
    env = make_dmc_env(env_id)
    env.reset(seed=seed)
    rewards = []
    for a in actions:
        _, r, terminated, truncated, _ = env.step(a)
        rewards.append(float(r))
        if terminated or truncated:
            break
    env.close()
    return rewards


@pytest.mark.parametrize("env_id", ["cartpole-swingup", "acrobot-swingup"])
def test_score_is_dm_controls_return_stepped_by_hand(env_id: str) -> None:
    actions = _fixed_actions(7)
    episode = run_dmc_episode(env_id, lambda x, t: actions[round(t / 0.01)], seed=3, record=True)
    expected = _by_hand(env_id, 3, actions)
    assert len(expected) == EPISODE_STEPS == episode.steps
    assert list(episode.rewards) == expected
    assert episode.score == pytest.approx(math.fsum(expected), rel=1e-12)
    assert np.array_equal(np.array(episode.actions), actions)
    assert episode.states is not None and len(episode.states) == EPISODE_STEPS + 1
    assert episode.decisions == EPISODE_STEPS
    assert episode.score > 0.0


def test_hold_repeats_each_decision_for_hold_steps() -> None:
    actions = _fixed_actions(11)
    calls: list[float] = []

    def controller(x: np.ndarray, t: float) -> np.ndarray:
        calls.append(t)
        return actions[len(calls) - 1]

    episode = run_dmc_episode("cartpole-swingup", controller, seed=5, hold=3, record=True)
    assert episode.decisions == len(calls) == math.ceil(EPISODE_STEPS / 3)
    assert calls[:3] == pytest.approx([0.0, 0.03, 0.06])
    held = np.repeat(actions[: len(calls)], 3, axis=0)[:EPISODE_STEPS]
    assert np.array_equal(np.array(episode.actions), held)
    assert list(episode.rewards) == _by_hand("cartpole-swingup", 5, held)


def test_start_is_dm_controls_reset_distribution_and_seeded() -> None:
    starts = [run_dmc_episode("acrobot-swingup", lambda x, t: np.zeros(1), seed=s).start for s in (0, 1, 0)]
    assert starts[0] == starts[2] != starts[1]
    assert all(-np.pi <= q < np.pi for q in starts[1][:2]) and starts[1][2:] == (0.0, 0.0)
    env = make_dmc_env("dm_control/pendulum-swingup-v0")
    env.reset(seed=0)
    x = physics_state(env)
    physics = env.unwrapped._env.physics  # type: ignore[attr-defined]
    assert np.array_equal(x, [physics.named.data.qpos["hinge"][0], physics.named.data.qvel["hinge"][0]])
    env.close()


def test_bad_input_is_refused_with_the_reason() -> None:
    with pytest.raises(ValueError, match="unknown DeepMind Control Suite env 'walker-walk'"):
        run_dmc_episode("walker-walk", lambda x, t: np.zeros(1), seed=0)
    with pytest.raises(ValueError, match=r"beyond the upper bound 1\.0"):
        run_dmc_episode("acrobot-swingup", lambda x, t: np.array([1.5]), seed=0)
    with pytest.raises(ValueError, match=r"beyond the lower bound -1\.0"):
        run_dmc_episode("pendulum-swingup", lambda x, t: np.array([-1.0 - 10 * ACTION_TOLERANCE]), seed=0)
    with pytest.raises(ValueError, match="non-finite action"):
        run_dmc_episode("acrobot-swingup", lambda x, t: np.array([np.nan]), seed=0)
    with pytest.raises(ValueError, match="action space has 1 entries"):
        run_dmc_episode("acrobot-swingup", lambda x, t: np.zeros(2), seed=0)
    with pytest.raises(ValueError, match="hold must be a positive integer"):
        run_dmc_episode("acrobot-swingup", lambda x, t: np.zeros(1), seed=0, hold=0)
    with pytest.raises(TypeError, match="callable"):
        run_dmc_episode("acrobot-swingup", 3.0, seed=0)
    # Round-off past a bound is clipped onto it (a solver's saturated input), and scored as the bound.
    episode = run_dmc_episode("acrobot-swingup", lambda x, t: np.array([1.0 + 0.5 * ACTION_TOLERANCE]), 0, record=True)
    assert episode.actions is not None and {a[0] for a in episode.actions} == {1.0}
    assert dmc_env_id("acrobot-swingup") == "dm_control/acrobot-swingup-v0" in DMC_ENV_IDS


class _Predictor:
    """An SB3-protocol policy that records what it is given."""

    def __init__(self, tau_max: float) -> None:
        self.task = type("T", (), {"tau_range": (0.0, tau_max)})()
        self.seen: list[tuple[np.ndarray, bool]] = []

    def predict(self, obs, state=None, episode_start=None, deterministic=False):  # type: ignore[no-untyped-def]
        assert deterministic
        self.seen.append((np.array(obs), bool(episode_start[0])))
        return np.array([0.1], dtype=np.float32), None


def test_predict_adapter_builds_the_seagul_observation() -> None:
    policy = _Predictor(tau_max=4.0)
    controller = PredictController(policy)
    episode = run_dmc_episode("acrobot-swingup", controller, seed=2, hold=10, record=True)
    assert len(policy.seen) == 100 == episode.decisions
    obs0, start0 = policy.seen[0]
    assert obs0.dtype == np.float32 and obs0.shape == (5,)
    assert np.array_equal(obs0[:4], np.asarray(episode.start, dtype=np.float32)) and start0
    assert not any(s for _, s in policy.seen[1:])
    taus = [float(o[4]) for o, _ in policy.seen]
    assert taus[0] == pytest.approx(4.0) and taus[-1] == pytest.approx(10.0 - 9.9)  # min(T - t, tau_max)
    assert episode.actions is not None and episode.actions[0] == pytest.approx((0.1,))
    # A second episode starts again (the MPC's warm start is reset).
    run_dmc_episode("acrobot-swingup", controller, seed=2, hold=500)
    assert policy.seen[-2][1] and not policy.seen[-1][1]
    assert PredictController(policy, time_to_go=2.5).tau(9.0) == 2.5


def test_suite_model_is_mujocos_dynamics() -> None:
    """M q'' + h = gear * ctrl on the actuated joint reproduces MuJoCo's own accelerations."""
    import mujoco

    rng = np.random.default_rng(0)
    for domain in ("acrobot", "pendulum", "cartpole"):
        model = spong.SuiteModel(domain)
        for _ in range(5):
            x = rng.uniform(-2.0, 2.0, model.nq + model.nv)
            ctrl = rng.uniform(-1.0, 1.0)
            M, h, _ = model.dynamics(x)
            force = np.zeros(model.nv)
            force[model.actuated] = model.gear * ctrl
            qacc = np.linalg.solve(M, force - h)
            model.data.qpos[:], model.data.qvel[:], model.data.ctrl[:] = x[: model.nq], x[model.nq :], ctrl
            mujoco.mj_forward(model.model, model.data)
            np.testing.assert_allclose(qacc, model.data.qacc, rtol=1e-8, atol=1e-8)
        assert model.energy(np.zeros(model.nq + model.nv)) == pytest.approx(model.top_energy)


def test_seagul_lqr_policy_runs_through_the_adapter() -> None:
    """A seagul policy of the suite's CasADi task acts on dm_control's physics state through PredictController."""
    from seagul_control.lqr import LQRPolicy
    from seagul_envs import make_task

    task = make_task(DMC_TASKS["dm_control/acrobot-swingup-v0"])
    policy = LQRPolicy(task)
    episode = run_dmc_episode("acrobot-swingup", PredictController(policy), seed=4, hold=1, record=True)
    assert episode.states is not None and episode.actions is not None
    for k in (0, 1, 500):
        x = np.asarray(episode.states[k], dtype=np.float32).astype(float)  # the observation's float32 state
        np.testing.assert_allclose(episode.actions[k], policy.action(x, 5.0), rtol=1e-6, atol=1e-9)


def test_catch_gain_equals_seagul_lqr_of_the_casadi_task() -> None:
    """The classical controllers' LQR (MuJoCo linearised by finite differences) is seagul's LQRPolicy of the
    suite's CasADi task with the same weights: two independent models of one MJCF agree."""
    from seagul_control.lqr import LQRPolicy
    from seagul_envs import make_task

    controller = spong.SpongAcrobotController()
    p = controller.params
    policy = LQRPolicy(make_task("dmc_acrobot"), Q=np.diag(p.lqr_q), R=np.array([[p.lqr_r]]))
    np.testing.assert_allclose(controller.lqr.K, policy.K, rtol=1e-5)


@pytest.mark.parametrize(("seed", "measured"), [(100, 74.9), (101, 182.3)])
def test_spong_swing_up_beats_doing_nothing_on_the_acrobot(seed: int, measured: float) -> None:
    """Spong's swing-up scores well above zero action (measured: 74.9 and 182.3 against 8.4 and 21.3 for zero
    action, seeds 100 and 101); the thresholds leave a third of the measured score as margin."""
    score = run_dmc_episode("acrobot-swingup", spong.SpongAcrobotController(), seed).score
    zero = run_dmc_episode("acrobot-swingup", lambda x, t: np.zeros(1), seed).score
    assert score > max(3.0 * zero, 0.66 * measured)


@pytest.mark.parametrize(
    ("env_id", "controller", "threshold"),
    [
        # measured on seed 100: 916.0, 855.7, 778.0 (zero action: 0.0, 0.0, 0.0)
        ("pendulum-swingup", spong.PendulumEnergyController, 800.0),
        ("cartpole-swingup", spong.AstromFurutaCartpoleController, 800.0),
        ("cartpole-swingup_sparse", spong.AstromFurutaCartpoleController, 700.0),
    ],
)
def test_energy_swing_ups_balance(env_id: str, controller: type, threshold: float) -> None:
    episode = run_dmc_episode(env_id, controller(), 100, record=True)
    assert episode.score > threshold
    assert episode.states is not None
    # Upright and still at the end: the LQR caught it.
    final = np.asarray(episode.states[-1])
    angle = final[0] if env_id.startswith("pendulum") else final[1]
    assert abs(float(spong.wrap_angle(angle))) < 0.05 and np.all(np.abs(final[len(final) // 2 :]) < 0.1)


def test_episodes_share_one_env_and_serialise() -> None:
    import json

    from seagul_control.dmc import run_dmc_episodes

    episodes = run_dmc_episodes("pendulum-swingup", lambda x, t: np.zeros(1), [0, 1, 0])
    assert [e.seed for e in episodes] == [0, 1, 0]
    assert episodes[0] == dataclasses.replace(
        episodes[2],
        wall_s=episodes[0].wall_s,
        decision_ms_median=episodes[0].decision_ms_median,
        decision_ms_p95=episodes[0].decision_ms_p95,
    )
    row = json.loads(json.dumps(episodes[1].to_dict()))
    assert row["score"] == episodes[1].score and len(row["rewards"]) == EPISODE_STEPS and row["states"] is None
    with pytest.raises(dataclasses.FrozenInstanceError):
        episodes[0].score = 1.0  # type: ignore[misc]
