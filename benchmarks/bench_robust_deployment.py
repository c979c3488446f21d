"""How the shipped robust MPC's deployment settings move its success, measured on validation starts x robots.

Usage::

    .venv/bin/python benchmarks/bench_robust_deployment.py [--tasks glider] [--starts 60] [--workers 2]
        [--out DIR] [--json benchmarks/results/robust_deployment.json]

Per task, every seed's robust network of ``param_adversary.json``'s ``robust.per_seed`` rows (written by
``bench_robust.py``) is deployed as the shipped robust MPC::

    LimitedLookaheadMPC(task, ValueNetwork.load(network), horizon=H, model_params=True, estimate_robot=True)

and once per variant of :data:`VARIANTS`, each changing one setting of that deployment (the lookahead, the solver's
iteration limit, the guard of the learned terminal cost, the online estimate's prior, box or first transition, or
the robot known instead of estimated). Every run flies the same ``--starts`` validation starts
(``validation_starts``), each on its own robot from Theta (``validation_robots``): the streams the RL runs select
their checkpoints on, never the held-out starts x robots the shipped figures are measured on, so a setting chosen
here is not chosen on the test.

The result file holds, per task, ``{"horizon", "starts", "set", "variants": [{"name", "label", "options",
"knows_robot", "success_per_seed", "success_median", "fallback_steps", "crashes", "median_ms", "p95_ms"}]}`` (the
first variant is the shipped deployment) and the ``machine``. Every evaluation is
``bench_param_adversary.closed_loop``'s, cached as JSON under ``--out``, so a re-run continues. The last line of
stdout is the result as one JSON object.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._common import machine  # noqa: E402
from benchmarks.bench_param_adversary import ParamBenchConfig, closed_loop  # noqa: E402
from benchmarks.bench_robust import robust_spec  # noqa: E402
from seagul_control.evaluation import PolicySpec  # noqa: E402
from seagul_control.io import atomic_write_json  # noqa: E402
from seagul_envs import make_task  # noqa: E402
from seagul_learn.baselines import validation_robots, validation_starts  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"


@dataclass(frozen=True)
class Variant:
    """One change to the shipped deployment: ``options`` replace the spec's (``horizon``, ``estimate_robot``, any
    :class:`~seagul_control.mpc.MPCOptions` field); ``knows_robot`` plans for the episode's true robot."""

    name: str
    label: str
    options: tuple[tuple[str, Any], ...] = ()
    knows_robot: bool = False


VARIANTS: tuple[Variant, ...] = (
    Variant("shipped", "as shipped"),
    Variant("knows-robot", "knows the robot (no estimate)", (("estimate_robot", False),), knows_robot=True),
    Variant("horizon-minus-2", "lookahead 2 steps shorter", (("horizon", -2),)),
    Variant("horizon-plus-2", "lookahead 2 steps longer", (("horizon", 2),)),
    Variant("max-iter-200", "200 solver iterations per step (default 50)", (("max_iter", 200),)),
    Variant("trust-box", "learned cost guarded by its training box", (("trust_region", "box"),)),
    Variant("trust-lqr", "learned cost guarded by the LQR region", (("trust_region", "lqr"),)),
    Variant(
        "estimate-in-theta",
        "estimate confined to Theta (default: 3x wider)",
        (("estimate_robot", (("box_scale", 1.0),)),),
    ),
    Variant("estimate-prior-1e-3", "estimate's prior weight 1e-3", (("estimate_robot", (("prior", 1e-3),)),)),
    Variant("estimate-prior-1e-7", "estimate's prior weight 1e-7", (("estimate_robot", (("prior", 1e-7),)),)),
    Variant("estimate-strong-prior", "estimate's prior weight 0.1", (("estimate_robot", (("prior", 0.1),)),)),
    Variant(
        "estimate-after-3",
        "estimate from the third transition (the glider's default: the first)",
        (("estimate_robot", (("min_transitions", 3),)),),
    ),
)
"""The deployments measured; ``horizon`` options are offsets from the shipped horizon."""


def variant_spec(variant: Variant, network: str, horizon: int) -> PolicySpec:
    """The shipped robust MPC's spec (``bench_robust.robust_spec``) with ``variant``'s changes."""
    options = robust_spec(network, horizon).option_dict()
    for key, value in variant.options:
        options[key] = horizon + int(value) if key == "horizon" else value
    return PolicySpec("mpc", variant.label, network, tuple(options.items()), variant.knows_robot)


def run_task(task_name: str, n_starts: int, workers: int, out: Path) -> dict[str, Any]:
    """Every variant of :data:`VARIANTS` for every seed's network of ``param_adversary.json``."""
    task = make_task(task_name)
    block = json.loads((RESULTS / "param_adversary.json").read_text()).get(task_name, {})
    if "shipped" not in block or "robust" not in block:
        raise SystemExit(f"{task_name}: param_adversary.json has no shipped robust MPC (run bench_robust.py first)")
    horizon = int(block["shipped"]["horizon"])
    networks = [str(ROOT / row["network"]) for row in block["robust"]["per_seed"]]
    starts, robots = validation_starts(task, n_starts), validation_robots(task, n_starts)
    scorer = ParamBenchConfig(task=task_name)
    variants = []
    for variant in VARIANTS:
        rows = [
            closed_loop(
                scorer,
                variant_spec(variant, net, horizon),
                starts,
                robots,
                workers,
                out / task_name / f"{variant.name}-seed{seed}.json",
            )
            for seed, net in enumerate(networks)
        ]
        rates = [r["success_rate"] for r in rows]
        variants.append(
            {
                "name": variant.name,
                "label": variant.label,
                "options": {k: (dict(v) if isinstance(v, tuple) else v) for k, v in variant.options},
                "knows_robot": variant.knows_robot,
                "success_per_seed": rates,
                "success_median": float(np.median(rates)),
                "fallback_steps": sum(r["fallback_steps"] for r in rows),
                "crashes": sum(r["crashes"] for r in rows),
                "median_ms": float(np.median([r["median_ms"] for r in rows])),
                "p95_ms": float(np.median([r["p95_ms"] for r in rows])),
            }
        )
        print(f"{task_name} {variant.name}: {[f'{r:.0%}' for r in rates]} median {np.median(rates):.1%}", flush=True)
    return {
        "horizon": horizon,
        "starts": n_starts,
        "set": "validation starts x validation robots (seagul_learn.baselines.validation_starts, validation_robots)",
        "networks": [row["network"] for row in block["robust"]["per_seed"]],
        "variants": variants,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", default="glider", help="comma-separated tasks of param_adversary.json")
    parser.add_argument("--starts", type=int, default=60, help="validation starts x robots")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("/tmp/seagul-bench-robust-deployment"))
    parser.add_argument("--json", type=Path, default=None, help="write the result here")
    args = parser.parse_args(argv)
    if args.starts < 1:
        parser.error(f"--starts must be >= 1, got {args.starts}")
    t0 = time.perf_counter()
    result: dict[str, Any] = {t: run_task(t, args.starts, args.workers, args.out) for t in args.tasks.split(",")}
    result["machine"] = {**machine("torch"), "wall_s": round(time.perf_counter() - t0, 1)}
    if args.json:
        atomic_write_json(args.json, result)
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
