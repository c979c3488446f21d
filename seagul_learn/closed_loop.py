"""The closed-loop sampler: SEAGuL's idea applied to the distribution the controller actually queries.

A limited-lookahead MPC (paper Eq. 3) minimises ``sum_k h l(x_k, u_k) + Vhat(x_n, tau_n)``: its optimizer searches
for terminal states where ``Vhat`` is low, so it finds the network's *under-estimates* wherever they are, including
states that no uniform draw or validation set looks at. Validation accuracy then does not carry into control
(docs/experiments/closed-loop.md shows the measurements). This sampler spends each round's solves where the deployed
controller looks:

1. **Roll out the controller as deployed.** The current network drives a :class:`~seagul_control.LimitedLookaheadMPC`
   of the deployed class, horizon and guard (``trust_region``) in closed loop, in the task's Gymnasium env, from
   training starts drawn uniformly from X0 (a stream of their own, never the evaluation grid). During the first
   ``warmup_rounds`` rounds the collector is the ``"lqr"``-guarded MPC instead: a fresh network's unguarded queries
   go to states with values in the tens of thousands, which teach the regression little and swamp its loss
   ("collect with a safer controller first, then with the learned one").
2. **Collect the planner's queries**: every converged step whose terminal cost was the learned value contributes
   its planned terminal state and time to go ``(x_n, tau_n)``.
3. **Choose where the network is most likely wrong** among them (``selection``):

   * ``"farthest"`` (default): greedy k-center in the network's standardised ``(x, tau)`` coordinates against
     every input already in the training buffer: each pick is the query farthest from the data and from the
     picks before it, so the round covers the part of the lookahead's reachable set the data are thinnest on
     (where a smooth regressor extrapolates, and the planner exploits the extrapolation);
   * ``"spread"``: with a :class:`~seagul_learn.value_network.ValueEnsemble`, the queries where the members
     disagree most (farthest-first among equal spreads);
   * ``"lowest"``: the queries whose value is lowest relative to the nearest training label's value minus the
     network's — the planner's favourite under-estimates first (requires the buffer's labels);
   * ``"random"``: a uniform subsample (the control).

4. **Solve the tail problems** from the chosen queries: for a fixed-step task the tail of the full problem with
   ``round(tau_n / h)`` intervals of the same step (:func:`seagul_learn.solving.tail_horizon`; one optimizer per
   horizon, built once per process and kept). Each tail solve gives per-knot labels and dual gradients like any
   other solve (Sobolev training applies unchanged); a failed tail solve is stored with its status, counted and
   never trained on. Queries may be restricted to tails whose interval count is a multiple of ``tail_stride``
   (fewer distinct solvers to build; the knots of each tail still cover every shorter time to go).

**Over robots** (``TrainConfig.model_params``: a pool that holds one robot per start): every episode of a round
runs on its own robot drawn uniformly from Theta (a stream of its own), the collecting MPC is the deployed robust
one (``LimitedLookaheadMPC(..., model_params=True, estimate_robot=True)``: it plans, and queries the value, for its
online estimate of the robot), each query is ``(x_n, tau_n, theta_hat)`` with the robot the plan was made for, and
its tail problem is solved for that robot. The selections measure distances in ``(x, tau, theta)``. With
``replay_failed`` a share of each round's episodes fly robots whose episodes failed in earlier rounds (each with a
fresh start; a replayed robot that perches leaves the pool): uniform draws rarely visit Theta's hard corners, where
the failures are.

``uniform_fraction`` of each round's solves are plain uniform draws from X0 at the nominal time to go (the
baseline's starts), which keep the function right where the episodes begin.

**Determinism and resume.** Episode starts come from ``np.random.default_rng([seed, stream, round])``; the MPC and
the env are deterministic, so a round re-run after an interruption asks for the same tail problems, which the
solve runner then reuses from disk bit for bit. The sampler's state (the round counter, the per-round log and the
replay pool) is part of the training checkpoint.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from seagul_control.evaluation import default_horizon, run_policy_episode, sample_grid_slice
from seagul_control.mpc import LimitedLookaheadMPC, MPCOptions
from seagul_envs import Task
from seagul_learn import member_selection
from seagul_learn.dataset import SolveRecord, TrainingArrays

# The options live in the torch-free seagul_learn.sampler_options (a configuration is parsed without torch); they
# are served here under the names they always had.
from seagul_learn.sampler_options import SELECTIONS as SELECTIONS
from seagul_learn.sampler_options import ClosedLoopOptions as ClosedLoopOptions
from seagul_learn.sampler_options import Selection as Selection
from seagul_learn.samplers import StartPool
from seagul_learn.solving import SolveRunner, tail_horizon
from seagul_learn.value_network import ValueEnsemble, ValueModel

_STREAM_EPISODE_STARTS = 11
_STREAM_SELECTION = 12
_STREAM_EPISODE_ROBOTS = 14
_STREAM_VISITED = 15
_STREAM_EPISODE_SLICE = 20
_STREAM_REPLAY = 25


@dataclass
class Queries:
    """Planned terminal states of closed-loop episodes and what the episodes did."""

    x: np.ndarray
    """``(q, nx)`` planned terminal states."""
    tau: np.ndarray
    """``(q,)`` their times to go (snapped to the task's step grid for fixed-step tasks)."""
    theta: np.ndarray | None
    """``(q, k)`` the robots the plans were made for (an MPC over robots), else None."""
    episodes: int
    """Episodes run."""
    successes: int
    """Episodes that reached the task's success set."""
    fallback_steps: int
    """Steps whose action did not come from a converged solve."""
    steps: int
    """Steps run."""
    visited_x: np.ndarray | None = None
    """``(v, nx)`` states the episodes visited before each step (not the last state), when recorded."""
    visited_tau: np.ndarray | None = None
    """``(v,)`` their times to go (snapped to the step grid)."""
    visited_failed: np.ndarray | None = None
    """``(v,)`` True where the visited state belongs to an episode that did not succeed."""
    visited_theta: np.ndarray | None = None
    """``(v, k)`` the simulated robot of each visited state's episode (over robots), else None."""
    episode_success: np.ndarray | None = None
    """``(episodes,)`` True where the episode reached the task's success set."""


def snap_tau(task: Task, tau: float) -> float:
    """A fixed-step task's time to go rounded to its step grid (observations carry float32 times)."""
    if not task.fixed_step:
        return float(tau)
    h = task.tau_nominal / task.num_steps
    return float(round(tau / h) * h)


def collect_queries(
    task: Task,
    policy: Any,
    starts: np.ndarray,
    env_id: str | None = None,
    robots: np.ndarray | None = None,
    record_visited: bool = False,
) -> Queries:
    """Run ``policy`` (an MPC with ``stats``) from every start and gather its planned terminal states.

    ``robots`` (one row of parameters per start): episode ``i`` simulates the robot ``robots[i]``, and each query
    carries the robot its plan was made for (``MPCStepInfo.terminal_theta``). ``record_visited`` (fixed-step tasks):
    also the states each episode visited before its steps, with their times to go ``tau_nominal - t h``.
    """
    starts = np.atleast_2d(starts)
    if robots is not None and len(robots) != starts.shape[0]:
        raise ValueError(f"collect_queries: {len(robots)} robots for {starts.shape[0]} starts")
    xs: list[tuple[float, ...]] = []
    taus: list[float] = []
    thetas: list[tuple[float, ...]] = []
    successes = fallbacks = steps = 0
    if record_visited and not task.fixed_step:
        raise ValueError(f"{task.name}: visited-state tails need a fixed-step task (the time to go of a state)")
    vx: list[list[float]] = []
    vtau: list[float] = []
    vfail: list[bool] = []
    vtheta: list[np.ndarray] = []
    per_episode: list[bool] = []
    for i, x0 in enumerate(starts):
        robot = None if robots is None else robots[i]
        episode, infos = run_policy_episode(task, policy, x0, env_id=env_id, robot=robot, record=record_visited)
        if record_visited:
            h = task.control_period
            for t, state in enumerate(episode.states[:-1]):
                vx.append(state)
                vtau.append(snap_tau(task, task.tau_nominal - t * h))
                vfail.append(not episode.success)
                if robot is not None:
                    vtheta.append(np.asarray(robot, dtype=np.float64))
        successes += int(episode.success)
        per_episode.append(bool(episode.success))
        fallbacks += episode.fallbacks
        steps += episode.steps
        for info in infos:
            if info.terminal_state is not None and math.isfinite(info.terminal_tau) and info.terminal_tau > 0:
                if robots is not None and info.terminal_theta is None:
                    raise ValueError("collect_queries over robots needs an MPC that plans over robots (model_params)")
                xs.append(info.terminal_state)
                taus.append(snap_tau(task, info.terminal_tau))
                if robots is not None:
                    thetas.append(info.terminal_theta)
    x = np.array(xs, dtype=np.float64).reshape(-1, task.nx)
    theta = None
    if robots is not None:
        theta = np.array(thetas, dtype=np.float64).reshape(x.shape[0], np.asarray(robots).shape[1])
    out = Queries(x, np.array(taus, dtype=np.float64), theta, starts.shape[0], successes, fallbacks, steps)
    out.episode_success = np.array(per_episode, dtype=bool)
    if record_visited:
        out.visited_x = np.array(vx, dtype=np.float64).reshape(-1, task.nx)
        out.visited_tau = np.array(vtau, dtype=np.float64)
        out.visited_failed = np.array(vfail, dtype=bool)
        out.visited_theta = np.array(vtheta).reshape(len(vx), -1) if robots is not None else None
    return out


def farthest_first(candidates: np.ndarray, known: np.ndarray, k: int) -> np.ndarray:
    """Greedy k-center: indices of ``k`` rows of ``candidates``, each the farthest from ``known`` and the picks so far.

    Distances are Euclidean in the given coordinates; ties go to the lowest index (deterministic).
    """
    n = candidates.shape[0]
    k = min(int(k), n)
    if k <= 0:
        return np.zeros(0, dtype=np.int64)
    if known.shape[0]:
        dist, _ = cKDTree(known).query(candidates, k=1)
        dist = np.asarray(dist, dtype=np.float64)
    else:
        dist = np.full(n, np.inf)
    picks = np.zeros(k, dtype=np.int64)
    for j in range(k):
        i = int(np.argmax(dist))
        picks[j] = i
        dist = np.minimum(dist, np.linalg.norm(candidates - candidates[i], axis=1))
        dist[i] = -1.0
    return picks


class ClosedLoopSampler:
    """Each round: roll out the deployed MPC, solve the tail problems at its most uncertain queries (module doc)."""

    name = "closed-loop"

    def __init__(self, task: Task, pool: StartPool, options: ClosedLoopOptions | None = None, seed: int = 0) -> None:
        self.task = task
        self.pool = pool
        """Uniform starts of the ``uniform_fraction`` share (the baseline's, consumed in order)."""
        self.options = options or ClosedLoopOptions()
        self.seed = int(seed)
        self.round = 0
        self.loop_rounds = 0
        """Rounds that ran the closed loop (the ``"lqr"`` warm-up counts these)."""
        self.log: list[dict[str, Any]] = []
        """One entry per round: collector, episodes, their success and fallbacks, queries, solves."""
        self._mpcs: dict[str, Any] = {}
        self._known_x = np.zeros((0, task.nx))
        self._known_tau = np.zeros(0)
        self._known_value = np.zeros(0)
        self.robots = pool.thetas is not None
        """Episodes, queries and tails over robots (a pool over robots, ``TrainConfig.model_params``)."""
        self._known_theta = np.zeros((0, pool.thetas.shape[1] if pool.thetas is not None else 0))
        if self.robots and task.parameters is None:
            raise ValueError(f"{task.name}: a start pool over robots needs a task that declares Task.parameters")
        if self.options.replay_failed and not self.robots:
            raise ValueError("closed-loop replay_failed replays robots: it needs training over robots (model_params)")
        self.replay_pool: list[list[float]] = []
        """Robots whose collector episodes failed and have not perched since (``replay_failed``), oldest first."""
        if task.fixed_step:
            self._check_tails()

    def _check_tails(self) -> None:
        # The MPC's queries are tails of the full problem (tail_horizon raises for anything else).
        h = self.task.tau_nominal / self.task.num_steps
        if abs(self.task.control_period - h) > 1e-9:
            raise ValueError(
                f"{self.task.name}: the closed-loop sampler needs the MPC step ({self.task.control_period} s) to "
                f"equal the transcription step ({h} s) so that its planned terminal states are tails"
            )

    # --------------------------------------------------------------------------- state (resume)
    def state_dict(self) -> dict[str, Any]:
        """Resumable state (saved in the training checkpoint)."""
        return {
            "round": self.round,
            "loop_rounds": self.loop_rounds,
            "log": list(self.log),
            "replay_pool": [list(r) for r in self.replay_pool],
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore :meth:`state_dict`."""
        self.round = int(state["round"])
        self.loop_rounds = int(state.get("loop_rounds", 0))
        self.log = list(state["log"])
        self.replay_pool = [[float(v) for v in r] for r in state.get("replay_pool", [])]

    def observe(self, buffer: TrainingArrays) -> None:
        """The training buffer after a round (the ``"farthest"``/``"lowest"`` selections measure against it)."""
        self._known_x, self._known_tau, self._known_value = buffer.x, buffer.tau, buffer.value
        if self.robots:
            if buffer.theta is None:
                raise ValueError("closed-loop sampler over robots: the training buffer holds no robots")
            self._known_theta = buffer.theta

    # ------------------------------------------------------------------------------------ MPC
    def collector(self, network: ValueModel) -> Any:
        """The MPC that collects this round's queries (built once per guard, then only re-parameterised)."""
        guard = "lqr" if self.loop_rounds < self.options.warmup_rounds else self.deployed_guard
        horizon = self.options.horizon or default_horizon(self.task)
        mpc = self._mpcs.get(guard)
        if mpc is None:
            extra = {"ipopt.max_wall_time": self.options.max_step_time} if self.options.solver == "ipopt" else {}
            options = MPCOptions(
                jit=self.options.jit,
                solver=self.options.solver,  # type: ignore[arg-type]
                solver_options=extra,
            )
            mpc = LimitedLookaheadMPC(
                self.task,
                network,
                horizon,
                options,
                trust_region=guard,  # type: ignore[arg-type]
                # Over robots: the deployed robust MPC, planning (and querying the value) for its estimate.
                model_params=self.robots,
                estimate_robot=self.robots,
            )
            self._mpcs[guard] = mpc
        else:
            mpc.set_value_function(network)
        return mpc

    def episode_starts(self) -> np.ndarray:
        """This round's training starts: uniform over X0 (their own random stream), ``slice_fraction`` of them on
        the grid's slice instead (another stream), those last."""
        n = self.options.episodes
        on_slice = round(self.options.slice_fraction * n)
        rng = np.random.default_rng([self.seed, _STREAM_EPISODE_STARTS, self.round])
        starts = self.task.sample_x0(rng, n - on_slice)
        if not on_slice:
            return starts
        rng_slice = np.random.default_rng([self.seed, _STREAM_EPISODE_SLICE, self.round])
        return np.vstack([starts, sample_grid_slice(self.task, on_slice, rng_slice)])

    def episode_robots(self) -> np.ndarray | None:
        """This round's simulated robots, one per episode, or None: the first :meth:`replayed` ones drawn from the
        replay pool without replacement (stream ``[seed, 25, round]``), the others uniform over Theta (their own
        stream)."""
        if not self.robots:
            return None
        assert self.task.parameters is not None
        rng = np.random.default_rng([self.seed, _STREAM_EPISODE_ROBOTS, self.round])
        robots = self.task.parameters.sample(rng, self.options.episodes).reshape(self.options.episodes, -1)
        n = self.replayed()
        if n:
            picks = np.random.default_rng([self.seed, _STREAM_REPLAY, self.round]).permutation(len(self.replay_pool))
            robots[:n] = np.array([self.replay_pool[i] for i in picks[:n]], dtype=np.float64)
        return robots

    def replayed(self) -> int:
        """How many of this round's episodes fly robots from the replay pool (``replay_failed``)."""
        return min(round(self.options.replay_failed * self.options.episodes), len(self.replay_pool))

    def _update_replay(self, robots: np.ndarray, success: np.ndarray, replayed: int) -> None:
        """After a round: replayed robots that perched leave the pool, every other failed robot joins (or stays)."""
        perched = {tuple(r) for r in robots[:replayed][success[:replayed]]}
        pool = [r for r in self.replay_pool if tuple(r) not in perched]
        known = {tuple(r) for r in pool}
        for robot, ok in zip(robots, success, strict=True):
            if not ok and tuple(robot) not in known:
                pool.append([float(v) for v in robot])
                known.add(tuple(robot))
        self.replay_pool = pool

    # ------------------------------------------------------------------------------- selection
    def _eligible(self, queries: Queries) -> np.ndarray:
        return self._eligible_tails(queries.x, queries.tau)

    def _eligible_tails(self, xs: np.ndarray, taus: np.ndarray) -> np.ndarray:
        """Indices of the ``(x, tau)`` rows that are tails of the full problem on the stride, with finite states."""
        keep = taus > 0
        for i, tau in enumerate(taus):
            try:
                k = tail_horizon(self.task, float(tau))
            except ValueError:
                keep[i] = False
                continue
            if k is not None and k % self.options.tail_stride:
                keep[i] = False
        keep &= np.all(np.isfinite(xs), axis=1)
        return np.flatnonzero(keep)

    def select_visited(self, queries: Queries, k: int) -> np.ndarray:
        """Indices of ``k`` visited states to solve tails from: states of failed episodes first, each group in a
        seeded random order (stream ``[seed, 15, round]``)."""
        if queries.visited_x is None or queries.visited_tau is None or queries.visited_failed is None or k <= 0:
            return np.zeros(0, dtype=np.int64)
        eligible = self._eligible_tails(queries.visited_x, queries.visited_tau)
        rng = np.random.default_rng([self.seed, _STREAM_VISITED, self.round])
        order = eligible[rng.permutation(eligible.size)]
        order = np.concatenate([order[queries.visited_failed[order]], order[~queries.visited_failed[order]]])
        return np.sort(order[: min(int(k), order.size)])

    def select(self, queries: Queries, network: ValueModel, k: int) -> np.ndarray:
        """Indices of the ``k`` queries to solve (see ``selection``)."""
        eligible = self._eligible(queries)
        if eligible.size == 0 or k <= 0:
            return np.zeros(0, dtype=np.int64)
        mean = network.in_mean.detach().numpy()
        std = network.in_std.detach().numpy()
        theta = None if queries.theta is None else queries.theta[eligible]
        cand_cols = [queries.x[eligible], queries.tau[eligible]]
        known_cols = [self._known_x, self._known_tau]
        if theta is not None:
            cand_cols.append(theta)
            known_cols.append(self._known_theta)
        cand = (np.column_stack(cand_cols) - mean) / std
        known = (np.column_stack(known_cols) - mean) / std
        method = self.options.selection
        if method == "random":
            rng = np.random.default_rng([self.seed, _STREAM_SELECTION, self.round])
            picks = rng.permutation(eligible.size)[: min(k, eligible.size)]
        elif method == "spread" and isinstance(network, ValueEnsemble):
            spread = network.spread(queries.x[eligible], queries.tau[eligible], theta)
            picks = np.argsort(-spread, kind="stable")[: min(k, eligible.size)]
        elif method == "lowest" and known.shape[0]:
            _, nearest = cKDTree(known).query(cand, k=1)
            vhat = network.predict(queries.x[eligible], queries.tau[eligible], theta)
            # How far below its nearest known label the network rates the query, farthest-first among ties.
            gap = vhat - self._known_value[np.asarray(nearest)]
            picks = np.argsort(gap, kind="stable")[: min(k, eligible.size)]
        else:
            picks = farthest_first(cand, known, k)
        return eligible[np.sort(picks)]

    # --------------------------------------------------------------------------------- sampling
    def _split(self, num_solves: int) -> tuple[int, int]:
        """``(uniform, tail)`` solves of a round of ``num_solves`` (before any shortfall of eligible queries)."""
        opts = self.options
        warmup = min(num_solves, max(0, opts.uniform_solves - self.pool.position))
        rest = num_solves - warmup
        n_uniform = warmup + round(opts.uniform_fraction * rest) if rest else warmup
        return n_uniform, num_solves - n_uniform

    def collects(self, num_solves: int) -> bool:
        """Whether a round of ``num_solves`` runs the collecting MPC (False during the uniform warm-up)."""
        return self._split(num_solves)[1] > 0

    @property
    def deployed_guard(self) -> str:
        """The guard of the deployed controller the sampler collects with after the warm-up rounds: ``trust_region``,
        or the task's ``profile.mpc.trust_region`` when that is None."""
        return self.options.trust_region or self.task.profile.mpc.trust_region

    def collects_deployed(self, num_solves: int) -> bool:
        """Whether a round of ``num_solves`` collects with the deployed guard (``trust_region``, after the
        ``"lqr"`` warm-up rounds)."""
        return self.collects(num_solves) and self.loop_rounds >= self.options.warmup_rounds

    def sample(self, num_solves: int, network: ValueModel, runner: SolveRunner) -> list[SolveRecord]:
        """Exactly ``num_solves`` solves: uniform draws, then tail problems at the chosen queries.

        If the episodes produce fewer eligible queries than needed (e.g. every step fell back), the rest of the
        round's solves are uniform draws, so the budget is always spent exactly.
        """
        records: list[SolveRecord] = []
        # Uniform warm-up first (pool.position counts the uniform solves spent so far), then the mixed rounds.
        n_uniform, n_tail = self._split(num_solves)
        entry: dict[str, Any] = {"round": self.round}
        if n_tail > 0:
            mpc = self.collector(network)
            entry["collector"] = mpc.trust_region
            n_visited = round(self.options.visited_fraction * n_tail)
            robots, replayed = self.episode_robots(), self.replayed()
            queries = collect_queries(
                self.task, mpc, self.episode_starts(), robots=robots, record_visited=n_visited > 0
            )
            visited = self.select_visited(queries, n_visited)
            chosen = self.select(queries, network, n_tail - int(visited.size))
            entry.update(
                episodes=queries.episodes,
                episode_successes=queries.successes,
                fallback_steps=queries.fallback_steps,
                steps=queries.steps,
                queries=int(queries.tau.shape[0]),
                tails=int(chosen.size),
                visited_tails=int(visited.size),
            )
            if self.options.replay_failed:
                assert robots is not None and queries.episode_success is not None
                entry.update(replayed=replayed, replayed_successes=int(queries.episode_success[:replayed].sum()))
                self._update_replay(robots, queries.episode_success, replayed)
                entry["replay_pool"] = len(self.replay_pool)
            n_uniform += n_tail - int(chosen.size) - int(visited.size)
            self.loop_rounds += 1
            if chosen.size:
                thetas = None if queries.theta is None else queries.theta[chosen]
                records += runner.solve(queries.x[chosen], queries.tau[chosen], self.name, thetas=thetas)
            if visited.size:
                assert queries.visited_x is not None and queries.visited_tau is not None
                vthetas = None if queries.visited_theta is None else queries.visited_theta[visited]
                records += runner.solve(
                    queries.visited_x[visited], queries.visited_tau[visited], self.name + "-visited", thetas=vthetas
                )
        if n_uniform:
            starts, taus, ids = self.pool.take(n_uniform)
            records += runner.solve(starts, taus, "uniform-mix", thetas=self.pool.thetas_of(ids))
        entry["uniform"] = int(n_uniform)
        entry["failures"] = int(sum(not r.success for r in records))
        self.log.append(entry)
        self.round += 1
        return records


# ------------------------------------------------------------------------------------------ planner-query error
@dataclass
class QueryError:
    """``|Vhat - V|`` at a sample of a controller's planned terminal states, against re-solved tail values."""

    median: float
    """Median absolute error over the successful re-solves."""
    p95: float
    """95th percentile of the absolute error."""
    mean_signed: float
    """Mean of ``Vhat - V`` (negative: the network under-estimates where the planner looks)."""
    sampled: int
    """Queries re-solved."""
    failed: int
    """Re-solves that failed (no reference value there; reported, never averaged in)."""
    available: int
    """Queries the episodes produced."""

    def as_dict(self) -> dict[str, Any]:
        """Plain dict (JSON)."""
        return asdict(self)


def query_errors(
    task: Task,
    network: ValueModel,
    queries: np.ndarray,
    batch_solver: Any,
    num: int = 50,
    seed: int = 0,
) -> QueryError:
    """The planner-query error: re-solve ``num`` of ``queries`` (rows ``[*x_n, tau_n]``) and compare to ``Vhat``.

    The sample is uniform over the queries with a fixed seed (every network's queries are sampled the same way);
    times to go are snapped to the task's step grid and queries that are not tails of the full problem are skipped.
    """
    q = np.asarray(queries, dtype=np.float64).reshape(-1, task.nx + 1)
    taus = np.array([snap_tau(task, t) for t in q[:, -1]])
    ok = np.zeros(q.shape[0], dtype=bool)
    for i, t in enumerate(taus):
        try:
            tail_horizon(task, float(t))
            ok[i] = t > 0 and bool(np.all(np.isfinite(q[i])))
        except ValueError:
            ok[i] = False
    idx = np.flatnonzero(ok)
    rng = np.random.default_rng([int(seed), 13])
    idx = np.sort(rng.permutation(idx)[: min(int(num), idx.size)])
    if idx.size == 0:
        return QueryError(float("nan"), float("nan"), float("nan"), 0, 0, int(q.shape[0]))
    results = batch_solver(q[idx, : task.nx], taus[idx])
    good = [(i, r) for i, r in zip(idx, results, strict=True) if r.success]
    if not good:
        return QueryError(float("nan"), float("nan"), float("nan"), int(idx.size), int(idx.size), int(q.shape[0]))
    xs = np.array([q[i, : task.nx] for i, _ in good])
    ts = np.array([taus[i] for i, _ in good])
    signed = network.predict(xs, ts) - np.array([r.value for _, r in good])
    err = np.abs(signed)
    return QueryError(
        float(np.median(err)),
        float(np.percentile(err, 95)),
        float(np.mean(signed)),
        int(idx.size),
        int(idx.size - len(good)),
        int(q.shape[0]),
    )


def __getattr__(name: str) -> Any:
    """``select_members``, ``MemberSelection`` and ``_selection_starts`` live in :mod:`seagul_learn.member_selection`
    (the closed-loop selection of a refit's members); these names keep working here."""
    if name in ("select_members", "MemberSelection", "_selection_starts"):
        return getattr(member_selection, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
