"""The acrobot swing-up/balance task (docs/reference/spec.md §3).

Model [src: Drake ``AcrobotPlant``/``AcrobotParams``, Underactuated ch. 3]::

    M(q) ddq + C(q, dq) dq = tau_g(q) + B u - b dq,   B = [0, 1]

with ``x = [th1, th2, dth1, dth2]``, ``th1 = 0`` hanging down, ``th2`` the elbow angle relative to link 1, and ``u``
the elbow torque. Goal ``x* = [pi, 0, 0, 0]``.

Choices [choice]:

* ``|u| <= 20 N m``; cost ``l = (x-x*)' Q (x-x*) + R u^2`` with ``Q = diag(1, 1, 0.1, 0.1)``, ``R = 0.01``.
* ``Qf`` is the discrete-time LQR cost-to-go matrix at the goal for the transcription's own discretisation
  (``h = 0.1 s``, RK4, stage weights ``h Q`` and ``h R``), so that near the goal ``V(x, tau)`` is already the
  infinite-horizon quadratic and the terminal cost does not bias the short-horizon MPC.
* ``m = 50`` intervals of ``h = 0.1 s`` (``tau = 5 s``), 4 RK4 substeps per interval: one step per 0.1 s was badly
  wrong at the joint speeds optimal swings reach (~30 rad/s) and the optimizer exploited the error.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np
import scipy.linalg

from seagul_envs.tasks.base import Task, rk4_map
from seagul_envs.tasks.mpc_defaults import MPCDefaults
from seagul_envs.tasks.parameters import ParameterSpace, parametric_dynamics
from seagul_envs.tasks.profile import (
    EvaluationGrid,
    SolverDefaults,
    SuccessRule,
    TaskProfile,
    ValidationSpec,
    with_recipe_book,
)

SUCCESS_DISTANCE = 0.05
"""Success: ``||x(T) - x*||_2 < 0.05`` at the end of an episode (docs/reference/spec.md §3.6)."""

SOLVER_DEFAULTS = SolverDefaults(
    plan=("fatrop:line", "ipopt_fast:line", "ipopt:line", "ipopt:goal"),
    multi_start="on_suspect",
    multi_start_guesses=("line", "goal"),
    suspect_value=30.0,
)
"""The acrobot's attempt plan (measured, docs/experiments/trajopt.md): fatrop is the fastest per iteration but fails
~10 % of
starts (no restoration on its line-search failures); ``ipopt_fast`` (IPOPT accepting every trial step) converges in
~15 iterations; the careful IPOPT with two guesses comes last. Multi-start: over 300 uniform starts 6 labels (2 %)
were poor local optima (34-129, while IPOPT from "the goal everywhere" found 16-35) and only one good label exceeded
30 (30.007; the 95th percentile is 24), so values above 30 trigger a re-solve; it recovered all 6."""


def acrobot_profile(p: AcrobotParams) -> TaskProfile:
    """The acrobot's :class:`TaskProfile` (docs/reference/spec.md §3.6): validation set, success, LQR weights, MPC
    defaults, ..."""
    # Training recipes and experiment presets: seagul_learn/recipes/acrobot.yml
    profile = TaskProfile(
        solver=SOLVER_DEFAULTS,
        # 10 x 10 over (th1, th2) at zero velocity (X0's velocity centre is 0) + 100 uniform 4-D draws.
        validation=ValidationSpec(grid_coords=(0, 1), grid_points=10, num_random=100),
        # The acrobot has no state bounds (an episode never terminates), so termination is not looked at.
        success=SuccessRule(distance=SUCCESS_DISTANCE, fail_on_termination=False),
        success_text=f"||x({p.tau:g} s) - x*|| < {SUCCESS_DISTANCE:g}",
        lqr_Q=np.diag(p.Q),
        lqr_R=np.array([[p.R]]),
        env_id="SeagulAcrobot-v0",
        mpc=MPCDefaults(
            horizon=5,  # paper §6: 5 steps (0.5 s)
            # the shipped networks are selected and measured unguarded: 99.25 % of the grid
            # (docs/experiments/closed-loop.md)
            trust_region="none",
            goal_blend=1.0,  # V = l_f measured while l_f <~ 1 (docs/experiments/closed-loop.md); 11 % -> 74 % unguarded
        ),
        grid=EvaluationGrid(coords=(0, 1), fixed=((2, 0.0), (3, 0.0)), points=20),  # Fig. 2: (th1, th2), at rest
        heatmap_metric="final_distance",
        heatmap_caption=(
            f"Final distance to the goal after {p.tau:g} s over a {{n1}} x {{n2}} grid of ({{dims}}) at zero velocity, "
            "seed-0 networks (Fig. 2)"
        ),
    )
    return with_recipe_book(profile, "acrobot")


@dataclass(frozen=True)
class AcrobotParams:
    """Physical parameters and task constants of the acrobot (one place for every number)."""

    m1: float = 1.0
    """Mass of link 1 (kg)."""
    m2: float = 1.0
    """Mass of link 2 (kg)."""
    l1: float = 1.0
    """Length of link 1 (m)."""
    l2: float = 2.0
    """Length of link 2 (m); only used for rendering."""
    lc1: float = 0.5
    """Shoulder to link-1 centre of mass (m)."""
    lc2: float = 1.0
    """Elbow to link-2 centre of mass (m)."""
    Ic1: float = 0.083
    """Link-1 inertia about its centre of mass (kg m^2)."""
    Ic2: float = 0.33
    """Link-2 inertia about its centre of mass (kg m^2)."""
    b1: float = 0.1
    """Shoulder viscous damping (N m s)."""
    b2: float = 0.1
    """Elbow viscous damping (N m s)."""
    g: float = 9.81
    """Gravity (m/s^2)."""
    u_max: float = 20.0
    """Elbow torque limit (N m)."""
    Q: tuple[float, float, float, float] = (1.0, 1.0, 0.1, 0.1)
    """Diagonal of the running state weight."""
    R: float = 0.01
    """Running input weight."""
    horizon_steps: int = 50
    """Transcription intervals m."""
    tau: float = 5.0
    """Time to go of the full-horizon problem (s)."""
    rk4_substeps: int = 4
    """RK4 substeps per 0.1 s interval."""
    control_period: float = 0.1
    """Control period of the env and the MPC (s)."""
    x0_half_width: tuple[float, float, float, float] = (0.3, 0.3, 0.5, 0.5)
    """X0 = goal +- this box."""


def acrobot_mass_matrix(q: ca.SX, p: AcrobotParams) -> ca.SX:
    """``M(q)`` of the manipulator equation (docs/reference/spec.md §3.2)."""
    c2 = ca.cos(q[1])
    I1 = p.Ic1 + p.m1 * p.lc1**2
    I2 = p.Ic2 + p.m2 * p.lc2**2
    m11 = I1 + I2 + p.m2 * p.l1**2 + 2 * p.m2 * p.l1 * p.lc2 * c2
    m12 = I2 + p.m2 * p.l1 * p.lc2 * c2
    return ca.vertcat(ca.horzcat(m11, m12), ca.horzcat(m12, I2))


def acrobot_bias(q: ca.SX, dq: ca.SX, p: AcrobotParams) -> ca.SX:
    """Bias forces ``C(q, dq) dq - tau_g(q) + b dq`` (everything but ``M ddq`` and ``B u``)."""
    s1, s2 = ca.sin(q[0]), ca.sin(q[1])
    s12 = ca.sin(q[0] + q[1])
    h = p.m2 * p.l1 * p.lc2 * s2
    coriolis = ca.vertcat(-2 * h * dq[1] * dq[0] - h * dq[1] ** 2, h * dq[0] ** 2)
    gravity = ca.vertcat(
        -p.m1 * p.g * p.lc1 * s1 - p.m2 * p.g * (p.l1 * s1 + p.lc2 * s12),
        -p.m2 * p.g * p.lc2 * s12,
    )
    damping = ca.vertcat(p.b1 * dq[0], p.b2 * dq[1])
    return coriolis - gravity + damping


THETA_NAMES: tuple[str, ...] = ("m1", "m2", "l1", "lc2", "b1", "b2")
"""The acrobot's parameters that may vary (docs/reference/spec.md §14): link masses, the length of link 1, link 2's
centre of
mass, the joint damping. The inertias about the centres of mass stay the model's."""
THETA_UNITS: tuple[str, ...] = ("kg", "kg", "m", "m", "N m s", "N m s")
THETA_SPREAD = 0.2
"""``Theta`` is the task's value +- 20 % for the masses and lengths, and from half to twice its damping (the
nominal 0.1 N m s: [0.05, 0.2])."""


def acrobot_xdot(x: ca.SX, u: ca.SX, p: AcrobotParams) -> ca.SX:
    """``xdot = f(x, u)`` for the parameters ``p`` (numbers, or SX symbols for the parametric dynamics)."""
    q, dq = x[:2], x[2:]
    M = acrobot_mass_matrix(q, p)
    bias = acrobot_bias(q, dq, p)
    # 2x2 solve written out (det M > 0 everywhere) so the expression stays small and SX-expandable.
    rhs = ca.vertcat(-bias[0], u[0] - bias[1])
    det = M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0]
    ddq = ca.vertcat(M[1, 1] * rhs[0] - M[0, 1] * rhs[1], -M[1, 0] * rhs[0] + M[0, 0] * rhs[1]) / det
    return ca.vertcat(dq, ddq)


def acrobot_parameter_space(p: AcrobotParams) -> ParameterSpace:
    """``Theta`` around the parameters ``p`` (:data:`THETA_SPREAD`) and the dynamics ``f(x, u, theta)``."""
    own = np.array([getattr(p, n) for n in THETA_NAMES], dtype=float)
    low, high = own * (1 - THETA_SPREAD), own * (1 + THETA_SPREAD)
    low[4:], high[4:] = own[4:] / 2, own[4:] * 2
    return ParameterSpace(
        names=THETA_NAMES,
        low=low,
        high=high,
        units=THETA_UNITS,
        dynamics=parametric_dynamics("acrobot", 4, 1, THETA_NAMES, p, acrobot_xdot),
        extras=_physics_extras,
    )


def _physics_extras(p: AcrobotParams) -> dict[str, ca.Function]:
    qs, dqs = ca.SX.sym("q", 2), ca.SX.sym("dq", 2)
    return {
        "mass_matrix": ca.Function("acrobot_M", [qs], [acrobot_mass_matrix(qs, p)]),
        "bias": ca.Function("acrobot_bias", [qs, dqs], [acrobot_bias(qs, dqs, p)]),
    }


def make_acrobot_task(params: AcrobotParams | None = None) -> Task:
    """Build the acrobot :class:`Task` (see the module docstring for the choices)."""
    p = params or AcrobotParams()
    x = ca.SX.sym("x", 4)
    u = ca.SX.sym("u", 1)
    dynamics = ca.Function("acrobot_f", [x, u], [acrobot_xdot(x, u, p)], ["x", "u"], ["xdot"])

    goal = np.array([np.pi, 0.0, 0.0, 0.0])
    Q = np.diag(p.Q)
    err = x - goal
    stage_cost = ca.Function("acrobot_l", [x, u], [ca.bilin(Q, err, err) + p.R * u[0] ** 2], ["x", "u"], ["l"])

    h = p.tau / p.horizon_steps
    Qf = _discrete_lqr_cost_to_go(dynamics, goal, p.rk4_substeps, h, Q, np.array([[p.R]]))
    terminal_cost = ca.Function("acrobot_lf", [x], [ca.bilin(Qf, err, err)], ["x"], ["lf"])

    half = np.asarray(p.x0_half_width)
    inf4 = np.full(4, np.inf)
    return Task(
        name="acrobot",
        state_names=("th1", "th2", "dth1", "dth2"),
        control_names=("elbow_torque",),
        dynamics=dynamics,
        stage_cost=stage_cost,
        terminal_cost=terminal_cost,
        goal=goal,
        u_low=np.array([-p.u_max]),
        u_high=np.array([p.u_max]),
        x_low=-inf4,
        x_high=inf4,
        x_final_low=-inf4,
        x_final_high=inf4,
        x0_low=goal - half,
        x0_high=goal + half,
        tau_range=(p.tau, p.tau),
        tau_nominal=p.tau,
        num_steps=p.horizon_steps,
        step_bounds=(h, h),
        fixed_step=True,
        rk4_substeps=p.rk4_substeps,
        control_period=p.control_period,
        params=p,
        parameters=acrobot_parameter_space(p),
        extras={"Qf": Qf, "Q": Q, "R": np.array([[p.R]]), **_physics_extras(p)},
        profile=acrobot_profile(p),
    )


def _discrete_lqr_cost_to_go(
    dynamics: ca.Function, goal: np.ndarray, substeps: int, h: float, Q: np.ndarray, R: np.ndarray
) -> np.ndarray:
    """DARE solution for the RK4 discretisation at the goal with stage weights ``h Q``, ``h R``."""
    step = rk4_map(dynamics, goal.size, R.shape[0], substeps)
    x, u = ca.SX.sym("x", goal.size), ca.SX.sym("u", R.shape[0])
    xs = step(x, u, h)
    jac = ca.Function("acrobot_linearization", [x, u], [ca.jacobian(xs, x), ca.jacobian(xs, u)])
    A, B = (np.asarray(m) for m in jac(goal, np.zeros(R.shape[0])))
    P = scipy.linalg.solve_discrete_are(A, B, h * Q, h * R)
    return 0.5 * (P + P.T)
