"""Animations of the suite controllers from one dm_control reset, side by side (docs/figures/dmc/*.gif).

Usage::

    nice .venv/bin/python benchmarks/animate_dmc.py [--seed S] [--tasks pendulum-swingup cartpole-swingup
        acrobot-swingup] [--out docs/figures/dmc] [--no-reference] [--fps 25]

Per env, from dm_control's reset with ``--seed`` (by default the evaluation seed of 0-9 whose start is farthest from
upright, :func:`hardest_seed`; the committed scores use seeds 0-9), it runs each controller that
``benchmarks/results/dmc.json`` scores, in dm_control's own episode (:func:`seagul_control.dmc.run_dmc_episode`,
``record=True``), and draws the episodes with MuJoCo's renderer (:func:`seagul_learn.dmc_animation.dmc_animation`):

* the learned short-horizon MPC of the block's first network (``learned_mpc.network``, deployed as
  ``seagul evaluate --dmc`` deploys it), where the block has one;
* the task's classical swing-up with LQR catch (``classical``: energy shaping, Astrom-Furuta, Spong);
* the full-horizon reference (:class:`seagul_control.dmc_reference.FullHorizonReference`; minutes on the acrobot;
  ``--no-reference`` leaves it out);
* SAC and PPO where their selected model is committed (``sac``/``ppo`` blocks with a ``model``, shipped by
  ``benchmarks/bench_dmc_rl.py --ship``), loaded by :func:`seagul_learn.dmc_rl.load_sb3_dmc`.

Every episode is deterministic, so each panel's score is the committed score of that controller on that reset seed;
the script prints both and says so when they differ, and records what each animation shows (reset seed, each
panel's controller and score) in ``animations.json`` beside the GIFs for the results page's captions. Rendering
needs an OpenGL backend (EGL on a headless machine).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path
from typing import Any

os.environ.setdefault("MUJOCO_GL", "egl")  # before MuJoCo is imported: a headless renderer

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.bench_dmc import CLASSICAL  # noqa: E402
from seagul_control.dmc import dmc_env_id, run_dmc_episode  # noqa: E402
from seagul_control.io import atomic_write_text  # noqa: E402

TASKS = ("pendulum-swingup", "cartpole-swingup", "acrobot-swingup")
RESULTS = ROOT / "benchmarks" / "results" / "dmc.json"
REFERENCE = ROOT / "benchmarks" / "results" / "dmc_reference.json"
RL = ROOT / "benchmarks" / "results" / "dmc_rl.json"


#: The physics state's angle coordinates per env (zero is upright; ``seagul_control.dmc.physics_state``).
ANGLES = {"pendulum-swingup": (0,), "cartpole-swingup": (1,), "acrobot-swingup": (0, 1)}


def hardest_seed(task: str, seeds: range = range(10)) -> int:
    """The evaluation reset seed whose start is farthest from upright (largest ``sum(1 - cos q)`` over the angles):
    the animation shows a whole swing-up."""
    from seagul_control.dmc import make_dmc_env, physics_state

    env = make_dmc_env(task)
    try:
        far = []
        for seed in seeds:
            env.reset(seed=seed)
            q = physics_state(env)
            far.append(sum(1.0 - math.cos(q[i]) for i in ANGLES[task]))
    finally:
        env.close()
    return int(seeds[max(range(len(far)), key=far.__getitem__)])


def _score(scores: Any, seeds: Any, seed: int) -> float | None:
    if not isinstance(scores, list) or not isinstance(seeds, list) or seed not in seeds:
        return None
    return float(scores[seeds.index(seed)])


def controllers(
    task: str, results: dict[str, Any], seed: int, reference: bool
) -> list[tuple[str, Any, float | None, int]]:
    """``(label, controller, committed score on reset seed or None, hold)`` of every controller animated for
    ``task``."""
    env_id = dmc_env_id(task)
    block = results[task]
    out: list[tuple[str, Any, float | None, int]] = []
    learned = block.get("learned_mpc")
    if learned and learned.get("network"):
        from seagul_learn.dmc_eval import DEFAULT_DEPLOYMENTS, DMCDeployment, learned_dmc_controller

        setting = DEFAULT_DEPLOYMENTS.get(env_id, DMCDeployment())
        first = learned["networks"][0]
        label = f"learned {setting.horizon}-step MPC, {first['solves']:,} solves"
        controller = learned_dmc_controller(env_id, ROOT / first["network"], setting)
        out.append((label, controller, _score(first["scores"], learned.get("reset_seeds"), seed), setting.hold))
    name, params_cls, controller_cls = CLASSICAL[env_id]
    row = next((r for r in block.get("classical", []) if r.get("controller") == name), {})
    label = {"energy": "energy shaping + LQR", "astrom_furuta": "Astrom-Furuta + LQR", "spong": "Spong + LQR"}[name]
    out.append((label, controller_cls(params_cls()), _score(row.get("scores"), row.get("seeds"), seed), 1))
    for algo in ("sac", "ppo"):
        rl = block.get(algo) or {}
        if not rl.get("model"):
            continue
        from seagul_learn.dmc_rl import load_sb3_dmc

        runs = json.loads(RL.read_text())
        shipped = next(row for row in runs["tasks"][env_id][algo]["per_seed"] if row["seed"] == rl["model_seed"])
        committed = _score(shipped["scores"], runs.get("eval_seeds"), seed)
        label = f"{algo.upper()}, {rl['env_steps'] / 1e6:.3g} M steps (seed {rl['model_seed']})"
        out.append((label, load_sb3_dmc(ROOT / rl["model"]), committed, 1))
    if reference:
        from seagul_control.dmc_reference import FullHorizonReference

        ref = json.loads(REFERENCE.read_text())["tasks"].get(env_id, {})
        committed = _score(ref.get("scores"), ref.get("seeds"), seed)
        out.append(("full-horizon reference", FullHorizonReference(env_id), committed, 1))
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--seed", type=int, default=None, help="dm_control's reset seed (default: the hardest start of seeds 0-9)"
    )
    parser.add_argument("--tasks", nargs="+", default=list(TASKS), choices=TASKS)
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "figures" / "dmc")
    parser.add_argument("--no-reference", action="store_true", help="leave out the full-horizon reference")
    parser.add_argument("--fps", type=float, default=25.0, help="frames per second of episode time (default 25)")
    args = parser.parse_args(argv)
    from seagul_learn.dmc_animation import dmc_animation

    results = json.loads(RESULTS.read_text())
    for task in args.tasks:
        episodes, panels = [], []
        seed = hardest_seed(task) if args.seed is None else args.seed
        for label, controller, committed, hold in controllers(task, results, seed, not args.no_reference):
            episode = run_dmc_episode(task, controller, seed, hold=hold, record=True)
            same = "" if committed is None or abs(committed - episode.score) < 0.5 else " (differs)"
            print(f"{task} seed {seed} {label}: {episode.score:.1f}, committed {committed}{same}", flush=True)
            episodes.append((label, episode))
            panels.append({"controller": label, "score": episode.score, "committed_score": committed})
        every = max(1, round(1.0 / (args.fps * episodes[0][1].control_dt)))
        path = dmc_animation(episodes, args.out / f"{task}.gif", every=every)
        # What each animation shows, for its caption on the results page (scripts/make_results.py).
        index = args.out / "animations.json"
        shown = json.loads(index.read_text()) if index.is_file() else {}
        shown[task] = {"file": path.name, "seed": seed, "panels": panels}
        atomic_write_text(index, json.dumps(dict(sorted(shown.items())), indent=1) + "\n")
        print(path.relative_to(ROOT) if path.is_relative_to(ROOT) else path, flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
