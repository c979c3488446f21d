"""The :class:`Task`: one symbolic model per system, the single source of truth.

A task bundles the CasADi continuous dynamics ``f(x, u)``, the running and terminal costs, the bounds, the goal,
the admissible start box ``X0`` and time-to-go range ``T0``, and the transcription settings. The Gymnasium
simulators, the trajectory optimizer and the MPC all read the same object; numeric fast paths are *generated* from
the CasADi expressions (never retyped). :meth:`Task.fingerprint` identifies a task by its content: caches (solved
results, per-worker optimizers, compiled solvers) are keyed by it, not by the name.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import hashlib
import pickle
import re
from dataclasses import dataclass, field
from typing import Any

import casadi as ca
import numpy as np

from seagul_envs.tasks.parameters import ParameterSpace
from seagul_envs.tasks.profile import TaskProfile

_TASK_NAME = re.compile(r"[A-Za-z][A-Za-z0-9]*(?:_[A-Za-z0-9]+)*")  # a CasADi Function name that takes "_suffix"

FINGERPRINT_LENGTH = 16
"""Hex digits of :meth:`Task.fingerprint` (64 bits of SHA-256)."""

_FINGERPRINT_VERSION = b"seagul-task-fingerprint-v1"  # change it whenever the encoding below changes
_MEMO = "_fingerprint"  # instance attribute holding the memoised fingerprint (never pickled)
_ORIGIN = "_origin_fingerprint"  # set by with_params: the fingerprint of the task the robot variant was made from


@dataclass(frozen=True, eq=False)
class Task:
    """An optimal-control task: dynamics, costs, bounds and the sets learning samples from."""

    name: str
    """Registry name (``"acrobot"``, ``"glider"``)."""
    state_names: tuple[str, ...]
    """One name per state coordinate."""
    control_names: tuple[str, ...]
    """One name per input coordinate."""
    dynamics: ca.Function
    """Continuous dynamics ``xdot = f(x, u)`` (SX-based, expandable)."""
    stage_cost: ca.Function
    """Running cost rate ``l(x, u)``; the transcription charges ``h * l(x_k, u_k)``."""
    terminal_cost: ca.Function
    """Terminal cost ``l_f(x)``; ``V(x, 0) = l_f(x)``."""
    goal: np.ndarray
    """Goal state ``x*``."""
    u_low: np.ndarray
    """Input lower bounds (physical units)."""
    u_high: np.ndarray
    """Input upper bounds."""
    x_low: np.ndarray
    """Path-state lower bounds (``-inf`` where free); leaving them ends an episode."""
    x_high: np.ndarray
    """Path-state upper bounds (``+inf`` where free)."""
    x_final_low: np.ndarray
    """Terminal-state box lower bounds of the full-horizon problem (``-inf`` where free)."""
    x_final_high: np.ndarray
    """Terminal-state box upper bounds."""
    x0_low: np.ndarray
    """Lower corner of the admissible start box X0."""
    x0_high: np.ndarray
    """Upper corner of X0."""
    tau_range: tuple[float, float]
    """Admissible time-to-go range T0 (seconds) for full-horizon solves."""
    tau_nominal: float
    """Nominal time to go (uniform samples, validation and episodes use it)."""
    num_steps: int
    """Number of transcription intervals ``m`` of the full-horizon problem."""
    step_bounds: tuple[float, float]
    """Bounds on each step ``h_k``; ignored when ``fixed_step``."""
    fixed_step: bool
    """If True every step is ``tau / m`` (no free time); otherwise ``h_k`` are decision variables."""
    rk4_substeps: int
    """RK4 substeps per transcription interval (accuracy of the defects; see the task's docstring)."""
    control_period: float
    """Default control period of the Gymnasium env (seconds)."""
    max_sim_substep: float = 0.005
    """Largest RK4 substep of the simulator inside one control period (seconds)."""
    params: Any = None
    """The task's physical parameter dataclass (for reference, rendering and tests)."""
    parameters: ParameterSpace | None = None
    """Which fields of ``params`` may vary, their box ``Theta`` and the dynamics ``f(x, u, theta)``
    (:class:`~seagul_envs.tasks.parameters.ParameterSpace`); None for a task whose model is fixed."""
    extras: dict[str, Any] = field(default_factory=dict)
    """Task-specific symbolic helpers (e.g. the acrobot's mass matrix for the MuJoCo test)."""
    profile: TaskProfile = field(default_factory=TaskProfile)
    """How the library treats the task beyond its problem: solver plan, validation set, success rule, LQR weights,
    presets, Gymnasium id, MPC horizon, evaluation grid, figures (:class:`~seagul_envs.tasks.profile.TaskProfile`;
    the defaults suit a new task)."""
    periodic: tuple[int, ...] = field(default=(), metadata={"fingerprint_skip": lambda task: not task.periodic})
    """State indices of angles whose problem is 2 pi-periodic (costs, goal and success rule alike): controllers
    compare them with the goal by the wrapped difference (:meth:`state_error`) and learners may see ``(cos, sin)``
    of them; nothing may assume such an angle stays bounded. Empty (the default) for a task whose cost tells the
    turns apart, as the paper's acrobot does (its upright at ``th1 = pi`` is one point, not a class)."""

    # ------------------------------------------------------------------ sizes
    @property
    def nx(self) -> int:
        """State dimension."""
        return len(self.state_names)

    @property
    def nu(self) -> int:
        """Input dimension."""
        return len(self.control_names)

    @property
    def tau_is_fixed(self) -> bool:
        """True when T0 is a single value (the acrobot)."""
        return self.tau_range[0] == self.tau_range[1]

    # ------------------------------------------------------------ parameters
    @property
    def theta(self) -> np.ndarray:
        """This task's values of the varying parameters (``parameters.names`` read from ``params``).

        Raises:
            ValueError: the task declares no :attr:`parameters`.
        """
        return self._space("theta").values_of(self.params)

    def _space(self, what: str) -> ParameterSpace:
        if self.parameters is None:
            raise ValueError(f"{self.name}: {what} needs a task that declares which parameters vary (Task.parameters)")
        return self.parameters

    def with_params(self, theta: Any) -> Task:
        """The same task for another robot: the dynamics at ``theta``, everything else (costs, bounds, X0, profile)
        as here. ``theta`` is a vector in ``parameters.names`` order or a mapping ``{name: value}``; names it leaves
        out keep this task's values. ``params`` records the new values (rendering, the MuJoCo model read them), and
        the fingerprint differs whenever the dynamics do. The variant remembers the task it was made from
        (:meth:`origin_fingerprint`), so a value function trained for that task is accepted by an MPC that plans
        with the variant's dynamics (``seagul_control.mpc.check_fingerprint``), while a same-named variant made any
        other way is refused.

        Raises:
            ValueError: the task declares no parameters, or ``theta`` is malformed (a wrong length, an unknown name,
                NaN/inf, a negative value).
        """
        space = self._space("with_params")
        values = space.resolve(theta, self.theta, self.name)
        params = dataclasses.replace(self.params, **space.as_dict(values))
        x = ca.SX.sym("x", self.nx)
        u = ca.SX.sym("u", self.nu)
        dynamics = ca.Function(self.dynamics.name(), [x, u], [space.dynamics(x, u, values)], ["x", "u"], ["xdot"])
        extras = dict(self.extras)
        if space.extras is not None:
            extras.update(space.extras(params))
        variant = dataclasses.replace(self, dynamics=dynamics, params=params, extras=extras)
        object.__setattr__(variant, _ORIGIN, self.origin_fingerprint())  # frozen dataclass: a private attribute
        return variant

    def state_error(self, x: Any) -> np.ndarray:
        """``x - goal`` with the :attr:`periodic` coordinates wrapped to ``[-pi, pi)`` (for an array of states
        too: the last axis is the state)."""
        error = np.asarray(x, dtype=np.float64) - self.goal
        if self.periodic:
            index = list(self.periodic)
            error[..., index] = (error[..., index] + np.pi) % (2.0 * np.pi) - np.pi
        return error

    def origin_fingerprint(self) -> str:
        """The :meth:`fingerprint` of the task this one was made from by :meth:`with_params` (through any chain of
        ``with_params`` calls: the first task's), or this task's own fingerprint when it was made otherwise.

        It travels with the task (pickling keeps it), but any other copy (``dataclasses.replace``) is a new task
        whose origin is itself: only a robot variant of a task counts as that task's family.
        """
        origin = self.__dict__.get(_ORIGIN)
        return str(origin) if origin is not None else self.fingerprint()

    def rk4_step_params(self, substeps: int | None = None) -> ca.Function:
        """``F(x, u, h, theta)``: :meth:`rk4_step` of the parametric dynamics ``parameters.dynamics``.

        Raises:
            ValueError: the task declares no parameters.
        """
        space = self._space("rk4_step_params")
        return _rk4_param_step(self, space, self.rk4_substeps if substeps is None else int(substeps))

    # ------------------------------------------------------------ integrators
    def rk4_step(self, substeps: int | None = None) -> ca.Function:
        """Symbolic RK4 map ``F(x, u, h) -> x(h)`` with ``substeps`` equal substeps, input held constant.

        Used by the transcription (as defect ``x_{k+1} - F(x_k, u_k, h_k) = 0``) and, numerically, by the simulator.
        """
        return _rk4_step(self, self.rk4_substeps if substeps is None else int(substeps))

    def simulator(self, dt: float, max_substep: float | None = None) -> ca.Function:
        """Numeric one-control-period map ``(x, u) -> x(t + dt)`` (zero-order hold, RK4 substeps <= max_substep)."""
        return _simulator(self, float(dt), self.simulator_substeps(dt, max_substep))

    def simulator_substeps(self, dt: float, max_substep: float | None = None) -> int:
        """RK4 substeps of :meth:`simulator` over ``dt``: ``ceil(dt / max_substep - 1e-9)``, at least 1."""
        max_substep = self.max_sim_substep if max_substep is None else max_substep
        return max(1, int(np.ceil(dt / max_substep - 1e-9)))

    def stage_cost_value(self, x: np.ndarray, u: np.ndarray) -> float:
        """``l(x, u)`` as a float."""
        return float(self.stage_cost(x, u))

    def terminal_cost_value(self, x: np.ndarray) -> float:
        """``l_f(x)`` as a float."""
        return float(self.terminal_cost(x))

    def goal_is_equilibrium(self, cost: bool = False) -> bool:
        """True when the goal is an equilibrium: ``f(x*, 0) = 0`` (to 1e-9), and with ``cost=True`` also a zero-cost
        one, ``l(x*, 0) = 0`` (to 1e-12). The LQR reference is stationary at an equilibrium goal and tracks a
        trajectory otherwise; the MPC's goal anchor and goal blend need a zero-cost equilibrium
        (docs/reference/spec.md)."""
        u0 = np.zeros(self.nu)
        drift = np.asarray(self.dynamics(self.goal, u0)).ravel()
        if not bool(np.allclose(drift, 0.0, atol=1e-9)):
            return False
        return not cost or abs(self.stage_cost_value(self.goal, u0)) < 1e-12

    # ---------------------------------------------------------------- checks
    def check_state(self, x: Any, what: str = "state") -> np.ndarray:
        """Return ``x`` as a float64 vector of length ``nx`` or raise a ValueError that names the problem."""
        arr = np.asarray(x, dtype=np.float64)
        if arr.shape != (self.nx,):
            raise ValueError(
                f"{self.name}: {what} must have shape ({self.nx},) {list(self.state_names)}, got shape {arr.shape}"
            )
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{self.name}: {what} contains NaN or inf: {arr.tolist()}")
        return arr

    def check_control(self, u: Any, what: str = "action") -> np.ndarray:
        """Return ``u`` as a float64 vector of length ``nu`` or raise a ValueError that names the problem."""
        arr = np.asarray(u, dtype=np.float64)
        if arr.shape == () and self.nu == 1:
            arr = arr.reshape(1)
        if arr.shape != (self.nu,):
            raise ValueError(
                f"{self.name}: {what} must have shape ({self.nu},) {list(self.control_names)}, got shape {arr.shape}"
            )
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{self.name}: {what} contains NaN or inf: {arr.tolist()}")
        return arr

    def check_tau(self, tau: Any, allow_shorter: bool = False) -> float:
        """Validate a time to go: finite, positive, inside ``tau_range`` (or below it if ``allow_shorter``)."""
        try:
            value = float(tau)
        except (TypeError, ValueError):
            raise ValueError(f"{self.name}: time to go must be a number, got {tau!r}") from None
        lo, hi = self.tau_range
        if not np.isfinite(value):
            raise ValueError(f"{self.name}: time to go must be finite, got {value}")
        tol = 1e-9
        if allow_shorter:
            if not (0.0 <= value <= hi + tol):
                raise ValueError(f"{self.name}: time to go {value} outside [0, {hi}] s")
        elif not (lo - tol <= value <= hi + tol):
            raise ValueError(f"{self.name}: time to go {value} outside the task's range T0 = [{lo}, {hi}] s")
        return value

    def in_x0(self, x: np.ndarray, tol: float = 1e-9) -> bool:
        """True if ``x`` lies in the start box X0."""
        x = np.asarray(x, dtype=np.float64)
        return bool(np.all(x >= self.x0_low - tol) and np.all(x <= self.x0_high + tol))

    def sample_x0(self, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
        """Uniform draw(s) from X0 (shape ``(nx,)`` or ``(n, nx)``)."""
        size = None if n is None else (n, self.nx)
        return rng.uniform(self.x0_low, self.x0_high, size=size)

    # ----------------------------------------------------------- identity
    def fingerprint(self) -> str:
        """A short hex digest of the task's *content*: equal for equal tasks, in any process.

        Tasks whose fields below are equal get the same fingerprint; a difference in any of them gives another one
        (up to the odds of a 64-bit hash collision), so caches keyed by it (solved results, per-worker optimizers,
        compiled solvers) never mix two problems that share a name. Functions are compared as built: the same
        mathematics written as another expression graph counts as different. It covers every field of the dataclass:

        * ``name``, ``state_names``, ``control_names``;
        * the CasADi functions ``dynamics``, ``stage_cost`` and ``terminal_cost`` by their ``serialize()`` form (the
          expression graph with every constant to the bit, the function and argument names);
        * the arrays ``goal``, ``u_low``/``u_high``, ``x_low``/``x_high``, ``x_final_low``/``x_final_high`` and
          ``x0_low``/``x0_high`` by dtype, shape and bytes;
        * ``tau_range``, ``tau_nominal``, ``num_steps``, ``step_bounds``, ``fixed_step``, ``rk4_substeps``,
          ``control_period`` and ``max_sim_substep`` (floats exactly, by ``float.hex``);
        * ``params`` (a dataclass: its type and every field's name and value) and ``extras`` (its keys and values:
          arrays, numbers, strings, containers, dataclasses and CasADi functions by content; other callables, e.g. a
          renderer, by their module and qualified name; any other object by its pickle);
        * ``periodic`` when the task declares periodic angles (an empty one leaves the fingerprint as it was);
        * ``profile`` (a dataclass like ``params``: the solver plan, validation set, success rule, MPC defaults, ...),
          so a task whose solver plan or validation set differs never shares a cache either. The deprecated
          ``presets`` and ``train_recipe`` count only when a task gives them (training recipes and presets are not
          the problem: ``seagul_learn/recipes/*.yml``); a dataclass field whose metadata has a
          ``"fingerprint_skip"`` predicate that is true of the dataclass is left out.

        It is deterministic across processes and runs (no ids or addresses enter it; checked for the built-in tasks),
        but CasADi's serialisation format belongs to its version, so another CasADi may give other fingerprints (a
        cache miss, never a wrong hit). Computed on the first call (about a millisecond) and memoised on the object:
        a task is treated as immutable (do not write into its arrays). A copy (pickle, ``copy``,
        ``dataclasses.replace``) computes its own.

        Returns:
            :data:`FINGERPRINT_LENGTH` lowercase hex digits.

        Raises:
            TypeError: a CasADi function of the task cannot be serialised (e.g. it wraps a Python callback).
        """
        memo = self.__dict__.get(_MEMO)
        if memo is None:
            digest = hashlib.sha256(_FINGERPRINT_VERSION)
            for f in dataclasses.fields(self):
                skip = f.metadata.get("fingerprint_skip")
                if skip is not None and skip(self):  # a field at its neutral default: fingerprints stay as before
                    continue
                _feed(digest, f.name, f.name)
                _feed(digest, getattr(self, f.name), f.name)
            memo = digest.hexdigest()[:FINGERPRINT_LENGTH]
            object.__setattr__(self, _MEMO, memo)  # frozen dataclass: bypass the guard for the private memo
        return str(memo)

    def __getstate__(self) -> dict[str, Any]:
        # The memoised fingerprint stays behind: the receiving process computes its own from what arrived, so a
        # field that did not survive pickling shows up as another fingerprint instead of a wrong cache hit.
        state = dict(self.__dict__)
        state.pop(_MEMO, None)
        return state

    def __repr__(self) -> str:
        return f"Task({self.name!r}, nx={self.nx}, nu={self.nu}, m={self.num_steps}, tau={self.tau_range})"


def _feed(digest: Any, value: Any, where: str) -> None:
    """Add a type-tagged, unambiguous encoding of ``value`` to ``digest`` (see :meth:`Task.fingerprint`)."""

    def put(tag: bytes, payload: bytes = b"") -> None:
        digest.update(tag + len(payload).to_bytes(8, "little") + payload)

    if value is None:
        put(b"none")
    elif isinstance(value, bool | np.bool_):
        put(b"bool", b"1" if value else b"0")
    elif isinstance(value, int | np.integer):
        put(b"int", str(int(value)).encode())
    elif isinstance(value, float | np.floating):
        put(b"float", float(value).hex().encode())
    elif isinstance(value, str):
        put(b"str", value.encode())
    elif isinstance(value, bytes):
        put(b"bytes", value)
    elif isinstance(value, np.ndarray):
        put(b"array", f"{value.dtype.str}{value.shape}".encode())
        if value.dtype.hasobject:
            _feed(digest, value.tolist(), where)
        else:
            put(b"data", np.ascontiguousarray(value).tobytes())
    elif isinstance(value, tuple | list):
        put(b"tuple" if isinstance(value, tuple) else b"list", str(len(value)).encode())
        for i, item in enumerate(value):
            _feed(digest, item, f"{where}[{i}]")
    elif isinstance(value, dict):
        put(b"dict", str(len(value)).encode())
        for key in sorted(value, key=repr):
            _feed(digest, key, where)
            _feed(digest, value[key], f"{where}[{key!r}]")
    elif isinstance(value, ca.Function):
        try:
            put(b"casadi", value.serialize().encode())
        except RuntimeError as e:
            raise TypeError(
                f"cannot fingerprint the task: its CasADi function {where} ({value.name()}) does not serialise "
                f"(build it from SX/MX expressions, not a Python callback): {str(e).strip().splitlines()[-1]}"
            ) from None
    elif isinstance(value, enum.Enum):
        put(b"enum", f"{type(value).__module__}.{type(value).__qualname__}.{value.name}".encode())
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        put(b"dataclass", f"{type(value).__module__}.{type(value).__qualname__}".encode())
        for f in dataclasses.fields(value):
            skip = f.metadata.get("fingerprint_skip")
            if skip is not None and skip(value):
                continue  # a field that says it does not count here (the profile's deprecated recipes, not given)
            _feed(digest, f.name, where)
            _feed(digest, getattr(value, f.name), f"{where}.{f.name}")
    elif callable(value):
        module = getattr(value, "__module__", None) or type(value).__module__
        qualname = getattr(value, "__qualname__", None) or type(value).__qualname__
        put(b"callable", f"{module}.{qualname}".encode())
    else:
        try:
            put(b"pickle", pickle.dumps(value, protocol=5))
        except Exception:  # an object that does not pickle (a lock, a handle) enters by its type only
            put(b"type", f"{type(value).__module__}.{type(value).__qualname__}".encode())


def validate_task(task: Any) -> Task:
    """Check that ``task`` is a well-formed :class:`Task`; return it, or raise naming every problem found.

    Checks the types of the fields, the signatures of the CasADi functions (``dynamics: (nx, nu) -> nx``,
    ``stage_cost: (nx, nu) -> scalar``, ``terminal_cost: nx -> scalar``, all callable on SX symbols as the simulator
    and the transcription need), the shapes and ordering of the boxes (finite input bounds and X0, X0 inside the state
    bounds), the positivity of the times and counts, and the profile (its state indices, weights' shapes, choices).
    Custom tasks go through it before an env is built for them (:func:`seagul_envs.make_env`,
    :func:`seagul_envs.register_task`).

    Raises:
        TypeError: ``task`` is not a :class:`Task`.
        ValueError: the task is malformed (the message lists each problem).
    """
    if not isinstance(task, Task):
        raise TypeError(f"expected a seagul_envs Task, got {type(task).__name__}")
    name = task.name
    problems: list[str] = []
    if not (isinstance(task.name, str) and _TASK_NAME.fullmatch(task.name)):
        problems.append(
            f"name must be a letter followed by letters, digits and single underscores (it names the task's CasADi "
            f"functions), got {task.name!r}"
        )
    for what, names in (("state_names", task.state_names), ("control_names", task.control_names)):
        if not (isinstance(names, tuple) and names and all(isinstance(n, str) for n in names)):
            problems.append(f"{what} must be a non-empty tuple of str, got {names!r}")
    if problems:  # sizes below are meaningless without the names
        raise ValueError(f"malformed task {name!r}: " + "; ".join(problems))
    nx, nu = task.nx, task.nu

    def check_function(what: str, fn: Any, inputs: tuple[int, ...]) -> None:
        if not isinstance(fn, ca.Function):
            problems.append(f"{what} must be a casadi.Function, got {type(fn).__name__}")
            return
        sizes = tuple(fn.size_in(i) for i in range(fn.n_in()))
        want_in = tuple((n, 1) for n in inputs)
        want_out = (nx, 1) if what == "dynamics" else (1, 1)
        if sizes != want_in or fn.n_out() < 1 or fn.size_out(0) != want_out:
            got_out = fn.size_out(0) if fn.n_out() else None
            problems.append(
                f"{what} must map inputs of shapes {list(want_in)} to {want_out}, got {list(sizes)} -> {got_out}"
            )
            return
        try:
            fn(*(ca.SX.sym("s", n) for n in inputs))
        except Exception as e:  # e.g. an MX Function with a linear solver: no SX evaluation
            last_line = str(e).strip().splitlines()[-1] if str(e).strip() else type(e).__name__
            problems.append(
                f"{what} cannot be evaluated on SX symbols (build it from SX, or .expand() it): {last_line}"
            )

    check_function("dynamics", task.dynamics, (nx, nu))
    check_function("stage_cost", task.stage_cost, (nx, nu))
    check_function("terminal_cost", task.terminal_cost, (nx,))

    def array(what: str, n: int, finite: bool = False) -> np.ndarray | None:
        value = getattr(task, what)
        if not isinstance(value, np.ndarray):
            problems.append(f"{what} must be a numpy array, got {type(value).__name__}")
            return None
        if value.shape != (n,):
            problems.append(f"{what} must have shape ({n},), got {value.shape}")
            return None
        if not np.issubdtype(value.dtype, np.number) or np.isnan(value.astype(np.float64)).any():
            problems.append(f"{what} must be real numbers (no NaN), got {value.tolist()}")
            return None
        if finite and not np.isfinite(value).all():
            problems.append(f"{what} must be finite, got {value.tolist()}")
            return None
        return value.astype(np.float64)

    array("goal", nx, finite=True)
    periodic = task.periodic
    if not (isinstance(periodic, tuple) and all(isinstance(i, int) and not isinstance(i, bool) for i in periodic)):
        problems.append(f"periodic must be a tuple of state indices (int), got {periodic!r}")
    elif len(set(periodic)) != len(periodic) or any(not 0 <= i < nx for i in periodic):
        problems.append(f"periodic must hold distinct state indices in 0..{nx - 1}, got {periodic!r}")
    boxes = {}
    for lo, hi, n, finite in (
        ("u_low", "u_high", nu, True),
        ("x_low", "x_high", nx, False),
        ("x_final_low", "x_final_high", nx, False),
        ("x0_low", "x0_high", nx, True),
    ):
        a, b = array(lo, n, finite), array(hi, n, finite)
        if a is not None and b is not None:
            if np.any(a > b):
                problems.append(f"{lo} must be <= {hi}, got {a.tolist()} and {b.tolist()}")
            else:
                boxes[lo] = (a, b)
    if "x0_low" in boxes and "x_low" in boxes:
        (a0, b0), (a, b) = boxes["x0_low"], boxes["x_low"]
        if np.any(a0 < a) or np.any(b0 > b):
            problems.append("the start box X0 [x0_low, x0_high] must lie inside the state bounds [x_low, x_high]")

    def positive(what: str, value: Any, integer: bool = False) -> None:
        ok = (
            isinstance(value, (int, np.integer))
            if integer
            else isinstance(value, (int, float, np.integer, np.floating))
        )
        if not ok or isinstance(value, bool) or not (np.isfinite(value) and value > 0):
            kind = "a positive int" if integer else "a positive finite number"
            problems.append(f"{what} must be {kind}, got {value!r}")

    tau_range = task.tau_range
    if not (isinstance(tau_range, tuple) and len(tau_range) == 2):
        problems.append(f"tau_range must be a (low, high) tuple, got {tau_range!r}")
    else:
        positive("tau_range[0]", tau_range[0])
        positive("tau_range[1]", tau_range[1])
        positive("tau_nominal", task.tau_nominal)
        try:
            if not tau_range[0] <= task.tau_nominal <= tau_range[1]:
                problems.append(f"tau_nominal {task.tau_nominal} must lie in tau_range {tau_range}")
        except TypeError:
            pass  # reported above
    step_bounds = task.step_bounds
    if not (isinstance(step_bounds, tuple) and len(step_bounds) == 2):
        problems.append(f"step_bounds must be a (low, high) tuple, got {step_bounds!r}")
    else:
        positive("step_bounds[0]", step_bounds[0])
        positive("step_bounds[1]", step_bounds[1])
    positive("num_steps", task.num_steps, integer=True)
    positive("rk4_substeps", task.rk4_substeps, integer=True)
    positive("control_period", task.control_period)
    positive("max_sim_substep", task.max_sim_substep)
    if not isinstance(task.extras, dict):
        problems.append(f"extras must be a dict, got {type(task.extras).__name__}")
    if task.parameters is not None:
        if not isinstance(task.parameters, ParameterSpace):
            problems.append(f"parameters must be a seagul_envs ParameterSpace, got {type(task.parameters).__name__}")
        else:
            problems += task.parameters.problems(task.params, nx, nu)
            if not problems:
                theta = task.parameters.values_of(task.params)
                rng = np.random.default_rng(0)
                for _ in range(3):
                    xs = rng.uniform(-1, 1, nx) + np.where(np.isfinite(task.goal), task.goal, 0.0)
                    us = rng.uniform(-1, 1, nu)
                    a = np.asarray(task.dynamics(xs, us)).ravel()
                    b = np.asarray(task.parameters.dynamics(xs, us, theta)).ravel()
                    if not np.allclose(a, b, rtol=1e-9, atol=1e-9):
                        problems.append(
                            "parameters.dynamics at the task's own parameters must equal dynamics, got "
                            f"{b.tolist()} against {a.tolist()} at x = {xs.tolist()}, u = {us.tolist()}"
                        )
                        break
    if not isinstance(task.profile, TaskProfile):
        problems.append(f"profile must be a seagul_envs TaskProfile, got {type(task.profile).__name__}")
    else:
        problems += task.profile.problems(task)
    if problems:
        raise ValueError(f"malformed task {name!r}: " + "; ".join(problems))
    return task


def rk4_map(
    dynamics: ca.Function, nx: int, nu: int, substeps: int, name: str = "rk4", n_params: int = 0
) -> ca.Function:
    """``F(x, u, h)``: ``substeps`` equal RK4 substeps of ``dynamics`` over ``h`` with ``u`` held constant; with
    ``n_params > 0`` the dynamics are ``f(x, u, theta)`` and the map ``F(x, u, h, theta)``."""
    x = ca.SX.sym("x", nx)
    u = ca.SX.sym("u", nu)
    h = ca.SX.sym("h")
    theta = ca.SX.sym("theta", n_params)
    extra = [theta] if n_params else []

    def f(xs: ca.SX) -> ca.SX:
        return dynamics(xs, u, *extra)

    dt = h / substeps
    xs = x
    for _ in range(substeps):
        k1 = f(xs)
        k2 = f(xs + dt / 2 * k1)
        k3 = f(xs + dt / 2 * k2)
        k4 = f(xs + dt * k3)
        xs = xs + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    names = ["x", "u", "h"] + (["theta"] if n_params else [])
    return ca.Function(name, [x, u, h, *extra], [xs], names, ["x_next"])


@functools.cache
def _rk4_param_step(task: Task, space: ParameterSpace, substeps: int) -> ca.Function:
    return rk4_map(space.dynamics, task.nx, task.nu, substeps, f"{task.name}_rk4_theta_{substeps}", space.size)


@functools.cache
def _rk4_step(task: Task, substeps: int) -> ca.Function:
    return rk4_map(task.dynamics, task.nx, task.nu, substeps, f"{task.name}_rk4_{substeps}")


@functools.cache
def _simulator(task: Task, dt: float, substeps: int) -> ca.Function:
    step = _rk4_step(task, substeps)
    x = ca.SX.sym("x", task.nx)
    u = ca.SX.sym("u", task.nu)
    return ca.Function(f"{task.name}_sim", [x, u], [step(x, u, dt)], ["x", "u"], ["x_next"])
