"""Classical swing-up controllers for the DeepMind Control Suite swing-ups: energy pumping plus an LQR catch.

The baseline per task that any learned controller of seagul should beat on dm_control's own score
(:mod:`seagul_control.dmc`). Each is a callable ``controller(x, t) -> action`` on the physics state
``x = [qpos, qvel]`` (MJCF joint order, angles zero at the upright, as :func:`seagul_control.dmc.physics_state`
reads it) returning dm_control's action (the actuator's ``ctrl`` in ``[-1, 1]``; the torque or force is
``gear * ctrl``), always clipped to the actuator's range: saturation is part of these designs.

* :class:`SpongAcrobotController` (``acrobot-swingup``): M. W. Spong, "The swing up control problem for the
  Acrobot", IEEE Control Systems 15(1), 1995, 49-55. Partial feedback linearisation of the active (elbow) joint,
  ``q2'' = v``, with the energy-pumping outer loop of Spong's paper (in the form of Tedrake, Underactuated Robotics,
  ch. "Acrobots, Cart-Poles, and Quadrotors", Sec. "Swing-up control"):
  ``v = k1 (q2d - q2) - k2 q2' + k3 sat(q1' (E - E_top))``, with the elbow reference of Spong's pumping strategy
  ``q2d = alpha (2/pi) arctan(q1')`` (signed by the energy's shortfall, so that it pumps out an excess); the
  torque realising ``v`` is
  ``tau = (M22 - M21 M12 / M11) v + h2 - M21 h1 / M11`` (``M`` the mass matrix, ``h`` gravity, Coriolis and the
  joints' damping), clipped to the suite's 2 N m (``ctrlrange`` 1 x ``gear`` 2). Near the upright an LQR catches
  and balances (switch when its cost to go ``dx' P dx`` is below ``catch_cost``).
* :class:`PendulumEnergyController` (``pendulum-swingup``): energy shaping ``tau = k sat(q' (E_top - E)) + b q'``
  (K. J. Åström and K. Furuta, "Swinging up a pendulum by energy control", Automatica 36(2), 2000, 287-295, for the
  simple pendulum; ``b q'`` cancels the hinge damping), clipped to 1 N m, then an LQR catch.
* :class:`AstromFurutaCartpoleController` (``cartpole-swingup``, ``cartpole-swingup_sparse``): Åström & Furuta's
  energy control of the pole through the cart's acceleration, ``a = k_e (E - E_top) sign(th' cos th)`` saturated,
  plus a weak PD keeping the cart near the middle of the rail, realised by partial feedback linearisation of the
  cart (force from the mass matrix), clipped to 10 N; then an LQR catch.

Models: the mass matrix, the bias forces and the energy are MuJoCo's own, of the suite's MJCF (each controller
loads the XML dm_control ships and evaluates it at the current state: ``mj_forward``, ``mj_fullM``, ``data.energy``);
the LQR gains come from the discrete linearisation of one control period of that model at the upright
(centred finite differences of MuJoCo's step: the suite's integrator and timestep) and the discrete Riccati
equation (:func:`seagul_control.lqr.discrete_lqr`). ``LQRPolicy(make_task("dmc_acrobot"), Q=..., R=...)`` gives
the same gain from seagul's CasADi model of the suite (``tests/test_dmc_scoring.py`` checks it); the MuJoCo
linearisation keeps these baselines independent of seagul's models.

Parameters are frozen dataclasses whose defaults were tuned by random search on reset seeds 100-139 of each env
(:data:`TUNING_SEEDS`; never the benchmark's evaluation seeds 0-9); each class's docstring gives the search and the
score it reached.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any

import numpy as np

from seagul_control.lqr import discrete_lqr

__all__ = [
    "TUNING_SEEDS",
    "AcrobotSwingUpParams",
    "AstromFurutaCartpoleController",
    "CartpoleSwingUpParams",
    "PendulumEnergyController",
    "PendulumSwingUpParams",
    "SpongAcrobotController",
    "SuiteModel",
    "wrap_angle",
]

#: Reset seeds the default parameters were tuned on (disjoint from the benchmark's evaluation seeds 0-9).
TUNING_SEEDS: tuple[int, ...] = tuple(range(100, 140))


def wrap_angle(angle: Any) -> Any:
    """``angle`` wrapped to ``[-pi, pi)`` (elementwise)."""
    return (np.asarray(angle, dtype=float) + np.pi) % (2.0 * np.pi) - np.pi


def _sat(value: float, limit: float) -> float:
    return float(np.clip(value, -limit, limit))


class SuiteModel:
    """The MuJoCo model of a suite domain (``"acrobot"``, ``"pendulum"``, ``"cartpole"``) from dm_control's MJCF,
    with a private ``MjData`` to evaluate it at given states.

    ``dynamics(x)`` -> ``(M, h, energy)``: the mass matrix, the generalised forces other than the actuator's
    (``qfrc_bias - qfrc_passive``: Coriolis, centrifugal, gravity, joint damping), so that
    ``M q'' + h = gear * ctrl`` on the actuated joint, and the total energy (kinetic + potential; the suite's MJCFs
    enable MuJoCo's energy computation). ``linearization()`` -> ``(A, B)`` of one control period at the upright
    (``qpos = qvel = 0``, ``ctrl = 0``).
    """

    def __init__(self, domain: str) -> None:
        mujoco = importlib.import_module("mujoco")
        try:
            suite_module = importlib.import_module(f"dm_control.suite.{domain}")
        except ImportError as exc:
            raise ImportError(f"the {domain} model is dm_control's (pip install 'seagul[dmc]'): {exc}") from exc
        xml, assets = suite_module.get_model_and_assets()
        self._mujoco = mujoco
        self.domain = domain
        self.model = mujoco.MjModel.from_xml_string(xml, assets)
        self.data = mujoco.MjData(self.model)
        self.nq, self.nv = int(self.model.nq), int(self.model.nv)
        self.gear = float(self.model.actuator_gear[0, 0])
        self.ctrl_limit = float(self.model.actuator_ctrlrange[0, 1])
        self.actuated = int(self.model.actuator_trnid[0, 0])
        """Index (qvel) of the actuated joint."""
        self._M = np.zeros((self.nv, self.nv))
        self.top_energy = self.energy(np.zeros(self.nq + self.nv))
        """Total energy at rest at the upright (the swing-ups' target energy)."""

    def _set(self, x: np.ndarray) -> None:
        self.data.qpos[:] = x[: self.nq]
        self.data.qvel[:] = x[self.nq :]
        self.data.ctrl[:] = 0.0
        self._mujoco.mj_forward(self.model, self.data)

    def energy(self, x: np.ndarray) -> float:
        """Kinetic plus potential energy (J) at ``x`` (potential relative to MuJoCo's world origin)."""
        self._set(np.asarray(x, dtype=float))
        return float(self.data.energy[0] + self.data.energy[1])

    def dynamics(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """``(M, h, energy)`` at ``x``; see the class docstring."""
        self._set(np.asarray(x, dtype=float))
        try:
            self._mujoco.mj_fullM(self.model, self.data, self._M)  # recent MuJoCo: (model, data, dst)
        except TypeError:
            self._mujoco.mj_fullM(self.model, self._M, self.data.qM)  # older: (model, dst, qM)
        h = np.array(self.data.qfrc_bias - self.data.qfrc_passive, dtype=float)
        return self._M.copy(), h, float(self.data.energy[0] + self.data.energy[1])

    def step(self, x: np.ndarray, ctrl: np.ndarray) -> np.ndarray:
        """The state after one physics step (the suite's integrator) from ``x`` under ``ctrl``."""
        self.data.qpos[:] = x[: self.nq]
        self.data.qvel[:] = x[self.nq :]
        self.data.ctrl[:] = ctrl
        self.data.time = 0.0
        self._mujoco.mj_step(self.model, self.data)
        return np.concatenate([self.data.qpos, self.data.qvel])

    def linearization(self, eps: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
        """``(A, B)``: ``dx+ = A dx + B du`` over one physics step (= one control step in these domains) at the
        upright, by centred finite differences of :meth:`step` (``mujoco.mjd_transitionFD`` refuses RK4, the
        integrator of the acrobot and the cart-pole)."""
        n, nu = self.nq + self.nv, int(self.model.nu)
        x0, u0 = np.zeros(n), np.zeros(nu)
        A, B = np.zeros((n, n)), np.zeros((n, nu))
        for i in range(n):
            d = np.zeros(n)
            d[i] = eps
            A[:, i] = (self.step(x0 + d, u0) - self.step(x0 - d, u0)) / (2 * eps)
        for j in range(nu):
            d = np.zeros(nu)
            d[j] = eps
            B[:, j] = (self.step(x0, u0 + d) - self.step(x0, u0 - d)) / (2 * eps)
        return A, B


class _LQRCatch:
    """Discrete LQR at the upright of a suite model: ``ctrl = -K dx`` with wrapped angles, and its cost to go
    ``dx' P dx``. Stage weights ``dt Q`` and ``dt R`` (a continuous-time cost sampled at the physics step, as
    :class:`seagul_control.lqr.LQRPolicy` weighs the task's running cost), so the cost to go is in the units of
    ``integral (dx' Q dx + r ctrl^2) dt`` whatever the step."""

    def __init__(self, model: SuiteModel, q_diag: tuple[float, ...], r: float, angles: tuple[int, ...]) -> None:
        A, B = model.linearization()
        dt = float(model.model.opt.timestep)
        self.K, self.P = discrete_lqr(A, B, dt * np.diag(q_diag), dt * np.array([[r]]))
        self.angles = list(angles)

    def error(self, x: np.ndarray) -> np.ndarray:
        dx = np.array(x, dtype=float)
        dx[self.angles] = wrap_angle(dx[self.angles])
        return dx

    def cost(self, x: np.ndarray) -> float:
        dx = self.error(x)
        return float(dx @ self.P @ dx)

    def action(self, x: np.ndarray) -> float:
        return float(-(self.K @ self.error(x))[0])


class _Classical:
    """What the three controllers share: the model, the LQR catch, the switch, clipping, a name."""

    name = "classical"

    def __init__(self, model: SuiteModel, lqr: _LQRCatch, catch_cost: float) -> None:
        self.model = model
        self.lqr = lqr
        self.catch_cost = float(catch_cost)
        self.caught = False
        """Whether the last decision was the LQR's."""

    def reset(self) -> None:
        self.caught = False

    def swing(self, x: np.ndarray) -> float:
        raise NotImplementedError

    def __call__(self, x: np.ndarray, t: float) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        self.caught = self.lqr.cost(x) < self.catch_cost
        ctrl = self.lqr.action(x) if self.caught else self.swing(x)
        return np.array([_sat(ctrl, self.model.ctrl_limit)])


# ------------------------------------------------------------------------------------------------------ acrobot
@dataclass(frozen=True)
class AcrobotSwingUpParams:
    """Gains of :class:`SpongAcrobotController` (Spong 1995's energy-based swing-up with an LQR catch).

    Provenance: the law and the gains ``k1, k2, k3`` are Spong's (Tedrake's notes use ``k1 = 50, k2 = 5, k3 = 10``
    for an acrobot with unlimited torque), the arctan reference ``alpha`` is Spong's original pumping strategy. The
    suite's acrobot (1 kg, 1 m links, 2 N m at the elbow against up to 4.9 N m of gravity on the lower link) cannot
    hold its elbow straight, so those gains spin the elbow; these defaults come from a random search
    (``benchmarks/bench_dmc.py --tune acrobot --trials 150``: all seven fields drawn from the box of
    ``SEARCH["acrobot"]`` there, each draw scored by its mean dm_control score on the first 10 :data:`TUNING_SEEDS`,
    the best 5 re-scored on all 40). They scored 44.7 on the 40 tuning seeds (the other four 23-36): the catch is
    the limit, the LQR's basin at 2 N m being about 0.01 rad of shoulder error (larger errors need elbow swings of
    ~27 times the error, where the linearisation fails), so most episodes pump to the upright's energy but are
    rarely caught.
    """

    k1: float = 1.8203
    """Elbow stiffness of the PFL outer loop (1/s^2): pulls ``q2`` to its reference."""
    k2: float = 0.508
    """Elbow damping of the outer loop (1/s)."""
    k3: float = 16.3629
    """Energy-pumping gain on ``sat(q1' (E - E_top))`` (1/(J s)); 0 leaves Spong's arctan reference alone."""
    alpha: float = -0.3864
    """Amplitude (rad) of Spong's elbow reference ``q2d = alpha (2/pi) arctan(q1') sign(E_top - E)``; 0 leaves the
    energy term alone."""
    energy_sat: float = 24.7559
    """Saturation of ``q1' (E - E_top)`` (J rad/s)."""
    catch_cost: float = 18.5287
    """Switch to the LQR when its cost to go ``dx' P dx`` (wrapped angles) is below this."""
    lqr_q: tuple[float, float, float, float] = (10.0, 10.0, 1.0, 1.0)
    """Diagonal state weights of the catch LQR."""
    lqr_r: float = 0.4775
    """Control weight of the catch LQR (ctrl units)."""


class SpongAcrobotController(_Classical):
    """Spong's energy-pumping swing-up of the suite's acrobot with an LQR catch (module docstring; parameters
    :class:`AcrobotSwingUpParams`). State ``[shoulder, elbow, d shoulder, d elbow]``, angles zero upright."""

    name = "spong"

    def __init__(self, params: AcrobotSwingUpParams | None = None) -> None:
        self.params = params or AcrobotSwingUpParams()
        model = SuiteModel("acrobot")
        lqr = _LQRCatch(model, self.params.lqr_q, self.params.lqr_r, angles=(0, 1))
        super().__init__(model, lqr, self.params.catch_cost)

    def swing(self, x: np.ndarray) -> float:
        p = self.params
        M, h, energy = self.model.dynamics(x)
        q2, dq1, dq2 = float(wrap_angle(x[1])), float(x[2]), float(x[3])
        excess = energy - self.model.top_energy
        pump = _sat(dq1 * excess, p.energy_sat)
        q2_ref = p.alpha * (2.0 / np.pi) * float(np.arctan(dq1)) * (1.0 if excess < 0 else -1.0)
        v = p.k1 * (q2_ref - q2) - p.k2 * dq2 + p.k3 * pump
        tau = (M[1, 1] - M[1, 0] * M[0, 1] / M[0, 0]) * v + h[1] - M[1, 0] * h[0] / M[0, 0]
        return tau / self.model.gear


# ----------------------------------------------------------------------------------------------------- pendulum
@dataclass(frozen=True)
class PendulumSwingUpParams:
    """Gains of :class:`PendulumEnergyController`.

    Provenance: random search (``benchmarks/bench_dmc.py --tune pendulum --trials 40``: log-uniform draws of all
    four fields, each scored by its mean dm_control score on the first 10 :data:`TUNING_SEEDS`, the best 5 re-scored
    on all 40); these defaults scored 833.3 on the 40 tuning seeds. The landscape is flat (the best five within
    2.5 points): once ``k`` saturates the torque the pendulum pumps at the actuator's limit whatever the gains.
    """

    k: float = 0.675
    """Energy gain: ``tau = k sat(q' (E_top - E)) + b q'`` (N m / (J rad/s))."""
    energy_sat: float = 14.721
    """Saturation of ``q' (E_top - E)`` (J rad/s)."""
    catch_cost: float = 13.5965
    """Switch to the LQR when its cost to go is below this."""
    lqr_q: tuple[float, float] = (10.0, 1.0)
    """Diagonal state weights of the catch LQR."""
    lqr_r: float = 6.2543
    """Control weight of the catch LQR."""


class PendulumEnergyController(_Classical):
    """Energy-shaping swing-up of the suite's pendulum with an LQR catch (module docstring). State ``[hinge,
    d hinge]``, zero upright; 1 N m against ``m g l = 4.9`` N m, so it pumps over several swings."""

    name = "energy"

    def __init__(self, params: PendulumSwingUpParams | None = None) -> None:
        self.params = params or PendulumSwingUpParams()
        model = SuiteModel("pendulum")
        lqr = _LQRCatch(model, self.params.lqr_q, self.params.lqr_r, angles=(0,))
        super().__init__(model, lqr, self.params.catch_cost)
        self.damping = float(model.model.dof_damping[0])

    def swing(self, x: np.ndarray) -> float:
        p = self.params
        energy = self.model.energy(x)
        dq = float(x[1])
        tau = p.k * _sat(dq * (self.model.top_energy - energy), p.energy_sat) + self.damping * dq
        return tau / self.model.gear


# ----------------------------------------------------------------------------------------------------- cartpole
@dataclass(frozen=True)
class CartpoleSwingUpParams:
    """Gains of :class:`AstromFurutaCartpoleController` (the same for ``cartpole-swingup`` and its sparse variant).

    Provenance: random search on ``cartpole-swingup`` (``benchmarks/bench_dmc.py --tune cartpole --trials 60``:
    draws of all six fields, each scored by its mean dm_control score on the first 10 :data:`TUNING_SEEDS`, the best
    5 re-scored on all 40); these defaults scored 856.4 on the 40 tuning seeds (the next best 827.8).
    """

    k_energy: float = 40.157
    """Åström-Furuta gain: cart acceleration ``a = sat(k_energy (E - E_top) sign(th' cos th), accel_max)``."""
    accel_max: float = 24.3885
    """Saturation of the energy term's cart acceleration (m/s^2)."""
    k_x: float = 1.3307
    """Cart-centering stiffness added to ``a``: ``- k_x x - k_v x'`` (1/s^2)."""
    k_v: float = 2.6947
    """Cart-centering damping (1/s)."""
    catch_cost: float = 2.1294
    """Switch to the LQR when its cost to go is below this."""
    lqr_q: tuple[float, float, float, float] = (1.0, 10.0, 1.0, 1.0)
    """Diagonal state weights of the catch LQR ``[x, th, x', th']``."""
    lqr_r: float = 6.2094
    """Control weight of the catch LQR."""


class AstromFurutaCartpoleController(_Classical):
    """Åström & Furuta's energy swing-up of the suite's cart-pole with an LQR catch (module docstring). State
    ``[slider, hinge_1, d slider, d hinge_1]``, hinge zero upright; force ``10 ctrl`` N."""

    name = "astrom_furuta"

    def __init__(self, params: CartpoleSwingUpParams | None = None) -> None:
        self.params = params or CartpoleSwingUpParams()
        model = SuiteModel("cartpole")
        lqr = _LQRCatch(model, self.params.lqr_q, self.params.lqr_r, angles=(1,))
        super().__init__(model, lqr, self.params.catch_cost)
        m = model.model
        pole = int(m.jnt_bodyid[1])
        mass, com = float(m.body_mass[pole]), float(m.body_ipos[pole][2])
        self.pole_inertia = float(m.body_inertia[pole][1]) + mass * com**2
        """The pole's moment of inertia about the hinge (kg m^2)."""
        self.pole_mgl = mass * -float(m.opt.gravity[2]) * com
        """``m g l`` of the pole (J): its potential energy at the upright relative to the hinge."""

    def pole_energy(self, x: np.ndarray) -> float:
        """Åström & Furuta's pendulum energy in the cart's frame: ``J th'^2 / 2 + m g l cos th`` (J)."""
        return 0.5 * self.pole_inertia * float(x[3]) ** 2 + self.pole_mgl * float(np.cos(x[1]))

    def swing(self, x: np.ndarray) -> float:
        p = self.params
        M, h, _ = self.model.dynamics(x)
        th, dx, dth = float(x[1]), float(x[2]), float(x[3])
        e = self.pole_energy(x) - self.pole_mgl
        a = _sat(p.k_energy * e * np.sign(dth * np.cos(th)), p.accel_max) - p.k_x * float(x[0]) - p.k_v * dx
        # PFL of the cart: q1'' = a with q2'' from the pole's row; force = (M00 - M01 M10 / M11) a + h0 - M01 h1 / M11.
        return ((M[0, 0] - M[0, 1] * M[1, 0] / M[1, 1]) * a + h[0] - M[0, 1] * h[1] / M[1, 1]) / self.model.gear
