"""A learned value's short-horizon MPC in the DeepMind Control Suite, scored by dm_control's own reward.

This is what ``seagul evaluate --dmc DOMAIN-TASK --network PATH`` runs and what the suite benchmark
(``benchmarks/bench_dmc_learned.py``, ``benchmarks/bench_dmc.py``) reports: the network ``V(x, tau)`` of the suite's
CasADi task (:data:`seagul_control.dmc.DMC_TASKS`: ``dmc_pendulum``, ``dmc_cartpole``, ``dmc_acrobot``) as the
terminal cost of :class:`~seagul_control.mpc.LimitedLookaheadMPC` (paper Eq. 3),

    u_0..u_{N-1} = argmin  sum_{k<N} l(x_k, u_k) dt + Vhat(x_N, tau_V),

deployed in dm_control's own episodes (:func:`seagul_control.dmc.run_dmc_episode`: the suite's reset distribution,
its 1,000 steps, the sum of its rewards).

How it is deployed (:class:`DMCDeployment`):

* **time to go** [choice]: the suite's episode pays every step the same and has no end for the controller to plan
  for, while the network is the value of a finite problem (``tau <= tau_max``). The MPC is given a constant time to
  go ``tau_V + N dt``, so its terminal cost is always ``Vhat(x_N, tau_V)``: "the optimal cost of the next
  ``tau_V`` seconds after the lookahead", a stationary receding-horizon policy that never enters the MPC's end
  phase. ``time_to_go=None`` instead passes the episode's remaining time, capped at ``tau_max``
  (:class:`~seagul_control.dmc.PredictController`'s default).
* **decision period and lookahead interval**: each action is held for ``hold`` control steps (zero-order hold;
  ``hold=1`` decides at every step); the MPC's interval ``dt`` is ``hold`` times the suite's control period unless
  :attr:`DMCDeployment.dt` sets it. Both tasks decide at every control step over a lookahead of longer intervals:
  the cart-pole five 0.05 s intervals (the value's own discretisation; five 0.01 s intervals scored 841 against 860
  on the tuning seeds), the pendulum five 0.1 s intervals (its value's discretisation; 840 against 831 with 0.02 s
  intervals on the tuning seeds, for a network of the suite's own starts; its shipped networks, of starts over the
  whole swing, take ``tau_V = 3`` s).
* **path bounds** [choice]: :attr:`DMCDeployment.path_bounds` says what the lookahead does with the task's state
  path bounds (the cart-pole's rail ``|slider| <= 1.8``). ``"hard"`` keeps them as constraints (then the lookahead
  has state bounds and is solved by fatrop); ``"soft"`` replaces them by a penalty in the lookahead's stage cost,
  ``w (max(0, x_i - (hi_i - m))^2 + max(0, (lo_i + m) - x_i)^2)`` from a margin ``m`` inside each bound
  (:attr:`DMCDeployment.soft_bound_margin`, :attr:`DMCDeployment.soft_bound_weight`), so the condensed solver
  applies (input bounds only); ``"none"`` drops them. The cart-pole deploys ``"soft"``: on its tuning seeds 2.5 ms a
  step at the median and a mean score of 864, against 20 ms and 801 with ``"hard"``; on reset seed 0 the cart
  stays within 1.68 m, where with ``"none"`` it runs into the end of the rail (1.93 m), a soft stop of dm_control's
  physics that the task's model does not have (docs/experiments/dmc-learned.md).
* the observation the MPC receives is the exact float64 physics state ``[qpos, qvel]`` and the time to go.

:data:`DEFAULT_DEPLOYMENTS` holds the setting per env chosen on the tuning reset seeds (never the evaluation seeds
0-9; ``benchmarks/bench_dmc_learned.py tune``).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

__all__ = ["DEFAULT_DEPLOYMENTS", "DMCDeployment", "evaluate_network_dmc", "learned_dmc_controller", "lookahead_task"]


@dataclass(frozen=True)
class DMCDeployment:
    """How a learned MPC is deployed in one suite env (module docstring)."""

    horizon: int = 10
    """MPC lookahead N (intervals of ``hold`` control steps)."""
    time_to_go: float | None = 5.0
    """``tau_V`` (s): the value's time to go at the end of the lookahead, constant (``None``: the episode's
    remaining time capped at the task's ``tau_max``, given to the MPC as is)."""
    hold: int = 1
    """Control steps per MPC decision (each action is held that long)."""
    dt: float | None = None
    """The MPC's interval (s); None: ``hold`` times the suite's control period."""
    path_bounds: Literal["hard", "soft", "none"] = "hard"
    """The task's state path bounds in the lookahead: constraints, a penalty, or dropped (module docstring)."""
    soft_bound_margin: float = 0.3
    """``"soft"``: how far inside each bound the penalty starts (in the state's unit)."""
    soft_bound_weight: float = 2000.0
    """``"soft"``: the penalty's weight ``w`` (cost per squared unit of state, per second)."""

    def __post_init__(self) -> None:
        if not isinstance(self.horizon, int) or isinstance(self.horizon, bool) or self.horizon < 1:
            raise ValueError(f"DMCDeployment.horizon must be an integer >= 1, got {self.horizon!r}")
        if not isinstance(self.hold, int) or isinstance(self.hold, bool) or self.hold < 1:
            raise ValueError(f"DMCDeployment.hold must be an integer >= 1, got {self.hold!r}")
        if self.time_to_go is not None and not (math.isfinite(self.time_to_go) and self.time_to_go >= 0):
            raise ValueError(f"DMCDeployment.time_to_go must be a finite number >= 0 or None, got {self.time_to_go}")
        if self.dt is not None and not (math.isfinite(self.dt) and self.dt > 0):
            raise ValueError(f"DMCDeployment.dt must be a finite number > 0 or None, got {self.dt}")
        if self.path_bounds not in ("hard", "soft", "none"):
            raise ValueError(f"DMCDeployment.path_bounds must be 'hard', 'soft' or 'none', got {self.path_bounds!r}")
        for name in ("soft_bound_margin", "soft_bound_weight"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"DMCDeployment.{name} must be a finite number >= 0, got {value}")


#: The deployment per suite env (Gymnasium id), chosen on the tuning reset seeds; envs not listed use
#: ``DMCDeployment()``.
DEFAULT_DEPLOYMENTS: dict[str, DMCDeployment] = {
    "dm_control/pendulum-swingup-v0": DMCDeployment(horizon=5, time_to_go=3.0, hold=1, dt=0.1),
    "dm_control/cartpole-swingup-v0": DMCDeployment(horizon=5, time_to_go=2.0, hold=1, dt=0.05, path_bounds="soft"),
    "dm_control/cartpole-swingup_sparse-v0": DMCDeployment(
        horizon=5, time_to_go=2.0, hold=1, dt=0.05, path_bounds="soft"
    ),
}


def _deployment(env_id: str, deployment: DMCDeployment | None) -> DMCDeployment:
    return deployment if deployment is not None else DEFAULT_DEPLOYMENTS.get(env_id, DMCDeployment())


def lookahead_task(task: Any, setting: DMCDeployment) -> Any:
    """The task the lookahead plans on: ``task`` itself (``"hard"``), or without its state path bounds, which
    ``"soft"`` turns into a penalty in the stage cost (module docstring)."""
    if setting.path_bounds == "hard":
        return task
    free = replace(task, x_low=np.full(task.nx, -np.inf), x_high=np.full(task.nx, np.inf))
    if setting.path_bounds == "none":
        return free
    import casadi as ca

    x = ca.SX.sym("x", task.nx)
    u = ca.SX.sym("u", task.nu)
    penalty = ca.SX(0)
    m, w = setting.soft_bound_margin, setting.soft_bound_weight
    for i in range(task.nx):
        if np.isfinite(task.x_high[i]):
            penalty += w * ca.fmax(0, x[i] - (task.x_high[i] - m)) ** 2
        if np.isfinite(task.x_low[i]):
            penalty += w * ca.fmax(0, (task.x_low[i] + m) - x[i]) ** 2
    cost = ca.Function("stage_cost", [x, u], [task.stage_cost(x, u) + penalty])
    return replace(free, stage_cost=cost)


def learned_dmc_controller(
    env_id: str, network: Any, deployment: DMCDeployment | None = None, *, jit: bool = True
) -> Any:
    """The learned MPC of ``network`` (a :class:`~seagul_learn.value_network.ValueNetwork` or a file path) as a suite
    controller (:class:`~seagul_control.dmc.PredictController`) for ``env_id`` (a suite id or its short form).
    ``jit=False`` solves interpreted (no C compilation: slower steps, no build time).

    Raises ``ValueError`` when the network was trained on another task than the env's CasADi task.
    """
    from seagul_control.dmc import DMC_TASKS, PredictController, dmc_env_id
    from seagul_control.mpc import LimitedLookaheadMPC, MPCOptions
    from seagul_envs import make_task
    from seagul_learn.value_network import ValueNetwork

    full = dmc_env_id(env_id)
    setting = _deployment(full, deployment)
    task = make_task(DMC_TASKS[full])
    if isinstance(network, (str, Path)):
        network = ValueNetwork.load(network)
    trained_on = getattr(network, "task_name", None)
    if trained_on not in (None, "", task.name):
        raise ValueError(f"{full} is modelled by task {task.name!r}, but the network was trained on {trained_on!r}")
    task = lookahead_task(task, setting)
    dt = setting.dt if setting.dt is not None else setting.hold * task.control_period
    mpc = LimitedLookaheadMPC(task, network, horizon=setting.horizon, options=MPCOptions(dt=dt, jit=jit))
    tau = None if setting.time_to_go is None else setting.time_to_go + setting.horizon * dt
    return PredictController(mpc, time_to_go=tau, observation_dtype=np.float64)


def evaluate_network_dmc(
    env_id: str,
    network: Any,
    seeds: list[int],
    deployment: DMCDeployment | None = None,
    *,
    progress: bool = False,
    jit: bool = True,
) -> dict[str, Any]:
    """Score the learned MPC of ``network`` on the reset ``seeds`` of ``env_id`` (one episode each).

    Returns ``{"task", "score_mean", "score_std", "episodes", "median_ms", "p95_ms", "scores", "seeds",
    "horizon", "time_to_go", "hold", "dt", "path_bounds", "wall_s"}``: ``task`` the short env name
    (``"pendulum-swingup"``), the score dm_control's return, ``score_std`` the population standard deviation over
    the episodes, ``median_ms`` and ``p95_ms`` the medians over the episodes of each episode's decision-time median
    and 95th percentile.
    ``progress`` shows a bar over the episodes; ``jit`` as in :func:`learned_dmc_controller`.
    """
    from seagul_control.dmc import dmc_env_id, make_dmc_env, run_dmc_episode

    full = dmc_env_id(env_id)
    if not seeds:
        raise ValueError("evaluate_network_dmc: no reset seeds given")
    setting = _deployment(full, deployment)
    controller = learned_dmc_controller(full, network, setting, jit=jit)
    env = make_dmc_env(full)
    scores: list[float] = []
    medians: list[float] = []
    p95s: list[float] = []
    start = time.perf_counter()
    bar: Any = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(seeds), desc=full.removeprefix("dm_control/"), unit="episode")
    try:
        for seed in seeds:
            episode = run_dmc_episode(full, controller, int(seed), hold=setting.hold, env=env)
            scores.append(float(episode.score))
            medians.append(episode.decision_ms_median)
            p95s.append(episode.decision_ms_p95)
            if bar is not None:
                bar.set_postfix(score=f"{episode.score:.0f}")
                bar.update(1)
    finally:
        env.close()
        if bar is not None:
            bar.close()
    return {
        "task": full.removeprefix("dm_control/").removesuffix("-v0"),
        "score_mean": round(float(np.mean(scores)), 3),
        "score_std": round(float(np.std(scores)), 3),
        "episodes": len(scores),
        "median_ms": round(float(np.median(medians)), 4),
        "p95_ms": round(float(np.median(p95s)), 4),
        "scores": [round(s, 3) for s in scores],
        "seeds": [int(s) for s in seeds],
        "horizon": setting.horizon,
        "time_to_go": setting.time_to_go,
        "hold": setting.hold,
        "dt": setting.dt,
        "path_bounds": setting.path_bounds,
        "wall_s": round(time.perf_counter() - start, 1),
    }
