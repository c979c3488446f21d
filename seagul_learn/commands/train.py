"""``seagul train``: one SEAGuL (or uniform-baseline) training run into a run directory."""

from __future__ import annotations

import argparse
import json
from typing import Any

from seagul_learn.cli import Command
from seagul_learn.commands._args import (
    add_parallel_arguments,
    add_task_argument,
    fraction,
    non_negative_float,
    non_negative_int,
    positive_float,
    positive_int,
)


def hidden_widths(value: str) -> tuple[int, ...]:
    """``"32"`` or ``"64,32"``: hidden-layer widths."""
    try:
        widths = tuple(int(v) for v in value.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers like 32 or 64,32, got {value!r}") from None
    if not widths or any(w < 1 for w in widths):
        raise argparse.ArgumentTypeError(f"widths must be >= 1, got {value!r}")
    return widths


def budgets(value: str) -> tuple[int, ...]:
    """``"100,300,1000"``: solve counts."""
    if not value.strip():
        return ()
    try:
        out = tuple(int(v) for v in value.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers like 100,300, got {value!r}") from None
    if any(b < 1 for b in out):
        raise argparse.ArgumentTypeError(f"budgets must be >= 1, got {value!r}")
    return out


def json_object(value: str) -> dict[str, Any]:
    """A JSON object (solver options)."""
    try:
        data = json.loads(value)
    except json.JSONDecodeError as exc:
        raise argparse.ArgumentTypeError(f"not valid JSON ({exc}): {value!r}") from None
    if not isinstance(data, dict):
        raise argparse.ArgumentTypeError(f"expected a JSON object like '{{\"max_iter\": 500}}', got {value!r}")
    return data


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare the ``train`` arguments (defaults are :class:`~seagul_learn.training.TrainConfig`'s)."""
    from seagul_learn.training import TrainConfig

    d = TrainConfig()
    add_task_argument(parser)
    parser.add_argument(
        "--sampler", choices=("uniform", "adversarial", "closed-loop"), default=d.sampler, help="sample selection"
    )
    parser.add_argument("--budget", type=positive_int, default=d.budget, help="solves spent by the sampler")
    parser.add_argument("--seed", type=int, default=d.seed, help="seed of every random stream")
    parser.add_argument("--out", required=True, help="run directory (created; must be new unless --resume)")
    parser.add_argument("--resume", action="store_true", help="continue an interrupted run in --out")
    parser.add_argument("--sobolev", type=non_negative_float, default=d.sobolev_weight, help="Sobolev weight w")
    parser.add_argument("--solves-per-round", type=positive_int, default=d.solves_per_round)
    parser.add_argument("--train-steps-per-round", type=non_negative_int, default=d.train_steps_per_round)
    parser.add_argument("--batch-size", type=positive_int, default=d.batch_size)
    parser.add_argument("--newest-fraction", type=fraction, default=d.newest_fraction)
    parser.add_argument("--lr", type=positive_float, default=d.lr)
    parser.add_argument("--hidden", type=hidden_widths, default=d.hidden, help="hidden widths, e.g. 32 or 64,32")
    parser.add_argument("--ensemble", type=positive_int, default=d.ensemble, help="networks (>= 2: an ensemble)")
    parser.add_argument("--ensemble-pessimism", type=non_negative_float, default=d.ensemble_pessimism)
    parser.add_argument("--pretrain-solves", type=positive_int, default=d.pretrain_solves)
    parser.add_argument("--pretrain-steps", type=non_negative_int, default=d.pretrain_steps)
    parser.add_argument("--adv-max-steps", type=positive_int, default=d.adv_max_steps)
    parser.add_argument("--adv-step-fraction", type=positive_float, default=d.adv_step_fraction)
    parser.add_argument("--adv-eps", type=non_negative_float, default=d.adv_eps)
    parser.add_argument("--adv-optimizer", choices=("pga", "adam"), default=d.adv_optimizer)
    parser.add_argument("--adv-projection", choices=("clip", "reflect"), default=d.adv_projection)
    parser.add_argument("--adv-uniform-fraction", type=fraction, default=d.adv_uniform_fraction)
    parser.add_argument("--adv-ascend-tau", action=argparse.BooleanOptionalAction, default=d.adv_ascend_tau)
    parser.add_argument("--adv-stop-on-decrease", action=argparse.BooleanOptionalAction, default=d.adv_stop_on_decrease)
    parser.add_argument("--uniform-tau", action=argparse.BooleanOptionalAction, default=d.uniform_tau)
    parser.add_argument("--cl-episodes", type=positive_int, default=d.cl_episodes, help="MPC episodes per round")
    parser.add_argument("--cl-horizon", type=non_negative_int, default=d.cl_horizon, help="0 = the task's default")
    parser.add_argument("--cl-trust-region", choices=("none", "lqr", "box"), default=d.cl_trust_region)
    parser.add_argument("--cl-warmup-rounds", type=non_negative_int, default=d.cl_warmup_rounds)
    parser.add_argument("--cl-selection", choices=("farthest", "spread", "lowest", "random"), default=d.cl_selection)
    parser.add_argument("--cl-tail-stride", type=positive_int, default=d.cl_tail_stride)
    parser.add_argument("--cl-uniform-fraction", type=fraction, default=d.cl_uniform_fraction)
    parser.add_argument("--cl-uniform-solves", type=non_negative_int, default=d.cl_uniform_solves)
    parser.add_argument("--cl-jit", action=argparse.BooleanOptionalAction, default=d.cl_jit)
    parser.add_argument("--value-cap", type=non_negative_float, default=d.value_cap, help="clip labels (0 = off)")
    parser.add_argument(
        "--snapshots", type=budgets, default=d.snapshots, help="save network_<n>.pt at these budgets, e.g. 100,300"
    )
    parser.add_argument("--eval-every", type=non_negative_int, default=d.eval_every)
    parser.add_argument("--solver-options", type=json_object, default=None, help="trajectory-optimizer options (JSON)")
    parser.add_argument("--cache-dir", default=None, help="validation-set cache (default $SEAGUL_CACHE_DIR)")
    parser.add_argument("--no-progress", action="store_true", help="hide progress bars")
    add_parallel_arguments(parser)


def config_from_args(args: argparse.Namespace) -> Any:
    """The :class:`~seagul_learn.training.TrainConfig` of parsed arguments."""
    from seagul_learn.training import TrainConfig

    return TrainConfig(
        task=args.task,
        sampler=args.sampler,
        budget=args.budget,
        solves_per_round=args.solves_per_round,
        train_steps_per_round=args.train_steps_per_round,
        batch_size=args.batch_size,
        newest_fraction=args.newest_fraction,
        lr=args.lr,
        sobolev_weight=args.sobolev,
        hidden=args.hidden,
        ensemble=args.ensemble,
        ensemble_pessimism=args.ensemble_pessimism,
        pretrain_solves=args.pretrain_solves,
        pretrain_steps=args.pretrain_steps,
        seed=args.seed,
        adv_max_steps=args.adv_max_steps,
        adv_step_fraction=args.adv_step_fraction,
        adv_eps=args.adv_eps,
        adv_optimizer=args.adv_optimizer,
        adv_projection=args.adv_projection,
        adv_uniform_fraction=args.adv_uniform_fraction,
        adv_ascend_tau=args.adv_ascend_tau,
        adv_stop_on_decrease=args.adv_stop_on_decrease,
        uniform_tau=args.uniform_tau,
        cl_episodes=args.cl_episodes,
        cl_horizon=args.cl_horizon,
        cl_trust_region=args.cl_trust_region,
        cl_warmup_rounds=args.cl_warmup_rounds,
        cl_selection=args.cl_selection,
        cl_tail_stride=args.cl_tail_stride,
        cl_uniform_fraction=args.cl_uniform_fraction,
        cl_uniform_solves=args.cl_uniform_solves,
        cl_jit=args.cl_jit,
        value_cap=args.value_cap,
        snapshots=args.snapshots,
        eval_every=args.eval_every,
        workers=args.workers,
        backend=args.backend,
        solver_options=args.solver_options,
        cache_dir=args.cache_dir,
        progress=not args.no_progress,
    )


def run(args: argparse.Namespace) -> int:
    """Train and print a summary; the last line is the run directory."""
    from seagul_learn.training import train

    result = train(config_from_args(args), args.out, resume=args.resume)
    last = result.metrics[-1]
    print(
        f"{args.task} {args.sampler}: {result.num_solves} solves ({result.num_failures} failed), "
        f"{last.train_steps} training steps, validation mse_initial={last.mse_initial:.4g} "
        f"mse_all_knots={last.mse_all_knots:.4g}"
    )
    print(result.out_dir)
    return 0


COMMAND = Command(
    name="train",
    help="train a value network with adversarial (SEAGuL) or uniform sampling",
    add_arguments=add_arguments,
    run=run,
)
