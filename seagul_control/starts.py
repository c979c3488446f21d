"""The starts closed-loop evaluations fly from: the evaluation grid over X0 and the held-out starts.

:func:`start_grid` is the ``n x n`` grid of the paper's figures (two coordinates of X0, ``task.profile.grid``; the
others held), :func:`sample_grid_slice` draws random starts from the slice that grid discretises (training and
member selection, never the grid's own points) and :func:`heldout_starts` is the uniform sample of X0 every
benchmark shares (seed :data:`HELDOUT_SEED`, never a training stream). Every name here is also importable from
:mod:`seagul_control.evaluation`, where it lived first.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from seagul_envs.tasks import resolve_task
from seagul_envs.tasks.base import Task

__all__ = ["HELDOUT_SEED", "heldout_starts", "sample_grid_slice", "start_grid"]


def _grid_slice(task: Task) -> tuple[np.ndarray, tuple[int, int]]:
    """The evaluation grid's slice of X0 (``task.profile.grid``): the state every grid start shares outside the
    grid's two coordinates (X0's centre, or the profile's ``fixed`` values), and those two coordinates."""
    grid = task.profile.grid
    base = 0.5 * (np.asarray(task.x0_low, dtype=np.float64) + np.asarray(task.x0_high, dtype=np.float64))
    for i, value in grid.fixed:
        base[i] = value
    return base, grid.resolved_coords(task)


def start_grid(task: Task | str, n: int) -> tuple[np.ndarray, dict[str, Any]]:
    """``n x n`` starts and a description of the grid's axes (``task.profile.grid``).

    Two coordinates span X0, the others sit at X0's centre unless the profile fixes them. Acrobot: ``(th1, th2)``
    over X0's angle box at zero velocity (Fig. 2). Glider: ``(x, z)`` over X0 with the other coordinates at the
    centre of X0 (Fig. 4).
    """
    task = resolve_task(task)
    if int(n) < 1:
        raise ValueError(f"grid size must be >= 1, got {n}")
    n = int(n)
    centre, dims = _grid_slice(task)
    axes = [np.linspace(task.x0_low[d], task.x0_high[d], n) if n > 1 else np.array([centre[d]]) for d in dims]
    starts = []
    for a in axes[0]:
        for b in axes[1]:
            x = centre.copy()
            x[dims[0]], x[dims[1]] = a, b
            starts.append(x)
    info = {
        "dims": [task.state_names[d] for d in dims],
        "axes": [ax.tolist() for ax in axes],
        "shape": [n, n],
    }
    return np.array(starts), info


def sample_grid_slice(task: Task | str, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` starts drawn uniformly on the slice of X0 that :func:`start_grid` discretises: the grid's two
    coordinates uniform over X0's range, every other one where the grid holds it (acrobot: at rest; glider: X0's
    centre). Random draws from the grid's distribution, never its points."""
    task = resolve_task(task)
    base, dims = _grid_slice(task)
    d = list(dims)
    out = np.repeat(base[None, :], int(n), axis=0)
    out[:, d] = rng.uniform(np.asarray(task.x0_low)[d], np.asarray(task.x0_high)[d], size=(int(n), 2))
    return out


#: Seed of the held-out starts every benchmark shares (never a training stream).
HELDOUT_SEED = 20211231


def heldout_starts(task: Task | str, n: int = 100) -> np.ndarray:
    """``n`` starts drawn uniformly from X0 with :data:`HELDOUT_SEED` (the same for every controller and benchmark)."""
    return resolve_task(task).sample_x0(np.random.default_rng(HELDOUT_SEED), n)
