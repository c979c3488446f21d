"""The do-mpc peer MPC (seagul_control.do_mpc_policy): the same discrete problem as the project's MPC, a closed loop,
the glider's build, and the message when the optional extra is missing."""

from __future__ import annotations

import sys

import numpy as np
import pytest

pytest.importorskip("do_mpc", reason="do-mpc is an optional extra: pip install 'seagul[anchors]'")

from seagul_control.do_mpc_policy import INSTALL_HINT, DoMPCPolicy
from seagul_control.evaluation import POLICY_KINDS, PolicySpec, build_policy, evaluate, run_policy_episode
from seagul_control.mpc import LimitedLookaheadMPC, MPCOptions
from seagul_envs import make_task

HORIZON = 5


@pytest.fixture(scope="module")
def acrobot():
    return make_task("acrobot")


@pytest.fixture(scope="module")
def acrobot_policy(acrobot):
    return DoMPCPolicy(acrobot, HORIZON, tol=1e-9, max_iter=200)


def test_first_action_matches_the_project_mpc(acrobot, acrobot_policy):
    # Same discrete problem (RK4 step, dt * l, the task's l_f, input box, N steps), both solved to a KKT tolerance of
    # 1e-9 from a cold start: the optimal first inputs agree to 1e-5 N m (observed <= 2e-8; 1e-5 leaves room for the
    # two solvers' different stopping points on a problem whose input Hessian is ~dt * R = 1e-3 at its smallest).
    # The starts are X0 draws whose first input is not on a bound (a saturated input would agree trivially).
    project = LimitedLookaheadMPC(acrobot, None, HORIZON, MPCOptions(jit=False, tol=1e-9, max_iter=200))
    starts = [
        acrobot.goal + np.array([0.05, -0.05, 0.1, -0.1]),
        *np.random.default_rng(1).uniform(acrobot.x0_low, acrobot.x0_high, size=(3, acrobot.nx)),
    ]
    unsaturated = 0
    for x0 in starts:
        ours, info = acrobot_policy.act(x0, acrobot.tau_nominal, new_episode=True)
        theirs, their_info = project.act(x0, acrobot.tau_nominal)
        project.reset()
        assert info.success and their_info.success, (info.status, their_info.status)
        np.testing.assert_allclose(ours, theirs, atol=1e-5)
        unsaturated += bool(np.all(np.abs(theirs) < acrobot.u_high - 1e-3))
    assert unsaturated >= 2


def test_closed_loop_balances_from_near_the_goal(acrobot, acrobot_policy):
    acrobot_policy.reset_stats()
    x0 = acrobot.goal + np.array([0.1, -0.1, 0.2, -0.2])
    result, infos = run_policy_episode(acrobot, acrobot_policy, x0)
    assert result.success and result.final_distance < 0.05
    steps = result.steps
    assert len(infos) == steps and len(acrobot_policy.solve_times) == steps and len(acrobot_policy.statuses) == steps
    assert all(ok for _, ok in acrobot_policy.statuses)
    assert all(t > 0 for t in acrobot_policy.solve_times) and result.fallbacks == 0
    assert len(result.solve_times) == steps  # run_policy_episode reads the policy's stats like the project MPC's


def test_batched_observations_and_bad_input(acrobot, acrobot_policy):
    obs = np.tile(np.r_[acrobot.goal + 0.01, acrobot.tau_nominal], (2, 1))
    actions, _ = acrobot_policy.predict(obs, episode_start=np.array([True, True]))
    assert actions.shape == (2, 1) and actions.dtype == np.float32
    np.testing.assert_allclose(actions[0], actions[1], atol=1e-6)
    with pytest.raises(ValueError, match="observation"):
        acrobot_policy.predict(np.zeros(3))
    with pytest.raises(ValueError, match="horizon"):
        DoMPCPolicy(acrobot, 0)


def test_features_do_mpc_cannot_express_raise(acrobot):
    with pytest.raises(NotImplementedError, match="free step lengths"):
        DoMPCPolicy(acrobot, HORIZON, steps="free")
    with pytest.raises(NotImplementedError, match="learned terminal cost"):
        DoMPCPolicy(acrobot, HORIZON, terminal="network")


def test_glider_builds_and_runs():
    task = make_task("glider")
    policy = DoMPCPolicy(task, 4)
    assert policy.end_phase == "mask"  # the glider's terminal box: the episode's end is a time-varying parameter
    x0 = 0.5 * (task.x0_low + task.x0_high)
    for tau in (task.tau_nominal, 2 * task.control_period):  # a lookahead step, and one whose horizon ends early
        action, _ = policy.predict(np.r_[x0, tau], episode_start=np.array([True]))
        assert action.shape == (1,) and np.all(np.isfinite(action))
        assert np.all(action >= task.u_low - 1e-6) and np.all(action <= task.u_high + 1e-6)
    assert [info.phase for info in policy.stats] == ["lookahead", "final"]


def test_missing_extra_names_the_install_command(monkeypatch, acrobot):
    # None in sys.modules: any import of do_mpc raises ImportError, as when the package is not installed.
    monkeypatch.setitem(sys.modules, "do_mpc", None)
    with pytest.raises(ImportError) as err:
        DoMPCPolicy(acrobot, HORIZON)
    assert str(err.value) == INSTALL_HINT == "do-mpc is not installed: pip install 'seagul[anchors]'"


def test_the_do_mpc_policy_kind_builds_it_for_an_evaluation(acrobot):
    assert "do-mpc" in POLICY_KINDS
    spec = PolicySpec("do-mpc", "do-mpc-3", None, (("horizon", 3),))
    policy = build_policy(acrobot, spec)
    assert isinstance(policy, DoMPCPolicy) and policy.horizon == 3
    (result,) = evaluate(acrobot, [spec], acrobot.goal[None, :] + 0.01, progress=False)
    assert result.success and result.steps == 50 and len(result.solve_times) == 50
