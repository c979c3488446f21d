"""The one NLP builder: solver/codegen equivalence, the elapsed-time state, guesses, the compiled-library cache."""

from __future__ import annotations

import numpy as np
import pytest

import seagul_control.transcription as tr_mod
from seagul_control.transcription import Transcription
from seagul_envs.tasks import make_task

ACROBOT_X = np.array([np.pi - 0.2, 0.15, 0.3, -0.2])
GLIDER_X = np.array([-3.5, 0.1, 0.0, 0.0, 7.0, 0.0, 0.0])


@pytest.mark.parametrize("name", ["acrobot", "glider"])
def test_interpreted_compiled_ipopt_and_fatrop_agree(name: str) -> None:
    task = make_task(name)
    x = ACROBOT_X if name == "acrobot" else GLIDER_X
    ref = Transcription(task, solver="ipopt", codegen=False).solve(x, task.tau_nominal)
    assert ref.success
    # Same problem, same optimum: every variant starts from a perturbed copy of the reference solution. fatrop is
    # checked on the acrobot only: on the glider it needs the kinematic guess (even this guess stalls it at
    # max_iter; docs/trajopt.md), which TrajectoryOptimizer supplies.
    guess = ref.primal * (1 + 1e-3 * np.random.default_rng(0).standard_normal(ref.primal.size))
    variants = [("ipopt", False), ("ipopt", True)] + ([("fatrop", True)] if name == "acrobot" else [])
    sols = [
        Transcription(task, solver=solver, codegen=codegen).solve(x, task.tau_nominal, guess=guess)
        for solver, codegen in variants
    ]
    for sol in sols:
        assert sol.success, sol.status
        assert sol.objective == pytest.approx(ref.objective, rel=1e-7)
        np.testing.assert_allclose(sol.states, ref.states, atol=1e-5)
        np.testing.assert_allclose(sol.param_sensitivity, ref.param_sensitivity, rtol=1e-4, atol=1e-6)
        np.testing.assert_allclose(sol.defect_multipliers, ref.defect_multipliers, rtol=1e-4, atol=1e-5)


def test_free_time_state_and_time_modes() -> None:
    task = make_task("glider")
    tr = Transcription(task, codegen=True)
    sol = tr.solve(GLIDER_X, 0.8)
    assert sol.success
    assert sol.steps.sum() == pytest.approx(0.8, abs=1e-9)
    np.testing.assert_allclose(sol.primal[tr._t_idx], np.concatenate([[0.0], np.cumsum(sol.steps)]), atol=1e-9)
    # IPOPT relaxes bounds by 1e-8 (bound_relax_factor).
    assert np.all(sol.steps >= task.step_bounds[0] - 1e-7) and np.all(sol.steps <= task.step_bounds[1] + 1e-7)
    # A short lookahead with sum(h) <= tau (the MPC's problem): the terminal cost sees tau - sum(h) >= 0.
    short = Transcription(task, 10, time_mode="at_most", final_box=False, solver="fatrop").solve(GLIDER_X, 0.8)
    assert short.success and short.steps.sum() <= 0.8 + 1e-9


def test_fixed_step_mpc_horizon() -> None:
    """The MPC's use: a few intervals of the control period, no terminal box."""
    task = make_task("acrobot")
    tr = Transcription(task, 5, free_time=False, step=0.1, final_box=False, solver="fatrop")
    sol = tr.solve(ACROBOT_X, 5.0)
    assert sol.success
    np.testing.assert_allclose(sol.steps, 0.1)
    assert sol.states.shape == (6, 4) and sol.controls.shape == (5, 1)
    costs = tr.stage_costs(sol.states, sol.controls, sol.steps)
    assert costs.sum() + task.terminal_cost_value(sol.states[-1]) == pytest.approx(sol.objective, rel=1e-9)


def test_pack_guess_round_trip() -> None:
    task = make_task("glider")
    tr = Transcription(task, 4)
    rng = np.random.default_rng(0)
    states, controls, steps = rng.normal(size=(5, 7)), rng.normal(size=(4, 1)), rng.uniform(0.015, 0.03, 4)
    w = tr.pack_guess(states, controls, steps)
    np.testing.assert_array_equal(np.stack([w[i] for i in tr._x_idx]), states)
    np.testing.assert_array_equal(np.stack([w[i] for i in tr._u_idx]), controls)
    np.testing.assert_array_equal(w[tr._h_idx], steps)
    np.testing.assert_allclose(w[tr._t_idx], np.concatenate([[0.0], np.cumsum(steps)]))
    line = tr.line_guess(GLIDER_X, 0.8)
    np.testing.assert_array_equal(line[tr._x_idx[0]], GLIDER_X)
    np.testing.assert_array_equal(line[tr._x_idx[-1]], task.goal)


def test_codegen_library_is_cached(tmp_path) -> None:
    task = make_task("acrobot")
    a = Transcription(task, 1, free_time=False, step=0.1, codegen=True, codegen_dir=tmp_path)
    lib = a.codegen_library
    assert lib is not None and lib.parent == tmp_path and lib.is_file()
    mtime = lib.stat().st_mtime_ns
    b = Transcription(task, 1, free_time=False, step=0.1, codegen=True, codegen_dir=tmp_path)
    assert b.codegen_library == lib and lib.stat().st_mtime_ns == mtime  # loaded, not recompiled
    c = Transcription(task, 2, free_time=False, step=0.1, codegen=True, codegen_dir=tmp_path)
    assert c.codegen_library != lib  # another problem, another key
    assert a.solve(ACROBOT_X, 0.1).objective == pytest.approx(b.solve(ACROBOT_X, 0.1).objective, rel=1e-12)


def test_no_compiler_falls_back_to_interpreted(monkeypatch: pytest.MonkeyPatch, tmp_path) -> None:
    monkeypatch.setattr(tr_mod, "find_c_compiler", lambda: None)
    with pytest.warns(UserWarning, match="code generation unavailable"):
        tr = Transcription(make_task("acrobot"), 3, free_time=False, step=0.1, codegen=True, codegen_dir=tmp_path)
    assert tr.codegen_library is None
    assert tr.solve(ACROBOT_X, 0.3).success


def test_bad_arguments_raise() -> None:
    task = make_task("acrobot")
    with pytest.raises(ValueError, match="horizon"):
        Transcription(task, 0)
    with pytest.raises(ValueError, match="unknown solver"):
        Transcription(task, solver="snopt")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="time_mode"):
        Transcription(task, time_mode="sometimes")  # type: ignore[arg-type]
