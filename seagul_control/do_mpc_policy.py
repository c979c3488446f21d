"""do-mpc as a peer MPC: the task's own short-horizon problem built and solved by do-mpc (https://www.do-mpc.com).

:class:`DoMPCPolicy` follows the same predictor protocol as :class:`~seagul_control.lqr.LQRPolicy` and
:class:`~seagul_control.mpc.LimitedLookaheadMPC` (``predict(observation, state, episode_start, deterministic)`` on
observations ``[x, time_to_go]``), so the closed-loop evaluation runs and times it like the project's MPC. do-mpc is
an optional extra (``pip install 'seagul[anchors]'``); it is imported only when a policy is built.

**Identical to the project's MPC** (``LimitedLookaheadMPC(task, None, horizon=N)``, i.e. without a value function):

* the discrete system: a do-mpc ``'discrete'`` model whose transition is the task's own one-step RK4 map
  ``task.rk4_step(substeps)(x, u, dt)`` with ``dt = task.control_period`` and, by default, the same substeps as the
  project's lookahead (``task.rk4_substeps``; acrobot 4 per 0.1 s). The env integrates the same dynamics with finer
  substeps (``task.simulator(dt)``: 20 per 0.1 s for the acrobot); ``substeps`` sets the model's, e.g.
  ``task.simulator_substeps(dt)`` for the env's map, and then the project's MPC needs the same ``substeps`` to
  optimise the same problem;
* the cost: ``sum_{k<N} dt * l(x_k, u_k) + l_f(x_N)`` with ``l = task.stage_cost`` (do-mpc ``lterm``) and ``l_f =
  task.terminal_cost``, the task's quadratic terminal cost (acrobot: ``(x - x*)' Qf (x - x*)``, ``Qf =
  task.extras["Qf"]``, the DARE matrix), as the project's MPC uses when it has no value function (do-mpc
  ``mterm``); no input-rate penalty (``set_rterm`` with weight 0);
* the constraints: the input box ``[u_low, u_high]`` at every stage and the finite path bounds
  ``[x_low, x_high]`` on the knots ``1..N`` (``use_terminal_bounds``: do-mpc's ``bounds`` stop at ``N - 1``; see
  below for a task with a terminal box);
* a constant horizon ``N`` of fixed steps ``dt`` while the episode lasts longer than the lookahead, and for a task
  without a terminal box (the acrobot) to the end: the project's ``end_phase="switch"``.

**What differs:**

* solver: IPOPT (MUMPS) on do-mpc's full-space multiple-shooting NLP (states and inputs are variables, one
  defect per step), SX graph, not compiled; the project's acrobot lookahead is the condensed projected-Newton
  solver (:mod:`seagul_control.shooting`, inputs only), its other problems fatrop/IPOPT on the transcription, JIT-
  compiled. Both stop at a KKT tolerance ``tol`` (default the project's 1e-6) within ``max_iter`` iterations
  (default the project's 50) and ``max_solve_time`` seconds (IPOPT's ``max_wall_time``);
* warm start: do-mpc's own, i.e. the previous solution *unshifted* (``opt_x_num``) as the primal guess (do-mpc
  also passes the previous multipliers, which IPOPT ignores without ``warm_start_init_point``); the project shifts
  its previous plan by one step and reuses the multipliers. A new episode starts from do-mpc's default guess
  (``mpc.x0`` = the start at every knot, ``u = 0``: :meth:`do_mpc.controller.MPC.set_initial_guess`); the project's
  from a zero-input rollout;
* a failed solve: do-mpc returns IPOPT's last iterate and this policy applies it (clipped) as a do-mpc user would,
  recording the status; only a non-finite input is replaced (by zero, the guess re-initialised). The project's MPC
  falls back to its previous plan, then to the LQR;
* the end of a free-time episode (the glider, a task with a terminal box): the project switches to a final problem
  of ``N`` knots whose free steps sum to the time to go exactly, with the terminal box and the path bounds as an L1
  penalty. do-mpc has one horizon of fixed steps, so here (``end_phase="mask"``) the episode's end is a
  time-varying parameter: stages after knot ``k_end = round(tau / dt)`` cost nothing, ``l_f`` is charged at
  ``x_{k_end}`` (at ``x_N`` while ``k_end > N``), and the path bounds on the knots ``1..k_end`` and the terminal
  box at ``k_end`` are do-mpc soft constraints (slacks with a linear, i.e. exact L1, penalty of the task's
  ``profile.mpc.final_soft_weight``) in every phase: do-mpc's ``bounds`` are the same at every knot, and a knot
  past the episode's end must not be bounded (the glider flies on past the perch). The project's lookahead bounds
  its knots hard; where they can be met and the weight exceeds their multipliers the two solutions coincide. The
  end knot is the episode's end only when ``tau`` is a multiple of ``dt`` (the glider's nominal 0.8 s is). With
  the task's quadratic ``l_f`` over a 0.25 s lookahead neither MPC perches the glider (from X0's centre both
  overshoot the perch and leave the path bounds at step 27): the glider needs the learned terminal cost;
* not offered (NotImplementedError): free step lengths (``steps="free"``: ``h_k`` as decision variables with
  ``sum(h) <= tau``; do-mpc's steps are its fixed ``t_step``) and a learned terminal cost (``terminal`` other than
  ``"lqr"``: this module is the peer of the project's MPC with the task's own terminal cost).

The glider's state-dependent input limit (the env clips an elevator rate that would drive ``phi`` past its stop) is
the path bound on ``phi`` in both MPCs, so their plans never need the clip.
"""

from __future__ import annotations

import importlib
import time
import warnings
from typing import Any

import casadi as ca
import numpy as np

from seagul_control.lqr import episode_start_mask, output_actions, split_observation
from seagul_control.mpc import MPCStepInfo
from seagul_envs.tasks.base import Task

INSTALL_HINT = "do-mpc is not installed: pip install 'seagul[anchors]'"

_TIME_EPS = 1e-4  # a remaining time below this counts as zero (observations are float32)


def _import_do_mpc() -> Any:
    """The ``do_mpc`` module (its import-time notices about optional features it lacks silenced)."""
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=r".*(ONNX|opcua) feature is not available.*")
            return importlib.import_module("do_mpc")
    except ImportError as exc:
        raise ImportError(INSTALL_HINT) from exc


class DoMPCPolicy:
    """A do-mpc MPC of the task's own problem at horizon ``N`` (see the module docstring for what matches the
    project's MPC and what differs).

    Args:
        task: the task.
        horizon: number of steps ``N`` of the constant horizon.
        terminal: the terminal cost; ``"lqr"`` (the only one): the task's quadratic terminal cost ``l_f``.
        dt: step and control period (default: the task's).
        substeps: RK4 substeps per step of the model (default: the task's, as the project's MPC).
        steps: ``"fixed"`` (the only one do-mpc can express; ``"free"`` raises NotImplementedError).
        end_phase: ``"switch"`` (constant horizon and ``l_f`` at ``x_N`` to the end) or ``"mask"`` (stages past the
            episode's end cost nothing, ``l_f`` and the terminal box at the end knot); default ``"mask"`` for a task
            with a terminal box (the glider), ``"switch"`` otherwise, as the project's ``end_phase`` default.
        max_iter: IPOPT iteration limit per step.
        tol: IPOPT tolerance.
        max_solve_time: IPOPT's wall-time limit per step (s; None: none).
        soft_weight: L1 penalty of the path bounds and the terminal box in ``"mask"`` (default:
            ``task.profile.mpc.final_soft_weight``, else 1e4).
        solver_options: extra ``nlpsol`` options (e.g. ``{"ipopt.linear_solver": "ma27"}``).

    Attributes:
        solve_times: wall time (s) of every ``mpc.make_step`` call (do-mpc's whole step, IPOPT included).
        ipopt_times: IPOPT's own wall time (``t_wall_total``) of every step.
        statuses: ``(return_status, success)`` of every step.
        stats: one :class:`~seagul_control.mpc.MPCStepInfo` per step (read, and cleared per episode, by
            :func:`seagul_control.evaluation.run_policy_episode`); ``source`` is ``"solver"`` for a converged solve,
            ``"unconverged"`` for IPOPT's last iterate, ``"zero"`` for a non-finite one replaced.

    Raises:
        ImportError: do-mpc is not installed.
        NotImplementedError: a feature do-mpc cannot express here (free steps, a learned terminal cost).
        ValueError: a bad horizon or option.
    """

    name = "DoMPC"

    def __init__(
        self,
        task: Task,
        horizon: int,
        terminal: str = "lqr",
        *,
        dt: float | None = None,
        substeps: int | None = None,
        steps: str = "fixed",
        end_phase: str | None = None,
        max_iter: int = 50,
        tol: float = 1e-6,
        max_solve_time: float | None = 5.0,
        soft_weight: float | None = None,
        solver_options: dict[str, Any] | None = None,
    ) -> None:
        self._do_mpc = _import_do_mpc()
        if isinstance(horizon, bool) or not isinstance(horizon, (int, np.integer)) or int(horizon) < 1:
            raise ValueError(f"{self.name}: horizon must be an integer >= 1 step, got {horizon!r}")
        if terminal != "lqr":
            raise NotImplementedError(
                f"{self.name}: terminal={terminal!r}: only the task's quadratic terminal cost ('lqr') is built; a "
                "learned terminal cost (a value network) is not offered in the do-mpc peer"
            )
        if steps == "free":
            raise NotImplementedError(
                f"{self.name}: free step lengths (h_k as decision variables with sum(h) <= time to go) cannot be "
                "expressed in do-mpc's model, whose steps are the fixed t_step"
            )
        if steps != "fixed":
            raise ValueError(f"{self.name}: steps must be 'fixed' (or 'free', not supported), got {steps!r}")
        has_box = bool(np.any(np.isfinite(task.x_final_low)) or np.any(np.isfinite(task.x_final_high)))
        end_phase = ("mask" if has_box else "switch") if end_phase is None else end_phase
        if end_phase not in ("switch", "mask"):
            raise ValueError(f"{self.name}: end_phase must be 'switch' or 'mask', got {end_phase!r}")
        self.task = task
        self.horizon = int(horizon)
        self.terminal = terminal
        self.dt = float(task.control_period if dt is None else dt)
        if not (np.isfinite(self.dt) and self.dt > 0):
            raise ValueError(f"{self.name}: dt must be a positive number of seconds, got {dt!r}")
        self.substeps = int(task.rk4_substeps if substeps is None else substeps)
        if self.substeps < 1:
            raise ValueError(f"{self.name}: substeps must be >= 1, got {substeps!r}")
        self.end_phase = end_phase
        if soft_weight is None:
            soft_weight = task.profile.mpc.final_soft_weight or 1e4
        self.soft_weight = float(soft_weight)
        if not (np.isfinite(self.soft_weight) and self.soft_weight > 0):
            raise ValueError(f"{self.name}: soft_weight must be a positive number, got {soft_weight!r}")
        if int(max_iter) < 1 or not (np.isfinite(tol) and tol > 0):
            raise ValueError(f"{self.name}: max_iter must be >= 1 and tol > 0, got {max_iter!r} and {tol!r}")
        options: dict[str, Any] = {
            "ipopt.print_level": 0,
            "print_time": 0,
            "record_time": True,  # IPOPT's own t_wall_total in the stats
            "ipopt.sb": "yes",
            "ipopt.max_iter": int(max_iter),
            "ipopt.tol": float(tol),
        }
        if max_solve_time is not None:
            if not (np.isfinite(max_solve_time) and max_solve_time > 0):
                raise ValueError(f"{self.name}: max_solve_time must be a positive number or None, got {max_solve_time}")
            options["ipopt.max_wall_time"] = float(max_solve_time)
        self.nlpsol_opts = {**options, **(solver_options or {})}
        self._mpcs: dict[int, Any] = {}
        self._taus: dict[int, float] = {}
        self._fresh: set[int] = set()
        """Envs whose warm start was dropped (:meth:`reset`): their next step starts from the default guess."""
        self.solve_times: list[float] = []
        self.ipopt_times: list[float] = []
        self.statuses: list[tuple[str, bool]] = []
        self.stats: list[MPCStepInfo] = []
        self.last_info: list[MPCStepInfo] = []
        self._mpcs[0] = self._build(0)  # env 0's MPC now: a bad option fails at construction

    # ------------------------------------------------------------------ building
    def _build(self, env_index: int) -> Any:
        """A set-up do-mpc MPC (one per env: do-mpc keeps one warm start per object)."""
        do_mpc, task, n = self._do_mpc, self.task, self.horizon
        model = do_mpc.model.Model("discrete", "SX")
        step = task.rk4_step(self.substeps)
        x = model.set_variable(var_type="_x", var_name="x", shape=(task.nx, 1))
        u = model.set_variable(var_type="_u", var_name="u", shape=(task.nu, 1))
        mask = self.end_phase == "mask"
        if mask:
            # Knot k lies before the episode's end (w_stage), is its end (w_end); knot k + 1 lies inside the episode
            # (w_in), is its end (w_next).
            for name in ("w_stage", "w_end", "w_in", "w_next"):
                model.set_variable(var_type="_tvp", var_name=name)
        model.set_rhs("x", step(x, u, self.dt))
        model.setup()
        # setup() replaces the model's symbols by new ones: every later expression is built from the model's own.
        x, u = model.x["x"], model.u["u"]
        x_next = step(x, u, self.dt)
        if mask:
            w_stage, w_end, w_in, w_next = (model.tvp[name] for name in ("w_stage", "w_end", "w_in", "w_next"))

        mpc = do_mpc.controller.MPC(model)
        mpc.set_param(
            n_horizon=n,
            t_step=self.dt,
            state_discretization="discrete",
            store_full_solution=False,
            use_terminal_bounds=True,
            nlpsol_opts=dict(self.nlpsol_opts),
        )
        lf = task.terminal_cost(x)
        l_stage = self.dt * task.stage_cost(x, u)
        if mask:
            # l_f at the end knot: in lterm when it is one of 0..N-1, in mterm when it is N.
            mpc.set_objective(mterm=w_end * lf, lterm=w_stage * l_stage + w_end * lf)
        else:
            mpc.set_objective(mterm=lf, lterm=l_stage)
        mpc.set_rterm(u=0.0)  # no input-rate penalty (do-mpc warns when it is not set)
        mpc.bounds["lower", "_u", "u"] = task.u_low
        mpc.bounds["upper", "_u", "u"] = task.u_high
        if not mask and (np.any(np.isfinite(task.x_low)) or np.any(np.isfinite(task.x_high))):
            # Knots 1..N-1 by `bounds`, knot N by the terminal bounds (use_terminal_bounds copies them).
            mpc.bounds["lower", "_x", "x"] = task.x_low
            mpc.bounds["upper", "_x", "x"] = task.x_high
        if mask:
            # Only the knots inside the episode are bounded (the path bounds on 1..k_end, the terminal box at k_end):
            # written on x_{k+1} = F(x_k, u_k), since do-mpc's nonlinear constraints see the knots 0..N-1, weighted
            # by the time-varying w_in / w_next and soft, with the exact L1 penalty (a stage past the episode's end,
            # or a box out of exact reach, never makes the problem infeasible).
            limits = (
                ("path", w_in, np.asarray(task.x_low, float), np.asarray(task.x_high, float)),
                ("end_box", w_next, np.asarray(task.x_final_low, float), np.asarray(task.x_final_high, float)),
            )
            for what, weight, lo, hi in limits:
                for side, idx in (
                    ("upper", np.flatnonzero(np.isfinite(hi))),
                    ("lower", np.flatnonzero(np.isfinite(lo))),
                ):
                    if idx.size == 0:
                        continue
                    rows = [int(i) for i in idx]
                    gap = x_next[rows] - ca.DM(hi[idx]) if side == "upper" else ca.DM(lo[idx]) - x_next[rows]
                    mpc.set_nl_cons(
                        f"{what}_{side}", weight * gap, ub=0.0, soft_constraint=True, penalty_term_cons=self.soft_weight
                    )
            template = mpc.get_tvp_template()

            def tvp_fun(t_now: float) -> Any:
                # The episode ends at knot k_end (l_f and the box there); beyond the horizon l_f stays at x_N, unboxed.
                tau = self._taus.get(env_index, float(task.tau_nominal))
                k_end = max(1, round(tau / self.dt))
                for k in range(n + 1):
                    template["_tvp", k, "w_stage"] = 1.0 if k < k_end else 0.0
                    template["_tvp", k, "w_end"] = 1.0 if k == min(k_end, n) else 0.0
                    template["_tvp", k, "w_in"] = 1.0 if k + 1 <= k_end else 0.0
                    template["_tvp", k, "w_next"] = 1.0 if k + 1 == k_end else 0.0
                return template

            mpc.set_tvp_fun(tvp_fun)
        with warnings.catch_warnings():
            # do-mpc's own bound checks call numpy on CasADi values (CasADi 3.8 notes it once per process).
            warnings.filterwarnings("ignore", message=r"(?s).*numpy function was called on a casadi value")
            mpc.setup()
        self._initial_guess(mpc, 0.5 * (task.x0_low + task.x0_high))
        return mpc

    def _initial_guess(self, mpc: Any, x: np.ndarray) -> None:
        """do-mpc's default guess from ``x`` (``x`` at every knot, zero input) and a fresh history."""
        mpc.reset_history()
        mpc.x0 = np.asarray(x, dtype=float).reshape(-1, 1)
        mpc.u0 = np.clip(np.zeros(self.task.nu), self.task.u_low, self.task.u_high).reshape(-1, 1)
        mpc.set_initial_guess()
        mpc.flags["initial_run"] = False  # no multipliers of another episode

    # ------------------------------------------------------------------ protocol
    def predict(
        self,
        observation: Any,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        """SB3 predictor protocol: actions for one or a batch of observations; ``state`` is passed through."""
        xs, taus, batched = split_observation(observation, self.task.nx, self.name)
        starts = episode_start_mask(episode_start, xs.shape[0])
        actions = np.zeros((xs.shape[0], self.task.nu))
        infos = []
        for i, (x, tau) in enumerate(zip(xs, taus, strict=True)):
            actions[i], info = self.act(x, float(tau), env_index=i, new_episode=bool(starts[i]))
            infos.append(info)
        self.last_info = infos
        return output_actions(actions, batched), state

    def act(
        self, x: np.ndarray, tau: float, env_index: int = 0, new_episode: bool = False
    ) -> tuple[np.ndarray, MPCStepInfo]:
        """Input for state ``x`` at time to go ``tau`` (env ``env_index``; ``new_episode`` drops its warm start)."""
        start = time.perf_counter()
        x = self.task.check_state(x, f"{self.name} state")
        mpc = self._mpcs.get(env_index)
        if mpc is None:
            mpc = self._mpcs[env_index] = self._build(env_index)
            new_episode = True
        if new_episode or env_index in self._fresh:
            self._initial_guess(mpc, x)
            self._fresh.discard(env_index)
        self._taus[env_index] = max(float(tau), 0.0)
        t0 = time.perf_counter()
        u = np.asarray(mpc.make_step(x.reshape(-1, 1)), dtype=float).reshape(self.task.nu)
        solve_time = time.perf_counter() - t0
        stats = mpc.solver_stats
        status, success = str(stats.get("return_status", "unknown")), bool(stats.get("success", False))
        source = "solver" if success else "unconverged"
        if not np.all(np.isfinite(u)):
            u, source = np.zeros(self.task.nu), "zero"
            self._initial_guess(mpc, x)  # a NaN iterate would poison every later warm start
        u = np.clip(u, self.task.u_low, self.task.u_high)
        self.solve_times.append(solve_time)
        self.ipopt_times.append(float(stats.get("t_wall_total", np.nan)))
        self.statuses.append((status, success))
        info = MPCStepInfo(
            source=source,
            status=status,
            success=success,
            iterations=int(stats.get("iter_count", -1)),
            solve_time=solve_time,
            step_time=time.perf_counter() - start,
            phase="lookahead" if tau - self.horizon * self.dt > _TIME_EPS or self.end_phase == "switch" else "final",
            objective=float("nan"),  # do-mpc keeps no objective value
        )
        self.stats.append(info)
        return u, info

    def reset(self) -> None:
        """Forget every warm start (all envs): the next step of each starts from do-mpc's default guess."""
        self._fresh = set(self._mpcs)

    def reset_stats(self) -> None:
        """Clear the recorded step times and statuses."""
        self.solve_times, self.ipopt_times, self.statuses, self.stats = [], [], [], []

    def step_times(self) -> np.ndarray:
        """``mpc.make_step`` wall times (s) of the recorded steps."""
        return np.asarray(self.solve_times, dtype=float)


__all__ = ["INSTALL_HINT", "DoMPCPolicy"]
