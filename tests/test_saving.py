"""Typed controller options, the deprecated keywords, saving and loading controllers, task fingerprints.

Everything runs interpreted (``jit=False``) with tiny networks, so the file stays fast.
"""

from __future__ import annotations

import inspect
import json
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

from seagul_control.lqr import LQRPolicy
from seagul_control.mpc import (
    FullHorizonMPC,
    FullHorizonOptions,
    LimitedLookaheadMPC,
    MPCOptions,
    SavedValueFunction,
    extract_value_function_file,
)
from seagul_control.transcription import Transcription, TranscriptionOptions
from seagul_envs import make_env, make_task
from seagul_envs.tasks.acrobot import AcrobotParams, make_acrobot_task
from seagul_learn.value_network import ValueEnsemble, ValueNetwork

FAST = MPCOptions(jit=False)


def _network(task, fingerprint: bool = True, seed: int = 0) -> ValueNetwork:
    rng = np.random.default_rng(seed)
    net = ValueNetwork(
        task.nx, (8,), task_name=task.name, seed=seed, task_fingerprint=task.fingerprint() if fingerprint else ""
    )
    net.set_normalization(task.sample_x0(rng, 64), rng.uniform(0, 5, 64), rng.uniform(0, 5, 64))
    return net


def _starts(task, n: int = 3) -> np.ndarray:
    rng = np.random.default_rng(11)
    return task.goal + 0.3 * (task.sample_x0(rng, n) - task.goal)


@pytest.fixture(scope="module")
def acrobot():
    return make_task("acrobot")


@pytest.fixture(scope="module")
def variant():
    """The acrobot with a heavier second link, under the same name."""
    return make_acrobot_task(AcrobotParams(m2=1.3))


# ------------------------------------------------------------------------------------------------ options
@pytest.mark.parametrize(
    ("cls", "field", "value", "message"),
    [
        (MPCOptions, "max_iter", -1, r"MPCOptions\.max_iter must be an integer >= 0, got -1"),
        (MPCOptions, "solver", "snopt", r"MPCOptions\.solver must be one of 'fatrop', 'ipopt', 'shooting', None"),
        (MPCOptions, "trust_region", "wall", r"MPCOptions\.trust_region must be one of 'box', 'lqr', 'none', None"),
        (MPCOptions, "dt", 0.0, r"MPCOptions\.dt must be a positive number or None, got 0\.0"),
        (MPCOptions, "trust_weight", float("nan"), r"MPCOptions\.trust_weight must be a finite number >= 0"),
        (MPCOptions, "jit", "yes", r"MPCOptions\.jit must be True or False, got 'yes'"),
        (MPCOptions, "trust_box", ([0, 0], [1]), r"MPCOptions\.trust_box must be None or \(low, high\)"),
        (MPCOptions, "multistart_starts", True, r"MPCOptions\.multistart_starts must be an integer >= 1"),
        (FullHorizonOptions, "cold_guess", "random", r"FullHorizonOptions\.cold_guess must be one of 'rollout'"),
        (FullHorizonOptions, "max_solve_time", -5, r"FullHorizonOptions\.max_solve_time must be a positive number"),
        (TranscriptionOptions, "time_mode", "sometimes", r"TranscriptionOptions\.time_mode must be one of 'equal'"),
        (TranscriptionOptions, "step_bounds", (0.2, 0.1), r"TranscriptionOptions\.step_bounds must be None or"),
    ],
)
def test_a_bad_option_names_its_field_and_the_allowed_values(cls, field, value, message) -> None:
    with pytest.raises(ValueError, match=message):
        cls(**{field: value})
    with pytest.raises(ValueError, match=message):
        cls().replace(**{field: value})  # replace validates too


def test_options_are_frozen_and_cross_checked() -> None:
    options = MPCOptions()
    with pytest.raises(AttributeError):
        options.max_iter = 3  # type: ignore[misc]
    with pytest.raises(ValueError, match=r"multistart='always' needs solver='shooting'"):
        MPCOptions(solver="ipopt", multistart="always")
    with pytest.raises(ValueError, match=r"final_soft_weight needs final_solver='ipopt'"):
        MPCOptions(final_soft_weight=10.0, final_solver="fatrop")
    with pytest.raises(ValueError, match=r"soft_bounds_weight .* needs solver='ipopt'"):
        TranscriptionOptions(soft_bounds_weight=1.0, solver="fatrop")


@pytest.mark.parametrize(
    "options",
    [
        MPCOptions(solver="fatrop", jit_flags=["-O2"], trust_box=([0, 1], [2, 3]), solver_options={"a.b": 1}),
        FullHorizonOptions(dt=0.05, jit_cache_dir=Path("/tmp/x")),
        TranscriptionOptions(step_bounds=[0.01, 0.1], codegen_flags=("-O1",), soft_bounds_weight=1e3),
    ],
)
def test_options_round_trip_through_json(options) -> None:
    data = json.loads(json.dumps(options.to_dict()))
    again = type(options).from_dict(data)
    assert again == options
    assert isinstance(again.to_dict(), dict) and again.to_dict() == data


def test_from_dict_rejects_unknown_keys() -> None:
    with pytest.raises(ValueError, match=r"MPCOptions\.from_dict: unknown option\(s\) \['horizon'\]; the options are"):
        MPCOptions.from_dict({"horizon": 5, "max_iter": 3})
    with pytest.raises(ValueError, match="needs a mapping"):
        FullHorizonOptions.from_dict([("max_iter", 3)])  # type: ignore[arg-type]


# ---------------------------------------------------------------------------------------- old keywords
def test_old_keywords_warn_and_still_configure_the_controllers(acrobot) -> None:
    with pytest.warns(DeprecationWarning, match=r"pass MPCOptions\(jit=\.\.\., max_iter=\.\.\., cold_guess=\.\.\.\)"):
        mpc = LimitedLookaheadMPC(acrobot, None, horizon=5, jit=False, max_iter=17, cold_guess="line")
    assert (mpc.options.max_iter, mpc.options.cold_guess, mpc.cold_guess, mpc.jit) == (17, "line", "line", False)
    with pytest.warns(DeprecationWarning, match=r"pass FullHorizonOptions\(max_iter=\.\.\.\)"):
        full = FullHorizonMPC(acrobot, max_iter=42)
    assert full.options.max_iter == 42 and full._max_iter == 42
    with pytest.warns(DeprecationWarning, match=r"pass TranscriptionOptions\(free_time=\.\.\., step=\.\.\.\)"):
        trans = Transcription(acrobot, 3, free_time=False, step=0.1)
    assert trans.options == TranscriptionOptions(free_time=False, step=0.1) and trans.step == 0.1
    with pytest.raises(TypeError, match=r"unexpected keyword argument\(s\) \['maxiter'\]"):
        LimitedLookaheadMPC(acrobot, None, 5, maxiter=3)
    with pytest.raises(TypeError, match="options must be a MPCOptions"):
        LimitedLookaheadMPC(acrobot, None, 5, FullHorizonOptions())  # type: ignore[arg-type]


def test_the_resolved_options_hold_the_task_defaults(acrobot) -> None:
    mpc = LimitedLookaheadMPC(acrobot, None, 5, FAST)
    assert FAST.end_phase is None and FAST.anchor_goal is None and FAST.trust_region is None
    resolved = mpc.options
    assert resolved.end_phase == "switch" and resolved.anchor_goal is True  # an equilibrium goal, no terminal box
    assert resolved.trust_region == acrobot.profile.mpc.trust_region == mpc.trust_region
    assert resolved.dt == acrobot.control_period and resolved.solver == mpc.solver == "shooting"
    assert resolved.cold_guess == "best" and resolved.multistart == "rise"
    # The resolved options rebuild the same controller.
    again = LimitedLookaheadMPC(acrobot, None, 5, resolved)
    assert again.options == resolved
    # The trust_region keyword wins over the options.
    assert LimitedLookaheadMPC(acrobot, None, 5, FAST, trust_region="box").options.trust_region == "box"


# ------------------------------------------------------------------------------------------------- saving
def _first_actions(mpc, starts: np.ndarray, tau: float) -> np.ndarray:
    out = []
    for x in starts:
        mpc.reset()
        u, info = mpc.act(x, tau)
        assert info.source == "solver", info
        out.append(u)
    return np.array(out)


def test_limited_lookahead_mpc_round_trip(acrobot, tmp_path: Path) -> None:
    net = _network(acrobot)
    mpc = LimitedLookaheadMPC(acrobot, net, 5, FAST.replace(goal_blend=0.5), trust_region="box")
    path = mpc.save(tmp_path / "mpc.zip")
    with zipfile.ZipFile(path) as archive:
        names = set(archive.namelist())
        data = json.loads(archive.read("data.json"))
    assert {"data.json", "value_function/scalar.casadi", "value_function/parameters.npy"} <= names
    assert {"value_function/matrix.casadi", "value_function/taylor.casadi", "value_function/network.pt"} <= names
    assert data["format"] == "seagul-mpc" and data["version"] == 1 and data["class"] == "LimitedLookaheadMPC"
    assert data["task_fingerprint"] == acrobot.fingerprint() and data["horizon"] == 5
    assert data["value_function"]["task_fingerprint"] == acrobot.fingerprint()
    assert data["options"]["goal_blend"] == 0.5 and data["options"]["trust_region"] == "box"

    loaded = LimitedLookaheadMPC.load(path)
    assert isinstance(loaded.value_function, SavedValueFunction)
    assert loaded.options == mpc.options.replace(trust_box=mpc.options.trust_box or loaded.options.trust_box)
    np.testing.assert_array_equal(loaded.trust_box[0], mpc.trust_box[0])
    starts = _starts(acrobot)
    np.testing.assert_allclose(_first_actions(loaded, starts, 3.0), _first_actions(mpc, starts, 3.0), atol=1e-9)
    x = starts[0]
    assert loaded.terminal_cost_value(x, 2.5) == pytest.approx(mpc.terminal_cost_value(x, 2.5), rel=1e-12)

    # The network itself comes back from its own file; a re-saved controller keeps it.
    back = ValueNetwork.load(extract_value_function_file(path, tmp_path / "net.pt"))
    np.testing.assert_array_equal(back.casadi_parameters(), net.casadi_parameters())
    assert back.task_fingerprint == acrobot.fingerprint()
    again = LimitedLookaheadMPC.load(loaded.save(tmp_path / "again.zip"))
    np.testing.assert_allclose(_first_actions(again, starts[:1], 3.0), _first_actions(mpc, starts[:1], 3.0), atol=1e-9)
    assert (
        extract_value_function_file(tmp_path / "again.zip", tmp_path / "net2.pt").read_bytes()
        == (tmp_path / "net.pt").read_bytes()
    )


def test_a_saved_mpc_loads_without_torch(acrobot, tmp_path: Path) -> None:
    mpc = LimitedLookaheadMPC(acrobot, _network(acrobot), 5, FAST.replace(solver="fatrop"))
    path = mpc.save(tmp_path / "mpc.zip")
    x = _starts(acrobot, 1)[0]
    expected = _first_actions(mpc, x[None], 3.0)[0]
    code = (
        "import sys, numpy as np; sys.modules['torch'] = None\n"
        "from seagul_control.mpc import LimitedLookaheadMPC\n"
        f"mpc = LimitedLookaheadMPC.load({str(path)!r})\n"
        f"u, info = mpc.act(np.array({x.tolist()!r}), 3.0)\n"
        "assert 'seagul_learn' not in sys.modules\n"
        "print(repr(float(u[0])))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert float(out.stdout.strip()) == pytest.approx(float(expected[0]), abs=1e-9)


def test_an_ensemble_and_no_value_function_round_trip(acrobot, tmp_path: Path) -> None:
    rng = np.random.default_rng(2)
    ens = ValueEnsemble(4, (8,), 2, 0.5, task_name="acrobot", seed=1)
    for net in ens.networks:
        net.set_normalization(acrobot.sample_x0(rng, 64), rng.uniform(0, 5, 64), rng.uniform(0, 5, 64))
    starts = _starts(acrobot, 2)
    for vf in (ens, None):
        mpc = LimitedLookaheadMPC(acrobot, vf, 5, FAST)
        loaded = LimitedLookaheadMPC.load(mpc.save(tmp_path / "mpc.zip"))
        assert (loaded.value_function is None) == (vf is None)
        np.testing.assert_allclose(_first_actions(loaded, starts, 3.0), _first_actions(mpc, starts, 3.0), atol=1e-9)


def test_a_value_function_over_robots_is_conditioned_after_loading(acrobot, tmp_path: Path) -> None:
    """``set_robot`` of a loaded MPC conditions the saved value function as the network's ``condition`` did."""
    rng = np.random.default_rng(4)
    net = ValueNetwork(4, (8,), task_name="acrobot", seed=0, n_params=6, theta=acrobot.theta)
    robots = acrobot.theta + rng.uniform(-0.05, 0.05, (64, 6))
    net.set_normalization(acrobot.sample_x0(rng, 64), rng.uniform(0, 5, 64), rng.uniform(0, 5, 64), robots)
    mpc = LimitedLookaheadMPC(acrobot, net, 5, FAST, model_params=True)
    loaded = LimitedLookaheadMPC.load(mpc.save(tmp_path / "robots.zip"))
    assert loaded.model_params and loaded.value_function is not None and loaded.value_function.n_params == 6
    x = _starts(acrobot, 1)
    for robot in (1.05 * acrobot.theta, None):
        mpc.set_robot(robot)
        loaded.set_robot(robot)
        assert loaded.terminal_cost_value(x[0], 2.0) == pytest.approx(mpc.terminal_cost_value(x[0], 2.0), rel=1e-12)
        np.testing.assert_allclose(_first_actions(loaded, x, 3.0), _first_actions(mpc, x, 3.0), atol=1e-9)


def test_the_robot_settings_round_trip(acrobot, tmp_path: Path) -> None:
    mpc = LimitedLookaheadMPC(acrobot, None, 5, FAST, model_params=True, estimate_robot={"window": 7, "prior": 0.01})
    loaded = LimitedLookaheadMPC.load(mpc.save(tmp_path / "estimating.zip"))
    assert loaded.model_params and loaded.estimate_robot == {"window": 7, "prior": 0.01}
    assert (loaded._estimators[0].window, loaded._estimators[0].prior) == (7, 0.01)


def test_full_horizon_mpc_round_trip(acrobot, tmp_path: Path) -> None:
    full = FullHorizonMPC(acrobot, FullHorizonOptions(max_iter=200))
    path = full.save(tmp_path / "full.zip")
    loaded = FullHorizonMPC.load(path)
    assert loaded.options == full.options and loaded.horizon == full.horizon
    starts = _starts(acrobot, 2)
    np.testing.assert_allclose(_first_actions(loaded, starts, 0.5), _first_actions(full, starts, 0.5), atol=1e-9)
    with pytest.raises(ValueError, match="holds a FullHorizonMPC, not a LimitedLookaheadMPC"):
        LimitedLookaheadMPC.load(path)


def test_lqr_round_trip_and_gain_check(acrobot, tmp_path: Path) -> None:
    lqr = LQRPolicy(acrobot)
    path = lqr.save(tmp_path / "lqr.zip")
    loaded = LQRPolicy.load(path)
    np.testing.assert_array_equal(loaded.K, lqr.K)
    obs = np.concatenate([_starts(acrobot, 4), np.full((4, 1), 2.0)], axis=1)
    np.testing.assert_array_equal(loaded.predict(obs)[0], lqr.predict(obs)[0])
    # Gains that do not match the recomputed ones are refused.
    tampered = tmp_path / "tampered.zip"
    with zipfile.ZipFile(path) as src, zipfile.ZipFile(tampered, "w") as dst:
        for name in src.namelist():
            blob = src.read(name)
            if name == "gains.npy":
                import io

                buffer = io.BytesIO()
                np.save(buffer, 1.5 * lqr.gains)
                blob = buffer.getvalue()
            dst.writestr(name, blob)
    with pytest.raises(ValueError, match="recomputed LQR gains differ from the stored ones"):
        LQRPolicy.load(tampered)
    with pytest.raises(ValueError, match="is not a 'seagul-mpc' file"):
        LimitedLookaheadMPC.load(path)


# -------------------------------------------------------------------------------------------- fingerprints
def test_loading_for_a_variant_task_names_both_fingerprints(acrobot, variant, tmp_path: Path) -> None:
    mpc = LimitedLookaheadMPC(acrobot, _network(acrobot), 5, FAST)
    path = mpc.save(tmp_path / "mpc.zip")
    message = rf"fingerprint {acrobot.fingerprint()}, but the task given \('acrobot'\) has fingerprint " + (
        rf"{variant.fingerprint()}.*load\(path, task=\.\.\.\)"
    )
    with pytest.raises(ValueError, match=message):
        LimitedLookaheadMPC.load(path, task=variant)
    with pytest.raises(ValueError, match=variant.fingerprint()):
        LQRPolicy.load(LQRPolicy(acrobot).save(tmp_path / "lqr.zip"), task=variant)
    with pytest.raises(ValueError, match=variant.fingerprint()):
        FullHorizonMPC.load(FullHorizonMPC(acrobot).save(tmp_path / "full.zip"), task=variant)


def test_a_value_function_of_another_variant_is_refused(acrobot, variant) -> None:
    net = _network(acrobot)
    with pytest.raises(ValueError, match=rf"fingerprint {acrobot.fingerprint()}, but task 'acrobot' has fingerprint"):
        LimitedLookaheadMPC(variant, net, 5, FAST)
    # Its own variant's network, and a network without a fingerprint, are accepted.
    assert LimitedLookaheadMPC(variant, _network(variant), 5, FAST).n_vf > 0
    assert LimitedLookaheadMPC(variant, _network(acrobot, fingerprint=False), 5, FAST).n_vf > 0
    mpc = LimitedLookaheadMPC(acrobot, net, 5, FAST)
    with pytest.raises(ValueError, match="another variant"):
        mpc.set_value_function(_network(variant))


def test_a_robot_variant_made_by_with_params_keeps_its_models_value_function(acrobot) -> None:
    """The oracle / adaptive controller: an MPC planning with ``task.with_params(robot)`` uses the value learned
    for ``task`` (the evaluation's ``knows_robot`` builds exactly that), through a chain of variants and a pickle."""
    import pickle

    robot = acrobot.theta * 1.1
    known = acrobot.with_params(robot)
    assert known.fingerprint() != acrobot.fingerprint() and known.origin_fingerprint() == acrobot.fingerprint()
    again = pickle.loads(pickle.dumps(known.with_params(robot * 1.05)))
    assert again.origin_fingerprint() == acrobot.fingerprint() and acrobot.origin_fingerprint() == acrobot.fingerprint()
    net = _network(acrobot)
    assert LimitedLookaheadMPC(known, net, 5, FAST).n_vf > 0
    assert LimitedLookaheadMPC(again, net, 5, FAST).n_vf > 0
    # A network trained for the variant is not one for the model it came from.
    with pytest.raises(ValueError, match="not made from it by with_params"):
        LimitedLookaheadMPC(acrobot, _network(known), 5, FAST)


def test_network_files_store_the_fingerprint_and_old_files_still_load(acrobot, tmp_path: Path) -> None:
    net = _network(acrobot)
    ValueNetwork.load(net.save(tmp_path / "net.pt"))
    assert ValueNetwork.load(tmp_path / "net.pt").task_fingerprint == acrobot.fingerprint()
    payload = torch.load(tmp_path / "net.pt", weights_only=True)
    assert payload["task_fingerprint"] == acrobot.fingerprint()
    del payload["task_fingerprint"]  # a file written before the key existed
    torch.save(payload, tmp_path / "old.pt")
    old = ValueNetwork.load(tmp_path / "old.pt")
    assert old.task_fingerprint == ""
    np.testing.assert_array_equal(old.casadi_parameters(), net.casadi_parameters())
    ens = ValueEnsemble(4, (8,), 2, task_name="acrobot", task_fingerprint=acrobot.fingerprint())
    loaded = ValueNetwork.load(ens.save(tmp_path / "ens.pt"))
    assert isinstance(loaded, ValueEnsemble) and loaded.task_fingerprint == acrobot.fingerprint()
    assert loaded.subset([1, 0]).task_fingerprint == acrobot.fingerprint()


# ------------------------------------------------------------------------------------ SB3 predictor protocol
def test_the_controllers_satisfy_sb3s_policy_predictor_protocol(acrobot) -> None:
    from stable_baselines3.common.type_aliases import PolicyPredictor

    protocol = inspect.signature(PolicyPredictor.predict)
    policies = [LimitedLookaheadMPC(acrobot, None, 5, FAST), FullHorizonMPC(acrobot), LQRPolicy(acrobot)]
    for policy in policies:
        ours = inspect.signature(type(policy).predict)
        assert list(ours.parameters) == list(protocol.parameters), type(policy).__name__
        for name, param in protocol.parameters.items():
            mine = ours.parameters[name]
            assert mine.kind == param.kind, (type(policy).__name__, name)
            # Every optional argument of the protocol is optional here too (callers may omit it).
            assert (mine.default is inspect.Parameter.empty) == (param.default is inspect.Parameter.empty), name
    env = make_env("acrobot")
    obs, _ = env.reset(seed=0)
    for policy in policies:
        actions, state = policy.predict(obs, state=None, episode_start=np.array([True]), deterministic=True)
        assert actions.shape == env.action_space.shape and env.action_space.contains(actions) and state is None
    env.close()


def test_a_value_function_fed_its_robots_invariants_is_conditioned_after_loading(tmp_path: Path) -> None:
    """A network (and an ensemble) over gliders fed ``log(theta) @ E.T`` (``theta_features``): the loaded MPC's
    value at a robot equals the original's, and gliders with equal products get equal values."""
    glider = make_task("glider")
    space = glider.parameters
    rng = np.random.default_rng(5)
    robots = space.sample(rng, 64)
    x0 = glider.sample_x0(rng, 64)
    for vf in (
        ValueNetwork(7, (8,), task_name="glider", seed=0, n_params=4, theta=glider.theta,
                     theta_features=space.feature_exponents()),
        ValueEnsemble(7, (8,), 2, task_name="glider", seed=0, n_params=4, theta=glider.theta,
                      theta_features=space.feature_exponents()),
    ):  # fmt: skip
        for net in vf.networks if isinstance(vf, ValueEnsemble) else [vf]:
            net.set_normalization(x0, rng.uniform(0.5, 1.0, 64), rng.uniform(0, 5, 64), robots)
        mpc = LimitedLookaheadMPC(glider, vf, 3, FAST, model_params=True)
        loaded = LimitedLookaheadMPC.load(mpc.save(tmp_path / f"{type(vf).__name__}.zip"))
        saved = loaded.value_function
        assert isinstance(saved, SavedValueFunction) and saved.n_params == 4
        np.testing.assert_array_equal(saved.condition_exponents, space.feature_exponents())
        robot = robots[0]
        same = robot * np.array([1.0, 1 / 1.1, 1 / 1.1, 1.1])  # the same products: flies identically
        values = []
        for theta in (robot, same, robots[1], None):
            mpc.set_robot(theta)
            loaded.set_robot(theta)
            value = mpc.terminal_cost_value(x0[0], 0.7)
            assert loaded.terminal_cost_value(x0[0], 0.7) == pytest.approx(value, rel=1e-12)
            values.append(value)
        assert values[0] == pytest.approx(values[1], rel=1e-12) and values[0] != pytest.approx(values[2], rel=1e-6)
