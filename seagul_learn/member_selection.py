"""The closed-loop selection of a final refit's members (``TrainConfig.refit.candidates``,
:class:`~seagul_learn.config.SelectionConfig`): every subset of the candidate networks drives the deployed MPC from
the same training starts, and the subset that succeeds most often is deployed.

Refits of one buffer from different initial weights differ by tens of points of closed-loop success
(docs/experiments/closed-loop.md), while their validation errors barely differ: the selection measures the metric
that matters, at no NLP solve, on training starts drawn from X0 (never an evaluation grid or held-out set).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from tqdm import tqdm

from seagul_control import evaluation
from seagul_control.evaluation import default_horizon, sample_grid_slice
from seagul_control.mpc import LimitedLookaheadMPC, MPCOptions
from seagul_envs import Task
from seagul_learn.value_network import ValueEnsemble

_STREAM_SELECT_STARTS = 16
_STREAM_SELECT_FINAL = 17
_STREAM_SELECT_SLICE = 18
_STREAM_SELECT_FINAL_SLICE = 19


@dataclass(frozen=True)
class MemberSelection:
    """Which members of a candidate ensemble the deployed MPC flies best with (:func:`select_members`)."""

    members: tuple[int, ...]
    """The chosen members' indices."""
    success: float
    """Their MPC's success rate on every selection episode it flew."""
    scores: dict[tuple[int, ...], float]
    """Success rate of every subset on the first ``episodes`` starts."""
    episodes: int
    """First-stage episodes per subset (training starts from X0, stream ``[seed, 16]``)."""
    finalists: dict[tuple[int, ...], float] = field(default_factory=dict)
    """Success rate of the second stage's subsets over all their episodes (empty without one)."""
    final_episodes: int = 0
    """Further episodes each finalist flew (stream ``[seed, 17]``)."""
    slice_fraction: float = 0.0
    """Share of each stage's starts drawn on the evaluation grid's slice of X0
    (:func:`seagul_control.evaluation.sample_grid_slice`)."""

    def as_dict(self) -> dict[str, Any]:
        """Plain dict (JSON)."""
        return {
            "members": list(self.members),
            "success": self.success,
            "episodes": self.episodes,
            "scores": {",".join(map(str, k)): v for k, v in self.scores.items()},
            "final_episodes": self.final_episodes,
            "finalists": {",".join(map(str, k)): v for k, v in self.finalists.items()},
            "slice_fraction": self.slice_fraction,
        }


def _selection_starts(task: Task, n: int, seed: int, stream: int, slice_stream: int, fraction: float) -> np.ndarray:
    """``n`` selection starts: ``round(fraction * n)`` on the grid's slice
    (:func:`seagul_control.evaluation.sample_grid_slice`, stream
    ``[seed, slice_stream]``), the rest uniform over X0 (stream ``[seed, stream]``)."""
    on_slice = round(float(fraction) * int(n))
    parts = [task.sample_x0(np.random.default_rng([int(seed), stream]), int(n) - on_slice)]
    if on_slice:
        parts.append(sample_grid_slice(task, on_slice, np.random.default_rng([int(seed), slice_stream])))
    return np.vstack(parts)


def select_members(
    task: Task,
    candidates: ValueEnsemble,
    size: int,
    episodes: int,
    seed: int,
    *,
    finalists: int = 0,
    final_episodes: int = 0,
    horizon: int | None = None,
    trust_region: Literal["lqr", "box", "none"] | None = None,
    jit: bool = True,
    progress: bool = False,
    slice_fraction: float = 0.0,
) -> MemberSelection:
    """The ``size`` members of ``candidates`` whose ensemble the deployed MPC flies best.

    Every subset drives a ``LimitedLookaheadMPC(task, subset, horizon, trust_region=...)`` (None: the task's deployed
    guard; one build, re-parameterised per subset) in closed loop from the same ``episodes`` training starts drawn
    uniformly from X0 (stream ``[seed, 16]``; never an evaluation grid or held-out set). With ``finalists``, the best
    ``finalists`` subsets then fly ``final_episodes`` more starts (stream ``[seed, 17]``) and are ranked on all their
    episodes: the first stage's scores of the top subsets differ by less than their binomial noise (~2 points at 100
    episodes). Ties go to the first subset in lexicographic order. Model selection on training episodes by the metric
    that matters, at no NLP solve: refits of one buffer differ by tens of points of closed-loop success
    (docs/experiments/closed-loop.md). ``slice_fraction`` of each stage's starts are drawn on the evaluation grid's
    slice of X0 instead (``seagul_control.evaluation.sample_grid_slice``, streams ``[seed, 18]`` and ``[seed, 19]``):
    the acrobot's grid starts at rest, a 2-D slice that uniform draws over the 4-D X0 rarely come near.
    """
    k = len(candidates.members)
    if not 2 <= int(size) <= k:
        raise ValueError(f"select_members: size must be in 2..{k} (the candidates' members), got {size}")
    if int(episodes) < 1 or int(finalists) < 0 or int(final_episodes) < 0:
        raise ValueError(
            f"select_members: episodes >= 1, finalists >= 0 and final_episodes >= 0 needed, got {episodes}, "
            f"{finalists}, {final_episodes}"
        )
    if not 0.0 <= float(slice_fraction) <= 1.0:
        raise ValueError(f"select_members: slice_fraction must be in [0, 1], got {slice_fraction}")
    if candidates.n_params:
        raise ValueError("select_members: candidates over robots are not supported (select on the nominal model)")
    subsets = list(itertools.combinations(range(k), int(size)))
    mpc: Any = None

    def wins(subset: tuple[int, ...], starts: np.ndarray) -> int:
        nonlocal mpc
        ensemble = candidates.subset(subset)
        if mpc is None:
            mpc = LimitedLookaheadMPC(
                task,
                ensemble,
                horizon or default_horizon(task),
                MPCOptions(jit=jit),
                trust_region=trust_region,
            )
        else:
            mpc.set_value_function(ensemble)
        # Looked up on the module, so that a replacement of seagul_control.evaluation.run_policy_episode is used.
        return sum(int(evaluation.run_policy_episode(task, mpc, x0)[0].success) for x0 in starts)

    first = _selection_starts(task, int(episodes), seed, _STREAM_SELECT_STARTS, _STREAM_SELECT_SLICE, slice_fraction)
    counts = {s: wins(s, first) for s in tqdm(subsets, desc="member selection", unit="subset", disable=not progress)}
    scores = {s: c / float(episodes) for s, c in counts.items()}
    ranked = sorted(subsets, key=lambda s: -counts[s])  # stable: ties keep lexicographic order
    final: dict[tuple[int, ...], float] = {}
    if finalists and final_episodes:
        more = _selection_starts(
            task, int(final_episodes), seed, _STREAM_SELECT_FINAL, _STREAM_SELECT_FINAL_SLICE, slice_fraction
        )
        total = int(episodes) + int(final_episodes)
        for s in ranked[: int(finalists)]:
            final[s] = (counts[s] + wins(s, more)) / float(total)
        best = max(ranked[: int(finalists)], key=lambda s: final[s])
        return MemberSelection(
            best, final[best], scores, int(episodes), final, int(final_episodes), float(slice_fraction)
        )
    best = ranked[0]
    return MemberSelection(best, scores[best], scores, int(episodes), slice_fraction=float(slice_fraction))
