"""Per-task knowledge the learning, control and reporting code needs, carried by the task (docs/reference/spec.md §2.1).

A :class:`TaskProfile` is the ``profile`` field of every :class:`~seagul_envs.tasks.base.Task`. It holds what is
not the optimal-control problem itself but how the library treats the task: the trajectory optimizer's attempt plan
(:class:`SolverDefaults`), the validation set (:class:`ValidationSpec`), the episode success rule
(:class:`SuccessRule`), the LQR weights, the Gymnasium id, the controller it is evaluated with
(:class:`~seagul_envs.tasks.mpc_defaults.MPCDefaults`), the closed-loop evaluation grid (:class:`EvaluationGrid`)
and the figures' axes and captions. The built-in tasks fill theirs in their own modules
(``seagul_envs/tasks/acrobot.py``, ``glider.py``); a new task gets the defaults of every field, which are chosen to
work for any task (the fields say how). No code outside the task definitions branches on a task's name.

The profile is plain data (numbers, strings, tuples, small dataclasses, arrays), so it pickles with the task and
enters :meth:`Task.fingerprint <seagul_envs.tasks.base.Task.fingerprint>`: two tasks whose solver plans differ never
share a cached solve. ``success`` may also be any picklable callable ``(task, x, terminated) -> bool``.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import operator
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from seagul_envs.tasks.mpc_defaults import LEGACY_NAMES as _MPC_LEGACY
from seagul_envs.tasks.mpc_defaults import TRUST_REGIONS as TRUST_REGIONS  # re-exported
from seagul_envs.tasks.mpc_defaults import MPCDefaults
from seagul_envs.tasks.profile_legacy import (
    _accept_flat_mpc_names,
    _given_only,
    _MovedToRecipes,
    legacy_module_attribute,
)

if TYPE_CHECKING:
    from seagul_envs.tasks.base import Task

VALIDATION_SEED = 20210718
"""Seed of the uniform draws of every validation set: one set for all training seeds (docs/reference/spec.md §12.1)."""

PLAN_SOLVERS = ("ipopt", "ipopt_fast", "fatrop")
"""Solvers an attempt ``"solver:guess"`` of :attr:`SolverDefaults.plan` may name (``seagul_learn.trajopt``)."""
PLAN_GUESSES = ("line", "goal", "hold", "kinematic")
"""Initial guesses an attempt, or :attr:`SolverDefaults.multi_start_guesses`, may name."""
MULTI_START = ("never", "on_suspect", "always")
"""Values of :attr:`SolverDefaults.multi_start`."""
HEATMAP_METRICS = ("final_distance", "cost")
"""Values of :attr:`TaskProfile.heatmap_metric`."""


@dataclass(frozen=True)
class SolverDefaults:
    """The trajectory optimizer's defaults for a task: the fields a :class:`~seagul_learn.trajopt.TrajOptConfig`
    leaves at None (docs/experiments/trajopt.md, docs/reference/spec.md §6.4)."""

    plan: tuple[str, ...] | None = None
    """Attempts ``"solver:guess"`` tried in order until one succeeds. None: derived from the config's ``solver``
    and ``guesses`` (default ``("ipopt:line", "ipopt:goal")``), the safe choice for a new task."""
    multi_start: str = "never"
    """``"never"``, ``"on_suspect"`` (re-solve from ``multi_start_guesses`` when a value exceeds
    ``suspect_value``) or ``"always"``."""
    multi_start_guesses: tuple[str, ...] = ("goal",)
    """Extra guesses of the multi-start."""
    suspect_value: float = math.inf
    """Value above which ``multi_start="on_suspect"`` triggers."""
    kinematic_pairs: tuple[tuple[int, int], ...] = ()
    """(position, velocity) state index pairs made consistent by the ``"kinematic"`` guess (none: it is the line)."""
    tail_soft_bounds_weight: float | None = None
    """Tail problems (from planned terminal states, mid-trajectory knots) impose the state bounds of their knots
    (path bounds, terminal box) as the exact L1 penalty of this weight instead of as bounds
    (``TrajOptConfig.soft_bounds_weight``); None: as bounds. For a task whose box may be unreachable, or whose crash
    unavoidable, from the states a planner visits (the glider's perch), the hard tail is infeasible there and
    teaches nothing; the soft one gives a large, graded value. Choose it above the bounds' multipliers on the data
    (then the soft value equals the hard one wherever the bounds can be met)."""

    def __post_init__(self) -> None:
        if self.plan is not None:
            object.__setattr__(self, "plan", tuple(self.plan))
            if not self.plan:
                raise ValueError("SolverDefaults.plan must name at least one attempt 'solver:guess' (or be None)")
            for attempt in self.plan:
                solver, _, guess = str(attempt).partition(":")
                if solver not in PLAN_SOLVERS or guess not in PLAN_GUESSES:
                    raise ValueError(
                        f"SolverDefaults.plan: attempt {attempt!r} must be 'solver:guess' with a solver of "
                        f"{list(PLAN_SOLVERS)} and a guess of {list(PLAN_GUESSES)}"
                    )
        if self.multi_start not in MULTI_START:
            raise ValueError(f"SolverDefaults.multi_start must be one of {list(MULTI_START)}, got {self.multi_start!r}")
        object.__setattr__(self, "multi_start_guesses", tuple(self.multi_start_guesses))
        bad = [g for g in self.multi_start_guesses if g not in PLAN_GUESSES]
        if bad:
            raise ValueError(
                f"SolverDefaults.multi_start_guesses: unknown guesses {bad}; choose from {list(PLAN_GUESSES)}"
            )

    def config_defaults(self) -> dict[str, Any]:
        """The defaults as :class:`~seagul_learn.trajopt.TrajOptConfig` field values (``plan`` only when set)."""
        out: dict[str, Any] = {
            "multi_start": self.multi_start,
            "multi_start_guesses": tuple(self.multi_start_guesses),
            "suspect_value": float(self.suspect_value),
        }
        if self.plan is not None:
            out["plan"] = tuple(self.plan)
        return out


@dataclass(frozen=True)
class ValidationSpec:
    """A validation set: a grid over some coordinates of X0 (the others at X0's centre) plus uniform draws from X0,
    all at the nominal time to go (docs/reference/spec.md §3.6, §4.6)."""

    grid_coords: tuple[int, ...]
    """State coordinates spanned by the grid."""
    grid_points: int
    """Points per grid coordinate (grid bounds are X0's)."""
    num_random: int
    """Uniform draws from X0 added to the grid (seed :data:`VALIDATION_SEED`)."""

    def starts(self, task: Task) -> np.ndarray:
        """The start states (grid first, then the draws)."""
        centre = 0.5 * (task.x0_low + task.x0_high)
        axes = [np.linspace(task.x0_low[j], task.x0_high[j], self.grid_points) for j in self.grid_coords]
        grid = np.tile(centre, (self.grid_points ** len(self.grid_coords), 1))
        for row, point in enumerate(itertools.product(*axes)):
            grid[row, list(self.grid_coords)] = point
        draws = task.sample_x0(np.random.default_rng(VALIDATION_SEED), self.num_random)
        return np.vstack([grid, draws])


_COMPARISONS: dict[str, Callable[[Any, Any], Any]] = {"<": operator.lt, "<=": operator.le}


@dataclass(frozen=True)
class SuccessRule:
    """When a closed-loop episode succeeded, from its final state ``x(T)`` (and whether it left the state bounds).

    Every condition given must hold: ``||x(T)[coords] - x*[coords]||_2 < distance`` (unless ``distance`` is None),
    each ``|x(T)[i] - x*[i]| OP tol`` of ``per_coordinate`` (``OP`` is ``"<"`` or ``"<="``), and, with
    ``fail_on_termination``, the episode did not end by leaving the state bounds. The default is the acrobot's rule
    without its exemption: within 0.05 of the goal in every coordinate, still inside the bounds.
    """

    distance: float | None = 0.05
    """Euclidean tolerance to the goal over ``coords`` (strict); None: no distance condition."""
    coords: tuple[int, ...] | None = None
    """State coordinates of the distance (None: all)."""
    per_coordinate: tuple[tuple[int, str, float], ...] = ()
    """``(i, "<" or "<=", tol)``: ``|x(T)[i] - x*[i]| OP tol``."""
    fail_on_termination: bool = True
    """An episode that left the state bounds (a crash) is a failure."""

    def __call__(self, task: Task, x: Any, terminated: bool = False) -> bool:
        """Whether the final state ``x`` of an episode of ``task`` is a success."""
        err = np.asarray(x, dtype=np.float64) - task.goal
        if self.fail_on_termination and terminated:
            return False
        if self.distance is not None:
            sel = err if self.coords is None else err[list(self.coords)]
            if not np.linalg.norm(sel) < self.distance:
                return False
        return all(bool(_COMPARISONS[op](abs(err[i]), tol)) for i, op, tol in self.per_coordinate)

    def violation(self, task: Task, x: Any) -> float:
        """How far the final state ``x`` misses the rule, in units of its tolerances: the sum over its conditions of
        ``max(0, |e| - tol) / tol`` (``|e|`` the distance or the coordinate's error). 0 where every condition
        holds up to its boundary; continuous in ``x``, so a learner's penalty on it has a slope towards the goal
        (``seagul_learn.baselines.SB3Config.miss_penalty``). The bounds' condition is not part of it."""
        err = np.asarray(x, dtype=np.float64) - task.goal
        total = 0.0
        if self.distance is not None:
            sel = err if self.coords is None else err[list(self.coords)]
            total += max(0.0, float(np.linalg.norm(sel)) - self.distance) / self.distance
        for i, _, tol in self.per_coordinate:
            total += max(0.0, abs(float(err[i])) - tol) / tol
        return total

    def scaled(self, factor: float) -> SuccessRule:
        """This rule with every tolerance (the distance and each coordinate's) times ``factor``; the bounds'
        condition unchanged. ``scaled(2.0)`` of the acrobot's rule is ``||x(T) - x*|| < 0.1``."""
        factor = float(factor)
        if not (factor > 0 and np.isfinite(factor)):
            raise ValueError(f"SuccessRule.scaled: factor must be a finite number > 0, got {factor}")
        return replace(
            self,
            distance=None if self.distance is None else self.distance * factor,
            per_coordinate=tuple((i, op, tol * factor) for i, op, tol in self.per_coordinate),
        )

    def scale_needed(self, task: Task, x: Any, terminated: bool = False) -> float:
        """The factor by which every tolerance must be scaled for the final state ``x`` to meet the rule: the
        largest ``|e| / tol`` over its conditions (:meth:`scaled` of any larger factor succeeds; at exactly this
        factor a strict condition still fails). Infinite for an episode the rule fails whatever the tolerance (it
        left the bounds under ``fail_on_termination``); 0 for a rule without conditions."""
        if self.fail_on_termination and terminated:
            return float("inf")
        err = np.asarray(x, dtype=np.float64) - task.goal
        ratios = []
        if self.distance is not None:
            sel = err if self.coords is None else err[list(self.coords)]
            ratios.append(float(np.linalg.norm(sel)) / self.distance)
        ratios += [abs(float(err[i])) / tol for i, _, tol in self.per_coordinate]
        return max(ratios, default=0.0)

    def describe(self, task: Task) -> str:
        """The rule in one line, e.g. ``||x(T) - x*|| < 0.05``."""
        parts = []
        if self.distance is not None:
            if self.coords is None:
                parts.append(f"||x(T) - x*|| < {self.distance:g}")
            else:
                names = ", ".join(task.state_names[i] for i in self.coords)
                parts.append(f"||({names})(T) - goal|| < {self.distance:g}")
        parts += [f"|{task.state_names[i]}(T) - goal| {op} {tol:g}" for i, op, tol in self.per_coordinate]
        if self.fail_on_termination and (np.isfinite(task.x_low).any() or np.isfinite(task.x_high).any()):
            parts.append("inside the state bounds")
        return ", ".join(parts) or "always"


@dataclass(frozen=True)
class EvaluationGrid:
    """The closed-loop start grid (``seagul_control.evaluation.start_grid``): ``n x n`` starts over two coordinates
    spanning X0, every other coordinate at X0's centre unless ``fixed`` sets it."""

    coords: tuple[int, int] | None = None
    """The two state coordinates of the grid (None: the first two along which X0 has a nonzero width, completed by
    the lowest remaining indices)."""
    fixed: tuple[tuple[int, float], ...] = ()
    """``(i, value)``: coordinates held at ``value`` instead of X0's centre."""
    points: int = 10
    """Default points per axis (``seagul evaluate`` without ``--grid``)."""

    def resolved_coords(self, task: Task) -> tuple[int, int]:
        """:attr:`coords`, or the default for ``task``."""
        if self.coords is not None:
            return (int(self.coords[0]), int(self.coords[1]))
        if task.nx < 2:
            raise ValueError(f"{task.name}: the evaluation grid needs two state coordinates, the task has {task.nx}")
        width = np.asarray(task.x0_high) - np.asarray(task.x0_low)
        spanned = [i for i in range(task.nx) if width[i] > 0]
        rest = [i for i in range(task.nx) if i not in spanned]
        first, second = (spanned + rest)[:2]
        return (first, second) if first < second else (second, first)


@dataclass(frozen=True)
class TrajectoryPlot:
    """A figure of recorded closed-loop paths in the plane of two state coordinates (the glider's x-z, Fig. 3)."""

    axes: tuple[int, int]
    """State coordinates of the horizontal and the vertical axis."""
    labels: tuple[str, str] | None = None
    """Axis labels (None: the state names)."""
    goal_label: str = "goal"
    """Legend entry of the goal's marker."""
    title: str = "trajectories (o = success, x = failure)"
    """Figure title."""
    caption: str = "Recorded closed-loop trajectories (seed-0 networks)"
    """Report caption of the figure."""


def with_recipe_book(profile: TaskProfile, book: str) -> TaskProfile:
    """``profile`` marked as a built-in task's, whose recipe file is ``book`` (what the deprecated read of
    ``presets`` / ``train_recipe`` returns)."""
    object.__setattr__(profile, "_recipe_book", book)
    return profile


@dataclass(frozen=True, eq=False)
class TaskProfile:
    """How the library treats a task beyond its optimal-control problem (see the module docstring).

    Every field has a default that works for any task; the built-in tasks set theirs in their task modules.
    """

    solver: SolverDefaults = field(default_factory=SolverDefaults)
    """The trajectory optimizer's attempt plan and multi-start (docs/reference/spec.md §6.4)."""
    validation: ValidationSpec | None = None
    """The validation set. None: a 10 x 10 grid over the two coordinates of :attr:`grid` plus 100 uniform draws."""
    success: SuccessRule | Callable[..., bool] = field(default_factory=SuccessRule)
    """Episode success: a :class:`SuccessRule` or a picklable callable ``(task, x_final, terminated) -> bool``."""
    success_text: str | None = None
    """The success condition in one line for reports (None: :meth:`SuccessRule.describe`, or ``"success"``)."""
    success_goal: str | None = None
    """What a controller manages to do when it succeeds, for reports (None: ``"reach the goal (<success_text>)"``)."""
    success_column: str | None = None
    """Extra name of the success-rate column in evaluation summaries (the glider's ``"perch_success_rate"``)."""
    lqr_Q: np.ndarray | None = None
    """State weight of the LQR reference (None: ``extras["Q"]`` or the identity at an equilibrium goal; ``extras["Qf"]``
    or the identity for the time-varying LQR)."""
    lqr_R: np.ndarray | None = None
    """Input weight of the LQR reference (None: ``extras["R"]`` or the identity at an equilibrium goal; ``0.01 I`` for
    the time-varying LQR)."""
    presets: Mapping[str, Mapping[str, Any]] = field(
        default=_MovedToRecipes(),  # type: ignore[arg-type]
        metadata={"fingerprint_skip": _given_only("presets")},
    )
    """Deprecated: experiment presets are data in ``seagul_learn/recipes/<task>.yml``
    (:func:`seagul_learn.recipes.preset`). Given, they are the task's presets (with a ``DeprecationWarning``)."""
    train_recipe: Mapping[str, Any] = field(
        default=_MovedToRecipes(),  # type: ignore[arg-type]
        metadata={"fingerprint_skip": _given_only("train_recipe")},
    )
    """Deprecated: training recipes are data in ``seagul_learn/recipes/<task>.yml``
    (:func:`seagul_learn.recipes.recipe`, :meth:`~seagul_learn.training.TrainConfig.recipe`). Given (flat
    TrainConfig names), it is the task's ``default`` recipe (with a ``DeprecationWarning``)."""
    env_id: str | None = None
    """Gymnasium id of the system's own env (the built-ins'); None: ``seagul_envs.make_env`` gives a ``TaskEnv``.
    Episodes always run in ``make_env(task)``, which makes this id with the task itself (so a variant is simulated
    as given)."""
    mpc: MPCDefaults = field(default_factory=MPCDefaults)
    """The controller the task is evaluated with: its limited-lookahead MPC's defaults (horizon, trust region, goal
    blend, final soft weight), for whatever ``seagul_control.mpc.MPCOptions`` leave at None."""
    grid: EvaluationGrid = field(default_factory=EvaluationGrid)
    """The closed-loop start grid."""
    heatmap_metric: str = "final_distance"
    """Episode field shown by the evaluation heat maps: ``"final_distance"`` (log colour) or ``"cost"``."""
    heatmap_caption: str = "{metric} over a {n1} x {n2} grid of ({dims}) starts, seed-0 networks"
    """Report caption of the heat map; ``{metric}``, ``{n1}``, ``{n2}`` and ``{dims}`` are filled in."""
    trajectory_plot: TrajectoryPlot | None = None
    """Record episodes' states and plot their paths (None: no trajectory figure)."""

    def __post_init__(self) -> None:
        if not isinstance(self.mpc, MPCDefaults):
            raise ValueError(f"TaskProfile.mpc must be an MPCDefaults, got {type(self.mpc).__name__}")
        if self.heatmap_metric not in HEATMAP_METRICS:
            raise ValueError(
                f"TaskProfile.heatmap_metric must be one of {list(HEATMAP_METRICS)}, got {self.heatmap_metric!r}"
            )
        if not isinstance(self.solver, SolverDefaults):
            raise ValueError(f"TaskProfile.solver must be a SolverDefaults, got {type(self.solver).__name__}")
        for name in ("lqr_Q", "lqr_R"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, np.array(value, dtype=np.float64, ndmin=2))

    # ---------------------------------------------------------------- derived values
    def validation_spec(self, task: Task) -> ValidationSpec:
        """:attr:`validation`, or the default for ``task``."""
        if self.validation is not None:
            return self.validation
        return ValidationSpec(grid_coords=self.grid.resolved_coords(task), grid_points=10, num_random=100)

    def is_success(self, task: Task, x: Any, terminated: bool = False) -> bool:
        """The success rule applied to an episode's final state."""
        return bool(self.success(task, np.asarray(x, dtype=np.float64), bool(terminated)))

    def describe_success(self, task: Task) -> str:
        """:attr:`success_text` or its default."""
        if self.success_text is not None:
            return self.success_text
        return self.success.describe(task) if isinstance(self.success, SuccessRule) else "success"

    def success_phrase(self, task: Task) -> str:
        """:attr:`success_goal` or its default, ``"reach the goal (<condition>)"``."""
        return self.success_goal if self.success_goal is not None else f"reach the goal ({self.describe_success(task)})"

    def default_horizon(self, task: Task) -> int:
        """``mpc.horizon``, or ``max(1, round(0.25 / task.control_period))`` steps."""
        return self.mpc.horizon_for(task.control_period)

    # Deprecated flat names of the MPC defaults (read-only; TaskProfile(mpc_horizon=...) still constructs).
    @property
    def mpc_horizon(self) -> int | None:
        """Deprecated: ``mpc.horizon``."""
        return self._moved_mpc("mpc_horizon")

    @property
    def mpc_trust_region(self) -> str:
        """Deprecated: ``mpc.trust_region``."""
        return self._moved_mpc("mpc_trust_region")

    @property
    def mpc_goal_blend(self) -> float:
        """Deprecated: ``mpc.goal_blend``."""
        return self._moved_mpc("mpc_goal_blend")

    @property
    def mpc_final_soft_weight(self) -> float | None:
        """Deprecated: ``mpc.final_soft_weight``."""
        return self._moved_mpc("mpc_final_soft_weight")

    def _moved_mpc(self, name: str) -> Any:
        new = _MPC_LEGACY[name]
        warnings.warn(f"TaskProfile.{name} is deprecated; use TaskProfile.mpc.{new}", DeprecationWarning, stacklevel=3)
        return getattr(self.mpc, new)

    def lqr_weights(self, task: Task, time_varying: bool) -> tuple[np.ndarray, np.ndarray]:
        """``(Q, R)`` of the LQR reference (stationary at an equilibrium goal, else tracking; docs/reference/spec.md
        §9.6)."""
        nx, nu = task.nx, task.nu
        if time_varying:
            Q = self.lqr_Q if self.lqr_Q is not None else task.extras.get("Qf", np.eye(nx))
            R = self.lqr_R if self.lqr_R is not None else 0.01 * np.eye(nu)
        else:
            Q = self.lqr_Q if self.lqr_Q is not None else task.extras.get("Q", np.eye(nx))
            R = self.lqr_R if self.lqr_R is not None else task.extras.get("R", np.eye(nu))
        return np.asarray(Q, dtype=np.float64), np.asarray(R, dtype=np.float64)

    def heatmap_text(self, task: Task, grid: Mapping[str, Any]) -> str:
        """The heat map's report caption for a grid description of ``start_grid``."""
        n1, n2 = grid["shape"]
        metric = "Final distance to the goal" if self.heatmap_metric == "final_distance" else "Trajectory cost"
        return self.heatmap_caption.format(metric=metric, n1=n1, n2=n2, dims=", ".join(grid["dims"]))

    def replace(self, **changes: Any) -> TaskProfile:
        """A copy with some fields changed (``dataclasses.replace``)."""
        return dataclasses.replace(self, **changes)

    # ---------------------------------------------------------------- checks
    def problems(self, task: Task) -> list[str]:
        """What is wrong with this profile for ``task`` (empty when it is well-formed); ``validate_task`` reports it."""
        out: list[str] = []
        nx = task.nx

        def index_ok(what: str, i: Any) -> bool:
            if isinstance(i, bool) or not isinstance(i, (int, np.integer)) or not 0 <= int(i) < nx:
                out.append(f"profile.{what}: state index {i!r} outside 0..{nx - 1}")
                return False
            return True

        if not isinstance(self.solver, SolverDefaults):
            out.append(f"profile.solver must be a SolverDefaults, got {type(self.solver).__name__}")
        else:
            for pos, vel in self.solver.kinematic_pairs:
                index_ok("solver.kinematic_pairs", pos)
                index_ok("solver.kinematic_pairs", vel)
        spec = self.validation
        if spec is not None:
            if not isinstance(spec, ValidationSpec):
                out.append(f"profile.validation must be a ValidationSpec or None, got {type(spec).__name__}")
            else:
                for i in spec.grid_coords:
                    index_ok("validation.grid_coords", i)
                if spec.grid_points < 1 or spec.num_random < 0:
                    out.append(f"profile.validation needs grid_points >= 1 and num_random >= 0, got {spec}")
        if isinstance(self.success, SuccessRule):
            rule = self.success
            for i in rule.coords or ():
                index_ok("success.coords", i)
            for entry in rule.per_coordinate:
                if len(entry) != 3 or entry[1] not in _COMPARISONS:
                    out.append(f"profile.success.per_coordinate entries are (index, '<' or '<=', tol), got {entry!r}")
                else:
                    index_ok("success.per_coordinate", entry[0])
        elif not callable(self.success):
            out.append(f"profile.success must be a SuccessRule or a callable, got {type(self.success).__name__}")
        for name, shape in (("lqr_Q", (nx, nx)), ("lqr_R", (task.nu, task.nu))):
            value = getattr(self, name)
            if value is not None and value.shape != shape:
                out.append(f"profile.{name} must have shape {shape}, got {value.shape}")
        if not isinstance(self.mpc, MPCDefaults):
            out.append(f"profile.mpc must be an MPCDefaults, got {type(self.mpc).__name__}")
        if not isinstance(self.grid, EvaluationGrid):
            out.append(f"profile.grid must be an EvaluationGrid, got {type(self.grid).__name__}")
        else:
            for i in self.grid.coords or ():
                index_ok("grid.coords", i)
            for i, _ in self.grid.fixed:
                index_ok("grid.fixed", i)
            if self.grid.points < 1:
                out.append(f"profile.grid.points must be >= 1, got {self.grid.points}")
            if self.grid.coords is None and nx < 2:
                out.append("profile.grid.coords: a task with one state coordinate needs an explicit grid")
        if self.heatmap_metric not in ("final_distance", "cost"):
            out.append(f"profile.heatmap_metric must be 'final_distance' or 'cost', got {self.heatmap_metric!r}")
        if self.trajectory_plot is not None:
            for i in self.trajectory_plot.axes:
                index_ok("trajectory_plot.axes", i)
        for name, fields_ in (self.__dict__.get("_given_presets") or {}).items():
            if not isinstance(fields_, dict):
                out.append(f"profile.presets[{name!r}] must be a mapping of Preset fields")
        return out


TaskProfile.__init__ = _accept_flat_mpc_names(TaskProfile.__init__)  # type: ignore[method-assign]


def __getattr__(name: str) -> Any:
    return legacy_module_attribute(name, __name__)
