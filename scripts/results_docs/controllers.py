"""The controllers' tables: every controller on the same starts, success per solve, sample efficiency, the baselines
and the horizon sweep, RL, speed."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from .common import count, load, load_sentence, machine_line, ms, pct, table
from .files import CURRENT


def short_name(method: str) -> str:
    """``learned 5-step MPC (uniform, 5 seeds)`` -> ``learned 5-step MPC, paper sampler uniform``; the closed-loop
    recipe's (or the shipped network's) row -> ``learned 5-step MPC, shipped``; other rows keep their name."""
    if not method.startswith("learned") or "(" not in method:
        return method.split(" (")[0]
    inner = method[method.find("(") + 1 : method.rfind(")")].split(",")[0].strip()
    head = method.split(" (")[0]
    return f"{head}, shipped" if inner.startswith(("closed-loop", "shipped")) else f"{head}, paper sampler {inner}"


def _controller_label(method: str) -> str:
    """A table row's name: :func:`short_name`, the shipped MPC in bold, with the rest of the row's parenthesis
    (the recipe and the seeds)."""
    short = short_name(method)
    if short == method.split(" (")[0] or "(" not in method:
        return method
    details = [d.strip() for d in method[method.find("(") + 1 : method.rfind(")")].split(",")]
    if short.endswith(", shipped"):
        details = [d for d in details if d != "shipped network"]
        return f"**{short}**" + (f" ({', '.join(details)})" if details else "")
    return f"{short} ({', '.join(details[1:])})"


def is_rl(row: Mapping[str, Any]) -> bool:
    """A controllers-table row of the earlier RL baselines (raw observations, the task's cost as reward): the current
    ones are in the baselines section, from ``baselines.json``."""
    return str(row["method"]).startswith(("PPO", "SAC"))


def controller_rows(task: str, *, brief: bool) -> list[list[str]]:
    data = load(f"controllers_{task}.json")
    rows = []
    for r in (r for r in data["rows"] if not is_rl(r)):
        label = _controller_label(r["method"])
        cells = [label, count(r.get("nlp_solves")), count(r.get("env_steps")), pct(r["grid_success"]),
                 pct(r["heldout_success"]), f"{ms(r['median_ms'])} / {ms(r['p95_ms'])}"]
        if not brief:
            cells.append(f"`{r['source']}`")
        rows.append(cells)
    return rows


CONTROLLER_HEADER = ["controller", "NLP solves", "env steps", "grid success", "held-out success",
                     "step ms (median / p95)"]
BASELINE_HEADER = ["controller", "N", "NLP solves", "env steps", "grid success", "held-out success", "@ 0.1",
                   "@ 0.2", "@ 0.5", "median final distance", "step ms (median / p95)"]
KIND_LABEL = {"learned-mpc": "learned", "quadratic-mpc": "quadratic terminal cost", "do-mpc": "do-mpc (IPOPT)"}


def baseline_label(row: Mapping[str, Any]) -> str:
    """A row's name in the tables: the shipped learned MPC in bold, RL rows with their seeds."""
    if row["kind"] in ("ppo", "sac"):
        return f"{row['kind'].upper()} ({row['seeds']} seeds, validation-selected)"
    if row["kind"] == "learned-mpc":
        label = f"learned {row['horizon']}-step MPC"
        return f"**{label}, shipped**" if row["horizon"] == row.get("trained_for_horizon") else label
    return row["controller"]


def baseline_rows(task: str) -> list[list[str]]:
    data = load("baselines.json")[task]
    rows = []
    for r in data["rows"]:
        at = r["success_at"]
        rows.append([baseline_label(r), r["horizon"] or "-", count(r["solves"]), count(r["env_steps"]),
                     pct(r["success"]), pct(r["heldout_success"]), pct(at["0.1"]), pct(at["0.2"]), pct(at["0.5"]),
                     f"{r['median_final_distance']:.3g}", f"{ms(r['median_ms'])} / {ms(r['p95_ms'])}"])
    return rows


def _first_horizon(rows: Sequence[Mapping[str, Any]], kind: str, level: float) -> Mapping[str, Any] | None:
    """The row of ``kind`` with the shortest horizon whose grid success reaches ``level``."""
    found = sorted((r for r in rows if r["kind"] == kind and r["success"] >= level), key=lambda r: r["horizon"])
    return found[0] if found else None


def _best(rows: Sequence[Mapping[str, Any]], kind: str) -> Mapping[str, Any] | None:
    found = [r for r in rows if r["kind"] == kind]
    return max(found, key=lambda r: r["success"]) if found else None


def horizon_summary(task: str) -> str:
    """What the learned value is worth on ``task``, in one generated paragraph: the shortest horizon at which each
    MPC comes within 5 points of the full horizon's grid success, with its step time; else its best."""
    rows = load("baselines.json")[task]["rows"]
    full = next(r for r in rows if r["kind"] == "full-horizon")
    level = full["success"] - 0.05
    parts = []
    for kind in ("learned-mpc", "quadratic-mpc", "do-mpc"):
        hit = _first_horizon(rows, kind, level)
        best = _best(rows, kind)
        if best is None:
            continue
        name = KIND_LABEL[kind]
        if hit is not None:
            parts.append(f"{name}: N = {hit['horizon']} ({pct(hit['success'])}, {ms(hit['median_ms'])} / "
                         f"{ms(hit['p95_ms'])} ms)")
        else:
            horizons = sorted(r["horizon"] for r in rows if r["kind"] == kind)
            best_text = (f"best {pct(best['success'])} at N = {best['horizon']}" if best["success"] > 0
                         else "0 % at every horizon")
            parts.append(f"{name}: no horizon up to {horizons[-1]} ({best_text})")
    ratios = []
    for peer in (r for r in rows if r["kind"] == "do-mpc"):
        ours = next((r for r in rows if r["kind"] == "quadratic-mpc" and r["horizon"] == peer["horizon"]), None)
        if ours is not None and abs(ours["success"] - peer["success"]) <= 0.05 and ours["success"] > 0:
            ratios.append(f"{peer['median_ms'] / ours['median_ms']:.1f}x at N = {peer['horizon']}")
    peer_text = (f" At equal horizon and success (within 5 points), do-mpc's median step takes "
                 f"{', '.join(ratios)} the project's quadratic-terminal MPC's." if ratios else "")
    rl = [r for r in rows if r["kind"] in ("ppo", "sac")]
    rl_text = ""
    if rl:
        top = max(rl, key=lambda r: r["success"])
        lqr = next((r for r in rows if r["kind"] == "lqr"), None)
        rl_text = (f" The best RL baseline, {top['kind'].upper()} after {top['env_steps']:,} environment steps per "
                   f"seed, reaches {pct(top['success'])} of the grid" +
                   (f" (LQR: {pct(lqr['success'])})." if lqr else "."))
    return (f"**{task}**: the shortest horizon within 5 points of the full horizon's {pct(full['success'])} "
            f"(median / p95 step time): " + "; ".join(parts) + "." + peer_text + rl_text)


def section_controllers() -> str:
    out = ["## Every controller on the same starts", ""]
    out.append(
        "Each row is one controller of the task on the evaluation grid (the paper's heat-map starts) and on 100 "
        "starts drawn from X0 that no method trained on. Learned rows are medians over seeds of "
        "`closed_loop.json`. Step times are the median and 95th percentile of one process's time per closed-loop "
        "step, taken from the file named under each table for that row (the rows timed by the command ran on the "
        "machine and at the load named there). NLP solves and environment steps are what it cost to make the "
        "controller (for the learned MPC: the closed-loop sampler's collection episodes plus the episodes its "
        "refit selection flies). The RL baselines are in the section above (`baselines.json`): these tables' "
        "files also hold rows of earlier RL models, trained on raw observations with the task's cost as reward, "
        "which are not shown."
    )
    for task, title in (("acrobot", "Acrobot (analytic model)"), ("acrobot_mujoco", "Acrobot in MuJoCo"),
                        ("glider", "Glider (perching)")):
        data = load(f"controllers_{task}.json")
        out += ["", f"### {title}", "", table(CONTROLLER_HEADER, controller_rows(task, brief=True))]
        sources: dict[str, list[str]] = {}
        for r in (r for r in data["rows"] if not is_rl(r)):
            sources.setdefault(r["source"], []).append(short_name(r["method"]))
        out += ["", "Where each row's numbers come from: " + "; ".join(
            f"{', '.join(rows)}: {src.replace('measured here', 'measured by the command below')}"
            for src, rows in sources.items()) + "."]
        source = f"benchmarks/results/controllers_{task}.json"
        out += ["", f"Command: `{CURRENT[f'controllers_{task}.json'][1]}` -> `{source}` "
                f"({machine_line(data.get('machine'))})."]
    out += ["", "![success against step time](figures/results/controllers.png)"]
    return "\n".join(out)


def section_success_per_solve() -> str:
    data = load("closed_loop.json")
    out = ["## Closed-loop success per solve", ""]
    out.append(
        "How many NLP solves each way of choosing training starts needs before its learned MPC controls. Every "
        "method trains the same network with the same optimizer; only the starts differ. Each cell is the median "
        "over seeds of the grid success of the networks saved at that budget (10 x 10 sub-grid below the largest "
        "budget where so marked in the per-seed files)."
    )
    for task in ("acrobot", "glider"):
        block = data[task]
        methods = block["methods"]
        budgets = sorted({int(b) for m in methods.values() for b in m["budgets"]})
        rows = []
        for name, m in methods.items():
            cells = [f"`{name}`" + (" (shipped)" if name == block["method"] else "")]
            for b in budgets:
                cell = m["budgets"].get(str(b))
                cells.append(pct(cell["success_median"]) if cell else "")
            rows.append(cells)
        out += ["", f"### {task.capitalize()}", "", table(["method", *[f"{b:,}" for b in budgets]], rows)]
        out += [
            "",
            f"Shipped: `{block['method']}` at {block['budget']:,} solves, {block['seeds']} seeds: "
            f"{pct(block['success_rate'])} of the {block['grid']} grid and {pct(block['heldout_success_rate'])} "
            f"of {block['heldout_starts']} held-out starts; the full-horizon MPC "
            f"{pct(block['full_horizon_success_rate'])} / {pct(block['full_horizon_heldout_success_rate'])}. "
            f"Deployed as a {block['horizon']}-step "
            f"`LimitedLookaheadMPC` (trust region `{block['trust_region']}`, goal blend {block['goal_blend']}), "
            f"{ms(block['median_ms'])} ms median / {ms(block['p95_ms'])} ms p95 per step over "
            f"{block['timed_steps']:,} steps. Error of the value at the planner's queries: median "
            f"{block['query_error_median']:.3g}, p95 {block['query_error_p95']:.3g}. Network: "
            f"`{block['network']}`.",
            "",
            f"![success per solve, {task}](figures/results/success_vs_solves_{task}.png)",
        ]
    out += ["", "Commands: each method's per-seed runs are trained and evaluated by `benchmarks/bench_closed_loop.py` "
            "(the index `benchmarks/results/README.md` names the folders) and aggregated into `closed_loop.json` by "
            "its `--aggregate` mode; the commands in full are in the "
            "[experiment log](experiments/closed-loop.md)."]
    return "\n".join(out)


def section_sample_efficiency() -> str:
    out = ["## The paper's metric: validation error at equal solves", ""]
    out.append(
        "The paper measures value error on a validation set of optimal trajectories. Ratios are per-seed "
        "SEAGuL / uniform (or Sobolev / plain) error ratios, then the median over seeds; win is the fraction of "
        "seeds where the variant is better; p is a two-sided Wilcoxon signed-rank test."
    )
    rows = []
    for name in ("sample_efficiency_acrobot_20seeds.json", "sample_efficiency_acrobot_10seeds_15000steps.json",
                 "sample_efficiency_glider_5seeds_sobolev1.json", "sample_efficiency_glider_5seeds_sobolev0.1.json"):
        for task, b in load(name).items():
            steps = b.get("train_steps", "-")
            seeds = len(b["seeds"]) if isinstance(b.get("seeds"), list) else b.get("seeds")
            rows.append([f"{task}, {seeds} seeds, {steps:,} steps, Sobolev weight {b.get('sobolev_weight', '-')}",
                         _ratio(b, "ratio_median", "adversarial_win_fraction", "ratio_median_p"),
                         _ratio(b, "ratio_median_all_knots", "adversarial_win_fraction_all_knots",
                                "ratio_median_all_knots_p"),
                         _ratio(b, "sobolev_ratio_median", "sobolev_win_fraction", "sobolev_ratio_median_p"),
                         f"`{name}`"])
    out += ["", table(["run", "SEAGuL / uniform, mse_initial", "SEAGuL / uniform, mse_all_knots",
                       "uniform + Sobolev / uniform, mse_all_knots", "file"], rows)]
    out += ["", "Commands: " + "; ".join(f"`{CURRENT[n][1]}`" for n in CURRENT if n.startswith("sample_eff")) + "."]
    return "\n".join(out)


def _ratio(b: Mapping[str, Any], key: str, win: str, p: str) -> str:
    if key not in b:
        return "-"
    text = f"{b[key]:.2f}"
    extra = [f"win {pct(b[win])}" if win in b else "", f"p = {b[p]:.2g}" if p in b else ""]
    extra = [e for e in extra if e]
    return text + (f" ({', '.join(extra)})" if extra else "")


def section_baselines() -> str:
    data = load("baselines.json")
    out = ["## Baselines: what the learned value is worth", ""]
    out.append(
        "Every controller on the same starts, measured in one run by `benchmarks/bench_baselines.py`: the shipped "
        "value network as the terminal cost of the project's MPC at several horizons (the network is trained once; "
        "only the lookahead changes), the same MPC with the task's quadratic (LQR) terminal cost, do-mpc (IPOPT) "
        "on the same discrete model and cost, the full-horizon MPC, LQR, and PPO and SAC set up as RL "
        "practitioners set them up (below). Success @ 0.1 to 0.5 re-judges the grid episodes with the rule's "
        "tolerance scaled to that distance (the glider: position within that many metres, speeds within 40 times "
        "it in m/s); the final distance is over the whole state (the glider's includes its speeds). Step time is "
        "each controller's own computation per step, timed in turn in one process. "
        "NLP solves and environment steps are what it cost to make the controller (RL: per seed)."
    )
    for task in ("acrobot", "glider"):
        b = data[task]
        out += ["", f"### {task.capitalize()} ({b['grid_starts']} grid starts, {b['heldout_starts']} held-out)", "",
                table(BASELINE_HEADER, baseline_rows(task)), "", horizon_summary(task), "",
                f"![final-state CDF, {task}](figures/results/baselines_cdf_{task}.png)", "",
                f"![horizon sweep, {task}](figures/results/horizon_sweep_{task}.png)"]
    out += ["", f"Machine: {machine_line(data.get('machine'))}.{load_sentence(data.get('machine'))}", "",
            "Command: `python benchmarks/bench_baselines.py --json benchmarks/results/baselines.json` "
            "(do-mpc rows need `pip install 'seagul[anchors]'`)."]
    return "\n".join(out)


def section_rl() -> str:
    data = load("rl_baselines.json")
    out = ["## RL baselines", ""]
    out.append(
        "Stable-Baselines3 PPO and SAC on `SeagulAcrobot-v0` and `SeagulGlider-v0`, set up by the book "
        "(`seagul_learn/hyperparams/{ppo,sac}.yml`): the learner sees (cos, sin) of the periodic angles, the time "
        "to go scaled to [0, 1] and acts in [-1, 1]; its reward is bounded and success-aware (a capped stage "
        "cost, a capped miss of the success rule at the end, a success bonus, a crash penalty); rl-zoo sizes "
        "(PPO 64 x 64 with an entropy bonus, SAC 256 x 256 with 10,000 random steps); gamma^N >= 0.9 over an "
        "episode. Each seed's checkpoint is selected on 50 validation starts of their own stream; the table "
        "evaluates the selected models on the grid and the held-out starts with the task's own rule. The "
        "shipped model (`benchmarks/results/models/<task>_<algo>/`, with its statistics and view) is the seed "
        "with the best validation point."
    )
    rows = []
    for task in ("acrobot", "glider"):
        for algo in ("ppo", "sac"):
            b = data.get(task, {}).get(algo)
            if not b:
                continue
            per_seed = " / ".join(pct(s["grid"]["success_rate"]) for s in b["per_seed"])
            rows.append([task, b["algo"], f"{b['env_steps']:,}", b["seeds"], pct(b["success_rate"]),
                         pct(b["heldout_success_rate"]), per_seed, f"{b['median_final_distance']:.3g}",
                         f"{b['train_wall_s']:,.0f}", f"`{b['model']}`"])
    out += ["", table(["task", "algorithm", "env steps per seed", "seeds", "grid success (median)",
                       "held-out success (median)", "grid success per seed", "median final distance (held-out)",
                       "training s (median)", "shipped model"], rows)]
    out += ["", "![RL curves, acrobot](figures/results/rl_curves_acrobot.png)", "",
            "![RL curves, glider](figures/results/rl_curves_glider.png)", "",
            f"Machine: {machine_line(data.get('machine'))}.", "",
            "Command: `python benchmarks/bench_rl_baselines.py --json benchmarks/results/rl_baselines.json` "
            "(budgets: `FULL_STEPS` in the script; `--steps` changes them)."]
    return "\n".join(out)


def section_speed() -> str:
    solvers = load("mpc_solvers_acrobot.json")
    par = load("parallel_speedup.json")
    out = ["## Speed", "", "### The acrobot lookahead: condensed solver against fatrop", ""]
    rows = []
    for name, s in solvers["solvers"].items():
        rows.append([f"`{name}`", pct(s.get("success_rate")), pct(s.get("heldout_success_rate")),
                     f"{ms(s.get('median_ms'))} / {ms(s.get('p95_ms'))}"])
    out += [table(["solver", "grid success", "held-out success", "step ms (median / p95)"], rows), "",
            f"Network `{solvers['network']}`, {solvers['grid']} grid; the solvers agree on "
            f"{pct(solvers['grid_agreement'])} of the grid starts. Command: "
            f"`{CURRENT['mpc_solvers_acrobot.json'][1]}` ({machine_line(solvers.get('machine'))}).", "",
            "### Parallel solves", ""]
    rows = []
    for backend in ("local", "ray"):
        rows.append([backend, f"{par[f'{backend}_w1']['wall_s']:.2f}", f"{par[f'{backend}_w2']['wall_s']:.2f}",
                     f"{par[f'{backend}_speedup']:.2f}x"])
    out += [table(["backend", "1 worker (s)", "2 workers (s)", "speed-up"], rows), "",
            f"{par['n']} acrobot solves, median of {par['repeats']} repeats; identical results on every backend and "
            f"worker count: {par['identical']}. Command: `{par.get('command', CURRENT['parallel_speedup.json'][1])}`"
            f" ({machine_line(par.get('machine'))})."]
    return "\n".join(out)
