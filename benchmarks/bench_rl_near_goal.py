"""Why the acrobot's RL baseline misses the task's 0.05 rule: how near upright its episodes come, and what an LQR
catch makes of those passes.

Usage::

    .venv/bin/python benchmarks/bench_rl_near_goal.py [--model benchmarks/results/models/acrobot_ppo/model.zip]
        [--radii 0.1,0.2,0.3] [--json benchmarks/results/rl_near_goal_acrobot.json]

The shipped acrobot PPO model (``baselines.json``'s ``ppo`` row: the validation-selected seed of the 8 M-step runs,
loaded as a user loads it, :class:`~seagul_learn.policies.SB3Policy`) flies the 20 x 20 evaluation grid. For every
episode the closest approach to upright (the smallest ``||x_t - x*||`` over its control steps, the task's own distance,
:meth:`~seagul_envs.tasks.base.Task.state_error`), the final distance and the final joint speed
``||(dth1, dth2)||`` are kept. The same starts are then flown by PPO handing over to the task's LQR (the ``lqr``
row's controller) the first time the state comes within ``r`` of upright, LQR to the end of the episode (latched),
for each ``r`` of ``--radii``, and by LQR alone.

The JSON (last line of stdout, and ``--json``): ``{"task", "model", "starts", "starts_within" (the fraction of
starts already within each tolerance at rest), "rows": [{"controller", "radius",
"success", "median_final_distance", "closest_within": {tol: fraction of episodes whose closest approach is within
tol}, "median_closest", "median_final_speed"}], "command", "machine", "wall_s"}``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._common import machine  # noqa: E402
from seagul_control.evaluation import PolicySpec, build_policy, run_policy_episode, start_grid  # noqa: E402
from seagul_control.io import atomic_write_json  # noqa: E402
from seagul_envs import make_task  # noqa: E402

TOLERANCES = (0.05, 0.1, 0.2, 0.3, 0.5)
GRID = 20


class Catch:
    """A predictor: ``first`` until the state first comes within ``radius`` of the goal, ``then`` from there to the
    episode's end. A new episode is recognised by its time to go (the observation's last entry) rising."""

    def __init__(self, task: Any, first: Any, then: Any, radius: float) -> None:
        self.task, self.first, self.then, self.radius = task, first, then, float(radius)
        self.caught, self.last_tau = False, -np.inf

    def predict(
        self, observation: Any, state: Any = None, episode_start: Any = None, deterministic: bool = True
    ) -> tuple[np.ndarray, Any]:
        obs = np.asarray(observation, dtype=np.float64)
        if obs[-1] > self.last_tau:
            self.caught = False
        self.last_tau = float(obs[-1])
        x = obs[: self.task.nx]
        self.caught = self.caught or float(np.linalg.norm(self.task.state_error(x))) < self.radius
        policy = self.then if self.caught else self.first
        return policy.predict(observation, deterministic=True)


def fly(task: Any, policy: Any, starts: np.ndarray) -> list[dict[str, float]]:
    """Each start's episode: success, final distance, closest approach and final joint speed."""
    out = []
    for i, x0 in enumerate(starts):
        result, _ = run_policy_episode(task, policy, x0, index=i, record=True)
        states = np.asarray(result.states, dtype=np.float64)
        distances = [float(np.linalg.norm(task.state_error(s))) for s in states]
        out.append(
            {
                "success": bool(result.success),
                "final": float(result.final_distance),
                "closest": min(distances),
                "final_speed": float(np.linalg.norm(states[-1][2:4])),
            }
        )
    return out


def row(label: str, radius: float | None, episodes: list[dict[str, float]]) -> dict[str, Any]:
    closest = np.array([e["closest"] for e in episodes])
    return {
        "controller": label,
        "radius": radius,
        "success": float(np.mean([e["success"] for e in episodes])),
        "median_final_distance": float(np.median([e["final"] for e in episodes])),
        "closest_within": {f"{t:g}": float(np.mean(closest < t)) for t in TOLERANCES},
        "median_closest": float(np.median(closest)),
        "median_final_speed": float(np.median([e["final_speed"] for e in episodes])),
    }


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", default="benchmarks/results/models/acrobot_ppo/model.zip")
    parser.add_argument("--radii", default="0.1,0.2,0.3")
    parser.add_argument("--grid", type=int, default=GRID, help="grid points per axis (20: the evaluation grid)")
    parser.add_argument("--json", default=None)
    args = parser.parse_args(argv)
    radii = [float(r) for r in args.radii.split(",") if r]
    if not radii or any(r <= 0 for r in radii):
        parser.error(f"--radii must be positive numbers, got {args.radii!r}")
    if not Path(args.model).is_file():
        parser.error(f"--model {args.model!r} does not exist")
    from seagul_learn.policies import SB3Policy

    start = time.perf_counter()
    task = make_task("acrobot")
    starts, _ = start_grid(task, args.grid)
    ppo = SB3Policy(task, args.model)
    lqr = build_policy(task, PolicySpec("lqr", "LQR"))
    rows = [row("PPO", None, fly(task, ppo, starts))]
    for radius in radii:
        rows.append(row(f"PPO, LQR from within {radius:g}", radius, fly(task, Catch(task, ppo, lqr, radius), starts)))
    rows.append(row("LQR", None, fly(task, lqr, starts)))
    start_distance = np.array([np.linalg.norm(task.state_error(x)) for x in starts])
    result = {
        "task": "acrobot",
        "model": args.model,
        "starts": int(starts.shape[0]),
        "starts_within": {f"{t:g}": float(np.mean(start_distance < t)) for t in TOLERANCES},
        "rows": rows,
        "command": "python benchmarks/bench_rl_near_goal.py" + (f" --json {args.json}" if args.json else ""),
        "machine": machine("torch", "stable_baselines3"),
        "wall_s": round(time.perf_counter() - start, 1),
    }
    if args.json:
        atomic_write_json(args.json, result)
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
