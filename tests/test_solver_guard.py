"""The wall-time guard of solves (``max_solve_time``): fatrop runs in a killable child, IPOPT stops itself.

fatrop's regularisation loop has no upper limit and once looped without end inside one MPC step
(docs/experiments/closed-loop.md, "fatrop hangs inside a solve"). A solve that never returns is stood in for by a solver
that sleeps far longer than the limit: the guard must stop it at the limit, report it as a failed solve, and
the next solve must work again (a fresh child). The outcome is asserted by the solve's status (``"timeout: ..."``)
and the counters (``ForkedSolver.timeouts``, ``_Server.forks``, ``TrajectoryOptimizer.counters.timeouts``), never by
the elapsed wall time: a loaded machine changes how long a solve takes, not what the guard reports. A guard that
did not stop the sleeper would let it return nothing after a minute, and every status assertion would fail.
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import numpy as np
import pytest

from seagul_control import _watchdog
from seagul_control._watchdog import ForkedSolver, SolveTimeout
from seagul_control.mpc import FullHorizonMPC, LimitedLookaheadMPC, MPCOptions
from seagul_control.transcription import Transcription, TranscriptionOptions
from seagul_envs import make_task

pytestmark = pytest.mark.skipif(not ForkedSolver.supported, reason="needs os.fork")

X = np.array([0.3, -0.2, 0.0, 0.0])


class _Hang:
    """A solver that does not return for a minute (fatrop's unbounded loop, as seen from outside)."""

    def __call__(self, **args):
        time.sleep(60)

    def stats(self):
        return {}


def _hang_next_solve(trans: Transcription) -> tuple[_watchdog._Server, int]:
    """Make the next guarded solve of ``trans`` hang (its solver swapped for :class:`_Hang`, the child stopped so the
    next call forks one holding it); returns the server and the solver's key, to put the real solver back."""
    server = _watchdog._server()
    key = trans._guard._key
    server.solvers[key] = _Hang()
    server.stop()
    return server, key


def _short_limit(trans: Transcription, seconds: float) -> None:
    """Give the guard of ``trans`` a short limit for the hung solve only: the real solves keep a generous one, so a
    loaded machine never times them out (the limit is read at each call)."""
    trans._guard.max_solve_time = seconds


def _child_alive(pid: int | None) -> bool:
    if pid is None:
        return False
    try:
        done, _ = os.waitpid(pid, os.WNOHANG)
    except ChildProcessError:
        return False
    return done == 0


def test_guarded_fatrop_solve_equals_the_direct_one():
    task = make_task("acrobot")
    direct = Transcription(task, 5, TranscriptionOptions(step=0.1, solver="fatrop"))
    guarded = Transcription(task, 5, TranscriptionOptions(step=0.1, solver="fatrop", max_solve_time=5.0))
    a, b = direct.solve(X, 5.0), guarded.solve(X, 5.0)
    assert a.success and b.success
    assert b.status == a.status and b.iterations == a.iterations
    np.testing.assert_allclose(b.primal, a.primal, rtol=0, atol=1e-12)
    np.testing.assert_allclose(b.lam_g, a.lam_g, rtol=0, atol=1e-12)
    assert b.objective == pytest.approx(a.objective, abs=1e-12)
    # warm-started from the solution: the same again
    c, d = direct.solve(X + 0.01, 4.9, guess=a.primal), guarded.solve(X + 0.01, 4.9, guess=a.primal)
    np.testing.assert_allclose(d.primal, c.primal, rtol=0, atol=1e-12)


def test_a_solve_that_never_returns_is_stopped_at_the_limit_and_the_next_one_works():
    task = make_task("acrobot")
    trans = Transcription(task, 5, TranscriptionOptions(step=0.1, solver="fatrop", max_solve_time=60.0))
    reference = trans.solve(X, 5.0)
    server, key = _hang_next_solve(trans)
    forks = server.forks
    _short_limit(trans, 1.0)
    hung = trans.solve(X, 5.0)
    assert not hung.success and hung.status == "timeout: no solution within max_solve_time=1 s (solve stopped)"
    assert np.all(np.isnan(hung.controls))
    assert trans._guard.timeouts == 1
    assert server.forks == forks + 1  # one child, forked for the hung solve
    assert server.pid is None  # the hanging child was killed and reaped
    server.solvers[key] = trans._solver
    _short_limit(trans, 60.0)
    again = trans.solve(X, 5.0)
    assert again.success and trans._guard.timeouts == 1
    assert server.forks == forks + 2  # a fresh child for the next solve
    np.testing.assert_allclose(again.primal, reference.primal, rtol=0, atol=1e-12)
    assert _child_alive(server.pid)


def test_forked_solver_raises_timeout_and_reports_solver_errors():
    slow = ForkedSolver(_Hang(), 0.3)
    with pytest.raises(SolveTimeout, match=r"max_solve_time=0\.3"):
        slow()

    class Broken:
        def __call__(self, **args):
            raise ValueError("bad input to the solver")

        def stats(self):
            return {}

    with pytest.raises(RuntimeError, match="bad input to the solver"):
        ForkedSolver(Broken(), 1.0)(x0=np.zeros(2))


def test_the_mpc_falls_back_when_a_step_hits_the_limit():
    task = make_task("acrobot")
    mpc = LimitedLookaheadMPC(task, None, 5, MPCOptions(jit=False, max_solve_time=60.0, solver="fatrop"))
    _, info0 = mpc.act(X, 5.0)
    assert info0.source == "solver"
    problem, _ = mpc._select(4.9)
    server, key = _hang_next_solve(problem.trans)
    _short_limit(problem.trans, 0.5)
    u1, info1 = mpc.act(X, 4.9)
    assert not info1.success and info1.status.startswith("timeout")
    assert problem.trans._guard.timeouts == 1
    assert info1.source == "shifted"  # the previous plan's next input, as for any failed solve
    assert np.all(np.isfinite(u1))
    server.solvers[key] = problem.trans._solver
    _short_limit(problem.trans, 60.0)
    _, info2 = mpc.act(X, 4.8)
    assert info2.success and problem.trans._guard.timeouts == 1


def test_ipopt_gets_its_own_wall_time_limit_and_bad_limits_are_named():
    task = make_task("acrobot")
    trans = Transcription(task, 5, TranscriptionOptions(step=0.1, solver="ipopt", max_solve_time=1e-6))
    assert trans._guard is None  # IPOPT stops itself (ipopt.max_wall_time): no child
    out = trans.solve(X, 5.0)
    assert not out.success and out.status == "Maximum_WallTime_Exceeded"
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="max_solve_time"):
            Transcription(task, 5, TranscriptionOptions(step=0.1, solver="fatrop", max_solve_time=bad))
        with pytest.raises(ValueError, match="max_solve_time"):
            LimitedLookaheadMPC(task, None, 5, MPCOptions(jit=False, max_solve_time=bad))


def test_a_trajectory_optimizer_attempt_that_never_returns_gives_way_to_the_next_attempt():
    """A full solve's fatrop attempt that hangs (one looped for 50 minutes in a training run) is stopped at
    ``TrajOptConfig.max_solve_time``; the plan's IPOPT attempt then solves it, with the same value as unguarded."""
    from seagul_learn.trajopt import TrajectoryOptimizer

    plan = ("fatrop:line", "ipopt:line")
    reference = TrajectoryOptimizer("acrobot", plan=plan, max_solve_time=None).solve(X, 5.0)
    # IPOPT's own wall-time stop is set far off (an option of its own wins over max_solve_time): on a loaded machine
    # a 1 s limit also stopped the IPOPT attempts, and this test is about the fatrop guard alone.
    no_ipopt_limit = {"ipopt.max_wall_time": 3600.0}
    opt = TrajectoryOptimizer("acrobot", plan=plan, max_solve_time=1.0, solver_options=no_ipopt_limit)
    fatrop = opt._transcription("fatrop")
    assert fatrop.max_solve_time == 1.0 and fatrop._guard is not None
    assert opt._transcription("ipopt").max_solve_time == 1.0 and opt._transcription("ipopt")._guard is None
    server, key = _hang_next_solve(fatrop)
    out = opt.solve(X, 5.0)
    assert out.success and out.value == pytest.approx(reference.value, rel=1e-6)
    assert out.status == "Solve_Succeeded"  # the IPOPT attempt's
    assert fatrop._guard.timeouts == 1
    assert (opt.counters.solves, opt.counters.timeouts, opt.counters.fallbacks, opt.counters.failures) == (1, 1, 1, 0)
    server.solvers[key] = fatrop._solver
    with pytest.raises(ValueError, match="max_solve_time"):
        TrajectoryOptimizer("acrobot", max_solve_time=0.0)


class _Crash:
    """A solver whose process dies inside the solve (SIGKILL: a segfault or the OOM killer, as seen from outside)."""

    def __call__(self, **args):
        os.kill(os.getpid(), signal.SIGKILL)

    def stats(self):
        return {}


def test_a_solving_child_that_dies_fails_that_solve_and_the_next_one_works():
    """A crash inside the solver (or a kill from outside) of the guarded child is a failed solve, not an exception
    that ends an evaluation or a training run; the next solve forks a fresh child. The child kills itself inside
    the solve: no timer races the fork."""
    task = make_task("acrobot")
    trans = Transcription(task, 5, TranscriptionOptions(step=0.1, solver="fatrop", max_solve_time=600.0))
    reference = trans.solve(X, 5.0)
    server, key = _hang_next_solve(trans)
    server.solvers[key] = _Crash()
    died = trans.solve(X, 5.0)
    assert not died.success and died.status.startswith("solver died")
    assert trans._guard.timeouts == 0  # a death, not a timeout
    assert server.pid is None
    server.solvers[key] = trans._solver
    again = trans.solve(X, 5.0)
    np.testing.assert_allclose(again.primal, reference.primal, rtol=0, atol=1e-12)


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="Linux: PR_SET_PDEATHSIG")
def test_the_solving_child_dies_with_its_parent():
    """A parent killed while its child is inside a solve that never returns (a Ray actor killed mid-solve) does not
    leave the child spinning."""
    read, write = os.pipe()
    parent = os.fork()
    if parent == 0:  # a process with a guarded solver whose child hangs; it reports the child's pid, then waits
        try:
            os.close(read)
            server = _watchdog._server()
            server.solvers[0] = _Hang()
            server.start()
            os.write(write, str(server.pid).encode())
            server.conn.send((0, {}))
            time.sleep(60)
        finally:
            os._exit(0)
    os.close(write)
    child = int(os.read(read, 64).decode())
    os.close(read)
    assert Path(f"/proc/{child}").exists()
    os.kill(parent, signal.SIGKILL)
    os.waitpid(parent, 0)
    deadline = time.monotonic() + 60.0  # a bound on the wait for the kernel's kill, not on its speed
    while Path(f"/proc/{child}").exists() and "Z" not in _state(child) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not Path(f"/proc/{child}").exists() or "Z" in _state(child)


def _state(pid: int) -> str:
    try:
        return next(line for line in Path(f"/proc/{pid}/status").read_text().splitlines() if line.startswith("State"))
    except (OSError, StopIteration):
        return "Z (gone)"


def test_the_full_horizon_reference_gets_more_time_per_solve_than_a_real_time_step():
    """``FullHorizonMPC`` defaults to 60 s per solve (the lookahead: 5 s), and its problems carry that limit: at 5 s a
    loaded machine timed out the glider reference's steps and changed its episodes."""

    task = make_task("acrobot")
    lookahead = LimitedLookaheadMPC(task, None, 5, MPCOptions(jit=False))
    full = FullHorizonMPC(task)
    assert lookahead.max_solve_time == 5.0 and full.max_solve_time == 60.0
    problem, _ = full._select(4.9)
    assert problem.trans.max_solve_time == 60.0
