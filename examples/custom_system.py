"""Your own system, end to end: a cart-pole swing-up with seagul's public API only (docs/tutorials/custom-system.md).

Run (from the repository root)::

    .venv/bin/python examples/custom_system.py            # ~6 minutes on 2 busy cores, all interpreted
    .venv/bin/python examples/custom_system.py --test     # under a minute of work, for CI
    seagul evaluate --task examples.custom_system:make_cartpole --network <out>/train/network.pt \\
        --lqr --no-jit --workers 2 --out <dir>

Top to bottom: (1) the task (CasADi dynamics and costs, bounds, X0, and a profile: validation set, success rule,
MPC horizon, evaluation grid) and Gymnasium's env checker on ``make_env(task)``, (2) one trajectory optimization,
(3) ``solve_many`` with 1 and 2 local workers and with Ray (skipped if ray is not installed): identical results,
(4) a short SEAGuL training run on the Task object, (5) the learned value function as terminal cost of a 10-step MPC
in a Gymnasium loop, (6) ``seagul evaluate`` of the learned MPC next to clipped LQR, the MPC with the task's own
quadratic terminal cost and the full-horizon MPC over the profile's start grid (the same code path as the command
line, called in-process).

**The system** (every number in :class:`CartPoleParams`, SI units). A cart of 1 kg on a horizontal track with a
pole of 0.1 kg, a uniform rod of half-length 0.5 m (length 1 m, centre of mass at its middle, inertia about it
``m (2 l)^2 / 12``) on a frictionless hinge; a horizontal force ``|F| <= 10 N`` on the cart; the cart must stay within
``|x| <= 1.5 m`` (leaving the track ends an episode). State ``[x, th, dx, dth]`` with ``th = 0`` hanging down and
``th = pi`` upright (angles are not wrapped: the goal is ``+pi``). Lagrange's equations of the cart and rod::

    (M + m) ddx + m l cos(th) ddth - m l sin(th) dth^2 = F
    m l cos(th) ddx + (4/3) m l^2 ddth + m g l sin(th) = 0

**The task.** Swing up from hanging down and balance: running cost ``(x - x*)' diag(1, 1, 0.1, 0.1) (x - x*) +
0.01 F^2``, terminal cost the DARE cost-to-go of the transcription's own discretisation at the upright goal (as the
acrobot's), ``tau = 3 s`` in 60 fixed steps of 0.05 s (2 RK4 substeps each), control period 0.05 s. X0: cart within
0.5 m of the centre, pole within 0.3 rad of hanging down, both rates within 0.5 (m/s, rad/s). **Success** (the
profile's rule): at the end of the 3 s episode ``|th - pi| < 0.1 rad`` and ``|dth| < 0.5 rad/s`` with the cart still
on the track. The example prints what it measured; the numbers are whatever this run gives, nothing is tuned to them.

**Measured** (the full run ``python examples/custom_system.py`` on a 2-core machine shared with three other jobs,
~20 min; every solver interpreted): one solve 0.15 s; 8 solves identical with 1 worker, 2 workers and 2
Ray actors. Training with the closed-loop sampler (the acrobot benchmark's recipe scaled down, see ``Config``): 500
uniform solves, then 10 rounds of 50 tail problems at the MPC's planned terminal states (2 rounds collected with the
``"lqr"``-guarded MPC, then 8 with the unguarded MPC on a refit of the buffer), a 3-member refit ensemble at the
end: 1,000 solves (170 failed tail solves, kept out of the regression) in 879 s, validation ``mse_initial`` 0.16 and
``mse_all_knots`` 0.011 (values 12-16). On the 5 x 5 grid of (x, th) starts at rest, the **learned 10-step MPC with
the default "lqr" guard succeeds from 25/25** (mean cost 15.1, 16 of 1,500 steps fell back); the **full-horizon
MPC from 25/25** (mean cost 13.99, the optimum); the MPC with the task's quadratic terminal cost alone and clipped
LQR from 0/25. Unguarded, a network of the same recipe (a separate run of it) succeeds from 1/25 (mean cost 43;
3/25 with a 20-step lookahead; 25/25 with the guard): the guard's ``l_f`` term holds the planner where the network
is thin. Trained with the adversarial sampler instead (100 solves, one network, validation ``mse_initial`` 0.24),
the learned MPC succeeded from 0/25 with either guard.
"""

from __future__ import annotations

import argparse
import tempfile
import time
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import casadi as ca
import numpy as np
import scipy.linalg
from gymnasium.utils.env_checker import check_env

from seagul_control import LimitedLookaheadMPC
from seagul_control.mpc import MPCOptions
from seagul_envs import (
    EvaluationGrid,
    MPCDefaults,
    SuccessRule,
    Task,
    TaskProfile,
    ValidationSpec,
    make_env,
    rk4_map,
)
from seagul_learn import (
    LossConfig,
    NetworkConfig,
    RefitConfig,
    RuntimeConfig,
    ScheduleConfig,
    TrainConfig,
    TrajectoryOptimizer,
    solve_many,
    train,
)
from seagul_learn.closed_loop import ClosedLoopOptions
from seagul_learn.parallel import shutdown_ray_pool


@dataclass(frozen=True)
class CartPoleParams:
    """Every number of the cart-pole task (SI units)."""

    cart_mass: float = 1.0
    """Cart mass M (kg)."""
    pole_mass: float = 0.1
    """Pole mass m (kg), a uniform rod."""
    half_length: float = 0.5
    """Hinge to the pole's centre of mass l (m); the pole is 2 l = 1 m long."""
    g: float = 9.81
    """Gravity (m/s^2)."""
    force_max: float = 10.0
    """Force limit on the cart |F| (N)."""
    track: float = 1.5
    """Half-length of the track: |x| <= track (m); leaving it ends an episode."""
    Q: tuple[float, float, float, float] = (1.0, 1.0, 0.1, 0.1)
    """Diagonal of the running state weight on (x, th, dx, dth) - goal."""
    R: float = 0.01
    """Running weight of F^2."""
    tau: float = 3.0
    """Time to go of the full-horizon problem (s)."""
    horizon_steps: int = 60
    """Transcription intervals (0.05 s each)."""
    rk4_substeps: int = 2
    """RK4 substeps per interval."""
    control_period: float = 0.05
    """Control period of the env and the MPC (s)."""
    x0_half_width: tuple[float, float, float, float] = (0.5, 0.3, 0.5, 0.5)
    """X0 = [0, 0, 0, 0] +- this box (m, rad, m/s, rad/s): hanging down."""
    mpc_horizon: int = 10
    """Steps of the limited-lookahead MPC (0.5 s)."""
    validation_grid: int = 5
    """Validation set: points per axis of the (x, th) grid ..."""
    validation_draws: int = 25
    """... plus this many uniform draws from X0."""
    success_angle: float = 0.1
    """Success: |th(T) - pi| below this (rad) ..."""
    success_rate: float = 0.5
    """... and |dth(T)| below this (rad/s), cart on the track."""


def make_cartpole(params: CartPoleParams | None = None) -> Task:
    """The cart-pole swing-up :class:`Task` (module docstring); ``--task examples.custom_system:make_cartpole``."""
    p = params or CartPoleParams()
    x = ca.SX.sym("x", 4)
    u = ca.SX.sym("u", 1)
    th, dx, dth = x[1], x[2], x[3]
    M, m, l = p.cart_mass, p.pole_mass, p.half_length
    # The 2x2 mass matrix solve written out (det > 0 for any angle), so the expression stays small SX.
    a11, a12, a22 = M + m, m * l * ca.cos(th), 4.0 / 3.0 * m * l**2
    r1 = u[0] + m * l * ca.sin(th) * dth**2
    r2 = -m * p.g * l * ca.sin(th)
    det = a11 * a22 - a12**2
    ddx = (a22 * r1 - a12 * r2) / det
    ddth = (a11 * r2 - a12 * r1) / det
    dynamics = ca.Function("cartpole_f", [x, u], [ca.vertcat(dx, dth, ddx, ddth)], ["x", "u"], ["xdot"])

    goal = np.array([0.0, np.pi, 0.0, 0.0])
    Q, R = np.diag(p.Q), np.array([[p.R]])
    err = x - goal
    stage_cost = ca.Function("cartpole_l", [x, u], [ca.bilin(Q, err, err) + p.R * u[0] ** 2], ["x", "u"], ["l"])
    h = p.tau / p.horizon_steps
    # Terminal cost: the DARE cost-to-go of one transcription interval (RK4, stage weights h Q, h R) at the goal.
    step = rk4_map(dynamics, 4, 1, p.rk4_substeps)
    xs, us = ca.SX.sym("xs", 4), ca.SX.sym("us", 1)
    x_next = step(xs, us, h)
    jac = ca.Function("cartpole_jac", [xs, us], [ca.jacobian(x_next, xs), ca.jacobian(x_next, us)])
    A, B = (np.asarray(a) for a in jac(goal, np.zeros(1)))
    P = scipy.linalg.solve_discrete_are(A, B, h * Q, h * R)
    Qf = 0.5 * (P + P.T)
    terminal_cost = ca.Function("cartpole_lf", [x], [ca.bilin(Qf, err, err)], ["x"], ["lf"])

    inf = np.inf
    half = np.array(p.x0_half_width)
    profile = TaskProfile(
        validation=ValidationSpec(grid_coords=(0, 1), grid_points=p.validation_grid, num_random=p.validation_draws),
        success=SuccessRule(
            distance=None,
            per_coordinate=((1, "<", p.success_angle), (3, "<", p.success_rate)),
            fail_on_termination=True,
        ),
        success_goal="swing up and balance the pole",
        mpc=MPCDefaults(horizon=p.mpc_horizon),
        # Heat maps over the cart position and the pole angle, at rest.
        grid=EvaluationGrid(coords=(0, 1), fixed=((2, 0.0), (3, 0.0)), points=5),
    )
    return Task(
        name="cartpole",
        state_names=("x", "th", "dx", "dth"),
        control_names=("force",),
        dynamics=dynamics,
        stage_cost=stage_cost,
        terminal_cost=terminal_cost,
        goal=goal,
        u_low=np.array([-p.force_max]),
        u_high=np.array([p.force_max]),
        x_low=np.array([-p.track, -inf, -inf, -inf]),
        x_high=np.array([p.track, inf, inf, inf]),
        x_final_low=np.full(4, -inf),
        x_final_high=np.full(4, inf),
        x0_low=-half,
        x0_high=half,
        tau_range=(p.tau, p.tau),
        tau_nominal=p.tau,
        num_steps=p.horizon_steps,
        step_bounds=(h, h),
        fixed_step=True,
        rk4_substeps=p.rk4_substeps,
        control_period=p.control_period,
        params=p,
        extras={"Q": Q, "R": R, "Qf": Qf},  # the LQR reference's weights (the profile's defaults read them)
        profile=profile,
    )


@dataclass
class Config:
    """What this example spends (CleanRL style)."""

    parallel_solves: int = 8
    """Starts solved by solve_many with 1 and 2 workers and with Ray."""
    budget: int = 1000
    """Solves of the training run (after 10 pretraining solves)."""
    uniform_solves: int = 500
    """Of the budget: uniform draws from X0 before the closed-loop rounds."""
    solves_per_round: int = 50
    """Solves per training round."""
    train_steps_per_round: int = 1000
    """Adam steps after each round."""
    sobolev_weight: float = 1.0
    """Weight of the dual-gradient (Sobolev) term."""
    hidden: tuple[int, ...] = (64, 64)
    """Hidden widths of the value network."""
    cl_episodes: int = 10
    """Closed-loop episodes from X0 per round (the planner's queries are the round's candidates)."""
    refit_steps: int = 10000
    """Adam steps of each refit of the buffer (the DAgger rounds' collectors and the final network)."""
    refit_ensemble: int = 3
    """Members of the final refit (deployed as their mean)."""
    grid: int = 5
    """Points per axis of the closed-loop grid of seagul evaluate."""
    ray: bool = True
    """Also solve on Ray (skipped with a message if ray is not installed)."""
    full_horizon: bool = True
    """Also evaluate the full-horizon MPC (the reference) on the grid."""
    workers: int = 2
    """Local worker processes."""
    out: str = ""
    """Output directory (default: a temporary one)."""
    params: CartPoleParams = CartPoleParams()
    """The task's parameters."""


def main(cfg: Config) -> None:
    """Run the example (see the module docstring)."""
    task = make_cartpole(cfg.params)
    out = Path(cfg.out or tempfile.mkdtemp(prefix="seagul-cartpole-"))
    solver_options = {"codegen": False}  # interpreted solvers: no C compilation anywhere in this example

    # 1. The env: observation = state + time to go, reward = minus the running cost; Gymnasium's checker. The action
    #    box is in newtons (the built-in envs' choice, docs/reference/spec.md §13), so its one recommendation is
    #    silenced.
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*symmetric and normalized space.*")
        check_env(make_env(task).unwrapped)
    print(f"task {task.name} (fingerprint {task.fingerprint()}): make_env(task) passes gymnasium's check_env")

    # 2. One solve of the full-horizon problem from a start near hanging down.
    optimizer = TrajectoryOptimizer(task, **solver_options)
    x0 = task.sample_x0(np.random.default_rng(0))
    start = time.perf_counter()
    result = optimizer.solve(x0)
    print(
        f"V(x0, {result.tau:g} s) = {result.value:.3f} ({result.status}, {result.iterations} iterations, "
        f"{time.perf_counter() - start:.2f} s); at the end th = {result.states[-1, 1]:.3f} rad"
    )

    # 3. solve_many: the Task object is pickled to the workers; results do not depend on where they ran.
    starts = task.sample_x0(np.random.default_rng(1), cfg.parallel_solves)
    runs = {}
    for label, kwargs in (("1 worker", {"workers": 1}), (f"{cfg.workers} workers", {"workers": cfg.workers})):
        start = time.perf_counter()
        runs[label] = solve_many(task, starts, progress=False, solver_options=solver_options, **kwargs)
        print(f"solve_many, {label}: {len(starts)} solves in {time.perf_counter() - start:.1f} s")
    if cfg.ray:
        try:
            import ray
        except ImportError:
            print("ray is not installed: the Ray solve is skipped (pip install 'seagul[ray]')")
        else:
            start = time.perf_counter()
            started_here = not ray.is_initialized()  # solve_many starts a local Ray when none is running
            try:
                runs["ray"] = solve_many(
                    task, starts, workers=cfg.workers, backend="ray", progress=False, solver_options=solver_options
                )
            finally:
                shutdown_ray_pool()
                if started_here:
                    ray.shutdown()
            print(f"solve_many on Ray, {cfg.workers} actors: {time.perf_counter() - start:.1f} s (with Ray's start-up)")
    reference = runs["1 worker"]
    for label, results in runs.items():
        same = all(
            np.array_equal(a.states, b.states) and a.value == b.value for a, b in zip(reference, results, strict=True)
        )
        print(f"  {label}: {sum(r.success for r in results)}/{len(results)} solved, identical to 1 worker: {same}")

    # 4. SEAGuL training on the Task object (not a registered name); config.json stores its name and fingerprint.
    #    The closed-loop sampler (the recipe of the acrobot's closed-loop benchmark, scaled to this task): uniform
    #    draws first, then rounds at the planned terminal states of the MPC itself, collected with the "lqr"-guarded
    #    MPC for two rounds and then with the unguarded MPC on a refit of everything so far; the final network is a
    #    refit ensemble.
    config = TrainConfig(
        task=task,
        sampler=ClosedLoopOptions(
            uniform_solves=cfg.uniform_solves,
            episodes=cfg.cl_episodes,
            trust_region="none",
            warmup_rounds=2,
            collect_refit=True,
            selection="random",
            jit=False,
        ),
        budget=cfg.budget,
        schedule=ScheduleConfig(solves_per_round=cfg.solves_per_round, train_steps_per_round=cfg.train_steps_per_round),
        loss=LossConfig(sobolev_weight=cfg.sobolev_weight, renormalize=True, grad_label_max=10.0),
        network=NetworkConfig(hidden=cfg.hidden, pessimism=0.0),
        refit=RefitConfig(steps=cfg.refit_steps, ensemble=cfg.refit_ensemble),
        solver_options=solver_options,
        runtime=RuntimeConfig(workers=cfg.workers, cache_dir=str(out / "cache"), progress=False),
    )
    start = time.perf_counter()
    trained = train(config, out / "train")
    last = trained.metrics[-1]
    print(
        f"trained on {trained.num_solves} solves ({trained.num_failures} failed) in "
        f"{time.perf_counter() - start:.0f} s: validation mse_initial {last.mse_initial:.3g}, "
        f"mse_all_knots {last.mse_all_knots:.3g}"
    )

    # 5. The network as terminal cost of a limited-lookahead MPC with the library's default guard (trust_region
    #    "lqr": Vhat + l_f), in a plain Gymnasium loop from hanging at rest.
    horizon = task.profile.default_horizon(task)
    policy = LimitedLookaheadMPC(task, trained.network, horizon, MPCOptions(jit=False))
    start = time.perf_counter()
    env = make_env(task)
    obs, info = env.reset(options={"state": np.zeros(4)})
    done, episode_return = False, 0.0
    while not done:
        action, _ = policy.predict(obs, deterministic=True)
        obs, reward, terminated, truncated, info = env.step(action)
        episode_return += float(reward)
        done = terminated or truncated
    x_end = info["state"]
    fallbacks = sum(s.source != "solver" for s in policy.stats)
    print(
        f"learned {horizon}-step MPC (lqr guard) from hanging at rest: return {episode_return:.2f}, final state "
        f"{np.round(x_end, 3).tolist()}, success {task.profile.is_success(task, x_end, terminated)}, {fallbacks} "
        f"of {len(policy.stats)} steps fell back (no converged solve), {time.perf_counter() - start:.0f} s"
    )

    # 6. `seagul evaluate --task examples.custom_system:make_cartpole ...`, in-process: the learned MPC (with the
    #    library's default "lqr" guard), the MPC with the task's own terminal cost, clipped LQR and the full-horizon
    #    MPC over the profile's (x, th) grid at rest.
    from seagul_learn.cli import main as seagul

    argv = [
        "evaluate",
        "--task",
        f"{Path(__file__).resolve()}:make_cartpole",  # the file form of examples.custom_system:make_cartpole
        "--network",
        str(out / "train" / "network.pt"),
        "--label",
        f"learned {horizon}-step MPC",
        "--task-terminal",
        "--lqr",
        "--no-jit",
        "--grid",
        str(cfg.grid),
        "--workers",
        str(cfg.workers),
        "--no-progress",
        "--out",
        str(out / "evaluate"),
    ] + (["--full-horizon"] if cfg.full_horizon else [])
    print("seagul " + " ".join(argv))
    if seagul(argv) != 0:
        raise SystemExit("seagul evaluate failed")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--test", action="store_true", help="shrink everything to under a minute (CI)")
    parser.add_argument("--out", default="", help="output directory (default: a temporary one)")
    parser.add_argument("--no-ray", action="store_true", help="skip the Ray solve")
    args = parser.parse_args()
    cfg = Config(out=args.out, ray=not args.no_ray)
    if args.test:
        small = replace(cfg.params, validation_grid=2, validation_draws=0)
        cfg = replace(
            cfg,
            parallel_solves=2,
            budget=6,
            uniform_solves=2,
            solves_per_round=2,
            train_steps_per_round=20,
            hidden=(16,),
            cl_episodes=1,
            refit_steps=20,
            refit_ensemble=2,
            grid=1,
            full_horizon=False,
            params=small,
        )
    main(cfg)
