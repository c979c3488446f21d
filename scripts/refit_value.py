"""Refit a value network from scratch on every solve of a finished training run (``seagul train --out RUN``).

Why: the sampler-driven training fixes its output standardisation from the 10 pretraining solves, so closed-loop
tail labels (values up to the cap, with large dual gradients) arrive many standard deviations out and wreck the fit
(docs/experiments/closed-loop.md, "Why the unguarded learned cost fails", point 7). This script fits a fresh network to
the whole dataset with the standardisation taken from all (capped) labels and the gradient labels whose standardised
norm exceeds ``--grad-max`` dropped: the run's config with ``TrainConfig.refit.steps`` etc. overridden, fitted by
:func:`seagul_learn.training.refit`.

    python scripts/refit_value.py RUN --cap 50 --grad-max 10 --hidden 64,64 --steps 20000 --out refit.pt

With ``--candidates N --ensemble K`` it fits ``N`` members and keeps the ``K`` whose MPC flies best on training starts
(``TrainConfig.refit.candidates``, :func:`seagul_learn.training.refit_and_select`): ``network_candidates.pt`` and
``network_selection.json`` are written beside ``--out``. Batch size and seed default to the run's own, so the
result is what the run would have deployed with ``refit.candidates``.

Prints the number of knots; the last line is a JSON object with the output path, the counts (knots, gradient labels
used) and the wall time.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch

from seagul_learn.dataset import Dataset, training_arrays
from seagul_learn.training import TrainConfig, _as_tensors, _Trainer, make_network, refit, refit_and_select


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="directory of a finished `seagul train` run")
    parser.add_argument("--out", type=Path, required=True, help="where to write the refitted network (.pt)")
    parser.add_argument("--cap", type=float, default=50.0, help="labels above this are clipped (gradients dropped)")
    parser.add_argument("--grad-max", type=float, default=10.0, help="drop gradient labels above this std. norm")
    parser.add_argument("--hidden", default="64,64", help="hidden widths, comma-separated")
    parser.add_argument("--steps", type=int, default=20000, help="Adam steps (cosine learning-rate decay)")
    parser.add_argument("--batch-size", type=int, default=None, help="default: the run's")
    parser.add_argument("--lr", type=float, default=1e-3)
    parser.add_argument("--sobolev", type=float, default=1.0, help="weight of the gradient term")
    parser.add_argument("--max-solves", type=int, default=0, help="use only records with index below this (0: all)")
    parser.add_argument("--seed", type=int, default=None, help="default: the run's")
    parser.add_argument("--ensemble", type=int, default=1, help="members (>= 2: a ValueEnsemble, one fit each)")
    parser.add_argument("--pessimism", type=float, default=1.0, help="the ensemble's spread weight in the MPC")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (1: a small network is fastest so)")
    parser.add_argument("--candidates", type=int, default=0, help="fit this many members, keep the --ensemble best")
    parser.add_argument("--select-episodes", type=int, default=100, help="closed-loop episodes per candidate subset")
    parser.add_argument("--finalists", type=int, default=0, help="second stage: the best N subsets fly more starts")
    parser.add_argument("--final-episodes", type=int, default=0, help="second-stage episodes per finalist")
    parser.add_argument(
        "--slice-fraction", type=float, default=0.0, help="share of selection starts on the grid's slice of X0"
    )
    args = parser.parse_args()
    if args.cap <= 0 or args.grad_max <= 0 or args.steps < 1:
        parser.error("--cap and --grad-max must be > 0 and --steps >= 1")

    stored = TrainConfig.from_run(args.run)
    config = stored.replaced(
        **{
            "loss.value_cap": args.cap,
            "loss.grad_label_max": args.grad_max,
            "loss.sobolev_weight": args.sobolev,
            "network.hidden": tuple(int(w) for w in args.hidden.split(",")),
            "network.ensemble": args.ensemble,
            "network.pessimism": args.pessimism,
            "refit.steps": args.steps,
            "refit.ensemble": args.ensemble if args.candidates else stored.refit.ensemble,
            "refit.candidates": args.candidates,
            "schedule.batch_size": stored.schedule.batch_size if args.batch_size is None else args.batch_size,
            "schedule.lr": args.lr,
            "seed": stored.seed if args.seed is None else args.seed,
            "runtime.torch_threads": args.threads,
            "selection.episodes": args.select_episodes,
            "selection.finalists": args.finalists,
            "selection.final_episodes": args.final_episodes,
            "selection.slice_fraction": args.slice_fraction,
        }
    )
    task = config.resolve_task()
    meta = json.loads((args.run / "dataset" / "dataset.json").read_text())["meta"]
    dataset = Dataset.open(args.run / "dataset", task.name, meta=meta)
    records = [r for r in dataset.records() if not args.max_solves or r.index < args.max_solves]
    arrays = training_arrays(records)
    print(f"{len(records)} solves, {len(arrays)} knots", flush=True)

    torch.set_num_threads(args.threads)  # more threads than free cores makes each small step many times slower
    start = time.perf_counter()
    trainer = _Trainer(config, make_network(config, task), None)
    if args.candidates:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        network = refit_and_select(config, task, arrays, trainer, args.out.parent)
    else:
        network = refit(config, task, arrays, trainer)  # the same refit as TrainConfig.refit.steps
    used = int(_as_tensors(arrays, config.loss.value_cap, config.loss.grad_label_max, network)["grad_ok"].sum())
    network.save(args.out)
    result = {
        "network": str(args.out),
        "solves": len(records),
        "knots": len(arrays),
        "gradient_labels_used": used,
        "train_s": round(time.perf_counter() - start, 1),
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
