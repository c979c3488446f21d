"""Where to solve next: the uniform baseline and the adversarial sampler (paper Alg. 1).

Both samplers draw their starting states from one :class:`StartPool`: the uniform baseline's draws from X0 for a
given seed. The uniform sampler solves them in order; the adversarial sampler starts its chains from a random
subset of them (paper §6: "taken from a randomly selected subset of the samples used by the baseline").

**Time to go.** Uniform draws and chain starts use the task's nominal ``tau`` (docs/reference/spec.md §4.5: uniform
samples and validation use the nominal ``tau``; for the acrobot T0 is the single value 5 s anyway). The adversarial
ascent moves ``tau`` inside T0 when T0 is an interval (``AdversarialOptions.ascend_tau``).

**Ascent step (paper Eq. 6, docs/reference/spec.md §11.2).** For a solved iterate with value ``V`` and dual gradient
``dV/dx`` (``dV/dtau``), and the network's ``Vhat`` and autograd ``dVhat/dx``, the gradient of ``1/2 (V - Vhat)^2`` is
``g = (V - Vhat) (dV/dx - dVhat/dx)``. The ascent runs in box-normalised coordinates ``u = (x - low) / width``
(coordinates whose X0 width is zero never move; ``tau`` is one more coordinate when it ascends), so
``g_u = g * width``. Rule ``"pga"``: ``du = step_fraction * g_u / max_j |g_u_j|`` — the coordinate with the
largest normalised gradient moves ``step_fraction`` of its box width and the others proportionally (the step size
is independent of the scale of ``V``, which changes by orders of magnitude across tasks and training). Rule
``"adam"``: an Adam update on ``u`` per chain with learning rate ``step_fraction`` (Adam normalises per coordinate).
Projection onto X0 (x T0): ``"clip"`` (the paper's projection) or ``"reflect"`` (mirror the overshoot back into
the box, so iterates do not pile up on the boundary). A chain stops after ``max_steps`` solves, when the projected
step is below ``eps`` (max-norm, in box widths), at its first failed solve (its earlier iterates are kept), and,
with ``stop_on_decrease``, when an iterate's loss fell below its predecessor's (the step overshot a peak).

**Over robots** (``TrainConfig.model_params``, docs/reference/spec.md §14). The pool then also holds one robot ``theta``
per start, drawn uniformly from the task's box Theta (after the starts, from the same stream: the starts equal the
nominal run's). The uniform baseline solves each start for its robot: uniform over ``X0 x Theta``. The adversarial
ascent moves ``theta`` as more box-normalised coordinates (Theta's widths), with the loss gradient
``(V - Vhat) (dV/dtheta - dVhat/dtheta)`` from the dual ``SolveResult.grad_theta``, and projects onto Theta like x
onto X0: the paper's "adversarial samples with respect to environment parameters".

**Improvements behind options** (for the benchmark): ``projection="reflect"``; ``uniform_fraction`` mixes a share of
each round's solves as plain uniform draws from the same pool (the knots of those solves cover the rest of the
function); short chains (``max_steps=2``: every chain is a uniform start plus one ascent iterate, "one or two
iterations often appear to suffice", paper §5); ``stop_on_decrease``; ``optimizer="adam"``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from seagul_envs import Task
from seagul_learn.dataset import SolveRecord

# The option classes live in the torch-free seagul_learn.sampler_options (a configuration is parsed without torch);
# they are served here under the names they always had.
from seagul_learn.sampler_options import AdversarialOptions as AdversarialOptions
from seagul_learn.sampler_options import SamplerOptions as SamplerOptions
from seagul_learn.sampler_options import UniformOptions as UniformOptions
from seagul_learn.solving import SolveRunner
from seagul_learn.value_network import ValueModel


@dataclass
class StartPool:
    """The uniform baseline's starting states for one seed, consumed in order (``position`` is resumable state)."""

    starts: np.ndarray
    """Start states, ``(n, nx)``."""
    taus: np.ndarray
    """Time to go of each start, ``(n,)``."""
    order: np.ndarray
    """Order in which a sampler consumes the pool (identity for uniform, a permutation for adversarial)."""
    position: int = 0
    """How many starts have been consumed."""
    thetas: np.ndarray | None = None
    """One robot per start, ``(n, k)`` (pools over robots), else None."""

    @classmethod
    def uniform(
        cls, task: Task, n: int, rng: np.random.Generator, uniform_tau: bool = False, model_params: bool = False
    ) -> StartPool:
        """``n`` uniform draws from X0 (and from T0 if ``uniform_tau``, else the nominal ``tau``); with
        ``model_params`` also one robot per start, uniform over the task's box Theta (drawn after the starts, so the
        starts are those of the pool without robots)."""
        starts = task.sample_x0(rng, n)
        lo, hi = task.tau_range
        taus = rng.uniform(lo, hi, size=n) if uniform_tau and hi > lo else np.full(n, task.tau_nominal)
        thetas = None
        if model_params:
            if task.parameters is None:
                raise ValueError(f"{task.name} declares no physical parameters (Task.parameters) to draw robots from")
            thetas = task.parameters.sample(rng, n).reshape(n, task.parameters.size)
        return cls(starts, taus, np.arange(n), 0, thetas)

    def shuffled(self, rng: np.random.Generator) -> StartPool:
        """The same starts, consumed in a random order (a random subset for whoever takes fewer than all)."""
        return StartPool(self.starts, self.taus, rng.permutation(self.starts.shape[0]), 0, self.thetas)

    def thetas_of(self, ids: np.ndarray) -> np.ndarray | None:
        """The robots of the starts ``ids`` (from :meth:`take`), or None for a pool without robots."""
        return None if self.thetas is None else self.thetas[np.asarray(ids, dtype=np.int64)].copy()

    def take(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The next ``n`` starts, their taus and their pool ids."""
        if self.position + n > self.order.shape[0]:
            raise RuntimeError(
                f"start pool exhausted: {n} starts asked, {self.order.shape[0] - self.position} left "
                "(the pool must hold at least the budget)"
            )
        ids = self.order[self.position : self.position + n]
        self.position += n
        return self.starts[ids].copy(), self.taus[ids].copy(), ids.copy()


class Sampler(Protocol):
    """Chooses and solves ``num_solves`` new problems given the current network (one round of Alg. 2)."""

    name: str
    pool: StartPool

    def sample(self, num_solves: int, network: ValueModel, runner: SolveRunner) -> list[SolveRecord]: ...


class UniformSampler:
    """The baseline: solve the pool's starts in order (uniform over X0, nominal ``tau``)."""

    name = "uniform"

    def __init__(self, task: Task, pool: StartPool) -> None:
        self.task = task
        self.pool = pool

    def sample(self, num_solves: int, network: ValueModel, runner: SolveRunner) -> list[SolveRecord]:
        """Exactly ``num_solves`` solves (failures included), each for its start's robot in a pool over robots."""
        starts, taus, ids = self.pool.take(num_solves)
        return runner.solve(starts, taus, self.name, thetas=self.pool.thetas_of(ids))


@dataclass
class _Chain:
    chain_id: int
    u: np.ndarray
    """Box-normalised free coordinates (x, then tau if it ascends, then theta in a pool over robots)."""
    step: int = 0
    last_loss: float = -np.inf
    adam_m: np.ndarray | None = None
    adam_v: np.ndarray | None = None


class AdversarialSampler:
    """Paper Alg. 1: chains of projected gradient ascent on ``1/2 (V - Vhat)^2``; every iterate is a solve."""

    name = "adversarial"

    def __init__(self, task: Task, pool: StartPool, options: AdversarialOptions | None = None) -> None:
        self.task = task
        self.pool = pool
        self.options = options or AdversarialOptions()
        lo, hi = task.tau_range
        self.ascend_tau = self.options.ascend_tau and hi > lo
        self.robots = pool.thetas is not None
        """The pool holds one robot per start (a run over robots): every solve is for its chain's robot."""
        self.ascend_theta = self.robots and self.options.ascend_theta
        low = np.append(task.x0_low, lo) if self.ascend_tau else task.x0_low.copy()
        high = np.append(task.x0_high, hi) if self.ascend_tau else task.x0_high.copy()
        if self.ascend_theta:
            assert task.parameters is not None  # a pool over robots was drawn from them
            low, high = np.append(low, task.parameters.low), np.append(high, task.parameters.high)
        self._low, self._width = low, high - low
        self._n_theta = task.parameters.size if self.ascend_theta and task.parameters is not None else 0
        self._free = self._width > 0
        """Coordinates that may move (zero-width X0 coordinates are fixed)."""

    # ------------------------------------------------------------ coordinates
    def _to_u(self, x: np.ndarray, tau: float, theta: np.ndarray | None = None) -> np.ndarray:
        z = np.append(x, tau) if self.ascend_tau else np.asarray(x, dtype=np.float64)
        if self.ascend_theta:
            assert theta is not None  # every start of a pool over robots has one
            z = np.append(z, theta)
        return np.where(self._free, (z - self._low) / np.where(self._free, self._width, 1.0), 0.0)

    def _from_u(
        self, u: np.ndarray, x_template: np.ndarray, tau: float, theta_template: np.ndarray | None = None
    ) -> tuple[np.ndarray, float, np.ndarray | None]:
        """``(x, tau, theta)`` of ``u``; fixed coordinates keep the template's values."""
        template = np.append(x_template, tau) if self.ascend_tau else np.asarray(x_template, dtype=np.float64)
        if self.ascend_theta:
            assert theta_template is not None
            template = np.append(template, theta_template)
        z = np.where(self._free, self._low + u * self._width, template)
        nx = np.asarray(x_template).size
        x = z[:nx]
        tau_new = float(z[nx]) if self.ascend_tau else float(tau)
        theta = z[z.size - self._n_theta :] if self.ascend_theta else theta_template
        return x, tau_new, None if theta is None else np.asarray(theta, dtype=np.float64).copy()

    def _project(self, u: np.ndarray) -> np.ndarray:
        if self.options.projection == "reflect":
            u = np.where(u > 1.0, 2.0 - u, u)
            u = np.where(u < 0.0, -u, u)
        return np.clip(u, 0.0, 1.0)

    # ------------------------------------------------------------------ steps
    def loss_gradient(self, record: SolveRecord, network: ValueModel) -> tuple[float, np.ndarray]:
        """``1/2 (V - Vhat)^2`` at the record's start (and robot) and its gradient in box-normalised coordinates."""
        if self.robots:
            vhat, dvhat_dx, dvhat_dtau, dvhat_dtheta = network.value_and_grads(record.x_init, record.tau, record.theta)
        else:
            vhat, dvhat_dx, dvhat_dtau = network.value_and_grad(record.x_init, record.tau)
        err = record.value - float(np.asarray(vhat).reshape(-1)[0])
        g = err * (record.grad_x - np.asarray(dvhat_dx).reshape(-1))
        if self.ascend_tau:
            g = np.append(g, err * (record.grad_tau - float(np.asarray(dvhat_dtau).reshape(-1)[0])))
        if self.ascend_theta:
            g = np.append(g, err * (record.grad_theta - np.asarray(dvhat_dtheta).reshape(-1)))
        return 0.5 * err**2, np.where(self._free, g * self._width, 0.0)

    def ascent_step(self, chain: _Chain, g_u: np.ndarray) -> np.ndarray:
        """The next (projected) box-normalised iterate of ``chain`` given the loss gradient ``g_u``."""
        opts = self.options
        if not np.all(np.isfinite(g_u)):
            return chain.u.copy()  # no usable gradient: the chain stops (zero step)
        if opts.optimizer == "adam":
            b1, b2 = opts.adam_betas
            if chain.adam_m is None or chain.adam_v is None:
                chain.adam_m, chain.adam_v = np.zeros_like(g_u), np.zeros_like(g_u)
            t = chain.step + 1
            chain.adam_m = b1 * chain.adam_m + (1 - b1) * g_u
            chain.adam_v = b2 * chain.adam_v + (1 - b2) * g_u**2
            m_hat, v_hat = chain.adam_m / (1 - b1**t), chain.adam_v / (1 - b2**t)
            du = opts.step_fraction * m_hat / (np.sqrt(v_hat) + 1e-12)
        else:
            scale = float(np.max(np.abs(g_u))) if g_u.size else 0.0
            du = opts.step_fraction * g_u / scale if scale > 0 else np.zeros_like(g_u)
        return self._project(chain.u + np.where(self._free, du, 0.0))

    # --------------------------------------------------------------- sampling
    def sample(self, num_solves: int, network: ValueModel, runner: SolveRunner) -> list[SolveRecord]:
        """Exactly ``num_solves`` solves: chains (and, if configured, uniform draws) until the budget is spent."""
        opts = self.options
        records: list[SolveRecord] = []
        n_uniform = round(opts.uniform_fraction * num_solves)
        if n_uniform:
            starts, taus, ids = self.pool.take(n_uniform)
            records += runner.solve(starts, taus, "uniform-mix", thetas=self.pool.thetas_of(ids))
        remaining = num_solves - n_uniform
        while remaining > 0:
            n_chains = math.ceil(remaining / opts.max_steps)
            starts, taus, ids = self.pool.take(n_chains)
            robots = self.pool.thetas_of(ids)
            thetas = [None] * len(ids) if robots is None else list(robots)
            chains = [
                _Chain(int(i), self._to_u(x, t, th)) for x, t, th, i in zip(starts, taus, thetas, ids, strict=True)
            ]
            xs = {c.chain_id: (x, float(t), th) for c, x, t, th in zip(chains, starts, taus, thetas, strict=True)}
            active = chains
            while active and remaining > 0:
                batch = active[:remaining]
                batch_x = np.array([xs[c.chain_id][0] for c in batch])
                batch_t = np.array([xs[c.chain_id][1] for c in batch])
                batch_th = np.array([xs[c.chain_id][2] for c in batch]) if self.robots else None
                solved = runner.solve(
                    batch_x,
                    batch_t,
                    self.name,
                    chains=[c.chain_id for c in batch],
                    steps=[c.step for c in batch],
                    thetas=batch_th,
                )
                records += solved
                remaining -= len(batch)
                next_active: list[_Chain] = []
                for chain, rec in zip(batch, solved, strict=True):
                    if not rec.success or chain.step + 1 >= opts.max_steps:
                        continue  # a failed solve ends its chain; earlier iterates stay
                    loss, g_u = self.loss_gradient(rec, network)
                    if opts.stop_on_decrease and loss < chain.last_loss:
                        continue
                    chain.last_loss = loss
                    u_new = self.ascent_step(chain, g_u)
                    if float(np.max(np.abs(u_new - chain.u), initial=0.0)) < max(opts.eps, 1e-15):
                        continue
                    chain.u = u_new
                    chain.step += 1
                    xs[chain.chain_id] = self._from_u(u_new, rec.x_init, rec.tau, rec.theta if self.robots else None)
                    next_active.append(chain)
                active = next_active
        return records
