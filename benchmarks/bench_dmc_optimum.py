"""The optimum of ``pendulum-swingup`` (dynamic programming on a grid of its state) scored by dm_control's own reward.

Usage::

    nice -n 5 .venv/bin/python benchmarks/bench_dmc_optimum.py [--seeds 0-9] [--wide-seeds 0-99] \\
        [--grids 360x201x11 720x401x11 1440x801x21] [--json benchmarks/results/dmc_optimum.json]

For each grid ``ANGLExVELOCITYxACTIONS`` (:class:`seagul_control.grid_optimum.GridSpec`: angle cells, velocity nodes,
torques per backup; the other fields their defaults) it runs the value iteration of
:class:`~seagul_control.grid_optimum.GridOptimum` and scores its greedy controller through
:func:`seagul_control.dmc.run_dmc_episode` on the evaluation reset seeds ``--seeds`` (those of every other row of
``benchmarks/results/dmc.json``) and on the wider set ``--wide-seeds`` (100 episodes: the published scores are means
over many episodes, and 10 of them differ from the reset distribution's mean by about 30 points). The grids are
refinements of each other: the scores' change from one to the next is the resolution's error. The last grid is the
result.

The same run also scores the classical energy-pumping swing-up (:class:`seagul_control.spong.PendulumEnergyController`,
its default gains) on the wide seeds, so the two are compared on the same 100 episodes.

Writes ``{"tasks": {"dm_control/pendulum-swingup-v0": {"controller": "grid optimum", "spec", "scores", "seeds",
"mean", "std", "decision_ms_median", "decision_ms_p95", "solve_s", "wide": {"seeds", "scores", "mean", "std"},
"energy_wide": {"seeds", "scores", "mean", "std"}, "refinement": [{"spec", "mean", "wide_mean", "solve_s"}]}},
"machine", "command", "wall_s"}``; ``benchmarks/bench_dmc.py --gather`` copies it into the ``optimum`` block of
``dmc.json``. Measured results and what they say: docs/experiments/dmc-learned.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path
from typing import Any

from tqdm import tqdm

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._common import machine, parse_seeds  # noqa: E402
from benchmarks.bench_dmc import score_row  # noqa: E402
from seagul_control import spong  # noqa: E402
from seagul_control.grid_optimum import GridOptimum, GridSpec  # noqa: E402

ENV_ID = "dm_control/pendulum-swingup-v0"
DEFAULT_GRIDS = ("360x201x11", "720x401x11", "1440x801x21")


def parse_grid(text: str) -> GridSpec:
    """``"720x401x11"`` -> ``GridSpec(angle_cells=720, velocity_points=401, actions=11)``."""
    parts = text.lower().split("x")
    if len(parts) != 3 or not all(p.isdigit() for p in parts):
        raise ValueError(f"a grid is ANGLExVELOCITYxACTIONS, e.g. 720x401x11; got {text!r}")
    a, v, u = (int(p) for p in parts)
    return GridSpec(angle_cells=a, velocity_points=v, actions=u)


def episodes(controller: Any, seeds: list[int]) -> dict[str, Any]:
    """``controller`` on each reset seed: :func:`benchmarks.bench_dmc.score_row`'s scores, mean, std and decision
    times (every seed's episode from one controller: the grid policy and the energy swing-up keep no state)."""
    row = score_row(ENV_ID, "", lambda _seed: controller, seeds)
    return {key: row[key] for key in ("seeds", "scores", "mean", "std", "decision_ms_median", "decision_ms_p95")}


def solve(spec: GridSpec) -> tuple[GridOptimum, float]:
    start = time.perf_counter()
    optimum = GridOptimum(spec)
    for _ in tqdm(
        optimum.iterate(),
        total=spec.backups,
        desc=f"backups {spec.angle_cells}x{spec.velocity_points}",
        leave=False,
        file=sys.stderr,
    ):
        pass
    return optimum, round(time.perf_counter() - start, 1)


def benchmark(grids: list[GridSpec], seeds: list[int], wide: list[int]) -> dict[str, Any]:
    refinement, last = [], None
    for spec in grids:
        optimum, solve_s = solve(spec)
        main = episodes(optimum, seeds)
        broad = episodes(optimum, wide)
        refinement.append(
            {"spec": dataclasses.asdict(spec), "mean": main["mean"], "wide_mean": broad["mean"], "solve_s": solve_s}
        )
        print(json.dumps(refinement[-1]), file=sys.stderr, flush=True)
        last = (spec, main, broad, solve_s)
    assert last is not None
    spec, main, broad, solve_s = last
    energy = episodes(spong.PendulumEnergyController(spong.PendulumSwingUpParams()), wide)
    return {
        "controller": "grid optimum",
        "spec": dataclasses.asdict(spec),
        **main,
        "solve_s": solve_s,
        "wide": {key: broad[key] for key in ("seeds", "scores", "mean", "std")},
        "energy_wide": {key: energy[key] for key in ("seeds", "scores", "mean", "std")},
        "refinement": refinement,
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", default="0-9", help="evaluation reset seeds (default 0-9)")
    parser.add_argument("--wide-seeds", default="0-99", help="the wider set of reset seeds (default 0-99)")
    parser.add_argument("--grids", nargs="+", default=list(DEFAULT_GRIDS), help="ANGLExVELOCITYxACTIONS, coarse first")
    parser.add_argument("--json", type=Path, default=None, help="write the result here (default: stdout only)")
    args = parser.parse_args(argv)
    try:
        grids = [parse_grid(g) for g in args.grids]
    except ValueError as error:
        parser.error(str(error))
    start = time.perf_counter()
    block = benchmark(grids, parse_seeds(args.seeds), parse_seeds(args.wide_seeds))
    result = {
        "tasks": {ENV_ID: block},
        "machine": machine(),
        "command": "benchmarks/bench_dmc_optimum.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "wall_s": round(time.perf_counter() - start, 1),
    }
    text = json.dumps(result, indent=1)
    if args.json:
        tmp = args.json.with_suffix(".tmp")
        tmp.write_text(text + "\n")
        tmp.replace(args.json)
    print(
        f"grid optimum: {block['mean']:.1f} on seeds {args.seeds}, {block['wide']['mean']:.1f} on {args.wide_seeds}; "
        f"energy {block['energy_wide']['mean']:.1f}",
        file=sys.stderr,
    )
    print(text)


if __name__ == "__main__":
    main()
