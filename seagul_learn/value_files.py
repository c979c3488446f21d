"""The value-network file format: what :meth:`ValueNetwork.save <seagul_learn.value_network.ValueNetwork.save>` and
:meth:`ValueEnsemble.save <seagul_learn.ensemble.ValueEnsemble.save>` write and
:meth:`ValueNetwork.load <seagul_learn.value_network.ValueNetwork.load>` reads.

One ``torch.save`` file holding a plain dict ``{"format": "seagul-value-network", "version": 1, "task_name",
"task_fingerprint", "config": {"nx", "hidden", "n_params"}, "state_dict"}`` (an ensemble: ``"format":
"seagul-value-ensemble"`` and also ``"members"`` and ``"pessimism"`` in its config). A network with periodic angles
(fed as ``(cos q, sin q)``) also has ``"periodic"``, the list of their state indices, in its config; files without
the key (all files written before it existed) are networks without periodic angles. Tensors and builtins only, so it
loads with ``weights_only=True`` (no code runs on load). ``task_fingerprint`` is the trained task's
:meth:`~seagul_envs.tasks.base.Task.fingerprint` (``""`` when unknown; files written before it existed lack the key
and load with ``""``): an MPC refuses a network whose fingerprint is not its task's, so a network trained on one
variant of a task is never used on a same-named other one. Files are written atomically (temp file + rename), so a
reader never sees half a network.
"""

from __future__ import annotations

import io
import os
from pathlib import Path
from typing import Any

import torch
from torch import nn

from seagul_control.io import atomic_write_bytes

__all__ = [
    "ENSEMBLE_FORMAT_TAG",
    "FORMAT_TAG",
    "FORMAT_VERSION",
    "ValueNetworkFileError",
    "check_version",
    "read_value_file",
    "write_value_file",
]

FORMAT_TAG = "seagul-value-network"
"""The ``"format"`` of a single network's file."""
ENSEMBLE_FORMAT_TAG = "seagul-value-ensemble"
"""The ``"format"`` of an ensemble's file."""
FORMAT_VERSION = 1
"""The ``"version"`` this seagul writes and reads."""


class ValueNetworkFileError(ValueError):
    """A network file is missing, unreadable, corrupt or not a seagul value network."""


def write_value_file(
    path: str | os.PathLike[str],
    tag: str,
    task_name: str,
    config: dict[str, Any],
    module: nn.Module,
    task_fingerprint: str = "",
) -> Path:
    """One ``torch.save`` dict (tensors and builtins only: loads with ``weights_only=True``), written atomically;
    returns the path. ``tag``: :data:`FORMAT_TAG` or :data:`ENSEMBLE_FORMAT_TAG`; ``config``: what rebuilds the
    module's architecture."""
    path = Path(path)
    payload = {
        "format": tag,
        "version": FORMAT_VERSION,
        "task_name": task_name,
        "task_fingerprint": task_fingerprint,
        "config": config,
        "state_dict": {k: v.detach().clone() for k, v in module.state_dict().items()},
    }
    buffer = io.BytesIO()
    torch.save(payload, buffer)
    atomic_write_bytes(path, buffer.getvalue())
    return path


def read_value_file(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The dict a value-network or ensemble file holds (its ``"format"`` not checked here: the caller dispatches on
    it), read on the CPU with ``weights_only=True``.

    Raises:
        ValueNetworkFileError: ``path`` is a directory, does not exist, is unreadable or corrupt, or holds no dict;
            the message names the file and the problem.
    """
    path = Path(path)
    if path.is_dir():
        raise ValueNetworkFileError(f"{str(path)!r} is a directory, not a value network file")
    if not path.is_file():
        raise ValueNetworkFileError(f"value network file {str(path)!r} does not exist")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        raise ValueNetworkFileError(
            f"value network file {str(path)!r} is unreadable or corrupt ({type(exc).__name__}: {exc})"
        ) from exc
    if not isinstance(payload, dict):
        raise ValueNetworkFileError(f"{str(path)!r} is not a seagul value network file (no {FORMAT_TAG!r} tag)")
    return payload


def check_version(payload: dict[str, Any], path: Path) -> None:
    """Raise :class:`ValueNetworkFileError` unless the file's ``"version"`` is :data:`FORMAT_VERSION`."""
    if payload.get("version") != FORMAT_VERSION:
        raise ValueNetworkFileError(
            f"{str(path)!r} has value-network format version {payload.get('version')!r}; "
            f"this seagul reads version {FORMAT_VERSION}"
        )
