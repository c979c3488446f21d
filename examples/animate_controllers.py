"""Watch the controllers: one closed-loop episode each from the same hard start, side by side, as a GIF.

Usage::

    .venv/bin/python examples/animate_controllers.py --task acrobot \\
        --network benchmarks/results/networks/acrobot_closed-loop_rest_b1000_seed1.pt \\
        [--sb3 PATH:ALGO ...] [--start "2.84159,-0.3,0,0"] [--out docs/figures/acrobot_controllers.gif] [--test]

Controllers, left to right: the learned limited-lookahead MPC (``--network``, deployed as the closed-loop
benchmark deploys it: the task's default horizon, no guard, the task's goal blend), LQR (time-varying along the
optimal path for the glider), the full-horizon MPC and every ``--sb3`` model (``model.zip:SAC``; its
``vecnormalize.pkl`` is found beside it). The default start is the corner of X0 that is farthest from the goal in
the task's grid coordinates (``seagul_learn.report.hard_start``; acrobot: ``(th1, th2) = (pi - 0.3, -0.3)`` at
rest). Frames come from the envs' ``rgb_array`` rendering (``seagul_learn.report.controller_animation``); the GIF
plays in real time and holds the last frame, whose labels say who succeeded and at what cost. ``--test`` is a
seconds-long check (CI): LQR only.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np

from seagul_control.evaluation import PolicySpec, build_policy, default_horizon
from seagul_envs import make_task
from seagul_learn.report import controller_animation, hard_start


@dataclasses.dataclass
class Config:
    """What to animate (CleanRL style: the command line is derived from these fields)."""

    task: str = "acrobot"
    """Registered task name."""
    network: str = ""
    """Value network or ensemble of the learned MPC (empty: no learned MPC)."""
    sb3: tuple[str, ...] = ()
    """SB3 models as ``path:ALGO`` (ALGO: PPO or SAC)."""
    start: str = ""
    """Start state, comma-separated (empty: the hard corner of X0)."""
    full_horizon: bool = True
    """Include the full-horizon MPC (the glider's takes ~1 s per step)."""
    out: str = ""
    """GIF path (default docs/figures/<task>_controllers.gif)."""
    test: bool = False
    """Seconds-long check: LQR only, written to a temporary directory."""


def main(cfg: Config) -> Path:
    task = make_task(cfg.task)
    x0 = np.array([float(v) for v in cfg.start.split(",")]) if cfg.start else hard_start(task)
    specs: list[PolicySpec] = []
    if cfg.network and not cfg.test:
        blend = float(task.profile.mpc.goal_blend)
        options = (("horizon", default_horizon(task)), ("trust_region", "none"), ("goal_blend", blend))
        specs.append(PolicySpec("mpc", f"learned {default_horizon(task)}-step MPC", cfg.network, options))
    specs.append(PolicySpec("lqr", "LQR"))
    if cfg.full_horizon and not cfg.test:
        specs.append(PolicySpec("full", "full-horizon MPC"))
    for entry in () if cfg.test else cfg.sb3:
        path, _, algo = entry.rpartition(":")
        if not path or algo.upper() not in ("PPO", "SAC"):
            raise SystemExit(f"--sb3 takes path:ALGO with ALGO PPO or SAC, got {entry!r}")
        specs.append(PolicySpec("sb3", algo.upper(), path, (("algo", algo.upper()),)))
    policies = [(spec.name, build_policy(task, spec)) for spec in specs]
    if cfg.out:
        out = Path(cfg.out)
    elif cfg.test:
        import tempfile

        out = Path(tempfile.mkdtemp(prefix="seagul-gif-")) / "test.gif"
    else:
        out = Path("docs/figures") / f"{cfg.task}_controllers.gif"
    path, episodes = controller_animation(task, policies, x0, out)
    print(f"start {np.round(x0, 4).tolist()}")
    for e in episodes:
        print(f"  {e.policy}: {'success' if e.success else 'failure'}, cost {e.cost:.2f}, {e.steps} steps")
    print(f"wrote {path}")
    return path


def parse(argv: list[str] | None = None) -> Config:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    for f in dataclasses.fields(Config):
        flag = "--" + f.name.replace("_", "-")
        if f.type in ("bool", bool):
            parser.add_argument(flag, action=argparse.BooleanOptionalAction, default=f.default)
        elif f.name == "sb3":
            parser.add_argument(flag, action="append", default=[], help="path:ALGO (repeatable)")
        else:
            parser.add_argument(flag, default=f.default)
    args = vars(parser.parse_args(argv))
    args["sb3"] = tuple(args["sb3"])
    return Config(**args)


if __name__ == "__main__":
    main(parse())
