"""The full-horizon reference on the DeepMind Control Suite swing-ups: what trajectory optimisation with the true model
reaches when it plans the whole remaining episode and re-plans as it goes, scored by dm_control's own reward.

:class:`FullHorizonReference` is a controller ``(x, t) -> action`` for :func:`seagul_control.dmc.run_dmc_episode`
(``x = [qpos, qvel]``, the physics state; ``t`` the episode time). It is not a learned policy and not cheap: it is
the yardstick a short-horizon MPC with a learned terminal value is measured against (how much of the suite's score
is reachable at all with the exact model and a generous solver budget).

What it solves [choice]: a direct multiple-shooting NLP (plain ``casadi.nlpsol`` with IPOPT: the objective is the
suite's reward summed over the episode's control steps, not a task's stage cost, so
:class:`~seagul_control.transcription.Transcription` does not fit) over the **whole episode**: ``N = 1000 /
interval_steps`` intervals of ``interval_steps`` suite control steps each, a piecewise-constant control held over
each interval's control steps (dm_control applies it at every step), the state propagated by
``task.extras["mujoco_step"]`` (MuJoCo's own step of the suite's MJCF, so the plan *is* what dm_control will do,
to round-off), and the reward taken after every control step as dm_control takes it. The horizon shrinks with the
episode: the NLP always has ``N`` intervals, and a weight of 0 on the intervals past the episode's end (a parameter)
makes them free, so one solver is built per task and reused for every decision. Why the whole episode and not a
window: the score counts every step up to the end, and a window would need a terminal value (the thing being
learned); with the exact model the full problem is only ~200 intervals.

Objective [choice, per task, :class:`ReferenceSettings`]: minimise ``sum_k w_k [(1 - alpha) S_k - alpha R_k] +
reg sum_k u_k^2``, ``R_k`` the reward summed over interval ``k``'s control steps and ``S_k`` a graded surrogate
(``alpha`` is a parameter of the NLP: a homotopy):

* acrobot-swingup: ``R`` = the suite's reward exactly (``tolerance(d, (0, 0.2), margin=1)`` of the tip-to-target
  distance: 1 inside 0.2 m, a gaussian beyond; ``d = sqrt(max(d^2, 0.04))`` keeps it differentiable), ``S = d^2``
  (the task's cost: graded everywhere, where the reward's gaussian is flat a metre beyond the target);
* cartpole-swingup: ``R`` = the suite's reward exactly (``upright * centered * small_control * small_velocity``, smooth
  on the control box), ``S = 1 - cos(hinge)``;
* pendulum-swingup: the suite's reward is an indicator (within 8 deg of upright), so ``R`` is a smooth stand-in: 1
  inside the 8 deg cone and a gaussian of the excess of ``cos(8 deg) - cos(hinge)`` beyond it (margin
  :attr:`ReferenceSettings.reward_margin`, value 0.1 there); ``S = 1 - cos(hinge)``;
* cartpole-swingup_sparse: the suite's reward is a product of two indicators (``|slider| <= 0.25``,
  ``cos(hinge) >= 0.995``); ``R`` is the product of the same tolerances with gaussian margins (``reward_margin`` on
  the cosine, ``cart_margin`` on the slider) and ``S = 1 - cos(hinge)``.

Global search [choice]: at the episode's start the reference solves from several initial guesses, each a control
sequence rolled out through the exact model from the start state: zero, square waves (bang-bang pumping) of a few
periods and both signs, and velocity feedback ``u = sat(g v_i)`` rollouts (energy pumping) of a few gains and both
signs. Each guess goes through the homotopy ``alpha`` = :attr:`ReferenceSettings.homotopy` (surrogate first, then
the reward: from a naive guess the reward's flat gaussian gives IPOPT no slope) and the plan with the largest
**true** suite return along its own states (the indicator rewards where the objective has stand-ins) is kept.

Re-planning: every :attr:`ReferenceSettings.resolve_every` control steps the NLP (``alpha = 1``) is re-solved from the
measured state, warm-started from the previous plan shifted by the elapsed intervals, with a smaller iteration and
wall-time budget. The upright is unstable, so an open-loop plan, exact as it is, drifts off it within seconds. A
re-solve that fails (IPOPT neither converged nor stopped at a feasible point) keeps the previous plan, whose controls
from now on are the shifted plan's, and is recorded as a fallback.

Every solve is recorded (:class:`SolveRecord`: control step, kind, wall time, IPOPT's status, objective, the plan's
true return, iterations); :attr:`FullHorizonReference.records` keeps the episode's, :meth:`FullHorizonReference.reset`
clears them.

Usage::

    from seagul_control.dmc import run_dmc_episode
    from seagul_control.dmc_reference import FullHorizonReference

    ref = FullHorizonReference("acrobot-swingup")
    episode = run_dmc_episode("acrobot-swingup", ref, seed=0)
    episode.score, [r.solve_s for r in ref.records]

Measured scores, settings and decision times: docs/experiments/dmc-reference.md
(``benchmarks/bench_dmc_reference.py``).
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import casadi as ca
import numpy as np

from seagul_control.codegen import compile_nlp_library
from seagul_control.dmc import DMC_TASKS, EPISODE_STEPS, dmc_env_id
from seagul_envs import make_task
from seagul_envs.tasks.base import Task
from seagul_envs.tasks.dmc.acrobot import dmc_acrobot_model, dmc_acrobot_reward, dmc_acrobot_tip_to_target
from seagul_envs.tasks.dmc.cartpole import dmc_cartpole_model, dmc_cartpole_reward
from seagul_envs.tasks.dmc.mechanics import ChainModel, gaussian_sx, potential_energy
from seagul_envs.tasks.dmc.pendulum import dmc_pendulum_model, dmc_pendulum_reward

__all__ = [
    "DEFAULT_SETTINGS",
    "FullHorizonReference",
    "ReferenceSettings",
    "SolveRecord",
    "pump_signal",
    "suite_reward",
    "swing_energy",
    "with_settings",
]

_SCALE = math.sqrt(-2.0 * math.log(0.1))  # dm_control's gaussian sigmoid: value 0.1 at the margin

#: IPOPT statuses that count as a solved NLP.
_SOLVED = ("Solve_Succeeded", "Solved_To_Acceptable_Level")


@dataclass(frozen=True)
class ReferenceSettings:
    """How :class:`FullHorizonReference` plans (module docstring); the defaults per env are :data:`DEFAULT_SETTINGS`."""

    interval_steps: int = 5
    """Suite control steps per transcription interval (the control is held over them): 5 = 0.05 s on the acrobot and
    the cart-pole, 0.1 s on the pendulum."""
    resolve_every: int = 25
    """Control steps between re-solves (a multiple of ``interval_steps``)."""
    homotopy: tuple[float, ...] = (0.0, 1.0)
    """``alpha`` of each search solve of one guess, in order (0: the surrogate alone, 1: the reward alone)."""
    bang_periods: tuple[float, ...] = (1.0, 2.0)
    """Periods (s) of the square-wave guesses (each with both signs and every phase of ``bang_phases``)."""
    bang_phases: tuple[float, ...] = (0.0,)
    """Phases of the square-wave guesses, in periods (0.25: the first switch a quarter period early)."""
    pump_gains: tuple[float, ...] = (1.0,)
    """Gains ``k`` (per J) of the energy-pumping guesses ``u = sat(k (E* - E) y)`` (each with both signs): ``E`` the
    swinging part's mechanical energy, ``E*`` its value upright at rest, ``y`` the velocity through which the
    actuator changes it (:func:`pump_signal`)."""
    zero_guess: bool = True
    """Also start from zero control."""
    catch_guesses: bool = True
    """Cut each rollout guess where it comes closest to the balanced goal (the task's LQR cost to go, ``l_f``) and
    continue it at the goal, at rest, with zero control: the guess then has the swing-up-then-balance shape of the
    optimum (the rollout itself swings through the top and falls back)."""
    control_reg: float = 1e-4
    """Weight of ``sum u_k^2`` (makes the control unique where the reward is flat, e.g. past the episode's end)."""
    reward_margin: float = 0.1
    """Pendulum and sparse cart-pole: margin of the reward's smooth stand-in, in units of ``cos(hinge)``."""
    cart_margin: float = 0.25
    """Sparse cart-pole: margin (m) of the stand-in's slider tolerance."""
    search_max_iter: int = 400
    """IPOPT iterations per search solve."""
    resolve_max_iter: int = 100
    """IPOPT iterations per re-solve."""
    resolve_max_time: float = 10.0
    """Wall-time limit of one re-solve (s; IPOPT's ``max_wall_time``)."""
    tol: float = 1e-6
    """IPOPT's ``tol``."""
    codegen: bool = True
    """Generate C for the NLP's functions and compile them once (:func:`seagul_control.codegen.compile_nlp_library`,
    cached under ``~/.cache/seagul/casadi``); without a C compiler it warns and interprets."""
    feasibility_tol: float = 1e-6
    """Largest defect (state units) of an unconverged solve that is still used as a plan."""

    def __post_init__(self) -> None:
        if self.interval_steps < 1 or EPISODE_STEPS % self.interval_steps:
            raise ValueError(f"interval_steps must divide {EPISODE_STEPS}, got {self.interval_steps}")
        if self.resolve_every < 1 or self.resolve_every % self.interval_steps:
            raise ValueError(
                f"resolve_every ({self.resolve_every}) must be a positive multiple of interval_steps "
                f"({self.interval_steps})"
            )
        if not self.homotopy or self.homotopy[-1] != 1.0:
            raise ValueError(f"homotopy must end with alpha = 1 (the reward), got {self.homotopy}")


#: The settings the benchmark uses per env (docs/experiments/dmc-reference.md says how they were chosen).
DEFAULT_SETTINGS: dict[str, ReferenceSettings] = {
    "dm_control/acrobot-swingup-v0": ReferenceSettings(
        homotopy=(1.0,),
        bang_periods=(1.0, 1.25, 1.5, 1.75, 2.0, 2.25, 2.5, 2.75, 3.0, 3.5),
        bang_phases=(0.0, 0.25),
        pump_gains=(0.5, 1.0, 2.0, 4.0),
        search_max_iter=150,
    ),
    "dm_control/pendulum-swingup-v0": ReferenceSettings(
        homotopy=(1.0,), bang_periods=(1.4,), pump_gains=(5.0, 20.0), search_max_iter=150
    ),
    "dm_control/cartpole-swingup-v0": ReferenceSettings(
        homotopy=(1.0,), bang_periods=(1.0, 1.5), pump_gains=(10.0,), search_max_iter=150
    ),
    "dm_control/cartpole-swingup_sparse-v0": ReferenceSettings(
        homotopy=(1.0,), bang_periods=(1.0, 1.5), pump_gains=(10.0,), search_max_iter=150
    ),
}


@dataclass(frozen=True)
class SolveRecord:
    """One NLP solve of :class:`FullHorizonReference`."""

    step: int
    """Suite control step of the decision (0 = the episode's start)."""
    kind: str
    """``"search"`` (the start's global search; ``guess`` and ``alpha`` say which solve), ``"resolve"``."""
    guess: str
    """The initial guess (``"zero"``, ``"bang T=1.5 +"``, ``"pump g=2 -"``; ``"shifted"`` for re-solves)."""
    alpha: float
    """The homotopy parameter of this solve (1 = the reward)."""
    solve_s: float
    """Wall time of the solve (s)."""
    status: str
    """IPOPT's return status."""
    iterations: int
    """IPOPT iterations."""
    objective: float
    """The NLP objective at the solution (the negative smooth return for ``alpha = 1``)."""
    plan_return: float
    """dm_control's reward summed along the plan's own states over the rest of the episode (the true reward)."""
    accepted: bool
    """Whether the plan was used; a rejected re-solve is a fallback to the shifted previous plan."""


def suite_reward(env_id: str) -> Callable[[Any, np.ndarray, np.ndarray], float]:
    """dm_control's reward of ``env_id`` as a function ``(params, x, u) -> float`` of the physics state and control."""
    full = dmc_env_id(env_id)
    if full == "dm_control/acrobot-swingup-v0":
        return dmc_acrobot_reward
    if full == "dm_control/pendulum-swingup-v0":
        return dmc_pendulum_reward
    if full == "dm_control/cartpole-swingup-v0":
        return dmc_cartpole_reward
    return _cartpole_sparse_reward


def _cartpole_sparse_reward(p: Any, x: np.ndarray, u: np.ndarray) -> float:
    """``cartpole.py`` ``Balance._get_reward(sparse=True)``: ``tolerance(slider, (-0.25, 0.25)) *
    tolerance(cos(hinge), (0.995, 1))`` (margin 0: indicators)."""
    del p, u
    return float(abs(float(x[0])) <= 0.25) * float(0.995 <= math.cos(float(x[1])) <= 1.0)


def _smooth_reward(env_id: str, task: Task, s: ReferenceSettings, x: ca.SX, u: ca.SX) -> tuple[ca.SX, ca.SX]:
    """``(R, S)`` at one control step: the reward (or its smooth stand-in) and the graded surrogate (module doc)."""
    p = task.params
    if env_id == "dm_control/acrobot-swingup-v0":
        dx, dz = dmc_acrobot_tip_to_target(p, x)
        d2 = dx**2 + dz**2
        d = ca.sqrt(ca.fmax(d2, p.target_radius**2))
        excess = (d - p.target_radius) / p.reward_margin
        return ca.exp(-0.5 * (excess * _SCALE) ** 2), d2
    if env_id == "dm_control/cartpole-swingup-v0":
        upright = (ca.cos(x[1]) + 1) / 2
        centered = (1 + gaussian_sx(x[0], p.centered_margin)) / 2
        small_control = (4 + 1 - (u[0] / p.control_margin) ** 2) / 5
        small_velocity = (1 + gaussian_sx(x[3], p.velocity_margin)) / 2
        return upright * centered * small_control * small_velocity, 1 - ca.cos(x[1])
    if env_id == "dm_control/pendulum-swingup-v0":
        excess = ca.fmax(math.cos(math.radians(p.angle_bound_deg)) - ca.cos(x[0]), 0) / s.reward_margin
        return ca.exp(-0.5 * (excess * _SCALE) ** 2), 1 - ca.cos(x[0])
    # cartpole-swingup_sparse
    angle = ca.fmax(0.995 - ca.cos(x[1]), 0) / s.reward_margin
    cart = ca.fmax(ca.fabs(x[0]) - 0.25, 0) / s.cart_margin
    return ca.exp(-0.5 * (angle * _SCALE) ** 2) * ca.exp(-0.5 * (cart * _SCALE) ** 2), 1 - ca.cos(x[1])


#: The state indices of each env's hinge angles (periodic).
_ANGLES: dict[str, tuple[int, ...]] = {
    "dm_control/acrobot-swingup-v0": (0, 1),
    "dm_control/pendulum-swingup-v0": (0,),
    "dm_control/cartpole-swingup-v0": (1,),
    "dm_control/cartpole-swingup_sparse-v0": (1,),
}


def swing_energy(env_id: str, task: Task) -> ca.Function:
    """``E(x)``: the mechanical energy (J) of the swinging part of ``env_id``'s model, ``0.5 v' M(q) v + V(q)``
    (:func:`~seagul_envs.tasks.dmc.mechanics.potential_energy` of the MJCF's bodies); for the cart-pole the pole's
    alone (the slider's velocity left out: pushing the cart is how the pole's energy is changed, not part of it)."""
    full = dmc_env_id(env_id)
    models: dict[str, Callable[[Any], ChainModel]] = {
        "dm_control/acrobot-swingup-v0": dmc_acrobot_model,
        "dm_control/pendulum-swingup-v0": dmc_pendulum_model,
        "dm_control/cartpole-swingup-v0": dmc_cartpole_model,
        "dm_control/cartpole-swingup_sparse-v0": dmc_cartpole_model,
    }
    model = models[full](task.params)
    n = model.nq
    x = ca.SX.sym("x", 2 * n)
    q, v = x[:n], x[n:]
    if full.startswith("dm_control/cartpole"):
        v = ca.vertcat(0, v[1])
    energy = 0.5 * ca.bilin(model.mass_matrix(q), v, v) + potential_energy(model.bodies, q, model.g)
    return ca.Function("swing_energy", [x], [energy])


def pump_signal(env_id: str, x: np.ndarray) -> float:
    """The velocity through which the actuator changes :func:`swing_energy` (up to sign and a positive factor):
    the pendulum's hinge velocity and the acrobot's elbow velocity (the power of the motor is ``gear u v``), the
    cart-pole's ``hinge_vel cos(hinge)`` (pushing the cart works on the pole through its hinge's horizontal
    acceleration)."""
    full = dmc_env_id(env_id)
    if full == "dm_control/pendulum-swingup-v0":
        return float(x[1])
    if full == "dm_control/acrobot-swingup-v0":
        return float(x[3])
    return float(x[3] * math.cos(x[1]))


class FullHorizonReference:
    """Receding full-horizon trajectory optimisation with the true model on one suite env (module docstring).

    ``env_id``: one of :data:`seagul_control.dmc.DMC_ENV_IDS` (or its short form); ``settings``: defaults from
    :data:`DEFAULT_SETTINGS`. Call it as ``ref(x, t)`` at every control step of an episode (``run_dmc_episode`` with
    ``hold=1`` does): it searches at ``t = 0``, re-solves every ``resolve_every`` steps and otherwise returns the
    current plan's control. ``reset()`` starts a new episode (``run_dmc_episode`` calls it).
    """

    def __init__(self, env_id: str, settings: ReferenceSettings | None = None) -> None:
        self.env_id = dmc_env_id(env_id)
        self.settings = settings or DEFAULT_SETTINGS[self.env_id]
        self.task = make_task(DMC_TASKS[self.env_id])
        self.name = "full-horizon reference"
        s = self.settings
        self.control_dt = float(self.task.control_period)
        self.nx = int(self.task.nx)
        self.n = EPISODE_STEPS // s.interval_steps
        self.u_low = float(self.task.u_low[0])
        self.u_high = float(self.task.u_high[0])
        self._reward_np = suite_reward(self.env_id)
        self._build()
        self.records: list[SolveRecord] = []
        self.reset()

    # ------------------------------------------------------------------------------------------ the NLP
    def _build(self) -> None:
        s, nx, n = self.settings, self.nx, self.n
        step = self.task.extras["mujoco_step"]
        x, u = ca.SX.sym("x", nx), ca.SX.sym("u", 1)
        xi, states = x, []
        reward: Any = 0
        surrogate: Any = 0
        for _ in range(s.interval_steps):
            xi = step(xi, u)
            r, sur = _smooth_reward(self.env_id, self.task, s, xi, u)
            reward, surrogate = reward + r, surrogate + sur
            states.append(xi)
        interval = ca.Function("reference_interval", [x, u], [xi, reward, surrogate])
        self._interval = interval
        self._energy = swing_energy(self.env_id, self.task)
        self._substates = ca.Function("reference_substates", [x, u], [ca.horzcat(*states)]).map(n)

        X = ca.MX.sym("X", nx, n + 1)
        U = ca.MX.sym("U", 1, n)
        x0 = ca.MX.sym("x0", nx)
        w = ca.MX.sym("w", 1, n)
        alpha = ca.MX.sym("alpha")
        x_next, R, S = interval.map(n)(X[:, :n], U)
        objective = ca.sum2(w * ((1 - alpha) * S - alpha * R)) + s.control_reg * ca.sumsqr(U)
        g = ca.vertcat(X[:, 0] - x0, ca.vec(X[:, 1:] - x_next))
        nlp: dict[str, Any] = {
            "x": ca.vertcat(ca.vec(X), ca.vec(U)),
            "p": ca.vertcat(x0, w.T, alpha),
            "f": objective,
            "g": g,
        }
        base: dict[str, Any] = {
            "expand": True,
            "print_time": False,
            "ipopt.print_level": 0,
            "ipopt.sb": "yes",
            "ipopt.tol": s.tol,
            "ipopt.acceptable_tol": 1e-4,
            "ipopt.acceptable_iter": 5,
        }
        self._nlp, self._options = nlp, base
        source: Any = nlp
        self.codegen_library: str | None = None
        if s.codegen:
            name = f"dmcref_{self.task.name}_n{n}_k{s.interval_steps}"
            try:
                plain = ca.nlpsol(name, "ipopt", nlp, {**base, "expand": False})
                lib = compile_nlp_library(plain, name, fingerprint=self.task.fingerprint())
                self.codegen_library = source = str(lib)
                base = {k: v for k, v in base.items() if k != "expand"}
            except (RuntimeError, OSError) as exc:
                warnings.warn(f"{name}: code generation unavailable ({exc}); solving interpreted", stacklevel=2)
        self._search_solver = ca.nlpsol(
            "reference_search", "ipopt", source, {**base, "ipopt.max_iter": s.search_max_iter}
        )
        self._resolve_solver = ca.nlpsol(
            "reference_resolve",
            "ipopt",
            source,
            {**base, "ipopt.max_iter": s.resolve_max_iter, "ipopt.max_wall_time": s.resolve_max_time},
        )
        lbx_x = np.tile(np.where(np.isfinite(self.task.x_low), self.task.x_low, -np.inf)[:, None], (1, n + 1))
        ubx_x = np.tile(np.where(np.isfinite(self.task.x_high), self.task.x_high, np.inf)[:, None], (1, n + 1))
        lbx_x[:, 0], ubx_x[:, 0] = -np.inf, np.inf  # the start is fixed by the constraint x_0 = x0
        self._lbx = np.concatenate([lbx_x.ravel(order="F"), np.full(n, self.u_low)])
        self._ubx = np.concatenate([ubx_x.ravel(order="F"), np.full(n, self.u_high)])
        self._ng = nx * (n + 1)

    def _pack(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        return np.concatenate([X.ravel(order="F"), U.ravel()])

    def _unpack(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        k = self.nx * (self.n + 1)
        return z[:k].reshape((self.nx, self.n + 1), order="F"), z[k:].copy()

    def _weights(self, step: int) -> np.ndarray:
        left = (EPISODE_STEPS - step) // self.settings.interval_steps
        return (np.arange(self.n) < left).astype(float)

    def _solve(
        self, solver: Any, x0: np.ndarray, X: np.ndarray, U: np.ndarray, step: int, alpha: float
    ) -> tuple[np.ndarray, np.ndarray, dict[str, Any], float, float, float]:
        """One IPOPT solve; returns ``(X, U, stats, objective, max defect, wall s)``."""
        p = np.concatenate([x0, self._weights(step), [alpha]])
        tic = time.perf_counter()
        sol = solver(x0=self._pack(X, U), p=p, lbx=self._lbx, ubx=self._ubx, lbg=0.0, ubg=0.0)
        wall = time.perf_counter() - tic
        z = np.asarray(sol["x"]).ravel()
        Xs, Us = self._unpack(z)
        defect = float(np.max(np.abs(np.asarray(sol["g"]).ravel()))) if self._ng else 0.0
        return Xs, np.clip(Us, self.u_low, self.u_high), solver.stats(), float(sol["f"]), defect, wall

    # ------------------------------------------------------------------------------------------ plans
    def rollout(self, x0: np.ndarray, policy: Callable[[int, np.ndarray], float]) -> tuple[np.ndarray, np.ndarray]:
        """The plan ``(X, U)`` of holding ``policy(k, x_k)`` (clipped to the bounds) over each interval ``k`` from
        ``x0``, through the exact model."""
        X = np.zeros((self.nx, self.n + 1))
        U = np.zeros(self.n)
        X[:, 0] = x0
        for k in range(self.n):
            U[k] = float(np.clip(policy(k, X[:, k]), self.u_low, self.u_high))
            X[:, k + 1] = np.asarray(self._interval(X[:, k], U[k])[0]).ravel()
        return X, U

    def plan_return(self, X: np.ndarray, U: np.ndarray, step: int) -> float:
        """dm_control's reward summed over the control steps from ``step`` to the episode's end along the plan
        ``(X, U)`` started at ``step`` (each interval integrated from its own node, so an optimizer's plan is
        scored on its own states, not on an open-loop replay that the unstable upright would amplify)."""
        left = (EPISODE_STEPS - step) // self.settings.interval_steps
        sub = np.asarray(self._substates(X[:, : self.n], U[None, :]))  # nx x (n * interval_steps)
        total = 0.0
        params = self.task.params
        for k in range(left):
            for j in range(self.settings.interval_steps):
                total += self._reward_np(params, sub[:, k * self.settings.interval_steps + j], U[k : k + 1])
        return total

    def catch(self, X: np.ndarray, U: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(X, U)`` cut at the node nearest the balanced goal (smallest ``task.terminal_cost``) and continued at
        the goal at rest with zero control (angles at the multiple of ``2 pi`` nearest the cut node's; the cart at
        0); see :attr:`ReferenceSettings.catch_guesses`."""
        lf = np.asarray(self.task.terminal_cost.map(self.n + 1)(X)).ravel()
        k = int(np.argmin(lf))
        goal = np.zeros(self.nx)
        for i in _ANGLES[self.env_id]:
            goal[i] = 2 * math.pi * round(X[i, k] / (2 * math.pi))
        X, U = X.copy(), U.copy()
        X[:, k + 1 :] = goal[:, None]
        U[k:] = 0.0
        return X, U

    def guesses(self, x0: np.ndarray) -> list[tuple[str, np.ndarray, np.ndarray]]:
        """The search's initial guesses from ``x0`` (module docstring): ``[(name, X, U)]``, each a rollout."""
        s = self.settings
        h = s.interval_steps * self.control_dt
        out: list[tuple[str, np.ndarray, np.ndarray]] = []
        if s.zero_guess:
            out.append(("zero", *self.rollout(x0, lambda k, x: 0.0)))
        for period in s.bang_periods:
            for phase in s.bang_phases:
                for sign in (1.0, -1.0):

                    def bang(
                        k: int, x: np.ndarray, period: float = period, phase: float = phase, sign: float = sign
                    ) -> float:
                        wave = math.sin(2 * math.pi * ((k + 0.5) * h / period + phase))
                        return sign * (1.0 if wave >= 0 else -1.0)

                    tag = f"bang T={period:g}" + (f" phase={phase:g}" if phase else "") + (" +" if sign > 0 else " -")
                    out.append((tag, *self.rollout(x0, bang)))
        target = float(self._energy(np.zeros(self.nx)))
        for gain in s.pump_gains:
            for sign in (1.0, -1.0):

                def pump(k: int, x: np.ndarray, gain: float = gain * sign) -> float:
                    return gain * (target - float(self._energy(x))) * pump_signal(self.env_id, x)

                out.append((f"energy k={gain:g} {'+' if sign > 0 else '-'}", *self.rollout(x0, pump)))
        if s.catch_guesses:
            out = [(name, *self.catch(X, U)) for name, X, U in out]
        return out

    # ------------------------------------------------------------------------------------------ decisions
    def reset(self) -> None:
        """Forget the plan and the records: the next call is an episode's start (a new global search)."""
        self.records = []
        self._plan: tuple[np.ndarray, np.ndarray] | None = None
        self._plan_step = 0

    def _record(
        self, step: int, kind: str, guess: str, alpha: float, out: tuple[Any, ...], ret: float, ok: bool
    ) -> None:
        _, _, stats, obj, _, wall = out
        self.records.append(
            SolveRecord(
                step=step,
                kind=kind,
                guess=guess,
                alpha=float(alpha),
                solve_s=float(wall),
                status=str(stats.get("return_status", "unknown")),
                iterations=int(stats.get("iter_count", -1)),
                objective=obj,
                plan_return=float(ret),
                accepted=ok,
            )
        )

    def _usable(self, out: tuple[Any, ...]) -> bool:
        _, U, stats, obj, defect, _ = out
        solved = str(stats.get("return_status", "")) in _SOLVED
        return bool(np.isfinite(obj) and np.all(np.isfinite(U)) and (solved or defect <= self.settings.feasibility_tol))

    def search(self, x0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The start's global search from ``x0`` (module docstring): the best plan over the guesses (every solve
        recorded). Raises ``RuntimeError`` if no guess gives a usable plan."""
        best: tuple[float, np.ndarray, np.ndarray] | None = None
        nearest: tuple[float, np.ndarray, np.ndarray] | None = None  # the finite plan with the smallest defect
        for name, X, U in self.guesses(x0):
            for alpha in self.settings.homotopy:
                out = self._solve(self._search_solver, x0, X, U, 0, alpha)
                ok = self._usable(out)
                final = alpha == self.settings.homotopy[-1]
                if ok or (not final and np.all(np.isfinite(out[0])) and np.all(np.isfinite(out[1]))):
                    X, U = out[0], out[1]  # an unconverged intermediate stage is still the next stage's guess
                ret = self.plan_return(out[0], out[1], 0) if final and ok else float("nan")
                self._record(0, "search", name, alpha, out, ret, ok)
                if final and ok and (best is None or ret > best[0]):
                    best = (ret, out[0], out[1])
                finite = bool(np.all(np.isfinite(out[0])) and np.all(np.isfinite(out[1])))
                if final and finite and (nearest is None or out[4] < nearest[0]):
                    nearest = (out[4], out[0], out[1])
        if best is not None:
            return best[1], best[2]
        if nearest is None:
            raise RuntimeError(f"{self.env_id}: no initial guess gave a finite plan from x0 = {x0.tolist()}")
        # No guess converged: act on the most nearly feasible plan; the re-solves start from it.
        return nearest[1], nearest[2]

    def _shifted(self, m: int) -> tuple[np.ndarray, np.ndarray]:
        assert self._plan is not None
        X, U = self._plan
        Xs = np.concatenate([X[:, m:], np.repeat(X[:, -1:], m, axis=1)], axis=1)
        Us = np.concatenate([U[m:], np.zeros(m)])
        return Xs, Us

    def resolve(self, x: np.ndarray, step: int) -> bool:
        """Re-solve at control step ``step`` from the measured ``x``, warm-started from the shifted plan; the new
        plan replaces the old one if usable, else the old one is kept (a recorded fallback). Returns acceptance."""
        m = (step - self._plan_step) // self.settings.interval_steps
        X, U = self._shifted(m)
        X[:, 0] = x
        out = self._solve(self._resolve_solver, x, X, U, step, 1.0)
        ok = self._usable(out)
        ret = self.plan_return(out[0], out[1], step) if ok else float("nan")
        self._record(step, "resolve", "shifted", 1.0, out, ret, ok)
        if ok:
            self._plan = (out[0], out[1])
            self._plan_step = step
        return ok

    def __call__(self, x: np.ndarray, t: float) -> np.ndarray:
        """The action at physics state ``x`` and episode time ``t`` (s)."""
        x = np.asarray(x, dtype=float).ravel()
        step = round(t / self.control_dt)
        if self._plan is None or step == 0:
            self.reset()
            self._plan = self.search(x)
            self._plan_step = step
        elif step % self.settings.resolve_every == 0:
            self.resolve(x, step)
        k = (step - self._plan_step) // self.settings.interval_steps
        U = self._plan[1]
        u = U[k] if k < U.size else 0.0
        return np.array([float(np.clip(u, self.u_low, self.u_high))])

    @property
    def plan(self) -> tuple[np.ndarray, np.ndarray]:
        """The plan the actions come from: states ``X`` (``nx x (n + 1)``, node 0 at :attr:`plan_step`) and controls
        ``U`` (``n``, each held over ``interval_steps`` control steps). ``RuntimeError`` before an episode's start."""
        if self._plan is None:
            raise RuntimeError("no plan yet: call the reference at an episode's start first")
        return self._plan

    @property
    def plan_step(self) -> int:
        """The control step at which :attr:`plan`'s node 0 lies (the last accepted solve's)."""
        return self._plan_step

    @property
    def failed_solves(self) -> int:
        """Re-solves of the episode that fell back to the shifted previous plan."""
        return sum(1 for r in self.records if r.kind == "resolve" and not r.accepted)

    def summary(self) -> dict[str, Any]:
        """The episode's solves in numbers: search wall time, re-solve times (median, 95th percentile, ms),
        failures, and the chosen guess."""
        search = [r for r in self.records if r.kind == "search"]
        res = [r for r in self.records if r.kind == "resolve"]
        finals = [r for r in search if r.alpha == 1.0 and r.accepted]
        best = max(finals, key=lambda r: r.plan_return) if finals else None
        ms = np.array([r.solve_s for r in res]) * 1e3
        return {
            "search_s": float(sum(r.solve_s for r in search)),
            "search_solves": len(search),
            "best_guess": best.guess if best else None,
            "search_plan_return": best.plan_return if best else None,
            "resolves": len(res),
            "resolve_ms_median": float(np.median(ms)) if ms.size else None,
            "resolve_ms_p95": float(np.percentile(ms, 95)) if ms.size else None,
            "failed_solves": self.failed_solves,
        }


def with_settings(env_id: str, **changes: Any) -> ReferenceSettings:
    """:data:`DEFAULT_SETTINGS` of ``env_id`` with ``changes`` (``dataclasses.replace``)."""
    return replace(DEFAULT_SETTINGS[dmc_env_id(env_id)], **changes)
