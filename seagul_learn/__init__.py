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
    "UniformOptions": "seagul_learn.sampler_options",
    "AdversarialSampler": "seagul_learn.samplers",
    "AdversarialOptions": "seagul_learn.sampler_options",
    "ClosedLoopOptions": "seagul_learn.sampler_options",
    "SamplerOptions": "seagul_learn.sampler_options",
    "TrainConfig": "seagul_learn.config",
    "NetworkConfig": "seagul_learn.config_parts",
    "ScheduleConfig": "seagul_learn.config_parts",
    "LossConfig": "seagul_learn.config_parts",
    "RefitConfig": "seagul_learn.config_parts",
    "SelectionConfig": "seagul_learn.config_parts",
    "RuntimeConfig": "seagul_learn.config_parts",
    "train": "seagul_learn.training",
    "PolicySpec": "seagul_learn.policies",
    "SB3Policy": "seagul_learn.policies",
    "build_policy": "seagul_learn.policies",
}

# Submodules served the same way: ``seagul_learn.recipes.recipe(task, name)`` without an import of its own.
_LAZY_MODULES: dict[str, str] = {
    "recipes": "seagul_learn.recipes",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    if name in _LAZY_MODULES:
        return importlib.import_module(_LAZY_MODULES[name])
    raise AttributeError(f"module 'seagul_learn' has no attribute {name!r}")


__all__ = sorted([*_LAZY, *_LAZY_MODULES])
