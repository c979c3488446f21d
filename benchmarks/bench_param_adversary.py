"""Adversarial samples over model parameters against uniform-over-Theta, and the robust MPC they give.

Usage::

    .venv/bin/python benchmarks/bench_param_adversary.py [--quick] [--tasks acrobot] [--seeds N] [--budget B]
        [--starts N] [--workers 2] [--out DIR] [--update FILE] [--closed-loop] [--model-reference]
        [--report-from JSON] [--dry-run]

Per task and seed (paired: the three runs of a seed share their pretraining solves, their pool of starts and, for
the two runs over robots, the robots of those starts), at equal solves:

* ``adversarial``: ``TrainConfig(sampler="adversarial", model_params=True)``: paper Alg. 1's ascent over
  ``(x, theta)`` in ``X0 x Theta`` on ``1/2 (V - Vhat)^2``, with ``dV/dtheta`` from the duals;
* ``uniform``: ``sampler="uniform", model_params=True``: uniform over ``X0 x Theta``;
* ``nominal``: ``sampler="uniform"`` on the model's robot only (``Vhat(x, tau)``);
* ``closed-loop`` (``--closed-loop``): the closed-loop sampler over robots (``CLOSED_LOOP``): its episodes fly
  robots from Theta under the deployed robust MPC and its tails are solved for the robots of the plans.

Each network is scored on

* the validation set over robots (the task's validation starts, each with a robot drawn from Theta with a fixed
  seed; ``mse_initial`` and ``mse_all_knots``; the nominal network ignores theta), and
* **robust closed-loop success**: ``--starts`` held-out X0 starts (never trained on), each simulated on its own
  robot drawn from Theta (a fixed seed), with the deployed learned MPC. The networks over robots drive
  ``LimitedLookaheadMPC(..., model_params=True, estimate_robot=True)``: the MPC plans, and evaluates the value, for
  an online least-squares estimate of the robot from the episode's transitions (``seagul_control.estimation``);
  the nominal network drives the MPC on the model (``nominal``) and, as a control for what the estimate alone
  gives, the same estimating MPC (``nominal_estimate``).

Beside them on the same starts and robots: LQR on the model, the full-horizon MPC on the model
(``--model-reference``, slow), and the full-horizon MPC that knows each true robot
(``FullHorizonMPC(model_params=True)``, ``set_robot``; the upper reference). The dual ``dV/dtheta`` is checked
against central finite differences of re-solved values at random ``(x, theta)``.

Every run also writes ``report.md``/``report.html`` into ``--out`` (the figure, success per controller and seed,
validation, paired tests); ``--report-from benchmarks/results/param_adversary.json --out DIR`` writes the report of
a stored result without running anything. Every stage is stored under ``--out`` (training checkpoints, one JSON
per evaluation), so a re-run continues. The last line of stdout is one JSON object (the full run's is committed as
``benchmarks/results/param_adversary.json``)::

    {"acrobot": {"theta_box": {...}, "seeds": int, "budget": int, "adversarial_success_rate": float,
                 "uniform_success_rate": float, "nominal_success_rate": float, "full_horizon_success_rate": float,
                 "grad_theta_fd_max_rel_error": float, ...}, "machine": {...}}

Success rates are over starts x drawn robots, medians over seeds; ``per_seed``, validation MSEs, the seed-paired
tests (adversarial minus uniform) and the reference controllers are in the same block.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from joblib import Parallel, delayed  # noqa: E402

from benchmarks._common import machine  # noqa: E402
from benchmarks.bench_closed_loop import FULL_TRAIN as CLOSED_LOOP_TRAIN  # noqa: E402
from benchmarks.bench_closed_loop import _train_one, paired_test  # noqa: E402
from seagul_control.evaluation import PolicySpec, default_horizon, evaluate, heldout_starts  # noqa: E402
from seagul_envs import make_task  # noqa: E402
from seagul_learn.config_legacy import LEGACY_NAMES, flat_name, new_name  # noqa: E402
from seagul_learn.dataset import training_arrays  # noqa: E402
from seagul_learn.report import Section, Table, write_report  # noqa: E402
from seagul_learn.solving import solver_key, trajopt_batch_solver  # noqa: E402
from seagul_learn.training import TrainConfig, default_cache_dir, validation_dataset  # noqa: E402
from seagul_learn.training import evaluate as validation_errors  # noqa: E402
from seagul_learn.trajopt import TrajectoryOptimizer  # noqa: E402
from seagul_learn.value_network import ValueNetwork  # noqa: E402

METHODS: dict[str, dict[str, Any]] = {
    "adversarial": {"sampler": "adversarial", "model_params": True},
    "uniform": {"sampler": "uniform", "model_params": True},
    "nominal": {"sampler": "uniform", "model_params": False},
}
#: ``--closed-loop`` adds the closed-loop sampler over robots: a third of the budget uniform over X0 x Theta, then
#: rounds whose 5 episodes each fly their own robot from Theta under the deployed robust MPC (``"lqr"`` guard,
#: online estimate), with the tails of their queries solved for the robots of the plans.
#: Its labels are handled as bench_closed_loop's recipe handles closed-loop tails (``FULL_TRAIN``: labels capped at
#: 50, extreme gradient labels dropped, the standardisation following the buffer, a fresh 20 k-step refit at the end);
#: without them one seed's tails (values up to ~1e4) gave validation errors 50-2,000x the uniform network's.
#: Settings are TrainConfig fields by their dotted place (``"sampler.episodes"``; ``seagul_learn.config_legacy``
#: maps the flat names of earlier versions, which the committed result's ``train_settings`` keep).
_CLOSED_LOOP_TRAIN = {new_name(k) if k in LEGACY_NAMES else k: v for k, v in CLOSED_LOOP_TRAIN.items()}
CLOSED_LOOP: dict[str, Any] = {
    "sampler": "closed-loop",
    "model_params": True,
    "sampler.episodes": 5,
    "sampler.warmup_rounds": 1,
    "sampler.trust_region": "lqr",
    **{k: _CLOSED_LOOP_TRAIN[k] for k in ("loss.value_cap", "loss.grad_label_max", "loss.renormalize", "refit.steps")},
}
ROBOT_SEED = 20261202
"""Seed of the robots the closed-loop starts are simulated on (the same for every method, seed and run)."""
FD_SEED = 7


@dataclass
class ParamBenchConfig:
    """Every number of one run (``--quick`` replaces some)."""

    task: str = "acrobot"
    seeds: int = 5
    budget: int = 300
    starts: int = 30
    """Closed-loop episodes per network: held-out X0 starts, each on its own robot from Theta."""
    fd_points: int = 2
    trust_region: str = "lqr"
    """The deployed MPC's guard (passed explicitly: these small networks are measured with ``"lqr"``)."""
    jit: bool = True
    solver: str = "ipopt"
    """The evaluated MPCs' solver. IPOPT with a wall-time limit per step (``max_step_time``) rather than the deployed
    default fatrop, which has looped without end inside one solve of the nominal MPC on a perturbed robot (over 35
    minutes; fatrop has no wall-time limit, docs/experiments/closed-loop.md, "fatrop hangs inside a solve")."""
    max_step_time: float = 5.0
    """IPOPT's ``max_wall_time`` per MPC step (s); a step that hits it falls back as any failed solve does."""
    closed_loop: bool = False
    """Also train and evaluate the closed-loop sampler over robots (``CLOSED_LOOP``; ``--closed-loop``)."""
    model_reference: bool = False
    """Also run the full-horizon MPC that plans with the model (slow: its solves on mismatched robots run into
    their iteration limits; a pilot of 20 such episodes measured 10 % success, docs/reference/spec.md §14.4)."""
    train: dict[str, Any] = field(
        default_factory=lambda: {
            "network.hidden": (64, 64),
            "schedule.solves_per_round": 10,
            "schedule.train_steps_per_round": 500,
            "loss.sobolev_weight": 1.0,
            "schedule.pretrain_solves": 10,
            "sampler.max_steps": 5,
        }
    )

    def methods(self) -> dict[str, dict[str, Any]]:
        """The trained methods and their TrainConfig settings."""
        # A third of the budget uniform (100 of the default 300 solves), then closed-loop rounds.
        settings = {**CLOSED_LOOP, "sampler.uniform_solves": self.budget // 3, "sampler.jit": self.jit}
        extra = {"closed-loop": settings} if self.closed_loop else {}
        return {**METHODS, **extra}

    @classmethod
    def for_task(cls, task: str, quick: bool) -> ParamBenchConfig:
        if quick:
            return cls(
                task=task,
                seeds=2,
                budget=20,
                starts=3,
                fd_points=1,
                jit=False,
                train={
                    "network.hidden": (16,),
                    "schedule.solves_per_round": 10,
                    "schedule.train_steps_per_round": 50,
                    "loss.sobolev_weight": 1.0,
                    "schedule.pretrain_solves": 4,
                    "sampler.max_steps": 3,
                },
            )
        return cls(task=task)


def train_all(bench: ParamBenchConfig, out: Path, workers: int) -> dict[tuple[str, int], Path]:
    """One run per (method, seed), in parallel processes."""
    jobs = {}
    for seed in range(bench.seeds):
        for method, settings in bench.methods().items():
            cfg = {"task": bench.task, **bench.train, **settings, "budget": bench.budget, "seed": seed}
            jobs[(method, seed)] = ({**cfg, "runtime.progress": False}, str(out / "train" / f"{method}-seed{seed}"))
    Parallel(n_jobs=workers)(delayed(_train_one)(*job) for job in jobs.values())
    return {k: Path(v[1]) for k, v in jobs.items()}


def robust_validation(task_name: str, run: Path) -> dict[str, float]:
    """Validation MSEs of a run's network on the validation set over robots (the nominal network ignores theta)."""
    task = make_task(task_name)
    config = TrainConfig.from_run(run)
    records = validation_dataset(
        task,
        trajopt_batch_solver(task, solver_options=config.solver_options),
        solver_key(config.solver_options, task),
        config.runtime.cache_dir or default_cache_dir(),
        model_params=True,
    )
    arrays = training_arrays(records, task.nx)
    mse_initial, mse_all = validation_errors(
        ValueNetwork.load(run / "network.pt"), arrays
    )  # a nominal network ignores theta
    return {"mse_initial": mse_initial, "mse_all_knots": mse_all}


def mpc_options(bench: ParamBenchConfig, estimating: bool) -> tuple[tuple[str, Any], ...]:
    task = make_task(bench.task)
    options: tuple[tuple[str, Any], ...] = (
        ("horizon", default_horizon(task)),
        ("trust_region", bench.trust_region),
        ("jit", bench.jit),
        ("solver", bench.solver),
    )
    if bench.solver == "ipopt":
        # as pairs: a PolicySpec is hashable (the evaluator caches built policies by it)
        options += (("solver_options", (("ipopt.max_wall_time", bench.max_step_time),)),)
    return options + ((("model_params", True), ("estimate_robot", True)) if estimating else ())


def closed_loop(
    bench: ParamBenchConfig, spec: PolicySpec, starts: np.ndarray, robots: np.ndarray, workers: int, out: Path
) -> dict[str, Any]:
    """Success of one policy over the starts x robots (cached as JSON)."""
    if out.is_file():
        return json.loads(out.read_text())
    t0 = time.perf_counter()
    results = evaluate(bench.task, [spec], starts, workers=workers, progress=False, robots=robots)
    times = np.array([t for r in results for t in r.solve_times]) * 1e3
    row = {
        "success_rate": float(np.mean([r.success for r in results])),
        "success": [bool(r.success) for r in results],
        "final_distance_median": float(np.median([r.final_distance for r in results])),
        "fallback_steps": int(sum(r.fallbacks for r in results)),
        "crashes": int(sum(r.terminated for r in results)),
        "median_ms": float(np.median(times)) if times.size else float("nan"),
        "p95_ms": float(np.percentile(times, 95)) if times.size else float("nan"),
        "wall_s": round(time.perf_counter() - t0, 1),
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(row, indent=1))
    return row


def grad_theta_fd_error(task_name: str, points: int) -> float:
    """Max over ``points`` random ``(x, theta)`` and parameters of ``|dV/dtheta - FD| / scale`` (central FD of
    re-solved values at ``theta +- 1e-4 |theta_i|``; scale ``max(|FD_i|, 1e-3 max|FD|)``)."""
    task = make_task(task_name)
    space = task.parameters
    assert space is not None
    opt = TrajectoryOptimizer(task, codegen=False, tol=1e-10, multi_start="never", model_params=True)
    rng = np.random.default_rng(FD_SEED)
    worst = 0.0
    for x, theta in zip(task.sample_x0(rng, points), space.sample(rng, points), strict=True):
        res = opt.solve(x, theta=theta)
        if not res.success or res.grad_theta is None:
            return float("nan")
        fd = np.zeros(space.size)
        for i in range(space.size):
            step = 1e-4 * abs(theta[i])
            up, down = theta.copy(), theta.copy()
            up[i] += step
            down[i] -= step
            v_up, v_down = opt.solve(x, theta=up), opt.solve(x, theta=down)
            if not (v_up.success and v_down.success):
                return float("nan")
            fd[i] = (v_up.value - v_down.value) / (2 * step)
        scale = np.maximum(np.abs(fd), 1e-3 * np.max(np.abs(fd)))
        worst = max(worst, float(np.max(np.abs(res.grad_theta - fd) / scale)))
    return worst


def run_task(bench: ParamBenchConfig, out: Path, workers: int) -> dict[str, Any]:
    task = make_task(bench.task)
    space = task.parameters
    if space is None:
        raise SystemExit(f"{bench.task} declares no physical parameters")
    t0 = time.perf_counter()
    runs = train_all(bench, out, workers)
    train_s = time.perf_counter() - t0
    starts = heldout_starts(task, bench.starts)
    robots = space.sample(np.random.default_rng(ROBOT_SEED), bench.starts)
    ev = out / "eval"
    refs = {
        "full_horizon": PolicySpec("full", "full horizon (knows the robot)", None, (("model_params", True),), True),
        "lqr": PolicySpec("lqr", "LQR (model)"),
    }
    if bench.model_reference:
        refs["full_horizon_model"] = PolicySpec("full", "full horizon (model)")
    reference = {k: closed_loop(bench, s, starts, robots, workers, ev / f"{k}.json") for k, s in refs.items()}
    methods = bench.methods()
    per_seed: dict[str, list[dict[str, Any]]] = {m: [] for m in (*methods, "nominal_estimate")}
    for seed in range(bench.seeds):
        for method in methods:
            run = runs[(method, seed)]
            net = str(run / "network.pt")
            spec = PolicySpec("mpc", method, net, mpc_options(bench, estimating=method != "nominal"))
            row = closed_loop(bench, spec, starts, robots, workers, ev / f"{method}-seed{seed}.json")
            row = {"seed": seed, **row, **robust_validation(bench.task, run)}
            row["solves"] = _solves(run)
            per_seed[method].append(row)
            if method == "nominal":
                spec = PolicySpec("mpc", "nominal_estimate", net, mpc_options(bench, estimating=True))
                extra = closed_loop(bench, spec, starts, robots, workers, ev / f"nominal_estimate-seed{seed}.json")
                per_seed["nominal_estimate"].append({"seed": seed, **extra})

    def med(method: str, key: str = "success_rate") -> float:
        return float(np.median([r[key] for r in per_seed[method]]))

    def col(method: str, key: str = "success_rate") -> list[float]:
        return [float(r[key]) for r in per_seed[method]]

    block = {
        "theta_box": space.box(),
        "theta_nominal": space.as_dict(task.theta),
        "seeds": bench.seeds,
        "budget": bench.budget,
        "starts": bench.starts,
        "adversarial_success_rate": med("adversarial"),
        "uniform_success_rate": med("uniform"),
        "nominal_success_rate": med("nominal"),
        "full_horizon_success_rate": reference["full_horizon"]["success_rate"],
        "grad_theta_fd_max_rel_error": grad_theta_fd_error(bench.task, bench.fd_points),
        "nominal_estimate_success_rate": med("nominal_estimate"),
        "full_horizon_model_success_rate": reference.get("full_horizon_model", {}).get("success_rate", float("nan")),
        "lqr_success_rate": reference["lqr"]["success_rate"],
        "validation": {
            m: {"mse_initial": med(m, "mse_initial"), "mse_all_knots": med(m, "mse_all_knots")} for m in methods
        },
        "paired_adversarial_minus_uniform": {
            "success_rate": paired_test(col("adversarial"), col("uniform")),
            # uniform minus adversarial: positive (a "win") when the adversary's error is the lower one
            "mse_all_knots_reduction": paired_test(
                col("uniform", "mse_all_knots"), col("adversarial", "mse_all_knots")
            ),
            "mse_initial_reduction": paired_test(col("uniform", "mse_initial"), col("adversarial", "mse_initial")),
        },
        "paired_adversarial_minus_nominal": {"success_rate": paired_test(col("adversarial"), col("nominal"))},
        **(
            {
                "closed_loop_success_rate": med("closed-loop"),
                "paired_closed_loop_minus_uniform": {"success_rate": paired_test(col("closed-loop"), col("uniform"))},
            }
            if "closed-loop" in methods
            else {}
        ),
        "per_seed": {m: [{k: v for k, v in r.items() if k != "success"} for r in rows] for m, rows in per_seed.items()},
        "deployed": {
            "learned": "LimitedLookaheadMPC(task, net, horizon, trust_region, model_params=True, estimate_robot=True)",
            "nominal": "LimitedLookaheadMPC(task, net, horizon, trust_region)",
            "options": dict(mpc_options(bench, estimating=True)),
        },
        "train_settings": {flat_name(k): (list(v) if isinstance(v, tuple) else v) for k, v in bench.train.items()},
        "robot_seed": ROBOT_SEED,
        "train_wall_s": round(train_s, 1),
    }
    return block


def plot(block: dict[str, Any], path: Path, task_name: str) -> None:
    """Two panels: robust closed-loop success per controller (bars: medians over seeds, dots: seeds) and the
    validation error over robots per method (seeds as dots)."""
    import matplotlib  # the only import made here: the backend is chosen before pyplot, by the one function that draws

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(13, 4.2), constrained_layout=True)
    learned = ["adversarial", "uniform", "nominal_estimate", "nominal"]
    labels = ["adversarial\nover Theta", "uniform\nover Theta", "nominal net\n+ estimate", "nominal net\n(model)"]
    if "closed-loop" in block["per_seed"]:
        learned.insert(2, "closed-loop")
        labels.insert(2, "closed-loop\nover Theta")
    refs = [("lqr", "LQR\n(model)"), ("full_horizon", "full horizon\n(true robot)")]
    per_seed = block["per_seed"]
    for i, m in enumerate(learned):
        values = [r["success_rate"] for r in per_seed[m]]
        ax.bar(i, np.median(values), color="C0" if "nominal" not in m else "C7", alpha=0.7)
        ax.plot(np.full(len(values), i) + np.linspace(-0.15, 0.15, len(values)), values, "k.", ms=5)
    for j, (key, _) in enumerate(refs):
        ax.bar(len(learned) + j, block[f"{key}_success_rate"], color="C2", alpha=0.7)
    ax.set_xticks(range(len(learned) + len(refs)), labels + [lab for _, lab in refs], fontsize=8)
    ax.set_ylabel(f"success over {block['starts']} starts x robots")
    ax.set_ylim(0, 1.05)
    ax.set_title(f"{task_name}: robust closed loop, {block['budget']} solves per network")
    trained = [m for m in ("adversarial", "uniform", "closed-loop", "nominal") if m in per_seed]
    for i, m in enumerate(trained):
        values = [r["mse_all_knots"] for r in per_seed[m]]
        bx.plot(np.full(len(values), i), values, "o", color="C0" if m != "nominal" else "C7")
        bx.plot([i - 0.2, i + 0.2], [np.median(values)] * 2, "k-")
    bx.set_xticks(range(len(trained)), [m if m == "nominal" else f"{m}\nover Theta" for m in trained])
    bx.set_yscale("log")
    bx.set_ylabel("validation mse_all_knots over robots")
    bx.set_title("value error over X0 x Theta (seeds)")
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _solves(run: Path) -> int:
    metrics = json.loads((run / "metrics.json").read_text())["metrics"]
    return int(metrics[-1]["solves"])


#: Rows of the report's closed-loop table: (per_seed key, label).
REPORT_ROWS = (
    ("adversarial", "adversarial network over robots, estimating MPC"),
    ("uniform", "uniform network over robots, estimating MPC"),
    ("closed-loop", "closed-loop sampler over robots, estimating MPC"),
    ("nominal_estimate", "nominal network, estimating MPC"),
    ("nominal", "nominal network, MPC on the model"),
)


def _pct(value: float) -> str:
    return "n/a" if not np.isfinite(value) else f"{100 * value:.1f} %"


def write_bench_report(result: dict[str, Any], out: Path) -> Path:
    """``report.md``/``report.html`` in ``out``: per task the figure, closed-loop success per controller and seed,
    validation over ``X0 x Theta``, the seed-paired tests and the dual-gradient check."""
    sections = []
    for task, block in result.items():
        if task == "machine" or "per_seed" not in block:
            continue  # the machine, or a task with only bench_robust.py's blocks (its shipped robust MPC)
        figure = out / task / "robust.png"
        figure.parent.mkdir(parents=True, exist_ok=True)
        plot(block, figure, task)
        per_seed = block["per_seed"]
        seeds = int(block["seeds"])
        rows = []
        for key, label in REPORT_ROWS:
            if key in per_seed:
                rates = [r["success_rate"] for r in per_seed[key]]
                rows.append([label, *(_pct(r) for r in rates), _pct(float(np.median(rates)))])
        for key, label in (("lqr", "LQR on the model"), ("full_horizon", "full-horizon MPC that knows the robot")):
            rows.append([label, *([""] * seeds), _pct(block[f"{key}_success_rate"])])
        validation = [
            [m, f"{v['mse_initial']:.3g}", f"{v['mse_all_knots']:.3g}"] for m, v in block["validation"].items()
        ]
        paired = [
            [
                name.removeprefix("paired_").replace("_", " "),
                metric,
                t["median_difference"],
                t["wins"],
                t["losses"],
                t["p"],
            ]
            for name, tests in block.items()
            if name.startswith("paired_")
            for metric, t in tests.items()
        ]
        sections.append(
            Section(
                f"{task}: robots that are not the model",
                [
                    f"{block['starts']} held-out X0 starts, each simulated on its own robot drawn from Theta "
                    f"({', '.join(f'`{k}` {lo:g}-{hi:g}' for k, (lo, hi) in block['theta_box'].items())}); the same "
                    f"starts and robots for every controller and seed. {seeds} paired seeds, {block['budget']} solves "
                    f"per network. Learned MPCs: `{block['deployed']['learned']}`; options "
                    f"`{block['deployed']['options']}`. The dual dV/dtheta against central differences of re-solved "
                    f"values: max relative error {block['grad_theta_fd_max_rel_error']:.2g}.",
                ],
                [
                    Table(["controller", *(f"seed {k}" for k in range(seeds)), "median"], rows),
                    Table(["network", "validation mse_initial (median)", "mse_all_knots (median)"], validation),
                    Table(["comparison", "metric", "median difference", "wins", "losses", "Wilcoxon p"], paired),
                ],
                [
                    (
                        str(figure.relative_to(out)),
                        "Success over starts x robots per seed (dots) and median (bars); "
                        "validation error over X0 x Theta",
                    )
                ],
            )
        )
    machine_info = result.get("machine", {})
    sections.append(Section("Machine", [f"`{json.dumps(machine_info)}`"]))
    return write_report(out, "Robust control over robots (bench_param_adversary)", sections)


def configured(task: str, args: argparse.Namespace) -> ParamBenchConfig:
    """The run's settings for ``task``: :meth:`ParamBenchConfig.for_task` with the command line's overrides."""
    bench = ParamBenchConfig.for_task(task, args.quick)
    for name in ("seeds", "budget", "starts"):
        if getattr(args, name) is not None:
            setattr(bench, name, int(getattr(args, name)))
    bench.model_reference = bool(args.model_reference)
    bench.closed_loop = bool(args.closed_loop)
    return bench


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="a minutes-long check of the pipeline")
    parser.add_argument("--tasks", default="acrobot", help="comma-separated tasks (acrobot, glider)")
    parser.add_argument("--seeds", type=int, default=None)
    parser.add_argument("--budget", type=int, default=None, help="solves per network")
    parser.add_argument("--starts", type=int, default=None, help="closed-loop starts (each on its own robot)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", default=None, help="work directory (default /tmp/seagul-bench-param-adversary)")
    parser.add_argument("--model-reference", action="store_true", help="also the full-horizon MPC on the model (slow)")
    parser.add_argument("--closed-loop", action="store_true", help="also the closed-loop sampler over robots")
    parser.add_argument("--update", default=None, metavar="JSON", help="also merge the result into this file")
    parser.add_argument("--figure", default=None, metavar="PNG", help="write the figure of the first task here")
    parser.add_argument(
        "--report-from", default=None, metavar="JSON", help="only write the report of a stored result into --out"
    )
    parser.add_argument(
        "--dry-run", action="store_true", help="print each task's settings and trained methods as JSON; run nothing"
    )
    args = parser.parse_args(argv)
    out = Path(args.out or f"/tmp/seagul-bench-param-adversary{'-quick' if args.quick else ''}")
    if args.report_from:
        print(write_bench_report(json.loads(Path(args.report_from).read_text()), out))
        return 0
    benches = [configured(task, args) for task in args.tasks.split(",")]
    if args.dry_run:
        print(json.dumps({b.task: {**asdict(b), "methods": b.methods()} for b in benches}, default=str))
        return 0
    result: dict[str, Any] = {}
    t0 = time.perf_counter()
    for bench in benches:
        task = bench.task
        result[task] = run_task(bench, out / task, args.workers)
        if args.figure and len(result) == 1:
            plot(result[task], Path(args.figure), task)
    result["machine"] = {**machine("torch"), "wall_s": round(time.perf_counter() - t0, 1)}
    if args.update:
        path = Path(args.update)
        merged = json.loads(path.read_text()) if path.is_file() else {}
        merged.update(result)
        path.write_text(json.dumps(merged, indent=1) + "\n")
    print(f"report: {write_bench_report(result, out)}", file=sys.stderr)
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
