"""Training loop (Alg. 2) on the toy solver: budgets, identical starts, determinism, exact resume, outputs."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import torch
from toy_problem import ToySolver

from seagul_envs import make_task
from seagul_learn.dataset import Dataset
from seagul_learn.training import (
    AdversarialOptions,
    LossConfig,
    NetworkConfig,
    RefitConfig,
    RuntimeConfig,
    ScheduleConfig,
    TrainConfig,
    ValidationSpec,
    train,
    training_loss,
    validation_dataset,
)
from seagul_learn.value_network import ValueNetwork

ALL_TASKS = r"\['acrobot', 'dmc_acrobot', 'dmc_cartpole', 'dmc_pendulum', 'glider'\]"
"""The message's list of every registered task (the built-ins, the suite's tasks included)."""


def _config(tmp_path, **overrides) -> TrainConfig:
    """A small run; ``overrides`` name fields, or fields of a part as ``part__field`` (``loss__sobolev_weight``)."""
    base = TrainConfig(
        task=overrides.pop("task", "acrobot"),
        sampler=AdversarialOptions(max_steps=3),
        budget=12,
        schedule=ScheduleConfig(
            solves_per_round=5, train_steps_per_round=15, batch_size=32, pretrain_solves=4, pretrain_steps=10
        ),
        seed=0,
        runtime=RuntimeConfig(cache_dir=str(tmp_path / "cache"), progress=False),
    )
    return base.replaced(**{k.replace("__", "."): v for k, v in overrides.items()})


def _run(tmp_path, name: str, toy: ToySolver | None = None, resume: bool = False, **overrides):
    toy = toy or ToySolver(make_task(overrides.get("task", "acrobot")), fail_above=np.pi + 0.25)
    return train(_config(tmp_path, **overrides), tmp_path / name, resume=resume, batch_solver=toy, solver_name="toy")


def _dataset_arrays(ds: Dataset) -> list[dict[str, np.ndarray]]:
    return [r.to_arrays() for r in ds.records()]


def _assert_same_datasets(a: Dataset, b: Dataset) -> None:
    ra, rb = _dataset_arrays(a), _dataset_arrays(b)
    assert len(ra) == len(rb)
    for x, y in zip(ra, rb, strict=True):
        for key in x:
            if key != "solve_time":
                np.testing.assert_array_equal(x[key], y[key], err_msg=key)


def _weights(net: ValueNetwork) -> np.ndarray:
    return net.casadi_parameters()


@pytest.mark.parametrize("sampler", ["uniform", "adversarial"])
def test_budget_is_exact_and_failures_are_recorded(tmp_path, sampler):
    task = make_task("acrobot")
    toy = ToySolver(task, fail_above=np.pi + 0.2)
    result = _run(tmp_path, "run", toy=toy, sampler=sampler)
    records = result.dataset.records()
    budget_recs = [r for r in records if r.sampler != "pretrain"]
    assert len(budget_recs) == 12 == result.num_solves
    assert [r.index for r in records] == list(range(16))
    failures = sum(not r.success for r in budget_recs)
    assert result.num_failures == failures == result.metrics[-1].failures
    assert [m.solves for m in result.metrics] == [0, 5, 10, 12]
    assert [m.train_steps for m in result.metrics] == [0, 15, 30, 45]
    # validation solves (200, cached) + pretraining + budget, nothing else
    assert toy.num_solves == 200 + 4 + 12


def test_both_samplers_start_from_identical_parameters_and_the_baseline_starts(tmp_path):
    uni = _run(tmp_path, "u", sampler="uniform")
    adv = _run(tmp_path, "a", sampler="adversarial")
    sob = _run(tmp_path, "s", sampler="uniform", loss__sobolev_weight=1.0)
    first = {(m.mse_initial, m.mse_all_knots) for m in (uni.metrics[0], adv.metrics[0], sob.metrics[0])}
    assert len(first) == 1  # identical pretrained network
    uniform_starts = {tuple(r.x_init) for r in uni.dataset.records() if r.sampler == "uniform"}
    chain_starts = [tuple(r.x_init) for r in adv.dataset.records() if r.sampler == "adversarial" and r.step == 0]
    assert chain_starts and all(s in uniform_starts for s in chain_starts)
    assert any(r.step > 0 for r in adv.dataset.records())
    assert not np.array_equal(_weights(uni.network), _weights(adv.network))


def test_training_reduces_validation_error(tmp_path):
    result = _run(
        tmp_path,
        "r",
        sampler="uniform",
        budget=20,
        schedule__train_steps_per_round=400,
        schedule__batch_size=64,
        schedule__lr=3e-3,
    )
    assert result.metrics[-1].mse_all_knots < 0.3 * result.metrics[0].mse_all_knots
    assert result.metrics[-1].mse_initial < 0.3 * result.metrics[0].mse_initial


def test_same_seed_same_dataset_and_weights_different_seed_differs(tmp_path):
    a = _run(tmp_path, "a", loss__sobolev_weight=0.5)
    b = _run(tmp_path, "b", loss__sobolev_weight=0.5, runtime__workers=2)  # worker count never changes results
    _assert_same_datasets(a.dataset, b.dataset)
    np.testing.assert_array_equal(_weights(a.network), _weights(b.network))
    c = _run(tmp_path, "c", loss__sobolev_weight=0.5, seed=1)
    assert not np.array_equal(_weights(a.network), _weights(c.network))


@pytest.mark.parametrize("crash_after", [2, 7, 13])  # inside pretraining, mid-round, last round
@pytest.mark.parametrize("sampler", ["uniform", "adversarial"])
def test_resume_after_interruption_matches_uninterrupted_run(tmp_path, crash_after, sampler):
    task = make_task("acrobot")
    reference = _run(tmp_path, "ref", sampler=sampler)
    # the validation set is cached by the reference run; the crash counts training solves only
    crashing = ToySolver(task, fail_above=np.pi + 0.25, raise_after=crash_after)
    with pytest.raises(KeyboardInterrupt):
        _run(tmp_path, "run", toy=crashing, sampler=sampler)
    assert len(Dataset.open(tmp_path / "run" / "dataset")) == crash_after
    resumed_toy = ToySolver(task, fail_above=np.pi + 0.25)
    resumed = _run(tmp_path, "run", toy=resumed_toy, resume=True, sampler=sampler)
    assert resumed_toy.num_solves == 16 - crash_after  # nothing solved twice, nothing lost
    _assert_same_datasets(reference.dataset, resumed.dataset)
    np.testing.assert_array_equal(_weights(reference.network), _weights(resumed.network))
    ref_metrics = [(m.solves, m.train_steps, m.mse_initial) for m in reference.metrics]
    assert [(m.solves, m.train_steps, m.mse_initial) for m in resumed.metrics] == ref_metrics


def test_resume_of_a_finished_run_is_a_no_op(tmp_path):
    first = _run(tmp_path, "r")
    toy = ToySolver(make_task("acrobot"))
    again = _run(tmp_path, "r", toy=toy, resume=True)
    assert toy.num_solves == 0
    np.testing.assert_array_equal(_weights(first.network), _weights(again.network))


def test_run_directory_guards(tmp_path):
    _run(tmp_path, "r")
    with pytest.raises(FileExistsError, match=r"already holds a run.*resume"):
        _run(tmp_path, "r")
    with pytest.raises(ValueError, match=r"different configuration \(budget: stored 12"):
        _run(tmp_path, "r", resume=True, budget=13)
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "file.txt").write_text("x")
    with pytest.raises(FileExistsError, match="not a seagul run"):
        _run(tmp_path, "other")


def test_outputs_are_written(tmp_path):
    result = _run(tmp_path, "r", task="glider", sampler="adversarial", schedule__eval_every=5)
    out = tmp_path / "r"
    net = ValueNetwork.load(out / "network.pt")
    assert net.task_name == "glider"
    np.testing.assert_array_equal(net.casadi_parameters(), _weights(result.network))
    data = json.loads((out / "metrics.json").read_text())
    keys = {"solves", "train_steps", "mse_initial", "mse_all_knots", "failures"}
    assert keys <= set(data["metrics"][0]) and data["config"]["task"] == "glider"
    assert [m["train_steps"] for m in data["metrics"]] == [0, 5, 10, 15, 20, 25, 30, 35, 40, 45]
    assert (out / "metrics.csv").read_text().startswith("solves,train_steps,mse_initial")
    assert (out / "validation.png").read_bytes()[:4] == b"\x89PNG"
    glider_taus = {r.tau for r in result.dataset.records()}
    assert all(0.75 - 1e-12 <= t <= 0.85 + 1e-12 for t in glider_taus)


def test_validation_set_is_cached_and_follows_the_spec(tmp_path):
    task = make_task("acrobot")
    toy = ToySolver(task)
    records = validation_dataset(task, toy, "toy", tmp_path)
    assert len(records) == 200 and toy.num_solves == 200
    starts = np.array([r.x_init for r in records])
    assert np.all(starts[:100, 2:] == 0.0)  # the grid is at zero velocity
    assert len(np.unique(starts[:100, 0])) == 10 and len(np.unique(starts[:100, 1])) == 10
    assert all(task.in_x0(x) for x in starts)
    again = ToySolver(task)
    assert len(validation_dataset(task, again, "toy", tmp_path)) == 200 and again.num_solves == 0
    other = ToySolver(task)
    validation_dataset(task, other, "toy-v2", tmp_path)  # other solver settings: another cache entry
    assert other.num_solves == 200
    glider = make_task("glider")
    small = ValidationSpec(grid_coords=(0, 1, 4), grid_points=2, num_random=3)
    g = validation_dataset(glider, ToySolver(glider), "toy", tmp_path, spec=small)
    assert len(g) == 11 and all(r.tau == 0.8 for r in g)


def test_a_complete_validation_set_is_read_once_per_process_and_again_after_it_changes(tmp_path, monkeypatch):
    task = make_task("acrobot")
    small = ValidationSpec(grid_coords=(0, 1), grid_points=2, num_random=3)
    first = validation_dataset(task, ToySolver(task), "toy", tmp_path, spec=small)
    reads: list[int] = []
    real_read = Dataset.read
    monkeypatch.setattr(Dataset, "read", lambda self, i: reads.append(i) or real_read(self, i))
    again = validation_dataset(task, ToySolver(task), "toy", tmp_path, spec=small)
    assert reads == [] and len(again) == len(first) == 7
    for a, b in zip(first, again, strict=True):
        for key, value in a.to_arrays().items():
            np.testing.assert_array_equal(b.to_arrays()[key], value, err_msg=key)
    # A record removed from the cache is solved again and the whole set re-read from disk.
    (folder,) = tmp_path.glob("validation-acrobot-*")
    sorted((folder / "records").glob("*.npz"))[0].unlink()
    toy = ToySolver(task)
    third = validation_dataset(task, toy, "toy", tmp_path, spec=small)
    assert toy.num_solves == 1 and sorted(reads) == list(range(7)) and len(third) == 7


def test_sobolev_term_matches_its_definition():
    task = make_task("acrobot")
    net = ValueNetwork(4, seed=0)
    rng = np.random.default_rng(0)
    x = task.sample_x0(rng, 8)
    tau = rng.uniform(0, 5, 8)
    net.set_normalization(x, tau, rng.normal(10, 3, 8))
    _, own_grad, _ = net.value_and_grad(x, tau)
    batch = {
        "x": torch.tensor(x),
        "tau": torch.tensor(tau),
        "value": torch.tensor(rng.normal(10, 3, 8)),
        "grad_x": torch.tensor(own_grad),
        "grad_ok": torch.ones(8, dtype=torch.bool),
    }
    plain = training_loss(net, batch, 0.0).item()
    assert training_loss(net, batch, 3.0).item() == pytest.approx(plain, rel=1e-12)
    shifted = dict(batch, grad_x=batch["grad_x"] + 0.5)
    expected = np.mean((0.5 * net.in_std[:4].numpy() / net.out_std.item()) ** 2)
    assert training_loss(net, shifted, 3.0).item() == pytest.approx(plain + 3.0 * expected, rel=1e-10)
    masked = dict(shifted, grad_ok=torch.zeros(8, dtype=torch.bool))
    assert training_loss(net, masked, 3.0).item() == pytest.approx(plain, rel=1e-12)


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ({"task": "pendulum"}, r"unknown task 'pendulum'; available tasks: " + ALL_TASKS),
        ({"sampler": "greedy"}, "unknown sampler 'greedy'"),
        ({"budget": 0}, "budget must be >= 1"),
        ({"runtime__workers": 0}, r"runtime\.workers must be >= 1"),
        ({"loss__sobolev_weight": -1.0}, r"loss\.sobolev_weight must be >= 0"),
        ({"sampler__projection": "wrap"}, "sampler: projection must be 'clip' or 'reflect'"),
        ({"runtime__backend": "dask"}, r"unknown runtime\.backend 'dask'"),
        ({"sampler__episode": 3}, "unknown TrainConfig field 'sampler.episode': no sampler has a field 'episode'"),
        ({"network__hidden": (32, 0)}, r"network\.hidden must be positive layer widths"),
    ],
)
def test_bad_config_is_named(tmp_path, override, message):
    with pytest.raises(ValueError, match=message):
        _config(tmp_path, **override)


_CHILD = """
import sys, time
sys.path.insert(0, {tests!r})
import numpy as np
from toy_problem import ToySolver
from seagul_envs import make_task
from seagul_learn.training import TrainConfig, train

class SlowToy(ToySolver):
    def solve(self, x, tau=None):
        time.sleep(0.02)
        return super().solve(x, tau)

config = TrainConfig.from_dict({config!r})
train(config, {out!r}, resume=True, batch_solver=SlowToy(make_task("acrobot"), fail_above=np.pi + 0.25),
      solver_name="toy")
"""


@pytest.mark.parametrize(
    "kill_at", [pytest.param(3, marks=pytest.mark.slow), 9, pytest.param(14, marks=pytest.mark.slow)]
)
def test_sigkill_at_any_moment_then_resume_matches(tmp_path, kill_at):
    """A real process killed with SIGKILL (no cleanup at all) resumes to the same dataset and weights."""
    import os
    import signal
    import subprocess
    import sys
    import time
    from pathlib import Path

    reference = _run(tmp_path, "ref", sampler="adversarial")  # also fills the validation cache
    config = _config(tmp_path, sampler="adversarial").to_dict()
    out = tmp_path / "killed"
    script = _CHILD.format(tests=str(Path(__file__).parent), config=config, out=str(out))
    child = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    records = out / "dataset" / "records"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and child.poll() is None:
        if records.is_dir() and len(list(records.glob("solve-*.npz"))) >= kill_at:
            break
        time.sleep(0.005)
    assert child.poll() is None, child.stderr.read().decode() if child.stderr else ""
    os.kill(child.pid, signal.SIGKILL)
    child.wait()
    resumed = _run(tmp_path, "killed", resume=True, sampler="adversarial")
    _assert_same_datasets(reference.dataset, resumed.dataset)
    np.testing.assert_array_equal(_weights(reference.network), _weights(resumed.network))


# ------------------------------------------------------------------------ labels far from the pretraining set
def test_renormalize_keeps_the_function_and_moves_the_statistics():
    rng = np.random.default_rng(3)
    x, tau, value = rng.normal(size=(64, 4)), rng.uniform(1, 3, 64), rng.normal(size=64)
    net = ValueNetwork(4, (8, 8), seed=0)
    net.set_normalization(x, tau, value)
    with torch.no_grad():  # make the layers non-trivial
        for p in net.parameters():
            p.add_(0.3 * torch.randn_like(p))
    before = net.predict(x, tau)
    _, grad_before, _ = net.value_and_grad(x, tau)
    net.renormalize(5 * x + 2, 3 * tau, 40 * value + 7)
    np.testing.assert_allclose(net.predict(x, tau), before, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(net.value_and_grad(x, tau)[1], grad_before, rtol=1e-10, atol=1e-12)
    assert net.out_std.item() == pytest.approx(np.std(40 * value + 7))
    np.testing.assert_allclose(net.in_mean.numpy()[:4], (5 * x + 2).mean(axis=0))


def test_renormalize_follows_the_buffer_in_training(tmp_path):
    fixed = _run(tmp_path, "fixed", sampler="uniform")
    moving = _run(tmp_path, "moving", sampler="uniform", loss__renormalize=True)
    from seagul_learn.dataset import training_arrays

    buffer_values = training_arrays(moving.dataset.records()).value
    assert moving.network.out_std.item() == pytest.approx(np.std(buffer_values), rel=1e-9)
    pretrain = [r for r in fixed.dataset.records() if r.sampler == "pretrain"]
    assert fixed.network.out_std.item() == pytest.approx(np.std(training_arrays(pretrain).value), rel=1e-9)
    assert moving.metrics[0].mse_initial == fixed.metrics[0].mse_initial  # the pretraining is shared
    assert moving.metrics[-1].mse_initial != fixed.metrics[-1].mse_initial


def test_grad_label_max_drops_only_extreme_gradient_labels():
    from seagul_learn.dataset import TrainingArrays
    from seagul_learn.training import _as_tensors

    net = ValueNetwork(2, (4,), seed=0)
    arrays = TrainingArrays(
        x=np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 0.0]]),
        tau=np.ones(3),
        value=np.array([1.0, 2.0, 3.0]),
        grad_x=np.array([[0.1, 0.0], [100.0, 0.0], [np.nan, 0.0]]),
        solve_index=np.zeros(3, dtype=np.int64),
        knot=np.zeros(3, dtype=np.int64),
    )
    net.set_normalization(arrays.x, arrays.tau, arrays.value)
    kept = _as_tensors(arrays, 0.0, 10.0, net)["grad_ok"].tolist()
    assert kept == [True, False, False]  # the big label dropped; a NaN label was never used
    assert _as_tensors(arrays, 0.0, 0.0, net)["grad_ok"].tolist() == [True, True, False]
    with pytest.raises(ValueError, match="grad_label_max needs the network"):
        _as_tensors(arrays, 0.0, 10.0, None)


def test_value_compress_keeps_the_order_and_the_gradients_of_labels_above_the_cap():
    """``loss.value_compress``: below the cap labels are untouched; above it ``cap (1 + ln(V / cap))``, continuous
    with slope 1 at the cap and increasing, with the gradient labels scaled by ``cap / V`` (the compression's
    derivative: checked by finite differences) and kept, where clipping drops them; the refit key names it only when
    on."""
    from seagul_learn.dataset import TrainingArrays
    from seagul_learn.fitting import capped
    from seagul_learn.refit import candidates_key
    from seagul_learn.training import _as_tensors

    cap = 100.0
    value = np.array([10.0, 100.0, 150.0, 1e4])
    squashed = capped(value, cap, compress=True)
    assert squashed[:2].tolist() == [10.0, 100.0] and np.all(np.diff(squashed) > 0)
    assert squashed[3] == pytest.approx(cap * (1 + np.log(100.0)))
    np.testing.assert_array_equal(capped(value, cap), [10.0, 100.0, 100.0, 100.0])
    np.testing.assert_array_equal(capped(value, 0.0, compress=True), value)
    for v in (50.0, 100.0 + 1e-3, 150.0, 1e4):  # d/dV of the compression = cap / max(V, cap)
        fd = (capped(np.array([v + 1e-4]), cap, True) - capped(np.array([v - 1e-4]), cap, True))[0] / 2e-4
        assert fd == pytest.approx(cap / max(v, cap), rel=1e-5)

    arrays = TrainingArrays(
        x=np.zeros((4, 2)),
        tau=np.ones(4),
        value=value,
        grad_x=np.array([[1.0, 2.0]] * 4),
        solve_index=np.zeros(4, dtype=np.int64),
        knot=np.zeros(4, dtype=np.int64),
    )
    clipped = _as_tensors(arrays, cap)
    assert clipped["grad_ok"].tolist() == [True, True, False, False]
    compressed = _as_tensors(arrays, cap, compress=True)
    assert compressed["grad_ok"].tolist() == [True] * 4
    np.testing.assert_allclose(compressed["value"].numpy(), squashed)
    np.testing.assert_allclose(compressed["grad_x"].numpy()[:, 0], [1.0, 1.0, cap / 150.0, cap / 1e4])

    config = TrainConfig(task="acrobot", loss=LossConfig(value_cap=cap))
    on = replace(config, loss=LossConfig(value_cap=cap, value_compress=True))
    assert "value_compress" not in config.to_dict()["loss"] and on.to_dict()["loss"]["value_compress"] is True
    assert TrainConfig.from_dict(on.to_dict()) == on
    assert "value_compress" not in candidates_key(config, arrays)["refit"]
    assert candidates_key(on, arrays)["refit"]["value_compress"] is True


def test_refit_replaces_the_network_and_resumes_to_the_same_weights(tmp_path):
    task = make_task("acrobot")
    reference = _run(tmp_path, "ref", sampler="uniform", refit__steps=30, loss__value_cap=20.0, loss__renormalize=True)
    out = tmp_path / "ref"
    assert (out / "network_loop.pt").is_file()
    loop = ValueNetwork.load(out / "network_loop.pt")
    assert not np.array_equal(_weights(loop), _weights(reference.network))
    np.testing.assert_array_equal(_weights(ValueNetwork.load(out / "network.pt")), _weights(reference.network))
    assert reference.metrics[-1].train_steps == reference.metrics[-2].train_steps + 30
    # A run killed during the refit (every round checkpointed) resumes to the same network without a solve.
    import seagul_learn.training as training_module

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    opts = dict(sampler="uniform", refit__steps=30, loss__value_cap=20.0, loss__renormalize=True)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(training_module, "refit", interrupted)
        with pytest.raises(KeyboardInterrupt):
            _run(tmp_path, "run", **opts)
    toy = ToySolver(task, fail_above=np.pi + 0.25)
    resumed = _run(tmp_path, "run", toy=toy, resume=True, **opts)
    assert toy.num_solves == 0
    np.testing.assert_array_equal(_weights(reference.network), _weights(resumed.network))


def test_refit_ensemble_is_the_refit_script_s_ensemble_and_loads_as_one_file(tmp_path):
    """``refit.ensemble=2``: ``network.pt`` is a 2-member ValueEnsemble (the loop's stays one network) and equals
    the same refit made afterwards from the stored run (``training.refit`` with ``network.ensemble=2``), so a finished
    run can be refit as an ensemble later with the same result."""
    from seagul_learn.dataset import training_arrays
    from seagul_learn.training import _Trainer, make_network, refit
    from seagul_learn.value_network import ValueEnsemble

    with pytest.raises(ValueError, match=r"refit\.ensemble must be >= 0 and needs refit\.steps > 0"):
        RefitConfig(ensemble=2)
    result = _run(tmp_path, "ens", sampler="uniform", refit__steps=20, loss__value_cap=20.0, refit__ensemble=2)
    out = tmp_path / "ens"
    loaded = ValueNetwork.load(out / "network.pt")
    assert isinstance(loaded, ValueEnsemble) and len(loaded.networks) == 2
    assert not isinstance(ValueNetwork.load(out / "network_loop.pt"), ValueEnsemble)
    config = TrainConfig.from_run(out, task=make_task("acrobot"))
    later_config = replace(config, refit=RefitConfig(steps=20), network=NetworkConfig(ensemble=2))
    task = make_task("acrobot")
    buffer = training_arrays(result.dataset.records(), task.nx)
    later = refit(later_config, task, buffer, _Trainer(later_config, make_network(later_config, task), None))
    np.testing.assert_array_equal(later.casadi_parameters(), loaded.casadi_parameters())
    x = task.sample_x0(np.random.default_rng(0), 4)
    members = np.array([m.predict(x, np.full(4, 5.0)) for m in loaded.networks])
    np.testing.assert_allclose(loaded.predict(x, np.full(4, 5.0)), members.mean(axis=0), rtol=1e-6)
    assert not np.allclose(members[0], members[1])  # two fits from their own initial weights
