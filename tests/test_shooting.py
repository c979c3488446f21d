"""The condensed single-shooting solver: the same NLP as the lifted transcription, exact derivatives, the Taylor
forms of the value networks, and the MPC on it against fatrop/IPOPT."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from seagul_control.mpc import LimitedLookaheadMPC, MPCOptions
from seagul_control.shooting import BufferedFunction, ShootingSolver
from seagul_control.transcription import Transcription, TranscriptionOptions
from seagul_envs import make_task


def _starts(task, n, seed=0):
    return task.sample_x0(np.random.default_rng(seed), n)


def test_shooting_solves_the_lifted_nlp_to_the_same_optimum_with_its_multipliers():
    """Input bounds only (the acrobot's lookahead): the condensed problem's optimum is IPOPT's on the lifted NLP,
    with the same states, defect multipliers (costates) and dV/dp (envelope theorem)."""
    task = make_task("acrobot")
    shooting = Transcription(task, 5, TranscriptionOptions(step=0.1, final_box=False, solver="shooting"))
    ipopt = Transcription(task, 5, TranscriptionOptions(step=0.1, final_box=False, solver="ipopt"))
    for x, tau in zip(_starts(task, 4), (3.0, 2.0, 4.5, 0.8), strict=True):
        a, b = shooting.solve(x, tau), ipopt.solve(x, tau)
        assert a.success and b.success and a.status == "Success"
        assert a.objective == pytest.approx(b.objective, rel=1e-8, abs=1e-8)
        np.testing.assert_allclose(a.controls, b.controls, atol=2e-5)
        np.testing.assert_allclose(a.states, b.states, atol=1e-5)
        np.testing.assert_allclose(a.defect_multipliers, b.defect_multipliers, rtol=1e-3, atol=1e-3)
        np.testing.assert_allclose(a.param_sensitivity, b.param_sensitivity, rtol=1e-3, atol=1e-3)
        # the primal vector is laid out as the lifted NLP's (warm starts of the MPC read it by stage)
        np.testing.assert_allclose(a.primal[shooting.control_index.ravel()], a.controls.ravel())


def test_active_input_bounds_are_kept_and_reported_as_bound_multipliers():
    task = make_task("acrobot")
    tight = Transcription(task, 5, TranscriptionOptions(step=0.1, final_box=False, solver="shooting"))
    ipopt = Transcription(task, 5, TranscriptionOptions(step=0.1, final_box=False, solver="ipopt"))
    for tr in (tight, ipopt):
        for k in range(5):
            tr.set(k, "lbu", -1.0)
            tr.set(k, "ubu", 1.0)
    x = task.goal + np.array([0.3, -0.3, 0.0, 0.0])
    a, b = tight.solve(x, 3.0), ipopt.solve(x, 3.0)
    assert a.success and np.all(np.abs(a.controls) <= 1.0 + 1e-12)
    assert np.any(np.abs(a.controls) > 1.0 - 1e-9)  # some bound is active
    np.testing.assert_allclose(a.controls, b.controls, atol=1e-5)
    u = tight.control_index.ravel()
    np.testing.assert_allclose(a.lam_x[u], b.lam_x[u], atol=1e-4)


def test_condensed_gradient_and_hessian_match_finite_differences():
    task = make_task("acrobot")
    tr = Transcription(task, 5, TranscriptionOptions(step=0.1, final_box=False, solver="shooting"))
    solver = tr._shooting
    x = _starts(task, 1, 3)[0]
    p = np.concatenate([x, [2.5]])
    u = np.array([1.0, -2.0, 0.5, 3.0, -1.0])
    solver.f.set_input(1, p)
    solver.fgh.set_input(1, p)
    j, g, h = solver._fgh(u)

    def f(v):
        return float(solver.f(v)[0].ravel()[0])

    eps = 1e-5
    fd_g = np.array([(f(u + eps * e) - f(u - eps * e)) / (2 * eps) for e in np.eye(5)])
    np.testing.assert_allclose(g, fd_g, rtol=1e-6, atol=1e-6)
    fd_h = np.array([(solver._fgh(u + eps * e)[1] - solver._fgh(u - eps * e)[1]) / (2 * eps) for e in np.eye(5)])
    np.testing.assert_allclose(h, fd_h, rtol=1e-5, atol=1e-5)
    assert j == pytest.approx(f(u))


@pytest.mark.parametrize("ensemble", [False, True])
def test_taylor_forms_equal_the_network_to_second_order(ensemble):
    """``casadi_function("taylor")`` and ``("taylor_model")``: value, gradient and Hessian in x at x0 are the scalar
    form's (CasADi's own derivatives), for a network and an ensemble with pessimism."""
    pytest.importorskip("torch")
    from seagul_learn.value_network import ValueEnsemble, ValueNetwork

    task = make_task("acrobot")
    rng = np.random.default_rng(2)
    vf = ValueEnsemble(4, (16, 8), 3, 0.7, task_name="acrobot", seed=1) if ensemble else ValueNetwork(4, (16, 8))
    for net in vf.networks if ensemble else [vf]:
        net.set_normalization(task.sample_x0(rng, 64), rng.uniform(0, 5, 64), rng.uniform(0, 50, 64))
    theta = vf.casadi_parameters()
    x = ca.SX.sym("x", 4)
    v = vf.casadi_function("scalar")(x, 2.5, theta)
    hess, grad = ca.hessian(v, x)
    exact = ca.Function("exact", [x], [v, grad, hess])
    coeffs = vf.casadi_function("taylor")
    model = vf.casadi_function("taylor_model")
    for x0 in task.sample_x0(rng, 3) + rng.normal(0, 0.5, (3, 4)):
        vq = model(x, x0, coeffs(x0, 2.5, theta))
        hq, gq = ca.hessian(vq, x)
        approx = ca.Function("approx", [x], [vq, gq, hq])
        for a, b in zip(exact(x0), approx(x0), strict=True):
            np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=1e-9, atol=1e-9)


def test_mpc_on_the_shooting_solver_plans_optima_of_the_lifted_nlp():
    """The same lookahead NLP with a network terminal cost (derivatives through its Taylor forms): along the
    condensed MPC's closed loop, IPOPT on the lifted NLP started from each of its plans stays there (a KKT point of
    the same problem, same objective), and the first step's action equals IPOPT's from a cold start."""
    pytest.importorskip("torch")
    from seagul_learn.value_network import ValueNetwork

    task = make_task("acrobot")
    rng = np.random.default_rng(5)
    net = ValueNetwork(4, (16, 16), task_name="acrobot", seed=0)
    # values of a few units beside the "lqr" prior: plans stay near the goal, where IPOPT converges reliably
    net.set_normalization(task.sample_x0(rng, 64), rng.uniform(0, 5, 64), rng.uniform(0, 3, 64))
    options = MPCOptions(trust_region="lqr", goal_blend=1.0, jit=False)
    shooting = LimitedLookaheadMPC(task, net, 5, options.replace(solver="shooting"))
    lifted = LimitedLookaheadMPC(task, net, 5, options.replace(solver="ipopt", max_iter=300))
    assert shooting._lookahead.trans.solver_name == "shooting"
    x, tau = task.goal + np.array([0.2, -0.2, 0.3, 0.0]), 5.0
    u_cold, _ = lifted.act(x, tau)
    step = task.rk4_step()
    for k in range(6):
        u_s, info_s = shooting.act(x, tau)
        assert info_s.success and info_s.source == "solver"
        if k == 0:
            np.testing.assert_allclose(u_s, u_cold, atol=1e-4)
        problem, theta = lifted._select(tau)
        plan = shooting._plans[0]
        guess = problem.trans.pack_guess(plan.states, plan.controls)
        ref = problem.trans.solve(x, tau, theta, guess=guess)
        assert ref.success
        np.testing.assert_allclose(ref.controls, plan.controls, rtol=1e-4, atol=1e-3)
        assert ref.objective == pytest.approx(info_s.objective, rel=1e-7, abs=1e-7)
        x, tau = np.asarray(step(x, u_s, task.control_period)).ravel(), tau - task.control_period


def test_shooting_refuses_what_it_cannot_solve_by_name():
    glider = make_task("glider")
    with pytest.raises(ValueError, match=r"shooting.*free steps"):
        Transcription(glider, 10, TranscriptionOptions(solver="shooting"))
    with pytest.raises(ValueError, match="finite state bounds"):
        Transcription(glider, 10, TranscriptionOptions(free_time=False, step=0.025, solver="shooting"))
    acrobot = make_task("acrobot")
    with pytest.raises(ValueError, match=r"does not take option .ipopt\.tol."):
        Transcription(
            acrobot,
            5,
            TranscriptionOptions(step=0.1, final_box=False, solver="shooting", solver_options={"ipopt.tol": 1e-6}),
        )
    with pytest.raises(ValueError, match="unknown shooting solver option"):
        Transcription(
            acrobot,
            5,
            TranscriptionOptions(step=0.1, final_box=False, solver="shooting", solver_options={"shooting.foo": 1}),
        )
    with pytest.raises(ValueError, match="solver must be"):
        LimitedLookaheadMPC(acrobot, None, 5, MPCOptions(solver="sqp", jit=False))  # type: ignore[arg-type]


def test_iteration_limit_is_a_reported_failure_and_the_mpc_falls_back():
    task = make_task("acrobot")
    tr = Transcription(
        task,
        5,
        TranscriptionOptions(step=0.1, final_box=False, solver="shooting", solver_options={"shooting.max_iter": 1}),
    )
    sol = tr.solve(task.goal + np.array([0.3, 0.3, 0.0, 0.0]), 3.0)
    assert not sol.success and sol.status == "Maximum_Iterations_Exceeded" and sol.iterations == 1
    mpc = LimitedLookaheadMPC(task, None, 5, MPCOptions(solver="shooting", max_iter=0, multistart="never", jit=False))
    u, info = mpc.act(task.goal + np.array([0.3, 0.3, 0.0, 0.0]), 3.0)
    assert not info.success and info.source in ("lqr", "zero") and np.all(np.isfinite(u))


def test_buffered_function_binds_numpy_arrays():
    x, w = ca.SX.sym("x", 2), ca.SX.sym("w", 3)
    fn = ca.Function("f", [x, w], [ca.sum1(w) * ca.dot(x, x), ca.vertcat(x, 2 * x).reshape((2, 2))])
    buf = BufferedFunction(fn)
    buf.set_input(1, [1.0, 2.0, 3.0])
    v, m = buf(np.array([1.0, 2.0]))
    assert float(v.ravel()[0]) == pytest.approx(30.0)
    np.testing.assert_allclose(m.T, np.array(fn([1.0, 2.0], [1.0, 2.0, 3.0])[1]))
    with pytest.raises(ValueError, match="dense"):
        BufferedFunction(ca.Function("s", [x], [ca.SX(ca.Sparsity.diag(2))]))
    with pytest.raises(ValueError, match="finite input bounds"):
        ShootingSolver(fn, fn, np.array([-np.inf]), np.array([1.0]))


def test_compiled_shooting_mpc_is_the_interpreted_one(tmp_path):
    """jit=True generates the condensed functions (the network through its Taylor forms) into one cached library:
    the same actions, iterations and plans as the interpreted (expanded) condensed MPC."""
    pytest.importorskip("torch")
    from seagul_control.mpc import find_c_compiler
    from seagul_learn.value_network import ValueEnsemble

    if find_c_compiler() is None:
        pytest.skip("no C compiler")
    task = make_task("acrobot")
    rng = np.random.default_rng(7)
    vf = ValueEnsemble(4, (8,), 2, 0.5, task_name="acrobot", seed=3)
    for net in vf.networks:
        net.set_normalization(task.sample_x0(rng, 64), rng.uniform(0, 5, 64), rng.uniform(0, 3, 64))
    options = MPCOptions(trust_region="lqr", goal_blend=1.0, solver="shooting")
    compiled = LimitedLookaheadMPC(
        task, vf, 5, options.replace(jit=True, jit_cache_dir=str(tmp_path), jit_flags=("-O0",))
    )
    interpreted = LimitedLookaheadMPC(task, vf, 5, options.replace(jit=False))
    assert compiled._lookahead.trans.codegen_library is not None
    x, tau = task.goal + np.array([0.2, -0.1, 0.0, 0.3]), 5.0
    for _ in range(3):
        u_c, info_c = compiled.act(x, tau)
        u_i, info_i = interpreted.act(x, tau)
        assert (info_c.status, info_c.iterations) == (info_i.status, info_i.iterations)
        np.testing.assert_allclose(u_c, u_i, rtol=1e-8, atol=1e-8)
        x, tau = x + 0.02 * rng.standard_normal(4), tau - 0.1


def _double_well() -> tuple[ca.Function, ca.Function]:
    """``J(U) = sum((u^2 - 1)^2 + 0.3 u)``: in each coordinate a local minimum near +1 and the global one near -1."""
    u, p = ca.SX.sym("u", 2), ca.SX.sym("p", 1)
    j = ca.sum1((u**2 - 1) ** 2 + 0.3 * u) + 0 * p
    g = ca.gradient(j, u)
    return ca.Function("f", [u, p], [j]), ca.Function("fgh", [u, p], [j, g, ca.densify(ca.hessian(j, u)[0])])


def test_extra_starts_find_the_lower_minimum_and_keep_the_given_one_on_ties():
    f, fgh = _double_well()
    lo, hi = np.full(2, -2.0), np.full(2, 2.0)
    single = ShootingSolver(f, fgh, lo, hi).solve(np.array([1.0, 1.0]), np.zeros(1))
    assert single.success and np.all(single.controls > 0.5) and single.start == 0
    multi = ShootingSolver(f, fgh, lo, hi, starts=2)
    res = multi.solve(np.array([1.0, 1.0]), np.zeros(1))
    assert res.success and np.all(res.controls < -0.5) and res.start == 1  # descended from the lower bound
    assert res.objective < single.objective - 1.0
    assert res.iterations > single.iterations  # the total over the starts
    # Started in the global minimum's basin, the given start's result is kept (the lower bound reaches the same).
    again = multi.solve(np.array([-1.0, -1.0]), np.zeros(1))
    assert again.start == 0 and again.objective == pytest.approx(res.objective, abs=1e-9)
    # One extra start is the midpoint of the bounds: from 0, a descent reaches the global basin too.
    mid = ShootingSolver(f, fgh, lo, hi, starts=1).solve(np.array([1.0, 1.0]), np.zeros(1))
    assert mid.start == 1 and mid.objective == pytest.approx(res.objective, abs=1e-9)
    for bad in (-1, 1.5):
        with pytest.raises(ValueError, match="starts"):
            ShootingSolver(f, fgh, lo, hi, starts=bad)


def test_mpc_with_extra_starts_plans_no_worse_than_without():
    """``solver_options={"shooting.starts": 2}``: every step's plan costs at most the single-start plan's."""
    task = make_task("acrobot")
    options = MPCOptions(solver="shooting", warm_start=False, jit=False, multistart="never")
    plain = LimitedLookaheadMPC(task, None, 5, options)
    multi = LimitedLookaheadMPC(task, None, 5, options.replace(solver_options={"shooting.starts": 2}))
    for x in _starts(task, 8, seed=3):
        _, a = plain.act(x, 3.0)
        _, b = multi.act(x, 3.0)
        assert a.success and b.success
        assert b.objective <= a.objective + 1e-6 * (1 + abs(a.objective))
    assert b.iterations > a.iterations


def test_mpc_multistart_modes_and_their_refusals():
    task = make_task("acrobot")
    assert (
        LimitedLookaheadMPC(task, None, 5, MPCOptions(jit=False)).multistart == "rise"
    )  # the condensed solver's default
    assert LimitedLookaheadMPC(task, None, 5, MPCOptions(solver="fatrop", jit=False)).multistart == "never"
    with pytest.raises(ValueError, match="multistart='rise' needs solver='shooting'"):
        LimitedLookaheadMPC(task, None, 5, MPCOptions(solver="fatrop", multistart="rise", jit=False))
    with pytest.raises(ValueError, match="multistart must be"):
        LimitedLookaheadMPC(task, None, 5, MPCOptions(multistart="sometimes", jit=False))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="multistart_starts"):
        LimitedLookaheadMPC(task, None, 5, MPCOptions(multistart_starts=0, jit=False))
    with pytest.raises(ValueError, match="extra starts need the condensed solver"):
        Transcription(task, 5, TranscriptionOptions(step=0.1, final_box=False, solver="ipopt")).solve(
            task.goal, 3.0, starts=2
        )


def test_rise_multistart_runs_the_extra_starts_when_the_plan_costs_more_than_the_last():
    """``multistart="rise"``: extra starts at a cold start and when the warm-started plan costs more than the last
    step's plan promised; then the plan is the "always" MPC's (the lowest over the same starts)."""
    task = make_task("acrobot")
    rise = LimitedLookaheadMPC(task, None, 5, MPCOptions(jit=False))
    always = LimitedLookaheadMPC(task, None, 5, MPCOptions(multistart="always", jit=False))
    never = LimitedLookaheadMPC(task, None, 5, MPCOptions(multistart="never", jit=False))
    x, tau = task.goal + np.array([0.4, -0.3, 0.5, 0.0]), 4.0
    _, first = rise.act(x, tau)
    assert first.extra_starts == 2 and never.act(x, tau)[1].extra_starts == 0
    step = task.rk4_step()
    u = rise._plans[0].controls[0]
    x, tau = np.asarray(step(x, u, task.control_period)).ravel(), tau - task.control_period
    _, calm = rise.act(x, tau)  # the plan's cost fell, as the stage cost paid says it should: no extra start
    assert calm.extra_starts == 0 and calm.objective < first.objective
    # The last plan promised less than the warm start now reaches: the extra starts run.
    rise._plans[0].objective = -1.0
    x, tau = np.asarray(step(x, rise._plans[0].controls[0], task.control_period)).ravel(), tau - task.control_period
    _, raised = rise.act(x, tau)
    _, reference = always.act(x, tau)
    assert raised.extra_starts == 2 and raised.success
    assert reference.extra_starts == 2
    assert raised.objective <= reference.objective + 1e-8 * (1 + abs(reference.objective))
