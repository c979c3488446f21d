"""The samplers' option classes: what ``TrainConfig.sampler`` holds (:class:`UniformOptions`,
:class:`AdversarialOptions`, :class:`ClosedLoopOptions`; their common base :class:`SamplerOptions`).

They are plain frozen dataclasses that depend on nothing but the standard library, so a configuration
(:mod:`seagul_learn.config`, the recipes, the command line's flags) is built, parsed and validated without importing
torch or the solver stack. The samplers that use them live with the code they drive: the uniform and adversarial
samplers in :mod:`seagul_learn.samplers`, the closed-loop sampler in :mod:`seagul_learn.closed_loop`, which import
these classes under the same names (``from seagul_learn.samplers import UniformOptions`` and
``from seagul_learn.closed_loop import ClosedLoopOptions`` give the classes defined here).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal

from seagul_learn.config_parts import omitted

Selection = Literal["farthest", "spread", "lowest", "random"]
"""How the closed-loop sampler chooses a round's queries among the collected ones (:attr:`ClosedLoopOptions.selection`;
:mod:`seagul_learn.closed_loop` describes each)."""
SELECTIONS = ("farthest", "spread", "lowest", "random")
"""The values of :data:`Selection`, in order."""

__all__ = ["SELECTIONS", "AdversarialOptions", "ClosedLoopOptions", "SamplerOptions", "Selection", "UniformOptions"]


class SamplerOptions:
    """Base of the samplers' option classes (:class:`UniformOptions`, :class:`AdversarialOptions`,
    :class:`ClosedLoopOptions`): ``TrainConfig.sampler`` holds one of them, and the class
    chosen is the sampler. ``name`` is the sampler's name (``"uniform"``, ``"adversarial"``, ``"closed-loop"``),
    which an instance also compares equal to, so ``config.sampler == "closed-loop"`` reads as it did when the field
    was that string."""

    name: ClassVar[str] = ""

    def __eq__(self, other: object) -> bool:
        if isinstance(other, str):
            return self.name == other
        if type(other) is not type(self):
            return NotImplemented
        return dataclasses.astuple(self) == dataclasses.astuple(other)  # type: ignore[call-overload]

    def __hash__(self) -> int:
        return hash((self.name, dataclasses.astuple(self)))  # type: ignore[call-overload]

    def to_dict(self) -> dict[str, Any]:
        """The options as JSON-ready data with the sampler's name under ``"name"`` (``TrainConfig.to_dict``). A field
        marked ``metadata={"omit_default": True}`` is written only when it differs from its default, so the recorded
        settings of runs made before it existed stay as they were."""
        out: dict[str, Any] = {"name": self.name}
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            if omitted(self, f.name):
                continue
            value = getattr(self, f.name)
            out[f.name] = list(value) if isinstance(value, tuple) else value
        return out


@dataclass(frozen=True, eq=False)
class UniformOptions(SamplerOptions):
    """The uniform baseline (:class:`~seagul_learn.samplers.UniformSampler`): the seed's uniform starts in order;
    nothing to set."""

    name: ClassVar[str] = "uniform"


@dataclass(frozen=True, eq=False)
class AdversarialOptions(SamplerOptions):
    """Settings of the adversarial sampler, paper Alg. 1 (:class:`~seagul_learn.samplers.AdversarialSampler`; the
    exact rules are in the docstring of :mod:`seagul_learn.samplers`)."""

    name: ClassVar[str] = "adversarial"

    max_steps: int = 5
    """Solves per chain at most (the start counts as one)."""
    step_fraction: float = 0.1
    """Largest move per ascent step, as a fraction of the X0 (T0) box width (Adam: its learning rate)."""
    eps: float = 1e-3
    """Stop a chain when the projected step is below this (max-norm, in box widths)."""
    optimizer: Literal["pga", "adam"] = "pga"
    """Normalised projected gradient ascent (paper) or Adam on the box-normalised start."""
    projection: Literal["clip", "reflect"] = "clip"
    """How an iterate leaving X0 is brought back."""
    uniform_fraction: float = 0.0
    """Share of each round's solves spent on plain uniform draws (0 = pure Alg. 1)."""
    ascend_tau: bool = True
    """Also ascend in ``tau`` when T0 is an interval."""
    ascend_theta: bool = True
    """In a pool over robots, also ascend in the robot's parameters inside Theta (False: each chain keeps its
    start's robot)."""
    adam_betas: tuple[float, float] = field(default=(0.9, 0.999))
    """Adam's moment decay rates (``optimizer="adam"``)."""
    stop_on_decrease: bool = False
    """End a chain when its new iterate's loss is below the previous one's (the ascent overshot)."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "adam_betas", tuple(float(b) for b in self.adam_betas))
        if self.max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {self.max_steps}")
        if not self.step_fraction > 0:
            raise ValueError(f"step_fraction must be > 0, got {self.step_fraction}")
        if self.eps < 0:
            raise ValueError(f"eps must be >= 0, got {self.eps}")
        if self.optimizer not in ("pga", "adam"):
            raise ValueError(f"optimizer must be 'pga' or 'adam', got {self.optimizer!r}")
        if self.projection not in ("clip", "reflect"):
            raise ValueError(f"projection must be 'clip' or 'reflect', got {self.projection!r}")
        if not 0.0 <= self.uniform_fraction <= 1.0:
            raise ValueError(f"uniform_fraction must be in [0, 1], got {self.uniform_fraction}")


@dataclass(frozen=True, eq=False)
class ClosedLoopOptions(SamplerOptions):
    """Settings of :class:`~seagul_learn.closed_loop.ClosedLoopSampler` (described in :mod:`seagul_learn.closed_loop`),
    and of what the training loop does around it (``collect_refit``, ``keep_best``):
    ``TrainConfig(sampler=ClosedLoopOptions(...))`` chooses the sampler."""

    name: ClassVar[str] = "closed-loop"

    episodes: int = 20
    """Closed-loop episodes per round (training starts from X0 at the nominal time to go, never the evaluation
    grid)."""
    horizon: int | None = None
    """Lookahead steps of the collecting MPC (None: the task's default, as deployed)."""
    trust_region: Literal["lqr", "box", "none"] | None = None
    """Guard of the collecting (= deployed) MPC after the warm-up rounds; None = the task's deployed default
    (``profile.mpc.trust_region``, as ``LimitedLookaheadMPC`` resolves it)."""
    warmup_rounds: int = 1
    """Rounds at the start that collect with the ``"lqr"``-guarded MPC instead."""
    selection: Selection = "farthest"
    """How the round's queries are chosen among the collected ones."""
    tail_stride: int = 5
    """Only queries whose tail has a multiple of this many intervals (fixed-step tasks; acrobot: 5 = every 0.5 s,
    so 9 tail solvers are built, ~12 s of compilation each on first use, instead of 45 with 1)."""
    uniform_fraction: float = 0.0
    """Share of each round's solves spent on uniform draws from X0 (the baseline's starts)."""
    uniform_solves: int = 0
    """Budget solves spent on uniform draws before the first closed-loop round (a network that has seen only the
    pretraining solves plans into states with values of 1e4 and more, which teach nothing)."""
    jit: bool = True
    """Compile the collecting MPC (as deployed); False solves it interpreted (tests)."""
    solver: str = "ipopt"
    """Solver of the collecting MPC: the same NLP as deployed, solved by IPOPT with a wall-time limit per step
    (``max_step_time``). The deployed default, fatrop, looped without end inside single solves from shifted warm
    starts at the extreme states closed-loop training visits (docs/experiments/closed-loop.md); ``"fatrop"`` collects
    with it anyway."""
    max_step_time: float = 5.0
    """IPOPT wall-time limit per collecting MPC step (s); a step that hits it falls back like any failed solve."""
    visited_fraction: float = 0.0
    """Share of each round's tail solves started from the states the collecting episodes *visited* ``(x_t, tau_t)``
    instead of the planned terminal states (DAgger's labels: the optimal continuation from where the learned
    controller actually went, whose first knots are the terminal states the planner should have chosen). States of
    episodes that failed come first; fixed-step tasks only."""
    replay_failed: float = field(default=0.0, metadata={"omit_default": True})
    """Over robots: share of each round's episodes flown on robots whose collector episodes failed in earlier rounds
    (each with a fresh start), the rest on new robots uniform over Theta. A replayed robot that perches leaves the
    replay pool; one that fails again stays. Uniform draws put few episodes in Theta's hard corners (the glider: heavy
    with little wing), where a round's failures are; replaying them puts the round's queries and tails there
    (prioritised level replay's idea, over robots). The collector's success rate that ranks rounds
    (``keep_best``, ``selection.rounds``) counts the new robots' episodes only."""
    slice_fraction: float = 0.0
    """Share of each round's episode starts drawn on the evaluation grid's slice of X0
    (:func:`seagul_control.evaluation.sample_grid_slice`: the acrobot at rest), random draws, never the grid's points.
    Uniform draws over the 4-D X0 almost never start at rest, where the grid's starts are. 0: every start uniform
    over X0 (exactly the uniform stream's draws)."""

    collect_refit: bool = False
    """Training loop: each round after the ``"lqr"`` warm-up rounds collects with a refit of the buffer so far
    (``TrainConfig.refit.steps`` Adam steps, as the final refit: the network that would be deployed if training
    stopped there) instead of the loop's network, so the queries are the deployed controller's (DAgger). Costs one
    refit per such round; the loop's own training is unchanged. Needs ``refit.steps > 0``."""
    keep_best: bool = False
    """Training loop: deploy the collector that flew best. Each round's collecting MPC runs ``episodes`` episodes
    from new X0 starts (never the evaluation's) with the network of the round before; the network of the round whose
    deployed collector (guard ``trust_region``) succeeded most often (ties: the later, trained on more data) is kept
    as ``network_best.pt`` (with ``network_best.json``: its round, successes, solves) and becomes ``network.pt``, the
    loop's last network ``network_last.pt``; snapshots are the best so far. Model selection on training episodes:
    round-to-round closed-loop success swings widely (glider: 4 to 19 of 20 over 60 rounds of one seed,
    docs/experiments/closed-loop.md). Needs ``refit.steps = 0``."""

    def __post_init__(self) -> None:
        if self.episodes < 1:
            raise ValueError(f"closed-loop episodes must be >= 1, got {self.episodes}")
        if self.horizon is not None and self.horizon < 1:
            raise ValueError(f"closed-loop horizon must be >= 1 step, got {self.horizon}")
        if self.trust_region not in ("lqr", "box", "none", None):
            raise ValueError(f"closed-loop trust_region must be 'lqr', 'box' or 'none', got {self.trust_region!r}")
        if self.warmup_rounds < 0:
            raise ValueError(f"closed-loop warmup_rounds must be >= 0, got {self.warmup_rounds}")
        if self.selection not in SELECTIONS:
            raise ValueError(f"closed-loop selection must be one of {list(SELECTIONS)}, got {self.selection!r}")
        if self.tail_stride < 1:
            raise ValueError(f"closed-loop tail_stride must be >= 1, got {self.tail_stride}")
        if not 0.0 <= self.uniform_fraction <= 1.0:
            raise ValueError(f"closed-loop uniform_fraction must be in [0, 1], got {self.uniform_fraction}")
        if self.solver not in ("ipopt", "fatrop"):
            raise ValueError(f"closed-loop solver must be 'ipopt' or 'fatrop', got {self.solver!r}")
        if not self.max_step_time > 0:
            raise ValueError(f"closed-loop max_step_time must be > 0 s, got {self.max_step_time}")
        if self.uniform_solves < 0:
            raise ValueError(f"closed-loop uniform_solves must be >= 0, got {self.uniform_solves}")
        if not 0.0 <= self.visited_fraction <= 1.0:
            raise ValueError(f"closed-loop visited_fraction must be in [0, 1], got {self.visited_fraction}")
        if not 0.0 <= self.slice_fraction <= 1.0:
            raise ValueError(f"closed-loop slice_fraction must be in [0, 1], got {self.slice_fraction}")
        if not 0.0 <= self.replay_failed < 1.0:
            raise ValueError(f"closed-loop replay_failed must be in [0, 1), got {self.replay_failed}")
