"""seagul_control: the one NLP builder (direct transcription), LQR, limited-lookahead MPC, closed-loop evaluation.

It sits on ``seagul_envs`` and never imports torch or ``seagul_learn`` (``tests/test_layers.py``): policy kinds that
need a learned artefact are named by module path (:func:`seagul_control.evaluation.register_policy_kind`) and built
by ``seagul_learn.policies``. Files are written through :mod:`seagul_control.io`.
"""

from __future__ import annotations

import importlib
from typing import Any

# Public names, imported lazily so that `import seagul_control` builds nothing and stays cheap.
_LAZY: dict[str, str] = {
    "Transcription": "seagul_control.transcription",
    "TranscriptionSolution": "seagul_control.transcription",
    "LimitedLookaheadMPC": "seagul_control.mpc",
    "FullHorizonMPC": "seagul_control.mpc",
    "MPCOptions": "seagul_control.mpc",
    "FullHorizonOptions": "seagul_control.mpc",
    "TranscriptionOptions": "seagul_control.transcription",
    "LQRPolicy": "seagul_control.lqr",
    "CasadiValueFunction": "seagul_control.value_function",
    "PolicySpec": "seagul_control.evaluation",
    "evaluate": "seagul_control.evaluation",
    "register_policy_kind": "seagul_control.evaluation",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'seagul_control' has no attribute {name!r}")


__all__ = sorted(_LAZY)
