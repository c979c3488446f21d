"""``seagul evaluate --dmc``: a learned MPC in dm_control's own episode prints the contract's JSON object last; the
deployment's settings reach the MPC; bad input names the problem."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

pytest.importorskip("dm_control.suite", reason="dm_control is optional: pip install 'seagul[dmc]'")
pytest.importorskip("shimmy", reason="shimmy wraps dm_control for Gymnasium: pip install 'seagul[dmc]'")

from seagul_control.dmc import dmc_env_id, make_dmc_env, run_dmc_episode
from seagul_learn.cli import main
from seagul_learn.dmc_eval import DEFAULT_DEPLOYMENTS, DMCDeployment, learned_dmc_controller
from seagul_learn.value_network import ValueNetwork

#: Small and interpreted, so the test builds no C code: a 4-unit network, 2 steps of lookahead, one decision per
#: 10 control steps (100 decisions per episode).
FAST = ["--horizon", "2", "--hold", "10", "--time-to-go", "1", "--no-jit", "--no-progress"]


@pytest.fixture(scope="module")
def network_file(tmp_path_factory: pytest.TempPathFactory) -> str:
    network = ValueNetwork(2, hidden=(4,), task_name="dmc_pendulum", seed=0, periodic=(0,))
    path = tmp_path_factory.mktemp("dmc") / "pendulum.pt"
    network.save(path)
    return str(path)


def last_json(text: str) -> dict:
    return json.loads(text.strip().splitlines()[-1])


def test_cli_prints_the_contract_json_last(network_file: str, capsys: pytest.CaptureFixture[str]) -> None:
    args = ["evaluate", "--dmc", "pendulum-swingup", "--network", network_file, "--episodes", "2", "--seed", "3"]
    assert main([*args, *FAST]) == 0
    result = last_json(capsys.readouterr().out)
    assert {"task", "score_mean", "score_std", "episodes", "median_ms", "p95_ms"} <= set(result)
    assert result["task"] == "pendulum-swingup" and result["episodes"] == 2 and result["seeds"] == [3, 4]
    assert (result["horizon"], result["hold"], result["time_to_go"]) == (2, 10, 1.0)
    assert 0.0 <= result["score_mean"] <= 1000.0 and result["median_ms"] > 0
    assert result["score_mean"] == pytest.approx(np.mean(result["scores"]), abs=1e-3)
    assert result["score_std"] == pytest.approx(np.std(result["scores"]), abs=1e-3)

    # The same controller stepped through dm_control by the scoring runner gives the same return (deterministic).
    # The CLI's flags replace those fields of the env's deployment and keep the rest (its lookahead interval).
    setting = dataclasses.replace(
        DEFAULT_DEPLOYMENTS[dmc_env_id("pendulum-swingup")], horizon=2, time_to_go=1.0, hold=10
    )
    controller = learned_dmc_controller("pendulum-swingup", ValueNetwork.load(network_file), setting, jit=False)
    env = make_dmc_env("pendulum-swingup")
    try:
        episode = run_dmc_episode("pendulum-swingup", controller, 3, hold=10, env=env)
    finally:
        env.close()
    assert episode.score == pytest.approx(result["scores"][0], abs=1e-3)


def test_the_deployment_sets_the_mpc() -> None:
    network = ValueNetwork(2, hidden=(4,), task_name="dmc_pendulum", seed=0, periodic=(0,))
    controller = learned_dmc_controller("pendulum-swingup", network, DMCDeployment(3, 2.0, 5), jit=False)
    assert controller.policy.horizon == 3
    assert controller.policy.dt == pytest.approx(5 * 0.02)  # hold x the suite's control period
    assert controller.tau(0.0) == pytest.approx(2.0 + 3 * 5 * 0.02)  # tau_V + N dt, constant
    assert controller.tau(17.0) == controller.tau(0.0)
    default = DEFAULT_DEPLOYMENTS["dm_control/pendulum-swingup-v0"]
    assert learned_dmc_controller("pendulum-swingup", network, jit=False).policy.horizon == default.horizon


def test_the_lookahead_interval_and_path_bounds_are_the_deployments() -> None:
    """The cart-pole's setting: one decision per 0.01 s control step over 0.05 s intervals, the rail bound a penalty
    in the lookahead's stage cost so the condensed solver applies (with the bound kept the MPC solves by fatrop)."""
    import casadi as ca

    network = ValueNetwork(4, hidden=(4,), task_name="dmc_cartpole", seed=0, periodic=(1,))
    soft = learned_dmc_controller(
        "cartpole-swingup", network, DMCDeployment(3, 2.0, 1, dt=0.05, path_bounds="soft"), jit=False
    )
    assert soft.policy.dt == pytest.approx(0.05) and soft.policy.solver == "shooting"
    assert soft.tau(0.0) == pytest.approx(2.0 + 3 * 0.05)
    planned = soft.policy.task
    assert np.all(np.isinf(planned.x_low)) and np.all(np.isinf(planned.x_high))
    hard = learned_dmc_controller("cartpole-swingup", network, DMCDeployment(3, 2.0, 1, dt=0.05), jit=False)
    assert hard.policy.solver != "shooting" and hard.policy.task.x_high[0] == pytest.approx(1.8)
    # The penalty: zero inside the margin, w * excess^2 beyond it, on either side; the physics unchanged.
    task = hard.policy.task
    u = np.zeros(1)
    for slider, excess in ((0.0, 0.0), (1.5, 0.0), (1.7, 0.2), (-1.9, 0.4)):
        x = np.array([slider, 0.3, 0.1, -0.2])
        extra = float(planned.stage_cost(x, u)) - float(task.stage_cost(x, u))
        assert extra == pytest.approx(2000.0 * excess**2, rel=1e-9, abs=1e-12)
    x, v = np.array([0.4, 2.0, 0.3, -1.0]), np.array([0.5])
    assert np.allclose(np.asarray(planned.dynamics(x, v)), np.asarray(task.dynamics(x, v)))
    none = learned_dmc_controller(
        "cartpole-swingup", network, DMCDeployment(3, 2.0, 1, dt=0.05, path_bounds="none"), jit=False
    )
    assert none.policy.solver == "shooting"
    assert float(none.policy.task.stage_cost(np.array([1.9, 0.3, 0.1, -0.2]), u)) == pytest.approx(
        float(task.stage_cost(np.array([1.9, 0.3, 0.1, -0.2]), u))
    )
    assert isinstance(planned.stage_cost, ca.Function)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"horizon": 0}, "horizon"),
        ({"hold": 0}, "hold"),
        ({"time_to_go": -1.0}, "time_to_go"),
        ({"time_to_go": float("nan")}, "time_to_go"),
        ({"dt": 0.0}, "dt"),
        ({"dt": float("inf")}, "dt"),
        ({"path_bounds": "keep"}, "path_bounds"),
        ({"soft_bound_weight": -1.0}, "soft_bound_weight"),
        ({"soft_bound_margin": float("nan")}, "soft_bound_margin"),
    ],
)
def test_deployment_rejects_bad_values(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        DMCDeployment(**kwargs)


def test_a_network_of_another_task_is_refused() -> None:
    network = ValueNetwork(4, hidden=(4,), task_name="acrobot", seed=0)
    with pytest.raises(ValueError, match="trained on 'acrobot'"):
        learned_dmc_controller("pendulum-swingup", network, jit=False)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--dmc", "pendulum-upright"], "unknown DeepMind Control Suite env"),
        (["--dmc", "pendulum-swingup", "--task", "acrobot"], "no --task"),
        (["--dmc", "pendulum-swingup", "--out", "x"], "no --out"),
        ([], "--task and --out are required"),
    ],
)
def test_cli_errors_name_the_problem(
    network_file: str, extra: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["evaluate", "--network", network_file, *extra]) == 2
    assert message in capsys.readouterr().err


def test_cli_needs_one_existing_network(network_file: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["evaluate", "--dmc", "pendulum-swingup", "--network", network_file, "--network", network_file]) == 2
    assert "exactly one --network" in capsys.readouterr().err
    assert main(["evaluate", "--dmc", "pendulum-swingup", "--network", "missing.pt"]) == 2
    assert "no such file" in capsys.readouterr().err
