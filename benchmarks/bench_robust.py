"""The robust learned MPC on robots that are not the model, against the oracle and the baselines.

Usage::

    .venv/bin/python benchmarks/bench_robust.py [--tasks acrobot] [--seeds 5] [--starts 50] [--workers 2]
        [--out DIR] [--update benchmarks/results/param_adversary.json] [--ship] [--figure-dir docs/figures]
        [--quick] [--dry-run]

Per task, ``--seeds`` networks are trained with the task's recipe ``RobustBenchConfig.recipe``
(``TrainConfig.recipe(task, recipe, seed=s)``, by default :data:`RECIPES`: the acrobot's ``shipped``, the nominal
robot's recipe, and the glider's ``robust-compress``, which learns ``V(x, tau, theta)`` over robots) and each is
deployed as the shipped robust MPC::

    LimitedLookaheadMPC(task, ValueNetwork.load(network), horizon=H, model_params=True, estimate_robot=True)

(``H = RobustBenchConfig.horizon``, ``--horizon``; every other option at its default). Every controller flies the
same ``--starts`` held-out X0 starts (``heldout_starts``, never trained on), each simulated on its own robot drawn
uniformly from the declared box Theta (``ROBOT_SEED``, the robots of ``bench_param_adversary.py``):

* ``robust``: each seed's network (and its snapshot at half the budget), success per seed, median over seeds;
* ``oracle``: the full-horizon MPC that knows each robot (``FullHorizonMPC(model_params=True)``, ``set_robot``);
* ``adaptive-quadratic``: the control engineer's adaptive MPC, the same online estimate with the task's quadratic
  terminal cost at ``quadratic_horizon`` steps (the horizon at which it succeeds on the nominal robot);
* ``nominal``: the shipped nominal network's MPC as deployed (it plans with the model) and, as a control, the same
  network with the estimating MPC (``nominal-estimate``);
* ``lqr``: the task's LQR on the model;
* ``nominal-ppo``: the shipped PPO baseline (``benchmarks/results/models/<task>_ppo``, trained on the model's robot);
* ``dr-ppo``, ``dr-sac``: domain-randomised RL (:data:`DR_RL`): per algorithm ``--seeds`` runs, each on a robot
  from Theta per episode (``SB3Config(domain_randomization=True)``, the env's tuned rl-zoo entry), its checkpoint
  selected on validation starts x robots of their own streams; success per seed and the median (:func:`dr_rows`).

Also: success against the size of the box (robots drawn from ``Theta.scaled(s, nominal)`` for ``s`` in ``SCALES``:
each side's ratio to the nominal value raised to ``s``) for the robust, the nominal and the oracle MPC; and the online
estimate's accuracy per step (its error as a fraction of each parameter's width in the declared box) with the whole
step's time (estimate update plus solve) in ``estimator_episodes`` episodes of the shipped robust MPC.

The shipped network is the seed whose success is the median of the seeds' (the lower one of a tied pair), never the
best. ``--ship`` copies every seed's network to
``benchmarks/results/networks/<task>_robust_<recipe>_b<budget>_seed<s>.pt`` and the rows name those files (a network
already committed there, given with ``--networks``, stays where it is). ``--update FILE`` merges into FILE, per task,
the ``"shipped"`` block (``network``, ``horizon``, ``estimate_robot``, ``success_rate`` (median over seeds),
``oracle_success_rate``, ``nominal_success_rate``, ``budget``, ``seeds``, ``starts``) and the ``"robust"`` block
(per-seed rows, baselines, box sweep, estimator), keeping every other field of the file.
Every evaluation is cached as JSON under ``--out`` and training resumes from its checkpoints, so a re-run continues.
``--baselines-from FILE`` takes the baseline rows (every controller above but ``robust``) and the box sweep's
nominal and oracle entries from FILE's task block instead of flying them again: they do not depend on the networks,
and the oracle's full-horizon solves are most of a run's time. The rows are kept as they are (the file's block then
says ``"baselines_reused_from"``), so only a benchmark with the same starts, robots and baselines should reuse them;
``--fly-baselines NAME ...`` flies the named ones again (those whose deployment changed since, e.g. the ones that
share the robust MPC's online estimate); an RL baseline of :data:`DR_RL` that FILE has no row for is trained (its
completed runs under ``--out`` reused) and flown too; the block lists both (``"baselines_flown"``).
The last line of stdout is the result as one JSON object.
"""

from __future__ import annotations

import argparse
import json
import shutil
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
from benchmarks.bench_param_adversary import ROBOT_SEED, ParamBenchConfig, closed_loop  # noqa: E402
from benchmarks.bench_rl_baselines import ENV_IDS, SHIP_DIR, best_run  # noqa: E402
from seagul_control.evaluation import (  # noqa: E402
    PolicySpec,
    episode_env,
    heldout_starts,
    is_success,
)
from seagul_control.policy_kinds import build_policy  # noqa: E402
from seagul_envs import make_task  # noqa: E402
from seagul_envs.tasks.parameters import log_features  # noqa: E402
from seagul_learn.baselines import SB3Config, smoke_config, train_sb3  # noqa: E402
from seagul_learn.experiment.runs import train_one  # noqa: E402
from seagul_learn.shipped import shipped_network  # noqa: E402
from seagul_learn.training import TrainConfig  # noqa: E402

RECIPES = {"acrobot": "shipped", "glider": "robust-compress"}
"""Each task's recipe of the robust MPC's networks (``--recipe`` replaces it): the acrobot's nominal shipped recipe
measured best over robots (its ``robust`` recipe over Theta did worse), the glider's nominal network does not carry
over to other robots and its ``robust-compress`` recipe learns over Theta, the value fed the products the dynamics
depend on (``robust-invariants``; fed the four parameters, the ``robust`` recipe perches as often with the estimate
and less often when the MPC knows the robot), the deployed round chosen on selection episodes (``selection.rounds``;
the round whose collector flew best perched less often on validation starts x robots), and the labels above the cap
compressed instead of clipped (``robust-compress``: the heavy robots' tails lie mostly above it; docs/experiments/
robust.md)."""
DR_RL: dict[str, dict[str, int]] = {"glider": {"PPO": 2_000_000, "SAC": 150_000}}
"""Domain-randomised RL per task (``SB3Config(domain_randomization=True)``, the env's tuned entry): algorithm ->
environment steps. The glider's PPO perches from every start of the model's robot at its nominal budget, 500 k steps
(``bench_rl_baselines.FULL_STEPS``); over robots its validation success was still rising there (0.16 at 100 k to
0.34 at 500 k), so the runs get four times that. The glider's SAC learns far faster per step: in a two-seed probe
its validation success rose to 46-50 % by 100 k steps and stayed there to 140 k, so the runs get 150 k (1 h 43 min
per seed with five runs sharing two cores; at about 60 steps per second on one core, 1 M steps take 4.5 hours a
seed). Over the five seeds the median validation point is then 0.48 at 100 k and 0.50 at 130-150 k
(docs/experiments/robust.md). Not the acrobot, whose nominal PPO reaches 3.5 % of its grid after 8 M steps (below
LQR) and whose nominal SAC runs stop at 20-40 k steps: randomising the robot makes the task harder, not easier."""
SCALES = (0.5, 1.0, 2.0)
"""Box sizes of the sweep, as multiples of the declared Theta (:meth:`ParameterSpace.scaled`)."""
NETWORKS = ROOT / "benchmarks" / "results" / "networks"


@dataclass
class RobustBenchConfig:
    """Every number of one task's run (``--quick`` replaces some)."""

    task: str = "acrobot"
    seeds: int = 5
    starts: int = 50
    """Held-out X0 starts, each on its own robot from Theta (the first 30 are ``bench_param_adversary``'s)."""
    recipe: str = "shipped"
    """The task's training recipe of the networks (``TrainConfig.recipe(task, recipe, seed=s)``; :data:`RECIPES`)."""
    horizon: int = 10
    """Lookahead steps of the deployed robust MPC."""
    quadratic_horizon: int = 10
    """Horizon of the adaptive quadratic MPC: the acrobot's quadratic MPC succeeds from every nominal start at 10."""
    estimator_episodes: int = 20
    train_overrides: dict[str, Any] = field(default_factory=dict)
    """TrainConfig fields (dotted) replacing the recipe's (``--quick``)."""
    rl_steps: dict[str, int] = field(default_factory=dict)
    """Domain-randomised RL baselines: algorithm -> environment steps (:data:`DR_RL`)."""
    quick_rl: bool = False
    """The RL runs at ``smoke_config``'s tiny sizes (``--quick``)."""

    def rl_config(self, algo: str, seed: int) -> SB3Config:
        config = SB3Config(
            algo=algo,
            env_id=ENV_IDS[self.task],
            total_timesteps=self.rl_steps[algo],
            seed=seed,
            domain_randomization=True,
        )
        if self.quick_rl:
            tiny = smoke_config(config).to_dict()
            config = SB3Config(**{**tiny, "total_timesteps": self.rl_steps[algo], "eval_every": self.rl_steps[algo]})
        return config

    def train_config(self, seed: int) -> TrainConfig:
        return TrainConfig.recipe(self.task, self.recipe, seed=seed, **self.train_overrides)

    @classmethod
    def for_task(cls, task: str, quick: bool) -> RobustBenchConfig:
        recipe = RECIPES.get(task, "shipped")
        if quick:
            small: dict[str, Any] = {
                "budget": 20,
                "runtime.snapshots": (10, 20),
                "sampler.uniform_solves": 10,
                "sampler.episodes": 2,
                "schedule.solves_per_round": 10,
                "schedule.train_steps_per_round": 50,
                "runtime.progress": False,
            }
            full = TrainConfig.recipe(task, recipe)
            if full.refit.steps:  # a short refit; none where the recipe has none
                small.update({"refit.steps": 200, "refit.candidates": 0})
            if full.selection.rounds:  # the one closed-loop round, two selection episodes
                small.update({"selection.rounds": 1, "selection.episodes": 2, "selection.finalists": 0})
            return cls(
                task=task,
                recipe=recipe,
                seeds=2,
                starts=3,
                estimator_episodes=2,
                horizon=3,
                train_overrides=small,
                rl_steps={a: 256 for a in DR_RL.get(task, {})},
                quick_rl=True,
            )
        return cls(task=task, recipe=recipe, rl_steps=dict(DR_RL.get(task, {})))


def robust_spec(network: str | Path, horizon: int, label: str = "robust MPC") -> PolicySpec:
    """The shipped robust MPC: ``LimitedLookaheadMPC(task, ValueNetwork.load(network), horizon=horizon,
    model_params=True, estimate_robot=True)``, defaults otherwise."""
    return PolicySpec(
        "mpc", label, str(network), (("horizon", horizon), ("model_params", True), ("estimate_robot", True))
    )


def train_all(bench: RobustBenchConfig, out: Path, workers: int) -> dict[int, Path]:
    runs = {seed: out / "train" / f"seed{seed}" for seed in range(bench.seeds)}
    Parallel(n_jobs=workers)(delayed(train_one)(bench.train_config(s), str(p)) for s, p in runs.items())
    return runs


def estimator_trace(task_name: str, spec: PolicySpec, starts: np.ndarray, robots: np.ndarray) -> dict[str, Any]:
    """Episodes of ``spec`` with its estimate after every step: the error per parameter as a fraction of its width
    in the declared box, and the whole step's time (estimate update plus solve). For a task that declares
    invariants (``ParameterSpace.invariants``: the products the dynamics depend on, all that transitions can
    determine) also each product's relative error ``|estimate / truth - 1|``: ``"invariants"`` (their names),
    ``"invariant_max_error_median"`` (per step, the worst product, median over episodes) and
    ``"invariant_final_error_median"``."""
    task = make_task(task_name)
    space = task.parameters
    assert space is not None
    width = space.high - space.low
    policy = build_policy(task, spec)
    errors, step_ms, success, inv_errors = [], [], [], []
    exps = space.invariants
    for x0, theta in zip(starts, robots, strict=True):
        env = episode_env(task)
        obs, info = env.reset(options={"state": np.asarray(x0, dtype=float), "params": np.asarray(theta)})
        first, done, terminated, trace, inv_trace = True, False, False, [], []
        true_features = None if exps is None else log_features(theta, exps)
        while not done:
            t0 = time.perf_counter()
            action, _ = policy.predict(obs, episode_start=np.array([first]), deterministic=True)
            step_ms.append((time.perf_counter() - t0) * 1e3)
            first = False
            obs, _, terminated, truncated, info = env.step(action)
            done = terminated or truncated
            estimate = policy.estimate(0)
            trace.append(np.abs(estimate - theta) / width)
            if exps is not None:
                inv_trace.append(np.abs(np.exp(log_features(estimate, exps) - true_features) - 1))
        env.close()
        inv_errors.append(np.array(inv_trace))
        success.append(is_success(task, np.asarray(info["state"], dtype=float), bool(terminated)))
        errors.append(np.array(trace))
    steps = min(len(e) for e in errors)
    worst = np.array([e[:steps].max(axis=1) for e in errors])  # per episode and step: the worst parameter
    products: dict[str, Any] = {}
    if exps is not None:
        names = [_product_name(space.names, row) for row in exps]
        products = {
            "invariants": names,
            "invariant_max_error_median": np.median([e[:steps].max(axis=1) for e in inv_errors], axis=0).tolist(),
            "invariant_final_error_median": dict(
                zip(names, np.median([e[-1] for e in inv_errors], axis=0).tolist(), strict=True)
            ),
        }
    return {
        "episodes": len(errors),
        "success_rate": float(np.mean(success)),
        "max_error_median": np.median(worst, axis=0).tolist(),
        "max_error_q90": np.quantile(worst, 0.9, axis=0).tolist(),
        "final_error_median_per_parameter": dict(
            zip(space.names, np.median([e[-1] for e in errors], axis=0).tolist(), strict=True)
        ),
        # None: in the median episode the worst parameter never stays within 5 % of its width (JSON has no inf)
        "steps_to_5pct_median": _finite(float(np.median([_first_below(w, 0.05) for w in worst]))),
        "step_ms_median": float(np.median(step_ms)),
        "step_ms_p95": float(np.percentile(step_ms, 95)),
        **products,
    }


def _product_name(names: tuple[str, ...], row: np.ndarray) -> str:
    """``"S_w*rho"``-style name of the product ``prod_j names_j ** row_j`` (in the parameters' order)."""
    parts = [n if e == 1 else f"{n}^{e:g}" for n, e in zip(names, row, strict=True) if e != 0]
    return "*".join(parts) or "1"


def _relative(path: Path) -> str:
    """``path`` relative to the repository when inside it."""
    path = path.resolve()
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)


def _finite(value: float) -> float | None:
    return value if np.isfinite(value) else None


def _first_below(trace: np.ndarray, level: float) -> float:
    """Steps after which the trace stays below ``level`` for good (inf: never)."""
    above = np.nonzero(trace >= level)[0]
    if above.size == 0:
        return 1.0
    return float(above[-1] + 2) if above[-1] + 1 < trace.size else float("inf")


def _train_dr_seed(config: SB3Config, run: str) -> None:
    train_sb3(config, run)


def train_dr(bench: RobustBenchConfig, out: Path, algo: str, workers: int) -> list[dict[str, Any]]:
    """Each seed's domain-randomised ``algo`` run (``out/rl/<algo>_dr_seed<s>``), trained unless a completed run of
    the same config is there; their ``curve.json`` summaries, in seed order."""
    runs = {s: out / "rl" / f"{algo.lower()}_dr_seed{s}" for s in range(bench.seeds)}

    def done(seed: int) -> bool:
        path = runs[seed] / "curve.json"
        return path.is_file() and json.loads(path.read_text())["config"] == bench.rl_config(algo, seed).to_dict()

    todo = [s for s in runs if not done(s)]
    Parallel(n_jobs=workers)(delayed(_train_dr_seed)(bench.rl_config(algo, s), str(runs[s])) for s in todo)
    return [json.loads((runs[s] / "curve.json").read_text()) for s in runs]


def _median_of(values: list[Any]) -> float | None:
    finite = [float(v) for v in values if v is not None and np.isfinite(v)]
    return float(np.median(finite)) if finite else None


def dr_rows(
    bench: RobustBenchConfig,
    out: Path,
    workers: int,
    ship: bool,
    score: Any,
    algos: list[str] | None = None,
) -> dict[str, dict[str, Any]]:
    """The domain-randomised RL baselines (``dr-<algo>``; ``algos``: only these of ``bench.rl_steps``): each seed's
    model selected on its validation starts x robots, flown on the benchmark's starts x robots; success is the median
    over seeds. The shipped model (``--ship``) is the seed with the best validation point, as for the nominal RL
    baselines, copied to ``benchmarks/results/models/<task>_<algo>_dr/``."""
    unknown = sorted(set(algos or ()) - set(bench.rl_steps))
    if unknown:
        raise ValueError(f"{bench.task}: no domain-randomised RL for {unknown}; DR_RL has {list(bench.rl_steps)}")
    rows: dict[str, dict[str, Any]] = {}
    for algo, steps in bench.rl_steps.items():
        if algos is not None and algo not in algos:
            continue
        runs = train_dr(bench, out, algo, workers)
        label = f"domain-randomised {algo} ({steps:,} steps)"
        per_seed = []
        for summary in runs:
            seed = int(summary["config"]["seed"])
            spec = PolicySpec("sb3", label, summary["model"], (("algo", algo),))
            result = score(spec, f"dr-{algo.lower()}-seed{seed}")
            per_seed.append(
                {
                    "seed": seed,
                    "success_rate": result["success_rate"],
                    "selected_at": summary["best"]["env_steps"],
                    "validation_success_rate": summary["best"]["success_rate"],
                    "median_ms": result.get("median_ms"),
                    "p95_ms": result.get("p95_ms"),
                }
            )
        model = Path(runs[best_run(runs)]["model"])
        if ship:
            target = SHIP_DIR / f"{bench.task}_{algo.lower()}_dr"
            shutil.rmtree(target, ignore_errors=True)
            shutil.copytree(model.parent, target)
            model = target / "model.zip"
        rows[f"dr-{algo.lower()}"] = {
            "controller": label,
            "success_rate": float(np.median([r["success_rate"] for r in per_seed])),
            "median_ms": _median_of([r["median_ms"] for r in per_seed]),
            "p95_ms": _median_of([r["p95_ms"] for r in per_seed]),
            "per_seed": per_seed,
            "env_steps": int(runs[0]["env_steps"]),
            "seeds": len(runs),
            "train_wall_s": float(np.median([r["train_wall_s"] for r in runs])),
            "model": _relative(model),
            "settings": runs[0]["resolved"],
        }
    return rows


def run_task(
    bench: RobustBenchConfig,
    out: Path,
    workers: int,
    ship: bool,
    networks: list[Path] | None = None,
    reuse: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """One task's blocks (module docstring); ``reuse``: a committed ``robust`` block whose baseline rows and box
    sweep entries (all but the robust MPC's) are taken instead of flown again (``--baselines-from``)."""
    task = make_task(bench.task)
    space = task.parameters
    if space is None:
        raise SystemExit(f"{bench.task} declares no physical parameters")
    horizon = bench.horizon
    t0 = time.perf_counter()
    if networks:
        # networks trained elsewhere with the same recipe, one per seed (``--networks``)
        runs = {seed: path for seed, path in enumerate(networks)}
        bench.seeds = len(networks)
    else:
        runs = {seed: run / "network.pt" for seed, run in train_all(bench, out, workers).items()}
    train_s = time.perf_counter() - t0
    config = bench.train_config(0)
    budget = int(config.budget)
    half = int(config.runtime.snapshots[0]) if config.runtime.snapshots else None
    starts = heldout_starts(task, bench.starts)
    robots = space.sample(np.random.default_rng(ROBOT_SEED), bench.starts)
    scorer = ParamBenchConfig(task=bench.task)
    ev = out / "eval"

    def score(spec: PolicySpec, name: str, robots_: np.ndarray = robots) -> dict[str, Any]:
        return closed_loop(scorer, spec, starts, robots_, workers, ev / f"{name}.json")

    per_seed = []
    for seed, path in runs.items():
        row: dict[str, Any] = {"seed": seed, "network": _relative(path)}
        row.update(score(robust_spec(path, horizon), f"robust-seed{seed}"))
        snapshot = path.parent / f"network_{half}.pt"
        if half is not None and half < budget and snapshot.is_file():
            snap = score(robust_spec(snapshot, horizon), f"robust-b{half}-seed{seed}")
            row[f"success_rate_b{half}"] = snap["success_rate"]
        row.pop("success", None)
        per_seed.append(row)
    rates = [r["success_rate"] for r in per_seed]
    order = sorted(range(len(rates)), key=lambda i: (rates[i], i))
    chosen = per_seed[order[(len(order) - 1) // 2]]
    if ship:  # every seed's network is committed (a committed one where it is); the rows name the committed files
        for row in per_seed:
            path = runs[row["seed"]]
            if path.resolve().parent != NETWORKS.resolve():
                target = NETWORKS / f"{bench.task}_robust_{bench.recipe}_b{budget}_seed{row['seed']}.pt"
                shutil.copyfile(path, target)
                runs[row["seed"]] = target
                row["network"] = _relative(target)
    network = runs[chosen["seed"]]

    nominal = shipped_network(task)

    def adaptive_quadratic(steps: int) -> PolicySpec:
        """The control engineer's adaptive MPC: the same estimate, the task's quadratic terminal cost."""
        options = (("horizon", steps), ("model_params", True), ("estimate_robot", True))
        return PolicySpec("mpc", f"adaptive quadratic-terminal MPC (N={steps})", None, options)

    baselines: dict[str, PolicySpec] = {
        "oracle": PolicySpec("full", "full horizon (knows the robot)", None, (("model_params", True),), True),
        "adaptive-quadratic": adaptive_quadratic(bench.quadratic_horizon),
        "lqr": PolicySpec("lqr", "LQR (plans with the model)"),
    }
    if nominal is not None:
        if nominal.horizon != bench.quadratic_horizon:
            # horizon for horizon with the nominal shipped MPC
            baselines[f"adaptive-quadratic-N{nominal.horizon}"] = adaptive_quadratic(nominal.horizon)
        baselines["nominal"] = nominal.spec(f"shipped learned {nominal.horizon}-step MPC (plans with the model)")
        baselines["nominal-estimate"] = PolicySpec(
            "mpc",
            f"shipped network, {nominal.horizon}-step MPC estimating the robot",
            str(nominal.network),
            (*nominal.options(), ("model_params", True), ("estimate_robot", True)),
        )
    nominal_rl = SHIP_DIR / f"{bench.task}_ppo" / "model.zip"
    if nominal_rl.is_file():  # the nominal RL baseline as shipped (trained on the model's robot)
        baselines["nominal-ppo"] = PolicySpec(
            "sb3", "shipped PPO (trained on the model)", str(nominal_rl), (("algo", "PPO"),)
        )

    def flown(name: str) -> dict[str, Any]:
        result = score(baselines[name], name)
        return {"controller": baselines[name].label, **{k: v for k, v in result.items() if k != "success"}}

    rl = {f"dr-{algo.lower()}": algo for algo in bench.rl_steps}
    fresh: list[str] = []  # with --baselines-from: the rows flown again, and the RL rows trained (or reused) and flown
    if reuse is not None:
        fly = set(reuse.get("fly", ()))
        unknown = sorted(fly - set(baselines) - set(rl))
        if unknown:
            raise SystemExit(
                f"{bench.task}: --fly-baselines names no baseline: {unknown}; there are {sorted([*baselines, *rl])}"
            )
        missing = sorted(set(baselines) - set(reuse["baselines"]) - fly)
        if missing:
            raise SystemExit(f"{bench.task}: --baselines-from has no rows {missing}; fly them (drop the option)")
        rows = {name: dict(row) for name, row in reuse["baselines"].items()}
        again = sorted(fly & set(baselines))
        rows.update({name: flown(name) for name in again})
        # an RL baseline the file has no row for (an algorithm added to DR_RL since) is run like the named ones
        todo = {name: algo for name, algo in rl.items() if name in fly or name not in rows}
        if todo:
            rows.update(dr_rows(bench, out, workers, ship, score, algos=list(todo.values())))
        fresh = sorted([*again, *todo])
    else:
        rows = {name: flown(name) for name in baselines}
        rows.update(dr_rows(bench, out, workers, ship, score))
    shipped_spec = robust_spec(network, horizon)
    sweep: dict[str, dict[str, Any]] = {}
    swept: dict[str, PolicySpec | None] = {
        "robust": shipped_spec,
        "nominal": baselines.get("nominal"),
        "oracle": baselines["oracle"],
    }
    for scale in SCALES:
        box = space.scaled(scale, task.theta)
        robots_s = robots if scale == 1.0 else box.sample(np.random.default_rng(ROBOT_SEED), bench.starts)
        entry: dict[str, Any] = {"box": box.box()}
        for name, candidate in swept.items():
            if candidate is None:
                continue
            # the declared box's rows are the ones above (the shipped seed's, the baselines')
            own = f"robust-seed{chosen['seed']}" if name == "robust" else name
            key = own if scale == 1.0 else f"{own}-x{scale:g}"
            if reuse is not None and name != "robust":
                entry[name] = reuse["box_sweep"][f"{scale:g}"][name]
            else:
                entry[name] = score(candidate, key, robots_s)["success_rate"]
        sweep[f"{scale:g}"] = entry
    n_est = min(bench.estimator_episodes, bench.starts)
    estimator = estimator_trace(bench.task, shipped_spec, starts[:n_est], robots[:n_est])

    oracle_rate = rows["oracle"]["success_rate"]
    shipped = {
        "network": _relative(network),
        "horizon": horizon,
        "estimate_robot": True,
        "success_rate": float(np.median(rates)),
        "oracle_success_rate": oracle_rate,
        "nominal_success_rate": rows["nominal"]["success_rate"] if "nominal" in rows else float("nan"),
        "budget": budget,
        "seeds": bench.seeds,
        "starts": bench.starts,
    }
    robust = {
        "recipe": bench.recipe,
        "train_settings": config.to_dict(),
        "shipped_seed": chosen["seed"],
        "shipped_network_success_rate": chosen["success_rate"],
        "ratio_to_oracle": shipped["success_rate"] / oracle_rate if oracle_rate else float("nan"),
        "per_seed": per_seed,
        "baselines": rows,
        "box_sweep": sweep,
        "estimator": estimator,
        "robot_seed": ROBOT_SEED,
        "quadratic_horizon": bench.quadratic_horizon,
        # this invocation's training stage: finished runs are reused, so a re-run reports seconds, not the training
        "train_wall_s": None if networks else round(train_s, 1),
        "deployed": "LimitedLookaheadMPC(task, ValueNetwork.load(network), horizon=horizon, model_params=True, "
        "estimate_robot=True)",
    }
    if reuse is not None:
        robust["baselines_reused_from"] = reuse.get("baselines_reused_from", "an earlier run of this benchmark")
        robust["baselines_flown"] = fresh
    return {"shipped": shipped, "robust": robust}


def plot(task_name: str, block: dict[str, Any], path: Path) -> None:
    """Three panels: success per controller (seeds as dots), success against the box size, estimator error."""
    import matplotlib  # the backend is chosen before pyplot, by the one function that draws

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    robust, shipped = block["robust"], block["shipped"]
    fig, axes = plt.subplots(1, 3, figsize=(17, 4.6), constrained_layout=True)
    ax = axes[0]
    seeds = [r["success_rate"] for r in robust["per_seed"]]
    names = [f"robust {shipped['horizon']}-step MPC"] + [r["controller"] for r in robust["baselines"].values()]
    values = [shipped["success_rate"]] + [r["success_rate"] for r in robust["baselines"].values()]
    ys = np.arange(len(values))[::-1]
    ax.barh(ys, values, color=["C0"] + ["C7"] * (len(values) - 1), alpha=0.8)
    ax.plot(seeds, np.full(len(seeds), ys[0]) + np.linspace(-0.2, 0.2, len(seeds)), "k.", ms=6)
    ax.set_yticks(ys, names, fontsize=7)
    ax.set_xlim(0, 1.05)
    ax.set_xlabel(f"success, {shipped['starts']} starts x robots (dots: seeds)")
    ax.set_title(f"{task_name}: robots from Theta ({shipped['budget']} solves, {shipped['seeds']} seeds)")
    bx = axes[1]
    scales = sorted(robust["box_sweep"], key=float)
    for name, style in (("robust", "C0o-"), ("nominal", "C7s--"), ("oracle", "C2^:")):
        ys = [robust["box_sweep"][s].get(name) for s in scales]
        if all(y is not None for y in ys):
            bx.plot([float(s) for s in scales], ys, style, label=name)
    bx.set_xscale("log", base=2)
    bx.set_xticks([float(s) for s in scales], [f"{float(s):g}x" for s in scales])
    bx.set_ylim(0, 1.05)
    bx.set_xlabel("box size (multiple of the declared Theta)")
    bx.set_title("success against the size of Theta")
    bx.legend()
    cx = axes[2]
    est = robust["estimator"]
    steps = np.arange(1, len(est["max_error_median"]) + 1)
    cx.plot(steps, est["max_error_median"], "C0-", label="median")
    cx.plot(steps, est["max_error_q90"], "C0:", label="90th percentile")
    if "invariant_max_error_median" in est:  # what the transitions can determine (ParameterSpace.invariants)
        cx.plot(steps, est["invariant_max_error_median"], "C1-", label="worst product, relative (median)")
    cx.set_yscale("log")
    cx.set_xlabel("control step")
    cx.set_ylabel("worst parameter error / box width")
    cx.set_title(f"online estimate ({est['episodes']} episodes)")
    cx.legend()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _reuse_label(block: dict[str, Any]) -> str:
    """Which run reused baseline rows come from: the one with the block's recipe's networks."""
    return f"this benchmark's run with the {block.get('recipe', '?')} recipe's networks"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="a minutes-long check of the pipeline")
    parser.add_argument("--tasks", default="acrobot", help="comma-separated tasks")
    parser.add_argument("--seeds", type=int, default=None)
    parser.add_argument("--starts", type=int, default=None)
    parser.add_argument("--recipe", default=None, help="the networks' training recipe (default: RECIPES[task])")
    parser.add_argument("--horizon", type=int, default=None, help="the robust MPC's lookahead steps (default 10)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", default=None, help="work directory (default /tmp/seagul-bench-robust)")
    parser.add_argument("--update", default=None, metavar="JSON", help="merge the blocks into this results file")
    parser.add_argument("--ship", action="store_true", help="copy the shipped network into benchmarks/results")
    parser.add_argument("--figure-dir", default=None, help="write <task>_robust_shipped.png here")
    parser.add_argument(
        "--networks",
        nargs="+",
        default=None,
        metavar="PT",
        help="evaluate these networks (one per seed, trained with the recipe) instead of training (one task)",
    )
    parser.add_argument(
        "--baselines-from",
        default=None,
        metavar="JSON",
        help="take the baseline rows and the box sweep's baseline entries from this results file (module docstring)",
    )
    parser.add_argument(
        "--fly-baselines",
        nargs="+",
        default=(),
        metavar="NAME",
        help="with --baselines-from: fly these baselines again (e.g. the ones whose deployment changed)",
    )
    parser.add_argument("--dry-run", action="store_true", help="print the settings as JSON; run nothing")
    args = parser.parse_args(argv)
    out = Path(args.out or f"/tmp/seagul-bench-robust{'-quick' if args.quick else ''}")
    benches = []
    for task in args.tasks.split(","):
        bench = RobustBenchConfig.for_task(task, args.quick)
        bench.seeds = args.seeds or bench.seeds
        bench.starts = args.starts or bench.starts
        bench.recipe = args.recipe or bench.recipe
        bench.horizon = args.horizon or bench.horizon
        benches.append(bench)
    if args.dry_run:
        print(json.dumps({b.task: {**asdict(b), "train": b.train_config(0).to_dict()} for b in benches}))
        return 0
    t0 = time.perf_counter()
    result: dict[str, Any] = {}
    for bench in benches:
        networks = [Path(p) for p in args.networks] if args.networks else None
        reuse = None
        if args.baselines_from:
            block = json.loads(Path(args.baselines_from).read_text()).get(bench.task, {}).get("robust")
            if block is None:
                raise SystemExit(f"{args.baselines_from} has no robust block for {bench.task}")
            # rows already reused keep naming the run that flew them; rows that run flew again name it
            origin = block.get("baselines_reused_from") or _reuse_label(block)
            if block.get("baselines_reused_from") and block.get("baselines_flown"):
                origin = f"{origin}; {', '.join(block['baselines_flown'])}: {_reuse_label(block)}"
            reuse = {**block, "baselines_reused_from": origin}
            reuse["fly"] = list(args.fly_baselines)
        result[bench.task] = run_task(bench, out / bench.task, args.workers, args.ship, networks, reuse)
        if args.figure_dir:
            plot(bench.task, result[bench.task], Path(args.figure_dir) / f"{bench.task}_robust_shipped.png")
    result["machine"] = {**machine("torch"), "wall_s": round(time.perf_counter() - t0, 1)}
    if args.update:
        path = Path(args.update)
        merged = json.loads(path.read_text()) if path.is_file() else {}
        for task, blocks in result.items():
            if task != "machine":  # the file's top level is its tasks and the sampler run's machine
                merged.setdefault(task, {}).update(blocks)
                merged[task]["robust"]["machine"] = result["machine"]
        path.write_text(json.dumps(merged, indent=1) + "\n")
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
