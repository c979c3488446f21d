"""Fitting a value network to the buffer: the loss, the minibatches, the trainer, the network of a run.

The pieces of SEAGuL's regression (module docstring of :mod:`seagul_learn.training`, which runs them): the
standardised value MSE plus the Sobolev term (:func:`training_loss`), minibatches that favour the newest knots
(paper §5), validation MSEs (:func:`evaluate`), and the :class:`Trainer` that holds a run's network, Adam state and
metrics between rounds. Every random stream is ``np.random.default_rng([seed, stream, index])`` (:func:`rng`), one
stream id per use, so results never depend on the order of unrelated draws.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from seagul_envs import Task
from seagul_learn.config import TrainConfig
from seagul_learn.dataset import TrainingArrays
from seagul_learn.value_network import ValueEnsemble, ValueModel, ValueNetwork

# Random streams: one id each, combined with the seed (and the round) into an independent generator.
STREAM_BASELINE_STARTS = 1
STREAM_ADVERSARIAL_ORDER = 2
STREAM_PRETRAIN_STARTS = 3
STREAM_PRETRAIN_BATCHES = 4
STREAM_ROUND_BATCHES = 5
STREAM_REFIT_BATCHES = 6
STREAM_VALIDATION_ROBOTS = 7


@dataclass
class Metric:
    """One evaluation point."""

    solves: int
    train_steps: int
    mse_initial: float
    mse_all_knots: float
    failures: int
    buffer_solves: int
    wall_time: float


def rng(seed: int, stream: int, index: int = 0) -> np.random.Generator:
    return np.random.default_rng([int(seed), int(stream), int(index)])


def _as_tensors(
    arrays: TrainingArrays,
    value_cap: float = 0.0,
    grad_label_max: float = 0.0,
    network: ValueModel | None = None,
    compress: bool = False,
) -> dict[str, torch.Tensor]:
    value = arrays.value
    grad_x, grad_theta = arrays.grad_x, arrays.grad_theta
    grad_ok = np.all(np.isfinite(grad_x), axis=1)
    if grad_theta is not None:
        grad_ok &= np.all(np.isfinite(grad_theta), axis=1)
    if value_cap > 0:
        if compress:  # the order of the labels stays; their gradients scale by the map's derivative, cap / V
            slope = value_cap / np.maximum(value, value_cap)
            grad_x = grad_x * slope[:, None]
            grad_theta = None if grad_theta is None else grad_theta * slope[:, None]
        else:  # a clipped label keeps "expensive" without its scale; its gradient label no longer applies
            grad_ok &= value <= value_cap
        value = capped(value, value_cap, compress)
    if grad_label_max > 0:
        if network is None:
            raise ValueError("grad_label_max needs the network whose standardisation measures the gradient labels")
        scale = _members(network)[0].in_std.numpy()[: arrays.x.shape[1]] / float(_members(network)[0].out_std)
        grad_ok &= np.linalg.norm(np.nan_to_num(grad_x) * scale, axis=1) <= grad_label_max
    out = {
        "x": torch.tensor(arrays.x, dtype=torch.float64),
        "tau": torch.tensor(arrays.tau, dtype=torch.float64),
        "value": torch.tensor(value, dtype=torch.float64),
        "grad_x": torch.tensor(np.nan_to_num(grad_x), dtype=torch.float64),
        "grad_ok": torch.tensor(grad_ok),
    }
    if arrays.theta is not None and grad_theta is not None:
        out["theta"] = torch.tensor(arrays.theta, dtype=torch.float64)
        out["grad_theta"] = torch.tensor(np.nan_to_num(grad_theta), dtype=torch.float64)
    return out


def training_loss(network: ValueNetwork, batch: dict[str, torch.Tensor], sobolev_weight: float) -> torch.Tensor:
    """The standardised value MSE plus ``loss.sobolev_weight`` times the standardised gradient MSE (module docstring).

    A network over robots takes the batch's ``theta``, and its gradient term averages over the ``nx`` state and the
    ``k`` parameter coordinates alike (``dV/dtheta`` labels standardised by theta's input scale)."""
    target = (batch["value"] - network.out_mean) / network.out_std
    theta = batch.get("theta") if network.n_params else None
    if sobolev_weight == 0.0:
        return torch.mean((network.forward_standardized(batch["x"], batch["tau"], theta) - target) ** 2)
    x = batch["x"].clone().requires_grad_(True)
    if theta is None:
        pred = network.forward_standardized(x, batch["tau"])
        (dy_dx,) = torch.autograd.grad(pred.sum(), x, create_graph=True)
        scale = network.in_std[: network.nx]
        # dy/dz = dy/dx * in_std; the label's dy/dz = dV/dx * in_std / out_std
        diff = dy_dx * scale - batch["grad_x"] * scale / network.out_std
    else:
        th = theta.clone().requires_grad_(True)
        pred = network.forward_standardized(x, batch["tau"], th)
        dy_dx, dy_dth = torch.autograd.grad(pred.sum(), (x, th), create_graph=True)
        scale = torch.cat([network.in_std[: network.nx], network.in_std[network.nx + 1 :]])
        grads = torch.cat([dy_dx, dy_dth], dim=1)
        labels = torch.cat([batch["grad_x"], batch["grad_theta"]], dim=1)
        diff = grads * scale - labels * scale / network.out_std
    mask = batch["grad_ok"].to(torch.float64)
    grad_term = torch.sum(mask * torch.mean(diff**2, dim=1)) / torch.clamp(mask.sum(), min=1.0)
    return torch.mean((pred - target) ** 2) + sobolev_weight * grad_term


def _minibatch(
    data: dict[str, torch.Tensor], newest: np.ndarray, batch_size: int, newest_fraction: float, rng: np.random.Generator
) -> dict[str, torch.Tensor]:
    n_total = data["value"].shape[0]
    n_new = round(newest_fraction * batch_size) if newest.size else 0
    idx = np.concatenate([rng.choice(newest, size=n_new), rng.integers(0, n_total, size=batch_size - n_new)])
    index = torch.from_numpy(idx)
    return {k: v[index] for k, v in data.items()}


def evaluate(network: ValueModel, validation: TrainingArrays) -> tuple[float, float]:
    """``(mse_initial, mse_all_knots)`` of ``network`` on per-knot validation arrays (NaN if empty)."""
    if len(validation) == 0:
        return float("nan"), float("nan")
    if network.n_params and validation.theta is not None:
        pred = network.predict(validation.x, validation.tau, validation.theta)
    else:
        pred = network.predict(validation.x, validation.tau)
    err2 = (pred - validation.value) ** 2
    init = validation.knot == 0
    return float(np.mean(err2[init])) if init.any() else float("nan"), float(np.mean(err2))


class Trainer:
    """Holds a run's mutable state between rounds (network, optimizer, buffer, metrics)."""

    def __init__(self, config: TrainConfig, network: ValueModel, validation: TrainingArrays | None) -> None:
        self.config = config
        self.network = network
        self.optimizer = torch.optim.Adam(network.parameters(), lr=config.schedule.lr)
        self.validation = validation
        self.metrics: list[Metric] = []
        self.train_steps = 0
        self.t0 = time.perf_counter()

    def record_metric(self, solves: int, failures: int, buffer_solves: int) -> None:
        mse_i, mse_a = evaluate(self.network, self.validation) if self.validation is not None else (np.nan, np.nan)
        self.metrics.append(
            Metric(solves, self.train_steps, mse_i, mse_a, failures, buffer_solves, time.perf_counter() - self.t0)
        )

    def train(
        self,
        buffer: TrainingArrays,
        newest: np.ndarray,
        steps: int,
        rng: np.random.Generator,
        count_steps: bool,
        on_eval: Callable[[], None] | None = None,
        cosine: bool = False,
    ) -> None:
        """``steps`` Adam steps on minibatches of ``buffer`` (``newest`` indexes this round's knots); ``cosine``
        decays the learning rate to 0 over the steps."""
        if len(buffer) == 0 or steps == 0:
            return
        labels = self.config.loss
        data = _as_tensors(buffer, labels.value_cap, labels.grad_label_max, self.network, labels.value_compress)
        fraction = self.config.schedule.newest_fraction
        members = _members(self.network)
        if cosine:
            schedule = torch.optim.lr_scheduler.CosineAnnealingLR(self.optimizer, steps)
        for _ in range(steps):
            self.optimizer.zero_grad(set_to_none=True)
            # Each member of an ensemble gets its own minibatch (drawn in order from the one stream).
            loss = sum(
                training_loss(
                    m, _minibatch(data, newest, self.config.schedule.batch_size, fraction, rng), labels.sobolev_weight
                )
                for m in members
            )
            loss.backward()  # type: ignore[union-attr]
            self.optimizer.step()
            if cosine:
                schedule.step()
            if count_steps:
                self.train_steps += 1
                every = self.config.schedule.eval_every
                if on_eval is not None and every and self.train_steps % every == 0:
                    on_eval()


def _members(network: ValueModel) -> list[ValueNetwork]:
    """The networks an optimizer step trains (one, or every member of an ensemble)."""
    return network.networks if isinstance(network, ValueEnsemble) else [network]


def make_network(config: TrainConfig, task: Task) -> ValueModel:
    """The run's (untrained) value function: a network, or an ensemble when ``config.network.ensemble >= 2``; over
    robots (``model_params``) with the task's parameters (or their invariant products, ``network.robot_invariants``)
    as inputs, conditioned on the task's own values; the task's periodic angles
    (:attr:`~seagul_envs.tasks.base.Task.periodic`) fed as ``(cos q, sin q)``."""
    robots = config.model_params and task.parameters is not None
    n_params = task.parameters.size if robots and task.parameters is not None else 0
    theta = task.theta if robots else None
    net = config.network
    features: tuple[tuple[float, ...], ...] = ()
    if net.robot_invariants:
        if not robots or task.parameters is None or task.parameters.invariants is None:
            raise ValueError(
                f"network.robot_invariants needs a run over robots (model_params) of a task whose parameters declare "
                f"invariants; {task.name} with model_params={config.model_params} does not"
            )
        features = task.parameters.feature_exponents()
    if net.ensemble >= 2:
        return ValueEnsemble(
            task.nx,
            net.hidden,
            net.ensemble,
            net.pessimism,
            task_name=task.name,
            seed=config.seed,
            n_params=n_params,
            theta=theta,
            periodic=task.periodic,
            theta_features=features,
        )
    return ValueNetwork(
        task.nx,
        net.hidden,
        task_name=task.name,
        seed=config.seed,
        n_params=n_params,
        theta=theta,
        periodic=task.periodic,
        theta_features=features,
    )


def capped(value: np.ndarray, value_cap: float, compress: bool = False) -> np.ndarray:
    """The value labels the loss sees: clipped at ``value_cap`` (0 = off), or with ``compress``
    (``loss.value_compress``) ``cap * (1 + ln(V / cap))`` above it."""
    value = np.asarray(value, dtype=np.float64)
    if value_cap <= 0:
        return value
    clipped = np.minimum(value, value_cap)
    return clipped + value_cap * np.log(np.maximum(value, value_cap) / value_cap) if compress else clipped
