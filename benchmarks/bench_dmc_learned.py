"""A learned short-horizon MPC on the DeepMind Control Suite's pendulum, scored by dm_control's own reward.

Usage::

    nice -n 5 .venv/bin/python benchmarks/bench_dmc_learned.py train [--sampler uniform] [--budget 1500] [--seed 0]
    nice -n 5 .venv/bin/python benchmarks/bench_dmc_learned.py tune NETWORK [--horizons 5 10] [--taus 2 5 8] \\
        [--countdowns 0 10] [--seeds 100-119]
    nice -n 5 .venv/bin/python benchmarks/bench_dmc_learned.py evaluate NETWORK... --solves B... [--horizon 5] \\
        [--tau 5] [--seeds 0-9] [--tuning TUNE.jsonl...] [--tuned-on NETWORK] \\
        [--json benchmarks/results/dmc_learned.json]
    nice -n 5 .venv/bin/python benchmarks/bench_dmc_learned.py labels RUN_DIR
    nice -n 5 .venv/bin/python benchmarks/bench_dmc_learned.py guesses [--angles 0.3 0.8 1.2 1.8 2.4 3.0]
    nice -n 5 .venv/bin/python benchmarks/bench_dmc_learned.py trace NETWORK --seed S [--horizon 5] [--tau 5]

Measured results, the choices below and why: docs/experiments/dmc-learned.md.

``train`` fits ``V(x, tau)`` of ``dmc_pendulum`` (:mod:`seagul_envs.tasks.dmc.pendulum`: cost ``1 - cos(hinge) +
0.01 u^2``, 10 s to go, 100 intervals of 0.1 s) with the project's trainer (:func:`seagul_learn.training.train`,
``TrainConfig(task=..., sampler=...)``) into ``/tmp/<network name>`` (:func:`run_dir`; with ``bench_train.json``, the
run's wall time) and copies the network to ``benchmarks/results/networks/dmc_pendulum_<sampler>_b<budget>_seed<k>.pt``.
The task's hinge angle is unbounded (the suite's pendulum spins), so the network is built over its periodic angle
(``Task.periodic = (0,)``: the input ``(cos q, sin q)``); where the checkout's task does not yet declare it,
:func:`pendulum_task` sets it with ``dataclasses.replace``.

The trajectory optimizer's attempts [choice]: ``hold`` (every knot at the start state), then ``line`` and ``goal``.
From the task's default plan (``line``, ``goal``) IPOPT converged to a point of local infeasibility on 18 of 20
random suite starts; ``hold`` first solves about half. ``labels`` tabulates a run's solves by the start's distance
from upright (which succeed, their values, whether the solved trajectories end balanced) and ``guesses`` compares
the plan with IPOPT from energy-pumping initial guesses (:func:`pumping_guess`) on a few starts: the labels'
quality is the weak point of this recipe (docs/experiments/dmc-learned.md).

``tune`` and ``evaluate`` deploy ``LimitedLookaheadMPC(task, network, horizon=N)`` at the suite's control period
(0.02 s, the task's ``control_period``: ``hold`` 1) in dm_control's own episodes
(:func:`seagul_control.dmc.run_dmc_episode` through :class:`~seagul_control.dmc.PredictController`). ``evaluate``
writes ``{"tasks": {env_id: {"rows": [{"controller", "scores", "mean", "std", "seeds", "decision_ms_median",
"decision_ms_p95", "hold", "solves", "network", "train_wall_s", "failed_solves", "budget_solves", "labels"}]}},
"seeds", "tuning_seeds", "params", "tuned_on", "tuning", "command", "machine", ...}``: the rows of
``benchmarks/results/dmc.json`` plus the network's file, training budget and (when its run directory is still there)
training wall time, failed solves and ``labels``, and the tuning lines the setting was chosen by.

The time to go [choice]: the suite's episode is 1,000 steps of 0.02 s (20 s) scored at every step, while the
network is the value of a 10 s problem ``V(x, tau)``, ``tau <= 10`` s. By default the MPC is given a **constant**
time to go ``tau_V + N dt`` (``PredictController(time_to_go=...)``), so its terminal cost is always
``V(x_N, tau_V)``: "the optimal cost of the next ``tau_V`` seconds after the lookahead", a stationary receding-horizon
policy that never enters the MPC's end phase (the suite's episode has no end for the controller to plan for: every
step is paid the same). ``--countdown C`` instead gives ``max(C - t, tau_V + N dt)`` (the training trajectories'
own time to go while ``t < C - tau_V - N dt``). ``N``, ``tau_V`` and the countdown are chosen by ``tune`` on reset
seeds 100-119 (``TUNING_SEEDS``, never the evaluation seeds 0-9).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._common import machine, parse_seeds  # noqa: E402
from seagul_envs import Task, make_task  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
NETWORKS = RESULTS / "networks"
ENV_ID = "dm_control/pendulum-swingup-v0"
TUNING_SEEDS = tuple(range(100, 120))
#: The training run's own record (wall time, machine), written into its output directory.
TRAIN_RECORD = "bench_train.json"
#: The trajectory optimizer's attempts for this task (module docstring).
SOLVER_OPTIONS: dict[str, Any] = {"plan": ["ipopt:hold", "ipopt:line", "ipopt:goal"]}


def pendulum_task() -> Task:
    """``dmc_pendulum`` with its hinge declared periodic (``(0,)``), as the suite task declares it."""
    task = make_task("dmc_pendulum")
    return task if task.periodic else dataclasses.replace(task, periodic=(0,))


#: ``train --guess``: the trajectory optimizer's plan (``SOLVER_OPTIONS``), IPOPT from energy-pumping guesses, or
#: both with the lowest converged value kept (``multistart``).
GUESSES = ("plan", "pumping", "multistart")
#: The pumping guesses' gain and kicks (``pumping_batch_solver``; ``guesses`` measured gain 2 lowest on 5 of 6 starts).
PUMPING_GAIN = 2.0
PUMPING_KICKS = (1.0, -1.0)


def network_path(sampler: str, budget: int, seed: int, guess: str = "plan") -> Path:
    label = sampler if guess == "plan" else f"{sampler}-{guess}"
    return NETWORKS / f"dmc_pendulum_{label}_b{budget}_seed{seed}.pt"


def train_config(sampler: str, budget: int, seed: int) -> Any:
    """The training run's configuration (module docstring)."""
    from seagul_learn.config import (
        ClosedLoopOptions,
        NetworkConfig,
        RefitConfig,
        RuntimeConfig,
        ScheduleConfig,
        TrainConfig,
        UniformOptions,
    )

    options: Any = UniformOptions() if sampler == "uniform" else ClosedLoopOptions(uniform_solves=budget // 2)
    return TrainConfig(
        task=pendulum_task(),
        seed=seed,
        budget=budget,
        sampler=options,
        network=NetworkConfig(hidden=(64, 64)),
        schedule=ScheduleConfig(
            solves_per_round=50, train_steps_per_round=1000, pretrain_solves=50, pretrain_steps=1000
        ),
        refit=RefitConfig(steps=20000),
        validate=False,
        solver_options=dict(SOLVER_OPTIONS),
        runtime=RuntimeConfig(workers=1, progress=False),
    )


def pumping_batch_solver(with_plan: bool = False) -> Any:
    """A batch solver for :func:`seagul_learn.training.train` (``batch_solver=``): every start solved by IPOPT (the
    task's transcription, as the trajectory optimizer builds it) from the energy-pumping guesses
    :func:`pumping_guess` (``PUMPING_GAIN``, each of ``PUMPING_KICKS``), the lowest converged value kept, labelled as
    the optimizer labels its own solutions. ``with_plan``: the trajectory optimizer's own plan (``SOLVER_OPTIONS``)
    is one more candidate (near upright the pumping guesses lead away from the top: their values there are ~6 where
    the plan's are ~0)."""
    from seagul_learn.trajopt import TrajectoryOptimizer

    task = pendulum_task()
    optimizer = TrajectoryOptimizer(task, plan=tuple(SOLVER_OPTIONS["plan"]))
    transcription = optimizer._transcription("ipopt")
    names = [f"ipopt:pumping{kick:+g}" for kick in PUMPING_KICKS]

    def solve_one(x_init: np.ndarray, tau_init: float) -> Any:
        x, tau = optimizer.check_inputs(x_init, tau_init)
        start = time.perf_counter()
        solutions = []
        for kick in PUMPING_KICKS:
            states, inputs = pumping_guess(task, x, PUMPING_GAIN, kick)
            solutions.append(transcription.solve(x, tau, guess=transcription.pack_guess(states, inputs)))
        solved = [sol for sol in solutions if sol.success]
        best = min(solved, key=lambda sol: sol.objective) if solved else None
        if with_plan:
            planned = optimizer.solve(x, tau)
            if planned.success and (best is None or planned.value <= best.objective):
                return planned
        return optimizer._result(
            x,
            tau,
            best if best is not None else solutions[-1],
            success=best is not None,
            iterations=sum(sol.iterations for sol in solutions),
            solve_time=time.perf_counter() - start,
            labels=names,
            transcription=transcription,
        )

    def batch(starts: Any, taus: Any, thetas: Any = None) -> list[Any]:
        return [solve_one(np.asarray(x, dtype=float), float(t)) for x, t in zip(starts, taus, strict=True)]

    return batch


def train(sampler: str, budget: int, seed: int, out: Path, guess: str = "plan") -> Path:
    """Train, copy the network into ``benchmarks/results/networks`` and return its path."""
    from seagul_learn.training import train as run

    start = time.perf_counter()
    if guess == "plan":
        run(train_config(sampler, budget, seed), out)
    else:
        solver = pumping_batch_solver(with_plan=guess == "multistart")
        run(train_config(sampler, budget, seed), out, batch_solver=solver, solver_name=f"{guess}-bench")
    wall = time.perf_counter() - start
    target = network_path(sampler, budget, seed, guess)
    target.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(out / "network.pt", target)
    record = {"network": target.name, "train_wall_s": round(wall, 1), "machine": machine("torch")}
    (out / TRAIN_RECORD).write_text(json.dumps(record, indent=1) + "\n")
    print(f"trained in {wall:.0f} s -> {target}", file=sys.stderr)
    return target


def make_mpc(network: Any, horizon: int, dt: float | None = None) -> Any:
    """``LimitedLookaheadMPC(task, network, horizon=N)`` with the task's defaults (the condensed ``shooting`` solver
    for N <= 10, the ``lqr`` guard ``Vhat + l_f``); ``dt`` None: the task's control period (0.02 s)."""
    from seagul_control.mpc import LimitedLookaheadMPC, MPCOptions

    options = MPCOptions() if dt is None else MPCOptions(dt=dt)
    return LimitedLookaheadMPC(pendulum_task(), network, horizon=horizon, options=options)


def time_to_go(mpc: Any, tau_v: float, countdown: float) -> Any:
    """The MPC's time to go at episode time ``t`` (module docstring): ``max(countdown - t, tau_v + N dt)``; with
    ``countdown = 0`` the constant ``tau_v + N dt``."""
    floor = tau_v + mpc.horizon * mpc.dt
    if countdown <= 0:
        return floor
    return lambda t: max(countdown - t, floor)


def controller(mpc: Any, tau_v: float, countdown: float = 0.0) -> Any:
    """The MPC as a suite controller with the time to go :func:`time_to_go`."""
    from seagul_control.dmc import PredictController

    return PredictController(mpc, time_to_go=time_to_go(mpc, tau_v, countdown), observation_dtype=np.float64)


def score(mpc: Any, tau_v: float, seeds: list[int], hold: int, countdown: float = 0.0) -> dict[str, Any]:
    """dm_control's scores of the MPC on ``seeds`` with the row's timing fields (``bench_dmc.score_row``'s row
    without its controller name)."""
    from benchmarks.bench_dmc import score_row

    row = score_row(ENV_ID, "learned MPC", lambda _seed: controller(mpc, tau_v, countdown), seeds, hold=hold)
    row.pop("controller")
    return row


def load_network(path: Path) -> Any:
    from seagul_learn.value_network import ValueNetwork

    return ValueNetwork.load(path)


def tune(
    path: Path,
    horizons: list[int],
    taus: list[float],
    dts: list[float],
    seeds: list[int],
    countdowns: tuple[float, ...] = (0.0,),
) -> list[dict[str, Any]]:
    """Mean score on tuning seeds (``TUNING_SEEDS``, never 0-9) of every (horizon, dt, tau_V); one JSON line each."""
    network = load_network(path)
    out = []
    for dt in dts:
        hold = round(dt / pendulum_task().control_period)
        for horizon in horizons:
            mpc = make_mpc(network, horizon, dt)
            for countdown in countdowns:
                for tau_v in taus:
                    row = score(mpc, tau_v, seeds, hold, countdown)
                    line = {"horizon": horizon, "dt": dt, "tau_v": tau_v, "countdown": countdown, **row}
                    print(json.dumps(line), flush=True)
                    out.append(line)
    return out


#: The fields of a tuning line kept in the evaluation's JSON.
TUNE_KEYS = (
    "horizon",
    "dt",
    "tau_v",
    "countdown",
    "hold",
    "scores",
    "mean",
    "seeds",
    "decision_ms_median",
    "decision_ms_p95",
)


def read_tuning(path: Path) -> list[dict[str, Any]]:
    """``tune``'s JSON lines in ``path``."""
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


#: Bands of the start's distance from upright ``|hinge|`` (rad) in :func:`labels`.
LABEL_BANDS = ((0.0, 0.5), (0.5, 1.0), (1.0, 1.5), (1.5, 2.0), (2.0, 2.5), (2.5, 3.2))


def labels(run: Path) -> list[dict[str, Any]]:
    """What a training run's solves are, per band of the start's ``|hinge|``: how many, how many succeeded, their
    values, and how many of the solved trajectories end balanced (every knot of the last second within the suite's
    8 degrees of upright) or ever enter that cone."""
    cone = float(np.cos(np.radians(pendulum_task().params.angle_bound_deg)))
    records = [np.load(f, allow_pickle=False) for f in sorted((run / "dataset" / "records").glob("solve-*.npz"))]
    out = []
    for lo, hi in LABEL_BANDS:
        band = [r for r in records if lo <= abs(float(r["x_init"][0])) < hi]
        solved = [r for r in band if bool(r["success"])]
        inside = [np.cos(r["states"][:, 0]) >= cone for r in solved]
        out.append(
            {
                "band_rad": [lo, hi],
                "solves": len(band),
                "succeeded": len(solved),
                "value_median": round(float(np.median([float(r["value"]) for r in solved])), 3) if solved else None,
                "balanced_last_second": int(sum(bool(k[-11:].all()) for k in inside)),
                "ever_in_cone": int(sum(bool(k.any()) for k in inside)),
            }
        )
    return out


def trace(path: Path, horizon: int, tau_v: float, seed: int, every: int = 50) -> dict[str, Any]:
    """One recorded episode of the learned MPC: its score and the hinge angle, velocity and action every ``every``
    control steps (1 s by default)."""
    from seagul_control.dmc import run_dmc_episode

    mpc = make_mpc(load_network(path), horizon)
    episode = run_dmc_episode(ENV_ID, controller(mpc, tau_v), seed, record=True)
    states, actions = np.asarray(episode.states), np.asarray(episode.actions).reshape(-1)
    return {
        "network": path.name,
        "seed": seed,
        "score": round(float(episode.score), 3),
        "t": [round(k * pendulum_task().control_period, 2) for k in range(0, len(actions), every)],
        "hinge": [round(float(q), 3) for q in states[: len(actions) : every, 0]],
        "hinge_vel": [round(float(v), 3) for v in states[: len(actions) : every, 1]],
        "action": [round(float(u), 3) for u in actions[::every]],
    }


def pumping_guess(task: Task, x0: np.ndarray, gain: float, kick: float) -> tuple[np.ndarray, np.ndarray]:
    """States and inputs of the task's 100 intervals under energy pumping ``u = sat(gain * hinge_vel)`` (``kick``
    at rest) and a PD catch ``u = sat(-20 hinge - 3 hinge_vel)`` once ``cos(hinge) > 0.9``, integrated by RK4 at
    the task's substeps (a trajectory optimizer's initial guess)."""
    f = task.dynamics
    h = task.step_bounds[0] / task.rk4_substeps

    def rk4(x: np.ndarray, u: np.ndarray) -> np.ndarray:
        k1 = np.asarray(f(x, u)).ravel()
        k2 = np.asarray(f(x + h / 2 * k1, u)).ravel()
        k3 = np.asarray(f(x + h / 2 * k2, u)).ravel()
        k4 = np.asarray(f(x + h * k3, u)).ravel()
        return x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)

    x = np.asarray(x0, dtype=float).copy()
    states, inputs = [x.copy()], []
    for _ in range(task.num_steps):
        q, v = x
        if np.cos(q) > 0.9:
            u = float(np.clip(-20 * np.arctan2(np.sin(q), np.cos(q)) - 3 * v, -1, 1))
        else:
            u = float(np.clip(gain * v, -1, 1)) if abs(v) > 1e-3 else kick
        for _ in range(task.rk4_substeps):
            x = rk4(x, np.array([u]))
        states.append(x.copy())
        inputs.append([u])
    return np.array(states), np.array(inputs)


def guesses(angles: list[float]) -> list[dict[str, Any]]:
    """The 10 s problem from rest at each ``|hinge|`` in ``angles``: the training's plan (``SOLVER_OPTIONS``) against
    IPOPT from four energy-pumping guesses (:func:`pumping_guess`, gains 2 and 10, both kicks; the lowest kept):
    success, value and when the solution is balanced for good (within 8 degrees from then on)."""
    from seagul_learn.trajopt import TrajectoryOptimizer

    task = pendulum_task()
    cone = float(np.cos(np.radians(task.params.angle_bound_deg)))
    optimizer = TrajectoryOptimizer(task, plan=tuple(SOLVER_OPTIONS["plan"]))
    transcription = optimizer._transcription("ipopt")

    def balanced_from(q: np.ndarray) -> float:
        outside = np.where(np.cos(q) < cone)[0]
        return 0.0 if len(outside) == 0 else round(float((outside[-1] + 1) * task.step_bounds[0]), 2)

    out = []
    for angle in angles:
        x0 = np.array([angle, 0.0])
        plan = optimizer.solve(x0, task.tau_nominal)
        best: dict[str, Any] | None = None
        for gain in (2.0, 10.0):
            for kick in (1.0, -1.0):
                states, inputs = pumping_guess(task, x0, gain, kick)
                sol = transcription.solve(x0, task.tau_nominal, guess=transcription.pack_guess(states, inputs))
                if sol.success and (best is None or sol.objective < best["value"]):
                    q = np.asarray(sol.states)[:, 0]
                    best = {"value": round(float(sol.objective), 3), "balanced_from_s": balanced_from(q)}
        out.append(
            {
                "hinge": angle,
                "plan_success": bool(plan.success),
                "plan_value": round(float(plan.value), 3) if plan.success else None,
                "plan_balanced_from_s": balanced_from(np.asarray(plan.states)[:, 0]) if plan.success else None,
                "pumping": best,
            }
        )
    return out


def evaluate(
    path: Path, horizon: int, tau_v: float, dt: float, seeds: list[int], solves: int, countdown: float = 0.0
) -> dict[str, Any]:
    network = load_network(path)
    mpc = make_mpc(network, horizon, dt)
    hold = round(dt / pendulum_task().control_period)
    row = score(mpc, tau_v, seeds, hold, countdown)
    name = f"learned_mpc_N{horizon}_dt{dt:g}_tau{tau_v:g}" + (f"_countdown{countdown:g}" if countdown > 0 else "")
    return {
        "controller": name,
        "horizon": horizon,
        "dt": dt,
        "tau_v": tau_v,
        "countdown": countdown,
        **row,
        "solves": solves,
        "network": str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path),
        "guess": next((g for g in GUESSES[1:] if f"-{g}_" in path.name), "plan"),
        **training_record(path),
    }


def run_dir(path: Path) -> Path:
    """``train``'s default output directory of the network ``path``."""
    return Path("/tmp") / path.stem


def training_record(path: Path) -> dict[str, Any]:
    """The training run's wall time, failed solves and :func:`labels`, when its output directory (``run_dir``) is still
    there."""
    out: dict[str, Any] = {}
    directory = run_dir(path)
    if (directory / TRAIN_RECORD).exists():
        out["train_wall_s"] = json.loads((directory / TRAIN_RECORD).read_text())["train_wall_s"]
    if (directory / "metrics.json").exists():
        metrics = json.loads((directory / "metrics.json").read_text())
        last = metrics["metrics"][-1]
        out["failed_solves"] = int(last["failures"])
        out["budget_solves"] = int(last["solves"])
    if (directory / "dataset" / "records").is_dir():
        out["labels"] = labels(directory)
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    tr = sub.add_parser("train")
    tr.add_argument("--sampler", default="uniform", choices=("uniform", "closed-loop"))
    tr.add_argument("--budget", type=int, default=1500)
    tr.add_argument("--seed", type=int, default=0)
    tr.add_argument("--out", type=Path, default=None)
    tr.add_argument("--guess", default="plan", choices=GUESSES)
    tu = sub.add_parser("tune")
    tu.add_argument("network", type=Path)
    tu.add_argument("--horizons", type=int, nargs="+", default=[10])
    tu.add_argument("--taus", type=float, nargs="+", default=[5.0])
    tu.add_argument("--dts", type=float, nargs="+", default=[0.02])
    tu.add_argument("--countdowns", type=float, nargs="+", default=[0.0])
    tu.add_argument("--seeds", default=f"{TUNING_SEEDS[0]}-{TUNING_SEEDS[-1]}")
    la = sub.add_parser("labels")
    la.add_argument("run", type=Path, help="a training run's output directory")
    trc = sub.add_parser("trace")
    trc.add_argument("network", type=Path)
    trc.add_argument("--seed", type=int, required=True)
    trc.add_argument("--horizon", type=int, default=5)
    trc.add_argument("--tau", type=float, default=5.0)
    gu = sub.add_parser("guesses")
    gu.add_argument("--angles", type=float, nargs="+", default=[0.3, 0.8, 1.2, 1.8, 2.4, 3.0])
    ev = sub.add_parser("evaluate")
    ev.add_argument("network", type=Path, nargs="+")
    ev.add_argument("--solves", type=int, nargs="+", required=True, help="each network's training budget")
    ev.add_argument("--horizon", type=int, default=5)
    ev.add_argument("--tau", type=float, default=5.0)
    ev.add_argument("--dt", type=float, default=0.02)
    ev.add_argument("--countdown", type=float, default=0.0)
    ev.add_argument("--seeds", default="0-9")
    ev.add_argument("--json", type=Path, default=None)
    ev.add_argument("--tuning", type=Path, nargs="*", default=[], help="tune's JSON lines, kept in the result")
    ev.add_argument(
        "--variant",
        action="store_true",
        help="add the rows to the existing --json file under 'variants' (another recipe, not more training seeds)",
    )
    ev.add_argument("--tuned-on", type=Path, default=None, help="the network the tuning lines were measured with")
    args = parser.parse_args(argv)
    if args.command == "train":
        out = args.out or run_dir(network_path(args.sampler, args.budget, args.seed, args.guess))
        train(args.sampler, args.budget, args.seed, out, args.guess)
    elif args.command == "labels":
        for line in labels(args.run):
            print(json.dumps(line))
    elif args.command == "trace":
        print(json.dumps(trace(args.network, args.horizon, args.tau, args.seed)))
    elif args.command == "guesses":
        for line in guesses(args.angles):
            print(json.dumps(line), flush=True)
    elif args.command == "tune":
        seeds = parse_seeds(args.seeds)
        if set(seeds) & set(range(10)):
            parser.error("the tuning seeds must not include the evaluation seeds 0-9")
        tune(args.network, args.horizons, args.taus, args.dts, seeds, tuple(args.countdowns))
    else:
        start = time.perf_counter()
        rows = [
            evaluate(path, args.horizon, args.tau, args.dt, parse_seeds(args.seeds), solves, args.countdown)
            for path, solves in zip(args.network, args.solves, strict=True)
        ]
        result = {
            "tasks": {ENV_ID: {"rows": rows}},
            "seeds": parse_seeds(args.seeds),
            "tuning_seeds": list(TUNING_SEEDS),
            "params": {
                "horizon": args.horizon,
                "dt": args.dt,
                "tau_v": args.tau,
                "countdown": args.countdown,
                "solver_options": SOLVER_OPTIONS,
            },
            "tuned_on": None if args.tuned_on is None else str(args.tuned_on),
            "tuning": [
                {key: line.get(key, 0.0 if key == "countdown" else None) for key in TUNE_KEYS}
                for path in args.tuning
                for line in read_tuning(path)
            ],
            "wall_s": round(time.perf_counter() - start, 1),
            "command": " ".join(["benchmarks/bench_dmc_learned.py", *(argv if argv is not None else sys.argv[1:])]),
            "machine": machine("mujoco", "shimmy", "gymnasium", "torch"),
        }
        if args.variant:
            if args.json is None or not args.json.exists():
                parser.error("--variant needs an existing --json file")
            previous = json.loads(args.json.read_text())
            if previous["params"] != result["params"] or previous["seeds"] != result["seeds"]:
                parser.error("--variant: the existing file was measured with other settings or seeds")
            variants = previous.setdefault("variants", {}).setdefault(ENV_ID, {"rows": []})
            variants["rows"] += [row | {key: result[key] for key in ("command", "wall_s", "machine")} for row in rows]
            result = previous
        text = json.dumps(result, indent=1)
        if args.json is not None:
            args.json.write_text(text + "\n")
        print(text)


if __name__ == "__main__":
    main()
