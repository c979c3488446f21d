"""The shipped controller of a task (``seagul_learn.shipped``): where its network and deployment come from, the
errors, and the report section of a task without one. The end-to-end checks (``seagul reproduce`` opens its report
with it, the ``experiment.json`` block, resume) are in ``tests/test_experiment.py`` on the smoke run."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from seagul_envs import make_task
from seagul_learn import shipped as shipped_mod
from seagul_learn.experiment import Experiment, ExperimentConfig, shipped_section
from seagul_learn.shipped import SHIPPED_RESULTS, ShippedNetworkMissing, shipped_network


def _acrobot_block() -> dict:
    return json.loads(SHIPPED_RESULTS.read_text())["acrobot"]


def _results(tmp_path: Path, blocks: dict) -> Path:
    path = tmp_path / "benchmarks" / "results" / "closed_loop.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(blocks))
    return path


def test_the_acrobot_ships_the_benchmarks_network_deployed_as_its_block_says() -> None:
    block = _acrobot_block()
    controller = shipped_network("acrobot")
    assert controller is not None
    assert controller.declared == block["network"] and controller.network.is_file()
    assert controller.network == (shipped_mod.REPO_ROOT / block["network"]).resolve()
    assert (controller.horizon, controller.trust_region, controller.goal_blend, controller.jit) == (
        block["horizon"],
        block["trust_region"],
        block["goal_blend"],
        block["jit"],
    )
    assert controller.measured["success_rate"] == block["success_rate"]
    spec = controller.spec("shipped MPC", jit=False)
    assert spec.kind == "mpc" and spec.path == str(controller.network)
    assert spec.option_dict() == {
        "horizon": block["horizon"],
        "trust_region": block["trust_region"],
        "goal_blend": block["goal_blend"],
        "jit": False,
    }
    assert controller.spec().option_dict()["jit"] == block["jit"]  # the benchmark's unless told otherwise


def test_a_missing_network_file_is_a_clear_error_naming_the_path(tmp_path: Path) -> None:
    results = _results(tmp_path, {"acrobot": {**_acrobot_block(), "network": "networks/gone_seed1.pt"}})
    with pytest.raises(ShippedNetworkMissing, match=r"'acrobot' is missing: .*'networks/gone_seed1\.pt'"):
        shipped_network("acrobot", results)
    assert issubclass(ShippedNetworkMissing, FileNotFoundError)


def test_a_declared_but_missing_network_stops_a_new_run_before_any_work(tmp_path: Path, monkeypatch) -> None:
    results = _results(tmp_path, {"acrobot": {**_acrobot_block(), "network": "networks/gone_seed1.pt"}})
    monkeypatch.setattr(shipped_mod, "SHIPPED_RESULTS", results)
    with pytest.raises(FileNotFoundError, match=r"gone_seed1\.pt"):
        Experiment.create(ExperimentConfig(task="acrobot", preset="smoke"), tmp_path / "run")
    assert not (tmp_path / "run").exists()


def test_tasks_without_a_block_variants_and_a_missing_results_file_have_none(tmp_path: Path) -> None:
    results = _results(tmp_path, {"acrobot": _acrobot_block(), "glider": {"method": "x", "network": None}})
    assert shipped_network("acrobot", results) is not None  # the relative path resolves against the repository
    assert shipped_network("glider", results) is None  # a block without a network
    assert shipped_network("acrobot", _results(tmp_path / "other", {})) is None
    assert shipped_network("acrobot", tmp_path / "nowhere.json") is None
    heavier = make_task("acrobot").with_params({"m2": 1.5})
    assert heavier.name == "acrobot" and shipped_network(heavier, results) is None  # not the network's robot


def test_a_block_without_its_deployment_is_an_error(tmp_path: Path) -> None:
    block = {k: v for k, v in _acrobot_block().items() if k != "trust_region"}
    with pytest.raises(ValueError, match=r"lacks \['trust_region'\]"):
        shipped_network("acrobot", _results(tmp_path, {"acrobot": block}))


def test_a_run_of_a_task_without_a_shipped_controller_says_so(tmp_path: Path, monkeypatch) -> None:
    """No block: the stage stores ``{"block": None}``, ``experiment.json`` gets no ``shipped`` block and the
    report's first section says the task has none."""
    monkeypatch.setattr(shipped_mod, "SHIPPED_RESULTS", _results(tmp_path, {}))
    experiment = Experiment.create(ExperimentConfig(task="acrobot", preset="smoke"), tmp_path / "run")
    result = experiment.evaluate_shipped()
    assert result["block"] is None and experiment.shipped is None
    assert json.loads((tmp_path / "run" / "shipped" / "shipped.json").read_text())["block"] is None
    experiment._save_state()
    assert "shipped" not in json.loads((tmp_path / "run" / "experiment.json").read_text())
    section = shipped_section(experiment.task, result)
    assert section.title.startswith("Shipped controller") and "has no shipped controller" in section.paragraphs[0]
    assert not section.tables and not section.figures


def test_the_animation_starts_from_the_hard_corner_of_x0() -> None:
    from seagul_learn.report import hard_start

    np.testing.assert_allclose(hard_start("acrobot"), [np.pi - 0.3, -0.3, 0.0, 0.0])


def test_the_benchmarks_block_is_what_the_shipped_controller_reads(tmp_path: Path, monkeypatch) -> None:
    """The block the closed-loop benchmark writes (``seagul_learn.experiment.benchmark.shipped_block``, with the keys
    ``run_task`` adds) carries every deployment and measured key :func:`shipped_network` reads, and deploys the
    network as the benchmark ran it."""
    from seagul_learn.experiment.benchmark import BenchConfig, shipped_block

    bench = BenchConfig.for_task("acrobot", quick=False)
    rows = [
        {"seed": s, "success_rate": r, "heldout_success_rate": r, "query_error": {"median": 1.0, "p95": 2.0}}
        for s, r in enumerate([0.5, 0.9, 0.7])
    ]
    network = shipped_network("acrobot").network
    timing = {"median_ms": 5.0, "p95_ms": 30.0, "steps": 10, "success_rate": 0.7}
    block = shipped_block(bench, rows, {"success_rate": 1.0, "heldout_success_rate": 0.9}, network, timing, 1000)
    added = {"network_seed", "budgets", "methods", "train_settings", "wall_s", "aggregated_from"}
    assert set(_acrobot_block()) - set(block) <= added  # the committed block's other keys come from run_task
    assert set(shipped_mod.DEPLOYMENT_KEYS) | set(shipped_mod.MEASURED_KEYS) <= set(block)
    assert block["network"] == _acrobot_block()["network"]  # relative to the repository
    monkeypatch.setattr(shipped_mod, "SHIPPED_RESULTS", _results(tmp_path, {"acrobot": block}))
    controller = shipped_network("acrobot")
    assert controller is not None and controller.network == network
    assert (controller.horizon, controller.trust_region, controller.goal_blend, controller.jit) == (
        bench.horizon,
        bench.trust_region,
        bench.goal_blend,
        bench.jit,
    )
    assert controller.measured["success_rate"] == 0.7 and controller.measured["seeds"] == 3
