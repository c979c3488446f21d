"""The DeepMind Control Suite swing-ups: the README's table and the results page's section."""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

from .common import RESULTS, ROOT, load, machine_line, table


def _best_published(block: Mapping[str, Any]) -> str:
    pub = block.get("published") or []
    if not pub:
        return "-"
    best = max(pub, key=lambda p: p["score"])
    return f"{best['score']:.0f} ({best['method']}, {best['env_steps'] / 1e6:g} M steps)"


def readme_dmc() -> str:
    """The DeepMind Control Suite's swing-ups in the README: one row per task from ``dmc.json``'s blocks."""
    data = load("dmc.json")
    rows = []
    for name in DMC_TASKS:
        b = data[name]
        learned = b.get("learned_mpc")
        ref = b.get("full_horizon")
        swing_ups = [r for r in b["classical"] if r["controller"] not in ("zero", "random", "lqr")]
        classical = max(swing_ups, key=lambda r: r["mean"])
        rows.append([
            name,
            "-" if learned is None else (f"{learned['score_mean']:.0f} ± {learned['score_std']:.0f} "
                                         f"({learned['seeds']} seeds, N = {learned['horizon']}, "
                                         f"{learned['solves']:,} solves, "
                                         f"{learned['median_ms']:.1f} ms)"),
            ("-" if ref is None else f"{ref['score_mean']:.0f} ± {ref['score_std']:.0f}")
            + ("" if not b.get("optimum") else f" (optimum {b['optimum']['score_mean']:.0f})"),
            f"{classical['mean']:.0f} ± {classical['std']:.0f} ({DMC_LABELS.get(classical['controller'], '')})",
            *["-" if b.get(algo) is None else (f"{b[algo]['score_mean']:.0f} ± {b[algo]['score_std']:.0f} "
                                               f"({b[algo]['seeds']} seeds, {b[algo]['env_steps'] / 1e6:.3g} M steps)")
              for algo in ("sac", "ppo")],
            _best_published(b),
        ])
    return "\n".join([
        "**DeepMind Control Suite swing-ups**, scored by dm_control's own reward on its own episodes (0 to 1000, "
        f"mean ± std over reset seeds {data['seeds'][0]}-{data['seeds'][-1]}, for SAC and PPO over training seeds "
        "of each seed's mean; `benchmarks/results/dmc.json`, "
        "[details](docs/results.md#deepmind-control-suite-swing-ups), "
        "[animations](docs/results.md#the-controllers-from-one-start)). A dash is a run not made yet.",
        "",
        table(["task", "learned MPC", "full-horizon reference", "classical swing-up", "SAC", "PPO", "best published"],
              rows),
    ])


DMC_TASKS = ("pendulum-swingup", "cartpole-swingup", "cartpole-swingup_sparse", "acrobot-swingup")
DMC_LABELS = {
    "zero": "zero action",
    "random": "uniform random action",
    "lqr": "seagul `LQRPolicy` (no swing-up)",
    "energy": "energy shaping + LQR catch",
    "astrom_furuta": "Astrom-Furuta energy control + LQR catch",
    "spong": "Spong's energy pumping + LQR catch",
}


def _dmc_cell(row: Mapping[str, Any] | None) -> str:
    return "" if row is None else f"{row['mean']:.0f} ± {row['std']:.0f}"


def section_dmc() -> str:
    """The suite's swing-ups: our controllers' scores (``dmc.json``, ``dmc_reference.json`` when present) and the
    published ones (``dmc_published.json`` when present), all on dm_control's own reward (0..1000)."""
    data = load("dmc.json")
    out = ["## DeepMind Control Suite swing-ups", ""]
    out.append(
        "Scored by dm_control's own reward on dm_control's own episodes (`gym.make(\"dm_control/<task>-v0\")` "
        "through shimmy: its reset distribution, 1,000 control steps, the score is the sum of rewards, 0 to "
        f"1000), mean ± std over reset seeds {data['seeds'][0]}-{data['seeds'][-1]}. The classical controllers' "
        f"gains were tuned on reset seeds {data['tuning_seeds'][0]}-{data['tuning_seeds'][-1]} only. seagul's "
        "models of the suite's physics (`make_task(\"dmc_acrobot\")`, ...) are described in "
        "[the suite tasks](tutorials/dmc-tasks.md)."
    )
    rows_by: dict[str, dict[str, Mapping[str, Any]]] = {}
    for name in DMC_TASKS:
        for r in data[name]["classical"]:
            rows_by.setdefault(r["controller"], {})[name] = r
    reference = (RESULTS / "dmc_reference.json").exists() and load("dmc_reference.json")
    rows = []
    if reference:
        ref = {env_id.split("/")[-1].removesuffix("-v0"): b for env_id, b in reference["tasks"].items()}
        rows.append(["full-horizon reference (true model, re-planned)", *[_dmc_cell(ref.get(t)) for t in DMC_TASKS]])
    optimum = {t: data[t].get("optimum") for t in DMC_TASKS if data[t].get("optimum")}
    if optimum:
        rows.append(["**optimum** (dynamic programming on a grid of the state; the pendulum only)", *[
            "" if t not in optimum else f"**{optimum[t]['score_mean']:.0f} ± {optimum[t]['score_std']:.0f}**"
            for t in DMC_TASKS]])
    for controller, per_task in rows_by.items():
        rows.append([DMC_LABELS.get(controller, controller), *[_dmc_cell(per_task.get(t)) for t in DMC_TASKS]])
    learned = (RESULTS / "dmc_learned.json").exists() and load("dmc_learned.json")
    for env_id, block in (learned["tasks"] if learned else {}).items():
        name, lp = env_id.split("/")[-1].removesuffix("-v0"), block["params"]
        for r in block["rows"]:
            label = (f"learned MPC, N = {lp['horizon']} x {lp['dt']:g} s, tau_V = {lp['tau_v']:g} s, "
                     f"{r['solves']:,} solves (`{r['network'].split('/')[-1]}`, {r['decision_ms_median']:.2f} ms "
                     "median step)")
            rows.append([label, *[_dmc_cell(r) if t == name else "" for t in DMC_TASKS]])
    for algo in ("sac", "ppo"):
        runs = {t: data[t][algo] for t in DMC_TASKS if data[t].get(algo)}
        if runs:
            steps = sorted({r["env_steps"] for r in runs.values()})
            rows.append([f"{algo.upper()} (SB3, {'/'.join(f'{s / 1e6:.3g}' for s in steps)} M steps, each seed's "
                         "model selected on validation episodes; mean ± std over seeds)", *[
                             "" if t not in runs else f"{runs[t]['score_mean']:.0f} ± {runs[t]['score_std']:.0f} "
                             f"({runs[t]['seeds']} seeds)" for t in DMC_TASKS]])
    pooled = {t: data[t]["learned_mpc"] for t in DMC_TASKS if data[t].get("learned_mpc")}
    if pooled:
        rows.append(["**learned MPC, every network's episodes pooled**", *[
            "" if t not in pooled else f"**{pooled[t]['score_mean']:.0f} ± {pooled[t]['score_std']:.0f}** "
            f"({pooled[t]['seeds']} x {pooled[t]['episodes']})" for t in DMC_TASKS]])
    out += ["", table(["controller", *DMC_TASKS], rows), "",
            f"Command: `{data['command']}` ({machine_line(data.get('machine'))})."]
    for env_id, block in (learned["tasks"] if learned else {}).items():
        out[-1] += (f" Learned MPC on {env_id.split('/')[-1].removesuffix('-v0')}: "
                    "`benchmarks/results/dmc_learned.json`, `" + block["command"].split(" --tuning")[0]
                    + "`; the setting was chosen on reset seeds " + f"{block['tuning_seeds'][0]}-"
                    f"{block['tuning_seeds'][-1]} ([the learned MPC](experiments/dmc-learned.md)).")
    if (RESULTS / "dmc_rl.json").exists():
        out[-1] += (" PPO: `benchmarks/results/dmc_rl.json`, `python benchmarks/bench_dmc_rl.py --tasks TASK --algos "
                    "PPO --json benchmarks/results/dmc_rl.json`, gathered by `python benchmarks/bench_dmc.py --gather "
                    "--json benchmarks/results/dmc.json` ([the RL baselines](experiments/dmc-rl.md)); each task's "
                    "selected model, the seed with the best validation point, is committed in "
                    "`benchmarks/results/models/dmc/<task>_ppo/` (`bench_dmc_rl.py --ship`; "
                    "`seagul_learn.dmc_rl.load_sb3_dmc` loads it).")
    if (RESULTS / "dmc_published.json").exists():
        pub = load("dmc_published.json")["scores"]
        prow = [[p["task"], p["method"], f"{p['score']:.0f}", f"{p['env_steps']:,}", p.get("observations", ""),
                 p.get("seeds") or "", p["source"]] for p in pub if p["task"] in DMC_TASKS]
        out += ["", "Published scores on the same tasks (`benchmarks/results/dmc_published.json`: each computed "
                "from the authors' released per-seed results or, where only a table is published, read off it; "
                "each number's source and budget in environment steps):",
                "",
                table(["task", "method", "score", "env steps", "observations", "seeds", "source"], prow)]
    out += dmc_wide(data)
    out += dmc_animations()
    return "\n".join(out)


def dmc_wide(data: Mapping[str, Any]) -> list[str]:
    """The pendulum on 100 reset seeds: the optimum, the learned MPC and the energy swing-up beside the published
    means (``dmc.json``'s ``optimum`` and ``learned_mpc.wide`` blocks, when present)."""
    block = data.get("pendulum-swingup") or {}
    optimum, learned = block.get("optimum"), (block.get("learned_mpc") or {}).get("wide")
    if not optimum:
        return []
    wide, energy = optimum["wide"], optimum["energy_wide"]
    seeds = f"{wide['reset_seeds'][0]}-{wide['reset_seeds'][-1]}"
    best = max(block["published"], key=lambda p: p["score"]) if block["published"] else None
    rows = [["optimum (grid dynamic programming)", f"{wide['score_mean']:.1f} ± {wide['score_std']:.0f}",
             f"{wide['episodes']}"]]
    if learned:
        rows.append([f"learned MPC ({len(learned['networks'])} networks)",
                     f"{learned['score_mean']:.1f} ± {learned['score_std']:.0f}",
                     f"{len(learned['networks'])} x {learned['episodes']}"])
    rows.append(["energy shaping + LQR catch", f"{energy['score_mean']:.1f} ± {energy['score_std']:.0f}",
                 f"{energy['episodes']}"])
    if best:
        rows.append([f"{best['method']} (published)", f"{best['score']:.0f}", "their evaluation episodes"])
    spec = optimum["spec"]
    return ["", f"**How far can the pendulum go?** Its state is two numbers, so its optimum is computed, not "
            f"searched for: value iteration on a {spec['angle_cells']} x {spec['velocity_points']} grid of (angle, "
            f"velocity) with MuJoCo's step and dm_control's reward ({spec['actions']} torques per backup, "
            f"{spec['backups']} backups; `seagul_control.grid_optimum`, `benchmarks/results/dmc_optimum.json`, "
            "refined until the score stops changing). Ten episodes are too few to compare with published means "
            "(their standard error is about 30 points), so the table adds reset seeds "
            f"{seeds}:", "", table(["controller", "score", "episodes"], rows)]


def dmc_animations() -> list[str]:
    """The suite animations (``docs/figures/dmc/*.gif``, drawn by ``benchmarks/animate_dmc.py``), captioned from the
    ``animations.json`` it writes beside them (reset seed, each panel's controller and score)."""
    index = ROOT / "docs" / "figures" / "dmc" / "animations.json"
    if not index.is_file():
        return []
    shown = json.loads(index.read_text())
    out = ["", "### The controllers from one start", "",
           "Each animation replays dm_control's own episodes from one reset seed, the evaluation seed whose start is "
           "farthest from upright, drawn by MuJoCo's renderer from the recorded physics states; each panel's score "
           "is that controller's committed score on this seed. PPO's panel is the task's committed model (the seed "
           "with the best validation point, [the RL baselines](experiments/dmc-rl.md)); SAC was not run. "
           "Command: `python benchmarks/animate_dmc.py`."]
    for task in DMC_TASKS:
        if task not in shown:
            continue
        a = shown[task]
        scores = "; ".join(f"{p['controller']} {p['score']:.0f}" for p in a["panels"])
        out += ["", f"![{task}, reset seed {a['seed']}](figures/dmc/{a['file']})", "",
                f"*{task}, reset seed {a['seed']}: {scores}.*"]
    return out
