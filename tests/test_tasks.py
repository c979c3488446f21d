"""Task registry errors and the acrobot's terminal weight (the checks every task passes, its shapes, sets, derivatives
and env, are the conformance battery's, tests/test_conformance.py; dynamics against independent references are in
tests/test_dynamics.py)."""

import numpy as np
import pytest

from seagul_envs import make_task

ALL_TASKS = r"\['acrobot', 'dmc_acrobot', 'dmc_cartpole', 'dmc_pendulum', 'glider'\]"
"""The message's list of every registered task (the built-ins, the suite's tasks included)."""


def test_unknown_task_lists_available():
    with pytest.raises(ValueError, match=r"available tasks: " + ALL_TASKS):
        make_task("pendulum")


@pytest.mark.parametrize("bad", [np.zeros(3), np.full(4, np.nan), [[0, 0, 0, 0]]])
def test_check_state_rejects(bad):
    with pytest.raises(ValueError, match="acrobot: state"):
        make_task("acrobot").check_state(bad)


def test_check_tau_range():
    glider = make_task("glider")
    assert glider.check_tau(0.8) == 0.8
    with pytest.raises(ValueError, match="outside the task's range"):
        glider.check_tau(1.0)
    with pytest.raises(ValueError, match="finite"):
        glider.check_tau(float("nan"))


def test_acrobot_qf_is_dare_solution():
    """Qf is the fixed point of the discrete Riccati recursion for the task's own RK4 discretisation."""
    import casadi as ca

    task = make_task("acrobot")
    h = task.tau_nominal / task.num_steps
    x, u = ca.SX.sym("x", 4), ca.SX.sym("u", 1)
    xn = task.rk4_step()(x, u, h)
    A = np.asarray(ca.Function("a", [x, u], [ca.jacobian(xn, x)])(task.goal, 0.0))
    B = np.asarray(ca.Function("b", [x, u], [ca.jacobian(xn, u)])(task.goal, 0.0))
    Q, R, P = h * task.extras["Q"], h * task.extras["R"], task.extras["Qf"]
    K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
    riccati = Q + A.T @ P @ A - A.T @ P @ B @ K
    np.testing.assert_allclose(riccati, P, rtol=1e-8, atol=1e-8)
    assert np.all(np.linalg.eigvalsh(P) > 0)
