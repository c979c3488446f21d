"""A wall-time guard for solvers that cannot stop themselves: the solve runs in a forked child that can be killed.

Why: fatrop's search-direction loop raises the Hessian regularisation until the KKT matrix has the right inertia
and has no upper limit (``while (regularity != 0)`` in its ``FatropAlg``): on a KKT matrix that no regularisation
fixes (a non-finite entry) it never returns, and ``max_iter`` does not bound it because it counts outer
iterations. IPOPT has ``max_wall_time``; fatrop has nothing equivalent, and a C loop cannot be interrupted from
Python. So :class:`ForkedSolver` solves in one child process per user process, forked from it (the compiled solvers are
inherited, nothing is rebuilt or pickled), sends it each call's arguments over a pipe and waits at most
``max_solve_time``; a call that takes longer kills the child and raises :class:`SolveTimeout`, and the next call
forks a fresh child. The round trip costs tens of microseconds per call (measured in docs/experiments/mpc.md).

POSIX only (``os.fork``); elsewhere the solver is called directly and the guard is off, with a warning.
"""

from __future__ import annotations

import itertools
import os
import signal
import warnings
import weakref
from multiprocessing import Pipe
from multiprocessing.connection import Connection
from typing import Any

import numpy as np


class SolveTimeout(RuntimeError):
    """A guarded solve did not return within its wall-time limit (the child running it was killed)."""


class SolverDied(RuntimeError):
    """The child running a guarded solve died (a crash inside the solver, or a kill from outside): that solve failed,
    the next call forks a fresh child."""


def _die_with_parent(parent: int) -> None:
    """Linux: the child is SIGKILLed when its parent dies (``PR_SET_PDEATHSIG``), so a solve that never returns
    does not outlive a killed parent (e.g. a Ray actor killed mid-solve). Best effort elsewhere."""
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL))  # PR_SET_PDEATHSIG = 1
    except (OSError, AttributeError):
        return
    if os.getppid() != parent:  # the parent died before prctl took effect
        os._exit(1)


def _serve(solvers: dict[int, Any], conn: Connection) -> None:
    """The child's loop: solve each request with the solver it names, send back the outputs (as arrays) and the
    solver's stats."""
    while True:
        try:
            key, args = conn.recv()
        except (EOFError, OSError, KeyboardInterrupt):
            return
        try:
            solver = solvers[key]
            out = solver(**args)
            reply: tuple[str, Any, Any] = ("ok", {k: np.asarray(v) for k, v in out.items()}, dict(solver.stats()))
        except Exception as exc:  # the parent re-raises it
            reply = ("error", f"{type(exc).__name__}: {exc}", None)
        try:
            conn.send(reply)
        except (OSError, KeyboardInterrupt):
            return


def _stop(pid: int, conn: Connection) -> None:
    """Close the pipe (an idle child exits on EOF), kill the child and reap it."""
    try:
        conn.close()
    except OSError:
        pass
    try:
        os.kill(pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    try:
        os.waitpid(pid, 0)
    except ChildProcessError:
        pass


class _Server:
    """This process's one solving child, serving every guarded solver that existed when it was forked."""

    def __init__(self) -> None:
        self.owner = os.getpid()
        self.solvers: dict[int, Any] = {}
        """Every live guarded solver of this process, by key."""
        self.pid: int | None = None
        self.conn: Connection | None = None
        self.known: set[int] = set()
        """The keys the current child has (it was forked after they were registered)."""
        self.forks = 0
        self._finalizer: weakref.finalize | None = None

    def start(self) -> None:
        self.stop()
        parent, child = Pipe(duplex=True)
        owner = os.getpid()
        # SIGINT is blocked across the fork: an interrupt landing in the child before its try block would return
        # into the parent's code in the child (a second copy of the program, running on). The child then ignores
        # SIGINT (a Ctrl-C is the parent's to handle; the parent kills the child); the parent gets any pending one.
        masked = hasattr(signal, "pthread_sigmask")
        if masked:
            signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        pid = os.fork()
        if pid == 0:  # the child: serve until the parent goes away, never return into the parent's code
            code = 0
            try:
                try:
                    signal.signal(signal.SIGINT, signal.SIG_IGN)
                except ValueError:  # forked from a thread Python does not treat as main: keep the mask instead
                    pass
                else:
                    if masked:
                        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
                _die_with_parent(owner)
                parent.close()
                _serve(self.solvers, child)
            except BaseException:
                code = 1
            finally:
                os._exit(code)
        if masked:
            signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
        child.close()
        self.pid, self.conn, self.known = pid, parent, set(self.solvers)
        self._finalizer = weakref.finalize(self, _stop, pid, parent)
        self.forks += 1

    def stop(self) -> None:
        if self._finalizer is not None:
            self._finalizer()
        self.pid = self.conn = self._finalizer = None
        self.known = set()

    def call(self, key: int, args: dict[str, Any], limit: float) -> tuple[dict[str, Any], dict[str, Any]]:
        if self.conn is None or key not in self.known:
            self.start()  # (re)fork: the child then holds every solver built so far
        conn = self.conn
        assert conn is not None
        # One try block from the request to the reply: a Ctrl-C landing anywhere in between (also between the poll
        # and the read) stops the child, so that its late reply can never answer a later call.
        try:
            conn.send((key, args))
            if not conn.poll(limit):
                self.stop()
                raise SolveTimeout(f"no solution within max_solve_time={limit:g} s (solve stopped)")
            kind, payload, stats = conn.recv()
        except SolveTimeout:
            raise
        except (BrokenPipeError, EOFError, OSError) as exc:  # the child crashed inside the solver, or was killed
            self.stop()
            raise SolverDied(f"the solver's child process died ({exc})") from exc
        except BaseException:  # Ctrl-C mid-solve
            self.stop()
            raise
        if kind != "ok":
            raise RuntimeError(payload)
        return payload, stats


_SERVER: _Server | None = None


def _server() -> _Server:
    """This process's server (a process forked from ours, e.g. a joblib worker, gets its own)."""
    global _SERVER
    if _SERVER is None or _SERVER.owner != os.getpid():
        _SERVER = _Server()
    return _SERVER


def _unregister(key: int) -> None:
    server = _SERVER
    if server is not None and server.owner == os.getpid():
        server.solvers.pop(key, None)


class ForkedSolver:
    """Call ``solver(**args)`` in this process's solving child with a wall-time limit; :meth:`stats` as CasADi's.

    One child serves every guarded solver of the process: a solver built after the child was forked makes the next
    call re-fork it (once), and a timeout kills it (the next call forks a fresh one).
    """

    supported = hasattr(os, "fork")
    _keys = itertools.count()

    def __init__(self, solver: Any, max_solve_time: float) -> None:
        if not (np.isfinite(max_solve_time) and max_solve_time > 0):
            raise ValueError(f"max_solve_time must be a positive number of seconds, got {max_solve_time!r}")
        self.solver = solver
        self.max_solve_time = float(max_solve_time)
        self.timeouts = 0
        """Calls of this solver that hit the limit (each killed the child)."""
        self._stats: dict[str, Any] = {}
        self._key = -1
        if not self.supported:
            warnings.warn("no os.fork on this platform: solves run unguarded (no wall-time limit)", stacklevel=2)
        else:
            self._register()

    def _register(self) -> None:
        self._key = next(self._keys)
        _server().solvers[self._key] = self.solver
        weakref.finalize(self, _unregister, self._key)

    def __call__(self, **args: Any) -> dict[str, Any]:
        if not self.supported:
            out = self.solver(**args)
            self._stats = dict(self.solver.stats())
            return out
        server = _server()
        if self._key not in server.solvers:  # first use in a process forked from the one that built us
            self._register()
        try:
            out, self._stats = server.call(self._key, args, self.max_solve_time)
        except SolveTimeout:
            self.timeouts += 1
            raise
        return out

    def stats(self) -> dict[str, Any]:
        """The last call's solver statistics."""
        return self._stats

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_key"] = -1
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        if self.supported:
            self._register()
