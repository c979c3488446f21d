"""The text of the ``seagul reproduce`` report (``report.md``/``report.html``, written by
:func:`seagul_learn.report.write_report`): its sections in order (:func:`experiment_sections`), each built from the
stored results of a stage, so a resumed run writes the same report.

The shipped controller first (:func:`shipped_section`), then the equal-budget comparison of the learning methods
(:func:`comparison_title`, :func:`comparison_intro`, the headlines, the tables of :func:`comparison_rows`,
:func:`method_rows` and :func:`paired_rows`), the other simulators, solver failures, settings, timings and versions.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict
from typing import Any

import numpy as np

from seagul_envs import Task, resolve_task
from seagul_learn.comparison import METRICS, PairedComparison
from seagul_learn.experiment.config import (
    BASELINE_METHOD,
    REFERENCE_METHOD,
    Preset,
    method_label,
    reference_method,
    versus_key,
)
from seagul_learn.experiment.methods import METHODS, SHIPPED_METHOD

# ----------------------------------------------------------------------------------------------------- report
CLOSED_LOOP_COLUMNS = (
    "policy", "episodes", "success_rate", "median_final_distance", "mean_cost", "crashes",
    "median_step_ms", "p95_step_ms", "fallback_steps",
)  # fmt: skip


def pct(rate: float) -> str:
    return f"{rate:.0%}" if math.isfinite(rate) else "n/a"


SHIPPED_COLUMNS = (
    "controller", "episodes", "success", "median step (ms)", "p95 step (ms)", "median final distance", "mean cost",
    "fallback steps",
)  # fmt: skip
"""Columns of the report's shipped-controller table."""


def _fine_pct(rate: Any) -> str:
    """A rate as a percentage with the decimals it has (0.9925 -> ``99.25%``); n/a when missing."""
    try:
        value = float(rate)
    except (TypeError, ValueError):
        return "n/a"
    return f"{100 * value:.2f}".rstrip("0").rstrip(".") + "%" if math.isfinite(value) else "n/a"


def _ms(value: Any) -> str:
    return f"{float(value):.2f} ms" if value is not None and math.isfinite(float(value)) else "n/a"


def shipped_section(task: Task, result: Mapping[str, Any]) -> Any:
    """The report's first section: the shipped controller in closed loop beside LQR and the full-horizon MPC (the
    result of :meth:`Experiment.evaluate_shipped`), or a line saying the task has none."""
    from seagul_learn.report import Section, Table
    from seagul_learn.shipped import SHIPPED_RESULTS

    title = f"Shipped controller: {task.name} in closed loop"
    block = result.get("block")
    if block is None:
        return Section(
            title,
            [
                f"Task `{task.name}` has no shipped controller (no block with a network for it in "
                f"`{SHIPPED_RESULTS.name}` of the closed-loop benchmark, or not the registered task of that name): "
                "this report is the comparison of the learning methods only."
            ],
        )
    rows = {row["policy"]: row for row in result["rows"]}
    n1, n2 = result["grid"]["shape"]
    bench = block.get("benchmark", {})
    step = f"median {_ms(block['median_ms'])}, p95 {_ms(block['p95_ms'])}"
    jit = bool(block.get("jit"))
    if jit:
        timing = f"Step time of the shipped MPC, compiled as the benchmark deploys it: {step}."
    else:
        timing = (
            "Step time of the shipped MPC with CasADi interpreted (jit off in this run; `--shipped-jit` compiles it, "
            f"about 2 minutes of gcc on a cold cache): {step}"
            + (
                f"; compiled, the benchmark measured {_ms(bench['median_ms'])} / {_ms(bench['p95_ms'])}."
                if "median_ms" in bench and "p95_ms" in bench
                else "."
            )
        )
    headline = (
        f"**The shipped MPC manages to {task.profile.success_phrase(task)} from {pct(block['success_rate'])} of "
        f"the {n1} x {n2} grid starts**; from the same starts LQR {pct(block['lqr_success_rate'])} and the "
        f"full-horizon MPC {pct(block['full_horizon_success_rate'])}. {timing}"
    )
    source = bench_text = ""
    if bench:
        heldout = bench.get("heldout_success_rate")
        bench_text = (
            f" It was trained with the task's recipe (`{bench.get('method', 'shipped')}`, "
            f"{int(bench.get('budget', 0)):,} solves) and measured by the benchmark at "
            f"{_fine_pct(bench.get('success_rate'))} of a {bench.get('grid', '?')} grid"
            + (f" and {_fine_pct(heldout)} of {bench.get('heldout_starts', '?')} held-out starts" if heldout else "")
            + "; those are the benchmark's figures, the table below is this run's."
        )
        source = f" (`benchmarks/results/{SHIPPED_RESULTS.name}`, its `{task.name}` block)"
    deployment = (
        f"The controller: {result['deployment']}, deployed as the closed-loop benchmark's results say{source}, "
        f"{'compiled' if jit else 'with jit off'}.{bench_text} Starts: the report's {n1} x {n2} reference grid over "
        f"({', '.join(result['grid']['dims'])}), where the full-horizon MPC (it solves the whole problem at every "
        "step, so it runs on the coarser grid only) is evaluated for the comparison below too. Success: "
        f"{task.profile.describe_success(task)}."
    )
    table = Table(
        list(SHIPPED_COLUMNS),
        [
            [
                name,
                row["episodes"],
                pct(row["success_rate"]),
                row["median_step_ms"],
                row["p95_step_ms"],
                row["median_final_distance"],
                row["mean_cost"],
                row["fallback_steps"],
            ]
            for name, row in rows.items()
        ],
    )
    animation = result["animation"]
    outcome = ", ".join(
        f"{e['policy']} {'succeeds' if e['success'] else 'fails'} (cost {e['cost']:.1f})" for e in animation["episodes"]
    )
    start = ", ".join(f"{name} = {value:.3g}" for name, value in zip(task.state_names, animation["start"], strict=True))
    caption = f"The shipped MPC and LQR from the hard corner of X0 ({start}), in real time: {outcome}."
    return Section(title, [headline, deployment], [table], [(animation["path"], caption)])


def comparison_title(preset: str, budget: int, seeds: int, shipped: bool = False) -> str:
    """Heading of the report's part that compares the learning methods: the samplers, not the shipped recipe, unless
    ``shipped`` (the run trains the task's recipe as one of its methods)."""
    size = "Quick equal-budget" if preset == "quick" else "Equal-budget"
    if shipped:
        return f"{size} comparison with the shipped recipe ({budget} solves per network, {seeds} seeds)"
    return f"{size} comparison of the samplers ({budget} solves per network, {seeds} seeds): not the shipped recipe"


def comparison_intro(task: Task, preset: Preset, deployment: Mapping[str, Any] | None = None) -> str:
    """What the comparison measures and how it differs from the shipped controller. ``deployment``: the
    ``LimitedLookaheadMPC`` options of the networks (default: the paper presets', IPOPT and the ``lqr`` guard)."""
    from seagul_learn.experiment.methods import recipe_fields

    names = ", ".join(method_label(m) for m in preset.methods)
    options = dict(deployment or {"solver": "ipopt", "trust_region": "lqr"})
    deployed = f"{preset.mpc_horizon}-step MPC" + (" with IPOPT" if options.get("solver") == "ipopt" else "")
    deployed += f" and the `{options.get('trust_region', 'lqr')}` guard"
    if float(options.get("goal_blend", 0.0)) > 0:
        deployed += f" (goal blend {float(options['goal_blend']):g})"
    if SHIPPED_METHOD in preset.methods:
        return (
            f"Everything below compares the ways of learning the value function ({names}) at the task's recipe's "
            f"budget: {preset.budget} solves per network over {preset.seeds} paired seeds, every method with the "
            f"recipe's network and label settings, each network deployed in a {deployed}, as the closed-loop "
            "benchmark measures the recipe. `shipped-recipe` is the task's recipe (`TrainConfig.recipe`) trained "
            "here from scratch, not the shipped network of the first section."
        )
    recipe = recipe_fields(task)
    shipped = ""
    if "budget" in recipe:
        hidden = recipe.get("hidden")
        shipped = (
            " The shipped network comes from the task's recipe (`TrainConfig.recipe`: "
            f"{int(recipe['budget']):,} solves, `{recipe.get('sampler', 'uniform')}` sampler"
            + (f", hidden layers {tuple(hidden)}" if hidden else "")
            + "); these networks are the library's default size, trained on the preset's schedule."
        )
    return (
        f"Everything below compares the ways of learning the value function ({names}) at one small, equal budget: "
        f"{preset.budget} solves per network over {preset.seeds} paired seeds, each network deployed in a "
        f"{deployed}. It ranks the samplers against each other at this budget; it does not measure the shipped "
        f"controller above.{shipped}"
    )


def learning_headline(learning: Mapping[str, Any], methods: Sequence[str], budget: int, seeds: int) -> str:
    """One paragraph: each method's validation error relative to the uniform baseline, on both metrics."""
    parts = []
    for metric in METRICS:
        what = "at the starts (`mse_initial`)" if metric == "mse_initial" else f"over every per-knot label (`{metric}`)"
        items = []
        for m in methods:
            if m == BASELINE_METHOD:
                continue
            c = PairedComparison(**learning[metric]["vs_uniform"][m])
            items.append(
                f"{method_label(m)} **{c.ratio_median:.2f}x** (better on {c.win_fraction:.0%} of seeds, Wilcoxon "
                f"p = {c.p_value:.3g})"
            )
        parts.append(f"{what}: " + ", ".join(items))
    return (
        f"At {budget} solves per network over {seeds} paired seeds, validation error relative to the uniform "
        "baseline (median of per-seed ratios) " + "; ".join(parts) + "."
    )


def closed_loop_headline(
    task: Task | str, methods: Mapping[str, Mapping[str, Any]], baselines: Mapping[str, float], seeds: int
) -> str:
    """One paragraph: each method's closed-loop success (median over seeds with the range), query error, baselines
    (what success means comes from the task's ``profile.success_phrase``)."""
    task = resolve_task(task)
    what = task.profile.success_phrase(task)
    rates = ", ".join(
        f"{s['policy']} **{pct(s['success_median'])}** ({pct(s['success_min'])}-{pct(s['success_max'])})"
        for s in methods.values()
    )
    others = ", ".join(f"{name} {pct(rate)}" for name, rate in baselines.items())
    errors = ", ".join(
        f"{s['label']} {s['query_error']['median']:.3g} (p95 {s['query_error']['p95']:.3g})" for s in methods.values()
    )
    return (
        f"Closed loop: fraction of grid starts from which each controller manages to {what}, median over {seeds} "
        f"seeds (range): {rates}; {others} (the full-horizon MPC on the reference grid). Planner-query error "
        f"|Vhat - V| at the MPC's planned terminal states (median over seeds): {errors}."
    )


def method_rows(methods: Mapping[str, Mapping[str, Any]], learning: Mapping[str, Any]) -> list[list[Any]]:
    """Report rows: method, grid success median, q25-q75, per seed, held-out success median (n/a in a run without
    held-out starts), query error median and p95, validation MSE median."""
    rows = []
    for m, s in methods.items():
        rows.append(
            [
                s["policy"],
                pct(s["success_median"]),
                f"{pct(s['success_q25'])}-{pct(s['success_q75'])}",
                ", ".join(pct(v) for v in s["success"]),
                pct(s.get("heldout_success_rate", math.nan)),
                float(s["query_error"]["median"]),
                float(s["query_error"]["p95"]),
                float(np.median(learning["mse_all_knots"][m])),
            ]
        )
    return rows


def paired_rows(methods: Mapping[str, Mapping[str, Any]], reference: str | None = "closed-loop") -> list[list[Any]]:
    """Report rows of the paired success tests against the ``reference`` method (``closed-loop``, or ``shipped`` in
    a run without it: :func:`~seagul_learn.experiment.config.reference_method`)."""
    if reference is None or reference not in methods:
        return []
    rows = []
    for s in methods.values():
        c = s.get(versus_key(reference))
        if c is not None:
            vs = methods[reference]["policy"]
            rows.append([s["policy"], vs, f"{c['median_difference']:+.0%}", c["wins"], c["losses"], c["p_value"]])
    return rows


def comparison_rows(learning: Mapping[str, Any], methods: Sequence[str]) -> list[list[Any]]:
    """Report table rows per metric and method: medians of the method and the baseline, ratio, wins, p."""
    rows = []
    for metric in METRICS:
        block = learning[metric]
        for m in methods:
            if m == BASELINE_METHOD:
                continue
            c = PairedComparison(**block["vs_uniform"][m])
            rows.append(
                [
                    metric,
                    method_label(m),
                    float(np.median(block[m])),
                    float(np.median(block[BASELINE_METHOD])),
                    c.ratio_median,
                    f"{c.win_fraction:.0%}",
                    c.p_value,
                ]
            )
    return rows


def other_envs_section(other: Mapping[str, Any], seeds: int) -> Any:
    """The report's table of every controller's grid success in each simulator of the task."""
    from seagul_learn.report import Section, Table

    envs = list(other["envs"])
    rows = [[name, *(pct(row.get(e, math.nan)) for e in envs)] for name, row in other["rows"].items()]
    return Section(
        "Other simulators",
        [
            f"The same controllers from the same {other['grid_points']} x {other['grid_points']} grid starts, "
            f"simulated in each env of the task: `{envs[0]}` (the task's own, where they were trained and "
            "evaluated above) and " + ", ".join(f"`{e}`" for e in envs[1:]) + ". Learned methods: the median "
            f"over their {seeds} seeds' final networks. A controller that transfers keeps its success; the "
            "difference between the columns is the model mismatch of the simulators (for the MuJoCo acrobot: "
            "MuJoCo's RK4 integration of the same MJCF dynamics)."
        ],
        [Table(["controller", *[f"success in {e}" for e in envs]], rows)],
        level=3,
    )


def experiment_sections(
    experiment: Any,
    learning: Mapping[str, Any],
    closed_loop: Mapping[str, Any],
    shipped: Mapping[str, Any] | None = None,
) -> list[Any]:
    """The sections of the report of ``experiment`` (a :class:`~seagul_learn.experiment.pipeline.Experiment`) from
    its stages' results: the shipped controller (:meth:`~seagul_learn.experiment.pipeline.Experiment.evaluate_shipped`)
    first, then the equal-budget comparison of the learning methods with its figures and tables, then settings,
    timings and versions."""
    from seagul_learn.report import Section, Table, library_versions, machine_description

    p, config = experiment.preset, experiment.config
    validation = json.loads((experiment.out / "validation.json").read_text())
    methods = closed_loop["methods"]
    reference = reference_method(p.methods)
    shown = set(closed_loop["report_policies"])  # the per-budget rows are in closed_loop/summary.json
    final_rows = [row for row in closed_loop["rows"] if row["policy"] in shown]
    names = ", ".join(f"{method_label(m)} (`{m}`)" for m in p.methods)
    sections = [
        shipped_section(experiment.task, shipped or {"block": None}),
        Section(
            comparison_title(experiment.config.preset, p.budget, p.seeds, shipped=SHIPPED_METHOD in p.methods),
            [comparison_intro(experiment.task, p, dict(experiment.deployment()))],
        ),
        Section(
            "Summary",
            [
                learning_headline(learning, p.methods, p.budget, p.seeds),
                closed_loop_headline(experiment.task, methods, closed_loop["baselines"], p.seeds),
            ],
            level=3,
        ),
        Section(
            "Value-function learning (paper Fig. 1 / Fig. 3 left)",
            [
                f"Methods: {names}. Every method of a seed starts from identical network parameters (pretrained "
                "on the same random solves), spends the same number of solves and takes the same number of "
                f"training steps ({learning['train_steps']} after pretraining); adversarial chains start from the "
                "uniform baseline's starts; the closed-loop method solves tail problems at the deployed MPC's "
                "planned terminal states (with Sobolev training). Validation: "
                f"{validation['solves']} solves ({validation['failures']} failed and are excluded).",
            ],
            [
                Table(
                    [
                        "metric",
                        "method",
                        "method (median)",
                        "uniform (median)",
                        "ratio (median per seed)",
                        "method wins",
                        "Wilcoxon p",
                    ],
                    comparison_rows(learning, p.methods),
                )
            ],
            [("validation_curves.png", "Validation MSE vs solves: median and 25-75 % band over seeds")],
            level=3,
        ),
        Section(
            "Closed loop (paper Fig. 2 / Fig. 3 centre / Fig. 4)",
            [
                f"Limited-lookahead MPC with {p.mpc_horizon} steps and each network as terminal cost, for every "
                f"seed of every method, next to clipped LQR"
                + "".join(f", {label}" for label, _, _ in experiment.config.sb3_policies())
                + " and the full-horizon MPC (on a coarser reference grid: it solves the whole problem at every "
                "step; every final network runs there too). Success: fraction of grid starts "
                f"({experiment.task.profile.describe_success(experiment.task)}) at "
                f"{p.budget} solves per network, median and quartiles over {p.seeds} seeds. Held-out success: "
                f"fraction of {p.heldout_starts} starts drawn uniformly from X0 with the closed-loop benchmark's "
                "fixed seed (no training stream draws with it), of each final network (median over seeds). "
                "Query error: "
                f"`|Vhat - V|` at {p.query_samples} of the final MPC's planned terminal states per seed, "
                "re-solved as tail problems (median and p95 per seed, then the median over seeds).",
                f"Paired tests against the {method_label(reference or REFERENCE_METHOD)} method: per-seed "
                "differences of the success rate (Wilcoxon signed-rank; n/a with fewer than 2 seeds or all "
                "differences 0).",
            ],
            [
                Table(
                    [
                        "method",
                        "success median",
                        "q25-q75",
                        "per seed",
                        "held-out success median",
                        "query error median",
                        "query error p95",
                        "validation mse_all_knots median",
                    ],
                    method_rows(methods, learning),
                ),
                Table(
                    ["method", "vs", "median difference", "wins", "losses", "Wilcoxon p"],
                    paired_rows(methods, reference),
                ),
                Table(
                    list(CLOSED_LOOP_COLUMNS),
                    [[row.get(c, "") for c in CLOSED_LOOP_COLUMNS] for row in final_rows],
                ),
            ],
            closed_loop["figures"],
            level=3,
        ),
        *([other_envs_section(closed_loop["other_envs"], p.seeds)] if "other_envs" in closed_loop else []),
        Section(
            "Solver failures",
            [
                "Failed training solves (counted against the budget, never trained on): "
                + ", ".join(f"{method_label(m)} {learning['failures'][m]}" for m in p.methods)
                + "."
            ],
            level=3,
        ),
        Section(
            "Settings",
            [
                f"Task `{experiment.task.name}`, preset `{config.preset}`, workers {config.workers}, "
                f"backend `{config.backend}`, shipped MPC compiled: {config.shipped_jit}. Run "
                f"directory: `{experiment.out}`. TrainConfig overrides of the "
                "methods (`METHODS`; the preset's `train_overrides` below come on top): "
                + "; ".join(
                    f"`{m}`: "
                    + (
                        "the task's recipe, `TrainConfig.recipe(task, 'shipped')`"
                        if m == SHIPPED_METHOD
                        else f"{METHODS[m]}"
                    )
                    for m in p.methods
                )
                + "."
            ],
            [Table(["setting", "value"], [[k, v] for k, v in asdict(p).items()])],
        ),
        Section(
            "Timings",
            [f"Machine: {machine_description()}."],
            [Table(["stage", "wall time (s)"], [[k, round(v, 1)] for k, v in experiment.timings.items()])],
        ),
        Section("Library versions", tables=[Table(["library", "version"], list(library_versions().items()))]),
    ]
    return sections
