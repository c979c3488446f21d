"""Limited-lookahead MPC (paper Eq. 3) with a learned terminal cost, and the full-horizon MPC reference.

Both controllers follow stable-baselines3's predictor protocol, ``predict(observation, state=None,
episode_start=None, deterministic=True) -> (actions, state)``, on the seagul envs' observations ``[x, time_to_go]``
(one ``(nx + 1,)`` or a batch ``(n_envs, nx + 1)``), so SB3's ``evaluate_policy`` runs them on a ``DummyVecEnv``.

**Problem.** The one NLP builder (:class:`~seagul_control.transcription.Transcription`) with ``n`` intervals,
``x_0 = x_now`` and terminal cost ``Vhat(x_n, tau_now - sum(h))``. The value function enters as its CasADi form
``(x, tau, theta) -> V`` with ``theta`` an NLP *parameter*: swapping in a newly trained network of the same
architecture (:meth:`LimitedLookaheadMPC.set_value_function`) never rebuilds a solver.

**End of the episode.** ``theta`` carries a switch ``s``: the terminal cost is ``s * Vhat_guarded + (1 - s) * l_f``.

* Fixed-step tasks (acrobot, ``h = dt``): ``s = 0`` once ``tau_now - n dt <= 0`` (the task's ``l_f``, the DARE
  quadratic, is then the right tail cost; the lookahead may pass the episode end by < n steps, harmlessly).
* Free-time tasks (glider): while ``tau_now > n * dt`` the lookahead problem has ``h_k`` in the task's step bounds
  and ``sum(h) <= tau_now``; after that a **final-phase problem built once** takes over: ``n`` steps with
  ``sum(h) = tau_now`` exactly, ``h_k in [0, h_max]``, the task's terminal box and ``l_f`` (a shrinking horizon in
  time with a constant number of knots, so one solver serves every remaining time).
* In both, the first step is pinned to the control period (``min(dt, tau_now)``) so that ``u_0`` is held exactly
  as long as the env holds it.

**Trust region (the learned terminal cost is only trustworthy where it was trained).** Three guards, chosen by
``trust_region``; ``clamp=True`` (default) also replaces ``Vhat`` by the smooth ``max(Vhat, 0)`` (a cost-to-go is
never negative) in each of them.

The default is the task's ``profile.mpc.trust_region``: ``"none"`` for the acrobot and the glider, whose shipped
networks are selected and measured unguarded (docs/experiments/closed-loop.md: 99.25 % of the acrobot grid, 91.7 % of
the glider's), ``"lqr"`` for a new task.

* ``"lqr"``: ``Vhat + l_f``, i.e. the task's quadratic terminal cost (acrobot: the DARE matrix) as a
  prior under the network. It biases the cost upward but gives the terminal cost the right curvature at the goal,
  where a network fitted to values of 2-130 over wide swings is flattest and least accurate; measured on the
  acrobot grid it was the only guard with which the learned MPC balanced (``docs/experiments/mpc.md``).
* ``"box"``: ``Vhat + w * sum_i ((x_n,i - clip(x_n,i, lo_i, hi_i)) / (hi_i - lo_i))^2``: zero inside the training
  box, a quadratic wall outside, so the optimizer cannot exploit the network where it never saw data. The box comes
  from the value function (``training_box()`` if it has one, else ``in_mean +- 2 in_std`` of its input
  standardisation, i.e. of its training inputs) or is given; it is part of ``theta``, so a new network brings its
  own box without a rebuild.
* ``"none"``: ``Vhat`` alone (the paper's Eq. 3 as written).

For a zero-cost equilibrium goal (the acrobot) ``anchor_goal`` (default on there) first replaces ``Vhat`` by
``Vhat - Vhat(x*, tau) - dVhat/dx(x*, tau) (x - x*)``: the true value and its gradient vanish at the goal, and a
network's small first-order error there otherwise shifts the closed loop's resting point off the goal.
``goal_blend = c > 0`` then hands the goal's neighbourhood to the task's quadratic: the learned cost becomes
``b l_f + (1 - b) Vhat`` with ``b = exp(-l_f / c)``. Near an equilibrium goal ``l_f`` (the DARE quadratic of the
transcription's own linearisation) *is* the value to second order (measured on the acrobot: ``V = l_f`` while
``l_f <~ 1``), while a network fitted to values up to tens errs there by more than ``V`` itself, so the closed loop
would settle next to the goal instead of on it (docs/experiments/closed-loop.md). Away from the goal (``l_f >> c``) the
network is untouched. The blend is applied to the guarded learned cost, before the end-of-episode switch.

**Speed.** The default solver is the condensed one (``"shooting"``, :mod:`seagul_control.shooting`) for a short
fixed-step lookahead with input bounds only (the acrobot), else CasADi's ``fatrop`` (the transcription orders
variables and constraints stage by stage); with ``jit=True`` (default) the NLP functions are compiled to C once
and the object file is cached on disk
(``$SEAGUL_CACHE_DIR`` or ``~/.cache/seagul/casadi``, keyed by a hash of the generated source and flags), so a new
process pays only code generation and linking. Without a C compiler the same solver runs interpreted (slower).
A value function that offers a *matrix* form (``casadi_function(form="matrix")``: an MX graph of dense
matrix-vector products, as ``ValueNetwork`` and ``ValueEnsemble`` do) is compiled differently: the lookahead NLP is
generated unexpanded (:class:`~seagul_control.transcription.Transcription` ``codegen=True``), so the network and its
exact Hessian stay a few dozen dense products (46 kB of C for a 3 x (2 x 64) ensemble, ~10 s to build) instead of
an expanded scalar graph (30 MB of C for that ensemble, which gcc -O1 did not finish in 21 CPU-minutes). Measured
on the acrobot, 5 steps, 500 closed-loop steps, one other core busy: 2 x 64 network 2.5 ms median / 4.0 ms p95
per step (the scalar JIT: 6.3 ms at load ~1, minutes to compile), 3-member ensemble 5.5 / 10.0 ms (interpreted:
16 / 28 ms); ``-O3`` is the default for this form (-O1: 11 ms for the ensemble).

**Robustness.** ``predict`` never raises on a failed solve: it falls back to the previous plan shifted by one
step, then to the LQR reference (:class:`~seagul_control.lqr.LQRPolicy`), then to a zero (clipped) input, and
records status, iterations, solve time and the source of each action in :attr:`last_info` / :attr:`stats`.
Warm starts are kept per env index (the previous solution shifted by one step) and dropped on ``episode_start``.
A cold start (no plan) of a lifted fixed-step problem descends from both the zero-input rollout and the straight
line to the goal and keeps the lower converged plan (``cold_guess="best"``, the default with fixed steps): over a
long horizon the rollout of an unstable system falls far from the goal and leads the solver to a poor local
minimum.
NaN observations, wrong shapes and a horizon < 1 raise ValueErrors naming the problem.

**Configuration.** Every setting is a field of a typed, validated option object: :class:`MPCOptions` for the
limited-lookahead MPC, :class:`FullHorizonOptions` for the reference (``LimitedLookaheadMPC(task, network, 5,
MPCOptions(solver="fatrop", max_iter=100))``); the old keyword arguments still work and emit a
``DeprecationWarning``. The controller's ``options`` attribute holds them with every task-dependent default
resolved.

**Saving.** ``mpc.save(path)`` writes one zip file (options, horizon, the task's fingerprint, the value function's
CasADi forms and parameters, and the network's own file); ``LimitedLookaheadMPC.load(path)`` rebuilds an identical
controller without torch (:mod:`seagul_control.mpc.saving`).

**Modules.** :mod:`~seagul_control.mpc.options` (the option objects), :mod:`~seagul_control.mpc.base` (the shared
receding-horizon machinery and :class:`MPCStepInfo`), :mod:`~seagul_control.mpc.terminal_cost` (the value function,
its guards, anchor and blend), :mod:`~seagul_control.mpc.lookahead`, :mod:`~seagul_control.mpc.full_horizon` and
:mod:`~seagul_control.mpc.saving`. This package replaces the former single module ``seagul_control/mpc.py`` and
exports every name it did.
"""

from __future__ import annotations

# The private names below are imported by other modules and tests from seagul_control.mpc (``x as x``: re-exported).
from seagul_control.codegen import find_c_compiler, jit_solver_options
from seagul_control.mpc.base import _TIME_EPS as _TIME_EPS
from seagul_control.mpc.base import MPCStepInfo, default_cache_dir
from seagul_control.mpc.base import _converged as _converged
from seagul_control.mpc.base import _jit_directory as _jit_directory
from seagul_control.mpc.base import _lower as _lower
from seagul_control.mpc.base import _MPCBase as _MPCBase
from seagul_control.mpc.base import _Plan as _Plan
from seagul_control.mpc.base import _Problem as _Problem
from seagul_control.mpc.base import _shift_guess as _shift_guess
from seagul_control.mpc.base import _shifted as _shifted
from seagul_control.mpc.full_horizon import FullHorizonMPC
from seagul_control.mpc.lookahead import LimitedLookaheadMPC
from seagul_control.mpc.options import (
    ColdGuess,
    FullHorizonOptions,
    MPCOptions,
    Multistart,
    SolverName,
    TrustRegion,
)
from seagul_control.mpc.saving import SavedValueFunction, extract_value_function_file, load_mpc, save_mpc
from seagul_control.mpc.terminal_cost import _taylor_forms as _taylor_forms
from seagul_control.mpc.terminal_cost import _to_numpy as _to_numpy
from seagul_control.mpc.terminal_cost import _value_function_form as _value_function_form

__all__ = [
    "ColdGuess",
    "FullHorizonMPC",
    "FullHorizonOptions",
    "LimitedLookaheadMPC",
    "MPCOptions",
    "MPCStepInfo",
    "Multistart",
    "SavedValueFunction",
    "SolverName",
    "TrustRegion",
    "default_cache_dir",
    "extract_value_function_file",
    "find_c_compiler",
    "jit_solver_options",
    "load_mpc",
    "save_mpc",
]
