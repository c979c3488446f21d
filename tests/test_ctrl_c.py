"""Ctrl-C during a solve stops the program: CasADi turns the interrupt it polls inside a solver into a failed
solve, and ``seagul_control._interrupt.interrupts_kept`` raises it again once the solver has returned."""

from __future__ import annotations

import os
import signal
import threading
import time

import numpy as np
import pytest

from seagul_control._interrupt import interrupts_kept


@pytest.fixture
def default_sigint():
    """Python's own SIGINT handler (test runners and their workers may install another one or ignore SIGINT)."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def test_an_interrupt_swallowed_inside_the_body_is_raised_after_it(default_sigint):
    swallowed = False
    with pytest.raises(KeyboardInterrupt):
        with interrupts_kept():
            try:
                signal.raise_signal(signal.SIGINT)  # what CasADi's solver loop sees ...
            except KeyboardInterrupt:
                swallowed = True  # ... and turns into a failed solve
    assert swallowed
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_an_exception_of_the_body_after_an_interrupt_becomes_the_interrupt(default_sigint):
    with pytest.raises(KeyboardInterrupt) as exc:
        with interrupts_kept():
            try:
                signal.raise_signal(signal.SIGINT)
            except KeyboardInterrupt:
                pass
            raise RuntimeError("solver died")  # e.g. the guarded solve's child killed by the same Ctrl-C
    assert isinstance(exc.value.__cause__, RuntimeError)


def test_without_an_interrupt_the_body_runs_and_its_exceptions_pass(default_sigint):
    with interrupts_kept():
        value = 1
    assert value == 1
    with pytest.raises(ValueError), interrupts_kept():
        raise ValueError("not an interrupt")


def test_another_handler_is_left_alone():
    seen = []
    previous = signal.signal(signal.SIGINT, lambda *_: seen.append(1))
    try:
        with interrupts_kept():
            signal.raise_signal(signal.SIGINT)
        assert seen == [1]
    finally:
        signal.signal(signal.SIGINT, previous)


def test_ctrl_c_during_an_ipopt_solve_raises_after_it(default_sigint):
    """One SIGINT sent while IPOPT runs in-process: CasADi ends the solve with ``NonIpopt_Exception_Thrown`` and
    clears the interrupt; the solve must still end in KeyboardInterrupt (it returned a failed solve without the
    re-raise)."""
    import seagul_control.transcription as transcription
    from seagul_envs import make_task

    task = make_task("acrobot")
    tr = transcription.Transcription(task, None, transcription.TranscriptionOptions(solver="ipopt", codegen=False))
    x0 = np.array([0.3, 0.2, 0.0, 0.0])  # far from upright: ~110 interpreted IPOPT iterations, ~0.5 s
    tr.solve(x0, task.tau_nominal)  # built before the interrupt
    timer = threading.Timer(0.05, os.kill, (os.getpid(), signal.SIGINT))
    start = time.perf_counter()
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            solution = tr.solve(x0, task.tau_nominal)
            # reached only when the interrupt was swallowed: say how
            pytest.fail(f"the solve returned {solution.status!r} after {time.perf_counter() - start:.2f} s")
    finally:
        timer.cancel()


def test_ctrl_c_during_a_guarded_solve_kills_its_child_and_the_next_solve_is_its_own(default_sigint):
    """fatrop solves in a forked child: a SIGINT while the parent waits raises KeyboardInterrupt, the child (still
    solving) is killed, so its late reply can never answer the next solve, which equals the uninterrupted one."""
    from seagul_control import _watchdog
    from seagul_control._watchdog import ForkedSolver
    from seagul_control.transcription import Transcription, TranscriptionOptions
    from seagul_envs import make_task

    if not ForkedSolver.supported:
        pytest.skip("needs os.fork")
    task = make_task("acrobot")
    trans = Transcription(task, 5, TranscriptionOptions(step=0.1, solver="fatrop", max_solve_time=30.0))
    x = np.array([0.3, -0.2, 0.0, 0.0])
    reference = trans.solve(x, 5.0)
    server = _watchdog._server()
    key = trans._guard._key
    real = server.solvers[key]

    class Slow:  # the Ctrl-C arrives while the parent waits; the reply after it is a stale one (from x0 = 0)
        def __call__(self, **args):
            os.kill(os.getppid(), signal.SIGINT)  # from inside the solve: no timer races the fork
            time.sleep(1.0)
            return real(**{**args, "x0": np.zeros_like(np.asarray(args["x0"]))})

        def stats(self):
            return real.stats()

    server.solvers[key] = Slow()
    server.stop()  # the next call forks a child holding the slow solver
    forks = server.forks
    with pytest.raises(KeyboardInterrupt):
        trans.solve(x, 5.0)
    assert server.pid is None and server.forks == forks + 1  # the interrupted child was killed and reaped
    server.solvers[key] = real
    time.sleep(1.2)  # past the moment the slow child would have replied, had it lived
    again = trans.solve(x, 5.0)
    assert server.forks == forks + 2  # a fresh child, with a fresh pipe
    np.testing.assert_allclose(again.primal, reference.primal, rtol=0, atol=1e-12)
