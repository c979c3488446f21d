"""The committed robust MPC (``param_adversary.json``'s ``shipped`` blocks): the contract's keys, figures that agree
with the rows they summarise, and a network that deploys as the block says."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from seagul_control.mpc import LimitedLookaheadMPC, MPCOptions
from seagul_envs import make_task
from seagul_learn.value_network import ValueNetwork

ROOT = Path(__file__).resolve().parents[1]
RESULT = json.loads((ROOT / "benchmarks" / "results" / "param_adversary.json").read_text())
SHIPPED_KEYS = {
    "network",
    "horizon",
    "estimate_robot",
    "success_rate",
    "oracle_success_rate",
    "nominal_success_rate",
    "budget",
    "seeds",
    "starts",
}
TASKS = [t for t in ("acrobot", "glider") if "shipped" in RESULT.get(t, {})]


def test_the_acrobot_has_a_shipped_robust_mpc():
    assert "acrobot" in TASKS


@pytest.mark.parametrize("task_name", TASKS)
def test_the_shipped_block_holds_the_contracts_keys_and_agrees_with_its_rows(task_name):
    block = RESULT[task_name]
    shipped, robust = block["shipped"], block["robust"]
    assert SHIPPED_KEYS <= set(shipped)
    assert isinstance(shipped["horizon"], int) and shipped["horizon"] >= 1
    assert isinstance(shipped["estimate_robot"], bool)
    assert shipped["seeds"] >= 5 and shipped["seeds"] == len(robust["per_seed"])
    assert shipped["budget"] <= 3000
    rates = [row["success_rate"] for row in robust["per_seed"]]
    assert shipped["success_rate"] == pytest.approx(float(np.median(rates)))
    assert shipped["oracle_success_rate"] == robust["baselines"]["oracle"]["success_rate"]
    assert shipped["nominal_success_rate"] == robust["baselines"]["nominal"]["success_rate"]
    # the shipped network is the median seed's, not the best one
    chosen = next(r for r in robust["per_seed"] if r["seed"] == robust["shipped_seed"])
    assert chosen["success_rate"] == robust["shipped_network_success_rate"]
    assert sorted(rates)[(len(rates) - 1) // 2] == chosen["success_rate"]
    assert set(robust["box_sweep"]) == {"0.5", "1", "2"}
    assert robust["box_sweep"]["1"]["oracle"] == shipped["oracle_success_rate"]
    assert robust["box_sweep"]["1"]["robust"] == chosen["success_rate"]


@pytest.mark.parametrize("task_name", TASKS)
def test_the_shipped_network_deploys_as_the_block_says_and_plans_for_its_estimate(task_name):
    shipped = RESULT[task_name]["shipped"]
    path = ROOT / shipped["network"]
    assert path.is_file(), f"{shipped['network']} is not committed"
    task = make_task(task_name)
    network = ValueNetwork.load(path)
    # the block's deployment, compiled by CasADi's virtual machine here (no C build in the default suite)
    mpc = LimitedLookaheadMPC(
        task,
        network,
        horizon=shipped["horizon"],
        options=MPCOptions(jit=False),
        model_params=True,
        estimate_robot=shipped["estimate_robot"],
    )
    x = task.sample_x0(np.random.default_rng(0))
    u, info = mpc.act(x, task.tau_nominal)
    assert np.all(np.isfinite(u)) and info.source == "solver"
    if shipped["estimate_robot"]:
        np.testing.assert_array_equal(mpc.estimate(), task.theta)  # no transition seen yet: the model's robot


def test_the_benchmarks_settings_are_the_deployment_the_block_records():
    """``bench_robust.py --dry-run``: each task's settings, its recipe's training config included, are the ones its
    block was measured with."""
    import subprocess
    import sys

    script = ROOT / "benchmarks" / "bench_robust.py"
    tasks = ",".join(TASKS)
    done = subprocess.run(
        [sys.executable, str(script), "--tasks", tasks, "--dry-run"], capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    every = json.loads(done.stdout.strip().splitlines()[-1])
    for task in TASKS:
        settings, shipped, robust = every[task], RESULT[task]["shipped"], RESULT[task]["robust"]
        assert settings["horizon"] == shipped["horizon"], task
        assert settings["seeds"] == shipped["seeds"] and settings["starts"] == shipped["starts"], task
        assert settings["train"]["budget"] == shipped["budget"], task
        assert settings["recipe"] == robust["recipe"], task
        assert settings["train"] == robust["train_settings"], task
        for algo, steps in settings["rl_steps"].items():  # the domain-randomised RL rows: budget and seeds
            row = robust["baselines"][f"dr-{algo.lower()}"]
            assert row["settings"]["n_timesteps"] == steps and row["seeds"] == settings["seeds"], task
            assert row["success_rate"] == np.median([r["success_rate"] for r in row["per_seed"]]), task
            assert (ROOT / row["model"]).is_file() and (ROOT / row["model"]).with_name("view.json").is_file(), task


def test_domain_randomised_rl_rows_train_once_select_on_validation_and_fly_the_benchmarks_robots(tmp_path, monkeypatch):
    """``bench_robust``'s RL baselines: one run per seed over robots (reused when complete), each seed's selected
    model flown by the benchmark's scorer, success the median over seeds."""
    from benchmarks import bench_robust

    bench = bench_robust.RobustBenchConfig.for_task("glider", quick=True)
    assert bench.rl_steps == {"PPO": 256, "SAC": 256}
    assert all(bench.rl_config(algo, s).domain_randomization for algo in bench.rl_steps for s in (0, 1))
    flown: list = []

    def score(spec, name):
        flown.append((spec, name))
        return {"success_rate": 0.25 * len(flown)}

    with pytest.raises(ValueError, match="no domain-randomised RL for \\['TD3'\\]"):
        bench_robust.dr_rows(bench, tmp_path, 1, False, score, algos=["TD3"])
    rows = bench_robust.dr_rows(bench, tmp_path, 1, False, score, algos=["PPO"])  # one algorithm of the task's
    assert list(rows) == ["dr-ppo"]
    row = rows["dr-ppo"]
    assert [name for _, name in flown] == ["dr-ppo-seed0", "dr-ppo-seed1"]
    assert all(spec.kind == "sb3" and spec.path.endswith("best/model.zip") for spec, _ in flown)
    assert row["success_rate"] == pytest.approx(np.median([0.25, 0.5])) and row["seeds"] == 2
    assert row["env_steps"] >= 256 and [r["seed"] for r in row["per_seed"]] == [0, 1]
    # completed runs of the same config are reused, not trained again
    monkeypatch.setattr(bench_robust, "train_sb3", lambda *a, **k: pytest.fail("retrained a completed run"))
    again = bench_robust.dr_rows(bench, tmp_path, 1, False, score, algos=["PPO"])
    assert again["dr-ppo"]["per_seed"][0]["selected_at"] == row["per_seed"][0]["selected_at"]


def test_the_deployment_sweep_varies_the_shipped_deployment_of_the_committed_networks():
    """``robust_deployment.json``: its first variant is the shipped robust MPC's spec, each other changes what its
    name says, the networks are the committed per-seed ones and each median is its seeds' median."""
    import sys

    sys.path.insert(0, str(ROOT))
    from benchmarks.bench_robust import robust_spec
    from benchmarks.bench_robust_deployment import VARIANTS, variant_spec

    sweep = json.loads((ROOT / "benchmarks" / "results" / "robust_deployment.json").read_text())
    net = str(ROOT / RESULT["glider"]["shipped"]["network"])
    shipped = variant_spec(VARIANTS[0], net, 10)
    assert (shipped.options, shipped.knows_robot) == (robust_spec(net, 10).options, False)
    by_name = {v.name: variant_spec(v, net, 10).option_dict() for v in VARIANTS}
    assert by_name["horizon-minus-2"]["horizon"] == 8 and by_name["horizon-plus-2"]["horizon"] == 12
    assert dict(by_name["estimate-prior-1e-3"]["estimate_robot"]) == {"prior": 1e-3}
    assert by_name["knows-robot"]["estimate_robot"] is False
    for task_name, block in ((k, v) for k, v in sweep.items() if k != "machine"):
        assert block["networks"] == [r["network"] for r in RESULT[task_name]["robust"]["per_seed"]]
        assert [v["name"] for v in block["variants"]] == [v.name for v in VARIANTS]
        for variant in block["variants"]:
            assert len(variant["success_per_seed"]) == len(block["networks"])
            assert variant["success_median"] == pytest.approx(float(np.median(variant["success_per_seed"])))


def test_baselines_from_a_results_file_fly_only_the_robust_mpc(tmp_path, monkeypatch):
    """``bench_robust.py --baselines-from``: the networks' rows are flown, every baseline row and the box sweep's
    nominal and oracle entries are the file's, and the block says where they came from."""
    from benchmarks import bench_robust

    committed = RESULT["glider"]["robust"]
    bench = bench_robust.RobustBenchConfig.for_task("glider", quick=True)
    flown: list[str] = []

    def fake_closed_loop(scorer, spec, starts, robots, workers, out):
        flown.append(out.stem)
        return {"success_rate": 0.5, "success": [True, False], "median_ms": 1.0}

    monkeypatch.setattr(bench_robust, "closed_loop", fake_closed_loop)
    monkeypatch.setattr(bench_robust, "estimator_trace", lambda *a, **k: {})
    trained: list = []

    def fake_dr_rows(bench, out, workers, ship, score, algos=None):
        trained.append(algos)
        return {f"dr-{algo.lower()}": {"controller": algo, "success_rate": 0.25} for algo in algos}

    monkeypatch.setattr(bench_robust, "dr_rows", fake_dr_rows)
    bench.rl_steps = {algo: 256 for algo in ("PPO", "SAC") if f"dr-{algo.lower()}" in committed["baselines"]}
    nets = [ROOT / r["network"] for r in committed["per_seed"][:2]]
    reuse = {**committed, "baselines_reused_from": "the committed run"}
    block = bench_robust.run_task(bench, tmp_path, 1, False, nets, reuse)
    # each seed once, then the shipped seed's (cached) declared box and the other two boxes
    assert sorted(flown) == ["robust-seed0", "robust-seed0", "robust-seed0-x0.5", "robust-seed0-x2", "robust-seed1"]
    robust = block["robust"]
    assert robust["baselines"] == committed["baselines"] and robust["baselines_reused_from"] == "the committed run"
    for scale, entry in robust["box_sweep"].items():
        assert entry["robust"] == 0.5
        assert {k: entry[k] for k in ("nominal", "oracle")} == {
            k: committed["box_sweep"][scale][k] for k in ("nominal", "oracle")
        }
    assert block["shipped"]["oracle_success_rate"] == committed["baselines"]["oracle"]["success_rate"]
    assert trained == [] and robust["baselines_flown"] == []  # every RL row the benchmark has is in the file
    with pytest.raises(SystemExit, match="no rows"):
        bench_robust.run_task(bench, tmp_path, 1, False, nets, {**reuse, "baselines": {}})
    # a named baseline is flown again and replaces the file's row
    flown.clear()
    again = bench_robust.run_task(bench, tmp_path, 1, False, nets, {**reuse, "fly": ["nominal-estimate"]})
    assert "nominal-estimate" in flown and again["robust"]["baselines"]["nominal-estimate"]["success_rate"] == 0.5
    assert again["robust"]["baselines_flown"] == ["nominal-estimate"]
    assert again["robust"]["baselines"]["oracle"] == committed["baselines"]["oracle"]
    with pytest.raises(SystemExit, match="names no baseline"):
        bench_robust.run_task(bench, tmp_path, 1, False, nets, {**reuse, "fly": ["nope"]})
    # an RL baseline the file has no row for is trained and flown; a named one again; the others stay the file's
    bench.rl_steps = {"PPO": 256, "SAC": 256}
    without_sac = {k: v for k, v in committed["baselines"].items() if k != "dr-sac"}
    added = bench_robust.run_task(bench, tmp_path, 1, False, nets, {**reuse, "baselines": without_sac})
    assert trained == [["SAC"]] and added["robust"]["baselines"]["dr-sac"]["success_rate"] == 0.25
    assert added["robust"]["baselines_flown"] == ["dr-sac"]
    assert added["robust"]["baselines"]["dr-ppo"] == committed["baselines"]["dr-ppo"]
    trained.clear()
    both = {**without_sac, "dr-sac": {"controller": "SAC", "success_rate": 0.5}}
    again = bench_robust.run_task(bench, tmp_path, 1, False, nets, {**reuse, "baselines": both, "fly": ["dr-ppo"]})
    assert trained == [["PPO"]] and again["robust"]["baselines"]["dr-sac"]["success_rate"] == 0.5
    assert again["robust"]["baselines_flown"] == ["dr-ppo"]
