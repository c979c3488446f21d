"""Steps per second of the seagul envs and of Gymnasium's ``Acrobot-v1``, measured side by side in one run.

Usage::

    .venv/bin/python benchmarks/bench_envs.py            # ~1 min
    .venv/bin/python benchmarks/bench_envs.py --quick    # a few seconds (smoke test)

Every env runs ``--steps`` steps per repetition (pre-drawn random actions, resetting at episode ends, resets
included in the time), in an interleaved order (A B C D, A B C D, ...) so that load from other processes hits all of
them alike; the medians over ``--reps`` repetitions are reported, for the raw env (``env.unwrapped.step``) and for
the ``gym.make`` stack (``PassiveEnvChecker``/``OrderEnforcing``/``TimeLimit``: every registered id declares
``max_episode_steps``).

It also measures what each acrobot's step integrates: the largest error of one control step against a
``solve_ivp`` (DOP853, rtol = atol = 1e-12) reference of the *same* model, from X0-like states. ``Acrobot-v1`` does
one RK4 step of 0.2 s; ours RK4 substeps of <= 5 ms over 0.1 s.

The last line of output is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import casadi
import gymnasium as gym
import numpy as np
from gymnasium.envs.classic_control import acrobot as gym_acrobot
from scipy.integrate import solve_ivp

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import seagul_envs  # noqa: E402
from benchmarks._common import machine  # noqa: E402
from seagul_envs import make_task  # noqa: E402

ENVS = ["Acrobot-v1", *seagul_envs.ENV_IDS]
BASELINE = "Acrobot-v1"


def make_runner(env_id: str, wrapped: bool, steps: int, seed: int) -> Callable[[], float]:
    """A closure that runs ``steps`` steps and returns the elapsed seconds."""
    env = gym.make(env_id)
    target = env if wrapped else env.unwrapped
    rng = np.random.default_rng(seed)
    if isinstance(env.action_space, gym.spaces.Discrete):
        actions = [int(a) for a in rng.integers(0, env.action_space.n, steps)]
    else:
        high = env.action_space.high
        actions = [(rng.uniform(-1, 1, high.shape) * high).astype(np.float32) for _ in range(steps)]
    target.reset(seed=seed)

    def run() -> float:
        step, reset = target.step, target.reset
        start = time.perf_counter()
        for a in actions:
            _, _, terminated, truncated, _ = step(a)
            if terminated or truncated:
                reset()
        return time.perf_counter() - start

    run()  # warm-up: builds kernels, first-step checks
    return run


def speed(reps: int, steps: int) -> dict[str, dict[str, float]]:
    runners = {(e, w): make_runner(e, w, steps, seed=i) for i, e in enumerate(ENVS) for w in (False, True)}
    times: dict[tuple[str, bool], list[float]] = {key: [] for key in runners}
    for _ in range(reps):
        for key, run in runners.items():  # interleaved: every env once per repetition
            times[key].append(run())
    out: dict[str, dict[str, float]] = {}
    for env_id in ENVS:
        raw = statistics.median(times[(env_id, False)])
        made = statistics.median(times[(env_id, True)])
        out[env_id] = {
            "steps_per_s": steps / raw,
            "us_per_step": 1e6 * raw / steps,
            "steps_per_s_make": steps / made,
            "us_per_step_make": 1e6 * made / steps,
        }
    for env_id in ENVS:
        out[env_id]["ratio_to_acrobot_v1"] = out[env_id]["steps_per_s"] / out[BASELINE]["steps_per_s"]
        out[env_id]["ratio_to_acrobot_v1_make"] = out[env_id]["steps_per_s_make"] / out[BASELINE]["steps_per_s_make"]
    return out


def accuracy(samples: int, seed: int = 0) -> dict[str, float]:
    """Max abs error of one control step vs a tight reference of the same model (X0-like states, random input)."""
    rng = np.random.default_rng(seed)
    # Acrobot-v1: its own model (_dsdt) and its own integrator (one RK4 step over dt = 0.2 s), before wrapping.
    v1 = gym.make(BASELINE).unwrapped
    err_v1 = 0.0
    for _ in range(samples):
        s = np.concatenate([rng.uniform(-0.1, 0.1, 4), [float(rng.choice(v1.AVAIL_TORQUE))]])
        ours = gym_acrobot.rk4(v1._dsdt, s, [0, v1.dt])[:4]
        ref = solve_ivp(lambda _t, y: np.asarray(v1._dsdt(y)), (0, v1.dt), s, "DOP853", rtol=1e-12, atol=1e-12)
        err_v1 = max(err_v1, float(np.abs(ours - ref.y[:4, -1]).max()))
    # SeagulAcrobot-v0: the env's step against the Task's dynamics integrated tightly.
    task = make_task("acrobot")
    env = gym.make("SeagulAcrobot-v0").unwrapped
    err_ours = 0.0
    for _ in range(samples):
        x0 = task.sample_x0(rng)
        u = float(rng.uniform(-20, 20))
        env.reset(options={"state": x0})
        x1 = env.step(np.array([u]))[4]["state"]
        f = lambda _t, x, u=u: np.asarray(task.dynamics(x, u)).ravel()  # noqa: E731
        ref = solve_ivp(f, (0, env.dt), x0, "DOP853", rtol=1e-12, atol=1e-12)
        err_ours = max(err_ours, float(np.abs(x1 - ref.y[:, -1]).max()))
    return {
        "Acrobot-v1_step_error": err_v1,
        "Acrobot-v1_dt": float(v1.dt),
        "SeagulAcrobot-v0_step_error": err_ours,
        "SeagulAcrobot-v0_dt": float(env.dt),
        "SeagulAcrobot-v0_max_substep": float(env.max_substep),
    }


def kernel_choices(n: int) -> dict[str, float]:
    """Microseconds per evaluation of the acrobot's one-period kernel ``(x, u) -> (x_next, l)``, three ways.

    ``call``: ``Function.__call__`` (DM conversions); ``buffer``: the FunctionBuffer the env uses; ``compiled``:
    the same Function generated to C, built with the system C compiler (``cc -O2``) and loaded with
    ``casadi.external``, through a FunctionBuffer (measured only if a compiler is found; not used by the env).
    """
    import os
    import shutil
    import subprocess
    import tempfile

    from seagul_envs.envs.base import BufferedFunction, step_function

    task = make_task("acrobot")
    f = step_function(task, task.control_period)
    x, u = task.goal + 0.1, np.array([1.0])

    def per_call(fn: Callable[[], Any]) -> float:
        fn()
        best = float("inf")
        for _ in range(5):
            start = time.perf_counter()
            for _ in range(n):
                fn()
            best = min(best, (time.perf_counter() - start) / n)
        return 1e6 * best

    out = {"call": per_call(lambda: f(x, u))}
    buffered = BufferedFunction(f)
    buffered.args[0][:], buffered.args[1][:] = x, u
    out["buffer"] = per_call(buffered)
    compiler = shutil.which("cc") or shutil.which("gcc")
    if compiler:
        with tempfile.TemporaryDirectory() as tmp:
            cwd = os.getcwd()
            os.chdir(tmp)  # Function.generate writes into the working directory
            try:
                f.generate("kernel.c")
                start = time.perf_counter()
                subprocess.run([compiler, "-O2", "-shared", "-fPIC", "kernel.c", "-o", "kernel.so"], check=True)
                out["compile_s"] = time.perf_counter() - start
                compiled = BufferedFunction(casadi.external(f.name(), os.path.join(tmp, "kernel.so")))
            finally:
                os.chdir(cwd)
            compiled.args[0][:], compiled.args[1][:] = x, u
            out["compiled"] = per_call(compiled)
            buffered()
            out["compiled_max_diff"] = float(np.abs(compiled.res[0] - buffered.res[0]).max())
    return out


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--reps", type=int, default=15, help="interleaved repetitions (median reported)")
    parser.add_argument("--steps", type=int, default=2000, help="steps per env per repetition")
    parser.add_argument("--quick", action="store_true", help="3 repetitions of 300 steps")
    args = parser.parse_args(argv)
    reps, steps = (3, 300) if args.quick else (args.reps, args.steps)

    info = machine("mujoco", "gymnasium")
    print(f"machine: {info['cpu']} ({info['cores_available']} of {info['cores']} cores available), {info['platform']}")
    print("versions: " + ", ".join(f"{k} {info[k]}" for k in ("python", "numpy", "casadi", "mujoco", "gymnasium")))
    print(f"{reps} interleaved repetitions x {steps} steps per env; medians")
    results = speed(reps, steps)
    header = f"{'env':26s} {'steps/s':>10s} {'us/step':>8s} {'ratio':>6s} | {'make: steps/s':>13s} {'ratio':>6s}"
    print(header)
    print("-" * len(header))
    for env_id, r in results.items():
        print(
            f"{env_id:26s} {r['steps_per_s']:10.0f} {r['us_per_step']:8.1f} {r['ratio_to_acrobot_v1']:6.2f} | "
            f"{r['steps_per_s_make']:13.0f} {r['ratio_to_acrobot_v1_make']:6.2f}"
        )
    acc = accuracy(samples=5 if args.quick else 20)
    print(
        f"one control step vs a 1e-12 reference of the same model (X0-like states): "
        f"Acrobot-v1 (1 RK4 step of {acc['Acrobot-v1_dt']} s) {acc['Acrobot-v1_step_error']:.1e}; "
        f"SeagulAcrobot-v0 (RK4 substeps <= {acc['SeagulAcrobot-v0_max_substep'] * 1e3:g} ms over "
        f"{acc['SeagulAcrobot-v0_dt']} s) {acc['SeagulAcrobot-v0_step_error']:.1e}"
    )
    kernels = kernel_choices(n=500 if args.quick else 5000)
    print(
        "acrobot kernel (x, u) -> (x_next, l), us per evaluation: "
        + ", ".join(f"{k} {v:.3g}" for k, v in kernels.items() if k in ("call", "buffer", "compiled"))
        + ("" if "compiled" in kernels else " (no C compiler: compiled path not measured)")
        + (f"; C build {kernels['compile_s']:.2f} s" if "compile_s" in kernels else "")
    )
    ours = results["SeagulAcrobot-v0"]["ratio_to_acrobot_v1"]
    verdict = "meets" if ours >= 1.0 else "MISSES"
    print(f"goal (SeagulAcrobot-v0 at least as fast per step as Acrobot-v1): {verdict} ({ours:.2f}x)")
    summary = {
        "machine": info,
        "reps": reps,
        "steps": steps,
        "envs": results,
        "accuracy": acc,
        "kernel_us": kernels,
        "goal_met": ours >= 1,
    }
    print(json.dumps(summary, sort_keys=True))
    return summary


if __name__ == "__main__":
    main(sys.argv[1:])
