"""The condensed solver's side of :class:`~seagul_control.transcription.Transcription` (``solver="shooting"``).

With ``solver="shooting"`` the transcription's NLP is solved with its states eliminated: the rollout from
``x_init`` under the inputs ``U`` gives the objective ``J(U; p)``, which
:class:`~seagul_control.shooting.ShootingSolver` minimises by projected Newton over the input box (fixed steps and
input bounds only; :func:`~seagul_control.shooting.condensation_problems` names what rules a problem out). This
module builds ``J``, its gradient and Hessian and the post-processing function (states, costates, ``dJ/dp``) as
CasADi Functions, compiles them like the lifted NLP's (:func:`~seagul_control.codegen.compile_nlp_library`), and lays
a condensed solution out as the lifted NLP's (primal vector, multipliers), so callers see one kind of solution.

The methods live on :class:`CondensedSolveMixin`, a base class of
:class:`~seagul_control.transcription.Transcription`; they read the transcription's index maps and bounds.
"""

from __future__ import annotations

import os
import time
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any

import casadi as ca
import numpy as np

from seagul_control.shooting import BufferedFunction, ShootingSolver, condensation_problems

if TYPE_CHECKING:
    from seagul_control.transcription import TranscriptionSolution
    from seagul_envs.tasks.base import Task


class CondensedSolveMixin:
    """Builds and runs the condensed solver of a transcription (see the module docstring)."""

    # Set by Transcription.__init__ before the condensed solver is built.
    task: Task
    horizon: int
    step: float | None
    free_time: bool
    final_box: bool
    soft_bounds_weight: float | None
    max_solve_time: float | None
    model_params: bool
    n_theta: int
    codegen_library: Path | None
    _shooting: Any
    _solver: Any
    _shooting_post: Any
    _lbw: np.ndarray
    _ubw: np.ndarray
    _lbg: np.ndarray
    _u_idx: list[np.ndarray]
    _defect_rows: list[np.ndarray]
    initial_rows: np.ndarray

    def pack_guess(self, states: np.ndarray, controls: np.ndarray, steps: np.ndarray | None = None) -> np.ndarray:
        raise NotImplementedError  # Transcription's

    def _build_shooting(
        self,
        p: ca.MX,
        step_fn: ca.Function,
        terminal_cost: ca.Function,
        terminal_model: tuple[ca.Function, ca.Function] | None,
        solver_options: dict[str, Any] | None,
        codegen: bool,
        codegen_dir: str | os.PathLike[str] | None,
        codegen_flags: tuple[str, ...] | None,
    ) -> None:
        """The condensed problem ``J(U; p)`` of the same NLP and its :class:`~seagul_control.shooting.ShootingSolver`
        (``solver="shooting"``; module docstring of :mod:`seagul_control.shooting`)."""
        task, n = self.task, self.horizon
        problems = condensation_problems(
            task, free_time=self.free_time, final_box=self.final_box, soft_bounds=self.soft_bounds_weight is not None
        )
        if problems:
            raise ValueError(
                f"{task.name}: solver 'shooting' needs fixed steps and input bounds only; this transcription has "
                + ", ".join(problems)
                + " (use 'fatrop' or 'ipopt')"
            )
        options = dict(solver_options or {})
        jit = options.pop("jit", False)
        jit_opts = options.pop("jit_options", {}) or {}
        for key in ("compiler", "jit_name", "jit_temp_suffix", "print_time", "expand", "show_eval_warnings"):
            options.pop(key, None)
        own = {}
        for key, value in options.items():
            if not key.startswith("shooting."):
                raise ValueError(f"solver 'shooting' does not take option {key!r}; its options are 'shooting.<name>'")
            own[key.split(".", 1)[1]] = value
        if jit and not codegen:
            codegen = True
            codegen_flags = (*jit_opts.get("flags", ("-O1",)), "-fPIC", "-shared")

        if terminal_model is None:
            fns = self._shooting_functions(p, step_fn, terminal_cost, None)
        else:
            # The derivatives in U of the model with x0 and c held fixed are an SX graph of the rollout (small);
            # then x0 := x_n and c := coefficients(x_n), evaluated once, outside every derivative sweep (inlined
            # in one MX graph, CasADi's forward sweeps of the Hessian re-evaluated the network per direction: 10x).
            try:
                light = terminal_model[1].expand()
            except RuntimeError as exc:
                raise ValueError(f"{task.name}: the terminal model must be expandable to SX ({exc})") from exc
            fns = self._shooting_functions(p, step_fn, terminal_cost, (terminal_model[0], light))
        name = f"{task.name}_shooting_n{n}" + ("_theta" if self.model_params else "")
        name += "_model" if terminal_model is not None else ""
        if codegen:
            try:
                # Looked up on the transcription module, where callers (and tests) may replace it; imported here
                # because that module imports this one at module level (import cycle).
                from seagul_control import transcription

                self.codegen_library = transcription.compile_nlp_library(
                    fns, name, codegen_dir, task.fingerprint(), codegen_flags
                )
                lib = str(self.codegen_library)
                fns = tuple(ca.external(fn.name(), lib) for fn in fns)  # type: ignore[assignment]
            except (RuntimeError, OSError) as exc:
                warnings.warn(f"{name}: code generation unavailable ({exc}); solving interpreted", stacklevel=3)
                self.codegen_library = None
        if self.codegen_library is None:
            fns = tuple(fn.expand() for fn in fns)  # type: ignore[assignment]
        lo = np.concatenate([self._lbw[idx] for idx in self._u_idx])
        hi = np.concatenate([self._ubw[idx] for idx in self._u_idx])
        self._shooting = ShootingSolver(fns[0], fns[1], lo, hi, **own)
        self._solver = self._shooting
        self._shooting_post = BufferedFunction(fns[2])

    def _shooting_functions(
        self,
        p_mx: ca.MX,
        step_fn: ca.Function,
        terminal_cost: ca.Function,
        terminal_model: tuple[ca.Function, ca.Function] | None,
    ) -> tuple[ca.Function, ca.Function, ca.Function]:
        """``f: (U, p) -> J``, ``fgh: (U, p) -> (J, dJ/dU, d2J/dU2)`` and ``post: (U, p) -> (states, costates,
        dJ/dp)`` of the condensed problem; with ``terminal_model`` the derivatives come from the model."""
        task, n, nx, nu = self.task, self.horizon, self.task.nx, self.task.nu
        n_p = int(p_mx.numel())
        name = f"{task.name}_shooting_n{n}"
        dense = ca.densify

        def step_of(p: Any) -> Any:
            return p[nx] / n if self.step is None else self.step

        def rollout(U: Any, p: Any, perturb: Any, end: Any) -> tuple[Any, list[Any]]:
            x_init, tau, h = p[:nx], p[nx], step_of(p)
            phys = [p[nx + 1 + self.n_theta :]] if self.model_params else []
            x = x_init if perturb is None else x_init + perturb[:, 0]
            states, total = [x], 0
            for k in range(n):
                u_k = U[k * nu : (k + 1) * nu]
                total = total + h * task.stage_cost(x, u_k)
                x = step_fn(x, u_k, h, *phys)
                if perturb is not None:
                    x = x + perturb[:, k + 1]
                states.append(x)
            return total + end(x, tau - n * h), states

        theta_slice = slice(nx + 1, nx + 1 + self.n_theta)
        U = ca.MX.sym("U", n * nu)
        J, states = rollout(U, p_mx, None, lambda x, t: terminal_cost(x, t, p_mx[theta_slice]))
        f = ca.Function(f"{name}_f", [U, p_mx], [J])
        if terminal_model is None:
            D = ca.MX.sym("D", nx, n + 1)
            H, grad = ca.hessian(J, U)
            Jd, _ = rollout(U, p_mx, D, lambda x, t: terminal_cost(x, t, p_mx[theta_slice]))
            costates = ca.substitute(ca.jacobian(Jd, ca.vec(D)), D, ca.DM.zeros(nx, n + 1))
            fgh = ca.Function(f"{name}_fgh", [U, p_mx], [J, dense(grad), dense(H)])
            outputs = [dense(ca.horzcat(*states)), dense(costates), dense(ca.jacobian(J, p_mx).T)]
            return f, fgh, ca.Function(f"{name}_post", [U, p_mx], outputs)
        coeff_fn, model = terminal_model
        # The light part in SX: the rollout, the stage costs and the terminal model with x0 and c as inputs (as an
        # MX graph calling the per-step integrator it compiled 5x faster for one network but 2x slower for the
        # shipped ensemble, 323 s against ~150 s at -O3 under load).
        Us, ps = ca.SX.sym("U", n * nu), ca.SX.sym("p", n_p)
        X0, C = ca.SX.sym("x0", nx), ca.SX.sym("c", int(coeff_fn.nnz_out(0)))
        Ds = ca.SX.sym("D", nx, n + 1)

        def end(x: Any, t: Any) -> Any:
            return model(x, t, ps[theta_slice], X0, C)

        Jl, states_s = rollout(Us, ps, None, end)
        Hl, gl = ca.hessian(Jl, Us)
        Jdl, _ = rollout(Us, ps, Ds, end)
        cost_l = ca.substitute(ca.jacobian(Jdl, ca.vec(Ds)), ca.vec(Ds), ca.DM.zeros(nx * (n + 1), 1))
        light = ca.Function(f"{name}_light", [Us, ps, X0, C], [Jl, dense(gl), dense(Hl)])
        light_post = ca.Function(f"{name}_light_post", [Us, ps, X0, C], [dense(cost_l)])
        roll = ca.Function(f"{name}_roll", [Us, ps], [dense(ca.horzcat(*states_s))])
        traj = roll(U, p_mx)
        x_n = traj[:, n]
        coeffs = coeff_fn(x_n, p_mx[nx] - n * step_of(p_mx), p_mx[theta_slice])
        j_l, g_l, h_l = light(U, p_mx, x_n, coeffs)
        c_l = light_post(U, p_mx, x_n, coeffs)
        fgh = ca.Function(f"{name}_fgh", [U, p_mx], [j_l, g_l, h_l])
        sens = ca.vertcat(c_l[:nx].T, ca.DM.nan(n_p - nx, 1))
        post = ca.Function(f"{name}_post", [U, p_mx], [traj, dense(c_l), dense(sens)])
        return f, fgh, post

    def _solve_shooting(
        self, w0: np.ndarray, p: np.ndarray, tau: float, starts: int | None = None
    ) -> TranscriptionSolution:
        """:meth:`solve` with ``solver="shooting"``: the inputs of ``w0`` start the condensed solve; the result is
        laid out as the lifted NLP's (states rolled out, multipliers from the costates)."""
        from seagul_control.transcription import TranscriptionSolution  # import cycle, as above

        start = time.perf_counter()
        u_idx = np.concatenate(self._u_idx)
        res = self._shooting.solve(w0[u_idx], p, self._lbw[u_idx], self._ubw[u_idx], self.max_solve_time, starts)
        self._shooting_post.set_input(1, p)
        states_t, costates, dj_dp = (o.T.copy() for o in self._shooting_post(res.controls))
        elapsed = time.perf_counter() - start
        nx, n = self.task.nx, self.horizon
        states = np.asarray(states_t, dtype=float).reshape(nx, n + 1).T
        lam_states = np.asarray(costates, dtype=float).reshape(n + 1, nx)  # column-major vec(D): knot by knot
        controls = res.controls.reshape(n, self.task.nu)
        w = self.pack_guess(states, controls)
        # Multipliers in CasADi's convention for the lifted NLP: rows x_{k+1} - F carry -dV_{k+1}/dx_{k+1}, the
        # initial rows x_0 - x_init carry dV/dx_0; the input bounds carry -dJ/du where a bound is active.
        lam_g = np.zeros(self._lbg.size)
        lam_g[self.initial_rows] = lam_states[0]
        for k, rows in enumerate(self._defect_rows):
            lam_g[rows] = -lam_states[k + 1]
        lam_x = np.zeros(self._lbw.size)
        if res.success:
            at_bound = (res.controls <= self._lbw[u_idx] + 1e-9) | (res.controls >= self._ubw[u_idx] - 1e-9)
            lam_x[u_idx] = np.where(at_bound, -res.gradient, 0.0)
        ok = res.success and bool(np.all(np.isfinite(w)))
        return TranscriptionSolution(
            success=ok,
            status=res.status,
            objective=res.objective,
            states=states,
            controls=controls,
            steps=np.full(n, tau / n if self.step is None else self.step),
            param_sensitivity=np.asarray(dj_dp, dtype=float).ravel(),
            defect_multipliers=lam_states[1:].copy(),
            iterations=res.iterations,
            solve_time=elapsed,
            primal=w,
            lam_g=lam_g,
            lam_x=lam_x,
        )
