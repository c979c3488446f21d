"""LQR references: discrete LQR at the goal (acrobot) and time-varying LQR along a nominal trajectory (glider).

Both follow stable-baselines3's predictor protocol (``predict(observation, state, episode_start, deterministic)``),
so the closed-loop evaluation and ``evaluate_policy`` run them exactly like the MPC and a trained PPO model.
Observations are ``[x, time_to_go]`` as the seagul envs emit them (single ``(nx + 1,)`` or batched ``(n, nx + 1)``).

* :class:`LQRPolicy` for a task whose goal is an equilibrium (the acrobot): ``u = clip(-K (x - x*))`` with ``K``
  from the discrete algebraic Riccati equation of the **env's own discretisation** (zero-order hold over the
  control period, the simulator's RK4 substeps), stage weights ``dt Q`` and ``dt R`` (the task's running cost);
  the task's periodic angles (``task.periodic``) enter ``x - x*`` wrapped to ``[-pi, pi)``.
* For the glider (no equilibrium at the perch) :class:`LQRPolicy` is a time-varying LQR: one full-horizon solve at
  the nominal start with a fixed step equal to the control period gives ``(x_k, u_k)`` on the control grid; the
  backward Riccati recursion of the linearised one-period maps gives ``K_k``, and the feedback at time to go
  ``tau`` uses the knot ``k = N - round(tau / dt)``. Tracking weights are the task's terminal weights (documented
  choice: the glider's running cost only penalises the input, which would give zero state feedback).
"""

from __future__ import annotations

import io
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np
import scipy.linalg

from seagul_control.transcription import Transcription, TranscriptionOptions
from seagul_envs.tasks.base import Task

#: Format tag of :meth:`LQRPolicy.save` files.
LQR_FORMAT_TAG = "seagul-lqr"


def _npy(arr: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, np.asarray(arr, dtype=float), allow_pickle=False)
    return buffer.getvalue()


# ---------------------------------------------------------------------------------------------- observations
def split_observation(observation: Any, nx: int, name: str = "policy") -> tuple[np.ndarray, np.ndarray, bool]:
    """``observation`` -> ``(states (n, nx) float64, times to go (n,), batched)``; raises ValueError on bad input.

    Accepts one observation of shape ``(nx + 1,)`` or a batch ``(n, nx + 1)`` (SB3's vectorised envs).
    """
    obs = np.asarray(observation, dtype=np.float64)
    if obs.ndim == 1 and obs.shape[0] == nx + 1:
        batched = False
        obs = obs[None, :]
    elif obs.ndim == 2 and obs.shape[1] == nx + 1:
        batched = True
    else:
        raise ValueError(
            f"{name}: observation must have shape ({nx + 1},) or (n_envs, {nx + 1}) = [state ({nx}), time to go], "
            f"got shape {obs.shape}"
        )
    if not np.all(np.isfinite(obs)):
        bad = np.argwhere(~np.isfinite(obs))[:, 0].tolist()
        raise ValueError(f"{name}: observation contains NaN or inf (rows {sorted(set(bad))}): {obs.tolist()}")
    return obs[:, :nx].copy(), obs[:, nx].copy(), batched


def episode_start_mask(episode_start: Any, n: int) -> np.ndarray:
    """``episode_start`` (None, a bool or an array of ``n`` bools) as a boolean array of length ``n``."""
    if episode_start is None:
        return np.zeros(n, dtype=bool)
    mask = np.asarray(episode_start, dtype=bool).reshape(-1)
    if mask.size == 1:
        return np.full(n, bool(mask[0]))
    if mask.size != n:
        raise ValueError(f"episode_start must have one entry per observation ({n}), got {mask.size}")
    return mask


def output_actions(actions: np.ndarray, batched: bool) -> np.ndarray:
    """Float32 actions shaped like the observations: ``(nu,)`` or ``(n, nu)`` (the envs' Box dtype)."""
    actions = np.asarray(actions, dtype=np.float32)
    return actions if batched else actions[0]


# ------------------------------------------------------------------------------------------------ LQR maths
def discrete_lqr(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Infinite-horizon discrete LQR: ``(K, P)`` with ``u = -K x`` and ``P`` the DARE solution."""
    P = scipy.linalg.solve_discrete_are(A, B, Q, R)
    P = 0.5 * (P + P.T)
    K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
    return K, P


def linearize_step(step: ca.Function, nx: int, nu: int) -> ca.Function:
    """``(x, u) -> (A, B)``: Jacobians of a one-period map ``step(x, u) -> x_next``."""
    x, u = ca.SX.sym("x", nx), ca.SX.sym("u", nu)
    xn = step(x, u)
    return ca.Function("linearization", [x, u], [ca.jacobian(xn, x), ca.jacobian(xn, u)])


def goal_linearization(task: Task, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """``(A, B)`` of the env's one-period map (zero-order hold over ``dt``) at the goal with zero input."""
    jac = linearize_step(task.simulator(dt), task.nx, task.nu)
    A, B = (np.asarray(m) for m in jac(task.goal, np.zeros(task.nu)))
    return A, B


@dataclass
class NominalTrajectory:
    """A trajectory on the control grid: ``states (N + 1, nx)``, ``controls (N, nu)``, step ``dt``."""

    states: np.ndarray
    controls: np.ndarray
    dt: float


# ------------------------------------------------------------------------------------------------- policies
class LQRPolicy:
    """LQR reference with SB3's predictor protocol (see the module docstring for the two variants).

    Args:
        task: the task.
        dt: control period (default: the task's).
        Q: state weight (default: the task's, ``task.profile.lqr_weights``: ``profile.lqr_Q``, else ``extras["Q"]``
            at an equilibrium goal and ``extras["Qf"]`` for tracking, else the identity).
        R: input weight (default: ``profile.lqr_R``, else ``extras["R"]`` at an equilibrium goal and ``0.01 * I``
            for tracking, else the identity).
        nominal: a given nominal trajectory for the time-varying variant (default: solved once at construction).

    :meth:`save` writes the policy's settings and the task's fingerprint to one zip file; :meth:`load` recomputes
    the gains and checks them against the stored ones.
    """

    def __init__(
        self,
        task: Task,
        dt: float | None = None,
        Q: np.ndarray | None = None,
        R: np.ndarray | None = None,
        nominal: NominalTrajectory | None = None,
    ) -> None:
        self.task = task
        self._given = (Q, R, nominal)  # what save() stores: the settings, not the derived gains
        self.dt = float(task.control_period if dt is None else dt)
        if not (np.isfinite(self.dt) and self.dt > 0):
            raise ValueError(f"LQRPolicy: dt must be a positive number of seconds, got {dt!r}")
        # An equilibrium goal (zero drift) gets the stationary LQR; otherwise track a nominal trajectory.
        self.time_varying = nominal is not None or not task.goal_is_equilibrium()
        self.last_info: list[dict[str, Any]] = []
        Q_task, R_task = task.profile.lqr_weights(task, self.time_varying)
        if not self.time_varying:
            Qm = np.asarray(Q_task if Q is None else Q, dtype=float)
            Rm = np.asarray(R_task if R is None else R, dtype=float)
            self.A, self.B = goal_linearization(task, self.dt)
            self.K, self.P = discrete_lqr(self.A, self.B, self.dt * Qm, self.dt * Rm)
            self.nominal = None
            self.gains = self.K[None]
        else:
            Qm = np.asarray(Q_task if Q is None else Q, dtype=float)
            Rm = np.asarray(R_task if R is None else R, dtype=float)
            self.nominal = solve_nominal(task, self.dt) if nominal is None else nominal
            self.gains = tvlqr_gains(task, self.nominal, Qm, Rm)
            self.K = self.gains[0]

    # ------------------------------------------------------------------ actions
    def action(self, x: np.ndarray, tau: float) -> np.ndarray:
        """The clipped feedback input for state ``x`` and time to go ``tau``."""
        if self.nominal is None:
            u = -self.K @ self.task.state_error(x)  # periodic angles wrapped: a full turn is the same state
        else:
            n = self.nominal.controls.shape[0]
            k = int(np.clip(n - round(tau / self.dt), 0, n - 1))
            u = self.nominal.controls[k] - self.gains[k] @ (x - self.nominal.states[k])
        return np.clip(u, self.task.u_low, self.task.u_high)

    def predict(
        self,
        observation: Any,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        """SB3 predictor protocol: actions for one or a batch of observations; ``state`` is passed through."""
        xs, taus, batched = split_observation(observation, self.task.nx, "LQRPolicy")
        episode_start_mask(episode_start, xs.shape[0])
        actions = np.stack([self.action(x, t) for x, t in zip(xs, taus, strict=True)])
        self.last_info = [{"source": "lqr"} for _ in range(xs.shape[0])]
        return output_actions(actions, batched), state

    # ------------------------------------------------------------------ saving
    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the policy to one zip file: ``data.json`` (``{"format": "seagul-lqr", "version": 1, "class", "dt",
        "Q", "R", "time_varying", "task_name", "task_fingerprint", "seagul_version"}``), the gains
        (``gains.npy``) and a given nominal trajectory (``nominal.npz``); returns the path."""
        # seagul_control.mpc (its base module) imports this module at module level: import cycle.
        from seagul_control.mpc.saving import FORMAT_VERSION, seagul_version, write_archive

        Q, R, nominal = self._given
        data = {
            "format": LQR_FORMAT_TAG,
            "version": FORMAT_VERSION,
            "class": type(self).__name__,
            "dt": self.dt,
            "Q": None if Q is None else np.asarray(Q, dtype=float).tolist(),
            "R": None if R is None else np.asarray(R, dtype=float).tolist(),
            "time_varying": self.time_varying,
            "task_name": self.task.name,
            "task_fingerprint": self.task.fingerprint(),
            "seagul_version": seagul_version(),
        }
        members = {"gains.npy": _npy(self.gains)}
        if nominal is not None:
            buffer = io.BytesIO()
            np.savez(buffer, states=nominal.states, controls=nominal.controls, dt=np.array(nominal.dt))
            members["nominal.npz"] = buffer.getvalue()
        return write_archive(path, data, members)

    @classmethod
    def load(cls, path: str | os.PathLike[str], task: Task | None = None) -> LQRPolicy:
        """Rebuild a policy written by :meth:`save` for ``task`` (default ``make_task`` of the stored name).

        Raises:
            ValueError: not an LQR file, a task whose fingerprint differs from the stored one, or recomputed gains
                that differ from the stored ones (another SciPy or CasADi may solve the Riccati equation or the
                nominal trajectory differently: rebuild the policy and save it again).
        """
        from seagul_control.mpc.saving import read_archive, resolve_saved_task

        data, members = read_archive(path, LQR_FORMAT_TAG)
        task = resolve_saved_task(data, task, path)
        nominal = None
        if "nominal.npz" in members:
            with np.load(io.BytesIO(members["nominal.npz"]), allow_pickle=False) as arrays:
                nominal = NominalTrajectory(arrays["states"], arrays["controls"], float(arrays["dt"]))
        Q, R = data.get("Q"), data.get("R")
        policy = cls(
            task,
            dt=float(data["dt"]),
            Q=None if Q is None else np.asarray(Q, dtype=float),
            R=None if R is None else np.asarray(R, dtype=float),
            nominal=nominal,
        )
        stored = np.load(io.BytesIO(members["gains.npy"]), allow_pickle=False)
        if stored.shape != policy.gains.shape or not np.allclose(policy.gains, stored, rtol=1e-6, atol=1e-9):
            diff = np.max(np.abs(policy.gains - stored)) if stored.shape == policy.gains.shape else float("nan")
            raise ValueError(
                f"{os.fspath(path)!r}: the recomputed LQR gains differ from the stored ones (shape {policy.gains.shape}"
                f" against {stored.shape}, largest difference {diff:.3g}); rebuild the policy with LQRPolicy(task) "
                "and save it again"
            )
        return policy


def solve_nominal(
    task: Task, dt: float, x_init: np.ndarray | None = None, tau: float | None = None
) -> NominalTrajectory:
    """One full-horizon solve (fixed step ``dt``, the task's terminal box) from the centre of X0 at nominal ``tau``."""
    x_init = 0.5 * (task.x0_low + task.x0_high) if x_init is None else np.asarray(x_init, dtype=float)
    tau = task.tau_nominal if tau is None else float(tau)
    n = max(1, round(tau / dt))
    trans = Transcription(task, n, TranscriptionOptions(free_time=False, step=dt, final_box=True, solver="ipopt"))
    sol = trans.solve(x_init, n * dt)
    if not sol.success:
        raise RuntimeError(f"{task.name}: nominal trajectory solve failed ({sol.status}); cannot build the TVLQR")
    return NominalTrajectory(states=sol.states, controls=sol.controls, dt=dt)


def tvlqr_gains(task: Task, nominal: NominalTrajectory, Q: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Backward Riccati recursion of the env's one-period maps along ``nominal``; ``(N, nu, nx)`` gains."""
    jac = linearize_step(task.simulator(nominal.dt), task.nx, task.nu)
    n = nominal.controls.shape[0]
    P = np.asarray(Q, dtype=float)
    Qd, Rd = nominal.dt * Q, nominal.dt * R
    gains = np.zeros((n, task.nu, task.nx))
    for k in range(n - 1, -1, -1):
        A, B = (np.asarray(m) for m in jac(nominal.states[k], nominal.controls[k]))
        K = np.linalg.solve(Rd + B.T @ P @ B, B.T @ P @ A)
        P = Qd + A.T @ P @ (A - B @ K)
        P = 0.5 * (P + P.T)
        gains[k] = K
    return gains
