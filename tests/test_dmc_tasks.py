"""The DeepMind Control Suite tasks (``dmc_pendulum``, ``dmc_cartpole``, ``dmc_acrobot``; seagul_envs.tasks.dmc)
against MuJoCo and dm_control themselves.

For each suite model, loaded by ``dm_control.suite.load`` (the suite's own XML and MuJoCo build):

* the masses, centres of mass and inertias the task derives from the geoms are ``model.body_mass``,
  ``model.body_ipos`` and the y moment of ``model.body_inertia`` (rotated by ``body_iquat``);
* at random states and controls, the task's ``M(q)``, ``qfrc_bias``, ``qfrc_passive`` and ``qacc`` are MuJoCo's
  (``mj_fullM`` and ``mj_forward``) to 1e-9, and ``extras["mujoco_step"]`` is ``n_sub_steps`` calls of ``mj_step``
  to 1e-9 (controls beyond the ctrlrange clamped, as MuJoCo clamps them);
* a dm_control episode (its reset distribution, its ``Physics.step``) is reproduced step by step by
  ``mujoco_step`` from the episode's first state, and each step's reward is the task module's ``dmc_*_reward``;
* the suite's reset states lie in X0; the cart-pole's cost is one minus the suite's reward; costs and dynamics are
  periodic in the angles; seagul's simulator of the RK4 models is MuJoCo's step;
* a cart-pole swing-up planned by the trajectory optimizer is what dm_control's physics flies, knot to knot.

The tasks' own checks (``validate_task``, derivatives, pickling, env, solvers) are the conformance battery's
(tests/test_conformance.py collects every name of ``available_tasks()``).
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
import pytest

pytest.importorskip(
    "dm_control.suite", reason="the suite tasks are checked against dm_control: pip install 'seagul[dmc]'"
)

import mujoco
from dm_control import suite

from seagul_envs import make_task, validate_task
from seagul_envs.tasks.base import Task
from seagul_envs.tasks.dmc import (
    DMC_SUITE_NAMES,
    dmc_acrobot_model,
    dmc_acrobot_reward,
    dmc_cartpole_model,
    dmc_cartpole_reward,
    dmc_pendulum_model,
    dmc_pendulum_reward,
)

NAMES = sorted(DMC_SUITE_NAMES)
TOL = 1e-9
REWARDS = {"dmc_acrobot": dmc_acrobot_reward, "dmc_cartpole": dmc_cartpole_reward, "dmc_pendulum": dmc_pendulum_reward}
MODELS = {"dmc_acrobot": dmc_acrobot_model, "dmc_cartpole": dmc_cartpole_model, "dmc_pendulum": dmc_pendulum_model}
BODIES = {"dmc_acrobot": ("upper_arm", "lower_arm"), "dmc_cartpole": ("cart", "pole_1"), "dmc_pendulum": ("pole",)}


@functools.cache
def _suite(name: str) -> Any:
    domain, task = DMC_SUITE_NAMES[name]
    return suite.load(domain, task, task_kwargs={"random": 0})


def _random_states(task: Task, rng: np.random.Generator, n: int) -> np.ndarray:
    """States with angles over several turns, speeds up to 10 (rad or m)/s, the cart inside its rail."""
    nq = task.nx // 2
    x = np.concatenate([rng.uniform(-7.0, 7.0, (n, nq)), rng.uniform(-10.0, 10.0, (n, nq))], axis=1)
    if task.name == "dmc_cartpole":
        x[:, 0] = rng.uniform(-1.75, 1.75, n)
    return x


def _mujoco_forward(name: str, x: np.ndarray, u: float) -> tuple[Any, Any]:
    physics = _suite(name).physics
    m, d = physics.model.ptr, mujoco.MjData(physics.model.ptr)
    nq = m.nq
    d.qpos[:], d.qvel[:], d.ctrl[:] = x[:nq], x[nq:], u
    mujoco.mj_forward(m, d)
    return m, d


@pytest.mark.parametrize("name", NAMES)
def test_inertials_are_mujocos(name: str) -> None:
    task = make_task(name)
    model = MODELS[name](task.params)
    mj = _suite(name).physics.model.ptr
    for body, name_in_xml in zip(model.bodies, BODIES[name], strict=True):
        b = mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_BODY, name_in_xml)
        R = np.zeros(9)
        mujoco.mju_quat2Mat(R, mj.body_iquat[b])
        R = R.reshape(3, 3)
        inertia = R @ np.diag(mj.body_inertia[b]) @ R.T  # the body frame's inertia tensor about the centre of mass
        assert body.mass == pytest.approx(mj.body_mass[b], abs=1e-15)
        np.testing.assert_allclose(body.com, mj.body_ipos[b][[0, 2]], atol=1e-15)
        assert body.inertia_y == pytest.approx(inertia[1, 1], rel=1e-12)
        np.testing.assert_allclose(body.pos, mj.body_pos[b][[0, 2]], atol=1e-15)
    np.testing.assert_allclose(model.damping, mj.dof_damping, atol=1e-15)
    assert not mj.dof_armature.any() and not mj.dof_frictionloss.any() and not mj.jnt_stiffness.any()
    assert model.gear == mj.actuator_gear[0, 0] and model.ctrl_range == tuple(mj.actuator_ctrlrange[0])
    assert mj.actuator_trnid[0, 0] == model.actuated  # the motor's joint (joints and dofs coincide here)
    assert model.timestep == mj.opt.timestep
    assert (
        model.integrator
        == {mujoco.mjtIntegrator.mjINT_EULER: "Euler", mujoco.mjtIntegrator.mjINT_RK4: "RK4"}[
            mujoco.mjtIntegrator(mj.opt.integrator)
        ]
    )
    np.testing.assert_allclose(mj.opt.gravity, [0.0, 0.0, -model.g])
    assert task.control_period == pytest.approx(_suite(name).control_timestep(), abs=1e-15)


@pytest.mark.parametrize("name", NAMES)
def test_forward_dynamics_equal_mujocos(name: str) -> None:
    task = make_task(name)
    fns = task.extras
    nq = task.nx // 2
    rng = np.random.default_rng(11)
    err = dict.fromkeys(("M", "bias", "passive", "qacc", "xdot"), 0.0)
    for x in _random_states(task, rng, 50):
        u = rng.uniform(-1.0, 1.0)
        m, d = _mujoco_forward(name, x, u)
        M = np.zeros((nq, nq))
        mujoco.mj_fullM(m, d, M)
        q, dq = x[:nq], x[nq:]
        err["M"] = max(err["M"], np.abs(np.asarray(fns["mass_matrix"](q)) - M).max())
        err["bias"] = max(err["bias"], np.abs(np.asarray(fns["bias"](q, dq)).ravel() - d.qfrc_bias).max())
        err["passive"] = max(err["passive"], np.abs(np.asarray(fns["passive"](dq)).ravel() - d.qfrc_passive).max())
        err["qacc"] = max(err["qacc"], np.abs(np.asarray(fns["qacc"](x, u)).ravel() - d.qacc).max())
        xdot = np.asarray(task.dynamics(x, u)).ravel()
        err["xdot"] = max(err["xdot"], np.abs(xdot - np.concatenate([dq, d.qacc])).max())
    print(name, {k: f"{v:.1e}" for k, v in err.items()})
    assert max(err.values()) < TOL, err


@pytest.mark.parametrize("name", NAMES)
def test_mujoco_step_is_mj_step(name: str) -> None:
    task = make_task(name)
    step = task.extras["mujoco_step"]
    n_sub = task.extras["n_sub_steps"]
    rng = np.random.default_rng(12)
    worst = 0.0
    for x in _random_states(task, rng, 50):
        u = rng.uniform(-1.5, 1.5)  # a third beyond the ctrlrange: MuJoCo clamps, so does mujoco_step
        m, d = _mujoco_forward(name, x, u)
        mujoco.mj_step(m, d, n_sub)
        worst = max(worst, np.abs(np.asarray(step(x, u)).ravel() - np.concatenate([d.qpos, d.qvel])).max())
    print(name, f"mujoco_step vs mj_step: {worst:.1e}")
    assert worst < TOL


@pytest.mark.parametrize("name", NAMES)
def test_dm_control_episode_is_reproduced(name: str) -> None:
    """dm_control's own reset and ``Physics.step``: 200 control steps of random actions, each reproduced by
    ``mujoco_step`` from the recorded state, each reward by the task module's reward function."""
    domain, task_name = DMC_SUITE_NAMES[name]
    env = suite.load(domain, task_name, task_kwargs={"random": 5})
    task = make_task(name)
    step, reward = task.extras["mujoco_step"], REWARDS[name]
    rng = np.random.default_rng(13)
    env.reset()
    physics = env.physics
    x = np.concatenate([physics.data.qpos, physics.data.qvel])
    assert task.in_x0(x)
    worst_state = worst_reward = 0.0
    for _ in range(200):
        u = rng.uniform(-1.0, 1.0, 1)
        timestep = env.step(u)
        x_next = np.concatenate([physics.data.qpos, physics.data.qvel])
        worst_state = max(worst_state, np.abs(np.asarray(step(x, u)).ravel() - x_next).max())
        worst_reward = max(worst_reward, abs(reward(task.params, x_next, u) - timestep.reward))
        x = x_next
    print(name, f"episode: state {worst_state:.1e}, reward {worst_reward:.1e}")
    assert worst_state < TOL and worst_reward < TOL


@pytest.mark.parametrize("name", NAMES)
def test_reset_distribution_lies_in_x0(name: str) -> None:
    """The pendulum's and the acrobot's resets always lie in X0 (uniform angles, at rest); the cart-pole's gaussian
    reset (0.01 standard deviations) lies in its +-3 sigma box with probability 0.9973^4 = 98.9 %."""
    domain, task_name = DMC_SUITE_NAMES[name]
    task = make_task(name)
    env = suite.load(domain, task_name, task_kwargs={"random": 6})
    inside = []
    for _ in range(200):
        env.reset()
        x = np.concatenate([env.physics.data.qpos, env.physics.data.qvel])
        inside.append(task.in_x0(x))
        centre, half = (task.x0_high + task.x0_low) / 2, (task.x0_high - task.x0_low) / 2
        assert np.all(np.abs(x - centre) <= 5 / 3 * half + 1e-12), x  # never beyond 5 sigma (p = 6e-7 per draw)
    if name == "dmc_cartpole":
        assert 0.95 <= np.mean(inside) < 1.0
    else:
        assert all(inside)


@pytest.mark.parametrize("name", NAMES)
def test_tasks_are_valid_and_periodic(name: str) -> None:
    task = validate_task(make_task(name))
    assert task.goal_is_equilibrium(cost=True) and task.terminal_cost_value(task.goal) == 0.0
    assert np.isinf(task.x_low[task.nx // 2 :]).all() and np.isinf(task.x_high[task.nx // 2 :]).all()
    angles = [i for i, s in enumerate(task.state_names[: task.nx // 2]) if s != "slider"]
    assert task.periodic == tuple(angles)  # the library wraps them in x - x* (LQR, learned values' features)
    assert all(np.isinf(task.x_low[i]) and np.isinf(task.x_high[i]) for i in angles)
    rng = np.random.default_rng(14)
    for x in _random_states(task, rng, 20):
        u = rng.uniform(-1.0, 1.0, 1)
        turned = x.copy()
        turned[angles] += 2 * np.pi * rng.integers(-3, 4, len(angles))
        np.testing.assert_allclose(task.dynamics(turned, u), task.dynamics(x, u), atol=1e-9)
        assert task.stage_cost_value(turned, u) == pytest.approx(task.stage_cost_value(x, u), abs=1e-9)
        assert task.terminal_cost_value(turned) == pytest.approx(task.terminal_cost_value(x), abs=1e-9)
        assert task.terminal_cost_value(x) > 0.0
    upright_again = task.goal.copy()
    upright_again[angles] = 2 * np.pi
    assert task.profile.is_success(task, upright_again)
    np.testing.assert_allclose(task.state_error(upright_again), 0.0, atol=1e-12)


def test_cartpole_cost_is_one_minus_the_suite_reward() -> None:
    task = make_task("dmc_cartpole")
    rng = np.random.default_rng(15)
    for x in _random_states(task, rng, 50):
        u = rng.uniform(-1.0, 1.0, 1)
        assert task.stage_cost_value(x, u) == pytest.approx(1.0 - dmc_cartpole_reward(task.params, x, u), abs=1e-12)


@pytest.mark.parametrize("name", NAMES)
def test_reward_functions_are_the_suites(name: str) -> None:
    """The task modules' rewards at random states equal the suite task's ``get_reward(physics)``, including the
    pendulum's 8-degree indicator and the acrobot's flat target region, both reached on purpose."""
    env = _suite(name)
    task = make_task(name)
    physics = env.physics
    rng = np.random.default_rng(16)
    states = list(_random_states(task, rng, 40))
    near = [task.goal + rng.normal(0, 0.05, task.nx) for _ in range(10)]
    nq = task.nx // 2
    for x in states + near:
        u = rng.uniform(-1.0, 1.0, 1)
        with physics.reset_context():
            physics.data.qpos[:], physics.data.qvel[:] = x[:nq], x[nq:]
        physics.set_control(u)
        expected = env.task.get_reward(physics)
        assert REWARDS[name](task.params, x, u) == pytest.approx(expected, abs=1e-12)
    assert any(REWARDS[name](task.params, x, np.zeros(1)) == 1.0 for x in near) or name == "dmc_cartpole"


@pytest.mark.parametrize("name", ["dmc_acrobot", "dmc_cartpole"])
def test_simulator_of_the_rk4_models_is_mujocos_step(name: str) -> None:
    """The RK4 models: seagul's simulator (RK4, one substep of the MuJoCo timestep per control period) and the
    transcription's substeps are MuJoCo's own step."""
    task = make_task(name)
    sim = task.simulator(task.control_period)
    rng = np.random.default_rng(17)
    for x in _random_states(task, rng, 20):
        u = rng.uniform(-1.0, 1.0, 1)
        np.testing.assert_allclose(sim(x, u), task.extras["mujoco_step"](x, u), rtol=0, atol=1e-12)


def test_pendulum_simulator_is_within_first_order_of_mujocos_euler() -> None:
    """The pendulum's MuJoCo integrator is semi-implicit Euler; seagul's simulator integrates the same ODE by RK4 at
    the same 0.02 s step. One step differs by O(h^2) in the angle (semi-implicit Euler moves it by ``h^2 qacc``, the
    exact flow by ``h^2 qacc / 2``) and O(h^2) in the speed: 5.2e-3 rad and 3.9e-2 rad/s at most over these states
    (speeds to 10 rad/s, |qacc| to about 28 rad/s^2)."""
    task = make_task("dmc_pendulum")
    sim = task.simulator(task.control_period)
    rng = np.random.default_rng(18)
    diff = np.array(
        [
            np.abs(np.asarray(sim(x, u)).ravel() - np.asarray(task.extras["mujoco_step"](x, u)).ravel())
            for x, u in ((x, rng.uniform(-1, 1, 1)) for x in _random_states(task, rng, 50))
        ]
    ).max(axis=0)
    print(f"pendulum RK4 simulator vs MuJoCo Euler, one step: angle {diff[0]:.1e} rad, speed {diff[1]:.1e} rad/s")
    assert diff[0] < 6e-3 and diff[1] < 5e-2 and diff.min() > 1e-6  # different integrators, not the same one


def test_a_cartpole_plan_is_flown_by_dm_controls_physics() -> None:
    """The cart-pole's transcription integrates each 0.05 s interval by five RK4 substeps of 0.01 s: MuJoCo's own
    step. For a swing-up planned from a suite reset, dm_control's ``Physics.step`` from every knot of the plan with
    the knot's control held for five control steps lands on the next knot up to the solver's defect tolerance, and
    the plan ends where the suite pays its full reward. (Replayed open loop from the start instead, the unstable
    upright amplifies those 1e-8 defects to millimetres within the 4 s.)"""
    from seagul_learn.trajopt import TrajectoryOptimizer

    task = make_task("dmc_cartpole")
    env = suite.load("cartpole", "swingup", task_kwargs={"random": 3})
    env.reset()
    physics = env.physics
    x0 = np.concatenate([physics.data.qpos, physics.data.qvel])
    plan = TrajectoryOptimizer(task, codegen=False, plan=("ipopt:line",), multi_start="never").solve(x0)
    assert plan.success
    hold = round(task.tau_nominal / task.num_steps / task.control_period)
    assert hold == 5 and hold * task.control_period == pytest.approx(plan.steps[0])
    worst = 0.0
    for k, u in enumerate(plan.controls):
        with physics.reset_context():
            physics.data.qpos[:], physics.data.qvel[:] = plan.states[k][:2], plan.states[k][2:]
        physics.set_control(u)
        physics.step(hold)
        x = np.concatenate([physics.data.qpos, physics.data.qvel])
        worst = max(worst, np.abs(x - plan.states[k + 1]).max())
    print(f"cart-pole plan: dm_control's step from each knot lands on the next within {worst:.1e}")
    assert worst < 1e-6
    assert dmc_cartpole_reward(task.params, plan.states[-1], np.zeros(1)) >= task.params.success_reward


def test_the_models_need_no_dm_control() -> None:
    """Building the three tasks imports neither dm_control nor shimmy: a plain install has the tasks, the ``dmc``
    extra is only for scoring and for these checks."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "from seagul_envs import make_task\n"
        "for name in ('dmc_pendulum', 'dmc_cartpole', 'dmc_acrobot'):\n"
        "    make_task(name)\n"
        "print(sorted(m for m in ('dm_control', 'shimmy') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120)
    assert out.stdout.strip().splitlines()[-1] == "[]"
