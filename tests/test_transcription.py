"""The one NLP builder: solver/codegen equivalence, the elapsed-time state, guesses, the compiled-library cache."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import seagul_control.transcription as tr_mod
from seagul_control import codegen
from seagul_control.transcription import STAGE_FIELDS, Transcription, TranscriptionOptions
from seagul_envs.tasks import make_task

ACROBOT_X = np.array([np.pi - 0.2, 0.15, 0.3, -0.2])
GLIDER_X = np.array([-3.5, 0.1, 0.0, 0.0, 7.0, 0.0, 0.0])


@pytest.mark.parametrize("name", ["acrobot", "glider"])
def test_interpreted_compiled_ipopt_and_fatrop_agree(name: str) -> None:
    task = make_task(name)
    x = ACROBOT_X if name == "acrobot" else GLIDER_X
    ref = Transcription(task, options=TranscriptionOptions(solver="ipopt", codegen=False)).solve(x, task.tau_nominal)
    assert ref.success
    # Same problem, same optimum: every variant starts from a perturbed copy of the reference solution. fatrop is
    # checked on the acrobot only: on the glider it needs the kinematic guess (even this guess stalls it at
    # max_iter; docs/experiments/trajopt.md), which TrajectoryOptimizer supplies.
    guess = ref.primal * (1 + 1e-3 * np.random.default_rng(0).standard_normal(ref.primal.size))
    variants = [("ipopt", False), ("ipopt", True)] + ([("fatrop", True)] if name == "acrobot" else [])
    sols = [
        Transcription(task, options=TranscriptionOptions(solver=solver, codegen=codegen)).solve(
            x, task.tau_nominal, guess=guess
        )
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
    tr = Transcription(task, options=TranscriptionOptions(codegen=True))
    sol = tr.solve(GLIDER_X, 0.8)
    assert sol.success
    assert sol.steps.sum() == pytest.approx(0.8, abs=1e-9)
    np.testing.assert_allclose(sol.primal[tr._t_idx], np.concatenate([[0.0], np.cumsum(sol.steps)]), atol=1e-9)
    # IPOPT relaxes bounds by 1e-8 (bound_relax_factor).
    assert np.all(sol.steps >= task.step_bounds[0] - 1e-7) and np.all(sol.steps <= task.step_bounds[1] + 1e-7)
    # A short lookahead with sum(h) <= tau (the MPC's problem): the terminal cost sees tau - sum(h) >= 0.
    short = Transcription(task, 10, TranscriptionOptions(time_mode="at_most", final_box=False, solver="fatrop")).solve(
        GLIDER_X, 0.8
    )
    assert short.success and short.steps.sum() <= 0.8 + 1e-9


def test_fixed_step_mpc_horizon() -> None:
    """The MPC's use: a few intervals of the control period, no terminal box."""
    task = make_task("acrobot")
    tr = Transcription(task, 5, TranscriptionOptions(free_time=False, step=0.1, final_box=False, solver="fatrop"))
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
    np.testing.assert_array_equal(w[tr.state_index], states)
    np.testing.assert_array_equal(w[tr.control_index], controls)
    np.testing.assert_array_equal(w[tr.step_index], steps)
    np.testing.assert_allclose(w[tr.time_index], np.concatenate([[0.0], np.cumsum(steps)]))
    line = tr.line_guess(GLIDER_X, 0.8)
    np.testing.assert_array_equal(line[tr.state_index[0]], GLIDER_X)
    np.testing.assert_array_equal(line[tr.state_index[-1]], task.goal)


def test_codegen_library_is_cached(tmp_path) -> None:
    task = make_task("acrobot")
    a = Transcription(task, 1, TranscriptionOptions(free_time=False, step=0.1, codegen=True, codegen_dir=tmp_path))
    lib = a.codegen_library
    assert lib is not None and lib.parent == tmp_path and lib.is_file()
    mtime = lib.stat().st_mtime_ns
    b = Transcription(task, 1, TranscriptionOptions(free_time=False, step=0.1, codegen=True, codegen_dir=tmp_path))
    assert b.codegen_library == lib and lib.stat().st_mtime_ns == mtime  # loaded, not recompiled
    c = Transcription(task, 2, TranscriptionOptions(free_time=False, step=0.1, codegen=True, codegen_dir=tmp_path))
    assert c.codegen_library != lib  # another problem, another key
    assert a.solve(ACROBOT_X, 0.1).objective == pytest.approx(b.solve(ACROBOT_X, 0.1).objective, rel=1e-12)


def test_no_compiler_falls_back_to_interpreted(monkeypatch: pytest.MonkeyPatch, tmp_path) -> None:
    monkeypatch.setattr(codegen, "find_c_compiler", lambda: None)
    with pytest.warns(UserWarning, match="code generation unavailable"):
        tr = Transcription(
            make_task("acrobot"), 3, TranscriptionOptions(free_time=False, step=0.1, codegen=True, codegen_dir=tmp_path)
        )
    assert tr.codegen_library is None
    assert tr.solve(ACROBOT_X, 0.3).success


def test_bad_arguments_raise() -> None:
    task = make_task("acrobot")
    with pytest.raises(ValueError, match="horizon"):
        Transcription(task, 0)
    with pytest.raises(ValueError, match=r"TranscriptionOptions\.solver must be one of 'ipopt', 'fatrop', 'shooting'"):
        Transcription(task, options=TranscriptionOptions(solver="snopt"))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="time_mode"):
        Transcription(task, options=TranscriptionOptions(time_mode="sometimes"))  # type: ignore[arg-type]


# ------------------------------------------------------------------------------------ per-stage set / get
class _SolverSpy:
    """Stands in for the CasADi solver and records the arguments each solve passes it."""

    def __init__(self, solver) -> None:
        self.solver = solver
        self.calls: list[dict] = []

    def __call__(self, **kwargs):
        self.calls.append({k: np.array(v, dtype=float, copy=True) for k, v in kwargs.items()})
        return self.solver(**kwargs)

    def stats(self):
        return self.solver.stats()


def test_index_maps_are_public_read_only_and_match_the_layout() -> None:
    tr = Transcription(make_task("glider"), 4)
    assert tr.state_index.shape == (5, 7) and tr.control_index.shape == (4, 1)
    assert tr.step_index.shape == (4,) and tr.time_index.shape == (5,) and tr.defect_rows.shape == (4, 7)
    np.testing.assert_array_equal(tr.initial_rows, np.arange(7))
    every = np.concatenate([tr.state_index.ravel(), tr.control_index.ravel(), tr.step_index, tr.time_index])
    np.testing.assert_array_equal(np.sort(every), np.arange(tr.num_variables))  # each variable exactly once
    with pytest.raises(ValueError, match="read-only"):
        tr.state_index[0, 0] = 3
    fixed = Transcription(make_task("acrobot"), 3, TranscriptionOptions(free_time=False, step=0.1))
    assert fixed.step_index.size == 0 and fixed.time_index.size == 0


def test_set_validates_stage_field_and_shape() -> None:
    tr = Transcription(make_task("acrobot"), 3, TranscriptionOptions(free_time=False, step=0.1, final_box=False))
    for stage in (-1, 4, 1.0, True, "0", None):
        with pytest.raises(ValueError, match=r"stage of field 'lbx' must be an integer in 0\.\.3"):
            tr.set(stage, "lbx", np.zeros(4))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"stage of field 'ubu' must be an integer in 0\.\.2"):
        tr.set(3, "ubu", 1.0)  # inputs exist on stages 0..n-1 only
    with pytest.raises(ValueError, match=r"unknown field 'lbz'; use one of \['h', 'lbh'"):
        tr.set(0, "lbz", 0.0)
    with pytest.raises(ValueError, match="unknown field"):
        tr.get(0, "LBX")
    with pytest.raises(ValueError, match=r"'lbh' needs free steps.*free_time=False"):
        tr.set(0, "lbh", 0.1)
    with pytest.raises(ValueError, match=r"field 'ubx' at stage 1 needs shape \(4,\), got \(3,\)"):
        tr.set(1, "ubx", np.zeros(3))
    with pytest.raises(ValueError, match=r"needs shape \(4,\), got \(\)"):
        tr.set(1, "ubx", 0.0)  # no silent broadcasting of a scalar over a state
    with pytest.raises(ValueError, match=r"needs shape \(1,\), got \(1, 1\)"):
        tr.set(0, "lbu", [[0.0]])
    with pytest.raises(ValueError, match="needs numbers"):
        tr.set(0, "lbu", "low")
    with pytest.raises(ValueError, match="contains NaN"):
        tr.set(0, "ubu", np.nan)
    with pytest.raises(ValueError, match="guess 'x' at stage 0 must be finite"):
        tr.set(0, "x", np.full(4, np.inf))
    with pytest.raises(ValueError, match="no initial guess is stored"):
        tr.get(0, "u")
    with pytest.raises(ValueError, match=r"set_guess: needs shape \(19,\), got \(3,\)"):
        tr.set_guess(np.zeros(3))
    # Nothing was changed by the rejected calls.
    task = tr.task
    np.testing.assert_array_equal(tr.get(1, "ubx"), task.x_high)
    np.testing.assert_array_equal(tr.get(0, "lbu"), task.u_low)
    assert tr.get_guess() is None
    assert set(STAGE_FIELDS) == {"x", "u", "h", "lbx", "ubx", "lbu", "ubu", "lbh", "ubh"}


def test_set_bounds_are_what_the_solver_sees() -> None:
    task = make_task("acrobot")
    tr = Transcription(task, 5, TranscriptionOptions(free_time=False, step=0.1, final_box=False))
    free = tr.solve(ACROBOT_X, 5.0)
    assert free.success and abs(free.controls[0, 0]) > 0.5  # the unconstrained plan pushes harder than 0.5
    cap = 0.5 * np.sign(free.controls[0, 0])
    field = "ubu" if cap > 0 else "lbu"
    tr.set(0, field, cap)
    assert tr.get(0, field).tolist() == [cap]
    spy = _SolverSpy(tr._solver)
    tr._solver = spy
    sol = tr.solve(ACROBOT_X, 5.0)
    # CasADi takes the bounds of every primal variable as lbx/ubx.
    sent = spy.calls[-1]
    assert sent["ubx" if cap > 0 else "lbx"][tr.control_index[0]].tolist() == [cap]
    np.testing.assert_array_equal(sent["lbx"][tr.control_index[1]], task.u_low)  # other stages untouched
    assert sol.success, sol.status
    assert sol.controls[0, 0] == pytest.approx(cap, abs=1e-6)  # the bound is active
    assert tr.solve(ACROBOT_X, 5.0).controls[0, 0] == pytest.approx(cap, abs=1e-6)  # bounds persist
    # A state box: pin x_3 (to a reachable point, the unconstrained plan's).
    pinned = Transcription(task, 5, TranscriptionOptions(free_time=False, step=0.1, final_box=False))
    pinned.set(3, "lbx", free.states[3])
    pinned.set(3, "ubx", free.states[3])
    spy = _SolverSpy(pinned._solver)
    pinned._solver = spy
    sol = pinned.solve(ACROBOT_X, 5.0)
    np.testing.assert_array_equal(spy.calls[-1]["lbx"][pinned.state_index[3]], free.states[3])
    np.testing.assert_array_equal(spy.calls[-1]["ubx"][pinned.state_index[3]], free.states[3])
    np.testing.assert_array_equal(spy.calls[-1]["ubx"][pinned.state_index[2]], task.x_high)
    assert sol.success, sol.status
    np.testing.assert_allclose(sol.states[3], free.states[3], atol=1e-7)
    np.testing.assert_allclose(sol.states, free.states, atol=1e-5)  # the optimum itself satisfies the pin


def test_free_step_bounds_and_stored_guess() -> None:
    task = make_task("glider")
    tr = Transcription(task, 6, TranscriptionOptions(time_mode="at_most", final_box=False))
    tr.set(0, "lbh", 0.02)
    tr.set(0, "ubh", 0.02)
    assert tr.get(0, "lbh").tolist() == [0.02] and tr.get(1, "ubh").tolist() == [task.step_bounds[1]]
    guess = tr.line_guess(GLIDER_X, 0.15)
    tr.set_guess(guess)
    tr.set(2, "h", 0.025)
    tr.set(1, "x", GLIDER_X + 0.01)
    stored = tr.get_guess()
    assert stored is not None and stored[tr.step_index[2]] == 0.025
    np.testing.assert_array_equal(tr.get(1, "x"), GLIDER_X + 0.01)
    np.testing.assert_allclose(stored[tr.time_index], np.concatenate([[0.0], np.cumsum(stored[tr.step_index])]))
    spy = _SolverSpy(tr._solver)
    tr._solver = spy
    sol = tr.solve(GLIDER_X, 0.15)
    np.testing.assert_array_equal(spy.calls[-1]["x0"], stored)  # solve without guess= uses the stored guess
    assert sol.success, sol.status
    assert sol.steps[0] == pytest.approx(0.02, abs=1e-7)
    tr.solve(GLIDER_X, 0.15, guess=guess)
    np.testing.assert_array_equal(spy.calls[-1]["x0"], guess)  # an explicit guess wins
    tr.set_guess(None)
    tr.solve(GLIDER_X, 0.15)
    np.testing.assert_array_equal(spy.calls[-1]["x0"], tr.line_guess(GLIDER_X, 0.15))  # back to the default
    # A partial guess starts from the zero guess of pack_guess.
    fresh = Transcription(task, 2, TranscriptionOptions(time_mode="at_most", final_box=False))
    fresh.set(0, "u", [1.5])
    zero = fresh.pack_guess(np.zeros((3, 7)), np.zeros((2, 1)))
    zero[fresh.control_index[0]] = 1.5
    np.testing.assert_array_equal(fresh.get_guess(), zero)


# ------------------------------------------------------------------------------------ the one cache directory
def test_one_cache_directory_for_compiled_code_and_data(monkeypatch: pytest.MonkeyPatch, tmp_path) -> None:
    import seagul_control.mpc as mpc_mod
    import seagul_learn.training as training
    from seagul_control import io as _io

    monkeypatch.delenv("SEAGUL_CACHE_DIR", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    root = tmp_path / "home" / ".cache" / "seagul"
    assert tr_mod.codegen_cache_dir() == mpc_mod.default_cache_dir() == root / "casadi"
    assert training.default_cache_dir() == root
    mine = tmp_path / "mine"
    monkeypatch.setenv("SEAGUL_CACHE_DIR", str(mine))
    assert tr_mod.codegen_cache_dir() == mpc_mod.default_cache_dir() == training.default_cache_dir() == mine
    assert _io.cache_dir("casadi") == _io.cache_dir() == tmp_path / "mine"
    assert mpc_mod.jit_solver_options is tr_mod.jit_solver_options  # one JIT-options builder
    if tr_mod.find_c_compiler() is not None:
        options = tr_mod.jit_solver_options()
        assert options is not None and str(tmp_path / "mine") in options["jit_options"]["compiler"]
        assert (tmp_path / "mine" / "seagul_cc.py").read_text() == codegen._CC_WRAPPER


def test_io_helpers_import_neither_torch_nor_casadi() -> None:
    code = (
        "import sys, seagul_control.io; "
        "bad = [m for m in ('torch', 'casadi', 'seagul_learn') if m in sys.modules]; "
        "sys.exit(f'imported {bad}' if bad else 0)"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
