""":mod:`seagul_control.grid_optimum`: the Bellman backups against an independent evaluation (the task's MuJoCo step
at each node, SciPy's interpolator), the value's bounds, and the greedy controller swinging dm_control's pendulum
up."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.interpolate import RegularGridInterpolator

from seagul_control.grid_optimum import GridOptimum, GridSpec

SMALL = GridSpec(angle_cells=60, velocity_points=31, velocity_max=9.0, actions=3, backups=8, policy_actions=5)


def _reference_backup(optimum: GridOptimum, values: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """One backup at ``nodes`` computed independently: MuJoCo's step per node and torque, dm_control's indicator,
    and ``values`` read by SciPy's linear interpolator on the grid extended by one period in the angle."""
    q = np.append(optimum.angles, np.pi)
    table = np.vstack([values, values[:1]])  # the node at +pi is the node at -pi
    read = RegularGridInterpolator((q, optimum.velocities), table)
    cone = math.cos(math.radians(8.0))
    out = np.full(nodes.shape[1], -np.inf)
    for u in np.linspace(-1.0, 1.0, optimum.spec.actions):
        for i in range(nodes.shape[1]):
            x = np.asarray(optimum.step(nodes[:, i], u)).ravel()
            angle = (x[0] + np.pi) % (2 * np.pi) - np.pi
            speed = np.clip(x[1], -optimum.spec.velocity_max, optimum.spec.velocity_max)
            total = float(math.cos(x[0]) >= cone) + float(read([[angle, speed]])[0])
            out[i] = max(out[i], total)
    return out


def test_each_backup_is_bellmans_recursion_evaluated_independently() -> None:
    optimum = GridOptimum(SMALL)
    nodes = optimum.nodes()
    picks = np.random.default_rng(0).choice(nodes.shape[1], 40, replace=False)
    previous = np.zeros((SMALL.angle_cells, SMALL.velocity_points))
    for k in optimum.iterate():
        assert optimum.values is not None
        expected = _reference_backup(optimum, previous, nodes[:, picks])
        np.testing.assert_allclose(optimum.values.ravel()[picks], expected, atol=1e-5)
        previous = optimum.values.copy()
        if k == 3:
            break


def test_the_grid_reward_is_the_tasks_suite_reward() -> None:
    from seagul_envs.tasks.dmc.pendulum import dmc_pendulum_reward

    optimum = GridOptimum(SMALL)
    x = np.random.default_rng(1).uniform([-4.0, -9.0], [4.0, 9.0], size=(400, 2))
    x[:5, 0] = [0.0, np.radians(7.9), -np.radians(7.9), np.radians(8.1), 2 * np.pi]  # inside, edges, a full turn
    expected = [dmc_pendulum_reward(optimum.task.params, row, np.zeros(1)) for row in x]
    np.testing.assert_array_equal(optimum._reward(x.T), expected)
    assert expected[:5] == [1.0, 1.0, 1.0, 0.0, 1.0]


def test_values_count_rewarded_steps() -> None:
    optimum = GridOptimum(SMALL)
    last = np.zeros((SMALL.angle_cells, SMALL.velocity_points))
    for k in optimum.iterate():
        assert optimum.values is not None
        assert np.all(optimum.values >= last - 1e-6), "a longer horizon never collects less"
        assert np.all(optimum.values <= k + 1e-6) and np.all(optimum.values >= 0)
        last = optimum.values.copy()
    upright, hanging = optimum.value(np.array([0.0, 0.0])), optimum.value(np.array([np.pi, 0.0]))
    assert upright == pytest.approx(SMALL.backups, abs=1e-6)  # held there every step
    assert hanging == 0.0  # 8 steps (0.16 s) from hanging at rest reach nothing
    both = optimum.value(np.array([[0.0, np.pi], [0.0, 0.0]]))
    np.testing.assert_allclose(both, [upright, hanging])


def test_the_greedy_controller_swings_the_suites_pendulum_up() -> None:
    from seagul_control.dmc import run_dmc_episode

    optimum = GridOptimum(GridSpec(angle_cells=180, velocity_points=101, actions=5, backups=500)).solve()
    episode = run_dmc_episode("pendulum-swingup", optimum, seed=4)  # a start near hanging
    assert episode.score > 600, episode.score


def test_bad_input_is_refused_with_its_name() -> None:
    with pytest.raises(ValueError, match=r"GridSpec\.angle_cells must be an integer >= 4"):
        GridSpec(angle_cells=2)
    with pytest.raises(ValueError, match=r"GridSpec\.velocity_max must be a finite number > 0"):
        GridSpec(velocity_max=float("nan"))
    optimum = GridOptimum(SMALL)
    with pytest.raises(RuntimeError, match="call solve"):
        optimum(np.zeros(2))
    optimum.solve()
    with pytest.raises(ValueError, match="must be finite"):
        optimum(np.array([np.nan, 0.0]))
