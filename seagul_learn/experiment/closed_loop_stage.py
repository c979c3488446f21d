"""The closed-loop stage of ``seagul reproduce``, behind ``Experiment.evaluate_closed_loop`` and
``Experiment.evaluate_other_envs`` (:mod:`seagul_learn.experiment.pipeline`): every snapshot network of every (method,
seed) run as the terminal cost of the limited-lookahead MPC on the main start grid, each final network also on the
held-out starts and the coarser reference grid, LQR, the SB3 models and the full-horizon MPC as baselines, the
planner-query error of every final network, the per-method statistics and the figures (:func:`evaluate_closed_loop`);
the final networks and baselines in the other simulators of the task (:func:`evaluate_other_envs`).

Every policy's episodes are stored as one table as soon as they are complete (:func:`stored_episodes`,
:func:`snapshot_episodes`), and every query error as one file (:func:`query_error`); a resumed run reads them back and
evaluates only what is missing, so it ends with the numbers of an uninterrupted one. The functions take the
:class:`~seagul_learn.experiment.pipeline.Experiment` whose run directory, task, configuration and preset they use.

What the stage runs on (the evaluation, the report's tables and figures, the solvers and the value network for the
query errors) is imported inside the functions, as in the rest of the pipeline: importing
:mod:`seagul_learn.experiment` (``seagul reproduce --help``, reading a run's configuration) loads neither torch nor
the report and solver modules.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import asdict, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from seagul_learn.dataset import atomic_write_text
from seagul_learn.experiment.config import _slug, method_label, policy_label, reference_method, versus_key
from seagul_learn.experiment.figures import plot_success_vs_solves
from seagul_learn.experiment.runs import evaluate_snapshot
from seagul_learn.experiment.statistics import (
    method_statistics,
    nanmedian,
    paired_success_comparison,
    success_rate,
)

if TYPE_CHECKING:  # the pipeline imports this module
    from seagul_learn.experiment.pipeline import Experiment, LearnedPolicy


def stored_episodes(
    experiment: Experiment,
    spec: Any,
    starts: np.ndarray,
    record: bool,
    record_queries: bool = False,
    env_id: str | None = None,
    folder: Path | None = None,
) -> list[Any]:
    """One policy's episodes (in ``env_id``, else the task's env), from its stored table if an interrupted run
    finished it. Stored in ``folder`` (default ``closed_loop/episodes`` or ``closed_loop/episodes_<env>``) as
    ``<slug of the label>.json``."""
    from seagul_control.evaluation import EpisodeResult, evaluate

    if folder is None:
        folder = experiment.out / "closed_loop" / ("episodes" if env_id is None else f"episodes_{_slug(env_id)}")
    path = folder / f"{_slug(spec.name)}.json"
    if path.is_file():
        return [EpisodeResult(**row) for row in json.loads(path.read_text())]
    results = evaluate(
        experiment.task,
        [spec],
        starts,
        experiment.config.workers,
        experiment.config.progress,
        record,
        record_queries=record_queries,
        env_id=env_id,
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, json.dumps([asdict(r) for r in results], allow_nan=True))
    return results


def snapshot_episodes(
    experiment: Experiment, policy: LearnedPolicy, starts: np.ndarray, record: bool
) -> tuple[list[Any], list[Any]]:
    """``(grid episodes, held-out episodes)`` of one snapshot network: the grid ``starts`` and, for a final
    network, the preset's ``heldout_starts`` held-out starts, through
    :func:`~seagul_learn.experiment.runs.evaluate_snapshot` (the closed-loop benchmark's evaluation). Each set is
    stored as its own table (``closed_loop/episodes/<slug>.json``, ``closed_loop/episodes_heldout/<slug>.json``)
    and read back by a resumed run, which evaluates only what is missing (e.g. the held-out starts of a run
    stored before they existed). A final network records its planner queries (:func:`query_error`)."""
    from seagul_control.evaluation import EpisodeResult

    n_held = experiment.preset.heldout_starts if policy.final else 0
    name = f"{_slug(policy.spec.name)}.json"
    paths = (
        experiment.out / "closed_loop" / "episodes" / name,
        experiment.out / "closed_loop" / "episodes_heldout" / name,
    )
    stored = [[EpisodeResult(**row) for row in json.loads(p.read_text())] if p.is_file() else None for p in paths]
    if n_held == 0:
        stored[1] = []
    if stored[0] is not None and stored[1] is not None:
        return stored[0], stored[1]
    grid, held = evaluate_snapshot(
        experiment.task,
        policy.spec,
        starts if stored[0] is None else starts[:0],
        n_held if stored[1] is None else np.empty((0, experiment.task.nx)),
        experiment.config.workers,
        experiment.config.progress,
        record,
        record_queries=policy.final,
    )
    for k, new in enumerate((grid, held)):
        if stored[k] is None:
            paths[k].parent.mkdir(parents=True, exist_ok=True)
            atomic_write_text(paths[k], json.dumps([asdict(r) for r in new], allow_nan=True))
            stored[k] = new
    return stored[0] or [], stored[1] or []


def query_error(experiment: Experiment, policy: LearnedPolicy, episodes: Sequence[Any]) -> dict[str, Any]:
    """The planner-query error of a final network over its grid episodes' queries (stored when computed)."""
    path = experiment.out / "closed_loop" / "query_errors" / f"{policy.method}-seed{policy.seed}.json"
    if path.is_file():
        return json.loads(path.read_text())
    from seagul_learn.closed_loop import query_errors
    from seagul_learn.solving import CachedBatchSolver, solver_key, trajopt_batch_solver
    from seagul_learn.value_network import ValueNetwork

    queries = np.array([q for e in episodes for q in e.queries], dtype=np.float64).reshape(-1, experiment.task.nx + 1)
    stride = experiment.preset.query_tail_stride
    if stride > 1:
        queries = queries[[_tail_multiple(experiment.task, float(t), stride) for t in queries[:, -1]]]
    solver = CachedBatchSolver(
        trajopt_batch_solver(experiment.task, workers=experiment.config.workers, backend=experiment.config.backend),
        experiment._solver_cache(),
        solver_key(None, experiment.task),
    )
    network = ValueNetwork.load(policy.spec.path)
    # One sampling seed for every network: the sample is a function of the queries only.
    error = query_errors(
        experiment.task, network, queries, solver, num=experiment.preset.query_samples, seed=0
    ).as_dict()
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, json.dumps(error, indent=2, allow_nan=True))
    return error


def evaluate_closed_loop(experiment: Experiment) -> dict[str, Any]:
    """Closed-loop runs of every network and baseline over the start grids, the per-method statistics, figures.

    Writes ``closed_loop/summary.json`` (``policies``: one row per policy and grid; ``methods``: see
    :func:`method_statistics`, with each final network's held-out success; the grids, budgets and the number of
    held-out starts) and ``success_vs_solves.png``.
    """
    from seagul_control.evaluation import start_grid
    from seagul_learn.report import summarize

    p = experiment.preset
    # Tasks with a trajectory figure (the glider, paper Fig. 3 centre) record the seed-0 paths.
    paths_shown = experiment.task.profile.trajectory_plot is not None
    starts, grid = start_grid(experiment.task, p.grid_points)
    ref_starts, ref_grid = start_grid(experiment.task, p.reference_grid_points)
    learned = experiment.learned_policies()
    finals = [lp for lp in learned if lp.final]
    episodes: dict[str, list[Any]] = {}
    heldout: dict[tuple[str, int], list[Any]] = {}
    for lp in learned:
        record = paths_shown and lp.final and lp.seed == 0
        episodes[lp.spec.name], held = snapshot_episodes(experiment, lp, starts, record)
        if lp.final:
            heldout[(lp.method, lp.seed)] = held
    errors = {(lp.method, lp.seed): query_error(experiment, lp, episodes[lp.spec.name]) for lp in finals}
    main_specs, reference_specs = experiment.baseline_specs()
    base_results = [r for spec in main_specs for r in stored_episodes(experiment, spec, starts, paths_shown)]
    ref_results = [r for spec in reference_specs for r in stored_episodes(experiment, spec, ref_starts, paths_shown)]
    # Every final network on the reference grid too, so its success compares with the full-horizon MPC's.
    ref_learned: dict[tuple[str, int], list[Any]] = {}
    for lp in finals:
        spec = replace(lp.spec, label=policy_label(lp.method, lp.seed, reference=True))
        ref_learned[(lp.method, lp.seed)] = stored_episodes(experiment, spec, ref_starts, False)

    main_results = [r for lp in learned for r in episodes[lp.spec.name]] + base_results
    reference_results = ref_results + [r for lp in finals for r in ref_learned[(lp.method, lp.seed)]]
    shown = [r for lp in finals if lp.seed == 0 for r in episodes[lp.spec.name]] + base_results
    shown_ref = ref_results + [r for lp in finals if lp.seed == 0 for r in ref_learned[(lp.method, lp.seed)]]
    main_paths = grid_outputs(experiment, "main", main_results, shown, grid)
    ref_paths = grid_outputs(experiment, "reference", reference_results, shown_ref, ref_grid)
    rows = summarize(experiment.task, main_results) + summarize(experiment.task, reference_results)

    success = {lp: success_rate(episodes[lp.spec.name]) for lp in learned}
    methods = {
        m: method_statistics(
            m,
            {(lp.seed, lp.budget): s for lp, s in success.items() if lp.method == m},
            {s: success_rate(ref_learned[(m, s)]) for s in range(p.seeds)},
            [errors[(m, s)] for s in range(p.seeds)],
            p.seeds,
            p.budgets,
            {s: success_rate(heldout[(m, s)]) for s in range(p.seeds)} if p.heldout_starts else None,
        )
        for m in p.methods
    }
    reference = reference_method(p.methods)
    if reference is not None:
        for m in p.methods:
            if m != reference:
                methods[m][versus_key(reference)] = paired_success_comparison(
                    methods[m]["success"], methods[reference]["success"]
                )
    baselines = {
        name: success_rate([r for r in base_results + ref_results if r.policy == name])
        for name in dict.fromkeys(r.policy for r in base_results + ref_results)
    }
    summary = {
        "methods": methods,
        "baselines": baselines,
        "reference_method": reference,
        "budgets": list(p.budgets),
        "seeds": p.seeds,
        "grid": grid,
        "reference_grid": ref_grid,
        "heldout_starts": p.heldout_starts,
        "policies": rows,
    }
    atomic_write_text(experiment.out / "closed_loop" / "summary.json", json.dumps(summary, indent=2, allow_nan=True))
    n, m = grid["shape"]
    plot_success_vs_solves(
        methods,
        experiment.out / "success_vs_solves.png",
        references={
            f"full-horizon MPC ({ref_grid['shape'][0]} x {ref_grid['shape'][1]} reference grid)": baselines.get(
                "full-horizon MPC", math.nan
            ),
            "LQR": baselines.get("LQR", math.nan),
        },
        title=f"{experiment.task.name}: closed-loop success on the {n} x {m} grid vs solves per network "
        f"(median, 25-75 % band over {p.seeds} seeds)",
    )
    figures = [
        ("success_vs_solves.png", "Grid success vs solves per network: median and 25-75 % band over seeds"),
        (
            str(main_paths["heatmap"].relative_to(experiment.out)),
            experiment.task.profile.heatmap_text(experiment.task, grid),
        ),
        (str(ref_paths["heatmap"].relative_to(experiment.out)), "The same on the coarser reference grid (seed 0)"),
    ]
    figure = experiment.task.profile.trajectory_plot
    if "trajectories" in main_paths and figure is not None:
        figures.append((str(main_paths["trajectories"].relative_to(experiment.out)), figure.caption))
    report_policies = [lp.spec.name for lp in finals] + [r.policy for r in reference_results + base_results]
    return {
        "rows": rows,
        "report_policies": list(dict.fromkeys(report_policies)),
        "methods": methods,
        "baselines": baselines,
        "figures": figures,
    }


def evaluate_other_envs(experiment: Experiment) -> dict[str, Any]:
    """Every final network of every seed, LQR and the SB3 models on the main grid in each of ``config.envs``
    (the same starts as in the task's env). Writes ``closed_loop/other_envs.json``: per controller (a method's
    seeds pooled into their median), its success in the task's env and in each other env."""
    from seagul_control.evaluation import start_grid

    starts, _ = start_grid(experiment.task, experiment.preset.grid_points)
    own = experiment.task.profile.env_id or experiment.task.name
    finals = [lp for lp in experiment.learned_policies() if lp.final]
    main_specs, _ = experiment.baseline_specs()
    rows: dict[str, dict[str, Any]] = {}
    for env_id in (None, *experiment.config.envs):
        column = own if env_id is None else env_id
        per_method: dict[str, list[float]] = {}
        for lp in finals:
            rate = success_rate(
                stored_episodes(experiment, lp.spec, starts, False, record_queries=False, env_id=env_id)
            )
            per_method.setdefault(lp.method, []).append(rate)
        for method, rates in per_method.items():
            row = rows.setdefault(f"{method_label(method)} MPC", {"seeds": len(rates)})
            row[column] = nanmedian(rates)
        for spec in main_specs:
            rows.setdefault(spec.name, {"seeds": 1})[column] = success_rate(
                stored_episodes(experiment, spec, starts, False, env_id=env_id)
            )
    result = {"envs": [own, *experiment.config.envs], "grid_points": experiment.preset.grid_points, "rows": rows}
    atomic_write_text(experiment.out / "closed_loop" / "other_envs.json", json.dumps(result, indent=2, allow_nan=True))
    return result


def grid_outputs(
    experiment: Experiment, name: str, results: list[Any], shown: list[Any], grid: dict[str, Any]
) -> dict[str, Path]:
    """Tables of every episode on one grid (queries left out) and the heatmap of the ``shown`` policies."""
    from seagul_learn.report import plot_heatmaps, write_outputs

    out = experiment.out / "closed_loop" / name
    paths = write_outputs(out, experiment.task, [replace(r, queries=[]) for r in results], None, {"grid": grid})
    paths["heatmap"] = plot_heatmaps(experiment.task, shown, grid, out / "heatmap.png")
    return paths


def _tail_multiple(task: Any, tau: float, stride: int) -> bool:
    """Whether the tail problem from time to go ``tau`` has a multiple of ``stride`` intervals."""
    from seagul_learn.closed_loop import snap_tau
    from seagul_learn.solving import tail_horizon

    try:
        k = tail_horizon(task, snap_tau(task, tau))
    except ValueError:
        return False
    return k is None or k % stride == 0
