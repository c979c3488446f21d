"""``benchmarks/results/dmc.json`` keeps its contract (one block per suite task with the learned MPC, the
full-horizon reference, SAC, PPO and the published scores), and ``benchmarks/dmc_contract`` builds those blocks from
the other benchmarks' result files without inventing anything."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks import dmc_contract  # noqa: E402
from seagul_control.dmc import DMC_TASKS  # noqa: E402
from seagul_envs import make_task  # noqa: E402

TASKS = ("acrobot-swingup", "cartpole-swingup", "pendulum-swingup")
LEARNED_KEYS = {"score_mean", "score_std", "seeds", "episodes", "solves", "horizon", "median_ms", "p95_ms", "network"}


@pytest.fixture(scope="module")
def dmc() -> dict[str, Any]:
    return json.loads((ROOT / "benchmarks" / "results" / "dmc.json").read_text())


def test_every_task_has_its_block(dmc: dict[str, Any]) -> None:
    for name in (*TASKS, "cartpole-swingup_sparse"):
        block = dmc[name]
        assert {"learned_mpc", "full_horizon", "sac", "ppo", "published", "classical"} <= set(block)
        assert block["env_id"] == f"dm_control/{name}-v0"
        for entry in block["published"]:
            assert {"method", "score", "env_steps", "source"} <= set(entry)
            assert 0 <= entry["score"] <= 1000 and entry["env_steps"] > 0
        for row in block["classical"]:
            assert row["mean"] == pytest.approx(np.mean(row["scores"]), abs=1e-3)
            assert row["seeds"] == dmc["seeds"]


def test_the_filled_blocks_have_the_contract_fields(dmc: dict[str, Any]) -> None:
    for name in TASKS:
        block = dmc[name]
        if block["learned_mpc"] is not None:
            learned = block["learned_mpc"]
            assert LEARNED_KEYS <= set(learned)
            assert (ROOT / learned["network"]).is_file()  # networks are committed
            assert learned["seeds"] >= 1 and learned["episodes"] >= 1
            scores = [s for n in learned["networks"] for s in n["scores"]]
            assert learned["score_mean"] == pytest.approx(np.mean(scores), abs=1e-3)
        if block["full_horizon"] is not None:
            assert {"score_mean", "score_std", "episodes"} <= set(block["full_horizon"])
        for algo in ("sac", "ppo"):
            if block[algo] is not None:
                assert {"score_mean", "score_std", "seeds", "env_steps"} <= set(block[algo])


def test_the_blocks_are_what_their_source_files_say(dmc: dict[str, Any]) -> None:
    """dmc.json's gathered blocks equal what dmc_contract reads from the committed source files now (nothing is
    edited by hand, nothing stale)."""
    for name in (*TASKS, "cartpole-swingup_sparse"):
        env_id = dmc[name]["env_id"]
        assert dmc[name]["learned_mpc"] == dmc_contract.learned_block(env_id)
        assert dmc[name]["full_horizon"] == dmc_contract.reference_block(env_id)
        assert dmc[name]["optimum"] == dmc_contract.optimum_block(env_id)
        assert dmc[name]["published"] == dmc_contract.published_block(env_id)
        for algo in ("sac", "ppo"):
            assert dmc[name][algo] == dmc_contract.rl_block(env_id, algo)


def test_the_rl_baselines_summarise_their_seeds() -> None:
    """``dmc_rl.json``: each block's mean and std are those of its seeds' means, each seed's mean that of its ten
    scores on the evaluation seeds, its selected point on its own validation curve; budgets of at least 1 M steps."""
    path = ROOT / "benchmarks" / "results" / "dmc_rl.json"
    if not path.is_file():
        pytest.skip("no RL run committed")
    data = json.loads(path.read_text())
    assert data["eval_seeds"] == list(range(10))
    for blocks in data["tasks"].values():
        for block in blocks.values():
            means = [row["mean"] for row in block["per_seed"]]
            assert block["seeds"] == len(means) >= 5 and block["env_steps"] >= 1_000_000
            assert block["score_mean"] == pytest.approx(np.mean(means), abs=1e-3)
            assert block["score_std"] == pytest.approx(np.std(means), abs=1e-3)
            for row, curve in zip(block["per_seed"], block["curves"], strict=True):
                assert len(row["scores"]) == 10 and row["mean"] == pytest.approx(np.mean(row["scores"]), abs=1e-3)
                assert row["selected_at"]["mean"] == max(point["mean"] for point in curve)


def _write(tmp: Path, name: str, payload: dict[str, Any]) -> None:
    (tmp / name).write_text(json.dumps(payload))


def test_assemble_pools_the_networks_and_leaves_missing_runs_empty(tmp_path: Path) -> None:
    env_id = "dm_control/pendulum-swingup-v0"
    row = {
        "scores": [800.0, 820.0],
        "mean": 810.0,
        "seeds": [0, 1],
        "decision_ms_median": 1.0,
        "decision_ms_p95": 2.0,
        "hold": 1,
        "solves": 1500,
        "network": "a.pt",
        "horizon": 10,
    }
    other = row | {"scores": [700.0, 740.0], "mean": 720.0, "decision_ms_median": 3.0, "network": "b.pt"}
    _write(tmp_path, "dmc_learned.json", {"tasks": {env_id: {"rows": [row, other]}}})
    _write(
        tmp_path,
        "dmc_reference.json",
        {"tasks": {env_id: {"mean": 850.0, "std": 10.0, "scores": [840.0, 860.0], "seeds": [0, 1]}}},
    )
    part = {"mean": 830.0, "std": 5.0, "scores": [825.0, 835.0], "seeds": [0, 1]}
    _write(
        tmp_path,
        "dmc_optimum.json",
        {"tasks": {env_id: {**part, "wide": part | {"mean": 842.0}, "energy_wide": part, "spec": {"backups": 9}}}},
    )
    blocks = dmc_contract.assemble({env_id: [], "dm_control/acrobot-swingup-v0": []}, tmp_path)
    optimum = blocks["pendulum-swingup"]["optimum"]
    assert optimum["score_mean"] == 830.0 and optimum["episodes"] == 2 and optimum["wide"]["score_mean"] == 842.0
    assert optimum["spec"] == {"backups": 9} and blocks["acrobot-swingup"]["optimum"] is None
    learned = blocks["pendulum-swingup"]["learned_mpc"]
    assert learned["score_mean"] == pytest.approx(765.0) and learned["seeds"] == 2 and learned["episodes"] == 2
    assert learned["score_std"] == pytest.approx(np.std([800, 820, 700, 740]), abs=1e-3)
    assert learned["median_ms"] == pytest.approx(2.0) and learned["network"] == "a.pt"
    assert blocks["pendulum-swingup"]["full_horizon"]["score_mean"] == 850.0
    acrobot = blocks["acrobot-swingup"]
    assert acrobot["learned_mpc"] is None and acrobot["full_horizon"] is None
    assert acrobot["sac"] is None and acrobot["ppo"] is None and acrobot["published"] == []


def test_the_cli_deploys_what_the_benchmark_measured(dmc: dict[str, Any]) -> None:
    """``seagul evaluate --dmc``'s defaults (``DEFAULT_DEPLOYMENTS``) are the setting of each committed row."""
    from seagul_learn.dmc_eval import DEFAULT_DEPLOYMENTS, DMCDeployment

    for name in TASKS:
        learned = dmc[name]["learned_mpc"]
        if learned is None:
            continue
        setting = DEFAULT_DEPLOYMENTS.get(dmc[name]["env_id"], DMCDeployment())
        assert (setting.horizon, setting.time_to_go, setting.hold, setting.path_bounds) == (
            learned["horizon"],
            learned["time_to_go"],
            learned["hold"],
            learned["path_bounds"],
        )
        period = make_task(DMC_TASKS[dmc[name]["env_id"]]).control_period
        interval = setting.dt if setting.dt is not None else setting.hold * period
        assert interval == pytest.approx(learned["dt"])
