"""SB3 PPO and SAC on the suite's swing-ups (seagul_learn.dmc_rl): tiny-budget runs end to end, a finished run is
reused and an interrupted one resumed, the score equals the same deterministic policy stepped by hand, the settings
file resolves, bad input is refused; and run_dmc_episode's dm_control observation mode."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("dm_control.suite", reason="dm_control is optional: pip install 'seagul[dmc]'")
pytest.importorskip("shimmy", reason="shimmy wraps dm_control for Gymnasium: pip install 'seagul[dmc]'")
pytest.importorskip("stable_baselines3")

import gymnasium as gym

from seagul_control.dmc import DMC_ENV_IDS, make_dmc_env, physics_state, run_dmc_episode
from seagul_learn.dmc_rl import (
    VALIDATION_SEED,
    dmc_settings,
    evaluate_sb3_dmc,
    load_sb3_dmc,
    train_dmc_sb3,
)

ENV = "dm_control/pendulum-swingup-v0"
#: Small networks and short updates: a few thousand steps in seconds.
TINY: dict[str, dict[str, Any]] = {
    "ppo": {
        "n_steps": 512,
        "batch_size": 128,
        "n_epochs": 2,
        "eval_every": 512,
        "validation_episodes": 1,
        "policy_kwargs": {"net_arch": {"pi": [16, 16], "vf": [16, 16]}},
    },
    "sac": {
        "learning_starts": 200,
        "batch_size": 64,
        "buffer_size": 5000,
        "eval_every": 400,
        "validation_episodes": 1,
        "policy_kwargs": {"net_arch": {"pi": [32, 32], "qf": [32, 32]}},
    },
}
STEPS = {"ppo": 1536, "sac": 800}


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, dict[str, Any]]]:
    root = tmp_path_factory.mktemp("dmc_rl")
    return {
        algo: (root / algo, train_dmc_sb3(algo, ENV, 0, STEPS[algo], root / algo, settings=TINY[algo]))
        for algo in ("ppo", "sac")
    }


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_tiny_run_end_to_end(runs: dict[str, tuple[Path, dict[str, Any]]], algo: str) -> None:
    out, summary = runs[algo]
    assert summary["env_steps"] >= STEPS[algo] and not summary["reused"] and summary["resumed_from"] is None
    every = TINY[algo]["eval_every"]
    assert [row["env_steps"] for row in summary["curve"][:-1]] == list(range(every, STEPS[algo], every))
    assert summary["curve"][-1]["env_steps"] == summary["env_steps"]
    best = summary["best"]
    assert best["mean"] == max(row["mean"] for row in summary["curve"])
    assert all(0.0 <= s <= 1000.0 for row in summary["curve"] for s in row["scores"])
    assert (out / "best" / "model.zip").is_file() and (out / "final" / "model.zip").is_file()
    assert (out / "best" / "vecnormalize.pkl").is_file() == (algo == "ppo")  # CleanRL normalises, pytorch_sac not
    assert not (out / "checkpoint").exists()
    stored = json.loads((out / "curve.json").read_text())
    assert stored["curve"] == summary["curve"] and stored["config"]["settings"]["n_timesteps"] == STEPS[algo]
    assert json.loads((out / "best" / "policy.json").read_text())["point"] == best
    result = evaluate_sb3_dmc(out, ENV, [0, 1])
    assert result["model"] == str(out / "best") and len(result["scores"]) == 2
    assert result["mean"] == pytest.approx(np.mean(result["scores"]))


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_finished_run_is_reused_not_retrained(runs: dict[str, tuple[Path, dict[str, Any]]], algo: str) -> None:
    out, summary = runs[algo]
    stamp = (out / "best" / "model.zip").stat().st_mtime_ns
    again = train_dmc_sb3(algo, ENV, 0, STEPS[algo], out, settings=TINY[algo])
    assert again["reused"] and again["curve"] == summary["curve"] and again["env_steps"] == summary["env_steps"]
    assert (out / "best" / "model.zip").stat().st_mtime_ns == stamp


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_score_is_the_deterministic_policy_stepped_by_hand(
    runs: dict[str, tuple[Path, dict[str, Any]]], algo: str
) -> None:
    import stable_baselines3
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    out, _ = runs[algo]
    model = getattr(stable_baselines3, algo.upper()).load(out / "best" / "model.zip", device="cpu")
    flat = gym.wrappers.FlattenObservation(make_dmc_env(ENV))
    stats = None
    if algo == "ppo":
        stats = VecNormalize.load(str(out / "best" / "vecnormalize.pkl"), DummyVecEnv([lambda: flat]))
    seed = 3
    obs, _ = flat.reset(seed=seed)
    rewards, actions, done = [], [], False
    while not done:
        seen = obs[None, :] if stats is None else stats.normalize_obs(obs[None, :])
        action, _ = model.predict(seen.astype(np.float32), deterministic=True)
        actions.append(np.asarray(action, dtype=float).reshape(-1))
        obs, reward, terminated, truncated, _ = flat.step(actions[-1])
        rewards.append(float(reward))
        done = terminated or truncated
    flat.close()
    result = evaluate_sb3_dmc(out / "best", ENV, [seed])
    assert result["scores"] == [pytest.approx(math.fsum(rewards), abs=1e-9)]
    episode = run_dmc_episode(ENV, load_sb3_dmc(out / "best"), seed, record=True)
    assert episode.actions is not None and np.array_equal(np.array(episode.actions), np.array(actions))
    assert list(episode.rewards) == rewards


def test_interrupted_run_resumes_from_its_checkpoint(tmp_path: Path) -> None:
    class Stop(Exception):
        pass

    def stop(row: dict[str, Any]) -> None:
        raise Stop

    out = tmp_path / "sac"
    with pytest.raises(Stop):
        train_dmc_sb3("sac", ENV, 1, STEPS["sac"], out, settings=TINY["sac"], on_point=stop)
    assert (out / "checkpoint" / "replay_buffer.pkl").is_file() and not (out / "curve.json").exists()
    first = json.loads((out / "checkpoint" / "state.json").read_text())["curve"]
    assert [row["env_steps"] for row in first] == [400]
    summary = train_dmc_sb3("sac", ENV, 1, STEPS["sac"], out, settings=TINY["sac"])
    assert summary["resumed_from"] == 400 and not summary["reused"]
    assert summary["curve"][0] == first[0] and summary["env_steps"] == STEPS["sac"]
    assert not (out / "checkpoint").exists()


def test_settings_file_resolves_with_sources() -> None:
    for env_id in DMC_ENV_IDS:
        ppo, sac = dmc_settings("PPO", env_id), dmc_settings("sac", env_id)
        assert ppo["n_steps"] == 2048 and ppo["batch_size"] == 64 and ppo["normalize"] and ppo["anneal_lr"]
        assert sac["batch_size"] == 1024 and sac["policy_kwargs"]["net_arch"]["qf"] == [1024, 1024]
        assert min(ppo["n_timesteps"], sac["n_timesteps"]) >= 1_000_000
    merged = dmc_settings("sac", "acrobot-swingup", {"batch_size": 8, "policy_kwargs": {"net_arch": [4]}})
    assert merged["batch_size"] == 8 and merged["policy_kwargs"] == {**sac["policy_kwargs"], "net_arch": [4]}
    assert VALIDATION_SEED >= 10  # never the scoring seeds 0-9


def test_bad_input_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="a2c"):
        train_dmc_sb3("a2c", ENV, 0, 100, tmp_path)
    with pytest.raises(ValueError, match="walker-walk"):
        train_dmc_sb3("ppo", "walker-walk", 0, 100, tmp_path)
    with pytest.raises(ValueError, match="steps"):
        train_dmc_sb3("ppo", ENV, 0, 0, tmp_path)
    with pytest.raises(ValueError, match="seed"):
        train_dmc_sb3("ppo", ENV, -1, 100, tmp_path)
    with pytest.raises(ValueError, match="eval_every"):
        train_dmc_sb3("sac", ENV, 0, 100, tmp_path, settings={"eval_every": 0})
    with pytest.raises(ValueError, match="a2c"):
        dmc_settings("a2c", ENV)
    assert not any(tmp_path.iterdir())


def test_run_dmc_episode_gives_the_flattened_observation_on_request() -> None:
    seen: dict[str, list[np.ndarray]] = {"dm_control": [], "physics": []}

    class Agent:
        observation = "dm_control"

        def __call__(self, x: np.ndarray, t: float) -> np.ndarray:
            seen["dm_control"].append(x)
            return np.array([np.sin(3 * t)])

    def physics(x: np.ndarray, t: float) -> np.ndarray:
        seen["physics"].append(x)
        return np.array([np.sin(3 * t)])

    a = run_dmc_episode(ENV, Agent(), seed=4, record=True)
    b = run_dmc_episode(ENV, physics, seed=4, record=True)
    assert a.rewards == b.rewards and a.states == b.states  # the same episode, only what the controller sees differs
    env = make_dmc_env(ENV)
    obs, _ = env.reset(seed=4)
    first = gym.spaces.flatten(env.observation_space, obs)
    assert np.array_equal(seen["dm_control"][0], first) and first.shape == (3,)  # orientation (cos, sin), velocity
    assert np.array_equal(seen["physics"][0], physics_state(env))  # [hinge, d hinge]
    for action in a.actions[:5] if a.actions else []:
        obs, *_ = env.step(np.array(action))
    assert np.array_equal(seen["dm_control"][5], gym.spaces.flatten(env.observation_space, obs))
    env.close()

    class Wrong:
        observation = "pixels"

        def __call__(self, x: np.ndarray, t: float) -> np.ndarray:
            return np.zeros(1)

    with pytest.raises(ValueError, match="pixels"):
        run_dmc_episode(ENV, Wrong(), seed=0)


def test_benchmark_file_keeps_the_blocks_of_tasks_run_separately(tmp_path: Path, monkeypatch: Any) -> None:
    """``bench_dmc_rl.py --json FILE`` run for one task, then another, keeps both tasks' blocks (each with the
    command that wrote it); re-running a task replaces only its block."""
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from benchmarks import bench_dmc_rl

    calls: list[tuple[str, str]] = []

    def fake_run(env_id: str, algo: str, seeds: list[int], steps: int | None, out: Path) -> dict[str, Any]:
        calls.append((env_id, algo))
        return {"score_mean": float(len(calls)), "score_std": 0.0, "seeds": len(seeds), "env_steps": steps}

    monkeypatch.setattr(bench_dmc_rl, "run_algo", fake_run)
    path = tmp_path / "dmc_rl.json"
    bench_dmc_rl.main(
        ["--tasks", "pendulum-swingup", "--algos", "PPO", "--seeds", "2", "--steps", "10", "--json", str(path)]
    )
    bench_dmc_rl.main(
        ["--tasks", "cartpole-swingup", "--algos", "PPO", "--seeds", "2", "--steps", "20", "--json", str(path)]
    )
    tasks = json.loads(path.read_text())["tasks"]
    pendulum, cartpole = tasks["dm_control/pendulum-swingup-v0"]["ppo"], tasks["dm_control/cartpole-swingup-v0"]["ppo"]
    assert (pendulum["score_mean"], pendulum["env_steps"]) == (1.0, 10)
    assert (cartpole["score_mean"], cartpole["env_steps"]) == (2.0, 20)
    assert "pendulum-swingup" in pendulum["command"] and "cartpole-swingup" in cartpole["command"]
    bench_dmc_rl.main(
        ["--tasks", "pendulum-swingup", "--algos", "PPO", "--seeds", "2", "--steps", "30", "--json", str(path)]
    )
    tasks = json.loads(path.read_text())["tasks"]
    assert tasks["dm_control/pendulum-swingup-v0"]["ppo"]["env_steps"] == 30
    assert tasks["dm_control/cartpole-swingup-v0"]["ppo"]["env_steps"] == 20


def test_ship_copies_the_best_validated_seeds_model(
    runs: dict[str, tuple[Path, dict[str, Any]]], tmp_path: Path
) -> None:
    """``bench_dmc_rl.py --ship`` copies the model of the seed with the best validation point (not the best score
    on the scoring seeds), the copy scores as the run's own model, and a run holding another seed's model is refused."""
    import shutil
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from benchmarks import bench_dmc_rl

    source, _ = runs["ppo"]
    out = tmp_path / "runs"
    shutil.copytree(source / "best", out / "pendulum-swingup" / "ppo" / "seed0" / "best")
    block = {
        "per_seed": [
            {"seed": 0, "selected_at": {"mean": 50.0}, "scores": [1.0, 2.0]},
            {"seed": 1, "selected_at": {"mean": 40.0}, "scores": [900.0, 900.0]},  # better scores, worse validation
        ]
    }
    dest = tmp_path / "models"
    bench_dmc_rl.ship(ENV, "ppo", block, out, dest)
    target = dest / "pendulum-swingup_ppo"
    assert block["model"] == str(target.resolve()) and block["model_seed"] == 0
    for name in ("model.zip", "policy.json", "vecnormalize.pkl"):
        assert (target / name).read_bytes() == (source / "best" / name).read_bytes()
    assert evaluate_sb3_dmc(target, ENV, [3])["scores"] == evaluate_sb3_dmc(source, ENV, [3])["scores"]
    block["per_seed"][1]["selected_at"]["mean"] = 60.0
    with pytest.raises(FileNotFoundError, match="seed1"):
        bench_dmc_rl.ship(ENV, "ppo", block, out, dest)
    shutil.copytree(source / "best", out / "pendulum-swingup" / "ppo" / "seed1" / "best")
    with pytest.raises(ValueError, match=r"seed 0, not .* seed 1"):
        bench_dmc_rl.ship(ENV, "ppo", block, out, dest)
    # a model without observation statistics shipped over one with them leaves no stale statistics behind
    unnormalised = runs["sac"][0] / "best"
    shutil.rmtree(out / "pendulum-swingup" / "ppo" / "seed0" / "best")
    shutil.copytree(unnormalised, out / "pendulum-swingup" / "ppo" / "seed0" / "best")
    block["per_seed"][1]["selected_at"]["mean"] = 0.0
    bench_dmc_rl.ship(ENV, "ppo", block, out, dest)
    assert (target / "model.zip").read_bytes() == (unnormalised / "model.zip").read_bytes()
    assert not (target / "vecnormalize.pkl").exists()


def test_ship_only_ships_the_committed_blocks_without_training(
    runs: dict[str, tuple[Path, dict[str, Any]]], tmp_path: Path, monkeypatch: Any
) -> None:
    """``--ship-only`` reads the blocks of ``--json FILE``, ships their models, records them in the file and trains
    or scores nothing; a task without a block is refused by name."""
    import shutil
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from benchmarks import bench_dmc_rl

    source, _ = runs["ppo"]
    out = tmp_path / "runs"
    shutil.copytree(source / "best", out / "pendulum-swingup" / "ppo" / "seed0" / "best")
    path = tmp_path / "dmc_rl.json"
    block = {"score_mean": 1.0, "per_seed": [{"seed": 0, "selected_at": {"mean": 5.0}, "scores": [7.0]}]}
    path.write_text(json.dumps({"tasks": {ENV: {"ppo": block}}}))
    monkeypatch.setattr(bench_dmc_rl, "SHIP_DIR", tmp_path / "models")

    def no_training(*args: Any, **kwargs: Any) -> None:
        raise AssertionError("--ship-only must not train or score")

    monkeypatch.setattr(bench_dmc_rl, "run_algo", no_training)
    argv = ["--tasks", "pendulum-swingup", "--algos", "PPO", "--json", str(path), "--out", str(out), "--ship-only"]
    bench_dmc_rl.main(argv)
    stored = json.loads(path.read_text())["tasks"][ENV]["ppo"]
    assert stored["model"] == str((tmp_path / "models" / "pendulum-swingup_ppo").resolve())
    assert (stored["model_seed"], stored["score_mean"]) == (0, 1.0)
    assert (tmp_path / "models" / "pendulum-swingup_ppo" / "model.zip").is_file()
    with pytest.raises(ValueError, match="no ppo block for dm_control/cartpole-swingup-v0"):
        bench_dmc_rl.main([*argv[:1], "cartpole-swingup", *argv[2:]])
