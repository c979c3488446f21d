"""seagul_control: the one NLP builder (direct transcription), LQR, limited-lookahead MPC, closed-loop evaluation."""

from __future__ import annotations

import importlib
from typing import Any

# Public names, imported lazily so that `import seagul_control` builds nothing and stays cheap.
_LAZY: dict[str, str] = {
    "Transcription": "seagul_control.transcription",
    "TranscriptionSolution": "seagul_control.transcription",
    "LimitedLookaheadMPC": "seagul_control.mpc",
    "FullHorizonMPC": "seagul_control.mpc",
    "LQRPolicy": "seagul_control.lqr",
    "CasadiValueFunction": "seagul_control.value_function",
    "PolicySpec": "seagul_control.evaluation",
    "evaluate": "seagul_control.evaluation",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'seagul_control' has no attribute {name!r}")


__all__ = sorted(_LAZY)
