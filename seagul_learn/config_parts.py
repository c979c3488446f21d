"""The parts of a :class:`~seagul_learn.config.TrainConfig`: one frozen dataclass per concern, each validated when it
is made, with errors that name the field by its place (``loss.sobolev_weight must be >= 0``)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar, Literal


def omitted(part: Any, name: str) -> bool:
    """Whether field ``name`` of a settings dataclass is left out of the written settings: it is marked
    ``metadata={"omit_default": True}`` and at its default, so a field added later leaves the recorded settings of runs
    that did not use it as they were (``TrainConfig.to_dict``, ``SamplerOptions.to_dict``)."""
    f = next(f for f in fields(part) if f.name == name)
    return bool(f.metadata.get("omit_default")) and getattr(part, name) == f.default


def _check(ok: bool, message: str) -> None:
    if not ok:
        raise ValueError(message)


def _finite_nonneg(value: float) -> bool:
    return value >= 0 and math.isfinite(value)


@dataclass(frozen=True)
class NetworkConfig:
    """The value function's architecture."""

    hidden: tuple[int, ...] = (32,)
    """Hidden-layer widths of the tanh network (paper: one layer of 32)."""
    ensemble: int = 1
    """Networks fitted to the same data (1 = a single network; >= 2 a :class:`~seagul_learn.value_network.
    ValueEnsemble`, whose CasADi form is pessimistic where the members disagree)."""
    pessimism: float = 1.0
    """Weight ``beta`` of the members' spread in an ensemble's CasADi form (``mean + beta * spread``)."""
    robot_invariants: bool = field(default=False, metadata={"omit_default": True})
    """A value over robots (``model_params``) fed the logarithms of the products of parameters the task's dynamics
    depend on (:attr:`~seagul_envs.tasks.parameters.ParameterSpace.invariants`) instead of ``theta``: robots that move
    identically get one value. Needs a task that declares invariants."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "hidden", tuple(int(h) for h in self.hidden))
        _check(
            bool(self.hidden) and all(h >= 1 for h in self.hidden),
            f"network.hidden must be positive layer widths, got {self.hidden}",
        )
        _check(self.ensemble >= 1, f"network.ensemble must be >= 1 network, got {self.ensemble}")
        _check(_finite_nonneg(self.pessimism), f"network.pessimism must be a number >= 0, got {self.pessimism}")


@dataclass(frozen=True)
class ScheduleConfig:
    """Pretraining, rounds and the optimiser (paper Alg. 2 and §6; module docstring of :mod:`seagul_learn.training`)."""

    solves_per_round: int = 10
    """New solves between two training phases (paper: 10)."""
    train_steps_per_round: int = 500
    """Adam steps after each round of solves (paper: 500)."""
    batch_size: int = 128
    """Knot samples per minibatch."""
    newest_fraction: float = 0.5
    """Share of each minibatch drawn from the knots added in the current round (paper §5)."""
    lr: float = 1e-3
    """Adam learning rate."""
    pretrain_solves: int = 10
    """Uniform solves of the shared pretraining set (also the standardisation statistics; not part of ``budget``)."""
    pretrain_steps: int = 100
    """Adam steps on the pretraining set."""
    eval_every: int = 0
    """Also evaluate every this many training steps inside rounds (0 = after each round only)."""

    def __post_init__(self) -> None:
        for name in ("solves_per_round", "batch_size", "pretrain_solves"):
            _check(int(getattr(self, name)) >= 1, f"schedule.{name} must be >= 1, got {getattr(self, name)}")
        for name in ("train_steps_per_round", "pretrain_steps", "eval_every"):
            _check(int(getattr(self, name)) >= 0, f"schedule.{name} must be >= 0, got {getattr(self, name)}")
        _check(
            0.0 <= self.newest_fraction <= 1.0,
            f"schedule.newest_fraction must be in [0, 1], got {self.newest_fraction}",
        )
        _check(self.lr > 0 and math.isfinite(self.lr), f"schedule.lr must be a positive number, got {self.lr}")


@dataclass(frozen=True)
class LossConfig:
    """The regression's loss and labels (module docstring of :mod:`seagul_learn.training`)."""

    sobolev_weight: float = 0.0
    """Weight ``w`` of the gradient-matching (Sobolev) term; 0 = plain MSE."""
    value_cap: float = 0.0
    """Labels above this value are clipped to it and their gradient labels dropped (0 = off): a tail problem from a
    far-off query can cost 1e4 and would otherwise swamp the loss; the clipped label still says "expensive"."""
    value_compress: bool = field(default=False, metadata={"omit_default": True})
    """With ``value_cap``: labels above the cap are compressed, ``cap * (1 + ln(V / cap))``, with their gradient
    labels scaled by ``cap / V`` (the compression's derivative), instead of clipped with their gradients dropped. The
    labels keep their order, so a planner whose reachable terminal states all cost more than the cap still sees which
    is least bad (the glider's heavy, little-winged robots, where most tail labels lie above the cap)."""
    grad_label_max: float = 0.0
    """Drop gradient labels whose standardised norm ``|dV/dx * in_std / out_std|`` exceeds this (0 = keep all):
    near-singular tails carry dual gradients orders of magnitude above the rest that would dominate the Sobolev term;
    their value labels stay."""
    renormalize: bool = False
    """Re-fit the standardisation to the whole buffer (labels capped at ``value_cap``, as the loss sees them) after
    each round's solves, rescaling the first and last layers so the network's function is unchanged (PopArt). Without
    it the statistics of the pretraining solves stay, and closed-loop tail labels land tens of standard deviations
    out."""

    def __post_init__(self) -> None:
        _check(_finite_nonneg(self.sobolev_weight), f"loss.sobolev_weight must be >= 0, got {self.sobolev_weight}")
        _check(_finite_nonneg(self.value_cap), f"loss.value_cap must be a number >= 0 (0 = off), got {self.value_cap}")
        _check(
            _finite_nonneg(self.grad_label_max),
            f"loss.grad_label_max must be a number >= 0 (0 = off), got {self.grad_label_max}",
        )


@dataclass(frozen=True)
class RefitConfig:
    """The final refit: a fresh network fitted to the whole buffer after the last round (docs/experiments/
    closed-loop.md)."""

    steps: int = 0
    """Adam steps of the refit (the seed's initial weights, uniform minibatches, cosine learning-rate decay, the
    buffer's standardisation); it becomes ``network.pt`` and the loop's network is kept as ``network_loop.pt``
    (0 = off)."""
    ensemble: int = 0
    """Members of the refit (0 or 1: one network; >= 2: a :class:`~seagul_learn.value_network.ValueEnsemble` of that
    many fits from their own initial weights, with ``network.pessimism``). The members' errors are partly
    independent, so the planner finds fewer under-estimates in their mean; the loop's and the collecting refits'
    networks stay single unless ``network.ensemble`` is set."""
    candidates: int = 0
    """Fit this many members (``> ensemble``) and deploy the ``ensemble`` of them whose MPC succeeds most often in
    closed loop from training starts (:class:`SelectionConfig`): refits of one buffer differ by tens of points of
    closed-loop success. Kept as ``network_candidates.pt``, the scores in ``network_selection.json`` (0 = off)."""

    def __post_init__(self) -> None:
        _check(self.steps >= 0, f"refit.steps must be >= 0, got {self.steps}")
        _check(
            self.ensemble >= 0 and (self.ensemble < 2 or self.steps > 0),
            f"refit.ensemble must be >= 0 and needs refit.steps > 0, got {self.ensemble}",
        )
        _check(
            not self.candidates or (self.ensemble >= 2 and self.candidates > self.ensemble),
            "refit.candidates must exceed refit.ensemble (>= 2) or be 0, got "
            f"{self.candidates} candidates for {self.ensemble} members",
        )
        _check(
            not self.candidates or math.comb(self.candidates, self.ensemble) <= 252,
            f"refit.candidates: C({self.candidates}, {self.ensemble}) subsets is too many to try (at most 252)",
        )


@dataclass(frozen=True)
class SelectionConfig:
    """How the members of ``refit.candidates`` are chosen, or (``rounds``) which closed-loop round's network is
    deployed: closed-loop episodes of the deployed MPC (horizon and guard of the closed-loop options) from training
    starts drawn from X0 (on robots from Theta over robots), never an evaluation set."""

    episodes: int = 100
    """Closed-loop episodes per candidate subset."""
    finalists: int = 0
    """Second stage: the best this many subsets fly ``final_episodes`` more starts and are ranked on all their
    episodes (0 = one stage)."""
    final_episodes: int = 0
    """Episodes of the second stage per finalist."""
    slice_fraction: float = 0.0
    """Share of the starts (both stages) drawn on the evaluation grid's slice of X0 instead of over all of X0
    (``seagul_control.evaluation.sample_grid_slice``: the acrobot's grid starts at rest); random draws, never the
    grid's points."""
    jit: bool = True
    """Compile the selection's MPC (False: interpreted, for tests)."""
    rounds: int = field(default=0, metadata={"omit_default": True})
    """With ``sampler.keep_best``: keep every closed-loop round's collecting network, and at the end let the
    ``rounds`` networks whose collectors succeeded most often fly ``episodes`` selection episodes (the best
    ``finalists`` then ``final_episodes`` more); the one with the most successes is deployed
    (:mod:`seagul_learn.round_selection`). 0: deploy the round whose collector flew best."""

    def __post_init__(self) -> None:
        _check(self.rounds >= 0, f"selection.rounds must be >= 0, got {self.rounds}")
        _check(self.episodes >= 1, f"selection.episodes must be >= 1, got {self.episodes}")
        _check(self.finalists >= 0, f"selection.finalists must be >= 0, got {self.finalists}")
        _check(self.final_episodes >= 0, f"selection.final_episodes must be >= 0, got {self.final_episodes}")
        _check(
            0.0 <= self.slice_fraction <= 1.0, f"selection.slice_fraction must be in [0, 1], got {self.slice_fraction}"
        )


@dataclass(frozen=True)
class RuntimeConfig:
    """How the run is executed. Only ``torch_threads`` can change the results; the other fields may differ between an
    interrupted run and its resumption."""

    workers: int = 1
    """Parallel solver processes (results do not depend on it)."""
    backend: Literal["local", "ray"] = "local"
    """``"local"`` (joblib processes) or ``"ray"``."""
    cache_dir: str | None = None
    """Where solved validation sets are cached (default ``$SEAGUL_CACHE_DIR`` or ``~/.cache/seagul``)."""
    progress: bool = True
    """Show progress bars."""
    snapshots: tuple[int, ...] = ()
    """Budgets (solves) after whose round ``network_<solves>.pt`` is saved (success-per-solve curves from one run)."""
    torch_threads: int = 1
    """Torch intra-op threads during training (fixed so results never depend on the machine's core count)."""

    RESUMABLE: ClassVar[tuple[str, ...]] = ("workers", "backend", "cache_dir", "progress", "snapshots")
    """Fields that may change between an interrupted run and its resumption."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "snapshots", tuple(sorted({int(b) for b in self.snapshots})))
        _check(self.workers >= 1, f"runtime.workers must be >= 1, got {self.workers}")
        _check(self.torch_threads >= 1, f"runtime.torch_threads must be >= 1, got {self.torch_threads}")
        _check(self.backend in ("local", "ray"), f"unknown runtime.backend {self.backend!r}; choose 'local' or 'ray'")
        _check(
            all(b >= 1 for b in self.snapshots), f"runtime.snapshots must be budgets >= 1, got {list(self.snapshots)}"
        )


#: The parts of a TrainConfig: field name -> class (``sampler`` is one of :data:`SAMPLER_OPTIONS`).
SECTIONS: dict[str, type] = {
    "network": NetworkConfig,
    "schedule": ScheduleConfig,
    "loss": LossConfig,
    "refit": RefitConfig,
    "selection": SelectionConfig,
    "runtime": RuntimeConfig,
}
