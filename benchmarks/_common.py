"""What every benchmark reports about the machine it ran on (timings are only comparable within one run)."""

from __future__ import annotations

import importlib
import os
import platform
from pathlib import Path
from typing import Any


def _cpu_model() -> str:
    """The first ``model name`` of ``/proc/cpuinfo``, else ``platform.processor()``, else ``platform.machine()``."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine(*extra_libraries: str) -> dict[str, Any]:
    """The machine, the interpreter, the library versions and the load at the time of the call.

    Keys: ``platform`` (``platform.platform()``), ``python``, ``casadi`` and ``numpy`` (versions), ``cpu`` (the CPU
    model, see ``_cpu_model``), ``cores`` (``os.cpu_count()``, the machine's logical CPUs), ``cores_available``
    (``len(os.sched_getaffinity(0))``, the CPUs this process may run on; ``None`` where unsupported),
    ``load_avg`` (the 1/5/15-minute load averages rounded to 2 decimals; ``None`` without ``os.getloadavg``) and
    ``load_avg_1m`` (its first entry, or ``None``).

    Each of ``extra_libraries`` is a module name (e.g. ``"mujoco"``, ``"gymnasium"``, ``"torch"``,
    ``"stable_baselines3"``), imported here, that adds the key ``<name>: module.__version__``; an import error
    propagates.
    """
    import casadi
    import numpy

    try:
        cores_available: int | None = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cores_available = None
    try:
        load: list[float] | None = [round(v, 2) for v in os.getloadavg()]
    except (AttributeError, OSError):
        load = None
    info: dict[str, Any] = {
        "platform": platform.platform(),
        "python": platform.python_version(),
        "casadi": casadi.__version__,
        "numpy": numpy.__version__,
        "cpu": _cpu_model(),
        "cores": os.cpu_count(),
        "cores_available": cores_available,
        "load_avg_1m": load[0] if load else None,
        "load_avg": load,
    }
    for name in extra_libraries:
        info[name] = importlib.import_module(name).__version__
    return info
