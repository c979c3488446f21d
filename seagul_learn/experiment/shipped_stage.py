"""The first stage of ``seagul reproduce``: the task's shipped controller (:mod:`seagul_learn.shipped`, the network
the closed-loop benchmark ships, deployed as its block of ``benchmarks/results/closed_loop.json`` says) in closed
loop on the preset's reference grid beside LQR and the full-horizon MPC, and one animation of it beside LQR from the
hard corner of X0 (:func:`seagul_learn.report.hard_start`).
:meth:`~seagul_learn.experiment.pipeline.Experiment.evaluate_shipped` stores the result in ``shipped/shipped.json``;
the report's first section
(:func:`~seagul_learn.experiment.sections.shipped_section`) is written from it.
"""

from __future__ import annotations

from typing import Any

from seagul_learn.experiment.closed_loop_stage import stored_episodes
from seagul_learn.experiment.config import SHIPPED_LABEL
from seagul_learn.shipped import shipped_network


def measure_shipped(experiment: Any) -> dict[str, Any]:
    """The shipped controller's stage of ``experiment`` (a :class:`~seagul_learn.experiment.pipeline.Experiment`):
    ``block`` (the ``experiment.json`` block; None for a task without a shipped controller), ``task``, ``grid``,
    ``rows`` (a :func:`~seagul_learn.report.summarize` row per controller), ``deployment`` and ``animation``. The
    shipped MPC's and LQR's episodes are stored in ``shipped/episodes``; the full-horizon MPC's are the closed-loop
    evaluation's (``closed_loop/episodes``, the same starts)."""
    from seagul_control.evaluation import PolicySpec, build_policy
    from seagul_learn.report import controller_animation, hard_start, summarize

    controller = shipped_network(experiment.task)
    if controller is None:
        return {"block": None, "task": experiment.task.name}
    starts, grid = experiment.shipped_grid()
    folder = experiment.out / "shipped" / "episodes"
    spec = controller.spec(SHIPPED_LABEL, jit=experiment.config.shipped_jit)
    lqr = PolicySpec("lqr", "LQR")
    episodes = [r for policy in (spec, lqr) for r in stored_episodes(experiment, policy, starts, False, folder=folder)]
    paths_shown = experiment.task.profile.trajectory_plot is not None  # as the closed-loop evaluation stores them
    _, reference_specs = experiment.baseline_specs()
    full = [r for s in reference_specs for r in stored_episodes(experiment, s, starts, paths_shown)]
    rows = summarize(experiment.task, episodes + full)
    by = {row["policy"]: row for row in rows}
    ours, full_row = by[SHIPPED_LABEL], by[reference_specs[0].name]
    x0 = hard_start(experiment.task)
    policies = [(SHIPPED_LABEL, build_policy(experiment.task, spec)), ("LQR", build_policy(experiment.task, lqr))]
    _, shown = controller_animation(experiment.task, policies, x0, experiment.out / "shipped" / "shipped_vs_lqr.gif")
    n1, n2 = grid["shape"]
    block = {
        "network": controller.declared,
        "horizon": controller.horizon,
        "success_rate": float(ours["success_rate"]),
        "full_horizon_success_rate": float(full_row["success_rate"]),
        "median_ms": float(ours["median_step_ms"]),
        "p95_ms": float(ours["p95_step_ms"]),
        "lqr_success_rate": float(by["LQR"]["success_rate"]),
        "full_horizon_median_ms": float(full_row["median_step_ms"]),
        "full_horizon_p95_ms": float(full_row["p95_step_ms"]),
        "trust_region": controller.trust_region,
        "goal_blend": controller.goal_blend,
        "jit": bool(experiment.config.shipped_jit),
        "benchmark_jit": controller.jit,
        "grid": f"{n1}x{n2}",
        "starts": len(starts),
        "network_file": str(controller.network),
        "results": "shipped/shipped.json",
        "animation": "shipped/shipped_vs_lqr.gif",
        "benchmark": dict(controller.measured),
        "benchmark_results": str(controller.source),
    }
    return {
        "block": block,
        "task": experiment.task.name,
        "grid": grid,
        "rows": rows,
        "deployment": controller.describe(),
        "animation": {
            "path": block["animation"],
            "start": [float(v) for v in x0],
            "episodes": [
                {"policy": e.policy, "success": bool(e.success), "cost": float(e.cost), "steps": int(e.steps)}
                for e in shown
            ],
        },
    }
