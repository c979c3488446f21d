"""A training run's checkpoint (written atomically after every round) and the best collector kept by
``ClosedLoopOptions.keep_best``: what :func:`seagul_learn.training.train` resumes from."""

from __future__ import annotations

import io
import json
from dataclasses import asdict
from pathlib import Path
from typing import Any

import torch

from seagul_control._io import atomic_write_bytes, atomic_write_text
from seagul_learn.config import TrainConfig
from seagul_learn.fitting import Trainer
from seagul_learn.round_selection import collector_rate, save_round
from seagul_learn.samplers import Sampler
from seagul_learn.value_network import ValueModel

CHECKPOINT_FORMAT = "seagul-train-checkpoint"


def keep_best(out: Path, config: TrainConfig, log: list[dict[str, Any]], collecting: ValueModel, solves: int) -> None:
    """``sampler.keep_best``: save ``collecting`` as ``network_best.pt`` when the round just logged is the best deployed
    collector so far (ties: the later). The best so far is recomputed from the log (resume-safe: a redone round
    rewrites the same file). With ``selection.rounds`` every closed-loop round's collector is also kept
    (:func:`seagul_learn.round_selection.save_round`)."""
    deployed = config.closed_loop_options().trust_region or config.resolve_task().profile.mpc.trust_region

    def rate(entry: dict[str, Any]) -> float | None:
        if entry.get("collector") != deployed or not entry.get("episodes"):
            return None
        return collector_rate(entry)

    if not log or (now := rate(log[-1])) is None:
        return
    entry = log[-1]
    info: dict[str, Any] = {
        "round": int(entry["round"]),
        "episode_successes": int(entry["episode_successes"]),
        "episodes": int(entry["episodes"]),
        **{k: int(entry[k]) for k in ("replayed", "replayed_successes") if k in entry},
        "solves_before_round": int(solves),
        "note": "the network the round's collector flew (trained on the solves before the round)",
    }
    if config.selection.rounds:  # every round is a candidate of the final selection (seagul_learn.round_selection)
        save_round(out, collecting, info)
    earlier = [r for r in (rate(e) for e in log[:-1]) if r is not None]
    if earlier and now < max(earlier):
        return
    collecting.save(out / "network_best.pt")
    atomic_write_text(out / "network_best.json", json.dumps(info, indent=1) + "\n")


def save_checkpoint(path: Path, trainer: Trainer, rounds_done: int, sampler: Sampler, next_index: int) -> None:
    pool_position = sampler.pool.position
    payload: dict[str, Any] = {
        "format": CHECKPOINT_FORMAT,
        "rounds_done": rounds_done,
        "network": trainer.network.state_dict(),
        "optimizer": trainer.optimizer.state_dict(),
        "train_steps": trainer.train_steps,
        "metrics": [asdict(m) for m in trainer.metrics],
        "pool_position": pool_position,
        "next_index": next_index,
    }
    if hasattr(sampler, "state_dict"):
        payload["sampler_state"] = json.dumps(sampler.state_dict())
    buf = io.BytesIO()
    torch.save(payload, buf)
    atomic_write_bytes(path, buf.getvalue())


def load_checkpoint(path: Path) -> dict[str, Any]:
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        raise ValueError(f"checkpoint {str(path)!r} is unreadable or corrupt ({type(exc).__name__}: {exc})") from exc
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(f"{str(path)!r} is not a seagul training checkpoint")
    return state
