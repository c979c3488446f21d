"""``seagul evaluate``: closed-loop evaluation of policies from a grid of starts (paper Figs. 2-4).

Example::

    seagul evaluate --task acrobot --network runs/acrobot/network.pt --lqr --full-horizon \\
        --sb3 runs/ppo_acrobot/model.zip --grid 20 --workers 2 --out results/eval_acrobot

writes ``summary.json``/``summary.csv``/``results.json``, ``heatmap.png`` and (glider) ``trajectories.png`` into
``--out`` (episodes are run by :mod:`seagul_control.evaluation`, tables and figures made by
:mod:`seagul_learn.report`). Several ``--network`` files may be given (one MPC each, labelled by ``--label`` or the
file's parent directory). ``--task`` is a registered name or ``module:factory`` (your own Task, e.g.
``--task examples.custom_system:make_cartpole``); the grid, the default horizon and the success rule are the task's
(``task.profile``).

In the DeepMind Control Suite::

    seagul evaluate --dmc pendulum-swingup --network NETWORK.pt --episodes 10 --seed 0

runs the learned MPC (:mod:`seagul_learn.dmc_eval`) in dm_control's own env on reset seeds ``S .. S+N-1``, scored by
dm_control's reward, and prints a JSON object last: ``{"task", "score_mean", "score_std", "episodes", "median_ms",
"p95_ms", ...}`` (``--task`` and ``--out`` are not used; ``--horizon``, ``--time-to-go``, ``--hold``, ``--dt`` and
``--path-bounds`` override the env's deployment, :data:`seagul_learn.dmc_eval.DEFAULT_DEPLOYMENTS`).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from seagul_control.starts import start_grid
from seagul_envs import resolve_task
from seagul_learn.cli import Command
from seagul_learn.commands._args import (
    add_task_argument,
    non_negative_float,
    non_negative_int,
    positive_float,
    positive_int,
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare the ``evaluate`` arguments."""
    add_task_argument(parser, required=False)
    parser.add_argument("--out", default=None, help="output directory (created if missing; required without --dmc)")
    dmc = parser.add_argument_group("DeepMind Control Suite (--dmc)")
    dmc.add_argument(
        "--dmc",
        default=None,
        metavar="DOMAIN-TASK",
        help="score the --network's MPC in dm_control's own env (pendulum-swingup, cartpole-swingup, "
        "cartpole-swingup_sparse, acrobot-swingup) and print a JSON object last; needs seagul[dmc]",
    )
    dmc.add_argument("--episodes", type=positive_int, default=10, help="--dmc: episodes (default 10)")
    dmc.add_argument("--seed", type=non_negative_int, default=0, help="--dmc: first reset seed (default 0)")
    dmc.add_argument(
        "--time-to-go",
        type=non_negative_float,
        default=None,
        help="--dmc: the value's constant time to go tau_V (s) after the lookahead (default: the env's deployment)",
    )
    dmc.add_argument(
        "--hold", type=positive_int, default=None, help="--dmc: control steps per MPC decision (default: the env's)"
    )
    dmc.add_argument(
        "--dt", type=positive_float, default=None, help="--dmc: the MPC's interval in s (default: the env's)"
    )
    dmc.add_argument(
        "--path-bounds",
        choices=("hard", "soft", "none"),
        default=None,
        help="--dmc: the task's state path bounds in the lookahead: constraints, a penalty, or dropped "
        "(default: the env's)",
    )
    parser.add_argument("--network", action="append", default=[], help="value network file for an MPC (repeatable)")
    parser.add_argument("--label", action="append", default=[], help="label of each --network MPC, in order")
    parser.add_argument("--task-terminal", action="store_true", help="also the MPC with the task's own l_f")
    parser.add_argument("--lqr", action="store_true", help="include the (clipped, TV for the glider) LQR reference")
    parser.add_argument("--full-horizon", action="store_true", help="include the full-horizon MPC (slow)")
    parser.add_argument("--sb3", action="append", default=[], help="a saved SB3 model zip (repeatable)")
    parser.add_argument(
        "--sb3-algo",
        default="PPO",
        choices=("A2C", "DDPG", "PPO", "SAC", "TD3"),
        help="SB3 algorithm class of the --sb3 models (default PPO)",
    )
    parser.add_argument(
        "--horizon", type=positive_int, default=None, help="MPC steps (default: the task's; acrobot 5, glider 10)"
    )
    parser.add_argument(
        "--trust-region",
        choices=("lqr", "box", "none"),
        default=None,
        help="guard of the learned terminal cost (default: the task's profile.mpc.trust_region; acrobot and glider: "
        "none)",
    )
    parser.add_argument(
        "--goal-blend",
        type=float,
        default=None,
        help="the learned MPCs' goal_blend c: b l_f + (1 - b) Vhat with b = exp(-l_f / c) (0 = off; default: the "
        "task's, acrobot 1)",
    )
    parser.add_argument(
        "--multistart",
        choices=("never", "rise", "always"),
        default=None,
        help="when the learned MPCs' condensed solver also descends from the input bounds (default: the MPC's, "
        "'rise' on the condensed solver: at a cold start and when the warm plan's cost rose)",
    )
    parser.add_argument(
        "--env",
        default=None,
        metavar="ENV_ID",
        help="run the episodes in this registered env of the task (e.g. SeagulAcrobotMujoco-v0; default: the task's)",
    )
    parser.add_argument("--no-jit", action="store_true", help="solve interpreted (no C compiler needed)")
    parser.add_argument(
        "--grid",
        type=positive_int,
        default=None,
        help="grid points per axis (default: the task's; acrobot 20, glider 6)",
    )
    parser.add_argument("--workers", type=positive_int, default=1, help="parallel processes (default 1)")
    parser.add_argument("--no-progress", action="store_true", help="hide progress bars")


def specs_from_args(args: argparse.Namespace) -> list[Any]:
    """The :class:`~seagul_control.policy_kinds.PolicySpec` list the arguments ask for."""
    # The controller stack (casadi, the MPC, LQR) loads when the command runs: `seagul --help` stays fast.
    from seagul_control.policy_kinds import PolicySpec

    if len(args.label) > len(args.network):
        raise ValueError(f"--label given {len(args.label)} times but --network only {len(args.network)} times")
    mpc_options: list[tuple[str, Any]] = [("jit", not args.no_jit)]
    if args.horizon is not None:
        mpc_options.append(("horizon", args.horizon))
    specs = []
    learned = [*mpc_options, ("trust_region", args.trust_region)]
    if getattr(args, "goal_blend", None) is not None:
        if args.goal_blend < 0:
            raise ValueError(f"--goal-blend must be >= 0, got {args.goal_blend}")
        learned.append(("goal_blend", args.goal_blend))
    if getattr(args, "multistart", None) is not None:
        learned.append(("multistart", args.multistart))
    for k, path in enumerate(args.network):
        label = args.label[k] if k < len(args.label) else f"mpc[{Path(path).parent.name or Path(path).stem}]"
        specs.append(PolicySpec("mpc", label, path, tuple(learned)))
    if args.task_terminal:
        specs.append(PolicySpec("mpc", "mpc[task l_f]", None, tuple(mpc_options)))
    if args.lqr:
        specs.append(PolicySpec("lqr", "lqr"))
    if args.full_horizon:
        specs.append(PolicySpec("full", "full-horizon"))
    for path in args.sb3:
        specs.append(
            PolicySpec("sb3", f"sb3[{Path(path).parent.name or Path(path).stem}]", path, (("algo", args.sb3_algo),))
        )
    if not specs:
        raise ValueError("no policy to evaluate: give --network, --task-terminal, --lqr, --full-horizon or --sb3")
    return specs


def run_dmc(args: argparse.Namespace) -> int:
    """``--dmc``: score one network's MPC in the suite's env; the last line printed is the JSON result."""
    import dataclasses

    from seagul_control.dmc import dmc_env_id
    from seagul_learn.dmc_eval import DEFAULT_DEPLOYMENTS, DMCDeployment, evaluate_network_dmc

    env_id = dmc_env_id(args.dmc)
    if len(args.network) != 1:
        raise ValueError(f"--dmc scores one learned MPC: give exactly one --network (got {len(args.network)})")
    if args.task is not None or args.out is not None:
        raise ValueError("--dmc takes its task from the env (no --task) and prints its result (no --out)")
    path = Path(args.network[0])
    if not path.is_file():
        raise FileNotFoundError(f"--network {path}: no such file")
    setting = DEFAULT_DEPLOYMENTS.get(env_id, DMCDeployment())
    changes = {
        key: value
        for key, value in (
            ("horizon", args.horizon),
            ("time_to_go", args.time_to_go),
            ("hold", args.hold),
            ("dt", args.dt),
            ("path_bounds", args.path_bounds),
        )
        if value is not None
    }
    setting = dataclasses.replace(setting, **changes)
    seeds = list(range(args.seed, args.seed + args.episodes))
    result = evaluate_network_dmc(env_id, path, seeds, setting, progress=not args.no_progress, jit=not args.no_jit)
    print(json.dumps({**result, "network": str(path)}))
    return 0


def run(args: argparse.Namespace) -> int:
    """Evaluate, write the tables and figures, print one line per policy; the last line is the output directory."""
    if args.dmc is not None:
        return run_dmc(args)
    if args.task is None or args.out is None:
        raise ValueError("--task and --out are required (or --dmc DOMAIN-TASK with one --network)")
    from seagul_control.evaluation import evaluate
    from seagul_learn.report import summarize, write_outputs

    task = resolve_task(args.task)  # resolved once: the Task object goes to the workers
    specs = specs_from_args(args)
    n = args.grid if args.grid is not None else task.profile.grid.points
    starts, grid = start_grid(task, n)
    record = task.profile.trajectory_plot is not None
    results = evaluate(
        task, specs, starts, workers=args.workers, progress=not args.no_progress, record=record, env_id=args.env
    )
    write_outputs(args.out, task, results, grid)
    for row in summarize(task, results):
        print(
            f"{row['policy']}: success {row['success_rate']:.1%}, mean distance {row['mean_final_distance']:.4g}, "
            f"mean cost {row['mean_cost']:.4g}, step median {row['median_step_ms']:.3g} ms, "
            f"p95 {row['p95_step_ms']:.3g} ms, fallbacks {row['fallback_steps']}"
        )
    print(Path(args.out))
    return 0


COMMAND = Command(
    name="evaluate",
    help="closed-loop evaluation of MPC/LQR/full-horizon/SB3 policies over a grid of starts (tables + figures)",
    add_arguments=add_arguments,
    run=run,
)
