"""Closed-loop evaluation: grids, determinism across workers, tables and figures, SB3 models, the CLI.

Episodes are run by :mod:`seagul_control.evaluation` (data only, no matplotlib); the tables and figures come from
:mod:`seagul_learn.report`, and their old names in ``seagul_control.evaluation`` still work with a warning.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import textwrap
import warnings

import gymnasium as gym
import numpy as np
import pytest

import seagul_control.evaluation as ev
import seagul_control.policy_kinds as policy_kinds
import seagul_control.starts as starts_module
import seagul_envs  # noqa: F401  (registers the envs)
from seagul_control.evaluation import (
    EpisodeResult,
    PolicySpec,
    build_policy,
    evaluate,
    is_success,
    run_policy_episode,
    start_grid,
)
from seagul_control.lqr import LQRPolicy
from seagul_control.mpc import FullHorizonMPC, FullHorizonOptions
from seagul_envs import make_task
from seagul_learn import policies, report
from seagul_learn.cli import main
from seagul_learn.commands.evaluate import add_arguments, specs_from_args
from seagul_learn.policies import SB3Policy
from seagul_learn.report import summarize, write_outputs

MOVED = ("summarize", "write_outputs", "plot_heatmaps", "plot_glider_trajectories")


def test_start_grids_follow_the_paper_figures():
    acro = make_task("acrobot")
    starts, grid = start_grid(acro, 3)
    assert starts.shape == (9, 4) and grid["dims"] == ["th1", "th2"]
    assert np.all(starts[:, 2:] == 0.0)  # zero velocity (Fig. 2)
    assert starts[:, 0].min() == pytest.approx(acro.x0_low[0]) and starts[:, 1].max() == pytest.approx(acro.x0_high[1])
    glider = make_task("glider")
    starts, grid = start_grid(glider, 2)
    assert grid["dims"] == ["x", "z"] and starts.shape == (4, 7)
    assert all(glider.in_x0(s) for s in starts)
    with pytest.raises(ValueError, match="grid size"):
        start_grid(acro, 0)


def test_success_definitions():
    acro, glider = make_task("acrobot"), make_task("glider")
    assert is_success(acro, acro.goal + 0.02)
    assert not is_success(acro, acro.goal + 0.03)  # norm 0.06
    perched = np.array([0.01, -0.02, 0.8, 0.0, 1.9, -1.5, 0.0])
    assert is_success(glider, perched)
    assert not is_success(glider, perched + np.array([0, 0, 0, 0, 0.2, 0, 0]))  # dx > 2
    assert not is_success(glider, perched, terminated=True)


def test_results_do_not_depend_on_the_number_of_workers(tmp_path):
    task = make_task("acrobot")
    starts, grid = start_grid(task, 2)
    specs = [PolicySpec("lqr", "lqr"), PolicySpec("mpc", "mpc", None, (("jit", False),))]
    one = evaluate("acrobot", specs, starts, workers=1, progress=False)
    two = evaluate("acrobot", specs, starts, workers=2, progress=False, chunk_size=1)
    assert [(r.policy, r.index) for r in one] == [(r.policy, r.index) for r in two]
    for a, b in zip(one, two, strict=True):
        np.testing.assert_allclose(a.final_state, b.final_state, rtol=1e-9, atol=1e-12)
    rows = summarize("acrobot", one)
    assert [r["policy"] for r in rows] == ["lqr", "mpc"]
    assert np.isnan(rows[0]["median_step_ms"]) and rows[1]["median_step_ms"] > 0
    paths = write_outputs(tmp_path, "acrobot", one, grid)
    for key in ("results", "summary_json", "summary_csv", "heatmap"):
        assert paths[key].is_file() and paths[key].stat().st_size > 0
    summary = json.loads(paths["summary_json"].read_text())
    assert summary["policies"][1]["episodes"] == 4
    assert paths["summary_csv"].read_text().splitlines()[0].startswith("policy,episodes,success_rate")


def test_glider_trajectory_figure(tmp_path):
    task = make_task("glider")
    starts, grid = start_grid(task, 1)
    results = evaluate("glider", [PolicySpec("lqr", "tvlqr")], starts, progress=False, record=True)
    assert len(results[0].states) == results[0].steps + 1 == 32 + 1
    paths = write_outputs(tmp_path, "glider", results, grid)
    assert paths["trajectories"].is_file()
    assert "perch_success_rate" in summarize("glider", results)[0]


def test_saved_sb3_model_with_vecnormalize_stats(tmp_path):
    from stable_baselines3 import PPO  # stable-baselines3 is imported by the tests that train a model
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    venv = VecNormalize(DummyVecEnv([lambda: gym.make("SeagulAcrobot-v0")]))
    model = PPO("MlpPolicy", venv, n_steps=64, batch_size=32, seed=0, device="cpu")
    model.save(tmp_path / "model.zip")
    venv.save(str(tmp_path / "vecnormalize.pkl"))
    task = make_task("acrobot")
    starts, _ = start_grid(task, 1)
    spec = PolicySpec("sb3", "ppo", str(tmp_path / "model.zip"))
    results = evaluate("acrobot", [spec], starts, progress=False)
    assert results[0].steps == 50 and np.isfinite(results[0].cost)
    assert build_policy("acrobot", spec).normalizer is not None


def test_episodes_in_another_simulator_of_the_task():
    """``env_id``: the same LQR from the same starts in the MuJoCo acrobot ends near, but not at, the analytic
    model's final states (different integrators); an env of another task is refused by name."""
    starts = make_task("acrobot").goal + np.array([[0.05, -0.05, 0.0, 0.0], [-0.1, 0.1, 0.2, 0.0]])
    analytic = evaluate("acrobot", [PolicySpec("lqr")], starts, progress=False)
    mujoco = evaluate("acrobot", [PolicySpec("lqr")], starts, progress=False, env_id="SeagulAcrobotMujoco-v0")
    for a, m in zip(analytic, mujoco, strict=True):
        assert a.steps == m.steps == 50
        assert np.allclose(a.final_state, m.final_state, atol=1e-2)
        assert a.final_state != m.final_state
    with pytest.raises(ValueError, match="simulates task 'glider', not 'acrobot'"):
        evaluate("acrobot", [PolicySpec("lqr")], starts, progress=False, env_id="SeagulGlider-v0")
    with pytest.raises(ValueError, match="unknown env id"):
        evaluate("acrobot", [PolicySpec("lqr")], starts, progress=False, env_id="NoSuchEnv-v0")


def test_policy_spec_errors():
    with pytest.raises(ValueError, match="unknown policy kind"):
        PolicySpec("dqn")
    with pytest.raises(ValueError, match="needs the path"):
        PolicySpec("sb3")
    with pytest.raises(FileNotFoundError, match="does not exist"):
        PolicySpec("mpc", path="/nonexistent/network.pt")
    with pytest.raises(ValueError, match="labels must be unique"):
        evaluate("acrobot", [PolicySpec("lqr"), PolicySpec("lqr")], np.zeros((1, 4)), progress=False)


def test_each_kind_names_its_builder_by_module_path_and_the_learned_ones_live_in_seagul_learn(tmp_path):
    """The control kinds are built by ``seagul_control``; an ``"mpc"`` spec with a network file and an ``"sb3"``
    spec by :mod:`seagul_learn.policies`, whose ``build_policy`` is the same function that knows every kind."""
    net = tmp_path / "net.pt"
    net.write_bytes(b"")
    assert ev.builder_path(PolicySpec("lqr")) == "seagul_control.policy_kinds:build_lqr_policy"
    assert ev.builder_path(PolicySpec("mpc")) == "seagul_control.policy_kinds:build_lookahead_policy"
    assert ev.builder_path(PolicySpec("mpc", path=str(net))) == "seagul_learn.policies:build_network_mpc_policy"
    assert ev.builder_path(PolicySpec("sb3", path=str(net))) == "seagul_learn.policies:build_sb3_policy"
    for kind in ev.POLICY_KINDS:
        for path in (ev.policy_kinds()[kind].builder, ev.policy_kinds()[kind].file_builder):
            if path is not None:
                module, name = path.split(":")
                assert callable(getattr(__import__(module, fromlist=[name]), name)), path
    assert policies.build_policy is ev.build_policy and policies.PolicySpec is PolicySpec


def test_a_kind_registered_at_run_time_is_built_in_the_worker_processes():
    """The workers start with the module's own registry: the caller's registration reaches them as the builder's
    module path, so a registered kind evaluates with two processes exactly as with one (and as the kind it
    copies)."""
    with pytest.raises(ValueError, match="module:function"):
        ev.register_policy_kind("bad", "seagul_control.evaluation.build_lqr_policy")
    with pytest.raises(ValueError, match="needs a builder"):
        ev.register_policy_kind("bad")
    with pytest.raises(ValueError, match="already registered"):
        ev.register_policy_kind("lqr", "seagul_control.policy_kinds:build_full_horizon_policy")
    # The builders' old module path (seagul_control.evaluation re-exports them) still names them.
    ev.register_policy_kind("lqr-copy", "seagul_control.evaluation:build_lqr_policy")
    try:
        ev.register_policy_kind("lqr-copy", "seagul_control.evaluation:build_lqr_policy")  # the same again: no-op
        task = make_task("acrobot")
        starts = task.goal + np.array([[0.05, -0.05, 0.0, 0.0], [-0.1, 0.1, 0.2, 0.0]])
        specs = [PolicySpec("lqr"), PolicySpec("lqr-copy")]
        one = evaluate(task, specs, starts, workers=1, progress=False)
        two = evaluate(task, specs, starts, workers=2, progress=False, chunk_size=1)
        assert [r.policy for r in two] == ["lqr", "lqr", "lqr-copy", "lqr-copy"]
        for a, b in zip(one, two, strict=True):
            np.testing.assert_allclose(a.final_state, b.final_state, rtol=1e-9, atol=1e-12)
        np.testing.assert_array_equal(two[0].final_state, two[2].final_state)
    finally:
        policy_kinds._KINDS.pop("lqr-copy", None)


def test_policy_kinds_and_starts_live_in_their_modules_and_still_import_from_evaluation():
    """The registry and builders (:mod:`seagul_control.policy_kinds`) and the starts (:mod:`seagul_control.starts`)
    are the same objects under their old names in ``seagul_control.evaluation``, without a warning; a kind registered
    through either name is one registry."""
    moved = {
        policy_kinds: (
            "POLICY_KINDS",
            "PolicyKind",
            "PolicySpec",
            "build_policy",
            "builder_path",
            "default_horizon",
            "policy_kinds",
            "register_policy_kind",
            "build_lqr_policy",
            "build_full_horizon_policy",
            "build_lookahead_policy",
            "build_do_mpc_policy",
        ),
        starts_module: ("HELDOUT_SEED", "heldout_starts", "sample_grid_slice", "start_grid"),
    }
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for module, names in moved.items():
            for name in names:
                assert getattr(ev, name) is getattr(module, name), name
                assert name in module.__all__ and name in ev.__all__, name
    assert ev._KINDS is policy_kinds._KINDS
    ev.register_policy_kind("lqr-alias", "seagul_control.policy_kinds:build_lqr_policy")
    try:
        assert "lqr-alias" in policy_kinds.policy_kinds() and PolicySpec("lqr-alias").name == "lqr-alias"
    finally:
        policy_kinds._KINDS.pop("lqr-alias", None)
    with pytest.raises(ValueError, match="unknown policy kind"):
        PolicySpec("lqr-alias")


def test_sb3_policy_moved_to_seagul_learn_policies_and_its_old_name_warns():
    with pytest.warns(DeprecationWarning, match=r"seagul_control\.evaluation\.SB3Policy .*seagul_learn\.policies"):
        old = ev.SB3Policy
    assert old is SB3Policy


def test_cli_evaluate(tmp_path, capsys):
    out = tmp_path / "eval"
    code = main(["evaluate", "--task", "acrobot", "--lqr", "--grid", "2", "--out", str(out), "--no-progress"])
    assert code == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[-1] == str(out) and lines[0].startswith("lqr: success")
    assert (out / "heatmap.png").is_file()
    mj = tmp_path / "mujoco"
    code = main(
        [
            "evaluate",
            "--task",
            "acrobot",
            "--lqr",
            "--grid",
            "2",
            "--env",
            "SeagulAcrobotMujoco-v0",
            "--out",
            str(mj),
            "--no-progress",
        ]
    )
    assert code == 0 and (mj / "heatmap.png").is_file()
    capsys.readouterr()
    assert main(["evaluate", "--task", "acrobot", "--out", str(out)]) == 2
    assert "no policy to evaluate" in capsys.readouterr().err


def test_running_episodes_imports_neither_matplotlib_nor_torch():
    """``seagul_control.evaluation`` is data only: importing it, running an episode and even touching a deprecated
    table/figure name (imported lazily from ``seagul_learn.report``) loads neither matplotlib nor torch."""
    code = textwrap.dedent(
        """
        import sys
        import warnings

        import seagul_control.evaluation as ev

        assert "matplotlib" not in sys.modules and "torch" not in sys.modules, "on import"
        assert "seagul_learn" not in sys.modules, "seagul_control never imports seagul_learn"
        assert "seagul_learn.report" not in sys.modules, "the new home is imported lazily"
        starts, _ = ev.start_grid(ev.make_task("acrobot"), 1)
        results = ev.evaluate("acrobot", [ev.PolicySpec("lqr")], starts, progress=False)
        assert results[0].steps == 50
        assert "matplotlib" not in sys.modules and "torch" not in sys.modules, "after an episode"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            ev.write_outputs
        assert "matplotlib" not in sys.modules and "torch" not in sys.modules, "after a deprecated name"
        print("ok")
        """
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "ok"


@pytest.mark.parametrize("name", MOVED)
def test_moved_names_still_import_from_evaluation_with_a_warning(name):
    with pytest.warns(DeprecationWarning, match=rf"seagul_control\.evaluation\.{name} .*seagul_learn\.report\.{name}"):
        old = getattr(ev, name)
    assert old is getattr(report, name)
    with pytest.warns(DeprecationWarning):
        exec(f"from seagul_control.evaluation import {name}", {})
    with pytest.raises(AttributeError, match="no attribute 'not_a_name'"):
        ev.not_a_name  # noqa: B018


def test_deprecated_write_outputs_gives_the_same_files(tmp_path):
    episodes = [
        EpisodeResult("mpc", 0, [0.1, 0.2, 0, 0], [3.1, 0.0, 0, 0], 0.02, 12.5, True, False, 50, [0.001], [4]),
        EpisodeResult("mpc", 1, [0.3, 0.4, 0, 0], [2.0, 1.0, 0, 0], 1.5, 40.0, False, False, 50, [0.002], [5]),
    ]
    grid = {"dims": ["th1", "th2"], "axes": [[0.0], [0.0, 1.0]], "shape": [1, 2]}
    new = write_outputs(tmp_path / "new", "acrobot", episodes, grid)
    with pytest.warns(DeprecationWarning):
        old = ev.write_outputs(tmp_path / "old", "acrobot", episodes, grid)
    assert set(old) == set(new) == {"results", "summary_json", "summary_csv", "heatmap"}
    for key in ("results", "summary_json", "summary_csv"):
        assert old[key].read_bytes() == new[key].read_bytes()
    with pytest.warns(DeprecationWarning):
        assert ev.summarize("acrobot", episodes) == summarize("acrobot", episodes)


def test_evaluation_over_robots_simulates_each_episodes_robot_and_the_oracle_plans_with_it():
    """``evaluate(..., robots=...)``: episode i runs on robot i (recorded on the result); a policy plans with the
    model unless its spec knows the robot; the model's own parameters reproduce the plain evaluation exactly."""
    task = make_task("acrobot")
    starts = start_grid(task, 2)[0][:2]
    model = PolicySpec("lqr", "lqr")
    oracle = PolicySpec("lqr", "lqr-oracle", knows_robot=True)
    plain = evaluate(task, [model], starts, progress=False)
    same = evaluate(task, [model], starts, progress=False, robots=np.tile(task.theta, (2, 1)))
    assert [r.final_state for r in same] == [r.final_state for r in plain]
    assert same[0].robot == task.theta.tolist() and plain[0].robot == []
    heavy = np.tile(task.parameters.high, (2, 1))
    runs = evaluate(task, [model, oracle], starts, progress=False, robots=heavy)
    on_model, on_oracle = runs[:2], runs[2:]
    assert all(r.robot == task.parameters.high.tolist() for r in runs)
    assert not np.allclose(on_model[0].final_state, plain[0].final_state)  # another robot flew the episode
    assert not np.allclose(on_model[0].final_state, on_oracle[0].final_state)  # the oracle planned for it
    # The oracle's episode is the LQR of the true robot on that robot (built independently here).

    robot_task = task.with_params(task.parameters.high)
    ref, _ = run_policy_episode(task, LQRPolicy(robot_task), starts[0], robot=task.parameters.high)
    np.testing.assert_allclose(on_oracle[0].final_state, ref.final_state, rtol=1e-12)
    mj = evaluate(task, [model], starts[:1], progress=False, robots=heavy[:1], env_id="SeagulAcrobotMujoco-v0")
    np.testing.assert_allclose(mj[0].final_state, on_model[0].final_state, atol=1e-5)
    with pytest.raises(ValueError, match=r"robots must have one row of 6 parameters"):
        evaluate(task, [model], starts, progress=False, robots=heavy[:, :2])
    with pytest.raises(ValueError, match="must not be negative"):
        evaluate(task, [model], starts, progress=False, robots=-heavy)


def test_full_horizon_oracle_with_model_params_equals_the_rebuilt_robot():
    """``FullHorizonMPC(model_params=True)``: one set of solvers for every robot; ``set_robot`` plans as the MPC of
    the rebuilt task does; an evaluation over robots re-targets it instead of rebuilding it per episode."""
    task = make_task("acrobot")
    robot = task.parameters.high
    x = np.array([np.pi - 0.3, 0.2, 0.1, -0.1])
    opts = FullHorizonOptions(solver="ipopt", solver_options={"ipopt.max_wall_time": 10.0}, warm_start=False)
    shared = FullHorizonMPC(task, opts, model_params=True)
    shared.set_robot(robot)
    u_shared, info = shared.act(x, 1.0)
    u_rebuilt, _ = FullHorizonMPC(task.with_params(robot), opts).act(x, 1.0)
    assert info.success
    np.testing.assert_allclose(u_shared, u_rebuilt, rtol=1e-6, atol=1e-8)
    shared.set_robot(None)
    u_model, _ = shared.act(x, 1.0)
    u_plain, _ = FullHorizonMPC(task, opts).act(x, 1.0)
    np.testing.assert_allclose(u_model, u_plain, rtol=1e-6, atol=1e-8)
    with pytest.raises(ValueError, match="set_robot needs FullHorizonMPC"):
        FullHorizonMPC(task, opts).set_robot(robot)


@pytest.mark.slow
def test_evaluation_over_robots_retargets_a_model_params_oracle_like_a_rebuilt_one():
    """The evaluation's oracle with ``model_params`` (built once, re-targeted per episode) flies the episode of the
    oracle rebuilt for the robot (about 2 minutes: 50 fixed-step solvers each)."""
    task = make_task("acrobot")
    robot = task.parameters.high
    opts = {"solver": "ipopt", "solver_options": {"ipopt.max_wall_time": 10.0}}
    options = tuple((k, v if not isinstance(v, dict) else tuple(v.items())) for k, v in opts.items())
    spec = PolicySpec("full", "oracle", options=(*options, ("model_params", True)), knows_robot=True)
    starts = start_grid(task, 2)[0][:1]
    run = evaluate(task, [spec], starts, progress=False, robots=robot[None, :])[0]
    ref = evaluate(
        task,
        [PolicySpec("full", "oracle", options=options, knows_robot=True)],
        starts,
        progress=False,
        robots=robot[None, :],
    )[0]
    np.testing.assert_allclose(run.final_state, ref.final_state, rtol=1e-6, atol=1e-6)


def test_evaluate_passes_the_multistart_mode_to_the_learned_mpcs(tmp_path):
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    (tmp_path / "n.pt").write_bytes(b"")
    base = ["--task", "acrobot", "--out", "o", "--network", str(tmp_path / "n.pt")]
    (spec,) = specs_from_args(parser.parse_args([*base, "--multistart", "never"]))
    assert spec.option_dict()["multistart"] == "never"
    (default,) = specs_from_args(parser.parse_args(base))
    assert "multistart" not in default.option_dict()  # the MPC's own default
    with pytest.raises(SystemExit):
        parser.parse_args([*base, "--multistart", "sometimes"])
