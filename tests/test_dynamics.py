"""Dynamics of the envs against independent references (written here from docs/reference/spec.md and first principles).

* Acrobot: a numpy model derived from the Lagrangian (link kinematics -> M(q) = sum m J'J + I, Christoffel symbols
  and gravity by complex-step differentiation), not the manipulator-form formulas the Task types in; energy
  conservation with damping and input off; the power balance with them on; one control step against a tight
  ``solve_ivp`` reference; the MJCF's mass matrix, bias and control step against the analytic model.
* Glider: docs/reference/spec.md §4.2's equations retyped in numpy, and physical sanity (free fall at zero airspeed,
  pitch moment signs of the elevator and the wing).
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from seagul_envs import make_task
from seagul_envs.envs.acrobot import AcrobotEnv
from seagul_envs.envs.acrobot_mujoco import AcrobotMujocoEnv
from seagul_envs.envs.glider import GliderEnv
from seagul_envs.tasks.acrobot import AcrobotParams, make_acrobot_task


# ----------------------------------------------------------------------------------------------- acrobot reference
class LagrangianAcrobot:
    """Acrobot equations of motion from its Lagrangian (th1 from the downward vertical, th2 relative)."""

    def __init__(self, p: AcrobotParams) -> None:
        self.p = p

    def com_jacobians(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Jacobians of the link COM positions ``(horizontal, up)`` w.r.t. ``q`` (complex-safe)."""
        p = self.p
        a, b = q[0], q[0] + q[1]
        # p1 = lc1 (sin a, -cos a); p2 = l1 (sin a, -cos a) + lc2 (sin b, -cos b)
        J1 = np.array([[p.lc1 * np.cos(a), 0 * a], [p.lc1 * np.sin(a), 0 * a]])
        J2 = np.array(
            [
                [p.l1 * np.cos(a) + p.lc2 * np.cos(b), p.lc2 * np.cos(b)],
                [p.l1 * np.sin(a) + p.lc2 * np.sin(b), p.lc2 * np.sin(b)],
            ]
        )
        return J1, J2

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        """``T = 1/2 dq' M dq`` with translational and rotational (about each COM) kinetic energy."""
        p = self.p
        J1, J2 = self.com_jacobians(q)
        w1, w2 = np.array([1.0, 0.0]), np.array([1.0, 1.0])  # link angular velocities per unit dq
        return p.m1 * J1.T @ J1 + p.Ic1 * np.outer(w1, w1) + p.m2 * J2.T @ J2 + p.Ic2 * np.outer(w2, w2)

    def potential(self, q: np.ndarray) -> np.ndarray:
        p = self.p
        a, b = q[0], q[0] + q[1]
        return p.g * (p.m1 * (-p.lc1 * np.cos(a)) + p.m2 * (-p.l1 * np.cos(a) - p.lc2 * np.cos(b)))

    @staticmethod
    def _cstep(fun, q: np.ndarray, i: int) -> np.ndarray:
        """Complex-step derivative of ``fun`` w.r.t. ``q[i]`` (exact to rounding, no subtraction error)."""
        dq = np.zeros(2, dtype=complex)
        dq[i] = 1e-30j
        return np.imag(fun(q + dq)) / 1e-30

    def bias(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """Everything but ``M ddq`` and ``B u``: Coriolis/centrifugal - gravity + damping."""
        p = self.p
        dM = [self._cstep(self.mass_matrix, q, k) for k in range(2)]  # dM/dq_k
        coriolis = np.zeros(2)
        for i in range(2):
            for j in range(2):
                for k in range(2):
                    christoffel = 0.5 * (dM[k][i, j] + dM[j][i, k] - dM[i][j, k])
                    coriolis[i] += christoffel * dq[j] * dq[k]
        tau_g = -np.array([self._cstep(self.potential, q, i) for i in range(2)])
        return coriolis - tau_g + np.array([p.b1, p.b2]) * dq

    def f(self, x: np.ndarray, u: float) -> np.ndarray:
        q, dq = x[:2], x[2:]
        ddq = np.linalg.solve(self.mass_matrix(q), np.array([0.0, u]) - self.bias(q, dq))
        return np.concatenate([dq, ddq])

    def energy(self, x: np.ndarray) -> float:
        q, dq = x[:2], x[2:]
        return float(0.5 * dq @ self.mass_matrix(q) @ dq + self.potential(q))


def _random_states(rng: np.random.Generator, n: int) -> np.ndarray:
    return np.column_stack([rng.uniform(-7, 7, (n, 2)), rng.uniform(-12, 12, (n, 2))])


def _reference_step(model: LagrangianAcrobot, x0: np.ndarray, u: float, h: float) -> np.ndarray:
    sol = solve_ivp(lambda _t, x: model.f(x, u), (0.0, h), x0, method="DOP853", rtol=1e-12, atol=1e-12)
    assert sol.success
    return sol.y[:, -1]


def test_acrobot_dynamics_match_lagrangian() -> None:
    task = make_task("acrobot")
    ref = LagrangianAcrobot(task.params)
    rng = np.random.default_rng(0)
    for x in _random_states(rng, 50):
        u = rng.uniform(-20, 20)
        ours = np.asarray(task.dynamics(x, u)).ravel()
        np.testing.assert_allclose(ours, ref.f(x, u), rtol=1e-11, atol=1e-10)


def _moderate_states(rng: np.random.Generator, n: int, speed: float = 6.0) -> np.ndarray:
    return np.column_stack([rng.uniform(-np.pi, np.pi, (n, 2)), rng.uniform(-speed, speed, (n, 2))])


def test_acrobot_energy_conserved_without_damping_and_input() -> None:
    """With b = 0 and u = 0 the total energy is constant: any sign error in M, C or gravity breaks this."""
    task = make_acrobot_task(AcrobotParams(b1=0.0, b2=0.0))
    ref = LagrangianAcrobot(task.params)
    zero = np.zeros(1)
    starts = ([np.pi / 2, 0.5, 0.0, 0.0], [0.3, -0.4, 1.0, -2.0])
    # The model itself, integrated tightly: energy constant to ~1e-8 J over 3 s.
    for x0 in starts:
        f = lambda _t, x: np.asarray(task.dynamics(x, zero)).ravel()  # noqa: E731
        sol = solve_ivp(f, (0.0, 3.0), x0, method="DOP853", rtol=1e-13, atol=1e-13, t_eval=np.linspace(0, 3, 31))
        drift = max(abs(ref.energy(x) - ref.energy(np.asarray(x0))) for x in sol.y.T)
        assert drift < 1e-8, f"model energy drift {drift:.2e} J"
    # The env's own integration (fine substeps): the same within 1e-8 J over 5 s, and the default within 1e-5 J.
    for max_substep, tol in ((0.001, 1e-8), (None, 1e-5)):
        env = AcrobotEnv(task=task, max_substep=max_substep)
        for x0 in starts:
            _, info = env.reset(options={"state": x0})
            e0 = ref.energy(info["state"])
            for _ in range(50):  # 5 s
                _, _, _, truncated, info = env.step(np.zeros(1, np.float32))
                assert abs(ref.energy(info["state"]) - e0) < tol
            assert truncated
    # The check has teeth: with damping on, energy visibly leaves the system over the same 5 s.
    env = AcrobotEnv()
    _, info = env.reset(options={"state": starts[0]})
    e0 = ref.energy(info["state"])
    for _ in range(50):
        _, _, _, _, info = env.step(np.zeros(1, np.float32))
    assert ref.energy(info["state"]) < e0 - 0.1


def test_acrobot_power_balance_with_damping_and_input() -> None:
    """dE/dt = u dth2 - b1 dth1^2 - b2 dth2^2: the signs of the input and of the damping."""
    p = make_task("acrobot").params
    ref = LagrangianAcrobot(p)
    env = AcrobotEnv(max_substep=0.001)
    rng = np.random.default_rng(1)
    for x0 in _moderate_states(rng, 6, speed=4.0):
        u = float(np.float32(rng.uniform(-20, 20)))

        def rhs(_t: float, z: np.ndarray, u: float = u) -> np.ndarray:
            x = z[:4]
            power = u * x[3] - p.b1 * x[2] ** 2 - p.b2 * x[3] ** 2
            return np.concatenate([ref.f(x, u), [power]])

        sol = solve_ivp(rhs, (0.0, 0.1), np.concatenate([x0, [0.0]]), method="DOP853", rtol=1e-12, atol=1e-12)
        work = sol.y[4, -1]
        env.reset(options={"state": x0})
        _, _, _, _, info = env.step(np.array([u], np.float32))
        assert ref.energy(info["state"]) - ref.energy(x0) == pytest.approx(work, abs=1e-7)
        assert abs(work) > 1e-2  # the check has teeth: work is done in this step


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_acrobot_control_step_matches_fine_reference(seed: int) -> None:
    """Default env (5 ms RK4 substeps): ~1e-6 over a 0.1 s step from the task's states and speeds up to 6 rad/s.

    The error grows with speed (u = 20 N m can reach 12 rad/s within the step), hence the small relative part.
    """
    task = make_task("acrobot")
    ref = LagrangianAcrobot(task.params)
    env = AcrobotEnv()
    rng = np.random.default_rng(seed)
    for x0 in [*_moderate_states(rng, 4), task.sample_x0(rng)]:
        u = rng.uniform(-20, 20)
        env.reset(options={"state": x0})
        _, _, _, _, info = env.step(np.array([u]))
        np.testing.assert_allclose(info["state"], _reference_step(ref, x0, u, 0.1), rtol=5e-7, atol=1e-6)


def test_shortened_last_step_matches_fine_reference() -> None:
    """tau = 0.25 s with dt = 0.1 s: steps of 0.1, 0.1 and 0.05 s, the last through the variable-step kernel."""
    ref = LagrangianAcrobot(make_task("acrobot").params)
    env = AcrobotEnv()
    x = np.array([2.5, 0.3, 1.0, -1.0])
    env.reset(options={"state": x, "time_to_go": 0.25})
    for h, u in ((0.1, 5.0), (0.1, -3.0), (0.05, 7.0)):
        x = _reference_step(ref, x, u, h)
        _, _, _, truncated, info = env.step(np.array([u]))
        np.testing.assert_allclose(info["state"], x, atol=1e-6)
    assert truncated


def test_acrobot_fast_states_need_finer_substeps() -> None:
    """At 10-12 rad/s 5 ms substeps are off by ~1e-4; ``max_substep=1 ms`` restores ~1e-6 (RK4: error ~ h^4)."""
    ref = LagrangianAcrobot(make_task("acrobot").params)
    coarse, fine = AcrobotEnv(), AcrobotEnv(max_substep=0.001)
    rng = np.random.default_rng(7)
    worst_coarse = 0.0
    for x0 in _moderate_states(rng, 6, speed=12.0):
        x0[2:] = np.sign(x0[2:]) * np.maximum(np.abs(x0[2:]), 10.0)
        u = rng.uniform(-20, 20)
        reference = _reference_step(ref, x0, u, 0.1)
        for env in (coarse, fine):
            env.reset(options={"state": x0})
        worst_coarse = max(worst_coarse, np.abs(coarse.step(np.array([u]))[4]["state"] - reference).max())
        np.testing.assert_allclose(fine.step(np.array([u]))[4]["state"], reference, rtol=0, atol=2e-6)
    assert worst_coarse > 1e-6  # documents why the option exists (and that the reference can tell them apart)


# ------------------------------------------------------------------------------------------------------ MuJoCo
def test_mjcf_recipe() -> None:
    """The MJCF choices of docs/reference/spec.md §3.7: RK4, no contacts, an elbow motor with gear 1 and +-20 N m,
    damping b, massless geoms."""
    model = AcrobotMujocoEnv().model
    p = make_task("acrobot").params
    assert model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4
    assert model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CONTACT
    assert model.nu == 1 and model.actuator_gear[0, 0] == 1.0 and model.actuator_ctrllimited[0]
    np.testing.assert_array_equal(model.actuator_ctrlrange[0], [-p.u_max, p.u_max])
    assert model.actuator_trnid[0, 0] == mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "elbow")
    np.testing.assert_array_equal(model.dof_damping, [p.b1, p.b2])
    np.testing.assert_array_equal(model.body_mass[1:], [p.m1, p.m2])
    np.testing.assert_array_equal(model.jnt_axis, [[0, -1, 0], [0, -1, 0]])


def _mujoco_mass_and_bias(m: mujoco.MjModel, d: mujoco.MjData, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """MuJoCo's ``M(q)`` and bias forces at the state ``x`` (Coriolis + gravity; its passive damping is -b dq)."""
    d.qpos[:] = x[:2]
    d.qvel[:] = x[2:]
    mujoco.mj_forward(m, d)
    M = np.zeros((2, 2))
    mujoco.mj_fullM(m, d, M)
    return M, d.qfrc_bias - d.qfrc_passive


def test_mujoco_mass_matrix_and_bias_equal_analytic() -> None:
    task = make_task("acrobot")
    ref = LagrangianAcrobot(task.params)
    env = AcrobotMujocoEnv()
    m, d = env.model, env.data
    rng = np.random.default_rng(2)
    worst_M = worst_b = 0.0
    for x in _random_states(rng, 40):
        M, bias = _mujoco_mass_and_bias(m, d, x)
        M_task = np.asarray(task.extras["mass_matrix"](x[:2]))
        bias_task = np.asarray(task.extras["bias"](x[:2], x[2:])).ravel()
        worst_M = max(worst_M, np.abs(M - M_task).max())
        worst_b = max(worst_b, np.abs(bias - bias_task).max())
        np.testing.assert_allclose(M, ref.mass_matrix(x[:2]), atol=1e-9)
        np.testing.assert_allclose(bias, ref.bias(x[:2], x[2:]), atol=1e-9)
    assert worst_M < 1e-9 and worst_b < 1e-9, (worst_M, worst_b)


def test_mujoco_control_step_agrees_with_analytic_env() -> None:
    """Same RK4 substeps (5 ms) on the same equations: the envs agree to rounding; both match the fine reference."""
    ref = LagrangianAcrobot(make_task("acrobot").params)
    analytic, mj = AcrobotEnv(), AcrobotMujocoEnv()
    rng = np.random.default_rng(3)
    worst = 0.0
    for x0 in _random_states(rng, 10):
        u = np.array([rng.uniform(-20, 20)])
        analytic.reset(options={"state": x0})
        mj.reset(options={"state": x0})
        xa = analytic.step(u)[4]["state"]
        xm = mj.step(u)[4]["state"]
        worst = max(worst, np.abs(xa - xm).max())
    assert worst < 1e-9, f"MuJoCo vs analytic control step: {worst:.2e}"
    for x0 in _moderate_states(rng, 5):
        u = rng.uniform(-20, 20)
        mj.reset(options={"state": x0})
        np.testing.assert_allclose(mj.step(np.array([u]))[4]["state"], _reference_step(ref, x0, u, 0.1), atol=2e-6)


def test_mujoco_episode_tracks_analytic_env() -> None:
    analytic, mj = AcrobotEnv(), AcrobotMujocoEnv()
    _, info_a = analytic.reset(seed=4)
    _, info_m = mj.reset(seed=4)
    np.testing.assert_array_equal(info_a["state"], info_m["state"])  # same task, same X0 draw
    rng = np.random.default_rng(4)
    total_a = total_m = 0.0
    for _ in range(50):
        u = rng.uniform(-20, 20, 1)
        _, ra, _, _, ia = analytic.step(u)
        _, rm, _, _, im = mj.step(u)
        total_a += ra
        total_m += rm
    # 5 s of a chaotic system amplifies rounding differences, but they stay far below the physics.
    np.testing.assert_allclose(im["state"], ia["state"], atol=1e-5)
    assert total_m == pytest.approx(total_a, rel=1e-8)


# ------------------------------------------------------------------------------------------------------ glider
def glider_reference(x: np.ndarray, u: float) -> np.ndarray:
    """docs/reference/spec.md §4.2, retyped: flat-plate wing and elevator, F = rho S sin(alpha) |v|^2 normal to each
    plate."""
    S_w, S_e, l_w, l_h, l_e, inertia, mass, g, rho = 0.0885, 0.0147, 0.0, 0.27, 0.022, 0.0015, 0.08, 9.81, 1.204
    _, _, th, phi, dx, dz, dth = x
    speed = lambda vx, vz: np.sqrt(vx * vx + vz * vz + 1e-6)  # noqa: E731 (docs/reference/spec.md §4.2's smoothed |v|)
    vwx, vwz = dx - l_w * dth * np.sin(th), dz + l_w * dth * np.cos(th)
    F_w = rho * S_w * (np.sin(th) * vwx - np.cos(th) * vwz) * speed(vwx, vwz)
    e = th + phi
    vex = dx + l_h * dth * np.sin(th) + l_e * (dth + u) * np.sin(e)
    vez = dz - l_h * dth * np.cos(th) - l_e * (dth + u) * np.cos(e)
    F_e = rho * S_e * (np.sin(e) * vex - np.cos(e) * vez) * speed(vex, vez)
    ddx = -(F_w * np.sin(th) + F_e * np.sin(e)) / mass
    ddz = (F_w * np.cos(th) + F_e * np.cos(e)) / mass - g
    ddth = (F_w * l_w - F_e * (l_h * np.cos(phi) + l_e)) / inertia
    return np.array([dx, dz, dth, u, ddx, ddz, ddth])


def test_glider_dynamics_match_spec() -> None:
    task = make_task("glider")
    rng = np.random.default_rng(5)
    for _ in range(100):
        x = np.concatenate([rng.uniform(-4, 1, 1), rng.uniform(-1, 1, 1), rng.uniform(-1.5, 1.5, 1)])
        x = np.concatenate([x, rng.uniform(-0.9, 0.4, 1), rng.uniform(-2, 8, 1), rng.uniform(-3, 3, 2)])
        u = rng.uniform(-13, 13)
        ours = np.asarray(task.dynamics(x, u)).ravel()
        np.testing.assert_allclose(ours, glider_reference(x, u), rtol=1e-12, atol=1e-9)


def test_glider_physics_sanity() -> None:
    f = make_task("glider").dynamics

    def accel(th: float = 0.0, phi: float = 0.0, dx: float = 0.0, dz: float = 0.0, dth: float = 0.0) -> np.ndarray:
        return np.asarray(f([0, 0, th, phi, dx, dz, dth], 0.0)).ravel()[4:]

    # Still air and no motion: free fall only, whatever the attitude.
    for th, phi in [(0.0, 0.0), (0.7, -0.5), (-1.2, 0.3)]:
        np.testing.assert_allclose(accel(th, phi), [0.0, -9.81, 0.0], atol=1e-9)
    # Level flight at 7 m/s: a flat plate at zero incidence makes no force.
    np.testing.assert_allclose(accel(dx=7.0), [0.0, -9.81, 0.0], atol=1e-9)
    # Elevator leading edge up (phi > 0) lifts the tail: nose-down pitch; phi < 0 pitches the nose up.
    assert accel(phi=0.2, dx=7.0)[2] < -1.0
    assert accel(phi=-0.2, dx=7.0)[2] > 1.0
    # Wing at positive incidence: lift up and drag back (flat plate, force normal to the wing).
    ddx, ddz, _ = accel(th=0.3, dx=7.0)
    assert ddz > -9.81 + 1.0 and ddx < -0.1
    # Pitch rate is damped by the tail (the elevator's velocity from dth opposes the rotation).
    assert accel(dx=7.0, dth=2.0)[2] < 0.0 < accel(dx=7.0, dth=-2.0)[2]


def test_glider_control_step_matches_fine_reference() -> None:
    env = GliderEnv()
    rng = np.random.default_rng(6)
    for _ in range(4):
        _, info = env.reset(seed=int(rng.integers(1 << 30)))
        x0 = info["state"]
        u = rng.uniform(-5, 5)
        sol = solve_ivp(
            lambda _t, x, u=u: glider_reference(x, u), (0, env.dt), x0, method="DOP853", rtol=1e-12, atol=1e-12
        )
        _, _, _, _, info = env.step(np.array([u]))
        np.testing.assert_allclose(info["state"], sol.y[:, -1], atol=1e-6)


# ------------------------------------------------------------------------------------ another robot (params)
ROBOT = {"m1": 1.15, "m2": 0.85, "l1": 1.1, "lc2": 0.9, "b1": 0.18, "b2": 0.06}  # inside Theta, every entry moved


def test_mujoco_model_rebuilt_with_other_parameters_equals_the_analytic_model() -> None:
    """``params`` are written into the MJCF model: at a robot that is not the nominal one MuJoCo's mass matrix and
    bias equal the retyped Lagrangian reference and the task's own extras at those parameters."""
    robot = make_task("acrobot").with_params(ROBOT)
    ref = LagrangianAcrobot(robot.params)
    env = AcrobotMujocoEnv(params=ROBOT)
    m, d = env.model, env.data
    assert env.params == pytest.approx(ROBOT)
    rng = np.random.default_rng(5)
    for x in _random_states(rng, 20):
        M, bias = _mujoco_mass_and_bias(m, d, x)
        np.testing.assert_allclose(M, ref.mass_matrix(x[:2]), atol=1e-9)
        np.testing.assert_allclose(bias, ref.bias(x[:2], x[2:]), atol=1e-9)
        np.testing.assert_allclose(M, np.asarray(robot.extras["mass_matrix"](x[:2])), atol=1e-9)
    # And the nominal model is not that robot (the parameters reached MuJoCo).
    nominal = AcrobotMujocoEnv()
    mujoco.mj_forward(nominal.model, nominal.data)
    assert not np.isclose(nominal.model.body_mass[1], m.body_mass[1])


def test_envs_with_params_simulate_the_rebuilt_task_and_randomise_per_episode() -> None:
    import pickle

    import gymnasium as gym

    robot = make_task("acrobot").with_params(ROBOT)
    sim = robot.simulator(0.1)
    analytic, mj = AcrobotEnv(params=ROBOT), gym.make("SeagulAcrobotMujoco-v0", params=ROBOT).unwrapped
    x0 = np.array([np.pi - 0.2, 0.1, 0.3, -0.2])
    analytic.reset(options={"state": x0, "time_to_go": 1.05})  # a shortened last step: the variable-h kernel
    mj.reset(options={"state": x0, "time_to_go": 1.05})
    x = x0.copy()
    for k in range(11):
        u = np.array([8.0 * np.sin(k)])
        # Ten full periods, then the 50 ms rest with the period's 20 RK4 substeps (as the env's variable-h kernel).
        x = np.asarray(sim(x, u) if k < 10 else robot.rk4_step(20)(x, u, 0.05)).ravel()
        xa = analytic.step(u)[4]["state"]
        xm = mj.step(u)[4]["state"]
        np.testing.assert_allclose(xa, x, rtol=1e-12, atol=1e-12)
        # MuJoCo's short step takes 10 steps of 5 ms where the analytic env keeps 20 substeps: RK4 error apart.
        np.testing.assert_allclose(xm, xa, atol=1e-9 if k < 10 else 1e-5)
    nominal = AcrobotEnv()
    nominal.reset(options={"state": x0})
    analytic.reset(options={"state": x0})
    u = np.array([8.0])
    assert np.abs(nominal.step(u)[4]["state"] - analytic.step(u)[4]["state"]).max() > 1e-3  # another robot
    # Domain randomisation: a mapping is relative to the model ({} is the model itself); bad params change nothing.
    env = gym.make("SeagulAcrobot-v0")
    env.reset(options={"params": {"b1": 0.2}})
    assert env.unwrapped.params["b1"] == 0.2 and env.unwrapped.params["m2"] == 1.0
    env.reset(options={"params": {"m2": 1.1}})
    assert env.unwrapped.params["b1"] == 0.1 and env.unwrapped.params["m2"] == 1.1
    with pytest.raises(ValueError, match=r"unknown parameter\(s\) \['mass'\]"):
        env.reset(options={"params": {"mass": 2.0}})
    assert env.unwrapped.params["m2"] == 1.1
    env.reset(options={"params": {}})
    assert env.unwrapped.task is env.unwrapped.model_task
    kernels = dict(env.unwrapped._kernels)  # one model kernel and one parametric kernel, built once
    for params in ({"m1": 0.9}, {}, {"m1": 1.1}, {}):
        env.reset(options={"params": params})
    assert env.unwrapped._kernels == kernels and len(kernels) == 2
    theta = make_task("acrobot").parameters.sample(np.random.default_rng(0))
    env.reset(options={"params": theta})
    np.testing.assert_array_equal(env.unwrapped.task.theta, theta)
    clone = pickle.loads(pickle.dumps(AcrobotEnv(params=ROBOT)))
    assert clone.params == pytest.approx(ROBOT) and clone.model_task is make_task("acrobot")
    glider = gym.make("SeagulGlider-v0", params={"m": 0.09}).unwrapped
    assert glider.params["m"] == 0.09 and glider.model_task.params.m == 0.08
