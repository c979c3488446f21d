"""RL baselines: the tuned settings as data, the learner's view, checkpoint selection and the saved policy."""

from __future__ import annotations

import json
import tempfile
from dataclasses import fields, replace
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import seagul_envs  # noqa: F401  (registers the envs)
from seagul_control.evaluation import EpisodeResult, heldout_starts, start_grid, success_at, tolerance_reached
from seagul_envs import make_task
from seagul_envs.wrappers import LearnerView, learner_env
from seagul_learn.baselines import (
    REPLAY_BUFFER,
    SB3Config,
    ZeroPolicy,
    config_from_args,
    episode_stats,
    extendable_run,
    learner_view,
    smoke_config,
    task_of_env,
    train_sb3,
    tuned,
    validation_starts,
)
from seagul_learn.policies import SB3Policy


def test_tuned_settings_are_data_keyed_by_env_id_with_overrides_over_them():
    ppo = SB3Config(env_id="SeagulAcrobot-v0").resolved()
    assert ppo == {**tuned("PPO", "SeagulAcrobot-v0"), "n_timesteps": ppo["n_timesteps"], "eval_every": 100_000}
    assert ppo["learner_view"]["angles"] == [0, 1] and ppo["ent_coef"] > 0 and "use_sde" not in ppo
    # The discount keeps the terminal term at >= 90 % of its weight over the longest episode.
    for env_id, steps in (("SeagulAcrobot-v0", 50), ("SeagulGlider-v0", 34)):
        for algo in ("PPO", "SAC"):
            assert tuned(algo, env_id)["gamma"] ** steps >= 0.9
    sac = SB3Config(algo="SAC", total_timesteps=5000, algo_overrides={"tau": 0.01}, view_overrides={"end_scale": 3.0})
    resolved = sac.resolved()
    assert resolved["tau"] == 0.01 and resolved["n_timesteps"] == 5000 and resolved["learner_view"]["end_scale"] == 3.0
    assert resolved["policy_kwargs"]["net_arch"] == [256, 256] and resolved["learning_starts"] == 10_000
    assert tuned("SAC", "SeagulAcrobot-v0")["tau"] == 0.005  # the file's entry is untouched
    assert tuned("PPO", "SomeUserEnv-v3") == tuned("PPO", "default")  # an id without an entry


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"algo": "A2C"}, "unknown algo"),
        ({"total_timesteps": -1}, "total_timesteps"),
        ({"n_validation": 0}, "n_validation"),
        ({"algo_overrides": {"learner_view": {}}}, "view_overrides"),
    ],
)
def test_config_rejects_bad_values(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SB3Config(**kwargs)


def test_learner_view_features_actions_and_a_bounded_success_aware_reward():
    view = learner_view("SeagulAcrobot-v0", tuned("PPO", "SeagulAcrobot-v0")["learner_view"])
    obs = np.array([np.pi + 2 * np.pi, 0.1, 0.5, -0.5, 2.5])
    features = view.observe(obs)
    # (cos, sin) of th1 (three turns up is upright), of th2, then the speeds, then the time to go over 5 s.
    np.testing.assert_allclose(features, [-1, 0, np.cos(0.1), np.sin(0.1), 0.5, -0.5, 0.5], atol=1e-6)
    np.testing.assert_allclose(view.action([-1.0, 1.0, 0.0, 3.0]), [-20, 20, 0, 20])
    env = learner_env(gym.make("SeagulAcrobot-v0"), view)
    assert env.action_space.low[0] == -1 and env.observation_space.shape == (7,)
    assert env.observation_space.contains(env.reset(seed=0)[0])
    # Hanging with no torque: every step costs at most h / tau_max, the end at most end_weight, no bonus.
    env.reset(options={"state": [0.0, 0.0, 0.0, 0.0]})
    rewards, done = [], False
    while not done:
        _, r, terminated, truncated, info = env.step(np.zeros(1, dtype=np.float32))
        rewards.append(r)
        done = terminated or truncated
    assert terminated and not truncated  # the horizon's end is terminal for the learner
    assert all(-0.1 / 5.0 - 1e-12 <= r < 0 for r in rewards[:-1]) and not info["learner_success"]
    assert -2.0 <= sum(rewards) < -1.0 and info["task_reward"] < -1.0  # bounded; the task's reward kept in info
    # At the goal: success earns the bonus on the last step.
    env.reset(options={"state": [np.pi, 0.0, 0.0, 0.0]})
    done = False
    while not done:
        _, r, terminated, truncated, info = env.step(np.zeros(1, dtype=np.float32))
        done = terminated or truncated
    assert info["learner_success"] and r == pytest.approx(1.0, abs=1e-3)


def test_a_glider_crash_is_worse_than_any_miss():
    view = learner_view("SeagulGlider-v0", tuned("SAC", "SeagulGlider-v0")["learner_view"])
    env = learner_env(gym.make("SeagulGlider-v0"), view)
    env.reset(seed=1)
    done = False
    while not done:  # full nose-up elevator: the glider pitches past pi/2 and crashes
        _, r, terminated, truncated, info = env.step(np.ones(1, dtype=np.float32))
        done = terminated or truncated
    assert terminated and not info["learner_success"]
    assert r <= -(view.crash_penalty) - 0.5 * view.end_weight and r > -(view.crash_penalty + view.end_weight) - 1


def test_view_round_trips_and_rejects_bad_settings(tmp_path):
    view = learner_view("SeagulAcrobot-v0", {"angles": [0, 1], "end_scale": 4.0})
    view.save(tmp_path / "view.json")
    assert LearnerView.load(tmp_path / "view.json") == view
    with pytest.raises(ValueError, match="unknown LearnerView keys"):
        LearnerView.from_dict({**view.to_dict(), "anglez": [0]})
    with pytest.raises(ValueError, match="end_scale"):
        LearnerView(end_scale=0.0)
    with pytest.raises(ValueError, match="angles"):
        LearnerView(angles=(0, 0))


def test_validation_starts_are_neither_the_grid_nor_the_heldout_starts():
    task = task_of_env("SeagulAcrobot-v0")
    val = validation_starts(task, 50)
    assert np.array_equal(val, validation_starts(task, 50)) and all(task.in_x0(x) for x in val)
    grid, _ = start_grid(task, task.profile.grid.points)
    for other in (grid, heldout_starts(task, 100)):
        distances = np.linalg.norm(val[:, None, :] - other[None, :, :], axis=2)
        assert distances.min() > 1e-6


def test_tiny_run_selects_on_validation_and_its_saved_policy_acts_on_the_raw_env(tmp_path, monkeypatch):
    config = smoke_config(SB3Config(algo="PPO", seed=3))
    seen: list[dict] = []
    scratch = tmp_path / "system-tmp"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    summary = train_sb3(config, tmp_path / "run", on_point=seen.append)
    # SB3's default logger would leave an empty SB3-<date> folder here on every learn()
    assert [p.name for p in scratch.iterdir() if p.name.startswith("SB3-")] == []
    tmp_path = tmp_path / "run"
    assert len(seen) >= 2 and not (tmp_path / "curve.partial.json").exists()
    for name in ("model.zip", "vecnormalize.pkl", "view.json"):
        assert (tmp_path / name).is_file() and (tmp_path / "best" / name).is_file()
    stored = json.loads((tmp_path / "curve.json").read_text())
    best = max(stored["curve"], key=lambda p: (p["success_rate"], -p["median_miss"]))
    assert stored["best"] == best and summary["model"].endswith("best/model.zip")
    task = task_of_env(config.env_id)
    policy = SB3Policy(task, summary["model"], algo="PPO")
    obs, _ = gym.make("SeagulAcrobot-v0").reset(seed=0)
    action, _ = policy.predict(obs)
    assert action.shape == (1,) and -20.0 <= float(action[0]) <= 20.0
    # The saved policy is the live one: the same validation statistics when re-evaluated from disk.
    again = episode_stats(task, policy, validation_starts(task, config.n_validation))
    last = SB3Policy(task, str(tmp_path / "model.zip"), algo="PPO")
    final = episode_stats(task, last, validation_starts(task, config.n_validation))
    assert final["median_miss"] == pytest.approx(stored["curve"][-1]["median_miss"], rel=1e-4)
    assert again["median_miss"] == pytest.approx(best["median_miss"], rel=1e-4)


def test_command_line_is_derived_from_the_config(tmp_path):
    config, out = config_from_args(
        ["--algo", "SAC", "--seed", "2", "--algo-overrides", '{"tau": 0.01}', "--out", str(tmp_path)]
    )
    assert (config.algo, config.seed, config.algo_overrides) == ("SAC", 2, {"tau": 0.01}) and out == tmp_path
    assert type(config) is SB3Config  # the command's own switches (--out, --test) are not part of the config
    small, default_out = config_from_args(["--algo", "PPO", "--test"])
    assert small.total_timesteps == 256 and small.algo_overrides["n_steps"] == 64
    assert default_out == Path("runs") / "ppo_SeagulAcrobot-v0"
    view, _ = config_from_args(["--env-id", "SeagulGlider-v0", "--view-overrides", '{"end_scale": 4.0}', "--progress"])
    assert (view.env_id, view.view_overrides, view.progress, view.algo_overrides) == (
        "SeagulGlider-v0",
        {"end_scale": 4.0},
        True,
        {},
    )


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--algo", "A2C"], "invalid choice 'A2C'"),
        (["--algo-overrides", "[1]"], "expected a JSON object"),
        (["--algo-overrides", "{bad"], "not valid JSON"),
        (["--view-overrides", "3"], "expected a JSON object"),
        (["--n-validation", "0"], "n_validation must be >= 1"),
        (["--algo-overrides", '{"policy": "CnnPolicy"}'], "algo_overrides cannot set"),
    ],
)
def test_a_bad_command_line_exits_with_status_2_naming_the_problem(argv, message, capsys):
    """Bad flags and values (the config's own checks included) are command-line errors, not tracebacks."""
    with pytest.raises(SystemExit) as exc:
        config_from_args(argv)
    assert exc.value.code == 2
    assert message in " ".join(capsys.readouterr().err.replace("│", " ").split())


def test_the_help_lists_every_config_field_as_a_flag(capsys):
    with pytest.raises(SystemExit) as exc:
        config_from_args(["--help"], description="Train one.")
    assert exc.value.code == 0
    out = capsys.readouterr().out
    flags = [f"--{f.name.replace('_', '-')}" for f in fields(SB3Config)]
    assert all(flag in out for flag in [*flags, "--out", "--test"]), out
    assert "Train one." in out and "--algo-overrides JSON" in out


def test_zero_input_floor_and_heldout_starts():
    task = task_of_env("SeagulAcrobot-v0")
    starts = heldout_starts(task, 5)
    assert np.array_equal(starts, heldout_starts(task, 5)) and all(task.in_x0(x) for x in starts)
    at_goal = episode_stats(task, ZeroPolicy(task.nu), task.goal[None, :])
    assert at_goal["success_rate"] == 1.0 and at_goal["mean_miss"] == 0.0
    away = episode_stats(task, ZeroPolicy(task.nu), starts)
    assert away["success_rate"] == 0.0 and away["mean_final_distance"] > 1.0
    radius = task.profile.success.distance
    assert away["mean_miss"] == pytest.approx((away["mean_final_distance"] - radius) / radius)


def test_success_rule_scaled_and_the_scale_a_final_state_needs():
    acrobot = make_task("acrobot")
    rule = acrobot.profile.success
    x = acrobot.goal + np.array([0.06, 0.0, 0.0, 0.0])
    assert not rule(acrobot, x) and rule.scaled(2.0)(acrobot, x)  # 0.06 misses 0.05, meets 0.1
    assert rule.scale_needed(acrobot, x) == pytest.approx(0.06 / 0.05)
    assert rule.scaled(1.0) == rule
    glider = make_task("glider")
    perch = glider.profile.success
    y = glider.goal.copy()
    y[0] += 0.08  # 8 cm short of the perch, slow enough
    y[4] += 3.0  # 3 m/s too fast in x: 1.5 speed tolerances
    assert perch.scale_needed(glider, y) == pytest.approx(max(0.08 / 0.05, 3.0 / 2.0))
    assert not perch.scaled(1.59)(glider, y) and perch.scaled(1.61)(glider, y)
    assert perch.scale_needed(glider, glider.goal, terminated=True) == float("inf")  # a crash
    with pytest.raises(ValueError, match="factor"):
        rule.scaled(0.0)


def test_success_at_rescales_the_rule_and_the_tolerance_reached_is_its_threshold():
    """The baselines table's tolerances (``seagul_control.evaluation``; the benchmark imports them)."""
    task = make_task("acrobot")
    episodes = [
        {"final_state": list(task.goal + np.array([d, 0, 0, 0])), "terminated": False} for d in (0.01, 0.07, 0.3, 2.0)
    ]
    assert success_at(task, episodes) == {"0.05": 0.25, "0.1": 0.5, "0.2": 0.5, "0.5": 0.75}
    results = [EpisodeResult("x", i, [], e["final_state"], 0.0, 0.0, False, False, 50) for i, e in enumerate(episodes)]
    assert success_at(task, results, ("0.5", "5")) == {"0.5": 0.75, "5": 1.0}  # results as well as stored dicts
    reached = [tolerance_reached(task, e["final_state"], False) for e in episodes]
    assert reached == pytest.approx([0.01, 0.07, 0.3, 2.0])
    glider = make_task("glider")
    assert tolerance_reached(glider, glider.goal, terminated=True) == float("inf")  # a crash meets no tolerance


def test_a_larger_budget_extends_a_completed_run_from_its_final_model(tmp_path):
    config = smoke_config(SB3Config(algo="PPO", seed=5))
    first = train_sb3(config, tmp_path)
    assert extendable_run(config, tmp_path) is None  # same budget: nothing to extend
    longer = replace(config, total_timesteps=2 * config.total_timesteps)
    assert extendable_run(longer, tmp_path)["env_steps"] == first["env_steps"]
    assert extendable_run(replace(longer, seed=6), tmp_path) is None  # another run's directory is not extended
    second = train_sb3(longer, tmp_path)
    assert second["extended_from"] == first["env_steps"]
    assert second["env_steps"] >= longer.total_timesteps
    assert second["curve"][: len(first["curve"])] == first["curve"]  # the stored curve carries over
    steps = [p["env_steps"] for p in second["curve"]]
    assert steps == sorted(steps) and len(set(steps)) == len(steps)
    assert second["train_wall_s"] >= first["train_wall_s"]
    assert not (tmp_path / "best.partial").exists() and (tmp_path / "best" / "model.zip").is_file()


def test_an_off_policy_run_is_extended_from_its_replay_buffer(tmp_path):
    """SAC's extension continues from the run's replay buffer (saved at its end), not from an empty one; a run
    without the buffer is refused before anything in its directory changes."""
    from stable_baselines3.common.save_util import load_from_pkl

    config = smoke_config(SB3Config(algo="SAC", seed=3))
    first = train_sb3(config, tmp_path)
    assert load_from_pkl(tmp_path / REPLAY_BUFFER).size() == first["env_steps"]
    longer = replace(config, total_timesteps=2 * config.total_timesteps)
    second = train_sb3(longer, tmp_path)
    assert second["extended_from"] == first["env_steps"]
    # the first run's transitions are still there (an empty buffer would hold only the extension's)
    assert load_from_pkl(tmp_path / REPLAY_BUFFER).size() == second["env_steps"] == longer.total_timesteps
    (tmp_path / REPLAY_BUFFER).unlink()
    before = (tmp_path / "curve.json").read_text()
    with pytest.raises(ValueError, match=r"no replay_buffer\.pkl"):
        train_sb3(replace(config, total_timesteps=3 * config.total_timesteps), tmp_path)
    assert (tmp_path / "curve.json").read_text() == before


# ------------------------------------------------------------------------------------------ domain randomisation
def test_random_robot_draws_each_episode_its_robot_from_theta_reproducibly():
    from seagul_envs.wrappers import RandomRobot

    def robots(seed: int, n: int = 6) -> np.ndarray:
        env = RandomRobot(gym.make("SeagulGlider-v0"))
        drawn = [env.reset(seed=seed)[1]["params"]]
        drawn += [env.reset()[1]["params"] for _ in range(n - 1)]
        # the simulated robot is the drawn one, and the observation does not carry it
        np.testing.assert_array_equal(env.unwrapped.task.theta, drawn[-1])
        assert env.observation_space == gym.make("SeagulGlider-v0").observation_space
        return np.asarray(drawn)

    task = make_task("glider")
    space = task.parameters
    first = robots(0)
    assert np.all(first >= space.low) and np.all(first <= space.high)
    assert len({tuple(r) for r in first}) == len(first)  # a new robot every episode
    np.testing.assert_array_equal(first, robots(0))  # the reset seed fixes the sequence
    assert not np.array_equal(first, robots(1))
    env = RandomRobot(gym.make("SeagulGlider-v0"))
    _, info = env.reset(seed=0, options={"params": task.theta})
    np.testing.assert_array_equal(info["params"], task.theta)  # a given robot is kept
    narrow = RandomRobot(gym.make("SeagulGlider-v0"), scale=0.5).space
    assert np.all(narrow.high - narrow.low < space.high - space.low)


def test_random_robot_refuses_a_task_without_parameters_and_a_bad_scale():
    from seagul_envs import Task
    from seagul_envs.envs.base import SeagulEnv
    from seagul_envs.wrappers import RandomRobot

    with pytest.raises(ValueError, match="scale"):
        RandomRobot(gym.make("SeagulGlider-v0"), scale=0.0)
    task = make_task("glider")
    bare: Task = replace(task, parameters=None)
    with pytest.raises(ValueError, match="declares no physical parameters"):
        RandomRobot(SeagulEnv(bare))


def test_a_domain_randomised_run_trains_over_robots_and_validates_on_robots(tmp_path, monkeypatch):
    import seagul_learn.baselines as baselines

    config = smoke_config(SB3Config(algo="PPO", env_id="SeagulGlider-v0", seed=2, domain_randomization=True))
    seen_robots: list = []
    original = baselines.episode_stats

    def spy(task, policy, starts, env_id=None, robots=None):
        seen_robots.append(robots)
        return original(task, policy, starts, env_id=env_id, robots=robots)

    monkeypatch.setattr(baselines, "episode_stats", spy)
    venv = baselines.training_env(config, learner_view(config.env_id, config.resolved()["learner_view"]))
    venv.reset()
    thetas = {tuple(e.unwrapped.task.theta) for e in venv.venv.envs}
    assert len(thetas) == len(venv.venv.envs)  # every training env flies its own robot
    summary = train_sb3(config, tmp_path / "run")
    task = task_of_env(config.env_id)
    expected = baselines.validation_robots(task, config.n_validation)
    assert seen_robots and all(np.array_equal(r, expected) for r in seen_robots)
    assert summary["config"]["domain_randomization"] is True
    # validation robots are their own stream: not the evaluation's robots
    from benchmarks.bench_param_adversary import ROBOT_SEED

    evaluation = task.parameters.sample(np.random.default_rng(ROBOT_SEED), config.n_validation)
    assert np.abs(expected - evaluation).min() > 0


def test_a_run_stored_before_domain_randomization_existed_still_extends(tmp_path):
    config = smoke_config(SB3Config(algo="PPO", seed=4))
    train_sb3(config, tmp_path)
    stored = json.loads((tmp_path / "curve.json").read_text())
    del stored["config"]["domain_randomization"]
    (tmp_path / "curve.json").write_text(json.dumps(stored))
    assert extendable_run(replace(config, total_timesteps=512), tmp_path) is not None
    assert extendable_run(replace(config, total_timesteps=512, domain_randomization=True), tmp_path) is None
