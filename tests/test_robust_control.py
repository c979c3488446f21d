"""The learned MPC over robots: planning for another robot without a rebuild."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from seagul_control.estimation import ParameterEstimator
from seagul_control.mpc import LimitedLookaheadMPC, MPCOptions
from seagul_envs import make_task
from seagul_learn.value_network import ValueNetwork

TASK = make_task("acrobot")
X = np.array([np.pi - 0.2, 0.15, 0.1, -0.2])
NO_JIT = MPCOptions(jit=False)
"""The MPCs of these tests run CasADi's virtual machine: nothing to compile for a few solves."""


def _network() -> ValueNetwork:
    net = ValueNetwork(TASK.nx, (8,), seed=3, n_params=TASK.parameters.size, theta=TASK.theta, task_name="acrobot")
    rng = np.random.default_rng(0)
    xs = TASK.sample_x0(rng, 64)
    thetas = TASK.parameters.sample(rng, 64)
    net.set_normalization(xs, np.full(64, 5.0), rng.uniform(0, 30, 64), thetas)
    return net


def test_set_robot_plans_like_an_mpc_built_for_that_robot_and_leaves_the_callers_network_alone():
    net = _network()
    theta = TASK.parameters.low + 0.8 * (TASK.parameters.high - TASK.parameters.low)
    options = MPCOptions(jit=False, solver="ipopt", tol=1e-10, max_iter=200)
    shared = LimitedLookaheadMPC(TASK, net, 5, options, trust_region="none", model_params=True)
    u_nominal, info = shared.act(X, 5.0)
    assert info.success
    shared.set_robot(theta)
    np.testing.assert_array_equal(shared.robot, theta)
    shared.reset()
    u_robot, info = shared.act(X, 5.0)
    assert info.success
    rebuilt = LimitedLookaheadMPC(
        TASK.with_params(theta), net, 5, options, trust_region="none"
    )  # conditioned on its task's robot
    u_ref, _ = rebuilt.act(X, 5.0)
    np.testing.assert_allclose(u_robot, u_ref, atol=1e-6)
    assert abs(float(u_robot[0] - u_nominal[0])) > 1e-3  # another robot, another action
    np.testing.assert_array_equal(net.theta, TASK.theta)  # the caller's network keeps its condition
    assert shared.terminal_cost_value(X, 4.5) == pytest.approx(rebuilt.terminal_cost_value(X, 4.5), rel=1e-9)
    shared.set_robot(None)
    shared.reset()
    np.testing.assert_allclose(shared.act(X, 5.0)[0], u_nominal, atol=1e-6)


def test_set_robot_needs_parameters_to_plan_with():
    plain = LimitedLookaheadMPC(TASK, None, 5, NO_JIT)
    with pytest.raises(ValueError, match="set_robot needs"):
        plain.set_robot(TASK.theta)
    with pytest.raises(ValueError, match="model_params=True needs a task"):
        LimitedLookaheadMPC(dataclasses.replace(TASK, parameters=None), None, 5, NO_JIT, model_params=True)
    mpc = LimitedLookaheadMPC(TASK, None, 5, NO_JIT, model_params=True)
    with pytest.raises(ValueError, match="unknown parameter"):
        mpc.set_robot({"mass": 1.0})


def _transitions(theta: np.ndarray, n: int, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """``n`` transitions of the robot ``theta`` in the task's own simulator, under random torques."""
    robot = TASK.with_params(theta)
    sim = robot.simulator(TASK.control_period)
    rng = np.random.default_rng(seed)
    x, out = X.copy(), []
    for _ in range(n):
        u = rng.uniform(TASK.u_low, TASK.u_high)
        nxt = np.asarray(sim(x, u)).ravel()
        out.append((x, u, nxt))
        x = nxt
    return out


def test_the_estimator_recovers_a_robot_from_its_transitions_and_resets_to_the_model():
    space = TASK.parameters
    theta = space.low + np.array([0.8, 0.3, 0.6, 0.2, 0.9, 0.1]) * (space.high - space.low)
    est = ParameterEstimator(TASK, window=20, iterations=5, prior=1e-6)
    np.testing.assert_array_equal(est.theta, TASK.theta)
    data = _transitions(theta, 20)
    for x, u, nxt in data:
        est.update(x, u, nxt)
    assert est.residual(est.theta) < 1e-6 * est.residual(TASK.theta)
    np.testing.assert_allclose(est.theta, theta, atol=0.02 * float(np.max(space.high - space.low)))
    assert np.all(est.theta >= space.low) and np.all(est.theta <= space.high)
    est.reset()
    assert len(est) == 0
    np.testing.assert_array_equal(est.theta, TASK.theta)
    with pytest.raises(ValueError, match="prior must be a positive number"):
        ParameterEstimator(TASK, prior=0.0)


def test_the_estimators_default_prior_is_the_tasks():
    """``prior=None`` takes ``ParameterSpace.estimator_prior``: 1e-3 by default, the glider's 1e-5; a given prior
    wins, and a space with a non-positive one is refused by its checks."""
    import dataclasses

    from seagul_envs import make_task

    glider = make_task("glider")
    assert ParameterEstimator(TASK, codegen=False).prior == TASK.parameters.estimator_prior == 1e-3
    assert ParameterEstimator(glider, codegen=False).prior == glider.parameters.estimator_prior == 1e-5
    assert ParameterEstimator(glider, prior=0.01, codegen=False).prior == 0.01
    bad = dataclasses.replace(glider.parameters, estimator_prior=-1.0)
    assert any("estimator_prior" in p for p in bad.problems(glider.params, glider.nx, glider.nu))


def test_the_estimators_default_wait_is_the_tasks():
    """``min_transitions=None`` takes ``ParameterSpace.estimator_min_transitions``: the acrobot's estimate stays at
    the model for two transitions and moves at the third, the glider's moves at the first; a given count wins, and a
    space with a count below one is refused by its checks."""
    import dataclasses

    from seagul_envs import make_task

    glider = make_task("glider")
    assert ParameterEstimator(TASK, codegen=False).min_transitions == TASK.parameters.estimator_min_transitions == 3
    est = ParameterEstimator(glider, codegen=False)
    assert est.min_transitions == glider.parameters.estimator_min_transitions == 1
    assert ParameterEstimator(glider, min_transitions=4, codegen=False).min_transitions == 4
    space = glider.parameters
    theta = space.low + np.array([0.9, 0.1, 0.8, 0.2]) * (space.high - space.low)
    x, u = np.asarray(glider.x0_low + glider.x0_high, dtype=float) / 2, np.array([0.1])
    x_next = np.asarray(est._f(x, u, theta)[0]).ravel()
    assert np.max(np.abs(est.update(x, u, x_next) - glider.theta)) > 0
    acro = ParameterEstimator(TASK, codegen=False)
    robot = TASK.parameters.low + 0.8 * (TASK.parameters.high - TASK.parameters.low)
    for k, (x, u, nxt) in enumerate(_transitions(robot, 3)):
        moved = np.max(np.abs(acro.update(x, u, nxt) - TASK.theta)) > 0
        assert moved == (k == 2), k
    for bad_count in (0, 1.5, True):
        bad = dataclasses.replace(space, estimator_min_transitions=bad_count)
        assert any("estimator_min_transitions" in p for p in bad.problems(glider.params, glider.nx, glider.nu))


def test_the_estimate_survives_a_balance_at_rest_that_says_nothing_about_the_robot():
    """A swing determines theta; then the robot rests upright (x_next = x for every theta). The default window
    keeps the swing, so the estimate stays at the truth; a window that forgets it lets the prior pull the
    undetermined parameters back to the model's (the failure the default avoids)."""
    space = TASK.parameters
    theta = space.low + np.array([0.9, 0.2, 0.7, 0.15, 0.85, 0.1]) * (space.high - space.low)
    upright = np.asarray(TASK.goal, dtype=float)
    rest = [(upright, np.zeros(TASK.nu), upright)] * 40
    width = space.high - space.low
    kept, short = ParameterEstimator(TASK), ParameterEstimator(TASK, window=20)
    for x, u, nxt in _transitions(theta, 20) + rest:
        kept.update(x, u, nxt)
        short.update(x, u, nxt)
    assert np.all(np.abs(kept.theta - theta) < 0.03 * width), (kept.theta - theta) / width
    assert float(np.max(np.abs(short.theta - theta) / width)) > 0.2


def test_a_robot_outside_the_declared_box_is_estimated_where_it_is():
    space = TASK.parameters
    wide = space.scaled(2.0, TASK.theta)
    theta = wide.low + np.array([0.05, 0.95, 0.1, 0.9, 0.97, 0.02]) * (wide.high - wide.low)
    assert np.any(theta < space.low) and np.any(theta > space.high)
    free, confined = ParameterEstimator(TASK, prior=1e-6), ParameterEstimator(TASK, prior=1e-6, box_scale=1.0)
    for x, u, nxt in _transitions(theta, 30):
        free.update(x, u, nxt)
        confined.update(x, u, nxt)
    width = space.high - space.low
    assert np.all(np.abs(free.theta - theta) < 0.03 * width), (free.theta - theta) / width
    assert np.all(confined.theta >= space.low) and np.all(confined.theta <= space.high)
    assert float(np.max(np.abs(confined.theta - theta) / width)) > 0.2


def test_the_compiled_estimator_gives_the_virtual_machines_estimates():
    theta = TASK.parameters.low + 0.3 * (TASK.parameters.high - TASK.parameters.low)
    compiled, vm = ParameterEstimator(TASK), ParameterEstimator(TASK, codegen=False)
    if compiled._f.class_name() != "External":
        pytest.skip("no C compiler: the estimator runs CasADi's virtual machine only")
    assert vm._f.class_name() == "SXFunction"
    for x, u, nxt in _transitions(theta, 12, seed=4):
        np.testing.assert_allclose(compiled.update(x, u, nxt), vm.update(x, u, nxt), rtol=0, atol=1e-9)


def test_an_estimating_mpc_plans_for_its_estimate_and_forgets_it_at_a_new_episode():
    space = TASK.parameters
    theta = space.low + 0.75 * (space.high - space.low)
    mpc = LimitedLookaheadMPC(
        TASK,
        _network(),
        5,
        MPCOptions(jit=False, solver="ipopt"),
        trust_region="none",
        model_params=True,
        estimate_robot=True,
    )
    sim = TASK.with_params(theta).simulator(TASK.control_period)
    x, tau = X.copy(), 5.0
    for _ in range(8):
        u, _ = mpc.act(x, tau)
        x, tau = np.asarray(sim(x, u)).ravel(), tau - TASK.control_period
    moved = mpc.estimate()
    assert np.max(np.abs(moved - theta)) < np.max(np.abs(TASK.theta - theta))  # nearer the truth than the model
    np.testing.assert_array_equal(mpc.robot, moved)
    obs = np.append(x, tau)[None, :]
    mpc.predict(obs, episode_start=np.array([True]))  # a new episode: its first step plans for the model
    np.testing.assert_array_equal(mpc.robot, TASK.theta)
    with pytest.raises(ValueError, match="estimate_robot needs model_params"):
        LimitedLookaheadMPC(TASK, None, 5, NO_JIT, estimate_robot=True)
