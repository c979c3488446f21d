"""The classical baselines scored by dm_control's own reward on the DeepMind Control Suite's own episodes.

Usage::

    nice .venv/bin/python benchmarks/bench_dmc.py [--seeds 0-9] [--json benchmarks/results/dmc.json]
    nice .venv/bin/python benchmarks/bench_dmc.py --tune acrobot [--trials 200]   # how the defaults were chosen
    .venv/bin/python benchmarks/bench_dmc.py --gather [--json benchmarks/results/dmc.json]

Per env of :data:`seagul_control.dmc.DMC_ENV_IDS` (pendulum-swingup, cartpole-swingup, cartpole-swingup_sparse,
acrobot-swingup) it runs, on the reset seeds ``--seeds`` (default 0-9, the evaluation seeds; the classical
controllers' gains were tuned on seeds 100-139, :data:`seagul_control.spong.TUNING_SEEDS`):

* ``zero``: action 0 throughout (what the passive system scores from dm_control's reset distribution);
* ``random``: actions uniform in ``[-1, 1]``, a fresh draw each step from ``numpy.random.default_rng(seed)``;
* ``lqr``: seagul's :class:`~seagul_control.lqr.LQRPolicy` of the suite's CasADi task
  (``make_task("dmc_acrobot")`` etc., :data:`seagul_control.dmc.DMC_TASKS`), through
  :class:`~seagul_control.dmc.PredictController` as any seagul policy would be (no swing-up: a reference for the
  catch alone, and the path a learned MPC takes);
* the task's classical swing-up with an LQR catch (:mod:`seagul_control.spong`): ``energy`` (pendulum),
  ``astrom_furuta`` (both cart-pole tasks), ``spong`` (acrobot).

Every row decides at every control step (``hold`` 1; the seagul tasks' control period is the suite's). The score
is the sum of dm_control's 1,000 rewards (:func:`seagul_control.dmc.run_dmc_episode`); the decision time is the
controller call's wall time in this process (per episode its median and 95th percentile; the row reports the median
of each over the episodes).

Writes one block per task, keyed by the suite's short name (``"acrobot-swingup"``, ``"cartpole-swingup"``,
``"cartpole-swingup_sparse"``, ``"pendulum-swingup"``), beside ``"seeds", "tuning_seeds", "params", "wall_s",
"command", "machine"`` (``params``: each classical controller's parameters)::

    {"env_id", "classical": [{"controller", "scores", "mean", "std", "seeds", "decision_ms_median",
     "decision_ms_p95", "hold"}], "learned_mpc": {"score_mean", "score_std", "seeds", "episodes", "solves",
     "horizon", "median_ms", "p95_ms", "network", ...}, "full_horizon": {"score_mean", "score_std", "episodes",
     ...}, "sac": ..., "ppo": {"score_mean", "score_std", "seeds", "env_steps"}, "published": [{"method", "score",
     "env_steps", "source"}]}

The ``classical`` rows are run here; the other blocks are gathered from the result files of their own benchmarks
(:mod:`benchmarks.dmc_contract`; ``None`` where that run has not been made). It prints a Markdown table on stderr.

``--tune TASK`` (``pendulum``, ``cartpole``, ``acrobot``) instead runs the random search the default parameters
came from: ``--trials`` draws from the task's search box (:data:`SEARCH`), each scored by its mean over the first
10 tuning seeds; the best 5 are re-scored on all 40 tuning seeds and printed (one JSON object per line, best last).
The evaluation seeds are never used by the search.

``--gather`` re-reads the other benchmarks' result files into the existing ``--json`` file (its classical rows,
seeds and command unchanged, ``gathered_by`` records the re-gathering), for when a learned MPC, reference or RL run
has been added since the classical rows were measured.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.metadata
import json
import math
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._common import machine, parse_seeds  # noqa: E402
from benchmarks.dmc_contract import assemble, short_name  # noqa: E402
from seagul_control import spong  # noqa: E402
from seagul_control.dmc import (  # noqa: E402
    DMC_ENV_IDS,
    DMC_TASKS,
    PredictController,
    make_dmc_env,
    run_dmc_episode,
)
from seagul_control.lqr import LQRPolicy  # noqa: E402
from seagul_envs import make_task  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"

#: The classical controller of each env: (row name, params class, controller class).
CLASSICAL: dict[str, tuple[str, type, type]] = {
    "dm_control/pendulum-swingup-v0": ("energy", spong.PendulumSwingUpParams, spong.PendulumEnergyController),
    "dm_control/cartpole-swingup-v0": (
        "astrom_furuta",
        spong.CartpoleSwingUpParams,
        spong.AstromFurutaCartpoleController,
    ),
    "dm_control/cartpole-swingup_sparse-v0": (
        "astrom_furuta",
        spong.CartpoleSwingUpParams,
        spong.AstromFurutaCartpoleController,
    ),
    "dm_control/acrobot-swingup-v0": ("spong", spong.AcrobotSwingUpParams, spong.SpongAcrobotController),
}

#: dm_control's control period of each env (s).
CONTROL_DT = {
    "dm_control/pendulum-swingup-v0": 0.02,
    "dm_control/cartpole-swingup-v0": 0.01,
    "dm_control/cartpole-swingup_sparse-v0": 0.01,
    "dm_control/acrobot-swingup-v0": 0.01,
}

#: ``--tune``'s search box per task: parameter -> (low, high, "log" or "lin"); the env each task is tuned on.
SEARCH: dict[str, tuple[str, dict[str, tuple[float, float, str]]]] = {
    "pendulum": (
        "dm_control/pendulum-swingup-v0",
        {
            "k": (0.1, 10.0, "log"),
            "energy_sat": (0.5, 50.0, "log"),
            "catch_cost": (0.1, 100.0, "log"),
            "lqr_r": (0.01, 10.0, "log"),
        },
    ),
    "cartpole": (
        "dm_control/cartpole-swingup-v0",
        {
            "k_energy": (1.0, 100.0, "log"),
            "accel_max": (2.0, 30.0, "log"),
            "k_x": (0.0, 5.0, "lin"),
            "k_v": (0.0, 5.0, "lin"),
            "catch_cost": (0.1, 100.0, "log"),
            "lqr_r": (0.01, 10.0, "log"),
        },
    ),
    "acrobot": (
        "dm_control/acrobot-swingup-v0",
        {
            "k1": (1.0, 100.0, "log"),
            "k2": (0.3, 20.0, "log"),
            "k3": (-20.0, 20.0, "lin"),
            "alpha": (-2.0, 2.0, "lin"),
            "energy_sat": (1.0, 50.0, "log"),
            "catch_cost": (0.3, 30.0, "log"),
            "lqr_r": (0.1, 100.0, "log"),
        },
    ),
}


def zero_controller(x: np.ndarray, t: float) -> np.ndarray:
    """Action 0 throughout."""
    return np.zeros(1)


class RandomController:
    """Actions uniform in ``[-1, 1]``, one fresh draw per call from ``default_rng(seed)`` (re-seeded by ``reset``)."""

    name = "random"

    def __init__(self, seed: int) -> None:
        self.seed = int(seed)
        self.rng = np.random.default_rng(self.seed)

    def reset(self) -> None:
        self.rng = np.random.default_rng(self.seed)

    def __call__(self, x: np.ndarray, t: float) -> np.ndarray:
        return self.rng.uniform(-1.0, 1.0, size=1)


def score_row(env_id: str, name: str, make: Callable[[int], Any], seeds: list[int], hold: int = 1) -> dict[str, Any]:
    """One row of the table: ``make(seed)`` builds the controller of each episode (a fresh one, so no state carries
    over between seeds)."""
    env = make_dmc_env(env_id)
    scores, medians, p95s = [], [], []
    try:
        for seed in seeds:
            episode = run_dmc_episode(env_id, make(seed), seed, hold=hold, env=env)
            scores.append(episode.score)
            medians.append(episode.decision_ms_median)
            p95s.append(episode.decision_ms_p95)
    finally:
        env.close()
    return {
        "controller": name,
        "scores": [round(s, 3) for s in scores],
        "mean": round(float(np.mean(scores)), 3),
        "std": round(float(np.std(scores)), 3),
        "seeds": list(seeds),
        # Per-episode median and p95 summarised by their median (one slow episode does not set the row).
        "decision_ms_median": round(float(np.median(medians)), 4),
        "decision_ms_p95": round(float(np.median(p95s)), 4),
        "hold": hold,
    }


def benchmark(seeds: list[int]) -> dict[str, Any]:
    tasks: dict[str, list[dict[str, Any]]] = {}
    params: dict[str, Any] = {}
    for env_id in DMC_ENV_IDS:
        name, params_cls, controller_cls = CLASSICAL[env_id]
        p = params_cls()
        params[name] = dataclasses.asdict(p)
        task = make_task(DMC_TASKS[env_id])
        lqr = LQRPolicy(task)
        hold = round(task.control_period / CONTROL_DT[env_id])
        rows = [
            score_row(env_id, "zero", lambda s: zero_controller, seeds),
            score_row(env_id, "random", RandomController, seeds),
            score_row(env_id, "lqr", lambda s, policy=lqr: PredictController(policy), seeds, hold=hold),
            score_row(env_id, name, lambda s, c=controller_cls, p=p: c(p), seeds),
        ]
        tasks[env_id] = rows
        for row in rows:
            print(f"{env_id} {row['controller']}: {row['mean']:.1f} +- {row['std']:.1f}", file=sys.stderr, flush=True)
    return {**assemble(tasks), "seeds": seeds, "tuning_seeds": list(spong.TUNING_SEEDS), "params": params}


def markdown(result: dict[str, Any]) -> str:
    lines = ["| env | controller | mean | std | decision ms (median / p95) |", "|---|---|---|---|---|"]
    for name in (short_name(env_id) for env_id in DMC_ENV_IDS):
        block = result[name]
        for row in block["classical"]:
            lines.append(
                f"| {name} | {row['controller']} | {row['mean']:.1f} | {row['std']:.1f} | "
                f"{row['decision_ms_median']:.3f} / {row['decision_ms_p95']:.3f} |"
            )
        for key in ("learned_mpc", "full_horizon", "sac", "ppo"):
            other = block[key]
            if other is not None:
                timing = f"{other['median_ms']:.3f} / {other['p95_ms']:.3f}" if other.get("median_ms") else ""
                lines.append(f"| {name} | {key} | {other['score_mean']:.1f} | {other['score_std']:.1f} | {timing} |")
    return "\n".join(lines)


def _draw(rng: np.random.Generator, box: dict[str, tuple[float, float, str]]) -> dict[str, float]:
    out = {}
    for key, (lo, hi, scale) in box.items():
        value = math.exp(rng.uniform(math.log(lo), math.log(hi))) if scale == "log" else rng.uniform(lo, hi)
        out[key] = round(float(value), 4)
    return out


def tune(task: str, trials: int, seed: int) -> list[dict[str, Any]]:
    """Random search of the task's :data:`SEARCH` box on the tuning seeds (see the module docstring)."""
    env_id, box = SEARCH[task]
    _, params_cls, controller_cls = CLASSICAL[env_id]
    rng = np.random.default_rng(seed)
    env = make_dmc_env(env_id)
    first = list(spong.TUNING_SEEDS[:10])

    def mean_score(kw: dict[str, float], seeds: list[int]) -> float:
        controller = controller_cls(params_cls(**kw))
        return float(np.mean([run_dmc_episode(env_id, controller, s, env=env).score for s in seeds]))

    found = [{"params": {}, "score10": mean_score({}, first)}]  # the current defaults compete too
    for _ in range(trials):
        kw = _draw(rng, box)
        found.append({"params": kw, "score10": mean_score(kw, first)})
        print(json.dumps(found[-1]), file=sys.stderr, flush=True)
    best = sorted(found, key=lambda r: r["score10"])[-5:]
    for row in best:
        row["score40"] = mean_score(row["params"], list(spong.TUNING_SEEDS))
    env.close()
    return sorted(best, key=lambda r: r["score40"])


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", default="0-9", help="evaluation reset seeds, e.g. 0-9 or 0,2,5 (default 0-9)")
    parser.add_argument("--json", type=Path, default=None, help="write the result here (default: stdout only)")
    parser.add_argument("--tune", choices=sorted(SEARCH), default=None, help="random search of a task's gains")
    parser.add_argument("--trials", type=int, default=200, help="--tune: parameter draws (default 200)")
    parser.add_argument("--tune-seed", type=int, default=0, help="--tune: the search's own RNG seed (default 0)")
    parser.add_argument("--gather", action="store_true", help="re-gather the other result files into --json")
    args = parser.parse_args(argv)
    if args.gather:
        path = args.json or RESULTS / "dmc.json"
        previous = json.loads(path.read_text())
        classical = {previous[short_name(e)]["env_id"]: previous[short_name(e)]["classical"] for e in DMC_ENV_IDS}
        previous.update(assemble(classical))
        previous["gathered_by"] = "python benchmarks/bench_dmc.py " + " ".join(
            argv if argv is not None else sys.argv[1:]
        )
        path.write_text(json.dumps(previous, indent=1) + "\n")
        print(markdown(previous), file=sys.stderr)
        return
    if args.tune:
        for row in tune(args.tune, args.trials, args.tune_seed):
            print(json.dumps(row))
        return
    try:
        seeds = parse_seeds(args.seeds)
    except ValueError as exc:
        parser.error(str(exc))
    if set(seeds) & set(spong.TUNING_SEEDS):
        parser.error(f"evaluation seeds overlap the tuning seeds {spong.TUNING_SEEDS[0]}-{spong.TUNING_SEEDS[-1]}")
    start = time.perf_counter()
    result = benchmark(seeds)
    result["wall_s"] = round(time.perf_counter() - start, 1)
    result["command"] = "python benchmarks/bench_dmc.py " + " ".join(argv if argv is not None else sys.argv[1:])
    result["machine"] = machine("mujoco", "shimmy", "gymnasium")
    result["machine"]["dm_control"] = importlib.metadata.version("dm_control")  # the package has no __version__
    print(markdown(result), file=sys.stderr)
    text = json.dumps(result, indent=1)
    if args.json is not None:
        args.json.write_text(text + "\n")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
