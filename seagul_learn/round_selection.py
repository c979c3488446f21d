"""Which closed-loop round's network to deploy (``SelectionConfig.rounds`` with ``ClosedLoopOptions.keep_best``).

``keep_best`` deploys the network whose round's collector perched most often, a choice made on that round's 20
episodes, each on its own start (and robot). Over robots those counts are noisy: on the glider one seed's networks of
neighbouring rounds perched from 70 % to 83 % of the same 60 validation starts x robots, and the round its collector
flew best (19 of 20) was a 72 % one (docs/experiments/robust.md). The selection here keeps every closed-loop
round's collecting network (``rounds/network_<solves>.pt`` with its collector's record), and at the end of training
the ``rounds`` networks whose collectors succeeded most often fly the same ``episodes`` selection episodes; the best
``finalists`` fly ``final_episodes`` more, and the network with the most successes over all its episodes is
deployed. Every selection episode is a training start from X0 (on its own robot from Theta when the run is over
robots), drawn from the run's own streams, never an evaluation or validation set, and costs no NLP solve.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from seagul_control import evaluation
from seagul_control._io import atomic_write_text
from seagul_control.evaluation import default_horizon
from seagul_control.mpc import LimitedLookaheadMPC, MPCOptions
from seagul_envs import Task
from seagul_learn.value_network import ValueNetwork

_STREAM_ROUND_STARTS = 21
_STREAM_ROUND_ROBOTS = 22
_STREAM_ROUND_FINAL_STARTS = 23
_STREAM_ROUND_FINAL_ROBOTS = 24

ROUNDS_DIR = "rounds"
"""Where a run keeps each closed-loop round's collecting network (``network_<solves>.pt`` and ``.json``)."""


def save_round(out: Path, network: Any, record: dict[str, Any]) -> Path:
    """Keep one closed-loop round's collecting network and its collector's record (``round``,
    ``episode_successes``, ``episodes``, ``solves_before_round``) under ``out/rounds`` (a redone round rewrites the
    same files)."""
    folder = Path(out) / ROUNDS_DIR
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"network_{int(record['solves_before_round'])}.pt"
    network.save(path)
    atomic_write_text(path.with_suffix(".json"), json.dumps(record, indent=1) + "\n")
    return path


def collector_rate(record: dict[str, Any]) -> float | None:
    """A round's collector success rate over the episodes on new robots: a log entry's or kept round's
    ``episode_successes / episodes`` less its ``replayed`` episodes and their ``replayed_successes``
    (``ClosedLoopOptions.replay_failed``: robots that failed before, which would rank rounds by how many hard robots
    they drew). None when the round flew no new episode."""
    episodes = int(record["episodes"]) - int(record.get("replayed", 0))
    if episodes <= 0:
        return None
    return float(int(record["episode_successes"]) - int(record.get("replayed_successes", 0))) / float(episodes)


def kept_rounds(out: Path) -> list[tuple[Path, dict[str, Any]]]:
    """The rounds ``save_round`` kept, in training order: ``(network file, collector record)``."""
    folder = Path(out) / ROUNDS_DIR
    rows = []
    for meta in folder.glob("network_*.json"):
        path = meta.with_suffix(".pt")
        if path.is_file():
            rows.append((path, json.loads(meta.read_text())))
    return sorted(rows, key=lambda r: int(r[1]["solves_before_round"]))


@dataclass(frozen=True)
class RoundSelection:
    """The outcome of :func:`select_round` (written as ``network_best.json``)."""

    round: int
    """The deployed network's round (the collector that flew it)."""
    solves_before_round: int
    """The solves it was trained on."""
    episode_successes: int
    """Its collector's successes in that round."""
    episodes: int
    """Its collector's episodes in that round."""
    selection_success: float
    """Its success rate over all its selection episodes."""
    selection_episodes: int
    """How many selection episodes it flew."""
    candidates: dict[str, float] = field(default_factory=dict)
    """First-stage success rate of every candidate, keyed by ``solves_before_round``."""
    finalists: dict[str, float] = field(default_factory=dict)
    """Success rate of every finalist over both stages."""
    note: str = (
        "the network the round's collector flew (trained on the solves before the round), chosen among the rounds "
        "whose collectors flew best by selection episodes (SelectionConfig.rounds)"
    )


def _draws(task: Task, n: int, seed: int, streams: tuple[int, int], robots: bool) -> tuple[np.ndarray, Any]:
    starts = task.sample_x0(np.random.default_rng([int(seed), streams[0]]), int(n))
    if not robots:
        return starts, [None] * int(n)
    assert task.parameters is not None
    thetas = task.parameters.sample(np.random.default_rng([int(seed), streams[1]]), int(n)).reshape(int(n), -1)
    return starts, list(thetas)


def select_round(
    task: Task,
    out: Path,
    *,
    rounds: int,
    episodes: int,
    finalists: int,
    final_episodes: int,
    seed: int,
    over_robots: bool,
    trust_region: str,
    horizon: int | None = None,
    jit: bool = True,
    progress: bool = False,
) -> RoundSelection:
    """Fly the ``rounds`` best-collecting kept networks of ``out`` (ties: the later round) and return the winner.

    The MPC is the deployed one: ``LimitedLookaheadMPC(task, network, horizon, MPCOptions(jit=jit),
    trust_region=trust_region, model_params=over_robots, estimate_robot=over_robots)`` (its default solver, built
    once and re-parameterised per candidate). Stage one:
    ``episodes`` starts (streams ``[seed, 21]`` and, over robots, ``[seed, 22]``); stage two: the best
    ``finalists`` fly ``final_episodes`` more (streams ``[seed, 23]``, ``[seed, 24]``) and are ranked on all their
    episodes; ties go to the later round.
    """
    if int(rounds) < 1 or int(episodes) < 1 or int(finalists) < 0 or int(final_episodes) < 0:
        raise ValueError(
            f"select_round: rounds >= 1, episodes >= 1, finalists >= 0 and final_episodes >= 0 needed, got "
            f"{rounds}, {episodes}, {finalists}, {final_episodes}"
        )
    kept = kept_rounds(out)
    if not kept:
        raise ValueError(f"select_round: {Path(out) / ROUNDS_DIR} holds no kept round (train with selection.rounds)")

    def rate(rec: dict[str, Any]) -> float:
        return collector_rate(rec) or 0.0

    order = sorted(range(len(kept)), key=lambda i: (rate(kept[i][1]), i), reverse=True)[: int(rounds)]
    mpc: Any = None

    def wins(i: int, draws: tuple[np.ndarray, Any]) -> int:
        nonlocal mpc
        network = ValueNetwork.load(kept[i][0])
        if mpc is None:
            mpc = LimitedLookaheadMPC(
                task,
                network,
                horizon or default_horizon(task),
                MPCOptions(jit=jit),
                trust_region=trust_region,  # type: ignore[arg-type]
                model_params=over_robots,
                estimate_robot=over_robots,
            )
        else:
            mpc.set_value_function(network)
        # Looked up on the module, so that a replacement of seagul_control.evaluation.run_policy_episode is used.
        return sum(
            int(evaluation.run_policy_episode(task, mpc, x0, robot=robot)[0].success)
            for x0, robot in zip(*draws, strict=True)
        )

    first = _draws(task, episodes, seed, (_STREAM_ROUND_STARTS, _STREAM_ROUND_ROBOTS), over_robots)
    bar = tqdm(order, desc="round selection", unit="network", disable=not progress)
    counts = {i: wins(i, first) for i in bar}
    ranked = sorted(order, key=lambda i: (counts[i], i), reverse=True)
    total = {i: (counts[i], int(episodes)) for i in order}
    final: dict[str, float] = {}
    if finalists and final_episodes:
        more = _draws(task, final_episodes, seed, (_STREAM_ROUND_FINAL_STARTS, _STREAM_ROUND_FINAL_ROBOTS), over_robots)
        for i in ranked[: int(finalists)]:
            total[i] = (counts[i] + wins(i, more), int(episodes) + int(final_episodes))
            final[str(kept[i][1]["solves_before_round"])] = total[i][0] / total[i][1]
        ranked = sorted(ranked[: int(finalists)], key=lambda i: (total[i][0], i), reverse=True)
    best = ranked[0]
    rec = kept[best][1]
    return RoundSelection(
        round=int(rec["round"]),
        solves_before_round=int(rec["solves_before_round"]),
        episode_successes=int(rec["episode_successes"]),
        episodes=int(rec["episodes"]),
        selection_success=total[best][0] / total[best][1],
        selection_episodes=total[best][1],
        candidates={str(kept[i][1]["solves_before_round"]): counts[i] / float(episodes) for i in order},
        finalists=final,
    )


def deploy_selected(out: Path, selection: RoundSelection) -> Path:
    """Copy the selected round's network to ``out/network_best.pt`` and write ``network_best.json``."""
    source = Path(out) / ROUNDS_DIR / f"network_{selection.solves_before_round}.pt"
    target = Path(out) / "network_best.pt"
    shutil.copyfile(source, target)
    atomic_write_text(Path(out) / "network_best.json", json.dumps(asdict(selection), indent=1) + "\n")
    return target


def select_kept_round(config: Any, task: Task, out: Path) -> RoundSelection:
    """:func:`select_round` with a :class:`~seagul_learn.config.TrainConfig`'s settings: its ``selection`` part, the
    closed-loop options' horizon and deployed guard, its seed, and robots when ``model_params``."""
    options = config.closed_loop_options()
    sel = config.selection
    return select_round(
        task,
        out,
        rounds=sel.rounds,
        episodes=sel.episodes,
        finalists=sel.finalists,
        final_episodes=sel.final_episodes,
        seed=config.seed,
        over_robots=bool(config.model_params),
        trust_region=options.trust_region or task.profile.mpc.trust_region,
        horizon=options.horizon,
        jit=sel.jit,
        progress=config.runtime.progress,
    )
