"""Benchmark of the trajectory optimizer: speed, robustness, accuracy and label consistency over uniform draws from X0.

Usage: ``python benchmarks/bench_trajopt.py [--quick] [--workers 2] [--seed 0]``. The last line printed is a JSON
object ``{"acrobot": {"median_ms", "p95_ms", "success_rate", "n", ...}, "glider": {...}, "parallel_speedup": ...,
"machine": {...}}``. Times are wall-clock per solve (``SolveResult.solve_time``, fallbacks included); ``cpu_*`` are
the solving thread's CPU times, which show what an unloaded core would give when other jobs share the machine.

``--parallel-only [--n 200] [--repeats 3] [--no-ray]``: ``solve_many`` on ``n`` acrobot starts with 1 and
``--workers`` workers, for the local backend and for Ray (every configuration warmed first, so Ray is measured
after its actor pool exists and every worker has built its solver); median wall time over the repeats, the
speed-ups, the per-chunk overhead and the machine's load; the last line is a JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._common import machine  # noqa: E402
from seagul_envs.tasks import make_task  # noqa: E402
from seagul_learn.parallel import solve_many  # noqa: E402
from seagul_learn.results import SolveResult  # noqa: E402
from seagul_learn.trajopt import TrajectoryOptimizer, integrator_error  # noqa: E402


def bench_task(name: str, n: int, seed: int, n_accuracy: int, n_consistency: int) -> dict[str, Any]:
    task = make_task(name)
    t0 = time.perf_counter()
    opt = TrajectoryOptimizer(name)
    build_s = time.perf_counter() - t0
    rng = np.random.default_rng(seed)
    opt.solve(task.sample_x0(np.random.default_rng(seed + 999)))  # warm-up (builds the fallback solver)
    starts = task.sample_x0(rng, n)
    results: list[SolveResult] = []
    cpu: list[float] = []
    for x in starts:
        c0 = time.thread_time()
        results.append(opt.solve(x))
        cpu.append(time.thread_time() - c0)
    wall = np.array([r.solve_time for r in results]) * 1e3
    cpu_ms = np.array(cpu) * 1e3
    ok = np.array([r.success for r in results])
    failures: dict[str, int] = {}
    for r in results:
        if not r.success:
            failures[r.status] = failures.get(r.status, 0) + 1
    first_attempt: dict[str, int] = {}
    for r in results:
        if r.success:
            first_attempt[r.attempts[-1]] = first_attempt.get(r.attempts[-1], 0) + 1
    out: dict[str, Any] = {
        "median_ms": round(float(np.median(wall)), 2),
        "p95_ms": round(float(np.percentile(wall, 95)), 2),
        "max_ms": round(float(wall.max()), 1),
        "success_rate": round(float(ok.mean()), 4),
        "n": n,
        "cpu_median_ms": round(float(np.median(cpu_ms)), 2),
        "cpu_p95_ms": round(float(np.percentile(cpu_ms, 95)), 2),
        "median_iterations": float(np.median([r.iterations for r in results])),
        "fallback_rate": round(float(np.mean([len(r.attempts) > 1 for r in results])), 4),
        "solved_by": first_attempt,
        "failure_statuses": failures,
        "build_s": round(build_s, 2),
        "plan": list(opt.config.plan or ()),
    }
    good = [r for r in results if r.success]
    if good:
        values = np.array([r.value for r in good])
        out["value_range"] = [round(float(values.min()), 4), round(float(values.max()), 4)]
        errs = [integrator_error(task, r, max_substep=1e-4) for r in good[:n_accuracy]]
        out["integrator"] = {
            "n": len(errs),
            "max_state_error": float(f"{max(e['max_state_error'] for e in errs):.3g}"),
            "max_cost_quadrature_rel_error": float(f"{max(e['cost_quadrature_rel_error'] for e in errs):.3g}"),
            "median_replay_final_error": float(f"{np.median([e['replay_final_error'] for e in errs]):.3g}"),
        }
        out["local_optima"] = local_optima(opt, good[:n_consistency])
    return out


def local_optima(opt: TrajectoryOptimizer, results: list[SolveResult]) -> dict[str, Any]:
    """How often a start's label depends on the initial guess, and how often nearby starts disagree.

    * ``guess_disagreement``: the same start re-solved from each other guess (same solver chain); fraction whose
      value differs by more than 1e-4 relative from the label, and fraction where another guess was strictly better.
    * ``neighbour_jumps``: a start moved by 1e-3 of the X0 box width; fraction where ``V(x + d)`` differs from the
      first-order prediction ``V(x) + grad . d`` by more than 1e-3 relative (a different local optimum).
    """
    task = opt.task
    width = np.where(task.x0_high > task.x0_low, task.x0_high - task.x0_low, 0.0)
    rng = np.random.default_rng(1234)
    differ = better = jumps = checked = 0
    gaps: list[float] = []
    # The "kinematic" guess differs from the line only for a task with (position, velocity) pairs (the glider).
    others = ["line", "goal"] + (["kinematic"] if task.profile.solver.kinematic_pairs else [])
    for r in results:
        alt_values = []
        for g in others:
            att = opt._attempt("ipopt", g, r.x_init, r.tau)
            if att.sol.success:
                alt_values.append(att.sol.objective)
        if alt_values:
            checked += 1
            rel = [abs(v - r.value) / max(abs(r.value), 1e-9) for v in alt_values]
            differ += int(max(rel) > 1e-4)
            best = min(alt_values)
            if best < r.value * (1 - 1e-4):
                better += 1
                gaps.append((r.value - best) / r.value)
        d = rng.uniform(-1e-3, 1e-3, task.nx) * width
        near = opt.solve(r.x_init + d, r.tau)
        if near.success:
            pred = r.value + float(r.grad_x @ d)
            jumps += int(abs(near.value - pred) > 1e-3 * max(abs(r.value), 1e-9))
    n = max(checked, 1)
    return {
        "n": len(results),
        "guess_disagreement": round(differ / n, 4),
        "another_guess_better": round(better / n, 4),
        "median_gap_when_better": round(float(np.median(gaps)), 4) if gaps else 0.0,
        "neighbour_jumps": round(jumps / max(len(results), 1), 4),
    }


def _busy(n: int) -> int:
    total = 0
    for i in range(n):
        total += i * i % 7
    return total


def machine_speedup(workers: int, n_tasks: int = 8, size: int = 3_000_000) -> float:
    """The machine's own speed-up on a pure-Python CPU loop (same pool type): the ceiling other jobs leave us."""
    from joblib.externals.loky import get_reusable_executor

    pool = get_reusable_executor(max_workers=workers, timeout=300)
    list(pool.map(_busy, [1000] * workers))
    t0 = time.perf_counter()
    for _ in range(n_tasks):
        _busy(size)
    t1 = time.perf_counter()
    list(pool.map(_busy, [size] * n_tasks))
    t2 = time.perf_counter()
    return round((t1 - t0) / (t2 - t1), 2)


def bench_parallel(n: int, workers: int, seed: int) -> dict[str, Any]:
    task = make_task("acrobot")
    starts = task.sample_x0(np.random.default_rng(seed + 7), n)
    warm = task.sample_x0(np.random.default_rng(seed + 8), 4 * workers)
    # Start the pool and build the solvers (every worker, and this process for workers=1) outside the timing.
    solve_many("acrobot", warm, workers=workers, progress=False)
    solve_many("acrobot", warm[:1], workers=1, progress=False)
    t0 = time.perf_counter()
    serial = solve_many("acrobot", starts, workers=1, progress=False)
    t_serial = time.perf_counter() - t0
    t0 = time.perf_counter()
    par = solve_many("acrobot", starts, workers=workers, progress=False)
    t_par = time.perf_counter() - t0
    same = all(np.array_equal(a.states, b.states) for a, b in zip(serial, par, strict=True))
    return {
        "n": n,
        "workers": workers,
        "machine_reference_speedup": machine_speedup(workers),
        "serial_s": round(t_serial, 2),
        "parallel_s": round(t_par, 2),
        "speedup": round(t_serial / t_par, 2),
        "identical": bool(same),
    }


def _tiny_chunk_overhead_ms(backend: str, workers: int, starts: np.ndarray, reps: int = 20) -> dict[str, float]:
    """Round trips of one-start chunks to one warm worker, one at a time: ``wall - solve_time`` is what a chunk costs
    beyond its solve (submission, pickling both ways, scheduling); ``noop_ms`` is a round trip that solves nothing."""
    from seagul_learn import parallel

    frozen = parallel._freeze({})
    taus = np.full(len(starts), make_task("acrobot").tau_nominal)
    if backend == "local":
        pool = parallel._local_pool(workers)

        def call(i: int) -> list[SolveResult]:
            return pool.submit(parallel._solve_chunk, "acrobot", frozen, starts[i : i + 1], taus[i : i + 1]).result()

        def noop() -> Any:
            return pool.submit(os.getpid).result()
    else:
        import ray

        actor = parallel._ray_actors(ray, workers)[0]

        def call(i: int) -> list[SolveResult]:
            return ray.get(actor.solve_chunk.remote("acrobot", frozen, starts[i : i + 1], taus[i : i + 1]))

        def noop() -> Any:
            return ray.get(actor.pid.remote())

    over, noops = [], []
    for i in range(reps):
        t0 = time.perf_counter()
        (res,) = call(i % len(starts))
        over.append(time.perf_counter() - t0 - res.solve_time)
        t0 = time.perf_counter()
        noop()
        noops.append(time.perf_counter() - t0)
    return {"chunk_ms": round(float(np.median(over)) * 1e3, 2), "noop_ms": round(float(np.median(noops)) * 1e3, 2)}


def bench_parallel_backends(n: int, workers: int, seed: int, repeats: int, with_ray: bool = True) -> dict[str, Any]:
    """``solve_many`` wall time for (local, ray) x (1, ``workers``) workers, each configuration warmed first."""
    from seagul_learn.parallel import _chunks

    task = make_task("acrobot")
    starts = task.sample_x0(np.random.default_rng(seed + 7), n)
    warm = task.sample_x0(np.random.default_rng(seed + 8), 4 * workers)
    load_start = [round(v, 2) for v in os.getloadavg()]
    backends = ["local", "ray"] if with_ray else ["local"]
    configs = [(b, w) for b in backends for w in (1, workers)]
    setup_s: dict[str, float] = {}
    for b, w in configs:  # pools started, every worker's solver built; Ray's second call onwards is what is timed
        t0 = time.perf_counter()
        solve_many("acrobot", warm, workers=w, backend=b, progress=False)
        setup_s[f"{b}_w{w}"] = round(time.perf_counter() - t0, 2)
    walls: dict[tuple[str, int], list[float]] = {c: [] for c in configs}
    solve_sums: dict[tuple[str, int], list[float]] = {c: [] for c in configs}
    reference: list[SolveResult] | None = None
    identical = True
    for _ in range(repeats):
        for b, w in configs:  # interleaved, so a change in the other jobs' load hits every configuration alike
            t0 = time.perf_counter()
            res = solve_many("acrobot", starts, workers=w, backend=b, progress=False)
            walls[(b, w)].append(time.perf_counter() - t0)
            solve_sums[(b, w)].append(sum(r.solve_time for r in res))
            if reference is None:
                reference = res
            else:
                identical &= all(
                    np.array_equal(x.states, y.states) and x.value == y.value
                    for x, y in zip(reference, res, strict=True)
                )
    out: dict[str, Any] = {"n": n, "workers": workers, "repeats": repeats}
    for b, w in configs:
        wall = float(np.median(walls[(b, w)]))
        solve = float(np.median(solve_sums[(b, w)]))
        in_process = b == "local" and w == 1
        chunks = n if in_process else len(_chunks(n, w, None))
        out[f"{b}_w{w}"] = {
            "wall_s": round(wall, 3),
            "walls_s": [round(v, 3) for v in walls[(b, w)]],
            "sum_solve_s": round(solve, 3),
            "chunks": chunks,
            # worker time not spent inside a solve, per chunk (in-process: per solve); includes end-of-batch idling
            "overhead_per_chunk_ms": round((w * wall - solve) / chunks * 1e3, 2),
        }
    for b in backends:
        out[f"{b}_speedup"] = round(out[f"{b}_w1"]["wall_s"] / out[f"{b}_w{workers}"]["wall_s"], 2)
    if with_ray:
        out["ray_vs_local_serial_speedup"] = round(out["local_w1"]["wall_s"] / out[f"ray_w{workers}"]["wall_s"], 2)
    out["tiny_chunk_overhead_ms"] = {b: _tiny_chunk_overhead_ms(b, workers, warm) for b in backends}
    out["first_call_setup_s"] = setup_s
    out["identical"] = bool(identical)
    out["machine_reference_speedup"] = machine_speedup(workers)
    out["cpu_count"] = os.cpu_count()
    out["load_avg_start"] = load_start
    out["load_avg_end"] = [round(v, 2) for v in os.getloadavg()]
    out["machine"] = machine()
    out["command"] = (
        f"python benchmarks/bench_trajopt.py --parallel-only --n {n} --workers {workers} --repeats {repeats}"
    )
    if with_ray:
        from seagul_learn.parallel import shutdown_ray_pool

        shutdown_ray_pool()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer draws (under ~3 minutes)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--parallel-only", action="store_true", help="only the speed-up measurement (local and Ray)")
    parser.add_argument("--n", type=int, default=200, help="--parallel-only: acrobot starts per batch")
    parser.add_argument("--repeats", type=int, default=3, help="--parallel-only: timed repeats per configuration")
    parser.add_argument("--no-ray", action="store_true", help="--parallel-only: the local backend only")
    args = parser.parse_args()
    if args.parallel_only:
        print(json.dumps(bench_parallel_backends(args.n, args.workers, args.seed, args.repeats, not args.no_ray)))
        return
    n_acro, n_glider, n_par = (200, 50, 96) if args.quick else (1000, 250, 400)
    n_acc, n_cons = (10, 30) if args.quick else (50, 100)
    report: dict[str, Any] = {"machine": machine()}
    t0 = time.perf_counter()
    for name, n in (("acrobot", n_acro), ("glider", n_glider)):
        report[name] = bench_task(name, n, args.seed, n_acc, n_cons if name == "acrobot" else n_cons // 3)
        print(f"{name}: {json.dumps(report[name])}", flush=True)
    par = bench_parallel(n_par, args.workers, args.seed)
    print(f"parallel: {json.dumps(par)}", flush=True)
    report["parallel"] = par
    report["parallel_speedup"] = par["speedup"]
    report["machine"]["load_avg_end"] = [round(v, 2) for v in os.getloadavg()]
    report["total_s"] = round(time.perf_counter() - t0, 1)
    report["command"] = "python benchmarks/bench_trajopt.py" + (" --quick" if args.quick else "")
    print(json.dumps(report))


if __name__ == "__main__":
    main()
