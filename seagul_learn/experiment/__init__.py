"""The paper's experiment end to end (``seagul reproduce``): the task's shipped controller in closed loop, validation
set, three ways of learning the value function trained over paired seeds, closed-loop MPC evaluation of every
network next to LQR and the full-horizon MPC, and a report.

**Shipped controller** (``shipped/shipped.json``, ``shipped/shipped_vs_lqr.gif``; the ``shipped`` block of
``experiment.json``; the report's first section). The network the closed-loop benchmark ships for the task
(:func:`seagul_learn.shipped.shipped_network`: ``benchmarks/results/closed_loop.json``) as the terminal cost of the
limited-lookahead MPC deployed as that benchmark deploys it, from the reference grid's starts beside LQR and the
full-horizon MPC (whose episodes there the closed-loop evaluation shares), and one animation of it beside LQR from the
hardest corner of X0. The MPC runs with CasADi interpreted unless ``--shipped-jit`` (the same problem and solver;
compiling it is about 2 minutes of gcc on a cold cache). A task without a shipped network gets a line saying so and
no block.

**Learning methods** (:data:`METHODS`: a name and its :class:`~seagul_learn.training.TrainConfig` overrides, one
table for this pipeline and the closed-loop benchmark: :mod:`seagul_learn.experiment.methods`). Every method of a
seed starts from IDENTICAL pretrained parameters and spends the same number of solves and training steps. The
presets compare the paper's three:

* ``uniform`` — the baseline: starts drawn uniformly from X0 at the nominal time to go.
* ``adversarial`` — SEAGuL (paper Alg. 1): projected gradient-ascent chains on the network's error, started from the
  baseline's starts.
* ``closed-loop`` — each round the deployed limited-lookahead MPC (the experiment's horizon) is rolled out and the
  tail problems at its planned terminal states are solved (:mod:`seagul_learn.closed_loop`); Sobolev training.

``--methods`` (:attr:`ExperimentConfig.methods`) names others: the benchmark's recipes, or ``shipped``, the task's
recipe (``TrainConfig.recipe``, behind the README's closed-loop success), e.g. ``seagul reproduce acrobot --methods
shipped,uniform``. A run with ``shipped`` takes the recipe's schedule (its budget, solves and Adam steps per round,
network and label settings for every method) and deploys the networks as the closed-loop benchmark does
(:meth:`Experiment.deployment`); its paired success tests are against ``shipped`` when ``closed-loop`` is absent.

**Validation** (``learning.json``, ``validation_curves.png``): both validation MSEs of every run, each method paired
against the uniform baseline per seed (median ratio, win fraction, Wilcoxon test; :mod:`seagul_learn.comparison`).

**Closed loop for every seed** (``closed_loop/summary.json``, ``success_vs_solves.png``). Every (method, seed) run
saves its network after each budget of :attr:`Preset.budgets`; each of these networks is the terminal cost of the
limited-lookahead MPC over the main start grid. Per method the summary holds the grid success of every seed at the
full budget, its median and 25/75 % quantiles, the median at every budget (the success-per-solve curve), the
planner-query error (``|Vhat - V|`` at a sample of the final MPC's planned terminal states, re-solved as tail
problems: :func:`seagul_learn.closed_loop.query_errors`; median over seeds of the per-seed median and p95) and a
paired test of the method against the closed-loop method on the per-seed success rates
(:func:`paired_success_comparison`; every paired test of the library is
:func:`~seagul_learn.experiment.statistics.paired_wilcoxon`). LQR, the saved stable-baselines3 models given
(``--sb3 MODEL --sb3-algo PPO|SAC``: :meth:`ExperimentConfig.sb3_policies`) and the full-horizon MPC (on the coarser
reference grid, next to every final network) run as baselines.

Every stage writes its results into the run directory before the next starts, and a finished stage is never run
again: training runs checkpoint after each round (``seagul_learn.training``), solves (training, query errors) are
cached on disk bit for bit, the closed-loop episodes of each policy and each query error are stored as soon as
they are complete, and the shipped controller's evaluation is read back from ``shipped/shipped.json``. So Ctrl-C
(or SIGKILL) at any moment leaves a run that ``seagul reproduce TASK --resume DIR`` finishes with the same numbers.

The package: :mod:`~seagul_learn.experiment.config` (:class:`ExperimentConfig`, :class:`Preset`),
:mod:`~seagul_learn.experiment.methods` (the named methods), :mod:`~seagul_learn.experiment.pipeline` (the stages),
:mod:`~seagul_learn.experiment.closed_loop_stage` (the closed-loop evaluation of every network and baseline),
:mod:`~seagul_learn.experiment.runs` (training runs of methods x seeds and the closed-loop evaluation of their
snapshots on grid and held-out starts),
:mod:`~seagul_learn.experiment.shipped_stage` (the shipped controller's stage),
:mod:`~seagul_learn.experiment.statistics` (the paired test, per-method statistics),
:mod:`~seagul_learn.experiment.figures` (success vs solves), :mod:`~seagul_learn.experiment.sections` (the report's
text) and :mod:`~seagul_learn.experiment.benchmark` (the closed-loop benchmark's grid and held-out evaluation, behind
``benchmarks/bench_closed_loop.py``).

Presets (one place for every number of the experiment; the paper's settings are §6 of the paper) are data in the
task's recipe file, ``seagul_learn/recipes/<task>.yml`` (:func:`seagul_learn.recipes.preset`; a task without a file
of its own gets ``default.yml``'s); :func:`task_preset` makes the :class:`Preset`:

* ``quick`` — the README's main job: fewer seeds, a smaller budget and a coarser closed-loop grid than the paper,
  same algorithms.
* ``smoke`` — seconds of work past the validation set: checks the whole pipeline (tests, CI), says nothing.
* ``paper`` — acrobot: 100 solves per network, 10 solves every 500 training steps (10,000 steps), 10 paired seeds,
  a 20 x 20 closed-loop grid; glider: the same schedule with its own grid.
"""

from __future__ import annotations

from typing import Any

from seagul_envs import Task, available_tasks, make_task, resolve_task
from seagul_learn.comparison import METRICS, PairedComparison, final_metric, paired_comparison, plot_curves_with_band
from seagul_learn.dataset import atomic_write_text
from seagul_learn.experiment.closed_loop_stage import _tail_multiple
from seagul_learn.experiment.config import (
    BASELINE_METHOD,
    METHOD_LABELS,
    OWNED_TRAIN_FIELDS,
    REFERENCE_METHOD,
    SB3_ALGOS,
    SHIPPED_LABEL,
    ExperimentConfig,
    Preset,
    _clashing,
    _slug,
    builtin_presets,
    method_label,
    policy_label,
    recipe_schedule,
    reference_method,
    task_preset,
    versus_key,
)
from seagul_learn.experiment.figures import plot_success_vs_solves, success_curve
from seagul_learn.experiment.methods import (
    METHOD_NAMES,
    METHODS,
    PAPER_METHODS,
    SHIPPED_METHOD,
    method_overrides,
    recipe_fields,
)
from seagul_learn.experiment.pipeline import Experiment, LearnedPolicy
from seagul_learn.experiment.runs import (
    deployment_options,
    evaluate_snapshot,
    network_spec,
    success_fields,
    train_one,
    train_runs,
)
from seagul_learn.experiment.sections import (
    CLOSED_LOOP_COLUMNS,
    SHIPPED_COLUMNS,
    _fine_pct,
    _ms,
    closed_loop_headline,
    comparison_intro,
    comparison_rows,
    comparison_title,
    experiment_sections,
    learning_headline,
    method_rows,
    other_envs_section,
    paired_rows,
    pct,
    shipped_section,
)
from seagul_learn.experiment.statistics import (
    method_statistics,
    nanmedian,
    paired_success_comparison,
    paired_test,
    paired_wilcoxon,
    success_rate,
)
from seagul_learn.shipped import shipped_network

# The names of the single-module experiment.py, kept for code that imported them from here.
_train_one = train_one
_success_rate = success_rate
_nanmedian = nanmedian
_pct = pct
_other_envs_section = other_envs_section

__all__ = [
    "BASELINE_METHOD",
    "CLOSED_LOOP_COLUMNS",
    "METHODS",
    "METHOD_LABELS",
    "METHOD_NAMES",
    "METRICS",
    "OWNED_TRAIN_FIELDS",
    "PAPER_METHODS",
    "REFERENCE_METHOD",
    "SB3_ALGOS",
    "SHIPPED_COLUMNS",
    "SHIPPED_LABEL",
    "SHIPPED_METHOD",
    "Experiment",
    "ExperimentConfig",
    "LearnedPolicy",
    "PairedComparison",
    "Preset",
    "Task",
    "_clashing",
    "_fine_pct",
    "_ms",
    "_slug",
    "_tail_multiple",
    "atomic_write_text",
    "available_tasks",
    "closed_loop_headline",
    "comparison_intro",
    "comparison_rows",
    "comparison_title",
    "deployment_options",
    "evaluate_snapshot",
    "experiment_sections",
    "final_metric",
    "learning_headline",
    "make_task",
    "method_label",
    "method_overrides",
    "method_rows",
    "method_statistics",
    "network_spec",
    "paired_comparison",
    "paired_rows",
    "paired_success_comparison",
    "paired_test",
    "paired_wilcoxon",
    "plot_curves_with_band",
    "plot_success_vs_solves",
    "policy_label",
    "recipe_fields",
    "recipe_schedule",
    "reference_method",
    "resolve_task",
    "shipped_network",
    "shipped_section",
    "success_curve",
    "success_fields",
    "task_preset",
    "train_one",
    "train_runs",
    "versus_key",
]


def __getattr__(name: str) -> Any:
    """``PRESETS``: a deprecated name-keyed view (task -> preset name -> :class:`Preset`) of the built-in tasks'
    presets (:func:`~seagul_learn.experiment.config.builtin_presets`)."""
    if name == "PRESETS":
        import warnings

        warnings.warn(
            "seagul_learn.experiment.PRESETS is deprecated; the presets live on the task: task_preset(task, name)",
            DeprecationWarning,
            stacklevel=2,
        )
        return builtin_presets()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
