"""SEAGuL training (paper Alg. 2) for both samplers, with validation, metrics, plots and exact resume.

One run, for a :class:`TrainConfig`:

1. **Validation set** (docs/reference/spec.md §3.6/§4.6): the task's ``task.profile.validation_spec(task)``, solved once
   and cached under ``cache_dir`` keyed by the task's fingerprint and the solver settings: acrobot a 10 x 10 grid over
   ``(th1, th2)`` at zero velocity plus 100 uniform draws from X0; glider a 6 x 6 x 6 grid over ``(x, z, dx)`` (other
   states 0) plus 250 uniform draws; a new task by default a 10 x 10 grid over two coordinates plus 100 draws; all at
   the nominal ``tau``. The random part uses a fixed seed, so every training seed is validated on the same set.
2. **Pretraining** (paper §6): ``pretrain_solves`` uniform solves (a stream that depends only on the seed) set the
   network's standardisation (all their knots) and train it for ``pretrain_steps`` steps. The result depends on
   neither the sampler nor the Sobolev weight, so every variant of a seed starts from IDENTICAL parameters. The
   pretraining solves stay in the buffer of every variant and are not counted in ``budget``.
3. **Rounds**: each round the sampler spends ``min(solves_per_round, budget left)`` solves (the uniform baseline's
   starts for this seed; adversarial chains start from a random subset of them), every knot of each successful
   solve joins the buffer, then ``train_steps_per_round`` Adam steps follow. Failed solves are stored, counted and
   never trained on.

**Minibatches favour the newest samples** (paper §5): each minibatch of ``batch_size`` draws
``round(newest_fraction * batch_size)`` samples uniformly from the knots added this round and the rest uniformly from
the whole buffer (with replacement), so a newest sample is drawn ``1 + f / (1 - f) * buffer / new`` times as often
as an older one (``f = newest_fraction``; with the defaults and 10 solves per round, ~2x after 10 rounds, ~11x
after the first). If no solve of the round succeeded, the whole minibatch comes from the buffer.

**Loss.** In the network's standardised units (``y = (V - out_mean) / out_std``, ``z = (x - in_mean) / in_std``)::

    loss = mean_i (y_i - yhat_i)^2 + w * mean_i mean_j ((dV/dx_ij - dVhat/dx_ij) * in_std_j / out_std)^2

i.e. the Sobolev term compares ``dy/dz`` (the gradient the network actually fits), averaged over coordinates, so
``w`` weighs one standardised gradient coordinate like the standardised value; knots whose gradient label is not
finite only enter the value term. ``w = 0`` is plain MSE.

**Labels far from the pretraining set** (closed-loop tails). ``value_cap`` clips labels (their gradient labels are
dropped), ``grad_label_max`` drops gradient labels whose standardised norm is extreme, and ``renormalize`` moves the
standardisation to the whole buffer after each round's solves without changing the network's function
(:meth:`ValueNetwork.renormalize`, PopArt). ``refit_steps`` finally fits a fresh network to the whole buffer
(docs/experiments/closed-loop.md measures all four).

**Metrics** (``metrics.json`` / ``metrics.csv``): after pretraining, after every round (and every ``eval_every``
training steps if set): ``solves`` (budget solves so far), ``train_steps`` (after pretraining), ``mse_initial`` (the
validation starts at their full ``tau``), ``mse_all_knots`` (every per-knot label of the successful validation
solves), ``failures`` (failed budget solves so far). MSEs are in the task's cost units squared.

**Determinism and resume.** Every random stream is a fresh ``np.random.default_rng([seed, stream, round])``; torch
runs in float64 with a fixed thread count and draws nothing from its global RNG after the seeded initialisation.
After each round a checkpoint (network, Adam state, start-pool position, next solve index, metrics) is written
atomically. ``train(config, out, resume=True)`` restores it, re-runs the interrupted round from its start, and reuses
the records that round had already stored (their requests are checked bit for bit), so a run killed at any moment
and resumed ends with the same dataset and the same weights as an uninterrupted one, whatever ``workers`` is.
"""

from __future__ import annotations

import csv
import functools
import hashlib
import io
import json
import math
import os
import shutil
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
from tqdm.auto import tqdm

from seagul_control._io import atomic_write_bytes, atomic_write_text
from seagul_control._io import cache_dir as seagul_cache_dir
from seagul_envs import Task, available_tasks, resolve_task, validate_task
from seagul_envs.tasks.profile import VALIDATION_SEED, ValidationSpec
from seagul_learn.closed_loop import ClosedLoopOptions, ClosedLoopSampler
from seagul_learn.dataset import (
    Dataset,
    SolveRecord,
    TrainingArrays,
    count_failures,
    training_arrays,
)
from seagul_learn.samplers import AdversarialOptions, AdversarialSampler, Sampler, StartPool, UniformSampler
from seagul_learn.solving import BatchSolver, SolveRunner, solver_key, trajopt_batch_solver
from seagul_learn.value_network import ValueEnsemble, ValueModel, ValueNetwork

SAMPLERS = ("uniform", "adversarial", "closed-loop")
CHECKPOINT_FORMAT = "seagul-train-checkpoint"

# Random streams: one id each, combined with the seed (and the round) into an independent generator.
_STREAM_BASELINE_STARTS = 1
_STREAM_ADVERSARIAL_ORDER = 2
_STREAM_PRETRAIN_STARTS = 3
_STREAM_PRETRAIN_BATCHES = 4
_STREAM_ROUND_BATCHES = 5
_STREAM_REFIT_BATCHES = 6
_STREAM_VALIDATION_ROBOTS = 7
_VALIDATION_SEED = VALIDATION_SEED  # one validation set for all training seeds (seagul_envs.tasks.profile)


@dataclass
class TrainConfig:
    """Everything that defines a training run (CleanRL style: one place, one line per field)."""

    task: str | Task = "acrobot"
    """A registered task name (``seagul_envs.available_tasks()``) or a Task object (a custom task, or a variant of a
    built-in one); ``config.json`` stores its name and fingerprint, and a resumed run must have the same task."""
    sampler: str = "adversarial"
    """``"uniform"`` (baseline), ``"adversarial"`` (paper Alg. 1) or ``"closed-loop"`` (the deployed MPC's queries,
    :mod:`seagul_learn.closed_loop`)."""
    budget: int = 100
    """Solves spent by the sampler (pretraining solves not included)."""
    solves_per_round: int = 10
    """New solves between two training phases (paper: 10)."""
    train_steps_per_round: int = 500
    """Adam steps after each round of solves (paper: 500)."""
    batch_size: int = 128
    """Knot samples per minibatch."""
    newest_fraction: float = 0.5
    """Share of each minibatch drawn from the knots added in the current round."""
    lr: float = 1e-3
    """Adam learning rate."""
    sobolev_weight: float = 0.0
    """Weight ``w`` of the gradient-matching term (0 = plain MSE)."""
    hidden: tuple[int, ...] = (32,)
    """Hidden-layer widths of the tanh network."""
    ensemble: int = 1
    """Networks fitted to the same data (1 = a single network; >= 2 a :class:`ValueEnsemble`, whose CasADi form is
    pessimistic where the members disagree)."""
    ensemble_pessimism: float = 1.0
    """Weight ``beta`` of the members' spread in the ensemble's CasADi form (``mean + beta * spread``)."""
    pretrain_solves: int = 10
    """Uniform solves of the shared pretraining set (also the standardisation statistics)."""
    pretrain_steps: int = 100
    """Adam steps on the pretraining set."""
    seed: int = 0
    """Seed of every random stream (starts, initial weights, minibatches)."""
    adv_max_steps: int = 5
    """Adversarial: solves per chain at most."""
    adv_step_fraction: float = 0.1
    """Adversarial: largest move per ascent step as a fraction of the X0 box width."""
    adv_eps: float = 1e-3
    """Adversarial: stop a chain when its step is below this (in box widths)."""
    adv_optimizer: str = "pga"
    """Adversarial: ``"pga"`` (normalised projected gradient ascent) or ``"adam"``."""
    adv_projection: str = "clip"
    """Adversarial: ``"clip"`` or ``"reflect"`` at the X0 boundary."""
    adv_uniform_fraction: float = 0.0
    """Adversarial: share of each round's solves spent on uniform draws."""
    adv_ascend_tau: bool = True
    """Adversarial: ascend in ``tau`` too when T0 is an interval."""
    adv_stop_on_decrease: bool = False
    """Adversarial: end a chain when its loss decreased from the previous iterate."""
    cl_episodes: int = 20
    """Closed-loop: MPC episodes per round (training starts from X0, never the evaluation grid)."""
    cl_horizon: int = 0
    """Closed-loop: lookahead steps of the collecting MPC (0 = the task's default, as deployed)."""
    cl_trust_region: Literal["lqr", "box", "none"] | None = None
    """Closed-loop: guard of the collecting MPC after the warm-up rounds and of the member selection; None = the
    guard the task deploys (``profile.mpc_trust_region``, ``LimitedLookaheadMPC``'s default), so the sampler
    collects with the controller as it will run. Set it when you deploy another guard."""
    cl_warmup_rounds: int = 1
    """Closed-loop: first rounds collect with the ``"lqr"``-guarded MPC (teachable queries)."""
    cl_selection: str = "farthest"
    """Closed-loop: which queries to solve: ``"farthest"`` from the data, ``"spread"`` (largest disagreement of an
    ensemble's members), ``"lowest"`` under-estimates, ``"random"``."""
    cl_tail_stride: int = 5
    """Closed-loop: only queries whose tail has a multiple of this many intervals (acrobot: 5 = every 0.5 s, so 9
    tail solvers are built, ~12 s of compilation each on first use, instead of 45)."""
    cl_uniform_fraction: float = 0.0
    """Closed-loop: share of each round's solves spent on uniform draws from X0."""
    cl_uniform_solves: int = 0
    """Closed-loop: budget solves spent on uniform draws before the first closed-loop round."""
    cl_jit: bool = True
    """Closed-loop: compile the collecting MPC (False: interpreted, for tests)."""
    cl_visited_fraction: float = 0.0
    """Closed-loop: share of each round's tail solves started from states the collecting episodes visited (states
    of failed episodes first) rather than from the planner's queries: the optimal continuation from where the
    learned controller went, DAgger's labels (fixed-step tasks)."""
    cl_slice_fraction: float = 0.0
    """Closed-loop: share of each round's episode starts drawn on the evaluation grid's slice of X0 (the acrobot at
    rest; random draws, never the grid's points) instead of uniformly over X0."""
    cl_collect_refit: bool = False
    """Closed-loop: each round after the ``"lqr"`` warm-up rounds collects with a refit of the buffer so far
    (``refit_steps`` Adam steps, as the final refit: the network that would be deployed if training stopped there)
    instead of the loop's network, so the queries are the deployed controller's (DAgger). Costs one refit per such
    round; the loop's own training is unchanged. Needs ``refit_steps > 0``."""
    cl_keep_best: bool = False
    """Closed-loop: deploy the collector that flew best. Each round's collecting MPC runs ``cl_episodes`` episodes
    from new X0 starts (never the evaluation's) with the network of the round before; the network of the round whose
    deployed collector (guard ``cl_trust_region``) succeeded most often (ties: the later, trained on more data) is
    kept as ``network_best.pt`` (with ``network_best.json``: its round, successes, solves) and becomes
    ``network.pt``, the loop's last network ``network_last.pt``; snapshots are the best so far. Model selection on
    training episodes: round-to-round closed-loop success swings widely (glider: 4 to 19 of 20 over 60 rounds of one
    seed, docs/experiments/closed-loop.md). Needs the closed-loop sampler and ``refit_steps = 0``."""
    value_cap: float = 0.0
    """Labels above this value are clipped to it and their gradient labels dropped (0 = off): a tail problem from
    a far-off query can cost 1e4 and would otherwise swamp the loss; the clipped label still says "expensive"."""
    renormalize: bool = False
    """Re-fit the standardisation to the whole buffer (labels capped at ``value_cap``) after each round's solves,
    rescaling the first and last layers so the network's function is unchanged (PopArt). Without it the statistics
    of the ``pretrain_solves`` stay, and closed-loop tail labels land tens of standard deviations out."""
    grad_label_max: float = 0.0
    """Drop gradient labels whose standardised norm ``|dV/dx * in_std / out_std|`` exceeds this (0 = keep all):
    near-singular tails carry dual gradients orders of magnitude above the rest that would dominate the Sobolev
    term; their value labels stay."""
    refit_steps: int = 0
    """After the last round, fit a fresh network (the seed's initial weights) to the whole buffer for this many Adam
    steps (uniform minibatches, cosine learning-rate decay, the buffer's standardisation); it becomes
    ``network.pt`` and the loop's network is kept as ``network_loop.pt`` (0 = off)."""
    refit_ensemble: int = 0
    """Members of the final refit (0 or 1: one network; >= 2: a :class:`ValueEnsemble` of that many fits from their
    own initial weights, with ``ensemble_pessimism``). The members' errors are partly independent, so the planner
    finds fewer under-estimates in their mean (docs/experiments/closed-loop.md); the loop's and the collecting refits'
    networks stay single unless ``ensemble`` is set."""
    refit_candidates: int = 0
    """Fit this many members in the final refit (``> refit_ensemble``) and deploy the ``refit_ensemble`` of them whose
    MPC (horizon ``cl_horizon``, guard ``cl_trust_region``) succeeds most often in closed loop from
    ``select_episodes`` training starts drawn from X0 (never an evaluation set): refits of one buffer differ by
    tens of points of closed-loop success. The candidates are kept as ``network_candidates.pt``, the scores in
    ``network_selection.json`` (0 = off)."""
    select_episodes: int = 100
    """Closed-loop episodes per candidate subset of ``refit_candidates``."""
    select_finalists: int = 0
    """Second stage of the ``refit_candidates`` selection: the best this many subsets fly ``select_final_episodes``
    more starts and are ranked on all their episodes (0 = one stage)."""
    select_final_episodes: int = 0
    """Episodes of that second stage per finalist."""
    select_slice_fraction: float = 0.0
    """Share of the selection's starts (both stages) drawn on the evaluation grid's slice of X0 instead of over all
    of X0 (``seagul_control.evaluation.sample_grid_slice``: the acrobot's grid starts at rest); random draws, never
    the grid's points."""
    select_jit: bool = True
    """Compile the MPC of the ``refit_candidates`` selection (False: interpreted, for tests)."""
    snapshots: tuple[int, ...] = ()
    """Budgets (solves) after whose round ``network_<solves>.pt`` is saved (success-per-solve curves from one run)."""
    uniform_tau: bool = False
    """Draw uniform starts' ``tau`` from T0 instead of using the nominal value."""
    model_params: bool = False
    """Learn ``V(x, tau, theta)`` over robots (docs/reference/spec.md §14): every start gets a robot ``theta`` drawn
    uniformly from the task's box Theta (``Task.parameters``), each solve takes it as NLP parameters (one built
    optimizer for all robots, with ``dV/dtheta`` from the duals), the network takes ``theta`` as inputs and is
    conditioned on the task's own values, and the Sobolev term covers x and theta. The uniform sampler is then uniform
    over ``X0 x Theta`` and the adversarial one ascends in theta as well (``adv_ascend_theta``); the validation set
    draws its robots from Theta with a fixed seed. The closed-loop sampler then flies every episode on its own robot
    from Theta with the deployed robust MPC (``model_params=True, estimate_robot=True``) and solves each tail for the
    robot its plan was made for."""
    adv_ascend_theta: bool = True
    """Adversarial, with ``model_params``: ascend in the robot's parameters too (False: each chain keeps its
    start's robot)."""
    eval_every: int = 0
    """Also evaluate every this many training steps inside rounds (0 = after each round only)."""
    validate: bool = True
    """Solve (or load) the validation set and record validation metrics."""
    torch_threads: int = 1
    """Torch intra-op threads during training (fixed so results never depend on the machine's core count)."""
    workers: int = 1
    """Parallel solver processes (results do not depend on it)."""
    backend: str = "local"
    """``"local"`` (joblib processes) or ``"ray"``."""
    solver_options: dict[str, Any] | None = None
    """Options of the trajectory optimizer (part of the validation-cache key)."""
    cache_dir: str | None = None
    """Where solved validation sets are cached (default ``$SEAGUL_CACHE_DIR`` or ``~/.cache/seagul``)."""
    progress: bool = True
    """Show progress bars."""

    # Fields that may change between an interrupted run and its resumption (they cannot change the results).
    RUNTIME_FIELDS = ("workers", "backend", "cache_dir", "progress", "snapshots")

    def __post_init__(self) -> None:
        self.hidden = tuple(int(h) for h in self.hidden)
        self.snapshots = tuple(sorted({int(b) for b in self.snapshots}))
        self.validate_values()

    def validate_values(self) -> None:
        """Raise a ValueError naming the first bad field and its accepted range."""
        if isinstance(self.task, Task):
            validate_task(self.task)
        elif not isinstance(self.task, str):
            raise ValueError(
                f"task must be a registered task name ({available_tasks()}) or a seagul_envs Task, "
                f"got {type(self.task).__name__}"
            )
        elif self.task not in available_tasks():
            raise ValueError(f"unknown task {self.task!r}; available tasks: {available_tasks()}")
        if self.sampler not in SAMPLERS:
            raise ValueError(f"unknown sampler {self.sampler!r}; choose one of {list(SAMPLERS)}")
        for name in ("budget", "solves_per_round", "batch_size", "pretrain_solves", "workers", "torch_threads"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        for name in ("train_steps_per_round", "pretrain_steps", "eval_every", "refit_steps"):
            if int(getattr(self, name)) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if not 0.0 <= self.newest_fraction <= 1.0:
            raise ValueError(f"newest_fraction must be in [0, 1], got {self.newest_fraction}")
        if not (self.lr > 0 and math.isfinite(self.lr)):
            raise ValueError(f"lr must be a positive number, got {self.lr}")
        if not (self.sobolev_weight >= 0 and math.isfinite(self.sobolev_weight)):
            raise ValueError(f"sobolev_weight must be >= 0, got {self.sobolev_weight}")
        if self.backend not in ("local", "ray"):
            raise ValueError(f"unknown backend {self.backend!r}; choose 'local' or 'ray'")
        if self.ensemble < 1:
            raise ValueError(f"ensemble must be >= 1 network, got {self.ensemble}")
        if not (self.ensemble_pessimism >= 0 and math.isfinite(self.ensemble_pessimism)):
            raise ValueError(f"ensemble_pessimism must be a number >= 0, got {self.ensemble_pessimism}")
        if not self.hidden or any(h < 1 for h in self.hidden):
            raise ValueError(f"hidden must be positive layer widths, got {self.hidden}")
        self.adversarial_options()  # validates the adv_* fields
        self.closed_loop_options()  # validates the cl_* fields
        if self.refit_ensemble < 0 or (self.refit_ensemble >= 2 and not self.refit_steps):
            raise ValueError(f"refit_ensemble must be >= 0 and needs refit_steps > 0, got {self.refit_ensemble}")
        if self.refit_candidates and not (self.refit_ensemble >= 2 and self.refit_candidates > self.refit_ensemble):
            raise ValueError(
                "refit_candidates must exceed refit_ensemble (>= 2) or be 0, got "
                f"{self.refit_candidates} candidates for {self.refit_ensemble} members"
            )
        if self.refit_candidates and math.comb(self.refit_candidates, self.refit_ensemble) > 252:
            raise ValueError(
                f"refit_candidates: C({self.refit_candidates}, {self.refit_ensemble}) subsets is too many to try "
                "(at most 252)"
            )
        if self.select_episodes < 1 or self.select_finalists < 0 or self.select_final_episodes < 0:
            raise ValueError(
                "select_episodes must be >= 1 and select_finalists, select_final_episodes >= 0, got "
                f"{self.select_episodes}, {self.select_finalists}, {self.select_final_episodes}"
            )
        if not 0.0 <= self.select_slice_fraction <= 1.0:
            raise ValueError(f"select_slice_fraction must be in [0, 1], got {self.select_slice_fraction}")
        if self.cl_collect_refit and not self.refit_steps:
            raise ValueError("cl_collect_refit needs refit_steps > 0 (the collecting network is a refit)")
        if self.cl_keep_best and (self.sampler != "closed-loop" or self.refit_steps):
            raise ValueError(
                "cl_keep_best needs sampler='closed-loop' and refit_steps=0 (it deploys a network a collector flew; "
                f"got sampler={self.sampler!r}, refit_steps={self.refit_steps})"
            )
        if self.model_params:
            task = self.resolve_task()
            if task.parameters is None:
                raise ValueError(
                    f"model_params needs a task with physical parameters (Task.parameters); {task.name} has none"
                )
        if not (self.value_cap >= 0 and math.isfinite(self.value_cap)):
            raise ValueError(f"value_cap must be a number >= 0 (0 = off), got {self.value_cap}")
        if not (self.grad_label_max >= 0 and math.isfinite(self.grad_label_max)):
            raise ValueError(f"grad_label_max must be a number >= 0 (0 = off), got {self.grad_label_max}")
        if any(b < 1 for b in self.snapshots):
            raise ValueError(f"snapshots must be budgets >= 1, got {list(self.snapshots)}")
        unreachable = [b for b in self.snapshots if b != self.budget and (b % self.solves_per_round or b > self.budget)]
        if unreachable:
            raise ValueError(
                f"snapshots {unreachable} are not round boundaries: a snapshot is taken after a round, so it must be "
                f"a multiple of solves_per_round ({self.solves_per_round}) up to the budget ({self.budget})"
            )

    def final_refit_config(self) -> TrainConfig:
        """The config the final refit is made with (``ensemble = refit_ensemble`` when that asks for members)."""
        return replace(self, ensemble=self.refit_ensemble) if self.refit_ensemble >= 2 else self

    def closed_loop_options(self) -> ClosedLoopOptions:
        """The closed-loop sampler's options from the ``cl_*`` fields."""
        return ClosedLoopOptions(
            episodes=self.cl_episodes,
            horizon=self.cl_horizon or None,
            trust_region=self.cl_trust_region,
            warmup_rounds=self.cl_warmup_rounds,
            selection=self.cl_selection,  # type: ignore[arg-type]
            tail_stride=self.cl_tail_stride,
            uniform_fraction=self.cl_uniform_fraction,
            uniform_solves=self.cl_uniform_solves,
            jit=self.cl_jit,
            visited_fraction=self.cl_visited_fraction,
            slice_fraction=self.cl_slice_fraction,
        )

    def adversarial_options(self) -> AdversarialOptions:
        """The adversarial sampler's options from the ``adv_*`` fields."""
        return AdversarialOptions(
            max_steps=self.adv_max_steps,
            step_fraction=self.adv_step_fraction,
            eps=self.adv_eps,
            optimizer=self.adv_optimizer,  # type: ignore[arg-type]
            projection=self.adv_projection,  # type: ignore[arg-type]
            uniform_fraction=self.adv_uniform_fraction,
            ascend_tau=self.adv_ascend_tau,
            ascend_theta=self.adv_ascend_theta,
            stop_on_decrease=self.adv_stop_on_decrease,
        )

    @property
    def num_rounds(self) -> int:
        """Rounds of solves (the last one may be partial)."""
        return math.ceil(self.budget / self.solves_per_round)

    @property
    def task_name(self) -> str:
        """The task's name (of the Task object, or the registered name given)."""
        return self.task.name if isinstance(self.task, Task) else str(self.task)

    def resolve_task(self) -> Task:
        """The Task of the run: the object given, or the registered name's shared task."""
        return resolve_task(self.task)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict of the fields (a Task object as its name: ``TrainConfig(**d)`` needs it registered, or
        :meth:`from_dict` with ``task=``)."""
        out = {f.name: getattr(self, f.name) for f in fields(self)}
        out["task"] = self.task_name
        out["hidden"] = list(self.hidden)
        out["snapshots"] = list(self.snapshots)
        if self.solver_options is not None:
            out["solver_options"] = dict(self.solver_options)
        return out

    @classmethod
    def recipe(cls, task: str | Task, **overrides: Any) -> TrainConfig:
        """The task's measured best settings (``task.profile.train_recipe``), then ``overrides``; what ``seagul
        train`` uses unless ``--recipe paper``. ``TrainConfig(task=...)`` alone keeps the paper's settings
        (adversarial sampler, 1 x 32 tanh, 100 solves). A task without a recipe gives the dataclass defaults, and so
        does an override naming another sampler than the recipe's (a recipe's settings belong to its sampler: the
        glider's ``cl_keep_best`` means nothing to the adversarial one).

        Raises:
            ValueError: the recipe or ``overrides`` name a field :class:`TrainConfig` does not have.
        """
        resolved = resolve_task(task)
        known = {f.name for f in fields(cls)}
        base = dict(resolved.profile.train_recipe)
        for where, names in (("task.profile.train_recipe", base), ("overrides", overrides)):
            unknown = sorted(set(names) - known)
            if unknown:
                raise ValueError(f"TrainConfig.recipe({resolved.name!r}): {where} names unknown fields {unknown}")
        if "sampler" in overrides and overrides["sampler"] != base.get("sampler", overrides["sampler"]):
            base = {}
        return cls(**{**base, **overrides, "task": task})

    @classmethod
    def from_dict(cls, data: dict[str, Any], task: Task | None = None) -> TrainConfig:
        """Inverse of :meth:`to_dict`; unknown keys are an error naming them. ``task``: the Task object to use
        for the stored name (a task that is not registered in this process); it must have that name."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown TrainConfig fields {unknown}")
        if task is not None:
            if data.get("task") != task.name:
                raise ValueError(f"the stored task is {data.get('task')!r}, not {task.name!r}")
            data = {**data, "task": task}
        return cls(**data)

    @classmethod
    def from_run(cls, run_dir: str | Path, task: Task | None = None) -> TrainConfig:
        """The config of a run directory (its ``config.json``, which also stores the task's fingerprint); with a
        ``task``, that fingerprint must match (same check as a resume)."""
        data = json.loads((Path(run_dir) / "config.json").read_text())
        stored = data.pop("task_fingerprint", None)
        if task is not None and stored is not None and stored != task.fingerprint():
            raise ValueError(
                f"run {str(run_dir)!r} was trained on a task {task.name!r} with fingerprint {stored}, not "
                f"{task.fingerprint()} (same name, other content)"
            )
        return cls.from_dict(data, task)

    def result_fields(self) -> dict[str, Any]:
        """The fields that determine the results (everything but the runtime ones; the task by its name, whose
        content :func:`train` checks by fingerprint)."""
        return {k: v for k, v in self.to_dict().items() if k not in self.RUNTIME_FIELDS}


# ----------------------------------------------------------------------------------------------- validation set
# ``ValidationSpec`` lives in seagul_envs.tasks.profile (imported above, so ``seagul_learn.training.ValidationSpec``
# still works): each task's validation set is ``task.profile.validation_spec(task)``, the built-ins' set in their
# task modules (docs/reference/spec.md §3.6, §4.6). ``VALIDATION_SPECS`` remains as a deprecated view of the built-in
# tasks'.
def __getattr__(name: str) -> Any:
    """``VALIDATION_SPECS``: a deprecated name-keyed view of the built-in tasks' validation sets."""
    if name == "VALIDATION_SPECS":
        import warnings

        from seagul_envs.tasks import BUILTIN_TASKS, make_task

        warnings.warn(
            "seagul_learn.training.VALIDATION_SPECS is deprecated; use task.profile.validation_spec(task)",
            DeprecationWarning,
            stacklevel=2,
        )
        return {n: make_task(n).profile.validation_spec(make_task(n)) for n in sorted(BUILTIN_TASKS)}
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def default_cache_dir() -> Path:
    """``$SEAGUL_CACHE_DIR`` or ``~/.cache/seagul`` (:func:`seagul_control._io.cache_dir`)."""
    return seagul_cache_dir()


def validation_dataset(
    task: Task,
    batch_solver: BatchSolver,
    solver_name: str,
    cache_dir: str | os.PathLike[str] | None = None,
    chunk_size: int = 1,
    progress: bool = False,
    spec: ValidationSpec | None = None,
    model_params: bool = False,
) -> list[SolveRecord]:
    """Solve (or load from the cache) the task's validation set; returns one record per validation start.

    The set is ``spec`` or the task's (``task.profile.validation_spec(task)``); with ``model_params`` every start
    is solved for a robot drawn uniformly from Theta (:func:`validation_robots`, a fixed seed). The cache entry is
    keyed by ``solver_name`` (give ``solver_key(options, task)`` for the real solver), the spec, ``tau`` and the task's
    fingerprint, so a variant of a task (one parameter changed, same name) gets a validation set of its own.
    """
    spec = spec or task.profile.validation_spec(task)
    starts = spec.starts(task)
    robots = validation_robots(task, starts.shape[0]) if model_params else None
    meta: dict[str, Any] = {"solver": solver_name, "spec": asdict(spec), "tau": task.tau_nominal}
    meta["task"] = task.fingerprint()
    if robots is not None:
        meta["robots"] = "uniform over Theta, seed " + str(_VALIDATION_SEED)
    key = hashlib.sha256(json.dumps(meta, sort_keys=True).encode()).hexdigest()[:16]
    root = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    dataset = Dataset.open(root / f"validation-{task.name}-{key}", task.name, meta=meta)
    have = set(dataset.indices())
    todo = [i for i in range(starts.shape[0]) if i not in have]
    bar = tqdm(total=starts.shape[0], initial=len(have), desc=f"validation set ({task.name})", disable=not progress)
    for lo in range(0, len(todo), chunk_size):
        chunk = todo[lo : lo + chunk_size]
        taus = np.full(len(chunk), task.tau_nominal)
        if robots is None:
            results = batch_solver(starts[chunk], taus)
        else:
            results = batch_solver(starts[chunk], taus, robots[chunk])
        for i, result in zip(chunk, results, strict=True):
            dataset.write(SolveRecord.from_result(result, i, "validation"), exist_ok=True)  # races are harmless
        bar.update(len(chunk))
    bar.close()
    records = [dataset.read(i) for i in range(starts.shape[0])]
    for i, rec in enumerate(records):
        if not rec.same_request(starts[i], task.tau_nominal, None if robots is None else robots[i]):
            raise RuntimeError(f"validation cache {str(dataset.path)!r} holds another start at index {i}")
    return records


def validation_robots(task: Task, n: int) -> np.ndarray:
    """The robots of a validation set over robots: ``n`` uniform draws from Theta with the validation seed (the same
    for every training seed, sampler and run)."""
    if task.parameters is None:
        raise ValueError(f"{task.name} declares no physical parameters (Task.parameters)")
    rng = np.random.default_rng([_VALIDATION_SEED, _STREAM_VALIDATION_ROBOTS])
    return task.parameters.sample(rng, n).reshape(n, task.parameters.size)


# ---------------------------------------------------------------------------------------------- training pieces
@dataclass
class Metric:
    """One evaluation point."""

    solves: int
    train_steps: int
    mse_initial: float
    mse_all_knots: float
    failures: int
    buffer_solves: int
    wall_time: float


@dataclass
class TrainResult:
    """What :func:`train` returns (everything is also on disk in the run directory)."""

    network: ValueModel
    metrics: list[Metric]
    out_dir: Path
    num_solves: int
    num_failures: int
    dataset: Dataset = field(repr=False)


def _rng(seed: int, stream: int, index: int = 0) -> np.random.Generator:
    return np.random.default_rng([int(seed), int(stream), int(index)])


def _as_tensors(
    arrays: TrainingArrays, value_cap: float = 0.0, grad_label_max: float = 0.0, network: ValueModel | None = None
) -> dict[str, torch.Tensor]:
    value = arrays.value
    grad_ok = np.all(np.isfinite(arrays.grad_x), axis=1)
    if arrays.grad_theta is not None:
        grad_ok &= np.all(np.isfinite(arrays.grad_theta), axis=1)
    if value_cap > 0:
        # A clipped label keeps "expensive" without its scale; its gradient label no longer applies.
        grad_ok &= value <= value_cap
        value = np.minimum(value, value_cap)
    if grad_label_max > 0:
        if network is None:
            raise ValueError("grad_label_max needs the network whose standardisation measures the gradient labels")
        scale = _members(network)[0].in_std.numpy()[: arrays.x.shape[1]] / float(_members(network)[0].out_std)
        grad_ok &= np.linalg.norm(np.nan_to_num(arrays.grad_x) * scale, axis=1) <= grad_label_max
    out = {
        "x": torch.tensor(arrays.x, dtype=torch.float64),
        "tau": torch.tensor(arrays.tau, dtype=torch.float64),
        "value": torch.tensor(value, dtype=torch.float64),
        "grad_x": torch.tensor(np.nan_to_num(arrays.grad_x), dtype=torch.float64),
        "grad_ok": torch.tensor(grad_ok),
    }
    if arrays.theta is not None and arrays.grad_theta is not None:
        out["theta"] = torch.tensor(arrays.theta, dtype=torch.float64)
        out["grad_theta"] = torch.tensor(np.nan_to_num(arrays.grad_theta), dtype=torch.float64)
    return out


def training_loss(network: ValueNetwork, batch: dict[str, torch.Tensor], sobolev_weight: float) -> torch.Tensor:
    """The standardised value MSE plus ``sobolev_weight`` times the standardised gradient MSE (module docstring).

    A network over robots takes the batch's ``theta``, and its gradient term averages over the ``nx`` state and the
    ``k`` parameter coordinates alike (``dV/dtheta`` labels standardised by theta's input scale)."""
    target = (batch["value"] - network.out_mean) / network.out_std
    theta = batch.get("theta") if network.n_params else None
    if sobolev_weight == 0.0:
        return torch.mean((network.forward_standardized(batch["x"], batch["tau"], theta) - target) ** 2)
    x = batch["x"].clone().requires_grad_(True)
    if theta is None:
        pred = network.forward_standardized(x, batch["tau"])
        (dy_dx,) = torch.autograd.grad(pred.sum(), x, create_graph=True)
        scale = network.in_std[: network.nx]
        # dy/dz = dy/dx * in_std; the label's dy/dz = dV/dx * in_std / out_std
        diff = dy_dx * scale - batch["grad_x"] * scale / network.out_std
    else:
        th = theta.clone().requires_grad_(True)
        pred = network.forward_standardized(x, batch["tau"], th)
        dy_dx, dy_dth = torch.autograd.grad(pred.sum(), (x, th), create_graph=True)
        scale = torch.cat([network.in_std[: network.nx], network.in_std[network.nx + 1 :]])
        grads = torch.cat([dy_dx, dy_dth], dim=1)
        labels = torch.cat([batch["grad_x"], batch["grad_theta"]], dim=1)
        diff = grads * scale - labels * scale / network.out_std
    mask = batch["grad_ok"].to(torch.float64)
    grad_term = torch.sum(mask * torch.mean(diff**2, dim=1)) / torch.clamp(mask.sum(), min=1.0)
    return torch.mean((pred - target) ** 2) + sobolev_weight * grad_term


def _minibatch(
    data: dict[str, torch.Tensor], newest: np.ndarray, batch_size: int, newest_fraction: float, rng: np.random.Generator
) -> dict[str, torch.Tensor]:
    n_total = data["value"].shape[0]
    n_new = round(newest_fraction * batch_size) if newest.size else 0
    idx = np.concatenate([rng.choice(newest, size=n_new), rng.integers(0, n_total, size=batch_size - n_new)])
    index = torch.from_numpy(idx)
    return {k: v[index] for k, v in data.items()}


def evaluate(network: ValueModel, validation: TrainingArrays) -> tuple[float, float]:
    """``(mse_initial, mse_all_knots)`` of ``network`` on per-knot validation arrays (NaN if empty)."""
    if len(validation) == 0:
        return float("nan"), float("nan")
    if network.n_params and validation.theta is not None:
        pred = network.predict(validation.x, validation.tau, validation.theta)
    else:
        pred = network.predict(validation.x, validation.tau)
    err2 = (pred - validation.value) ** 2
    init = validation.knot == 0
    return float(np.mean(err2[init])) if init.any() else float("nan"), float(np.mean(err2))


class _Trainer:
    """Holds a run's mutable state between rounds (network, optimizer, buffer, metrics)."""

    def __init__(self, config: TrainConfig, network: ValueModel, validation: TrainingArrays | None) -> None:
        self.config = config
        self.network = network
        self.optimizer = torch.optim.Adam(network.parameters(), lr=config.lr)
        self.validation = validation
        self.metrics: list[Metric] = []
        self.train_steps = 0
        self.t0 = time.perf_counter()

    def record_metric(self, solves: int, failures: int, buffer_solves: int) -> None:
        mse_i, mse_a = evaluate(self.network, self.validation) if self.validation is not None else (np.nan, np.nan)
        self.metrics.append(
            Metric(solves, self.train_steps, mse_i, mse_a, failures, buffer_solves, time.perf_counter() - self.t0)
        )

    def train(
        self,
        buffer: TrainingArrays,
        newest: np.ndarray,
        steps: int,
        rng: np.random.Generator,
        count_steps: bool,
        on_eval: Callable[[], None] | None = None,
        cosine: bool = False,
    ) -> None:
        """``steps`` Adam steps on minibatches of ``buffer`` (``newest`` indexes this round's knots); ``cosine``
        decays the learning rate to 0 over the steps."""
        if len(buffer) == 0 or steps == 0:
            return
        data = _as_tensors(buffer, self.config.value_cap, self.config.grad_label_max, self.network)
        fraction = self.config.newest_fraction
        members = _members(self.network)
        if cosine:
            schedule = torch.optim.lr_scheduler.CosineAnnealingLR(self.optimizer, steps)
        for _ in range(steps):
            self.optimizer.zero_grad(set_to_none=True)
            # Each member of an ensemble gets its own minibatch (drawn in order from the one stream).
            loss = sum(
                training_loss(
                    m, _minibatch(data, newest, self.config.batch_size, fraction, rng), self.config.sobolev_weight
                )
                for m in members
            )
            loss.backward()  # type: ignore[union-attr]
            self.optimizer.step()
            if cosine:
                schedule.step()
            if count_steps:
                self.train_steps += 1
                if on_eval is not None and self.config.eval_every and self.train_steps % self.config.eval_every == 0:
                    on_eval()


def _members(network: ValueModel) -> list[ValueNetwork]:
    """The networks an optimizer step trains (one, or every member of an ensemble)."""
    return network.networks if isinstance(network, ValueEnsemble) else [network]


def make_network(config: TrainConfig, task: Task) -> ValueModel:
    """The run's (untrained) value function: a network, or an ensemble when ``config.ensemble >= 2``; over robots
    (``model_params``) with the task's parameters as inputs, conditioned on the task's own values."""
    robots = config.model_params and task.parameters is not None
    n_params = task.parameters.size if robots and task.parameters is not None else 0
    theta = task.theta if robots else None
    if config.ensemble >= 2:
        return ValueEnsemble(
            task.nx,
            config.hidden,
            config.ensemble,
            config.ensemble_pessimism,
            task_name=task.name,
            seed=config.seed,
            n_params=n_params,
            theta=theta,
        )
    return ValueNetwork(task.nx, config.hidden, task_name=task.name, seed=config.seed, n_params=n_params, theta=theta)


def _make_sampler(config: TrainConfig, task: Task) -> Sampler:
    """The run's sampler over the uniform baseline's starts (and, with ``model_params``, robots) for this seed."""
    pool = StartPool.uniform(
        task, config.budget, _rng(config.seed, _STREAM_BASELINE_STARTS), config.uniform_tau, config.model_params
    )
    if config.sampler == "uniform":
        return UniformSampler(task, pool)
    if config.sampler == "closed-loop":
        return ClosedLoopSampler(task, pool, config.closed_loop_options(), seed=config.seed)
    return AdversarialSampler(
        task, pool.shuffled(_rng(config.seed, _STREAM_ADVERSARIAL_ORDER)), config.adversarial_options()
    )


# --------------------------------------------------------------------------------------------------- the loop
def train(
    config: TrainConfig,
    out_dir: str | os.PathLike[str],
    resume: bool = False,
    batch_solver: BatchSolver | None = None,
    solver_name: str | None = None,
) -> TrainResult:
    """Run (or resume) SEAGuL training into ``out_dir``; see the module docstring.

    ``config.task`` is a registered name or a Task object (resolved once, here; the object is what the solver's
    workers get). ``batch_solver`` replaces the trajectory optimizer (tests inject a toy); ``solver_name`` then
    names it in the validation-cache key. Outputs: ``config.json`` (with the task's name and fingerprint),
    ``dataset/``, ``checkpoint.pt``, ``network.pt``, ``metrics.json``, ``metrics.csv``, ``validation.png``.

    Raises:
        ValueError: a bad configuration, or ``resume`` of a run made with another configuration or with a task of
            another fingerprint (same name, other content).
    """
    config.validate_values()
    out = Path(out_dir)
    task = config.resolve_task()
    if batch_solver is None:
        batch_solver = trajopt_batch_solver(
            task, workers=config.workers, backend=config.backend, solver_options=config.solver_options
        )
        solver_name = solver_key(config.solver_options, task)
    solver_name = solver_name or "custom"
    _prepare_run_dir(out, config, resume, task)

    previous_threads = torch.get_num_threads()
    torch.set_num_threads(config.torch_threads)
    try:
        return _train(config, out, task, batch_solver, solver_name)
    finally:
        torch.set_num_threads(previous_threads)


class _OtherTask(Exception):
    """The stored run config names another task (raised and caught inside :func:`_prepare_run_dir`)."""


def _prepare_run_dir(out: Path, config: TrainConfig, resume: bool, task: Task) -> None:
    config_path = out / "config.json"
    if out.exists() and not out.is_dir():
        raise FileExistsError(f"run directory {str(out)!r} is a file, not a directory; choose a directory for the run")
    if config_path.is_file():
        if not resume:
            raise FileExistsError(
                f"run directory {str(out)!r} already holds a run; pass resume=True (--resume) or choose a new one"
            )
        try:
            data = json.loads(config_path.read_text())
            stored_fingerprint = data.pop("task_fingerprint", None)
            if data.get("task") != task.name:
                raise _OtherTask(data.get("task"))
            stored = TrainConfig.from_dict(data, task=task).result_fields()
        except _OtherTask as other:
            raise ValueError(
                f"cannot resume {str(out)!r} with a different configuration (task: stored {other.args[0]!r} vs "
                f"{task.name!r})"
            ) from None
        except (ValueError, TypeError, AttributeError) as exc:
            raise ValueError(f"cannot resume: {str(config_path)!r} is not a valid run config ({exc})") from exc
        if stored_fingerprint is not None and stored_fingerprint != task.fingerprint():
            raise ValueError(
                f"cannot resume {str(out)!r}: it was trained on task {task.name!r} with fingerprint "
                f"{stored_fingerprint}, and the task given now has fingerprint {task.fingerprint()} (same name, other "
                "content: a parameter, bound, cost or setting differs); resume with the task the run was made with, "
                "or start a new run directory"
            )
        wanted = config.result_fields()
        diff = sorted(k for k in wanted if json.dumps(wanted[k]) != json.dumps(stored.get(k)))
        if diff:
            details = ", ".join(f"{k}: stored {stored.get(k)!r} vs {wanted[k]!r}" for k in diff)
            raise ValueError(f"cannot resume {str(out)!r} with a different configuration ({details})")
    elif out.exists() and any(p.name != ".gitkeep" for p in out.iterdir()):
        raise FileExistsError(f"run directory {str(out)!r} exists and is not a seagul run; choose a new one")
    out.mkdir(parents=True, exist_ok=True)
    payload = {**config.to_dict(), "task_fingerprint": task.fingerprint()}
    atomic_write_text(config_path, json.dumps(payload, indent=2, sort_keys=True))


def _train(config: TrainConfig, out: Path, task: Task, batch_solver: BatchSolver, solver_name: str) -> TrainResult:
    chunk = max(1, config.workers)
    validation: TrainingArrays | None = None
    if config.validate:
        val_records = validation_dataset(
            task,
            batch_solver,
            solver_name,
            config.cache_dir or default_cache_dir(),
            chunk,
            config.progress,
            model_params=config.model_params,
        )
        validation = training_arrays(val_records, task.nx)
        if len(validation) == 0:
            raise RuntimeError(f"no validation solve of {task.name} succeeded; check the solver settings")

    dataset = Dataset.open(out / "dataset", task.name, meta={"solver": solver_name, "seed": config.seed})
    runner = SolveRunner(batch_solver, dataset, next_index=0, chunk_size=chunk)
    sampler = _make_sampler(config, task)
    network = make_network(config, task)
    trainer = _Trainer(config, network, validation)
    checkpoint_path = out / "checkpoint.pt"

    # Pretraining: identical for every sampler and Sobolev weight of this seed (only the value loss).
    pool = StartPool.uniform(
        task, config.pretrain_solves, _rng(config.seed, _STREAM_PRETRAIN_STARTS), model_params=config.model_params
    )
    pre_records = runner.solve(pool.starts, pool.taus, "pretrain", thetas=pool.thetas)
    buffer = training_arrays(pre_records, task.nx)
    if len(buffer) == 0:
        raise RuntimeError(f"all {config.pretrain_solves} pretraining solves of {task.name} failed")
    budget_records: list[SolveRecord] = []
    rounds_done = 0

    if checkpoint_path.is_file():
        state = _load_checkpoint(checkpoint_path)
        network.load_state_dict(state["network"])
        trainer.optimizer.load_state_dict(state["optimizer"])
        trainer.train_steps = int(state["train_steps"])
        trainer.metrics = [Metric(**m) for m in state["metrics"]]
        rounds_done = int(state["rounds_done"])
        sampler.pool.position = int(state["pool_position"])
        if "sampler_state" in state and hasattr(sampler, "load_state_dict"):
            sampler.load_state_dict(json.loads(state["sampler_state"]))
        runner.next_index = int(state["next_index"])
        budget_records = [dataset.read(i) for i in range(config.pretrain_solves, runner.next_index)]
        new = training_arrays(budget_records, task.nx)
        buffer = buffer.concat(new)
    else:
        network.set_normalization(buffer.x, buffer.tau, buffer.value, buffer.theta)
        pre_cfg = replace(config, sobolev_weight=0.0, newest_fraction=0.0)
        _Trainer(pre_cfg, network, None).train(
            buffer,
            np.zeros(0, dtype=np.int64),
            config.pretrain_steps,
            _rng(config.seed, _STREAM_PRETRAIN_BATCHES),
            count_steps=False,
        )
        trainer.optimizer = torch.optim.Adam(network.parameters(), lr=config.lr)  # fresh Adam for the rounds
        trainer.record_metric(0, 0, config.pretrain_solves)
        _save_checkpoint(checkpoint_path, trainer, 0, sampler, runner.next_index)

    bar = tqdm(
        total=config.num_rounds,
        initial=rounds_done,
        desc=f"{config.sampler} {task.name}",
        unit="round",
        disable=not config.progress,
    )
    for round_index in range(rounds_done, config.num_rounds):
        n_new = min(config.solves_per_round, config.budget - round_index * config.solves_per_round)
        if hasattr(sampler, "observe"):
            sampler.observe(buffer)
        collecting: ValueModel = network
        if config.cl_collect_refit and getattr(sampler, "collects_deployed", lambda n: False)(n_new):
            # Deterministic from (buffer, seed, round): a resumed run recomputes the same collecting network.
            collecting = refit(config, task, buffer, _Trainer(config, network, None), round_index=round_index)
        records = sampler.sample(n_new, collecting, runner)
        if config.cl_keep_best:
            spent = config.pretrain_solves + len(budget_records)
            _keep_best(out, config, getattr(sampler, "log", []), collecting, spent)
        budget_records += records
        new = training_arrays(records, task.nx)
        newest = np.arange(len(buffer), len(buffer) + len(new))
        buffer = buffer.concat(new)
        solves, failures = len(budget_records), count_failures(budget_records)
        buffer_solves = config.pretrain_solves + solves
        if config.renormalize:
            network.renormalize(buffer.x, buffer.tau, _capped(buffer.value, config.value_cap), buffer.theta)
        trainer.train(
            buffer,
            newest,
            config.train_steps_per_round,
            _rng(config.seed, _STREAM_ROUND_BATCHES, round_index),
            count_steps=True,
            on_eval=functools.partial(trainer.record_metric, solves, failures, buffer_solves),
        )
        if (
            not trainer.metrics
            or trainer.metrics[-1].train_steps != trainer.train_steps
            or (trainer.metrics[-1].solves != solves)
        ):
            trainer.record_metric(solves, failures, buffer_solves)
        _save_checkpoint(checkpoint_path, trainer, round_index + 1, sampler, runner.next_index)
        if solves in config.snapshots:
            best = out / "network_best.pt"
            if config.cl_keep_best and best.is_file():
                shutil.copyfile(best, out / f"network_{solves}.pt")  # the method at this budget: the best so far
            else:
                network.save(out / f"network_{solves}.pt")
        bar.set_postfix(mse_initial=f"{trainer.metrics[-1].mse_initial:.3g}", failures=failures)
        bar.update(1)
    bar.close()

    if config.refit_steps:
        network.save(out / "network_loop.pt")
        if config.refit_candidates:
            network = refit_and_select(config, task, buffer, trainer, out)
        else:
            network = refit(config.final_refit_config(), task, buffer, trainer)
        trainer.record_metric(
            len(budget_records), count_failures(budget_records), config.pretrain_solves + len(budget_records)
        )
    if config.cl_keep_best and (out / "network_best.pt").is_file():
        network.save(out / "network_last.pt")
        network = ValueNetwork.load(out / "network_best.pt")
    network.save(out / "network.pt")
    _write_metrics(out, trainer.metrics, config, getattr(sampler, "log", None))
    return TrainResult(network, trainer.metrics, out, len(budget_records), count_failures(budget_records), dataset)


def _capped(value: np.ndarray, value_cap: float) -> np.ndarray:
    return np.minimum(value, value_cap) if value_cap > 0 else value


def refit(
    config: TrainConfig, task: Task, buffer: TrainingArrays, trainer: _Trainer, round_index: int | None = None
) -> ValueModel:
    """Fit a fresh network to the whole buffer (``TrainConfig.refit_steps``); it replaces ``trainer.network``.

    The fresh network starts from the seed's initial weights with the buffer's standardisation (capped labels), so
    every label is in range from the first step; minibatches are uniform over the buffer (stream
    ``_STREAM_REFIT_BATCHES``, and the round for the collecting refits of ``cl_collect_refit``) and the learning
    rate decays along a cosine to 0. Deterministic, so a run interrupted during the refit and resumed ends with the
    same network.
    """
    network = make_network(config, task)
    network.set_normalization(buffer.x, buffer.tau, _capped(buffer.value, config.value_cap), buffer.theta)
    trainer.network = network
    trainer.optimizer = torch.optim.Adam(network.parameters(), lr=config.lr)
    trainer.train(
        buffer,
        np.zeros(0, dtype=np.int64),
        config.refit_steps,
        _rng(config.seed, _STREAM_REFIT_BATCHES, 0 if round_index is None else round_index + 1),
        count_steps=round_index is None,
        cosine=True,
    )
    return network


#: TrainConfig fields that shape the final refit (the candidates of ``refit_candidates`` are reused only if equal).
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
    """What the candidates' refit of ``refit_candidates`` depends on (stored beside them; JSON-ready)."""
    key = {
        "candidates": config.refit_candidates,
        "knots": len(buffer),
        "refit": {k: v for k, v in config.to_dict().items() if k in _REFIT_FIELDS},
    }
    return json.loads(json.dumps(key))


def refit_and_select(
    config: TrainConfig, task: Task, buffer: TrainingArrays, trainer: _Trainer, out: Path
) -> ValueModel:
    """``refit_candidates``: refit ``refit_candidates`` members to the whole buffer (as :func:`refit`), save them as
    ``network_candidates.pt``, and return the ``refit_ensemble`` of them whose deployed MPC succeeds most often on
    ``select_episodes`` training starts (:func:`seagul_learn.closed_loop.select_members`; the scores go to
    ``network_selection.json``). Deterministic (the refit, the starts and the MPC are)."""
    from seagul_learn.closed_loop import select_members

    # The candidates' refit is deterministic: a run interrupted during the selection reuses the stored one when it
    # was made with the same settings from the same buffer.
    key = candidates_key(config, buffer)
    stored, stored_key = out / "network_candidates.pt", out / "network_candidates.json"
    candidates: ValueModel | None = None
    if stored.is_file() and stored_key.is_file() and json.loads(stored_key.read_text()) == key:
        candidates = ValueNetwork.load(stored)
    if not isinstance(candidates, ValueEnsemble) or len(candidates.members) != config.refit_candidates:
        candidates = refit(replace(config, ensemble=config.refit_candidates), task, buffer, trainer)
        if not isinstance(candidates, ValueEnsemble):
            raise TypeError("refit_candidates: the candidate refit must be an ensemble")
        candidates.save(stored)
        atomic_write_text(stored_key, json.dumps(key, indent=1) + "\n")
    start = time.perf_counter()
    chosen = select_members(
        task,
        candidates,
        config.refit_ensemble,
        config.select_episodes,
        config.seed,
        finalists=config.select_finalists,
        final_episodes=config.select_final_episodes,
        horizon=config.cl_horizon or None,
        trust_region=config.cl_trust_region,
        jit=config.select_jit,
        progress=config.progress,
        slice_fraction=config.select_slice_fraction,
    )
    info = {**chosen.as_dict(), "wall_s": round(time.perf_counter() - start, 1), "candidates": config.refit_candidates}
    atomic_write_text(out / "network_selection.json", json.dumps(info, indent=1) + "\n")
    network = candidates.subset(chosen.members, pessimism=config.ensemble_pessimism)
    trainer.network = network
    return network


# ------------------------------------------------------------------------------------------------- checkpoints
def _keep_best(out: Path, config: TrainConfig, log: list[dict[str, Any]], collecting: ValueModel, solves: int) -> None:
    """``cl_keep_best``: save ``collecting`` as ``network_best.pt`` when the round just logged is the best deployed
    collector so far (ties: the later). The best so far is recomputed from the log (resume-safe: a redone round
    rewrites the same file)."""
    deployed = config.cl_trust_region or config.resolve_task().profile.mpc_trust_region

    def rate(entry: dict[str, Any]) -> float | None:
        if entry.get("collector") != deployed or not entry.get("episodes"):
            return None
        return float(entry["episode_successes"]) / float(entry["episodes"])

    if not log or (now := rate(log[-1])) is None:
        return
    earlier = [r for r in (rate(e) for e in log[:-1]) if r is not None]
    if earlier and now < max(earlier):
        return
    collecting.save(out / "network_best.pt")
    entry = log[-1]
    info = {
        "round": int(entry["round"]),
        "episode_successes": int(entry["episode_successes"]),
        "episodes": int(entry["episodes"]),
        "solves_before_round": int(solves),
        "note": "the network the round's collector flew (trained on the solves before the round)",
    }
    atomic_write_text(out / "network_best.json", json.dumps(info, indent=1) + "\n")


def _save_checkpoint(path: Path, trainer: _Trainer, rounds_done: int, sampler: Sampler, next_index: int) -> None:
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


def _load_checkpoint(path: Path) -> dict[str, Any]:
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        raise ValueError(f"checkpoint {str(path)!r} is unreadable or corrupt ({type(exc).__name__}: {exc})") from exc
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(f"{str(path)!r} is not a seagul training checkpoint")
    return state


# ----------------------------------------------------------------------------------------------------- outputs
def _write_metrics(
    out: Path, metrics: list[Metric], config: TrainConfig, sampler_log: list[dict[str, Any]] | None = None
) -> None:
    rows = [asdict(m) for m in metrics]
    payload: dict[str, Any] = {"config": config.to_dict(), "metrics": rows}
    if sampler_log is not None:
        payload["sampler_log"] = sampler_log
    atomic_write_text(out / "metrics.json", json.dumps(payload, indent=2, allow_nan=True))
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=list(rows[0]) if rows else [f.name for f in fields(Metric)])
    writer.writeheader()
    writer.writerows(rows)
    atomic_write_text(out / "metrics.csv", text.getvalue())
    plot_metrics(metrics, out / "validation.png", title=f"{config.task_name}: {config.sampler} (seed {config.seed})")


def plot_metrics(metrics: list[Metric], path: str | os.PathLike[str], title: str = "") -> None:
    """PNG of both validation MSEs vs solves and vs training steps (matplotlib Agg, headless)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    for ax, key in zip(axes, ("solves", "train_steps"), strict=True):
        xs = [getattr(m, key) for m in metrics]
        ax.plot(xs, [m.mse_initial for m in metrics], marker="o", ms=3, label="mse_initial (starts, full tau)")
        ax.plot(xs, [m.mse_all_knots for m in metrics], marker="s", ms=3, label="mse_all_knots")
        ax.set_xlabel("solves" if key == "solves" else "training steps")
        ax.set_ylabel("validation MSE")
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend()
    if title:
        fig.suptitle(title)
    fig.savefig(path, dpi=100)
    plt.close(fig)
