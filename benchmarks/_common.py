"""What every benchmark reports about the machine it ran on (timings are only comparable within one run), and the
seed lists their command lines take."""

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


def parse_seeds(text: str) -> list[int]:
    """``"0-9"``, ``"0,3,5"`` or a mix (``"0-4,10"``) -> the list of seeds, in order; anything else raises
    ``ValueError`` naming the part it could not read."""
    seeds: list[int] = []
    for part in (p.strip() for p in text.split(",")):
        if not part:
            continue
        try:
            if "-" in part:
                lo, hi = part.split("-")
                if int(hi) < int(lo):
                    raise ValueError
                seeds.extend(range(int(lo), int(hi) + 1))
            else:
                seeds.append(int(part))
        except ValueError:
            raise ValueError(f"seeds: cannot read {part!r} (expected N, A-B with A <= B, or a comma list)") from None
    if not seeds:
        raise ValueError(f"seeds: no seed in {text!r}")
    return seeds
