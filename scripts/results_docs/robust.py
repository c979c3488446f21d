"""Robots that differ from the model: the shipped robust MPC's tables, in the README and on the results page."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from .common import RESULTS, load, ms, pct, table
from .files import CURRENT, ROBUST_COMMAND, ROBUST_TASK_FLAGS

ROBUST_ORDER = (
    "adaptive-quadratic", "adaptive-quadratic-N5", "nominal-estimate", "nominal", "dr-sac", "dr-ppo", "nominal-ppo",
    "lqr", "oracle",
)
"""Rows of the robust table after the shipped robust MPC (``param_adversary.json``'s ``robust.baselines`` keys)."""


def robust_rows(task: str, keys: tuple[str, ...] | None = None) -> list[list[str]]:
    """The robust learned MPC and its baselines on the same starts x robots (``param_adversary.json``); ``keys``:
    only those baselines (``robust.baselines`` keys, in :data:`ROBUST_ORDER`)."""
    block = load("param_adversary.json")[task]
    shipped, robust = block["shipped"], block["robust"]
    oracle = shipped["oracle_success_rate"]
    seeds = ", ".join(pct(r["success_rate"]) for r in robust["per_seed"])
    own = next(r for r in robust["per_seed"] if r["seed"] == robust["shipped_seed"])

    def of_oracle(rate: float) -> str:
        return pct(rate / oracle) if oracle else "-"

    rows = [[
        f"**learned {shipped['horizon']}-step MPC, estimating the robot** ({shipped['budget']:,} solves; "
        f"seeds {seeds})",
        pct(shipped["success_rate"]),
        of_oracle(shipped["success_rate"]),
        f"{ms(own['median_ms'])} / {ms(own['p95_ms'])}",
    ]]
    baselines = robust["baselines"]
    order = [k for k in ROBUST_ORDER if k in baselines] + [k for k in baselines if k not in ROBUST_ORDER]
    for key in order if keys is None else [k for k in order if k in keys]:
        row = baselines[key]
        label = row["controller"]
        if "per_seed" in row:  # a baseline trained over seeds (domain-randomised RL): its median and each seed's
            label += f"; seeds {', '.join(pct(r['success_rate']) for r in row['per_seed'])}"
        rows.append([label, pct(row["success_rate"]), of_oracle(row["success_rate"]),
                     f"{ms(row.get('median_ms'))} / {ms(row.get('p95_ms'))}"])
    return rows


ROBUST_TIMES = (
    "Step times are the solver's (without the estimate's update; the estimate's sentence gives whole steps), "
    "measured while other runs shared the machine: compare successes, not times."
)
ROBUST_HEADER = ["controller", "success", "of the oracle's", "step ms (median / p95)"]
ROBUST_BOXES = {
    "acrobot": "masses and lengths +-20 %, damping half to twice",
    "glider": "mass +-15 %, wing area +-10 %, elevator area +-20 %, air density +-10 %",
}
"""Each task's box Theta in words (``acrobot_parameter_space``, ``glider.THETA_SPREAD``)."""


def robust_tasks() -> list[str]:
    """The tasks of ``param_adversary.json`` with a shipped robust MPC, in the README's order."""
    data = load("param_adversary.json")
    return [t for t in ROBUST_BOXES if "shipped" in data.get(t, {})]


def readme_robust() -> str:
    """Robots that differ from the model in the README: per task, the shipped robust MPC, the adaptive MPC and the
    oracle."""
    data = load("param_adversary.json")
    rows, boxes, nominal = [], [], []
    for task in robust_tasks():
        shipped = data[task]["shipped"]
        # the shipped robust MPC, then the engineer's adaptive MPC, RL over robots and the oracle
        rows += [[f"{task}: {r[0]}", r[1], r[2]]
                 for r in robust_rows(task, keys=("adaptive-quadratic", "dr-sac", "dr-ppo", "oracle"))]
        boxes.append(f"{task}: {ROBUST_BOXES[task]}")
        nominal.append(f"{pct(shipped['nominal_success_rate'])} ({task})")
    first_task = data[robust_tasks()[0]]["shipped"]
    return "\n".join([
        f"**Robots that differ from the model**: {first_task['starts']} held-out starts, each flown on its own robot "
        f"drawn from the task's box Theta ({'; '.join(boxes)}); median over {first_task['seeds']} seeds; the "
        f"shipped nominal MPC, planning with the model, {' and '.join(nominal)} "
        "(`benchmarks/results/param_adversary.json`, every baseline and the step times in "
        "[the details](docs/results.md#the-shipped-robust-mpc)).",
        "",
        table(ROBUST_HEADER[:3], rows),
    ])


def estimate_sentence(est: Mapping[str, Any]) -> str:
    """The online estimate's accuracy and cost from a ``robust.estimator`` block."""
    steps = est["steps_to_5pct_median"]  # None: never within 5 % for good in the median episode
    within = (f"falls below 5 % of its box width after {steps:g} steps" if steps is not None
              else "does not stay below 5 % of its box width")
    final = ", ".join(f"`{k}` {pct(v)}" for k, v in est["final_error_median_per_parameter"].items())
    products = ""
    if "invariants" in est:  # what the transitions determine: the products the dynamics depend on
        inv = ", ".join(f"`{k}` {pct(v)}" for k, v in est["invariant_final_error_median"].items())
        products = (
            f" The transitions determine only the products the dynamics depend on; their relative errors are "
            f"{pct(est['invariant_max_error_median'][0])} at the first step and "
            f"{pct(est['invariant_max_error_median'][-1])} at the last (the worst product, median), each at the "
            f"end {inv}."
        )
    return (
        f"The online estimate ({est['episodes']} episodes of the shipped robust MPC): the worst parameter's error "
        f"{within} (median episode); it is {pct(est['max_error_median'][0])} of the width at the first step and "
        f"{pct(est['max_error_median'][-1])} at the last (median), each parameter's at the end {final}.{products} "
        f"A step (estimate and solve) takes {ms(est['step_ms_median'])} / {ms(est['step_ms_p95'])} ms "
        "(median / p95)."
    )


def shipped_robust_section(task: str) -> list[str]:
    """One task's shipped robust MPC: the table, the box sweep, the estimate and the figure."""
    b = load("param_adversary.json")[task]
    shipped, robust = b["shipped"], b["robust"]
    sweep, est = robust["box_sweep"], robust["estimator"]
    return [
        f"#### {task}",
        "",
        f"`{robust['deployed']}` with `network = {shipped['network']}` (the median of {shipped['seeds']} "
        f"seeds' networks, recipe `{robust['recipe']}`, {shipped['budget']:,} solves each) and horizon "
        f"{shipped['horizon']}, on {shipped['starts']} held-out starts x robots (Theta: {ROBUST_BOXES[task]}).",
        "",
        table(ROBUST_HEADER, robust_rows(task)),
        "",
        "Success against the size of the box (robots drawn from Theta scaled about the model's values, "
        "each side's ratio to the model's value raised to the scale):",
        "",
        table(["box", "learned robust MPC", "nominal shipped MPC", "oracle"],
              [[f"{k}x", pct(v.get("robust")), pct(v.get("nominal")), pct(v.get("oracle"))]
               for k, v in sorted(sweep.items(), key=lambda kv: float(kv[0]))]),
        "",
        estimate_sentence(est),
        "",
        f"![robust MPC, box size and estimate](figures/results/robust_shipped_{task}.png)",
        "",
        f"Command: `{ROBUST_COMMAND}{ROBUST_TASK_FLAGS[task]}`.",
    ]


def section_robust() -> str:
    b = load("param_adversary.json")["acrobot"]
    out = ["## Robots that differ from the model", ""]
    out.append(
        f"Each of {b['starts']} held-out starts is flown on its own robot drawn from the task's box Theta "
        f"({', '.join(b['theta_box'])}); {b['seeds']} paired seeds, {b['budget']} solves per network. The learned "
        "networks over robots drive the 5-step MPC that estimates the robot online; the full horizon knows the true "
        "robot. These 300-solve networks compare the samplers over Theta; the shipped robust MPC "
        "([below](#the-shipped-robust-mpc)) is another deployment."
    )
    rows = [
        ["closed-loop sampler over Theta, estimating MPC", pct(b.get("closed_loop_success_rate"))],
        ["uniform over Theta, estimating MPC", pct(b["uniform_success_rate"])],
        ["adversarial over Theta, estimating MPC", pct(b["adversarial_success_rate"])],
        ["nominal network, estimating MPC", pct(b["nominal_estimate_success_rate"])],
        ["nominal network, MPC on the model", pct(b["nominal_success_rate"])],
        ["LQR on the model", pct(b["lqr_success_rate"])],
        ["full-horizon MPC that knows the robot (oracle)", pct(b["full_horizon_success_rate"])],
    ]
    out += ["", table(["controller", "success (median over seeds)"], rows)]
    out += ["", f"`dV/dtheta` from the duals against central differences: largest relative error "
            f"{b['grad_theta_fd_max_rel_error']:.1e}.", "",
            "![robust closed loop](figures/results/robust_acrobot.png)", "",
            f"Command: `{CURRENT['param_adversary.json'][1]}`."]
    tasks = robust_tasks()
    if tasks:
        out += ["", "### The shipped robust MPC", "",
                "Per task, the shipped network deployed as the MPC that estimates the robot online, on held-out "
                "starts each flown on its own robot from Theta; every baseline on the same starts and robots. "
                + ROBUST_TIMES]
        for task in tasks:
            out += ["", *shipped_robust_section(task), *deployment_section(task)]
    return "\n".join(out)


def deployment_section(task: str) -> list[str]:
    """The shipped robust MPC under other deployment settings (``robust_deployment.json``), when measured."""
    path = RESULTS / "robust_deployment.json"
    block = load("robust_deployment.json").get(task) if path.exists() else None
    if not block:
        return []
    rows = [[v["label"], " / ".join(pct(r) for r in v["success_per_seed"]), f"**{pct(v['success_median'])}**",
             str(v["fallback_steps"]), str(v["crashes"]), f"{ms(v['median_ms'])} / {ms(v['p95_ms'])}"]
            for v in block["variants"]]
    return [
        "",
        f"The same networks under other deployment settings, each changing one setting of the shipped one, on "
        f"{block['starts']} validation starts x robots (never the held-out ones above; "
        "[what they show](experiments/robust.md)):",
        "",
        table(["deployment", "success per seed", "median", "fallback steps", "crashes", "solve ms (median / p95)"],
              rows),
        "",
        f"Command: `{CURRENT['robust_deployment.json'][1]}`.",
    ]
