"""A learned short-horizon MPC on the DeepMind Control Suite's pendulum and cart-pole, scored by dm_control's own
reward.

Usage::

    nice -n 5 .venv/bin/python benchmarks/bench_dmc_learned.py train [--domain pendulum] [--sampler uniform] \\
        [--budget 1500] [--seed 0]
    nice -n 5 .venv/bin/python benchmarks/bench_dmc_learned.py tune NETWORK [--domain pendulum] [--horizons 5 10] \\
        [--taus 2 5 8] [--dts 0.02] [--holds 1] [--countdowns 0 10] [--seeds 100-119]
    nice -n 5 .venv/bin/python benchmarks/bench_dmc_learned.py evaluate NETWORK... --solves B... [--domain pendulum] \\
        [--horizon 5] [--tau 5] [--dt 0.02] [--hold 1] [--seeds 0-9] [--tuning TUNE.jsonl...] [--tuned-on NETWORK] \\
        [--json benchmarks/results/dmc_learned.json]
    nice -n 5 .venv/bin/python benchmarks/bench_dmc_learned.py labels RUN_DIR
    nice -n 5 .venv/bin/python benchmarks/bench_dmc_learned.py guesses [--angles 0.3 0.8 1.2 1.8 2.4 3.0]
    nice -n 5 .venv/bin/python benchmarks/bench_dmc_learned.py trace NETWORK --seed S [--horizon 5] [--tau 5] \\
        [--domain pendulum]

Measured results, the choices below and why: docs/experiments/dmc-learned.md.

Each ``--domain`` (:data:`DOMAINS`) is one suite env with its training recipe and default deployment:

* ``pendulum`` (``dm_control/pendulum-swingup-v0``): ``train`` fits ``V(x, tau)`` of ``dmc_pendulum``
  (:mod:`seagul_envs.tasks.dmc.pendulum`: cost ``1 - cos(hinge) + 0.01 u^2``, 10 s to go, 100 intervals of 0.1 s)
  from the task's own starts (the suite's: any hinge angle at rest), 2 x 64 network, 50 solves per round, one
  worker;
* ``pendulum_box``: the same task with the cart-pole's recipe: starts drawn uniformly over the whole swing
  (``train_box``: hinge +-pi, hinge velocity +-8 rad/s, the fastest an optimal swing-up moves is about 9 rad/s),
  100 solves per round, two workers; its networks are ``dmc_pendulum_uniform-box_b<budget>_seed<k>.pt``
  (``Domain.network_tag``);
* ``cartpole`` (``dm_control/cartpole-swingup-v0``): ``V(x, tau)`` of ``dmc_cartpole`` (cost ``1 - r``, the
  suite's smooth reward itself, 4 s to go, 80 intervals of 0.05 s) from starts drawn uniformly over a box of the
  whole swing (``train_box``: slider +-1.2 m, hinge +-pi, slider velocity +-3 m/s, hinge velocity +-7 rad/s, what an
  optimal swing-up from rest spans: the suite's own starts are a 0.03-wide box around hanging at rest and would
  teach the value nothing about the swing), 2 x 128 network, 100 solves per round, two workers, the trajectory
  optimizer's default plan;
* ``cartpole_sparse`` (``dm_control/cartpole-swingup_sparse-v0``): the same task and the same networks (the
  suite's sparse task has the same physics; only its reward differs), deployed and scored in the sparse env.

``--sampler closed-loop`` spends half the budget on those uniform starts and the rest in rounds of the closed-loop
sampler (:mod:`seagul_learn.closed_loop`): 20 episodes a round from the same box, each flown by the LQR-guarded
lookahead of the deployment's ``N`` intervals deciding once per interval (the training task's control period is set
to the transcription step, which the sampler needs so that every plan's end is a tail of the task's problem), and
half of each round's tail solves from the planned terminal states, half from the states the episodes visited.

Training uses the project's trainer (:func:`seagul_learn.training.train`, ``TrainConfig(task=..., sampler=...)``)
into ``/tmp/<network name>`` (:func:`run_dir`; with ``bench_train.json``, the run's wall time) and copies the
network to ``benchmarks/results/networks/<task>_<sampler>_b<budget>_seed<k>.pt``. Angles are periodic
(``Task.periodic``): the network's input has ``(cos q, sin q)`` in their place.

The pendulum's trajectory optimizer attempts [choice]: ``hold`` (every knot at the start state), then ``line`` and
``goal``.
From the task's default plan (``line``, ``goal``) IPOPT converged to a point of local infeasibility on 18 of 20
random suite starts; ``hold`` first solves about half. ``labels`` tabulates a run's solves by the start's distance
from upright (which succeed, their values, whether the solved trajectories end balanced) and ``guesses`` compares
the plan with IPOPT from energy-pumping initial guesses (:func:`pumping_guess`) on a few starts: the labels'
quality is the weak point of this recipe (docs/experiments/dmc-learned.md).

``tune`` and ``evaluate`` deploy the learned MPC exactly as ``seagul evaluate --dmc`` does
(:func:`seagul_learn.dmc_eval.learned_dmc_controller` with a :class:`~seagul_learn.dmc_eval.DMCDeployment`:
``LimitedLookaheadMPC(task, network, horizon=N)`` with the task's defaults, an interval ``dt``, a decision every
``hold`` control steps, the cart-pole's rail bound a penalty in the lookahead) in dm_control's own episodes
(:func:`seagul_control.dmc.run_dmc_episode`). ``--dts`` are the MPC's intervals; without ``--holds`` each ``dt`` is
also the decision period (the pendulum: 0.02 s, its control period); ``--holds 1`` decides at every control step
over intervals of ``dt`` (the cart-pole: 0.05 s intervals, decisions every 0.01 s; the pendulum: 0.1 s intervals,
decisions every 0.02 s). ``evaluate`` writes (and merges into an existing file, one block per env) ``{"tasks":
{env_id: {"rows": [{"controller", "scores", "mean", "std", "seeds", "decision_ms_median", "decision_ms_p95", "hold",
"solves", "network", "train_wall_s", "failed_solves", "budget_solves", "labels"}], "seeds", "tuning_seeds", "params",
"tuned_on", "wide", "tuning", "command", "machine", ...}}, "variants": {env_id: {"rows": [...], "tuning": [...]}}}``:
the rows of ``benchmarks/results/dmc.json`` plus the network's file, training budget and (when its run directory is
still there) training wall time, failed solves and (pendulum) ``labels``, the tuning lines the setting was chosen by
(a block of other networks that ``evaluate`` replaces moves under ``"variants"``: each row with its command and its
``wide`` scores, its tuning lines with the network they were measured on), and (``--wide-seeds``, else None) ``wide``:
``{"seeds", "rows": [{"network", "scores", "mean", "std"}], "score_mean", "score_std"}``, every network on a wider set
of reset seeds (the published scores are means over many episodes; ten of them carry about 30 points of noise).

The time to go [choice]: the suite's episode is 1,000 control steps (the pendulum 20 s, the cart-pole 10 s) scored
at every step, while the network is the value of a finite problem ``V(x, tau)`` (``tau <= 10`` s, the cart-pole's
``<= 4`` s). By default the MPC is given a **constant**
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
import math
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._common import machine, parse_seeds  # noqa: E402
from seagul_envs import Task, make_task  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
NETWORKS = RESULTS / "networks"
TUNING_SEEDS = tuple(range(100, 120))
#: The training run's own record (wall time, machine), written into its output directory.
TRAIN_RECORD = "bench_train.json"


@dataclass(frozen=True)
class Domain:
    """One suite env's training recipe and default deployment (module docstring; ``--domain``)."""

    name: str
    env_id: str
    task: str
    solver_options: dict[str, Any] | None
    """The trajectory optimizer's attempts (None: the task's default plan)."""
    train_box: tuple[tuple[float, ...], tuple[float, ...]] | None
    """The box the uniform sampler draws starts from (None: the task's X0)."""
    hidden: tuple[int, ...]
    solves_per_round: int
    workers: int
    deployment: Any
    """The :class:`~seagul_learn.dmc_eval.DMCDeployment` ``evaluate`` uses unless told otherwise."""
    network_tag: str = ""
    """Added to the sampler's name in the committed networks' file names (recipes of one task apart)."""


def _domains() -> dict[str, Domain]:
    from seagul_learn.dmc_eval import DEFAULT_DEPLOYMENTS

    pendulum = "dm_control/pendulum-swingup-v0"
    cartpole = "dm_control/cartpole-swingup-v0"
    cartpole_recipe = {
        "task": "dmc_cartpole",
        "solver_options": None,
        "train_box": ((-1.2, -math.pi, -3.0, -7.0), (1.2, math.pi, 3.0, 7.0)),
        "hidden": (128, 128),
        "solves_per_round": 100,
        "workers": 2,
    }
    sparse = "dm_control/cartpole-swingup_sparse-v0"
    return {
        "pendulum": Domain(
            name="pendulum",
            env_id=pendulum,
            task="dmc_pendulum",
            solver_options={"plan": ["ipopt:hold", "ipopt:line", "ipopt:goal"]},
            train_box=None,
            hidden=(64, 64),
            solves_per_round=50,
            workers=1,
            deployment=DEFAULT_DEPLOYMENTS[pendulum],
        ),
        "pendulum_box": Domain(
            name="pendulum_box",
            env_id=pendulum,
            task="dmc_pendulum",
            solver_options={"plan": ["ipopt:hold", "ipopt:line", "ipopt:goal"]},
            train_box=((-math.pi, -8.0), (math.pi, 8.0)),
            hidden=(64, 64),
            solves_per_round=100,
            workers=2,
            deployment=DEFAULT_DEPLOYMENTS[pendulum],
            network_tag="box",
        ),
        "cartpole": Domain(
            name="cartpole",
            env_id=cartpole,
            deployment=DEFAULT_DEPLOYMENTS[cartpole],
            **cartpole_recipe,
        ),
        "cartpole_sparse": Domain(
            name="cartpole_sparse",
            env_id=sparse,
            deployment=DEFAULT_DEPLOYMENTS[sparse],
            **cartpole_recipe,
        ),
    }


DOMAINS = _domains()
#: The pendulum's attempts and env id, used by its diagnostics below (``labels``, ``guesses``, ``trace``).
SOLVER_OPTIONS: dict[str, Any] = dict(DOMAINS["pendulum"].solver_options or {})
ENV_ID = DOMAINS["pendulum"].env_id


def domain_task(domain: Domain, training: bool = False) -> Task:
    """The domain's task; ``training``: with X0 replaced by ``train_box``."""
    task = make_task(domain.task)
    if training and domain.train_box is not None:
        low, high = (np.asarray(b, dtype=float) for b in domain.train_box)
        task = dataclasses.replace(task, x0_low=low, x0_high=high)
    return task


def pendulum_task() -> Task:
    """``dmc_pendulum`` (its hinge periodic, ``(0,)``)."""
    return domain_task(DOMAINS["pendulum"])


#: ``train --guess``: the trajectory optimizer's plan (``SOLVER_OPTIONS``), IPOPT from energy-pumping guesses, or
#: both with the lowest converged value kept (``multistart``).
GUESSES = ("plan", "pumping", "multistart")
#: The pumping guesses' gain and kicks (``pumping_batch_solver``; ``guesses`` measured gain 2 lowest on 5 of 6 starts).
PUMPING_GAIN = 2.0
PUMPING_KICKS = (1.0, -1.0)


def network_path(sampler: str, budget: int, seed: int, guess: str = "plan", domain: str = "pendulum") -> Path:
    """The committed network of a training run (the sparse cart-pole deploys the cart-pole's: one task, one value)."""
    d = DOMAINS[domain]
    label = sampler + (f"-{d.network_tag}" if d.network_tag else "") + ("" if guess == "plan" else f"-{guess}")
    return NETWORKS / f"{d.task}_{label}_b{budget}_seed{seed}.pt"


def train_config(sampler: str, budget: int, seed: int, domain: str = "pendulum") -> Any:
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

    d = DOMAINS[domain]
    task = domain_task(d, training=True)
    options: Any = UniformOptions()
    if sampler == "closed-loop":
        # The collector decides once per transcription interval (its plans' ends are then tails of the task's
        # problem, which the sampler requires) over the deployment's number of intervals, interpreted.
        task = dataclasses.replace(task, control_period=task.step_bounds[0])
        options = ClosedLoopOptions(
            uniform_solves=budget // 2, horizon=d.deployment.horizon, jit=False, visited_fraction=0.5
        )
    per_round = d.solves_per_round
    return TrainConfig(
        task=task,
        seed=seed,
        budget=budget,
        sampler=options,
        network=NetworkConfig(hidden=d.hidden),
        schedule=ScheduleConfig(
            solves_per_round=per_round, train_steps_per_round=1000, pretrain_solves=per_round, pretrain_steps=1000
        ),
        refit=RefitConfig(steps=20000),
        validate=False,
        solver_options=None if d.solver_options is None else dict(d.solver_options),
        runtime=RuntimeConfig(workers=d.workers, progress=False),
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


def train(sampler: str, budget: int, seed: int, out: Path, guess: str = "plan", domain: str = "pendulum") -> Path:
    """Train, copy the network into ``benchmarks/results/networks`` and return its path."""
    from seagul_learn.training import train as run

    if guess != "plan" and DOMAINS[domain].task != "dmc_pendulum":
        raise ValueError(f"--guess {guess} exists for the pendulum only, not {domain!r}")
    start = time.perf_counter()
    if guess == "plan":
        run(train_config(sampler, budget, seed, domain), out)
    else:
        solver = pumping_batch_solver(with_plan=guess == "multistart")
        run(train_config(sampler, budget, seed, domain), out, batch_solver=solver, solver_name=f"{guess}-bench")
    wall = time.perf_counter() - start
    target = network_path(sampler, budget, seed, guess, domain)
    target.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(out / "network.pt", target)
    record = {"network": target.name, "train_wall_s": round(wall, 1), "machine": machine("torch")}
    (out / TRAIN_RECORD).write_text(json.dumps(record, indent=1) + "\n")
    print(f"trained in {wall:.0f} s -> {target}", file=sys.stderr)
    return target


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


def deployment(
    domain: Domain, horizon: int, tau_v: float, dt: float, hold: int | None, path_bounds: str | None = None
) -> Any:
    """The :class:`~seagul_learn.dmc_eval.DMCDeployment` of a setting: ``hold`` None decides every ``dt`` (``dt`` a
    multiple of the control period), else every ``hold`` control steps over a lookahead of ``dt`` intervals;
    everything else (the path bounds unless ``path_bounds`` says) as the domain deploys it."""
    period = make_task(domain.task).control_period
    steps = round(dt / period) if hold is None else hold
    interval = None if math.isclose(steps * period, dt) else dt
    bounds = domain.deployment.path_bounds if path_bounds is None else path_bounds
    return dataclasses.replace(
        domain.deployment, horizon=horizon, time_to_go=tau_v, hold=steps, dt=interval, path_bounds=bounds
    )


def suite_controller(domain: Domain, network: Any, setting: Any, countdown: float = 0.0) -> Any:
    """The learned MPC as ``seagul evaluate --dmc`` deploys it (:func:`seagul_learn.dmc_eval.learned_dmc_controller`);
    ``countdown > 0``: the time to go counts down instead (:func:`time_to_go`)."""
    from seagul_learn.dmc_eval import learned_dmc_controller

    deployed = learned_dmc_controller(domain.env_id, network, setting)
    return deployed if countdown <= 0 else controller(deployed.policy, float(setting.time_to_go), countdown)


def score(domain: Domain, network: Any, setting: Any, seeds: list[int], countdown: float = 0.0) -> dict[str, Any]:
    """dm_control's scores of the learned MPC on ``seeds`` with the row's timing fields (``bench_dmc.score_row``'s
    row without its controller name)."""
    from benchmarks.bench_dmc import score_row

    ctrl = suite_controller(domain, network, setting, countdown)
    row = score_row(domain.env_id, "learned MPC", lambda _seed: ctrl, seeds, hold=setting.hold)
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
    domain: str = "pendulum",
    holds: tuple[int | None, ...] = (None,),
    path_bounds: str | None = None,
) -> list[dict[str, Any]]:
    """Mean score on tuning seeds (``TUNING_SEEDS``, never 0-9) of every (hold, dt, horizon, countdown, tau_V); one
    JSON line each."""
    d = DOMAINS[domain]
    network = load_network(path)
    out = []
    for hold in holds:
        for dt in dts:
            for horizon in horizons:
                for countdown in countdowns:
                    for tau_v in taus:
                        setting = deployment(d, horizon, tau_v, dt, hold, path_bounds)
                        row = score(d, network, setting, seeds, countdown)
                        line = {
                            "horizon": horizon,
                            "dt": dt,
                            "tau_v": tau_v,
                            "countdown": countdown,
                            "path_bounds": setting.path_bounds,
                            **row,
                        }
                        print(json.dumps(line), flush=True)
                        out.append(line)
    return out


#: The fields of a tuning line kept in the evaluation's JSON.
TUNE_KEYS = (
    "horizon",
    "dt",
    "path_bounds",
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
    """One recorded episode of the pendulum's learned MPC: its score and the hinge angle, velocity and action every
    ``every`` control steps (1 s by default)."""
    from seagul_control.dmc import run_dmc_episode

    d = DOMAINS["pendulum"]
    setting = deployment(d, horizon, tau_v, pendulum_task().control_period, None)
    ctrl = suite_controller(d, load_network(path), setting)
    episode = run_dmc_episode(ENV_ID, ctrl, seed, record=True)
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


def trace_states(path: Path, domain: str, seed: int, every: int = 10, path_bounds: str | None = None) -> dict[str, Any]:
    """One recorded episode of the learned MPC as the domain deploys it: its score, every state coordinate every
    ``every`` control steps, and each coordinate's largest magnitude and the control steps where the state left the
    task's state bounds (the cart-pole's rail: dm_control's soft stop acts there, which the task does not model)."""
    from seagul_control.dmc import run_dmc_episode

    d = DOMAINS[domain]
    task = make_task(d.task)
    setting = d.deployment if path_bounds is None else dataclasses.replace(d.deployment, path_bounds=path_bounds)
    episode = run_dmc_episode(d.env_id, suite_controller(d, load_network(path), setting), seed, record=True)
    states = np.asarray(episode.states)
    outside = np.where(np.any((states < task.x_low) | (states > task.x_high), axis=1))[0]
    return {
        "network": path.name,
        "domain": domain,
        "seed": seed,
        "path_bounds": setting.path_bounds,
        "score": round(float(episode.score), 3),
        "state_names": list(task.state_names),
        "max_abs": [round(float(v), 3) for v in np.abs(states).max(axis=0)],
        "steps_outside_bounds": int(outside.size),
        "outside_from_to": [int(outside[0]), int(outside[-1])] if outside.size else None,
        "t": [round(k * task.control_period, 2) for k in range(0, len(states), every)],
        "states": [[round(float(v), 3) for v in row] for row in states[::every]],
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
    path: Path,
    horizon: int,
    tau_v: float,
    dt: float,
    seeds: list[int],
    solves: int,
    countdown: float = 0.0,
    domain: str = "pendulum",
    hold: int | None = None,
) -> dict[str, Any]:
    d = DOMAINS[domain]
    setting = deployment(d, horizon, tau_v, dt, hold)
    row = score(d, load_network(path), setting, seeds, countdown)
    name = f"learned_mpc_N{horizon}_dt{dt:g}_tau{tau_v:g}" + (f"_countdown{countdown:g}" if countdown > 0 else "")
    return {
        "controller": name,
        "horizon": horizon,
        "dt": dt,
        "tau_v": tau_v,
        "time_to_go": tau_v,
        "countdown": countdown,
        **row,
        "solves": solves,
        "network": _relative(path),
        "guess": next((g for g in GUESSES[1:] if f"-{g}_" in path.name), "plan"),
        **training_record(path, d),
    }


def wide(networks: list[Path], domain: Domain, setting: Any, seeds_text: str) -> dict[str, Any]:
    """Every network's scores on the reset seeds ``seeds_text`` (``--wide-seeds``: more episodes than the
    evaluation seeds, for a mean that can be set beside published means over many episodes)."""
    seeds = parse_seeds(seeds_text)
    rows = []
    for path in networks:
        row = score(domain, load_network(path), setting, seeds)
        rows.append({"network": _relative(path), **{k: row[k] for k in ("scores", "mean", "std")}})
    pooled = [s for row in rows for s in row["scores"]]
    return {
        "seeds": seeds,
        "rows": rows,
        "score_mean": round(float(np.mean(pooled)), 3),
        "score_std": round(float(np.std(pooled)), 3),
    }


def _wide_of(block: dict[str, Any], network: str) -> dict[str, Any] | None:
    """The ``wide`` row of ``network`` in an evaluated block (its scores on the wider seeds), or None."""
    wide_block = block.get("wide") or {}
    row = next((r for r in wide_block.get("rows", []) if r["network"] == network), None)
    return None if row is None else {"seeds": wide_block["seeds"], **row}


def _relative(path: Path) -> str:
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)


def run_dir(path: Path) -> Path:
    """``train``'s default output directory of the network ``path``."""
    return Path("/tmp") / path.stem


def training_record(path: Path, domain: Domain) -> dict[str, Any]:
    """The training run's wall time, failed solves and (pendulum) :func:`labels`, when its output directory
    (``run_dir``) is still there."""
    out: dict[str, Any] = {}
    directory = run_dir(path)
    if (directory / TRAIN_RECORD).exists():
        out["train_wall_s"] = json.loads((directory / TRAIN_RECORD).read_text())["train_wall_s"]
    if (directory / "metrics.json").exists():
        metrics = json.loads((directory / "metrics.json").read_text())
        last = metrics["metrics"][-1]
        out["failed_solves"] = int(last["failures"])
        out["budget_solves"] = int(last["solves"])
    if (directory / "dataset" / "records").is_dir() and domain.task == "dmc_pendulum":
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
    tr.add_argument("--domain", default="pendulum", choices=sorted(DOMAINS))
    tu = sub.add_parser("tune")
    tu.add_argument("network", type=Path)
    tu.add_argument("--domain", default="pendulum", choices=sorted(DOMAINS))
    tu.add_argument("--horizons", type=int, nargs="+", default=[10])
    tu.add_argument("--taus", type=float, nargs="+", default=[5.0])
    tu.add_argument("--dts", type=float, nargs="+", default=[0.02], help="the MPC's intervals (s)")
    tu.add_argument("--holds", type=int, nargs="+", default=None, help="control steps per decision (default: dt's)")
    tu.add_argument("--countdowns", type=float, nargs="+", default=[0.0])
    tu.add_argument(
        "--path-bounds",
        choices=("hard", "soft", "none"),
        default=None,
        help="the task's state path bounds in the lookahead (default: the domain's deployment)",
    )
    tu.add_argument("--seeds", default=f"{TUNING_SEEDS[0]}-{TUNING_SEEDS[-1]}")
    la = sub.add_parser("labels")
    la.add_argument("run", type=Path, help="a training run's output directory")
    trc = sub.add_parser("trace")
    trc.add_argument("network", type=Path)
    trc.add_argument("--seed", type=int, required=True)
    trc.add_argument("--horizon", type=int, default=5)
    trc.add_argument("--tau", type=float, default=5.0)
    trc.add_argument(
        "--domain", default="pendulum", choices=sorted(DOMAINS), help="other than the pendulum: trace_states"
    )
    trc.add_argument("--path-bounds", choices=("hard", "soft", "none"), default=None, help="trace_states only")
    gu = sub.add_parser("guesses")
    gu.add_argument("--angles", type=float, nargs="+", default=[0.3, 0.8, 1.2, 1.8, 2.4, 3.0])
    ev = sub.add_parser("evaluate")
    ev.add_argument("network", type=Path, nargs="+")
    ev.add_argument("--domain", default="pendulum", choices=sorted(DOMAINS))
    ev.add_argument("--solves", type=int, nargs="+", required=True, help="each network's training budget")
    ev.add_argument("--horizon", type=int, default=5)
    ev.add_argument("--tau", type=float, default=5.0)
    ev.add_argument("--dt", type=float, default=0.02, help="the MPC's interval (s)")
    ev.add_argument("--hold", type=int, default=None, help="control steps per decision (default: dt's)")
    ev.add_argument("--countdown", type=float, default=0.0)
    ev.add_argument("--seeds", default="0-9")
    ev.add_argument(
        "--wide-seeds",
        default=None,
        help="also score every network on these reset seeds (e.g. 0-99), kept under the block's 'wide'",
    )
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
        out = args.out or run_dir(network_path(args.sampler, args.budget, args.seed, args.guess, args.domain))
        train(args.sampler, args.budget, args.seed, out, args.guess, args.domain)
    elif args.command == "labels":
        for line in labels(args.run):
            print(json.dumps(line))
    elif args.command == "trace":
        if args.domain == "pendulum":
            print(json.dumps(trace(args.network, args.horizon, args.tau, args.seed)))
        else:
            print(json.dumps(trace_states(args.network, args.domain, args.seed, path_bounds=args.path_bounds)))
    elif args.command == "guesses":
        for line in guesses(args.angles):
            print(json.dumps(line), flush=True)
    elif args.command == "tune":
        seeds = parse_seeds(args.seeds)
        if set(seeds) & set(range(10)):
            parser.error("the tuning seeds must not include the evaluation seeds 0-9")
        holds = tuple(args.holds) if args.holds else (None,)
        tune(
            args.network,
            args.horizons,
            args.taus,
            args.dts,
            seeds,
            tuple(args.countdowns),
            args.domain,
            holds,
            args.path_bounds,
        )
    else:
        start = time.perf_counter()
        domain = DOMAINS[args.domain]
        rows = [
            evaluate(
                path,
                args.horizon,
                args.tau,
                args.dt,
                parse_seeds(args.seeds),
                solves,
                args.countdown,
                domain.name,
                args.hold,
            )
            for path, solves in zip(args.network, args.solves, strict=True)
        ]
        setting = deployment(domain, args.horizon, args.tau, args.dt, args.hold)
        block = {
            "rows": rows,
            "seeds": parse_seeds(args.seeds),
            # The reset seeds the tuning lines were measured on (TUNING_SEEDS when none are given).
            "tuning_seeds": sorted(
                {seed for path in args.tuning for line in read_tuning(path) for seed in line["seeds"]}
            )
            or list(TUNING_SEEDS),
            "params": {
                "horizon": args.horizon,
                "dt": args.dt,
                "tau_v": args.tau,
                "countdown": args.countdown,
                "hold": setting.hold,
                "path_bounds": setting.path_bounds,
                "soft_bound_margin": setting.soft_bound_margin,
                "soft_bound_weight": setting.soft_bound_weight,
                "solver_options": domain.solver_options,
                "train_box": None if domain.train_box is None else [list(b) for b in domain.train_box],
            },
            "tuned_on": None if args.tuned_on is None else str(args.tuned_on),
            "wide": None if args.wide_seeds is None else wide(args.network, domain, setting, args.wide_seeds),
            "tuning": [
                {key: line.get(key, 0.0 if key == "countdown" else None) for key in TUNE_KEYS}
                for path in args.tuning
                for line in read_tuning(path)
            ],
            "wall_s": round(time.perf_counter() - start, 1),
            "command": " ".join(["benchmarks/bench_dmc_learned.py", *(argv if argv is not None else sys.argv[1:])]),
            "machine": machine("mujoco", "shimmy", "gymnasium", "torch"),
        }
        previous = json.loads(args.json.read_text()) if args.json is not None and args.json.exists() else {}
        result = {"tasks": {}, **previous}
        if args.variant:
            base = result["tasks"].get(domain.env_id)
            if base is None:
                parser.error(f"--variant needs an existing --json file with {domain.env_id}")
            if base["params"] != block["params"] or base["seeds"] != block["seeds"]:
                parser.error("--variant: the existing file was measured with other settings or seeds")
            variants = result.setdefault("variants", {}).setdefault(domain.env_id, {"rows": []})
            variants["rows"] += [row | {key: block[key] for key in ("command", "wall_s", "machine")} for row in rows]
        else:
            replaced = result["tasks"].get(domain.env_id)
            if replaced and {r["network"] for r in replaced["rows"]} != {r["network"] for r in rows}:
                # Other networks' block: its rows move under "variants" (with their own command), not lost.
                variants = result.setdefault("variants", {}).setdefault(domain.env_id, {"rows": []})
                keep = {key: replaced.get(key) for key in ("command", "wall_s", "machine")}
                variants["rows"] += [
                    row | keep | {"wide": _wide_of(replaced, row["network"])} for row in replaced["rows"]
                ]
                variants.setdefault("tuning", []).extend(
                    line | {"tuned_on": replaced.get("tuned_on")} for line in replaced.get("tuning", [])
                )
            result["tasks"][domain.env_id] = block
        text = json.dumps(result, indent=1)
        if args.json is not None:
            args.json.write_text(text + "\n")
        print(text)


if __name__ == "__main__":
    main()
