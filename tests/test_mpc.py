"""Limited-lookahead and full-horizon MPC: exactness checks, warm starts, fallbacks, the predictor protocol."""

from __future__ import annotations

import dataclasses

import casadi as ca
import gymnasium as gym
import numpy as np
import pytest
import scipy.linalg

import seagul_envs  # noqa: F401  (registers the envs)
from seagul_control.mpc import (
    FullHorizonMPC,
    FullHorizonOptions,
    LimitedLookaheadMPC,
    MPCOptions,
    _Plan,
    _Problem,
    _shift_guess,
)
from seagul_control.transcription import Transcription, TranscriptionOptions
from seagul_envs import make_task

# Interpreted solvers keep the default suite free of minutes of C compilation.
FAST = MPCOptions(jit=False)
GLIDER_X0 = np.array([-3.5, 0.1, 0.0, 0.0, 7.0, 0.0, 0.0])


class QuadraticValue:
    """Stand-in value function ``V = v0 + g'(x - c) + (x - c)' P (x - c)`` implementing the CasADi protocol."""

    def __init__(self, P: np.ndarray, center: np.ndarray, grad: np.ndarray | None = None, value: float = 0.0) -> None:
        nx = center.size
        self.task_name = ""
        self.theta = np.concatenate([P.ravel(order="F"), center, np.zeros(nx) if grad is None else grad, [value]])
        x, tau, th = ca.SX.sym("x", nx), ca.SX.sym("tau"), ca.SX.sym("theta", self.theta.size)
        Pm = ca.reshape(th[: nx * nx], nx, nx)
        c, g, v0 = th[nx * nx : nx * nx + nx], th[nx * nx + nx : nx * nx + 2 * nx], th[-1]
        e = x - c
        self.fn = ca.Function("quadratic_value", [x, tau, th], [v0 + ca.dot(g, e) + ca.bilin(Pm, e, e)])

    def casadi_function(self) -> ca.Function:
        return self.fn

    def casadi_parameters(self) -> np.ndarray:
        return self.theta


def _linear_acrobot():
    """The acrobot linearised at the goal (same costs): RK4 of it is linear, so LQR is exact."""
    task = make_task("acrobot")
    x, u = ca.SX.sym("x", 4), ca.SX.sym("u", 1)
    f = task.dynamics(x, u)
    jac = ca.Function("j", [x, u], [ca.jacobian(f, x), ca.jacobian(f, u)])
    Ac, Bc = (np.asarray(m) for m in jac(task.goal, 0.0))
    linear = ca.Function("lin_f", [x, u], [Ac @ (x - task.goal) + Bc @ u])
    lin = dataclasses.replace(task, name="acrobot_linear", dynamics=linear)
    h = task.control_period
    xn = lin.rk4_step()(x, u, h)
    A, B = (np.asarray(m) for m in ca.Function("d", [x, u], [ca.jacobian(xn, x), ca.jacobian(xn, u)])(task.goal, 0))
    Q, R = h * task.extras["Q"], h * task.extras["R"]
    P = scipy.linalg.solve_discrete_are(A, B, Q, R)
    K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
    err = x - task.goal
    lin = dataclasses.replace(lin, terminal_cost=ca.Function("lf", [x], [ca.bilin(P, err, err)]))
    return lin, P, K


def test_lq_mpc_with_exact_terminal_cost_equals_lqr_and_full_horizon():
    """Linear dynamics, quadratic cost, DARE terminal: a 5-step MPC is the infinite-horizon LQR exactly."""
    task, P, K = _linear_acrobot()
    x0 = task.goal + np.array([0.02, -0.03, 0.05, -0.02])
    expected = -K @ (x0 - task.goal)
    assert 0.05 < abs(expected[0]) < task.u_high[0]  # inside the bounds, and not trivially zero
    tight = FAST.replace(tol=1e-10, clamp=False)
    mpc = LimitedLookaheadMPC(task, QuadraticValue(P, task.goal), 5, tight, trust_region="none")
    full = FullHorizonMPC(task, FullHorizonOptions(tol=1e-10))
    u_mpc, info = mpc.act(x0, 5.0)
    u_full, _ = full.act(x0, 5.0)
    assert info.source == "solver"
    np.testing.assert_allclose(u_mpc, expected, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(u_full, expected, rtol=1e-6, atol=1e-8)
    # A wrong terminal cost must change the answer (the check above is not vacuous).
    wrong = LimitedLookaheadMPC(task, QuadraticValue(0.1 * P, task.goal), 5, tight, trust_region="none")
    assert abs(wrong.act(x0, 5.0)[0][0] - expected[0]) > 1e-3


def test_mpc_with_full_horizon_cost_to_go_reproduces_the_full_horizon_first_action():
    """Nonlinear acrobot: terminal cost with the full-horizon cost-to-go's value and gradient at knot 5."""
    task = make_task("acrobot")
    n, m = 5, task.num_steps
    x0 = task.goal + np.array([0.15, -0.1, 0.2, -0.1])
    full = Transcription(task, m, TranscriptionOptions(free_time=False, step=task.control_period, final_box=False))
    sol = full.solve(x0, task.tau_nominal)
    assert sol.success
    x_n = sol.states[n]
    stage = full.stage_costs(sol.states, sol.controls, sol.steps)
    v_n = sol.objective - stage[:n].sum()
    grad_n = sol.defect_multipliers[n - 1]
    # Re-solve the tail from knot n: same cost-to-go and the same gradient (dual of x_0 = x_init).
    tail = Transcription(
        task, m - n, TranscriptionOptions(free_time=False, step=task.control_period, final_box=False)
    ).solve(x_n, task.tau_nominal - n * task.control_period)
    assert tail.objective == pytest.approx(v_n, rel=1e-6)
    np.testing.assert_allclose(tail.param_sensitivity[: task.nx], grad_n, rtol=1e-4, atol=1e-6)

    value = QuadraticValue(task.extras["Qf"], x_n, grad_n, v_n)
    exact = FAST.replace(trust_region="none", clamp=False, anchor_goal=False, tol=1e-10)
    mpc = LimitedLookaheadMPC(task, value, n, exact)
    u, info = mpc.act(x0, task.tau_nominal)
    assert info.success
    np.testing.assert_allclose(u, sol.controls[0], atol=1e-4)
    # Without the gradient term the short MPC acts differently: the check has teeth.
    plain = LimitedLookaheadMPC(task, QuadraticValue(task.extras["Qf"], x_n, None, v_n), n, exact)
    assert np.max(np.abs(plain.act(x0, task.tau_nominal)[0] - sol.controls[0])) > 1e-2


def _acrobot_mpc(**kwargs):
    task = make_task("acrobot")
    trust_region = kwargs.pop("trust_region", None)
    options = FAST.replace(**kwargs)
    return task, LimitedLookaheadMPC(
        task, QuadraticValue(task.extras["Qf"], task.goal), 5, options, trust_region=trust_region
    )


def _obs(x: np.ndarray, tau: float) -> np.ndarray:
    return np.concatenate([x, [tau]]).astype(np.float32)


def test_evaluate_policy_on_a_two_env_dummy_vec_env():
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.evaluation import evaluate_policy
    from stable_baselines3.common.vec_env import DummyVecEnv

    _, mpc = _acrobot_mpc()
    venv = make_vec_env("SeagulAcrobot-v0", n_envs=2, seed=3, vec_env_cls=DummyVecEnv)
    rewards, lengths = evaluate_policy(mpc, venv, n_eval_episodes=2, return_episode_rewards=True, warn=False)
    assert lengths == [50, 50]
    assert np.all(np.isfinite(rewards))
    assert len(mpc.stats) == 100  # one solve per env per step
    assert sum(s.source == "solver" for s in mpc.stats) >= 90
    assert {0, 1} <= set(mpc._plans)  # one warm start per env index
    # The balancing MPC beats doing nothing from the same starts.
    venv_zero = make_vec_env("SeagulAcrobot-v0", n_envs=2, seed=3, vec_env_cls=DummyVecEnv)

    class Zero:
        def predict(self, obs, state=None, episode_start=None, deterministic=True):
            return np.zeros((obs.shape[0], 1), dtype=np.float32), state

    zero_rewards, _ = evaluate_policy(Zero(), venv_zero, n_eval_episodes=2, return_episode_rewards=True, warn=False)
    assert np.mean(rewards) > np.mean(zero_rewards)


def test_warm_start_is_per_env_and_dropped_on_episode_start(monkeypatch):
    task, mpc = _acrobot_mpc()
    cold_calls: list[float] = []
    original = _Problem.cold_guess

    def spy(self, x, tau, dt, kind):
        cold_calls.append(tau)
        return original(self, x, tau, dt, kind)

    monkeypatch.setattr(_Problem, "cold_guess", spy)
    obs = np.stack([_obs(task.goal + 0.05, 5.0), _obs(task.goal - 0.05, 5.0)])
    mpc.predict(obs, episode_start=np.array([True, True]))
    assert len(cold_calls) == 2
    obs[:, -1] = 4.9
    mpc.predict(obs, episode_start=np.array([False, False]))
    assert len(cold_calls) == 2  # both warm-started from their shifted plans
    mpc.predict(obs, episode_start=np.array([False, True]))
    assert len(cold_calls) == 3  # only env 1 restarted cold
    assert all(i.source == "solver" for i in mpc.last_info)


def test_failed_solves_fall_back_to_the_shifted_plan_then_lqr(monkeypatch):
    task, mpc = _acrobot_mpc()
    x = task.goal + np.array([0.1, -0.1, 0.0, 0.0])
    _, info = mpc.act(x, 5.0)
    assert info.source == "solver"
    plan = mpc._plans[0].controls.copy()

    def broken(self, *args, **kwargs):
        raise RuntimeError("forced failure")

    monkeypatch.setattr(_Problem, "solve", broken)
    sources, actions = [], []
    for k in range(1, 7):
        u, info = mpc.act(x, 5.0 - 0.1 * k)
        sources.append(info.source)
        actions.append(u)
        assert not info.success and info.status.startswith("exception")
    assert sources == ["shifted"] * 4 + ["lqr"] * 2
    np.testing.assert_allclose(np.array(actions[:4])[:, 0], plan[1:5, 0])
    lqr = mpc._backup_policy()
    np.testing.assert_allclose(actions[-1], lqr.action(x, 4.4))


def test_real_solver_failure_is_reported_not_raised():
    task, mpc = _acrobot_mpc(max_iter=0, multistart="never")
    actions, _ = mpc.predict(_obs(task.goal + np.array([0.2, 0.1, 0.3, 0.0]), 5.0))
    info = mpc.last_info[0]
    assert actions.shape == (1,) and np.all(np.isfinite(actions))
    assert not info.success and info.source == "lqr"
    assert info.iterations == 0 and info.solve_time > 0


def test_terminal_cost_equals_the_value_network_it_wraps():
    torch = pytest.importorskip("torch")
    from seagul_learn.value_network import ValueNetwork

    task = make_task("acrobot")
    net = ValueNetwork(4, (32,), task_name="acrobot", seed=1)
    rng = np.random.default_rng(0)
    xs = task.sample_x0(rng, 64)
    net.set_normalization(xs, rng.uniform(0, 5, 64), rng.uniform(0, 50, 64))
    with torch.no_grad():
        net.layers[-1].bias.fill_(3.0)  # keep V > 0 so the clamp is inactive on most points
    box = (task.goal - 1.0, task.goal + 1.0)
    mpc = LimitedLookaheadMPC(
        task,
        net,
        5,
        FAST.replace(trust_box=box, trust_weight=7.0, anchor_goal=False, goal_blend=0.0),
        trust_region="box",
    )
    raw = {"clamp": False, "anchor_goal": False, "goal_blend": 0.0}
    prior = LimitedLookaheadMPC(task, net, 5, FAST.replace(**raw), trust_region="lqr")
    plain = LimitedLookaheadMPC(task, net, 5, FAST.replace(**raw), trust_region="none")
    for x, tau in zip(task.sample_x0(rng, 5), rng.uniform(0.5, 4.5, 5), strict=True):
        expected = float(net.predict(x[None], tau)[0])
        assert plain.terminal_cost_value(x, tau) == pytest.approx(expected, rel=1e-10, abs=1e-10)
        lf = task.terminal_cost_value(x)
        assert prior.terminal_cost_value(x, tau) == pytest.approx(expected + lf, rel=1e-10, abs=1e-10)
    # Outside the trust box: the quadratic wall is added (in box widths).
    x = task.goal + np.array([1.5, 0.0, 0.0, -1.2])
    v = float(net.predict(x[None], 2.0)[0])
    wall = 7.0 * ((0.5 / 2.0) ** 2 + (0.2 / 2.0) ** 2)
    assert mpc.terminal_cost_value(x, 2.0) == pytest.approx(max(v, 0) + wall, rel=1e-3, abs=1e-3)


def test_new_network_of_the_same_architecture_does_not_rebuild_the_solver():
    pytest.importorskip("torch")
    from seagul_learn.value_network import ValueNetwork

    task = make_task("acrobot")
    a = ValueNetwork(4, (32,), task_name="acrobot", seed=1)
    b = ValueNetwork(4, (32,), task_name="acrobot", seed=2)
    mpc = LimitedLookaheadMPC(task, a, 5, FAST, trust_region="none")
    solver_before = mpc._lookahead.trans._solver
    x = task.goal + np.array([0.1, 0.1, 0.0, 0.0])
    u_a, _ = mpc.act(x, 5.0)
    mpc.set_value_function(b)
    assert mpc._lookahead.trans._solver is solver_before
    u_b, _ = mpc.act(x, 5.0)
    assert not np.allclose(u_a, u_b)
    with pytest.raises(ValueError, match="different CasADi structure"):
        mpc.set_value_function(ValueNetwork(4, (16,), task_name="acrobot"))
    with pytest.raises(ValueError, match="trained for task 'glider'"):
        mpc.set_value_function(ValueNetwork(4, (32,), task_name="glider"))


@pytest.mark.parametrize("horizon", [0, -3, 2.5, True])
def test_bad_horizon_raises(horizon):
    with pytest.raises(ValueError, match="horizon must be an integer >= 1"):
        LimitedLookaheadMPC(make_task("acrobot"), None, horizon, FAST)


def test_bad_observations_raise():
    _, mpc = _acrobot_mpc()
    with pytest.raises(ValueError, match="NaN"):
        mpc.predict(np.array([np.pi, np.nan, 0, 0, 5.0]))
    with pytest.raises(ValueError, match=r"shape \(5,\) or \(n_envs, 5\)"):
        mpc.predict(np.zeros(4))
    with pytest.raises(ValueError, match="episode_start"):
        mpc.predict(np.zeros((2, 5)), episode_start=np.array([True, False, True]))


def test_end_of_episode_switches_to_the_task_terminal_cost():
    task, mpc = _acrobot_mpc()
    x = task.goal + 0.05
    _, theta_mid = mpc._select(5.0)
    _, theta_end = mpc._select(0.5)  # tau - n dt = 0: no learned cost left
    assert theta_mid[-1] == 1.0 and theta_end[-1] == 0.0
    assert mpc.act(x, 0.3)[1].success


def test_glider_final_phase_shrinks_to_the_episode_end():
    task = make_task("glider")
    goal_like = QuadraticValue(np.diag(task.extras["Qf"].diagonal()), task.goal)
    goal_like.task_name = "glider"
    mpc = LimitedLookaheadMPC(task, goal_like, 10, FAST)
    from seagul_control.lqr import LQRPolicy

    nominal = LQRPolicy(task)
    x0 = 0.5 * (task.x0_low + task.x0_high)
    # Fly the TVLQR along the nominal perch to 0.1 s before the end, then let the MPC finish (final phase, 4 steps).
    env = gym.make("SeagulGlider-v0")
    obs, info = env.reset(options={"state": x0})
    for _ in range(28):
        action, _ = nominal.predict(obs)
        obs, _, terminated, _, info = env.step(action)
        assert not terminated
    assert info["time_to_go"] == pytest.approx(0.1)
    done = False
    while not done:
        action, _ = mpc.predict(obs)
        assert mpc.last_info[0].phase == "final"
        obs, _, terminated, truncated, info = env.step(action)
        done = terminated or truncated
    assert sorted(mpc._final_fixed) == [1, 2, 3, 4]
    x = info["state"]
    assert abs(x[0]) < 0.05 and abs(x[1]) < 0.05, x


def test_goal_anchoring_removes_the_networks_value_and_slope_at_the_goal():
    pytest.importorskip("torch")
    from seagul_learn.value_network import ValueNetwork

    task = make_task("acrobot")
    net = ValueNetwork(4, (32,), task_name="acrobot", seed=3)
    anchored = LimitedLookaheadMPC(task, net, 5, FAST.replace(clamp=False, goal_blend=0.0), trust_region="none")
    assert anchored.anchor_goal  # default for a zero-cost equilibrium goal
    unanchored = FAST.replace(clamp=False, anchor_goal=False, goal_blend=0.0)
    raw = LimitedLookaheadMPC(task, net, 5, unanchored, trust_region="none")
    g = task.goal
    assert abs(raw.terminal_cost_value(g, 2.0)) > 1e-3  # the random network is not zero there
    assert anchored.terminal_cost_value(g, 2.0) == pytest.approx(0.0, abs=1e-12)
    eps = 1e-6
    for e in np.eye(4):
        slope = (anchored.terminal_cost_value(g + eps * e, 2.0) - anchored.terminal_cost_value(g - eps * e, 2.0)) / 2
        assert abs(slope / eps) < 1e-6
    # Away from the goal the anchored cost is the network minus its first-order expansion at the goal.
    x = g + np.array([0.2, -0.1, 0.3, 0.1])
    v, grad, _ = net.value_and_grad(g, 2.0)
    expected = float(net.predict(x[None], 2.0)[0]) - v - grad @ (x - g)
    assert anchored.terminal_cost_value(x, 2.0) == pytest.approx(expected, rel=1e-9, abs=1e-9)
    with pytest.raises(ValueError, match="zero-cost equilibrium"):
        LimitedLookaheadMPC(make_task("glider"), None, 10, FAST.replace(anchor_goal=True))


def test_goal_blend_is_l_f_at_the_goal_and_the_network_far_away():
    pytest.importorskip("torch")
    from seagul_learn.value_network import ValueNetwork

    task = make_task("acrobot")
    net = ValueNetwork(4, (32,), task_name="acrobot", seed=3)
    plain = LimitedLookaheadMPC(task, net, 5, FAST.replace(clamp=False, goal_blend=0.0), trust_region="none")
    blended = LimitedLookaheadMPC(task, net, 5, FAST.replace(clamp=False, goal_blend=0.5), trust_region="none")
    g = task.goal
    for d in (np.zeros(4), np.array([0.01, -0.02, 0.05, 0.0]), np.array([0.3, 0.2, -0.5, 1.0]), np.full(4, 3.0)):
        x = g + d
        lf = task.terminal_cost_value(x)
        b = np.exp(-lf / 0.5)
        expected = b * lf + (1 - b) * plain.terminal_cost_value(x, 2.0)
        assert blended.terminal_cost_value(x, 2.0) == pytest.approx(expected, rel=1e-10, abs=1e-12)
    far = g + np.full(4, 3.0)
    assert blended.terminal_cost_value(far, 2.0) == pytest.approx(plain.terminal_cost_value(far, 2.0), rel=1e-6)
    assert LimitedLookaheadMPC(task, net, 5, FAST).goal_blend == 1.0  # the acrobot's profile
    assert LimitedLookaheadMPC(make_task("glider"), None, 10, FAST).goal_blend == 0.0
    with pytest.raises(ValueError, match="goal_blend must be a finite number >= 0"):
        FAST.replace(goal_blend=-1.0)
    with pytest.raises(ValueError, match="goal_blend needs a goal that is a zero-cost equilibrium"):
        LimitedLookaheadMPC(make_task("glider"), None, 10, FAST.replace(goal_blend=1.0))


def test_jit_object_cache_is_keyed_by_the_generated_source(tmp_path):
    from seagul_control.mpc import find_c_compiler, jit_solver_options

    if find_c_compiler() is None:
        pytest.skip("no C compiler")
    x, p = ca.SX.sym("x", 2), ca.SX.sym("p")
    nlp = {"x": x, "p": p, "f": (x[0] - p) ** 2 + (x[1] - 2 * p) ** 2}
    objects = []
    for _ in range(2):
        options = {**jit_solver_options(tmp_path), "ipopt.print_level": 0, "print_time": False}
        solver = ca.nlpsol("jit_probe", "ipopt", nlp, options)
        np.testing.assert_allclose(np.asarray(solver(x0=[0, 0], p=1.5)["x"]).ravel(), [1.5, 3.0], atol=1e-6)
        objects.append(sorted(f.name for f in tmp_path.glob("*.o")))
    assert len(objects[0]) == 1 and objects[1] == objects[0]  # the second build reused the cached object
    assert (tmp_path / "seagul_cc.py").is_file()


# ------------------------------------------------------------------------ the MPC uses the transcription's public API
def _glider_final_problem(shrink: bool) -> _Problem:
    task = make_task("glider")
    hi = max(task.step_bounds[1], task.control_period)
    trans = Transcription(
        task, 5, TranscriptionOptions(free_time=True, step_bounds=(0.0, hi), time_mode="equal", final_box=True)
    )
    return _Problem(trans, "final", True, shrink, task.step_bounds[0])


@pytest.mark.parametrize("shrink", [False, True])
def test_first_step_pin_and_shrinking_steps_go_through_the_setters(monkeypatch, shrink):
    problem = _glider_final_problem(shrink)
    trans, task = problem.trans, problem.trans.task
    seen = []
    monkeypatch.setattr(trans, "solve", lambda *a, **k: seen.append([trans.get(s, "lbh")[0] for s in range(5)]))
    lo0, hi0 = trans.get(1, "lbh")[0], trans.get(1, "ubh")[0]
    dt = 0.05
    for tau in (0.3, 0.02):
        problem.solve(GLIDER_X0, tau, np.zeros(0), dt, trans.line_guess(GLIDER_X0, tau))
        h0 = min(dt, tau)
        assert trans.get(0, "lbh")[0] == trans.get(0, "ubh")[0] == h0
        rest = max(tau - h0, 0.0) / 4
        for k in range(1, 5):
            expect = (min(task.step_bounds[0], 0.5 * rest), max(trans.step_bounds[1], rest)) if shrink else (lo0, hi0)
            assert (trans.get(k, "lbh")[0], trans.get(k, "ubh")[0]) == expect
    assert len(seen) == 2


@pytest.mark.parametrize("name", ["acrobot", "glider"])
def test_shifted_multipliers_match_the_stage_layout(name):
    """_shift_guess through the public index maps equals the stage-by-stage shift on the raw index lists."""
    task = make_task(name)
    if name == "glider":
        problem = _glider_final_problem(True)
    else:
        problem = _Problem(
            Transcription(task, 5, TranscriptionOptions(free_time=False, step=0.1, final_box=False)), "lookahead", False
        )
    trans = problem.trans
    n, nx, a = trans.horizon, task.nx, 2
    rng = np.random.default_rng(3)
    plan = _Plan(
        problem,
        rng.normal(size=(n + 1, nx)),
        rng.normal(size=(n, task.nu)),
        rng.uniform(0.01, 0.03, n),
        rng.normal(size=trans.num_variables),
        rng.normal(size=trans._lbg.size),
        age=a,
    )
    x = rng.normal(size=nx)
    primal, lam_g, lam_x = _shift_guess(plan, problem, x, 0.05, 0.5)

    def shifted(rows):
        arr = np.stack(rows)
        tail = arr[min(a, arr.shape[0] - 1) :]
        return np.concatenate([tail, np.repeat(tail[-1:], max(0, len(rows) - tail.shape[0]), axis=0)])[: len(rows)]

    lx = plan.lam_x
    want_x = np.zeros(trans.num_variables)
    for idx, vals in zip(trans._x_idx, shifted([lx[i] for i in trans._x_idx]), strict=True):
        want_x[idx] = vals
    for idx, vals in zip(trans._u_idx, shifted([lx[i] for i in trans._u_idx]), strict=True):
        want_x[idx] = vals
    if trans.free_time:
        want_x[trans._h_idx] = shifted([lx[i] for i in trans._h_idx])
        want_x[trans._t_idx] = shifted([lx[i] for i in trans._t_idx])
    np.testing.assert_array_equal(lam_x, want_x)
    want_g = plan.lam_g.copy()
    want_g[:nx] = plan.lam_g[trans._defect_rows[a - 1]]
    for rows, vals in zip(trans._defect_rows, shifted([plan.lam_g[r] for r in trans._defect_rows]), strict=True):
        want_g[rows] = vals
    np.testing.assert_array_equal(lam_g, want_g)
    np.testing.assert_array_equal(primal[trans.state_index[0]], x)
    other = _Problem(
        Transcription(task, n, TranscriptionOptions(free_time=trans.free_time, step=trans.step)), "other", False
    )
    assert _shift_guess(plan, other, x, 0.05, 0.5)[1:] == (None, None)  # another layout: no multipliers


# The ensemble case compiles a second, larger library (half a minute cold): the single network covers the contract.
@pytest.mark.parametrize("ensemble", [False, pytest.param(True, marks=pytest.mark.slow)])
def test_compiled_matrix_form_value_function_is_the_interpreted_one(tmp_path, ensemble):
    """With ``jit=True`` a ``ValueNetwork``/``ValueEnsemble`` enters the lookahead in its matrix (MX) form, compiled
    unexpanded, with the goal anchor's terms as NLP parameters: the terminal cost, the goal anchor after a new value
    function, and the actions equal the interpreted scalar (SX) MPC's."""
    pytest.importorskip("torch")
    from seagul_control.mpc import find_c_compiler
    from seagul_learn.value_network import ValueEnsemble, ValueNetwork

    if find_c_compiler() is None:
        pytest.skip("no C compiler")
    task = make_task("acrobot")
    rng = np.random.default_rng(4)

    def make(seed):
        if ensemble:
            vf = ValueEnsemble(4, (16,), 2, 0.5, task_name="acrobot", seed=seed)
            nets = vf.networks
        else:
            vf = ValueNetwork(4, (16, 16), task_name="acrobot", seed=seed)
            nets = [vf]
        for net in nets:
            net.set_normalization(task.sample_x0(rng, 64), rng.uniform(0, 5, 64), rng.uniform(0, 50, 64))
        return vf

    a, b = make(1), make(2)
    options = MPCOptions(trust_region="lqr", goal_blend=0.5, max_iter=50, solver="fatrop")
    compiled = LimitedLookaheadMPC(task, a, 5, options.replace(jit=True, jit_cache_dir=str(tmp_path)))
    interpreted = LimitedLookaheadMPC(task, a, 5, options.replace(jit=False))
    assert compiled._matrix_form() and not interpreted._matrix_form()
    assert compiled.anchor_goal and compiled._lookahead.trans.codegen_library is not None
    for vf in (a, b):
        compiled.set_value_function(vf)
        interpreted.set_value_function(vf)
        for x, tau in zip(task.sample_x0(rng, 6), rng.uniform(0.6, 4.5, 6), strict=True):
            assert compiled.terminal_cost_value(x, tau) == pytest.approx(
                interpreted.terminal_cost_value(x, tau), rel=1e-9, abs=1e-9
            )
        # The anchor's terms follow the new value function (its cache is cleared): l_f-free zero at the goal.
        assert compiled.terminal_cost_value(task.goal, 2.0) == pytest.approx(0.0, abs=1e-9)
    x, tau = task.goal + np.array([0.1, -0.1, 0.05, 0.0]), 5.0
    for _ in range(3):
        u_c, info_c = compiled.act(x, tau)
        u_i, info_i = interpreted.act(x, tau)
        assert (info_c.source, info_c.status, info_c.iterations) == (info_i.source, info_i.status, info_i.iterations)
        np.testing.assert_allclose(u_c, u_i, rtol=1e-6, atol=1e-6)
        x, tau = x + 0.02 * rng.standard_normal(4), tau - 0.1  # the next state, warm-started in both


def test_a_value_function_with_one_form_is_used_in_it_and_a_bad_form_is_refused():
    """The MPC asks for the matrix form only from value functions whose ``casadi_function`` takes ``form``."""
    pytest.importorskip("torch")
    from seagul_control.mpc import _value_function_form
    from seagul_learn.value_network import ValueNetwork

    quadratic = QuadraticValue(np.eye(4), np.zeros(4))
    assert _value_function_form(quadratic, "matrix") is quadratic.fn
    net = ValueNetwork(4, (8,), task_name="acrobot", seed=0)
    assert _value_function_form(net, "matrix").is_a("MXFunction")
    assert _value_function_form(net, "scalar").is_a("SXFunction")
    with pytest.raises(ValueError, match="form must be 'scalar', 'matrix'"):
        net.casadi_function(form="dense")


def test_glider_soft_final_phase_returns_a_plan_where_the_exact_perch_is_out_of_reach() -> None:
    """Final phase (the last 10 steps end at the episode end): from this state no plan lands exactly in the perch box
    with fixed 25 ms steps, so the hard final phase fails and the step falls back; the glider's default soft box
    (IPOPT, exact L1 penalty) converges to the plan that ends closest to it."""
    task = make_task("glider")
    x = np.array([-0.38, 0.08, 1.46, -0.7, 2.48, 0.16, 1.61])
    hard = LimitedLookaheadMPC(task, None, 10, MPCOptions(jit=False, final_soft_weight=0))
    assert hard.final_soft_weight is None and hard.final_solver == "fatrop"
    _, info = hard.act(x, 0.25)
    assert info.phase == "final" and not info.success and info.source != "solver"
    soft = LimitedLookaheadMPC(task, None, 10, MPCOptions(jit=False))
    assert soft.final_soft_weight == task.profile.mpc.final_soft_weight == 1e4 and soft.final_solver == "ipopt"
    u, info = soft.act(x, 0.25)
    assert info.phase == "final" and info.success and info.source == "solver", info.status
    assert np.all(np.abs(u) <= task.u_high)
    with pytest.raises(ValueError, match="final_soft_weight must be a finite number >= 0"):
        LimitedLookaheadMPC(task, None, 10, MPCOptions(jit=False, final_soft_weight=-1.0))
    with pytest.raises(ValueError, match="final_solver must be"):
        LimitedLookaheadMPC(task, None, 10, MPCOptions(jit=False, final_solver="snopt"))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="final_soft_weight needs final_solver='ipopt'"):
        LimitedLookaheadMPC(task, None, 10, MPCOptions(jit=False, final_solver="fatrop", final_soft_weight=1e4))
    # The free-time MPC's final phase (one problem for every remaining time) takes the same soft box.
    free = LimitedLookaheadMPC(task, None, 10, MPCOptions(jit=False, steps="free"))
    assert free._final is not None and free._final.trans.soft_bounds_weight == 1e4
    _, info = free.act(x, 0.25)
    assert info.phase == "final" and info.success, info.status
    free_hard = LimitedLookaheadMPC(task, None, 10, MPCOptions(jit=False, steps="free", final_soft_weight=0))
    assert free_hard._final is not None and free_hard._final.trans.soft_bounds_weight is None


def test_the_final_phase_plans_with_l_f_only_and_leaves_the_network_out_of_its_nlp() -> None:
    """At the episode's end the learned term is switched off (s = 0); the final-phase problems are built with the
    plain ``l_f`` terminal cost, so their NLP (and its compiled code) carries no network: the same action as an MPC
    without a network, and no dependence on the network's weights."""
    import casadi as ca

    pytest.importorskip("torch")
    from seagul_learn.value_network import ValueNetwork

    task = make_task("glider")
    x = np.array([-0.38, 0.08, 1.46, -0.7, 2.48, 0.16, 1.61])
    net = ValueNetwork(7, (8,), task_name="glider", seed=0)
    learned = LimitedLookaheadMPC(task, net, 10, MPCOptions(jit=False))
    plain = LimitedLookaheadMPC(task, None, 10, MPCOptions(jit=False))
    u_learned, info = learned.act(x, 0.2)
    u_plain, _ = plain.act(x, 0.2)
    assert info.phase == "final" and info.success
    np.testing.assert_allclose(u_learned, u_plain, atol=1e-6)
    fn = learned._final_fixed[8].trans.terminal_cost
    xs, ts, th = ca.SX.sym("x", 7), ca.SX.sym("t"), ca.SX.sym("th", learned._theta.size)
    assert not ca.depends_on(fn(xs, ts, th), th)
    assert float(fn(x, 0.0, np.ones(learned._theta.size))) == pytest.approx(task.terminal_cost_value(x))
