"""The final refit (``TrainConfig.refit``): a fresh network fitted to the whole buffer after the last round, and the
closed-loop selection of its members (``refit.candidates``, :class:`~seagul_learn.config.SelectionConfig`).

A network trained round by round carries the order its data came in; a fresh fit of everything at the end does not
(docs/experiments/closed-loop.md measures both). Refits of one buffer from different initial weights differ by tens
of points of closed-loop success, so the selection flies the deployed MPC on training starts (never an evaluation
set) and keeps the members that fly best. Everything here is deterministic, so an interrupted run resumed during
the refit or the selection ends with the same network.
"""

from __future__ import annotations

import json
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from seagul_control._io import atomic_write_text
from seagul_envs import Task
from seagul_learn.config import TrainConfig
from seagul_learn.dataset import TrainingArrays
from seagul_learn.fitting import STREAM_REFIT_BATCHES, Trainer, capped, make_network, rng
from seagul_learn.member_selection import select_members
from seagul_learn.value_network import ValueEnsemble, ValueModel, ValueNetwork


def refit(
    config: TrainConfig, task: Task, buffer: TrainingArrays, trainer: Trainer, round_index: int | None = None
) -> ValueModel:
    """Fit a fresh network to the whole buffer (``TrainConfig.refit.steps``); it replaces ``trainer.network``.

    The fresh network starts from the seed's initial weights with the buffer's standardisation (capped labels), so
    every label is in range from the first step; minibatches are uniform over the buffer (stream
    ``STREAM_REFIT_BATCHES``, and the round for the collecting refits of ``sampler.collect_refit``) and the learning
    rate decays along a cosine to 0. Deterministic, so a run interrupted during the refit and resumed ends with the
    same network.
    """
    network = make_network(config, task)
    network.set_normalization(
        buffer.x, buffer.tau, capped(buffer.value, config.loss.value_cap, config.loss.value_compress), buffer.theta
    )
    trainer.network = network
    trainer.optimizer = torch.optim.Adam(network.parameters(), lr=config.schedule.lr)
    trainer.train(
        buffer,
        np.zeros(0, dtype=np.int64),
        config.refit.steps,
        rng(config.seed, STREAM_REFIT_BATCHES, 0 if round_index is None else round_index + 1),
        count_steps=round_index is None,
        cosine=True,
    )
    return network


#: What shapes the final refit (the stored candidates of ``refit.candidates`` are reused only if equal), by the flat
#: names of :meth:`TrainConfig.flat_dict`, so the key stored beside candidates made by earlier versions still matches.
_REFIT_FIELDS = frozenset(
    {
        "task",
        "seed",
        "hidden",
        "lr",
        "batch_size",
        "sobolev_weight",
        "value_cap",
        "grad_label_max",
        "refit_steps",
        "ensemble_pessimism",
        "torch_threads",
        "model_params",
    }
)


def candidates_key(config: TrainConfig, buffer: TrainingArrays) -> dict[str, Any]:
    """What the candidates' refit of ``refit.candidates`` depends on (stored beside them; JSON-ready)."""
    refit = {k: v for k, v in config.flat_dict().items() if k in _REFIT_FIELDS}
    if config.loss.value_compress:  # newer than the flat names: in the key only when on, so older keys still match
        refit["value_compress"] = True
    key = {"candidates": config.refit.candidates, "knots": len(buffer), "refit": refit}
    return json.loads(json.dumps(key))


def refit_and_select(
    config: TrainConfig, task: Task, buffer: TrainingArrays, trainer: Trainer, out: Path
) -> ValueModel:
    """``refit.candidates``: refit that many members to the whole buffer (as :func:`refit`), save them as
    ``network_candidates.pt``, and return the ``refit.ensemble`` of them whose deployed MPC succeeds most often on
    ``selection.episodes`` training starts (:func:`seagul_learn.member_selection.select_members`; the scores go to
    ``network_selection.json``). Deterministic (the refit, the starts and the MPC are)."""
    # The candidates' refit is deterministic: a run interrupted during the selection reuses the stored one when it
    # was made with the same settings from the same buffer.
    key = candidates_key(config, buffer)
    stored, stored_key = out / "network_candidates.pt", out / "network_candidates.json"
    candidates: ValueModel | None = None
    if stored.is_file() and stored_key.is_file() and json.loads(stored_key.read_text()) == key:
        candidates = ValueNetwork.load(stored)
    if not isinstance(candidates, ValueEnsemble) or len(candidates.members) != config.refit.candidates:
        members = replace(config.network, ensemble=config.refit.candidates)
        candidates = refit(replace(config, network=members), task, buffer, trainer)
        if not isinstance(candidates, ValueEnsemble):
            raise TypeError("refit_candidates: the candidate refit must be an ensemble")
        candidates.save(stored)
        atomic_write_text(stored_key, json.dumps(key, indent=1) + "\n")
    select, closed_loop = config.selection, config.closed_loop_options()
    start = time.perf_counter()
    chosen = select_members(
        task,
        candidates,
        config.refit.ensemble,
        select.episodes,
        config.seed,
        finalists=select.finalists,
        final_episodes=select.final_episodes,
        horizon=closed_loop.horizon,
        trust_region=closed_loop.trust_region,
        jit=select.jit,
        progress=config.runtime.progress,
        slice_fraction=select.slice_fraction,
    )
    info = {**chosen.as_dict(), "wall_s": round(time.perf_counter() - start, 1), "candidates": config.refit.candidates}
    atomic_write_text(out / "network_selection.json", json.dumps(info, indent=1) + "\n")
    network = candidates.subset(chosen.members, pessimism=config.network.pessimism)
    trainer.network = network
    return network
