"""LQR references: the acrobot gain against an independent Riccati solution, stability, clipping, glider TVLQR."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import scipy.linalg

import seagul_envs  # noqa: F401  (registers the envs)
from seagul_control.lqr import LQRPolicy, split_observation
from seagul_envs import make_task


def _finite_difference_linearization(task, dt: float, eps: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """``(A, B)`` of the env's one-period map by central differences (independent of CasADi's Jacobians)."""
    sim = task.simulator(dt)
    x0, u0 = task.goal, np.zeros(task.nu)

    def f(x: np.ndarray, u: np.ndarray) -> np.ndarray:
        return np.asarray(sim(x, u)).ravel()

    A = np.column_stack([(f(x0 + eps * e, u0) - f(x0 - eps * e, u0)) / (2 * eps) for e in np.eye(task.nx)])
    B = np.column_stack([(f(x0, u0 + eps * e) - f(x0, u0 - eps * e)) / (2 * eps) for e in np.eye(task.nu)])
    return A, B


def test_acrobot_gain_matches_independent_riccati_solution():
    task = make_task("acrobot")
    policy = LQRPolicy(task)
    dt = task.control_period
    A, B = _finite_difference_linearization(task, dt)
    np.testing.assert_allclose(policy.A, A, atol=1e-6)
    np.testing.assert_allclose(policy.B, B, atol=1e-6)
    Q, R = dt * task.extras["Q"], dt * task.extras["R"]
    P = scipy.linalg.solve_discrete_are(A, B, Q, R)
    K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
    np.testing.assert_allclose(policy.K, K, rtol=1e-5, atol=1e-5)
    # The Riccati fixed point holds for the policy's own P.
    Pp = policy.P
    residual = Q + A.T @ Pp @ A - A.T @ Pp @ B @ np.linalg.solve(R + B.T @ Pp @ B, B.T @ Pp @ A) - Pp
    assert np.max(np.abs(residual)) < 1e-6 * np.max(np.abs(Pp))


def test_acrobot_closed_loop_is_stable():
    policy = LQRPolicy(make_task("acrobot"))
    eig = np.linalg.eigvals(policy.A - policy.B @ policy.K)
    assert np.max(np.abs(eig)) < 1.0
    # And the open loop is not (the upright acrobot is unstable), so the check is not vacuous.
    assert np.max(np.abs(np.linalg.eigvals(policy.A))) > 1.0


def test_acrobot_balances_from_a_small_offset_in_the_env():
    task = make_task("acrobot")
    policy = LQRPolicy(task)
    env = gym.make("SeagulAcrobot-v0")
    obs, info = env.reset(options={"state": task.goal + np.array([0.05, -0.05, 0.0, 0.0])})
    done = False
    while not done:
        action, _ = policy.predict(obs)
        obs, _, terminated, truncated, info = env.step(action)
        done = terminated or truncated
    assert np.linalg.norm(info["state"] - task.goal) < 1e-3


def test_actions_are_clipped_and_batched():
    task = make_task("acrobot")
    policy = LQRPolicy(task)
    far = np.concatenate([task.goal + np.array([1.0, 1.0, 3.0, 3.0]), [5.0]])
    near = np.concatenate([task.goal + 1e-3, [5.0]])
    actions, state = policy.predict(np.stack([far, near]), state="kept")
    assert state == "kept"
    assert actions.shape == (2, 1) and actions.dtype == np.float32
    assert abs(actions[0, 0]) == pytest.approx(task.u_high[0])
    assert abs(actions[1, 0]) < task.u_high[0]
    single, _ = policy.predict(near)
    assert single.shape == (1,)


@pytest.mark.parametrize(
    ("obs", "match"),
    [(np.zeros(4), r"shape \(5,\)"), (np.full(5, np.nan), "NaN"), (np.zeros((2, 3)), r"shape \(5,\)")],
)
def test_bad_observations_raise(obs, match):
    with pytest.raises(ValueError, match=match):
        split_observation(obs, 4, "LQRPolicy")


def test_glider_tvlqr_tracks_the_nominal_perch():
    task = make_task("glider")
    policy = LQRPolicy(task)
    assert policy.time_varying
    n = policy.nominal.controls.shape[0]
    assert policy.gains.shape == (n, 1, 7) and np.all(np.isfinite(policy.gains))
    env = gym.make("SeagulGlider-v0")
    x0 = 0.5 * (task.x0_low + task.x0_high) + np.array([0.05, -0.02, 0, 0, 0.1, 0, 0])
    obs, info = env.reset(options={"state": x0})
    done = False
    while not done:
        action, _ = policy.predict(obs)
        obs, _, terminated, truncated, info = env.step(action)
        done = terminated or truncated
    x = info["state"]
    assert abs(x[0]) < 0.05 and abs(x[1]) < 0.05, x
