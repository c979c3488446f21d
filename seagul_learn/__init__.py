"""seagul_learn: trajectory optimization with dual gradients, SEAGuL sampling, value networks, training, CLI."""

from __future__ import annotations

import importlib
from importlib.metadata import PackageNotFoundError, version
from typing import Any

try:
    __version__ = version("seagul")
except PackageNotFoundError:  # imported from a source tree that was never installed
    __version__ = "0+unknown"

# Public names, imported lazily so that `import seagul_learn` stays cheap (no torch or solver stack until used).
_LAZY: dict[str, str] = {
    "TrajectoryOptimizer": "seagul_learn.trajopt",
    "TrajOptConfig": "seagul_learn.trajopt",
    "SolveResult": "seagul_learn.results",
    "solve_many": "seagul_learn.parallel",
    "ValueNetwork": "seagul_learn.value_network",
    "Dataset": "seagul_learn.dataset",
    "SolveRecord": "seagul_learn.dataset",
    "UniformSampler": "seagul_learn.samplers",
    "AdversarialSampler": "seagul_learn.samplers",
    "AdversarialOptions": "seagul_learn.samplers",
    "TrainConfig": "seagul_learn.training",
    "train": "seagul_learn.training",
    "PolicySpec": "seagul_learn.policies",
    "SB3Policy": "seagul_learn.policies",
    "build_policy": "seagul_learn.policies",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'seagul_learn' has no attribute {name!r}")


__all__ = sorted(_LAZY)
