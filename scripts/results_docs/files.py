"""The index of the result files: what each current file holds and the command that reproduces it, and the archive
of the superseded ones."""

from __future__ import annotations

import json
from pathlib import Path

from .common import ARCHIVE, GENERATED, RESULTS, pct, table

ROBUST_COMMAND = (
    "python benchmarks/bench_robust.py --workers 2 --ship --update benchmarks/results/param_adversary.json"
)
"""The command of the robust MPC's block of ``param_adversary.json`` (per task: :data:`ROBUST_TASK_FLAGS`)."""
ROBUST_TASK_FLAGS = {"acrobot": "", "glider": " --tasks glider"}
"""Each task's flags of ``ROBUST_COMMAND`` (the acrobot's are the defaults)."""

#: Current result files: path under benchmarks/results -> (what it holds, the command that reproduces it).
CURRENT: dict[str, tuple[str, str]] = {
    "controllers_acrobot.json": (
        "every acrobot controller on the 20 x 20 grid and 100 held-out starts",
        "python benchmarks/bench_controllers.py --task acrobot",
    ),
    "controllers_acrobot_mujoco.json": (
        "the same controllers in the MuJoCo acrobot",
        "python benchmarks/bench_controllers.py --task acrobot --env SeagulAcrobotMujoco-v0",
    ),
    "controllers_glider.json": (
        "every glider controller on the 6 x 6 grid and 100 held-out starts",
        "python benchmarks/bench_controllers.py --task glider",
    ),
    "closed_loop.json": (
        "closed-loop success per solve of every learning method (median of seeds per budget), the shipped "
        "method's block per task (network, deployment, step time, planner-query error); aggregated from the "
        "per-seed folders below by `bench_closed_loop.py --aggregate` with one `--compare` per method (the "
        "commands in full: docs/experiments/closed-loop.md)",
        "",
    ),
    "closed_loop_b1000_rest/": (
        "per-seed evaluations of the shipped acrobot recipe (closed-loop+rest-1000) and its selection logs",
        "python benchmarks/bench_closed_loop.py --tasks acrobot --methods closed-loop+rest-1000 --budgets 1000 "
        "--seed-list 0,1,2,3,4",
    ),
    "closed_loop_b2000_rest/": (
        "per-seed evaluations of the same recipe at 2,000 solves (closed-loop+rest-2000)",
        "python benchmarks/bench_closed_loop.py --tasks acrobot --methods closed-loop+rest --budgets 2000 "
        "--seed-list 0,1,2,3,4",
    ),
    "closed_loop_others/": (
        "per-seed evaluations of the paper's samplers (uniform, adversarial, each with and without Sobolev) on the "
        "acrobot at 100-2,000 solves",
        "python benchmarks/bench_closed_loop.py --tasks acrobot --methods uniform,adversarial,uniform+sobolev,"
        "adversarial+sobolev --budgets 100,300,1000,2000 --seed-list 0,1,2,3,4",
    ),
    "closed_loop_glider/": (
        "the glider's shipped method (keep-best), its last-network variant to 5,000 solves, the paper's samplers "
        "to 5,000 solves, and the full-horizon evaluation (commands: docs/experiments/closed-loop.md)",
        "",
    ),
    "mpc_solvers_acrobot.json": (
        "the acrobot lookahead on the condensed solver (with and without extra starts) against fatrop",
        "python benchmarks/bench_mpc_solvers.py",
    ),
    "parallel_speedup.json": (
        "parallel solves on 1 and 2 workers, local and Ray",
        "python benchmarks/bench_trajopt.py --parallel-only --n 200 --workers 2 --repeats 3",
    ),
    "param_adversary.json": (
        "learning over robots drawn from Theta (acrobot's samplers); per task, the `shipped` and `robust` blocks: the "
        "shipped robust MPC, its baselines, the box-size sweep and the estimator (`" + ROBUST_COMMAND + "`, with "
        "`" + ROBUST_TASK_FLAGS["glider"].strip() + "` for the glider)",
        "python benchmarks/bench_param_adversary.py --workers 1 --closed-loop --update "
        "benchmarks/results/param_adversary.json",
    ),
    "robust_deployment.json": (
        "the shipped robust MPC's deployment settings (lookahead, iterations, guard, the estimate's prior and box, "
        "the robot known) for every seed's network, on validation starts x robots",
        "python benchmarks/bench_robust_deployment.py --json benchmarks/results/robust_deployment.json",
    ),
    "rl_baselines.json": (
        "SB3 PPO and SAC set up by the book, 5 seeds per task: validation curves, the selected models on the grid "
        "and the held-out starts, the shipped model; the acrobot PPO sweep (`sweep`)",
        "python benchmarks/bench_rl_baselines.py --json benchmarks/results/rl_baselines.json",
    ),
    "rl_near_goal_acrobot.json": (
        "why the acrobot's PPO misses the 0.05 rule: its closest approach to upright per grid episode, its final "
        "distance and speed, and PPO handing over to LQR near upright",
        "python benchmarks/bench_rl_near_goal.py --json benchmarks/results/rl_near_goal_acrobot.json",
    ),
    "baselines.json": (
        "every controller on the same starts: learned and quadratic-terminal MPC at N = 3-20, do-mpc, full "
        "horizon, LQR, PPO, SAC; success at 0.05-0.5, final-state distribution, step times",
        "python benchmarks/bench_baselines.py --json benchmarks/results/baselines.json",
    ),
    "sample_efficiency_acrobot_20seeds.json": (
        "the paper's metric: validation error of SEAGuL against uniform sampling, 20 paired seeds, 5,000 steps",
        "python benchmarks/bench_sample_efficiency.py --tasks acrobot --seeds 20 --extra adversarial-mix "
        "adversarial-short adversarial-stop adversarial-stopmix",
    ),
    "sample_efficiency_acrobot_10seeds_15000steps.json": (
        "the same with 15,000 training steps, 10 seeds",
        "python benchmarks/bench_sample_efficiency.py --tasks acrobot --seeds 10 --train-steps-per-round 1500 "
        "--extra adversarial-stop",
    ),
    "sample_efficiency_glider_5seeds_sobolev1.json": (
        "the glider's validation errors, 5 seeds, Sobolev weight 1",
        "python benchmarks/bench_sample_efficiency.py --tasks glider --seeds 5 --extra adversarial-notau "
        "adversarial-mix adversarial-short adversarial-stop",
    ),
    "sample_efficiency_glider_5seeds_sobolev0.1.json": (
        "the glider's validation errors, 5 seeds, Sobolev weight 0.1",
        "python benchmarks/bench_sample_efficiency.py --tasks glider --seeds 5 --sobolev-weight 0.1",
    ),
    "dmc.json": (
        "the DeepMind Control Suite swing-ups scored by dm_control's own reward on its episodes (reset seeds 0-9): "
        "the classical swing-ups (energy shaping, Astrom-Furuta, Spong), zero and random actions, seagul's LQR",
        "python benchmarks/bench_dmc.py --json benchmarks/results/dmc.json",
    ),
    "dmc_published.json": (
        "published DeepMind Control Suite swing-up scores at a stated budget, each computed from its authors' "
        "released per-seed results or read off their published table (source repository and commit per entry)",
        "python benchmarks/dmc_published.py",
    ),
    "dmc_reference.json": (
        "the full-horizon reference on the four swing-ups (the true model, the whole episode by multiple shooting "
        "through MuJoCo's step, re-solved every 25 control steps), reset seeds 0-9: scores, search and re-solve "
        "times, failed re-solves",
        "python benchmarks/bench_dmc_reference.py",
    ),
    "dmc_optimum.json": (
        "the pendulum's optimum: value iteration on grids of its state (three refinements) with MuJoCo's step and "
        "dm_control's reward, its greedy controller scored on reset seeds 0-9 and 0-99, and the energy swing-up on "
        "0-99",
        "python benchmarks/bench_dmc_optimum.py --json benchmarks/results/dmc_optimum.json",
    ),
    "dmc_learned.json": (
        "the learned short-horizon MPC on the suite's pendulum and cart-pole: five networks per task scored on "
        "reset seeds 0-9 (the pendulum's also on 0-99), the tuning lines each setting was chosen by, and the "
        "earlier recipes' rows under variants",
        "python benchmarks/bench_dmc_learned.py evaluate NETWORKS --domain DOMAIN --solves ... --seeds 0-9 "
        "--json benchmarks/results/dmc_learned.json",
    ),
    "dmc_rl.json": (
        "SB3 PPO (CleanRL's settings) on the suite's swing-ups: per task, each training seed's model selected on "
        "validation episodes (reset seeds 1000+) and scored on reset seeds 0-9, with the validation curves",
        "python benchmarks/bench_dmc_rl.py --tasks TASK --algos PPO --json benchmarks/results/dmc_rl.json",
    ),
    "networks/": ("value networks: the shipped ones and one representative seed of each compared sampler", ""),
    "models/": ("the shipped SB3 models: PPO and SAC per seagul task, PPO per suite task under `dmc/`", ""),
}


#: Figures drawn by the benchmarks themselves and kept beside their JSON.
CURRENT_FIGURES = (
    "rl_curves_acrobot.png",
    "rl_curves_glider.png",
    "baselines_cdf_acrobot.png",
    "baselines_cdf_glider.png",
    "sample_efficiency_acrobot.png",
    "sample_efficiency_acrobot_15000steps.png",
    "sample_efficiency_glider.png",
    "success_vs_solves_acrobot.png",
    "success_vs_solves_glider.png",
)


#: Superseded results: path under benchmarks/results/archive -> what it was and what replaced it.
ARCHIVED: dict[str, str] = {
    "closed_loop_ensemble_b2000/": (
        "closed-loop sampler with a 3-member refitted ensemble, 2,000 solves, 5 seeds (91.25 % of the grid); "
        "replaced by selection of the refit that flies (closed-loop+select)"
    ),
    "closed_loop_ensemble_b2000_rerun/": (
        "the same recipe retrained from scratch with later code (82.5 % of the grid), and with ensemble "
        "pessimism 0.5 (`pessimism0.5/`): the run-to-run spread is as large as the gap to the target"
    ),
    "closed_loop_select_b2000/": (
        "closed-loop+select with a single-start condensed solver, 2,000 solves (94.5 % of the grid); replaced by "
        "extra starts where the plan's cost rises"
    ),
    "closed_loop_select_rise_b2000/": (
        "closed-loop+select with extra starts where the plan's cost rises (95.75 % of the grid); replaced by "
        "closed-loop+rest (half of the episodes at rest)"
    ),
    "closed_loop_visited_b2000/": (
        "closed-loop sampler with visited-state tails and no selection; the basis of closed-loop+select"
    ),
    "rl_baselines_zoo_defaults.json": (
        "RL baselines with rl-zoo's settings unchanged, before the sweep of rl_sweep_task_cost.json"
    ),
    "rl_curves_acrobot_sac.png": "acrobot SAC curves alone; rl_curves_acrobot.png draws both algorithms",
    "rl_curves_glider_ppo.png": "glider PPO curves alone; rl_curves_glider.png draws both algorithms",
    "networks/": "networks of the superseded recipes and of the non-median seeds of the 2,000-solve recipes",
    "rl_baselines_task_cost.json": (
        "RL baselines on raw observations with the task's trajectory cost as reward (the glider with a perch-miss "
        "penalty), 3 seeds, swept settings: superseded by the learner's view and bounded reward of rl_baselines.json"
    ),
    "rl_sweep_task_cost.json": "the hyperparameter sweep of those runs",
    "rl_glider_early.json": "the glider's RL curves of those runs over their first steps (PPO to 300 k, SAC to 40 k)",
    "rl_curves_acrobot_task_cost.png": "acrobot learning curves of those runs",
    "rl_curves_glider_task_cost.png": "glider learning curves of those runs",
    "rl_curves_glider_early.png": "the glider's early curves of those runs",
    "models_task_cost/": "the models of those runs (PPO and SAC per task, best seed)",
}


def results_index() -> str:
    lines = ["# Benchmark results", "", GENERATED, "",
             "Current result files (read by `scripts/make_results.py` into `docs/results.md` and the README). "
             "Superseded results are in [`archive/`](archive/README.md).", ""]
    rows = []
    for name, (what, command) in CURRENT.items():
        if not (RESULTS / name).exists():
            raise SystemExit(f"make_results: the index names benchmarks/results/{name}, which does not exist")
        rows.append([f"`{name}`", what, f"`{command}`" if command else ""])
    for name in CURRENT_FIGURES:
        if not (RESULTS / name).exists():
            raise SystemExit(f"make_results: the index names benchmarks/results/{name}, which does not exist")
        rows.append([f"`{name}`", "figure drawn by the benchmark beside its JSON", ""])
    lines.append(table(["file", "what", "command"], rows))
    listed = {n.rstrip("/") for n in CURRENT} | set(CURRENT_FIGURES) | {"README.md", "archive"}
    missing = sorted(p.name for p in RESULTS.iterdir() if p.name not in listed)
    if missing:
        raise SystemExit(f"make_results: result files not in the index (add them to CURRENT or archive them): "
                         f"{missing}")
    return "\n".join(lines) + "\n"


def _summary(path: Path) -> str:
    """One line of what a JSON file holds: its success rates where it has them."""
    if path.suffix != ".json":
        return ""
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return "unreadable JSON"
    if not isinstance(data, dict):
        return ""
    found = [f"{k} {pct(v)}" for k, v in data.items() if k.endswith("success_rate") and isinstance(v, int | float)]
    return ", ".join(found[:3])


def archive_index() -> str:
    lines = ["# Archived results", "", GENERATED, "",
             "Results of recipes and settings that were superseded, kept because the experiment log "
             "(`docs/experiments/`) quotes them. Nothing current reads them.", ""]
    for name, what in ARCHIVED.items():
        path = ARCHIVE / name
        if not path.exists():
            raise SystemExit(f"make_results: the archive index names archive/{name}, which does not exist")
        lines += [f"## `{name}`", "", what, ""]
        if path.is_dir():
            rows = [[f"`{p.relative_to(path)}`", _summary(p)] for p in sorted(path.rglob("*")) if p.is_file()]
            lines += [table(["file", "summary"], rows), ""]
    listed = {n.rstrip("/") for n in ARCHIVED} | {"README.md"}
    missing = sorted(p.name for p in ARCHIVE.iterdir() if p.name not in listed)
    if missing:
        raise SystemExit(f"make_results: archived files not in the index: {missing}")
    return "\n".join(lines)
