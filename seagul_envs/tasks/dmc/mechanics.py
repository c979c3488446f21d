"""Planar rigid-body chains as MuJoCo builds them from an MJCF, in CasADi (the DeepMind Control Suite tasks).

The suite's pendulum, cart-pole and acrobot move in the x-z plane of MuJoCo's world: every joint is a hinge about
the y axis or a slide along x. For such a chain MuJoCo's equations of motion are

    M(q) qacc + qfrc_bias(q, qvel) = qfrc_passive(qvel) + qfrc_actuator(u)

with ``qfrc_bias = C(q, qvel) qvel + dV/dq`` (Coriolis/centrifugal and gravity), ``qfrc_passive = -D qvel`` (joint
``damping``) and ``qfrc_actuator = gear * clamp(ctrl, ctrlrange)`` on the actuated joint. This module writes them
from a :class:`PlanarBody` list: ``M = sum_i m_i Jc_i' Jc_i + I_i Jphi_i' Jphi_i`` from the Jacobians of each body's
centre of mass ``c_i(q)`` and angle ``phi_i(q)``, and the bias from the Lagrangian,
``C qvel = d(M qvel)/dq qvel - 1/2 d(qvel' M qvel)/dq``, by CasADi's automatic differentiation (exact, not
approximated). Masses, centres of mass and inertias come from the geoms by MuJoCo's rules (:func:`capsule_inertia`,
:func:`sphere_inertia`, :func:`box_inertia`), and ``tests/test_dmc_tasks.py`` checks them against
``model.body_mass``, ``model.body_ipos`` and ``model.body_inertia`` and the matrices against ``mj_fullM``,
``qfrc_bias``, ``qfrc_passive`` and ``qacc``.

Integrators (MuJoCo's ``mj_step``, one ``option timestep`` ``h``, ctrl held):

* ``integrator="RK4"`` (cart-pole, acrobot): the classic four-stage Runge-Kutta step of ``xdot = f(x, u)``, i.e.
  :func:`seagul_envs.tasks.base.rk4_map` with one substep.
* the default ``Euler`` (pendulum): semi-implicit Euler with implicit joint damping (``mjINT_EULER`` when a dof has
  damping and ``eulerdamp`` is not disabled): ``qvel' = qvel + h (M + h D)^-1 (tau - qfrc_bias - D qvel)``, then
  ``qpos' = qpos + h qvel'`` (the new velocity).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import casadi as ca
import numpy as np
import scipy.linalg

from seagul_envs.tasks.base import rk4_map

GRAVITY = 9.81
"""MuJoCo's default ``option gravity="0 0 -9.81"`` (m/s^2); none of the three suite files sets another."""


# ----------------------------------------------------------------------------------------------- geom inertias
def capsule_inertia(mass: float, radius: float, length: float) -> tuple[float, float]:
    """``(I_transverse, I_axial)`` (kg m^2) of a capsule of ``mass`` about its centre, as MuJoCo computes it.

    MuJoCo's capsule is a cylinder of ``length`` (the ``fromto`` distance, ``2 * size[1]``) and ``radius`` with two
    hemispherical caps; a given ``mass`` is split between them in proportion to their volumes (uniform density). The
    caps' transverse inertia about the capsule's centre is ``m_s (2 r^2 / 5 + L^2 / 4 + 3 L r / 8)`` (each cap's
    centre of mass lies ``3 r / 8`` beyond the cylinder's end).
    """
    r, L = radius, length
    v_cyl = math.pi * r**2 * L
    v_sph = 4.0 / 3.0 * math.pi * r**3
    m_sph = mass * v_sph / (v_cyl + v_sph)
    m_cyl = mass - m_sph
    transverse = m_cyl * (3 * r**2 + L**2) / 12 + m_sph * (2 * r**2 / 5 + L**2 / 4 + 3 * L * r / 8)
    axial = m_cyl * r**2 / 2 + m_sph * 2 * r**2 / 5
    return transverse, axial


def sphere_inertia(mass: float, radius: float) -> float:
    """Inertia (kg m^2) of a solid sphere about any axis through its centre: ``2 m r^2 / 5``."""
    return 2.0 * mass * radius**2 / 5.0


def box_inertia(mass: float, half_sizes: tuple[float, float, float]) -> tuple[float, float, float]:
    """``(Ixx, Iyy, Izz)`` (kg m^2) of a solid box of ``mass`` and MuJoCo half-sizes ``size="a b c"``."""
    a, b, c = (2 * s for s in half_sizes)
    return mass * (b**2 + c**2) / 12, mass * (a**2 + c**2) / 12, mass * (a**2 + b**2) / 12


# ----------------------------------------------------------------------------------------------- planar chain
@dataclass(frozen=True)
class PlanarBody:
    """One body of a chain in MuJoCo's x-z plane, with the joint that moves it relative to its parent.

    Angles rotate about the world's y axis as MuJoCo's ``axis="0 1 0"`` does: a positive angle turns the body's z axis
    towards +x, so a local vector ``(a_x, a_z)`` of a body at angle ``phi`` is ``(a_x cos phi + a_z sin phi,
    -a_x sin phi + a_z cos phi)`` in the world.
    """

    parent: int
    """Index of the parent body in the chain (-1: the world)."""
    pos: tuple[float, float]
    """The body's ``pos`` (x, z) in its parent's frame (m)."""
    joint: Literal["hinge", "slide"]
    """``hinge`` about y (one angle, rad) or ``slide`` along the parent's x axis (m); at the body's origin."""
    mass: float
    """Body mass (kg): the sum of its geoms' masses."""
    com: tuple[float, float]
    """Centre of mass (x, z) in the body's frame (m): MuJoCo's ``body_ipos``."""
    inertia_y: float
    """Inertia about the y axis through the centre of mass (kg m^2)."""


def _rotate(phi: ca.SX, v: tuple[float, float] | ca.SX) -> ca.SX:
    c, s = ca.cos(phi), ca.sin(phi)
    return ca.vertcat(c * v[0] + s * v[1], -s * v[0] + c * v[1])


def chain_kinematics(bodies: Sequence[PlanarBody], q: ca.SX) -> tuple[list[ca.SX], list[ca.SX], list[ca.SX]]:
    """Each body's origin (x, z), angle and centre of mass (x, z) in the world as functions of ``q`` (one
    coordinate per body, in body order: MuJoCo's ``qpos`` order for these chains)."""
    origins: list[ca.SX] = []
    angles: list[ca.SX] = []
    coms: list[ca.SX] = []
    for i, body in enumerate(bodies):
        origin: ca.SX
        angle: ca.SX
        if body.parent < 0:
            origin, angle = ca.SX(list(body.pos)), ca.SX(0)
        else:
            origin = origins[body.parent] + _rotate(angles[body.parent], body.pos)
            angle = angles[body.parent]
        if body.joint == "hinge":
            angle = angle + q[i]
        else:
            origin = origin + _rotate(angle, (1.0, 0.0)) * q[i]
        origins.append(origin)
        angles.append(angle)
        coms.append(origin + _rotate(angle, body.com))
    return origins, angles, coms


def mass_matrix(bodies: Sequence[PlanarBody], q: ca.SX) -> ca.SX:
    """MuJoCo's joint-space inertia ``M(q)`` (``mj_fullM``): ``sum_i m_i Jc_i' Jc_i + I_i Jphi_i' Jphi_i``."""
    _, angles, coms = chain_kinematics(bodies, q)
    n = len(bodies)
    M = ca.SX.zeros(n, n)
    for body, angle, com in zip(bodies, angles, coms, strict=True):
        Jc = ca.jacobian(com, q)
        Jphi = ca.jacobian(angle, q)
        M += body.mass * (Jc.T @ Jc) + body.inertia_y * (Jphi.T @ Jphi)
    return ca.simplify(M)


def potential_energy(bodies: Sequence[PlanarBody], q: ca.SX, g: float = GRAVITY) -> ca.SX:
    """Gravitational potential energy ``sum_i m_i g z_i`` (J) of the centres of mass."""
    _, _, coms = chain_kinematics(bodies, q)
    return sum((body.mass * g * com[1] for body, com in zip(bodies, coms, strict=True)), ca.SX(0))


def bias_forces(bodies: Sequence[PlanarBody], q: ca.SX, dq: ca.SX, g: float = GRAVITY) -> ca.SX:
    """MuJoCo's ``qfrc_bias``: ``C(q, dq) dq + dV/dq`` (Coriolis, centrifugal and gravity), from the Lagrangian."""
    M = mass_matrix(bodies, q)
    Mdq = M @ dq
    coriolis = ca.jacobian(Mdq, q) @ dq - 0.5 * ca.gradient(ca.dot(dq, Mdq), q)
    return ca.simplify(coriolis + ca.gradient(potential_energy(bodies, q, g), q))


def solve_small(A: ca.SX, b: ca.SX) -> ca.SX:
    """``A^-1 b`` written out for 1x1 and 2x2 ``A`` (symmetric positive definite here), so the expression stays
    small and SX-expandable; larger systems use CasADi's symbolic solve."""
    n = A.shape[0]
    if n == 1:
        return b / A[0, 0]
    if n == 2:
        det = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
        return ca.vertcat(A[1, 1] * b[0] - A[0, 1] * b[1], -A[1, 0] * b[0] + A[0, 0] * b[1]) / det
    return ca.solve(A, b)


@dataclass(frozen=True)
class ChainModel:
    """A chain with its passive and actuator forces: everything MuJoCo's forward dynamics of these models uses."""

    bodies: tuple[PlanarBody, ...]
    """The bodies, one joint each, in MuJoCo's body (and dof) order."""
    damping: tuple[float, ...]
    """Joint ``damping`` per dof (N m s or N s/m): ``qfrc_passive = -damping * qvel``."""
    actuated: int
    """Dof the single motor drives."""
    gear: float
    """The motor's ``gear``: generalized force = ``gear * ctrl``."""
    ctrl_range: tuple[float, float]
    """The motor's ``ctrlrange`` (``ctrllimited="true"``: MuJoCo clamps ctrl into it)."""
    timestep: float
    """``option timestep`` (s)."""
    integrator: Literal["Euler", "RK4"]
    """``option integrator``."""
    g: float = GRAVITY
    """Gravity (m/s^2), acting along -z."""

    @property
    def nq(self) -> int:
        """Number of joints (= dofs)."""
        return len(self.bodies)

    def mass_matrix(self, q: ca.SX) -> ca.SX:
        """``M(q)`` (``mj_fullM``)."""
        return mass_matrix(self.bodies, q)

    def bias(self, q: ca.SX, dq: ca.SX) -> ca.SX:
        """``qfrc_bias(q, dq)``."""
        return bias_forces(self.bodies, q, dq, self.g)

    def passive(self, dq: ca.SX) -> ca.SX:
        """``qfrc_passive(dq) = -D dq`` (joint damping; no springs, no friction loss in these models)."""
        return -ca.vertcat(*self.damping) * dq

    def actuator(self, u: ca.SX) -> ca.SX:
        """``qfrc_actuator``: ``gear * u`` on the actuated dof (``u`` inside the ctrlrange, not clamped here)."""
        tau = [ca.SX(0)] * self.nq
        tau[self.actuated] = self.gear * u[0]
        return ca.vertcat(*tau)

    def qacc(self, x: ca.SX, u: ca.SX) -> ca.SX:
        """``qacc = M^-1 (qfrc_actuator + qfrc_passive - qfrc_bias)`` (``mj_forward``)."""
        q, dq = x[: self.nq], x[self.nq :]
        rhs = self.actuator(u) + self.passive(dq) - self.bias(q, dq)
        return solve_small(self.mass_matrix(q), rhs)

    def xdot(self, x: ca.SX, u: ca.SX) -> ca.SX:
        """``xdot = [qvel, qacc]``."""
        return ca.vertcat(x[self.nq :], self.qacc(x, u))

    def functions(self, prefix: str) -> dict[str, ca.Function]:
        """The CasADi functions the task keeps in ``extras``: ``mass_matrix(q)``, ``bias(q, dq)``,
        ``passive(dq)``, ``qacc(x, u)`` and ``mujoco_step(x, u)``."""
        n = self.nq
        q, dq = ca.SX.sym("q", n), ca.SX.sym("dq", n)
        x, u = ca.SX.sym("x", 2 * n), ca.SX.sym("u", 1)
        return {
            "mass_matrix": ca.Function(f"{prefix}_M", [q], [self.mass_matrix(q)], ["q"], ["M"]),
            "bias": ca.Function(f"{prefix}_bias", [q, dq], [self.bias(q, dq)], ["q", "dq"], ["qfrc_bias"]),
            "passive": ca.Function(f"{prefix}_passive", [dq], [self.passive(dq)], ["dq"], ["qfrc_passive"]),
            "qacc": ca.Function(f"{prefix}_qacc", [x, u], [self.qacc(x, u)], ["x", "u"], ["qacc"]),
            "mujoco_step": self.mujoco_step(prefix),
        }

    def mujoco_step(self, prefix: str) -> ca.Function:
        """``mujoco_step(x, u) -> x_next``: one ``mj_step`` of ``timestep`` with ``ctrl = u`` clamped into the
        ctrlrange (as MuJoCo clamps it), by the model's integrator (module docstring). The suite's control step is
        ``n_sub_steps`` of these (1 for the three tasks)."""
        n = self.nq
        x, u = ca.SX.sym("x", 2 * n), ca.SX.sym("u", 1)
        lo, hi = self.ctrl_range
        ctrl = ca.fmin(ca.fmax(u, lo), hi)
        h = self.timestep
        if self.integrator == "RK4":
            xs = ca.SX.sym("xs", 2 * n)
            us = ca.SX.sym("us", 1)
            f = ca.Function(f"{prefix}_mj_f", [xs, us], [self.xdot(xs, us)])
            x_next = rk4_map(f, 2 * n, 1, 1, f"{prefix}_mj_rk4")(x, ctrl, h)
        else:
            q, dq = x[:n], x[n:]
            D = ca.diag(ca.vertcat(*self.damping))
            rhs = self.actuator(ctrl) + self.passive(dq) - self.bias(q, dq)
            dq_next = dq + h * solve_small(self.mass_matrix(q) + h * D, rhs)
            x_next = ca.vertcat(q + h * dq_next, dq_next)
        return ca.Function(f"{prefix}_mujoco_step", [x, u], [x_next], ["x", "u"], ["x_next"])


# ----------------------------------------------------------------------------------------------- costs
def wrapped_quadratic(x: ca.SX, P: np.ndarray, angles: Sequence[int]) -> ca.SX:
    """A periodic, smooth, nonnegative stand-in for ``e' P e`` around a goal at 0 (``e = x``, angles wrapped).

    Each angle ``th`` of ``angles`` enters ``e`` as ``sin th`` and adds ``P_ii (1 - cos th)^2``; since
    ``sin^2 th + (1 - cos th)^2 = 2 (1 - cos th) = th^2 + O(th^4)``, the function equals ``e' P e`` to second order
    at the goal (its Hessian there is ``2 P``), is 2 pi periodic in every angle, and is positive away from the goal
    modulo 2 pi for a positive-definite ``P`` (at ``th = pi`` the angle still costs ``4 P_ii``).
    """
    e = [ca.sin(x[i]) if i in angles else x[i] for i in range(x.shape[0])]
    ev = ca.vertcat(*e)
    value = ca.bilin(ca.DM(P), ev, ev)
    for i in angles:
        value += float(P[i, i]) * (1 - ca.cos(x[i])) ** 2
    return value


def discrete_lqr_cost_to_go(
    dynamics: ca.Function, goal: np.ndarray, substeps: int, h: float, Q: np.ndarray, R: np.ndarray, name: str
) -> np.ndarray:
    """``P`` of the discrete-time LQR at the goal for the transcription's own discretisation (RK4 with ``substeps``
    over an interval ``h``, stage weights ``h Q`` and ``h R``): near the goal ``e' P e`` is the infinite-horizon
    cost to go, so a terminal cost built on it does not bias a short horizon (the seagul acrobot's choice)."""
    nx, nu = goal.size, R.shape[0]
    step = rk4_map(dynamics, nx, nu, substeps, f"{name}_lqr_rk4")
    x, u = ca.SX.sym("x", nx), ca.SX.sym("u", nu)
    xs = step(x, u, h)
    jac = ca.Function(f"{name}_linearization", [x, u], [ca.jacobian(xs, x), ca.jacobian(xs, u)])
    A, B = (np.asarray(m) for m in jac(goal, np.zeros(nu)))
    P = scipy.linalg.solve_discrete_are(A, B, h * Q, h * R)
    return np.asarray(0.5 * (P + P.T))


def tolerance_gaussian(x: float | np.ndarray, margin: float, bound: float = 0.0) -> np.ndarray:
    """``dm_control.utils.rewards.tolerance(x, bounds=(-bound, bound), margin=margin)`` with its default gaussian
    sigmoid and ``value_at_margin=0.1``: 1 inside the bounds, ``exp(-1/2 (d scale)^2)`` at a distance ``d`` beyond
    them, ``scale = sqrt(-2 ln 0.1) / margin`` (so 0.1 at ``d = margin``)."""
    d = np.maximum(np.abs(np.asarray(x, dtype=np.float64)) - bound, 0.0) / margin
    scale = math.sqrt(-2.0 * math.log(0.1))
    return np.asarray(np.exp(-0.5 * (d * scale) ** 2))


def gaussian_sx(x: ca.SX, margin: float) -> ca.SX:
    """:func:`tolerance_gaussian` with ``bound = 0`` as a CasADi expression (smooth everywhere)."""
    scale = math.sqrt(-2.0 * math.log(0.1)) / margin
    return ca.exp(-0.5 * (x * scale) ** 2)
