"""Physical parameters as inputs: the box Theta, ``Task.with_params``, the parametric NLP and ``dV/dtheta``.

The reference for every parametric quantity is the non-parametric path: the task rebuilt at ``theta``
(``task.with_params``) and solved as any task is. ``grad_theta`` (from the multipliers of one parametric solver) is
checked against central finite differences of those independently solved values.
"""

from __future__ import annotations

import dataclasses

import casadi as ca
import numpy as np
import pytest

from seagul_control.transcription import Transcription
from seagul_control.transcription_options import TranscriptionOptions
from seagul_envs.tasks import make_task, validate_task
from seagul_envs.tasks.parameters import ParameterSpace
from seagul_learn.trajopt import TrajectoryOptimizer

QUIET = {"ipopt.print_level": 0, "print_time": False, "ipopt.tol": 1e-10}


@pytest.mark.parametrize("name", ["acrobot", "glider"])
def test_parametric_dynamics_equal_the_model_at_its_own_and_at_other_parameters(name):
    task = make_task(name)
    space = task.parameters
    assert space is not None and space.size == len(space.names) == len(space.units)
    assert np.all(space.low <= task.theta) and np.all(task.theta <= space.high)
    rng = np.random.default_rng(1)
    other = task.with_params(space.sample(rng))
    validate_task(other)
    for _ in range(5):
        x = task.sample_x0(rng) + rng.normal(0, 0.3, task.nx)
        u = rng.uniform(task.u_low, task.u_high)
        np.testing.assert_allclose(
            np.asarray(space.dynamics(x, u, task.theta)).ravel(), np.asarray(task.dynamics(x, u)).ravel(), rtol=1e-13
        )
        np.testing.assert_allclose(
            np.asarray(space.dynamics(x, u, other.theta)).ravel(),
            np.asarray(other.dynamics(x, u)).ravel(),
            rtol=1e-13,
            atol=1e-13,
        )
    # Another robot moves differently (the parameters matter) and is another task for every cache.
    x = task.sample_x0(rng)
    u = task.u_high * 0.5
    assert not np.allclose(np.asarray(task.dynamics(x, u)), np.asarray(other.dynamics(x, u)))
    assert other.fingerprint() != task.fingerprint()


def test_with_params_records_the_values_keeps_the_objective_and_names_bad_input():
    task = make_task("acrobot")
    heavy = task.with_params({"m2": 1.15, "b1": 0.2})
    assert heavy.params.m2 == 1.15 and heavy.params.b1 == 0.2 and heavy.params.m1 == task.params.m1
    np.testing.assert_array_equal(heavy.theta, [1.0, 1.15, 1.0, 1.0, 0.2, 0.1])
    assert heavy.terminal_cost is task.terminal_cost and heavy.stage_cost is task.stage_cost
    assert heavy.profile is task.profile and heavy.parameters is task.parameters
    np.testing.assert_array_equal(heavy.extras["Qf"], task.extras["Qf"])  # the objective is the nominal one
    # The physics extras follow the robot (the MuJoCo comparison reads them).
    q = np.array([0.3, -0.2])
    m_heavy = np.asarray(heavy.extras["mass_matrix"](q))
    assert not np.allclose(m_heavy, np.asarray(task.extras["mass_matrix"](q)))
    np.testing.assert_array_equal(task.with_params(task.theta).theta, task.theta)
    with pytest.raises(ValueError, match=r"unknown parameter\(s\) \['mass'\]"):
        task.with_params({"mass": 1.0})
    with pytest.raises(ValueError, match=r"shape \(6,\)"):
        task.with_params([1.0, 2.0])
    with pytest.raises(ValueError, match="NaN or inf"):
        task.with_params([1.0, np.nan, 1.0, 1.0, 0.1, 0.1])
    with pytest.raises(ValueError, match="must not be negative"):
        task.with_params({"m1": -1.0})
    with pytest.raises(ValueError, match="outside the box Theta: m1 = 2 kg not in"):
        task.parameters.check([2.0, 1.0, 1.0, 1.0, 0.1, 0.1], "acrobot", inside=True)
    fixed = dataclasses.replace(task, parameters=None)
    with pytest.raises(ValueError, match=r"declares which parameters vary \(Task.parameters\)"):
        fixed.with_params({"m1": 1.0})
    with pytest.raises(ValueError, match="model_params=True needs a task"):
        Transcription(fixed, options=TranscriptionOptions(model_params=True))


def test_validate_task_rejects_parametric_dynamics_that_disagree_with_the_model():
    task = make_task("acrobot")
    space = task.parameters
    assert isinstance(space, ParameterSpace)
    x, u, th = ca.SX.sym("x", 4), ca.SX.sym("u", 1), ca.SX.sym("th", 6)
    off = ca.Function("off", [x, u, th], [space.dynamics(x, u, th) * 1.01])
    with pytest.raises(ValueError, match="must equal dynamics"):
        validate_task(dataclasses.replace(task, parameters=dataclasses.replace(space, dynamics=off)))
    renamed = dataclasses.replace(space, names=("m1", "m2", "l1", "lc2", "b1", "mass"))
    with pytest.raises(ValueError, match="not fields of the task's params"):
        validate_task(dataclasses.replace(task, parameters=renamed))
    with pytest.raises(ValueError, match="params to be a dataclass instance"):
        validate_task(dataclasses.replace(task, params={"m1": 1.0}))
    with pytest.raises(ValueError, match=r"must map \(x\[4\], u\[1\], theta\[6\]\)"):
        validate_task(dataclasses.replace(task, parameters=dataclasses.replace(space, dynamics=task.dynamics)))


def test_one_parametric_transcription_solves_every_robot_like_the_rebuilt_task():
    task = make_task("acrobot")
    x0 = np.array([np.pi - 0.25, 0.2, 0.3, -0.2])
    parametric = Transcription(task, options=TranscriptionOptions(model_params=True, solver_options=QUIET))
    assert parametric.num_parameters == task.nx + 1 + task.parameters.size
    for theta in (task.parameters.low, task.parameters.high):
        sol = parametric.solve(x0, task.tau_nominal, model_params=theta)
        ref = Transcription(task.with_params(theta), options=TranscriptionOptions(solver_options=QUIET)).solve(
            x0, task.tau_nominal
        )
        assert sol.success and ref.success
        assert sol.objective == pytest.approx(ref.objective, rel=1e-8)
        np.testing.assert_allclose(sol.param_sensitivity[: task.nx + 1], ref.param_sensitivity, rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match="model_params must have 6 entries"):
        parametric.solve(x0, task.tau_nominal, model_params=[1.0])
    with pytest.raises(ValueError, match="built without model_params=True"):
        Transcription(task, options=TranscriptionOptions(solver_options=QUIET)).solve(
            x0, task.tau_nominal, model_params=task.theta
        )


def fd_grad_theta(opt, x0, theta, rel_step=1e-4, **solve_kwargs):
    """Central differences of the optimal value over each parameter: ``opt`` (an optimizer with ``model_params``)
    solved at each shifted robot. Only its optimal values enter, never its multipliers, so this is a route to
    ``dV/dtheta`` independent of the one under test; that the parametric problem is the rebuilt task's is checked
    separately (its value at ``theta`` equals the rebuilt task's)."""
    grad = np.zeros(theta.size)
    for i in range(theta.size):
        step = rel_step * abs(theta[i])
        values = []
        for sign in (1.0, -1.0):
            shifted = theta.copy()
            shifted[i] += sign * step
            res = opt.solve(x0, theta=shifted, **solve_kwargs)
            assert res.success, res.status
            values.append(res.value)
        grad[i] = (values[0] - values[1]) / (2 * step)
    return grad


@pytest.mark.parametrize(
    ("name", "x0", "draw"),
    [
        ("acrobot", [np.pi - 0.25, 0.2, 0.3, -0.2], 0.7),
        ("glider", [-3.5, 0.15, 0.0, 0.0, 7.0, 0.0, 0.0], 0.3),
    ],
)
def test_grad_theta_from_the_multipliers_matches_central_finite_differences(name, x0, draw):
    task = make_task(name)
    space = task.parameters
    theta = space.low + draw * (space.high - space.low)  # a robot that is not the model
    opt = TrajectoryOptimizer(task, codegen=False, tol=1e-10, multi_start="never", model_params=True)
    res = opt.solve(x0, theta=theta)
    assert res.success, res.status
    np.testing.assert_array_equal(res.theta, theta)
    assert res.grad_theta is not None and res.grad_theta.shape == (space.size,)
    fd = fd_grad_theta(opt, np.asarray(x0, dtype=float), theta)
    scale = np.maximum(np.abs(fd), 1e-3 * np.max(np.abs(fd)))
    assert np.max(np.abs(res.grad_theta - fd) / scale) < 1e-4, (res.grad_theta, fd)
    # The same robot through the rebuilt task: the same value (the parametric NLP is that problem).
    ref = TrajectoryOptimizer(task.with_params(theta), codegen=False, tol=1e-10, multi_start="never").solve(x0)
    assert res.value == pytest.approx(ref.value, rel=1e-7)


def test_theta_needs_model_params_and_a_well_formed_vector():
    task = make_task("acrobot")
    plain = TrajectoryOptimizer(task, codegen=False)
    assert plain.solve(task.goal).grad_theta is None
    with pytest.raises(ValueError, match="model_params=True"):
        plain.solve(task.goal, theta=task.theta)
    parametric = TrajectoryOptimizer(task, codegen=False, model_params=True)
    with pytest.raises(ValueError, match="unknown parameter"):
        parametric.solve(task.goal, theta={"mass": 2.0})
    res = parametric.solve(task.goal, theta={"m2": 1.1})  # a partial mapping keeps the task's other values
    np.testing.assert_array_equal(res.theta, task.with_params({"m2": 1.1}).theta)


@pytest.mark.parametrize("name", ["acrobot", "glider"])
def test_per_knot_grad_theta_sums_the_tail_and_matches_finite_differences_of_a_tail_solve(name):
    """``knot_grad_theta[k] = sum_{j >= k} lambda_{j+1}' dF_j/dtheta``: row 0 is ``grad_theta`` (from ``lam_p``, an
    independent route), row m is 0, and (acrobot, fixed steps) a mid knot's row equals central differences of the
    tail problem solved from that knot on the rebuilt task."""
    task = make_task(name)
    space = task.parameters
    theta = space.low + 0.7 * (space.high - space.low)
    x0 = [np.pi - 0.25, 0.2, 0.3, -0.2] if name == "acrobot" else [-3.5, 0.15, 0.0, 0.0, 7.0, 0.0, 0.0]
    res = TrajectoryOptimizer(task, codegen=False, tol=1e-10, multi_start="never", model_params=True).solve(
        x0, theta=theta
    )
    assert res.success and res.knot_grad_theta.shape == (res.num_knots, space.size)
    np.testing.assert_allclose(res.knot_grad_theta[0], res.grad_theta, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(res.knot_grad_theta[-1], 0.0)
    if name != "acrobot":
        return
    k = 20
    # the tail problem from knot k on, over robots: central differences of its optimal values
    tail = TrajectoryOptimizer(
        task, codegen=False, tol=1e-10, multi_start="never", horizon=task.num_steps - k, model_params=True
    )
    fd = fd_grad_theta(tail, res.states[k], theta, tau=res.time_to_go[k])
    rebuilt = TrajectoryOptimizer(
        task.with_params(theta), codegen=False, tol=1e-10, multi_start="never", horizon=task.num_steps - k
    )
    assert tail.solve(res.states[k], res.time_to_go[k], theta=theta).value == pytest.approx(
        rebuilt.solve(res.states[k], res.time_to_go[k]).value, rel=1e-7
    )
    np.testing.assert_allclose(res.knot_grad_theta[k], fd, rtol=1e-4, atol=1e-7)


@pytest.mark.parametrize("name", ["acrobot", "glider"])
def test_a_scaled_box_widens_each_side_by_its_ratio_to_the_nominal_value_and_names_bad_input(name):
    task = make_task(name)
    space = task.parameters
    same = space.scaled(1.0, task.theta)
    np.testing.assert_allclose(same.low, space.low)
    np.testing.assert_allclose(same.high, space.high)
    wide, narrow = space.scaled(2.0, task.theta), space.scaled(0.5, task.theta)
    # ratios to the nominal value are squared (2x) or square-rooted (0.5x); the nominal robot stays inside
    np.testing.assert_allclose(wide.low / task.theta, (space.low / task.theta) ** 2)
    np.testing.assert_allclose(narrow.high / task.theta, np.sqrt(space.high / task.theta))
    assert np.all(wide.low < space.low) and np.all(wide.high > space.high) and np.all(wide.low > 0)
    assert np.all(narrow.low > space.low) and np.all(narrow.high < space.high)
    assert wide.names == space.names and wide.dynamics is space.dynamics
    with pytest.raises(ValueError, match="factor must be a positive number"):
        space.scaled(0.0, task.theta)
    with pytest.raises(ValueError, match="outside the box"):
        space.scaled(2.0, space.high * 1.1)
    with pytest.raises(ValueError, match="positive values"):
        space.scaled(2.0, task.theta[:-1])


def test_the_gliders_declared_invariants_are_what_its_dynamics_depend_on():
    """Gliders with equal ``m``, ``rho * S_w`` and ``rho * S_e`` fly identically (the products of
    ``ParameterSpace.invariants``), and changing any one of the products changes the motion."""
    task = make_task("glider")
    space = task.parameters
    assert space is not None and space.invariants is not None
    assert space.problems(task.params, task.nx, task.nu) == []
    exps = np.array(space.feature_exponents())
    assert exps.shape == (space.size, space.size) and np.all(exps[len(space.invariants) :] == 0)
    rng = np.random.default_rng(3)
    for _ in range(5):
        theta = space.sample(rng)
        c = rng.uniform(0.7, 1.4)
        along = theta * np.array([1.0, 1.0 / c, 1.0 / c, c])  # rho up, both areas down: the same products
        np.testing.assert_allclose(np.log(along) @ space.invariants.T, np.log(theta) @ space.invariants.T)
        x = task.sample_x0(rng) + rng.normal(0, 0.3, task.nx)
        u = rng.uniform(task.u_low, task.u_high)
        np.testing.assert_allclose(
            np.asarray(space.dynamics(x, u, along)).ravel(), np.asarray(space.dynamics(x, u, theta)).ravel(), rtol=1e-12
        )
        for j in range(len(space.invariants)):  # each product on its own moves the glider
            other = theta * np.exp(0.1 * np.linalg.pinv(space.invariants)[:, j])
            assert not np.allclose(np.asarray(space.dynamics(x, u, other)), np.asarray(space.dynamics(x, u, theta)))
    bad = dataclasses.replace(space, invariants=np.ones((2, 3)))
    assert any("invariants" in p for p in bad.problems(task.params, task.nx, task.nu))
    with pytest.raises(ValueError, match="declare no invariants"):
        make_task("acrobot").parameters.feature_exponents()


def test_robot_invariants_reach_the_network_and_need_a_task_that_declares_them():
    from seagul_learn.fitting import make_network
    from seagul_learn.training import TrainConfig

    glider = make_task("glider")
    net = make_network(TrainConfig.recipe("glider", "robust-invariants", seed=0), glider)
    assert net.config.theta_features == glider.parameters.feature_exponents()
    np.testing.assert_array_equal(net.theta, glider.theta)
    assert make_network(TrainConfig.recipe("glider", "robust", seed=0), glider).config.theta_features == ()
    config = TrainConfig(model_params=True, network={"robot_invariants": True})
    with pytest.raises(ValueError, match=r"robot_invariants.*acrobot"):
        make_network(config, make_task("acrobot"))
