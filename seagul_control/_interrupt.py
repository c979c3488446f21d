"""Ctrl-C during a solve stops the program.

CasADi polls Python's signal handlers inside its solvers (IPOPT, fatrop, compiled functions) and turns the
``KeyboardInterrupt`` it receives into a failed solve (IPOPT: ``NonIpopt_Exception_Thrown`` with a
``KeyboardInterruptException`` warning; fatrop: an unknown return code), after which the pending interrupt is gone:
the trajectory optimizer then tries its next attempt and a training run goes on. :func:`interrupts_kept` remembers
that SIGINT arrived while a solve ran and raises ``KeyboardInterrupt`` once the solver has returned, so Ctrl-C stops
a run at the next solve boundary and ``--resume`` finishes it.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType


@contextmanager
def interrupts_kept() -> Iterator[None]:
    """Run the body with a SIGINT handler that records the signal (and raises ``KeyboardInterrupt`` as Python's
    default one does); if a SIGINT arrived and the body returned anyway, raise ``KeyboardInterrupt`` after it.

    Only where Python's default handler is installed and in the main thread (signal handlers can be set nowhere
    else); elsewhere (a user's own handler, a worker thread, SIGINT ignored) the body runs unchanged."""
    if (
        threading.current_thread() is not threading.main_thread()
        or signal.getsignal(signal.SIGINT) is not signal.default_int_handler
    ):
        yield
        return
    received: list[int] = []

    def handler(signum: int, frame: FrameType | None) -> None:
        received.append(signum)
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, handler)
    try:
        yield
    except Exception as exc:  # e.g. a guarded solve's child that the same Ctrl-C killed
        if received:
            raise KeyboardInterrupt from exc
        raise
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    if received:
        raise KeyboardInterrupt
