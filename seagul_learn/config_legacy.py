"""The flat ``TrainConfig`` field names of earlier versions and where each one lives now.

Until the config became nested it was one dataclass of 59 flat fields (``cl_episodes``, ``adv_max_steps``,
``refit_steps``, ``select_episodes``, ``hidden``, ``sobolev_weight``, ...). :data:`LEGACY_NAMES` maps each to its
part and field; :func:`new_name` and :func:`flat_name` translate one way and the other, :func:`flat_fields` a whole
partial config (a recipe) to the old form, for code that still reads it.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from seagul_learn.config_parts import SECTIONS

_ADV = "adversarial"
_CL = "closed-loop"

#: The flat field names of earlier versions -> ``(part, field, sampler)``: the part of :class:`TrainConfig` (None:
#: top level) and the field there; ``sampler`` names the options class a ``sampler`` field belongs to.
LEGACY_NAMES: dict[str, tuple[str | None, str, str | None]] = {
    "solves_per_round": ("schedule", "solves_per_round", None),
    "train_steps_per_round": ("schedule", "train_steps_per_round", None),
    "batch_size": ("schedule", "batch_size", None),
    "newest_fraction": ("schedule", "newest_fraction", None),
    "lr": ("schedule", "lr", None),
    "pretrain_solves": ("schedule", "pretrain_solves", None),
    "pretrain_steps": ("schedule", "pretrain_steps", None),
    "eval_every": ("schedule", "eval_every", None),
    "sobolev_weight": ("loss", "sobolev_weight", None),
    "value_cap": ("loss", "value_cap", None),
    "grad_label_max": ("loss", "grad_label_max", None),
    "renormalize": ("loss", "renormalize", None),
    "hidden": ("network", "hidden", None),
    "ensemble": ("network", "ensemble", None),
    "ensemble_pessimism": ("network", "pessimism", None),
    "refit_steps": ("refit", "steps", None),
    "refit_ensemble": ("refit", "ensemble", None),
    "refit_candidates": ("refit", "candidates", None),
    "select_episodes": ("selection", "episodes", None),
    "select_finalists": ("selection", "finalists", None),
    "select_final_episodes": ("selection", "final_episodes", None),
    "select_slice_fraction": ("selection", "slice_fraction", None),
    "select_jit": ("selection", "jit", None),
    "workers": ("runtime", "workers", None),
    "backend": ("runtime", "backend", None),
    "cache_dir": ("runtime", "cache_dir", None),
    "progress": ("runtime", "progress", None),
    "snapshots": ("runtime", "snapshots", None),
    "torch_threads": ("runtime", "torch_threads", None),
    **{
        f"adv_{n}": ("sampler", n, _ADV)
        for n in (
            "max_steps",
            "step_fraction",
            "eps",
            "optimizer",
            "projection",
            "uniform_fraction",
            "ascend_tau",
            "ascend_theta",
            "stop_on_decrease",
        )
    },
    **{
        f"cl_{n}": ("sampler", n, _CL)
        for n in (
            "episodes",
            "horizon",
            "trust_region",
            "warmup_rounds",
            "selection",
            "tail_stride",
            "uniform_fraction",
            "uniform_solves",
            "jit",
            "visited_fraction",
            "slice_fraction",
            "collect_refit",
            "keep_best",
        )
    },
}


def new_name(legacy: str) -> str:
    """The dotted place of a flat name of earlier versions (``"cl_episodes"`` -> ``"sampler.episodes"``)."""
    part, name, _ = LEGACY_NAMES[legacy]
    return name if part is None else f"{part}.{name}"


def flat_name(name: str) -> str:
    """The flat name of earlier versions for a dotted field (``"sampler.episodes"`` -> ``"cl_episodes"``; a field of
    both sampler option classes takes the closed-loop one's); other names unchanged."""
    if "." not in name:
        return name
    part, _, field_name = name.partition(".")
    for legacy, (p, n, _owner) in sorted(LEGACY_NAMES.items(), key=lambda kv: kv[1][2] != _CL):
        if p == part and n == field_name:
            return legacy
    return name


def flat_fields(nested: Mapping[str, Any]) -> dict[str, Any]:
    """Partial TrainConfig data (nested, as a recipe file holds it) in the flat names of earlier versions (tuples for
    lists; ``sampler`` as its name); keys without a flat name (new fields) keep their dotted name."""
    out: dict[str, Any] = {}
    for key, value in nested.items():
        if key == "sampler" and isinstance(value, Mapping):
            out["sampler"] = value.get("name")
            owner = value.get("name")
            for n, v in value.items():
                if n == "name":
                    continue
                legacy = next(
                    (k for k, (p, f, o) in LEGACY_NAMES.items() if p == "sampler" and f == n and o == owner),
                    f"sampler.{n}",
                )
                out[legacy] = _flat_value(legacy, v)
        elif key in SECTIONS and isinstance(value, Mapping):
            for n, v in value.items():
                legacy = flat_name(f"{key}.{n}")
                out[legacy] = _flat_value(legacy, v)
        else:
            out[key] = tuple(value) if isinstance(value, list) else value
    return out


def _flat_value(legacy: str, value: Any) -> Any:
    if legacy == "cl_horizon" and value is None:
        return 0
    return tuple(value) if isinstance(value, list) else value


def _legacy_value(legacy: str, value: Any) -> Any:
    """A flat value in its new form (``cl_horizon = 0`` meant the task's default: ``horizon = None``)."""
    if legacy == "cl_horizon":
        return None if value in (0, None) else int(value)
    return value
