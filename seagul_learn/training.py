"""SEAGuL training (paper Alg. 2) for both samplers, with validation, metrics, plots and exact resume.

One run, for a :class:`TrainConfig`:

1. **Validation set** (docs/reference/spec.md §3.6/§4.6): the task's ``task.profile.validation_spec(task)``, solved once
   and cached under ``cache_dir`` keyed by the task's fingerprint and the solver settings: acrobot a 10 x 10 grid over
   ``(th1, th2)`` at zero velocity plus 100 uniform draws from X0; glider a 6 x 6 x 6 grid over ``(x, z, dx)`` (other
   states 0) plus 250 uniform draws; a new task by default a 10 x 10 grid over two coordinates plus 100 draws; all at
   the nominal ``tau``. The random part uses a fixed seed, so every training seed is validated on the same set.
2. **Pretraining** (paper §6): ``schedule.pretrain_solves`` uniform solves (a stream that depends only on the seed) set
   the network's standardisation (all their knots) and train it for ``schedule.pretrain_steps`` steps. The result
   depends on neither the sampler nor the Sobolev weight, so every variant of a seed starts from IDENTICAL parameters.
   The pretraining solves stay in the buffer of every variant and are not counted in ``budget``.
3. **Rounds**: each round the sampler spends ``min(solves_per_round, budget left)`` solves (the uniform baseline's
   starts for this seed; adversarial chains start from a random subset of them), every knot of each successful solve
   joins the buffer, then ``schedule.train_steps_per_round`` Adam steps follow. Failed solves are stored, counted and
   never trained on.

**Minibatches favour the newest samples** (paper §5): each minibatch of ``schedule.batch_size`` draws
``round(newest_fraction * batch_size)`` samples uniformly from the knots added this round and the rest uniformly from
the whole buffer (with replacement), so a newest sample is drawn ``1 + f / (1 - f) * buffer / new`` times as often
as an older one (``f = newest_fraction``; with the defaults and 10 solves per round, ~2x after 10 rounds, ~11x
after the first). If no solve of the round succeeded, the whole minibatch comes from the buffer.

**Loss.** In the network's standardised units (``y = (V - out_mean) / out_std``, ``z = (x - in_mean) / in_std``)::

    loss = mean_i (y_i - yhat_i)^2 + w * mean_i mean_j ((dV/dx_ij - dVhat/dx_ij) * in_std_j / out_std)^2

i.e. the Sobolev term compares ``dy/dz`` (the gradient the network actually fits), averaged over coordinates, so
``w`` weighs one standardised gradient coordinate like the standardised value; knots whose gradient label is not
finite only enter the value term. ``w = 0`` is plain MSE.

**Labels far from the pretraining set** (closed-loop tails). ``loss.value_cap`` clips labels (their gradient labels are
dropped), ``loss.grad_label_max`` drops gradient labels whose standardised norm is extreme, and ``loss.renormalize``
moves the standardisation to the whole buffer after each round's solves without changing the network's function
(:meth:`ValueNetwork.renormalize`, PopArt). ``refit.steps`` finally fits a fresh network to the whole buffer
(docs/experiments/closed-loop.md measures all four).

**Metrics** (``metrics.json`` / ``metrics.csv``): after pretraining, after every round (and every
``schedule.eval_every`` training steps if set): ``solves`` (budget solves so far), ``train_steps`` (after pretraining),
``mse_initial`` (the validation starts at their full ``tau``), ``mse_all_knots`` (every per-knot label of the successful
validation solves), ``failures`` (failed budget solves so far). MSEs are in the task's cost units squared.

**Determinism and resume.** Every random stream is a fresh ``np.random.default_rng([seed, stream, round])``; torch
runs in float64 with a fixed thread count and draws nothing from its global RNG after the seeded initialisation.
After each round a checkpoint (network, Adam state, start-pool position, next solve index, metrics) is written
atomically. ``train(config, out, resume=True)`` restores it, re-runs the interrupted round from its start, and reuses
the records that round had already stored (their requests are checked bit for bit), so a run killed at any moment
and resumed ends with the same dataset and the same weights as an uninterrupted one, whatever ``runtime.workers`` is.
"""

from __future__ import annotations

import csv
import functools
import io
import json
import os
import shutil
import warnings
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from seagul_control._io import atomic_write_text
from seagul_envs import Task
from seagul_envs.tasks import BUILTIN_TASKS, make_task
from seagul_envs.tasks.profile import ValidationSpec
from seagul_learn.checkpoint import CHECKPOINT_FORMAT, keep_best, load_checkpoint, save_checkpoint
from seagul_learn.closed_loop import ClosedLoopOptions, ClosedLoopSampler
from seagul_learn.config import (
    SAMPLERS,
    LossConfig,
    NetworkConfig,
    RefitConfig,
    RuntimeConfig,
    ScheduleConfig,
    SelectionConfig,
    TrainConfig,
)
from seagul_learn.dataset import Dataset, SolveRecord, TrainingArrays, count_failures, training_arrays
from seagul_learn.fitting import (
    STREAM_ADVERSARIAL_ORDER,
    STREAM_BASELINE_STARTS,
    STREAM_PRETRAIN_BATCHES,
    STREAM_PRETRAIN_STARTS,
    STREAM_ROUND_BATCHES,
    Metric,
    Trainer,
    capped,
    evaluate,
    make_network,
    rng,
    training_loss,
)
from seagul_learn.fitting import (
    _as_tensors as fitting_as_tensors,
)
from seagul_learn.refit import candidates_key, refit, refit_and_select
from seagul_learn.round_selection import deploy_selected, select_kept_round
from seagul_learn.samplers import (
    AdversarialOptions,
    AdversarialSampler,
    Sampler,
    StartPool,
    UniformOptions,
    UniformSampler,
)
from seagul_learn.solving import BatchSolver, SolveRunner, solver_key, trajopt_batch_solver
from seagul_learn.validation import default_cache_dir, validation_dataset, validation_robots
from seagul_learn.value_network import ValueModel, ValueNetwork

__all__ = [
    "CHECKPOINT_FORMAT",
    "SAMPLERS",
    "AdversarialOptions",
    "ClosedLoopOptions",
    "LossConfig",
    "Metric",
    "NetworkConfig",
    "RefitConfig",
    "RuntimeConfig",
    "ScheduleConfig",
    "SelectionConfig",
    "TrainConfig",
    "TrainResult",
    "UniformOptions",
    "ValidationSpec",
    "candidates_key",
    "default_cache_dir",
    "evaluate",
    "make_network",
    "plot_metrics",
    "refit",
    "refit_and_select",
    "train",
    "training_loss",
    "validation_dataset",
    "validation_robots",
]

# Private names of earlier versions, kept for code that imported them (tests, notebooks).
_Trainer = Trainer
_rng = rng
_capped = capped
_as_tensors = fitting_as_tensors
_keep_best = keep_best
_save_checkpoint = save_checkpoint
_load_checkpoint = load_checkpoint


# ----------------------------------------------------------------------------------------------- validation set
# ``ValidationSpec`` lives in seagul_envs.tasks.profile (imported above, so ``seagul_learn.training.ValidationSpec``
# still works): each task's validation set is ``task.profile.validation_spec(task)``, the built-ins' set in their
# task modules (docs/reference/spec.md §3.6, §4.6). ``VALIDATION_SPECS`` remains as a deprecated view of the built-in
# tasks'.
def __getattr__(name: str) -> Any:
    """``VALIDATION_SPECS``: a deprecated name-keyed view of the built-in tasks' validation sets."""
    if name == "VALIDATION_SPECS":
        warnings.warn(
            "seagul_learn.training.VALIDATION_SPECS is deprecated; use task.profile.validation_spec(task)",
            DeprecationWarning,
            stacklevel=2,
        )
        return {n: make_task(n).profile.validation_spec(make_task(n)) for n in sorted(BUILTIN_TASKS)}
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


@dataclass
@dataclass
class TrainResult:
    """What :func:`train` returns (everything is also on disk in the run directory)."""

    network: ValueModel
    metrics: list[Metric]
    out_dir: Path
    num_solves: int
    num_failures: int
    dataset: Dataset = field(repr=False)


def _make_sampler(config: TrainConfig, task: Task) -> Sampler:
    """The run's sampler over the uniform baseline's starts (and, with ``model_params``, robots) for this seed."""
    pool = StartPool.uniform(
        task, config.budget, rng(config.seed, STREAM_BASELINE_STARTS), config.uniform_tau, config.model_params
    )
    options = config.sampler
    if isinstance(options, ClosedLoopOptions):
        return ClosedLoopSampler(task, pool, options, seed=config.seed)
    if isinstance(options, AdversarialOptions):
        return AdversarialSampler(task, pool.shuffled(rng(config.seed, STREAM_ADVERSARIAL_ORDER)), options)
    return UniformSampler(task, pool)


# --------------------------------------------------------------------------------------------------- the loop
def train(
    config: TrainConfig,
    out_dir: str | os.PathLike[str],
    resume: bool = False,
    batch_solver: BatchSolver | None = None,
    solver_name: str | None = None,
) -> TrainResult:
    """Run (or resume) SEAGuL training into ``out_dir``; see the module docstring.

    ``config.task`` is a registered name or a Task object (resolved once, here; the object is what the solver's
    workers get). ``batch_solver`` replaces the trajectory optimizer (tests inject a toy); ``solver_name`` then
    names it in the validation-cache key. Outputs: ``config.json`` (with the task's name and fingerprint),
    ``dataset/``, ``checkpoint.pt``, ``network.pt``, ``metrics.json``, ``metrics.csv``, ``validation.png``.

    Raises:
        ValueError: a bad configuration, or ``resume`` of a run made with another configuration or with a task of
            another fingerprint (same name, other content).
    """
    config.validate_values()
    out = Path(out_dir)
    task = config.resolve_task()
    if batch_solver is None:
        batch_solver = trajopt_batch_solver(
            task, workers=config.runtime.workers, backend=config.runtime.backend, solver_options=config.solver_options
        )
        solver_name = solver_key(config.solver_options, task)
    solver_name = solver_name or "custom"
    _prepare_run_dir(out, config, resume, task)

    previous_threads = torch.get_num_threads()
    torch.set_num_threads(config.runtime.torch_threads)
    try:
        return _train(config, out, task, batch_solver, solver_name)
    finally:
        torch.set_num_threads(previous_threads)


class _OtherTask(Exception):
    """The stored run config names another task (raised and caught inside :func:`_prepare_run_dir`)."""


def _prepare_run_dir(out: Path, config: TrainConfig, resume: bool, task: Task) -> None:
    config_path = out / "config.json"
    if out.exists() and not out.is_dir():
        raise FileExistsError(f"run directory {str(out)!r} is a file, not a directory; choose a directory for the run")
    if config_path.is_file():
        if not resume:
            raise FileExistsError(
                f"run directory {str(out)!r} already holds a run; pass resume=True (--resume) or choose a new one"
            )
        try:
            data = json.loads(config_path.read_text())
            stored_fingerprint = data.pop("task_fingerprint", None)
            if data.get("task") != task.name:
                raise _OtherTask(data.get("task"))
            stored = TrainConfig.from_dict(data, task=task).result_fields()
        except _OtherTask as other:
            raise ValueError(
                f"cannot resume {str(out)!r} with a different configuration (task: stored {other.args[0]!r} vs "
                f"{task.name!r})"
            ) from None
        except (ValueError, TypeError, AttributeError) as exc:
            raise ValueError(f"cannot resume: {str(config_path)!r} is not a valid run config ({exc})") from exc
        if stored_fingerprint is not None and stored_fingerprint != task.fingerprint():
            raise ValueError(
                f"cannot resume {str(out)!r}: it was trained on task {task.name!r} with fingerprint "
                f"{stored_fingerprint}, and the task given now has fingerprint {task.fingerprint()} (same name, other "
                "content: a parameter, bound, cost or setting differs); resume with the task the run was made with, "
                "or start a new run directory"
            )
        wanted, stored = _dotted(config.result_fields()), _dotted(stored)
        diff = sorted(
            k for k in wanted.keys() | stored.keys() if json.dumps(wanted.get(k)) != json.dumps(stored.get(k))
        )
        if diff:
            details = ", ".join(f"{k}: stored {stored.get(k)!r} vs {wanted[k]!r}" for k in diff)
            raise ValueError(f"cannot resume {str(out)!r} with a different configuration ({details})")
    elif out.exists() and any(p.name != ".gitkeep" for p in out.iterdir()):
        raise FileExistsError(f"run directory {str(out)!r} exists and is not a seagul run; choose a new one")
    out.mkdir(parents=True, exist_ok=True)
    payload = {**config.to_dict(), "task_fingerprint": task.fingerprint()}
    atomic_write_text(config_path, json.dumps(payload, indent=2, sort_keys=True))


def _dotted(data: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested config data as ``{"part.field": value}`` (a resume's differences are named field by field)."""
    out: dict[str, Any] = {}
    for key, value in data.items():
        if isinstance(value, dict) and key != "solver_options":
            out.update(_dotted(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def _train(config: TrainConfig, out: Path, task: Task, batch_solver: BatchSolver, solver_name: str) -> TrainResult:
    chunk = max(1, config.runtime.workers)
    validation: TrainingArrays | None = None
    if config.validate:
        val_records = validation_dataset(
            task,
            batch_solver,
            solver_name,
            config.runtime.cache_dir or default_cache_dir(),
            chunk,
            config.runtime.progress,
            model_params=config.model_params,
        )
        validation = training_arrays(val_records, task.nx)
        if len(validation) == 0:
            raise RuntimeError(f"no validation solve of {task.name} succeeded; check the solver settings")

    dataset = Dataset.open(out / "dataset", task.name, meta={"solver": solver_name, "seed": config.seed})
    runner = SolveRunner(batch_solver, dataset, next_index=0, chunk_size=chunk)
    sampler = _make_sampler(config, task)
    network = make_network(config, task)
    trainer = Trainer(config, network, validation)
    checkpoint_path = out / "checkpoint.pt"

    # Pretraining: identical for every sampler and Sobolev weight of this seed (only the value loss).
    pool = StartPool.uniform(
        task,
        config.schedule.pretrain_solves,
        rng(config.seed, STREAM_PRETRAIN_STARTS),
        model_params=config.model_params,
    )
    pre_records = runner.solve(pool.starts, pool.taus, "pretrain", thetas=pool.thetas)
    buffer = training_arrays(pre_records, task.nx)
    if len(buffer) == 0:
        raise RuntimeError(f"all {config.schedule.pretrain_solves} pretraining solves of {task.name} failed")
    budget_records: list[SolveRecord] = []
    rounds_done = 0

    if checkpoint_path.is_file():
        state = load_checkpoint(checkpoint_path)
        network.load_state_dict(state["network"])
        trainer.optimizer.load_state_dict(state["optimizer"])
        trainer.train_steps = int(state["train_steps"])
        trainer.metrics = [Metric(**m) for m in state["metrics"]]
        rounds_done = int(state["rounds_done"])
        sampler.pool.position = int(state["pool_position"])
        if "sampler_state" in state and hasattr(sampler, "load_state_dict"):
            sampler.load_state_dict(json.loads(state["sampler_state"]))
        runner.next_index = int(state["next_index"])
        budget_records = [dataset.read(i) for i in range(config.schedule.pretrain_solves, runner.next_index)]
        new = training_arrays(budget_records, task.nx)
        buffer = buffer.concat(new)
    else:
        network.set_normalization(buffer.x, buffer.tau, buffer.value, buffer.theta)
        pre_cfg = replace(
            config,
            loss=replace(config.loss, sobolev_weight=0.0),
            schedule=replace(config.schedule, newest_fraction=0.0),
        )
        Trainer(pre_cfg, network, None).train(
            buffer,
            np.zeros(0, dtype=np.int64),
            config.schedule.pretrain_steps,
            rng(config.seed, STREAM_PRETRAIN_BATCHES),
            count_steps=False,
        )
        trainer.optimizer = torch.optim.Adam(network.parameters(), lr=config.schedule.lr)  # fresh Adam for the rounds
        trainer.record_metric(0, 0, config.schedule.pretrain_solves)
        save_checkpoint(checkpoint_path, trainer, 0, sampler, runner.next_index)

    closed_loop = config.closed_loop_options()  # the defaults (no collecting refit, no best kept) for the others
    bar = tqdm(
        total=config.num_rounds,
        initial=rounds_done,
        desc=f"{config.sampler.name} {task.name}",
        unit="round",
        disable=not config.runtime.progress,
    )
    for round_index in range(rounds_done, config.num_rounds):
        n_new = min(config.schedule.solves_per_round, config.budget - round_index * config.schedule.solves_per_round)
        if hasattr(sampler, "observe"):
            sampler.observe(buffer)
        collecting: ValueModel = network
        if closed_loop.collect_refit and getattr(sampler, "collects_deployed", lambda n: False)(n_new):
            # Deterministic from (buffer, seed, round): a resumed run recomputes the same collecting network.
            collecting = refit(config, task, buffer, Trainer(config, network, None), round_index=round_index)
        records = sampler.sample(n_new, collecting, runner)
        if closed_loop.keep_best:
            spent = config.schedule.pretrain_solves + len(budget_records)
            keep_best(out, config, getattr(sampler, "log", []), collecting, spent)
        budget_records += records
        new = training_arrays(records, task.nx)
        newest = np.arange(len(buffer), len(buffer) + len(new))
        buffer = buffer.concat(new)
        solves, failures = len(budget_records), count_failures(budget_records)
        buffer_solves = config.schedule.pretrain_solves + solves
        if config.loss.renormalize:
            network.renormalize(
                buffer.x,
                buffer.tau,
                capped(buffer.value, config.loss.value_cap, config.loss.value_compress),
                buffer.theta,
            )
        trainer.train(
            buffer,
            newest,
            config.schedule.train_steps_per_round,
            rng(config.seed, STREAM_ROUND_BATCHES, round_index),
            count_steps=True,
            on_eval=functools.partial(trainer.record_metric, solves, failures, buffer_solves),
        )
        if (
            not trainer.metrics
            or trainer.metrics[-1].train_steps != trainer.train_steps
            or (trainer.metrics[-1].solves != solves)
        ):
            trainer.record_metric(solves, failures, buffer_solves)
        save_checkpoint(checkpoint_path, trainer, round_index + 1, sampler, runner.next_index)
        if solves in config.runtime.snapshots:
            best = out / "network_best.pt"
            if closed_loop.keep_best and best.is_file():
                shutil.copyfile(best, out / f"network_{solves}.pt")  # the method at this budget: the best so far
            else:
                network.save(out / f"network_{solves}.pt")
        bar.set_postfix(mse_initial=f"{trainer.metrics[-1].mse_initial:.3g}", failures=failures)
        bar.update(1)
    bar.close()

    if config.refit.steps:
        network.save(out / "network_loop.pt")
        if config.refit.candidates:
            network = refit_and_select(config, task, buffer, trainer, out)
        else:
            network = refit(config.final_refit_config(), task, buffer, trainer)
        trainer.record_metric(
            len(budget_records), count_failures(budget_records), config.schedule.pretrain_solves + len(budget_records)
        )
    if closed_loop.keep_best and config.selection.rounds:
        deploy_selected(out, select_kept_round(config, task, out))
        if config.budget in config.runtime.snapshots:  # the method at the full budget is the selected network
            shutil.copyfile(out / "network_best.pt", out / f"network_{config.budget}.pt")
    if closed_loop.keep_best and (out / "network_best.pt").is_file():
        network.save(out / "network_last.pt")
        network = ValueNetwork.load(out / "network_best.pt")
    network.save(out / "network.pt")
    _write_metrics(out, trainer.metrics, config, getattr(sampler, "log", None))
    return TrainResult(network, trainer.metrics, out, len(budget_records), count_failures(budget_records), dataset)


# ----------------------------------------------------------------------------------------------------- outputs
def _write_metrics(
    out: Path, metrics: list[Metric], config: TrainConfig, sampler_log: list[dict[str, Any]] | None = None
) -> None:
    rows = [asdict(m) for m in metrics]
    payload: dict[str, Any] = {"config": config.to_dict(), "metrics": rows}
    if sampler_log is not None:
        payload["sampler_log"] = sampler_log
    atomic_write_text(out / "metrics.json", json.dumps(payload, indent=2, allow_nan=True))
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=list(rows[0]) if rows else [f.name for f in fields(Metric)])
    writer.writeheader()
    writer.writerows(rows)
    atomic_write_text(out / "metrics.csv", text.getvalue())
    plot_metrics(
        metrics, out / "validation.png", title=f"{config.task_name}: {config.sampler.name} (seed {config.seed})"
    )


def plot_metrics(metrics: list[Metric], path: str | os.PathLike[str], title: str = "") -> None:
    """PNG of both validation MSEs vs solves and vs training steps (matplotlib Agg, headless)."""
    # matplotlib only when a plot is drawn: it is slow to import and selects its backend (Agg) on first use.
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    for ax, key in zip(axes, ("solves", "train_steps"), strict=True):
        xs = [getattr(m, key) for m in metrics]
        ax.plot(xs, [m.mse_initial for m in metrics], marker="o", ms=3, label="mse_initial (starts, full tau)")
        ax.plot(xs, [m.mse_all_knots for m in metrics], marker="s", ms=3, label="mse_all_knots")
        ax.set_xlabel("solves" if key == "solves" else "training steps")
        ax.set_ylabel("validation MSE")
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend()
    if title:
        fig.suptitle(title)
    fig.savefig(path, dpi=100)
    plt.close(fig)
