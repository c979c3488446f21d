"""``SeagulGlider-v0``: the perching glider simulated from the Task's CasADi model."""

from __future__ import annotations

from typing import Any

import numpy as np

from seagul_envs.envs.base import TaskSimulatorEnv, resolve_task
from seagul_envs.rendering import glider_frame
from seagul_envs.tasks.base import Task
from seagul_envs.tasks.glider import GliderParams


class GliderEnv(TaskSimulatorEnv):
    """The perching glider of SEAGuL, integrated from the task's CasADi model.

    Registered as ``SeagulGlider-v0``. The numbers below are the defaults of the task's parameter dataclass
    ``GliderParams`` (``seagul_envs/tasks/glider.py``), named next to each value.

    **Description**

    A flat-plate glider, its wing at the centre of mass and an elevator on a tail boom, flies towards a perch (a
    string at the origin). It must pitch up into a post-stall attitude, bleed its speed and reach the perch exactly
    when the time to go runs out, the goal being ``x_d = [0, 0, pi/4, 0, 0, 0, 0]`` (Moore, Cory & Tedrake 2014).
    The dynamics are Drake's ``GliderPlant``: the force normal to each plate is ``rho S sin(alpha) |v|^2``, with
    mass ``m = 0.08`` kg, pitch inertia ``I = 0.0015`` kg m^2, wing area ``S_w = 0.0885`` m^2, elevator area
    ``S_e = 0.0147`` m^2, lever arms ``l_w = 0.0``, ``l_h = 0.27`` and ``l_e = 0.022`` m, air density
    ``rho = 1.204`` kg/m^3 and ``g = 9.81`` m/s^2. The input is the elevator rate. Each step holds the action over one
    control period ``dt`` (``control_period = 0.025`` s; zero-order hold) and integrates the task's dynamics with
    RK4 substeps of at most ``Task.max_sim_substep = 0.005`` s (5 per period).

    **Action Space**

    ``Box(-13.0, 13.0, (1,), float32)``: the elevator rate ``dphi`` in rad/s (``u_max = 13.0``), in physical units.
    Actions outside the box are clipped, and so is a rate that would drive the elevator past its range within the
    step: the range acts as a mechanical stop that keeps ``phi`` in ``[phi_min, phi_max] = [-0.9473, 0.4463]`` rad.
    The reward charges the rate applied. A NaN/inf or wrongly shaped action raises ``ValueError`` and leaves the env
    unchanged.

    **Observation Space**

    ``Box((8,), float32)``, the state followed by the time to go:

    | Index | Observation                                         | Unit  | Bounds                     |
    |-------|-----------------------------------------------------|-------|----------------------------|
    | 0     | ``x``: horizontal position of the centre of mass    | m     | +- float32 max             |
    | 1     | ``z``: vertical position of the centre of mass      | m     | +- float32 max             |
    | 2     | ``th``: pitch, positive nose-up                     | rad   | +- float32 max             |
    | 3     | ``phi``: elevator angle relative to the body        | rad   | +- float32 max             |
    | 4     | ``dx``                                              | m/s   | +- float32 max             |
    | 5     | ``dz``                                              | m/s   | +- float32 max             |
    | 6     | ``dth``                                             | rad/s | +- float32 max             |
    | 7     | time to go                                          | s     | ``[0, 0.85]`` (``tau_max``) |

    The perch is at ``x = z = 0``. ``info["state"]`` is the float64 state and ``info["time_to_go"]`` the time to go,
    in the infos of ``reset`` and ``step``.

    **Rewards**

    A step of length ``h`` with the applied rate ``u_k`` earns ``-h * 100.0 * u_k^2`` (``input_weight = 100.0``; the
    running cost penalises only the input). The step on which the episode ends, by truncation or by a crash, also
    earns ``-l_f(x_end)``, ``l_f(x) = (x - x_d)' diag(10, 10, 1, 10, 1, 1, 1) (x - x_d)`` (``terminal_weights``).
    Charging ``l_f`` at a crash keeps a crash from being cheaper than arriving at the same place. An episode's return
    is therefore minus the cost of the trajectory flown.

    **Starting State**

    Uniform in X0, from ``x0_low = (-3.75, 0.0, 0.0, 0.0, 6.5, 0.0, 0.0)`` to
    ``x0_high = (-3.25, 0.3, 0.0, 0.0, 7.5, 0.0, 0.0)``: ``x`` in ``[-3.75, -3.25]`` m, ``z`` in ``[0, 0.3]`` m,
    ``dx`` in ``[6.5, 7.5]`` m/s, the other states 0, drawn with the env's ``np_random``. The time to go is
    ``tau_nominal = 0.8`` s.

    **Episode End**

    Termination (a crash): the state leaves the task's path bounds, ``x`` in ``[-4, 1]`` m, ``z`` in ``[-1, 1]`` m,
    ``th`` in ``[-pi/2, pi/2]`` rad (with a 1e-8 rounding slack), or stops being finite. ``phi`` never leaves its
    range: the action limit above keeps it in.

    Truncation: when the time to go reaches 0, after ``ceil(tau / dt)`` steps: 32 steps of 25 ms for the nominal
    ``tau_nominal / control_period = 0.8 / 0.025``. If ``tau`` is not a multiple of ``dt``, the last step is
    shortened so that the time to go reaches exactly 0. An episode may be reset with any ``tau`` up to
    ``tau_max = 0.85`` s (the upper end of T0 = ``[tau_min, tau_max] = [0.75, 0.85]`` s), 34 steps, so the
    registered spec has ``max_episode_steps = 34`` (``ceil(tau_max / control_period)``): ``gym.make``'s
    ``TimeLimit`` never ends an episode before its time to go reaches 0, and truncates on the same step as the env
    for ``tau = 0.85``. A nominal episode ends by the env's own truncation at step 32. Stepping after the end warns
    once and returns the final observation with reward 0.

    Success (perching) is not part of the episode's end: ``task.profile.success`` judges the final state (no crash,
    ``|x|, |z| < 0.05`` m and ``|dx|, |dz| <= 2.0`` m/s).

    **Arguments**

    ``gym.make("SeagulGlider-v0", dt=None, render_mode=None, task=None, max_substep=None, params=None)``:

    * ``dt``: the control period in seconds (default ``control_period = 0.025``). The registered ``TimeLimit``
      counts default periods; with another ``dt`` also pass ``max_episode_steps=ceil(0.85 / dt)``
      (``seagul_envs.make_env`` does it) or ``max_episode_steps=-1`` to leave the episode end to the env.
    * ``render_mode``: ``"rgb_array"`` (a numpy frame, no display needed) or ``"human"``; ``render_fps`` is 40.
    * ``task``: a glider ``Task`` with other constants, e.g. ``make_glider_task(GliderParams(m=0.09))``; default
      ``make_task("glider")``.
    * ``max_substep``: the largest RK4 substep in seconds (default ``Task.max_sim_substep = 0.005``).
    * ``params``: another glider than the task's model, a mapping ``{name: value}`` over ``task.parameters.names``
      (``m, S_w, S_e, rho``; the others keep the model's values) or a full vector. The env then simulates
      ``task.with_params(params)`` (``env.unwrapped.task``; the model stays ``env.unwrapped.model_task``).

    ``reset(seed=None, options=None)`` takes the options (all optional):

    * ``"state"``: the start, any finite state inside the state bounds (the path bounds above, ``phi`` in its
      range).
    * ``"time_to_go"``: ``tau`` in ``(0, 0.85]`` s (the float32 time to go of an observation is accepted).
    * ``"params"``: the glider from this episode on, as the ``params`` argument (domain randomisation).

    Unknown keys and bad values raise ``ValueError`` and leave the env as it was.

    **Version History**

    * v0: initial version.

    **References**

    * B. Landry, H. Dai and M. Pavone, "SEAGuL: Sample Efficient Adversarially Guided Learning of Value
      Functions", Learning for Dynamics and Control (L4DC), PMLR 144, 2021. arXiv:2107.08893.
    * J. Moore, R. Cory and R. Tedrake, "Robust post-stall perching with a simple fixed-wing glider using
      LQR-Trees", Bioinspiration & Biomimetics, 9(2), 2014.
    """

    params_class: type = GliderParams
    """The parameter class of the tasks this env simulates (any name: variants of the system included)."""

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 40}  # noqa: RUF012 (Gymnasium convention)

    def __init__(
        self,
        dt: float | None = None,
        render_mode: str | None = None,
        task: Task | None = None,
        max_substep: float | None = None,
        params: Any = None,
    ) -> None:
        super().__init__(
            resolve_task(task, "glider", type(self).__name__, self.params_class),
            dt=dt,
            render_mode=render_mode,
            max_substep=max_substep,
            params=params,
        )
        self._trail: list[tuple[float, float]] = []

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        self._trail = []
        return super().reset(seed=seed, options=options)

    def _limit_action(self, u: np.ndarray, h: float) -> np.ndarray:
        # The elevator's range acts as a mechanical stop: dphi = u exactly, so clipping u to the travel left over
        # this step keeps phi inside [phi_min, phi_max] without touching the model. Trajectories that respect the
        # bounds (all optimizer solutions) are unchanged; random exploration never "crashes" on the elevator.
        phi = self._x[3]
        lo = max(self._u_low[0], (self._x_low[3] - phi) / h)
        hi = min(self._u_high[0], (self._x_high[3] - phi) / h)
        return np.array([min(max(u[0], lo), hi)])

    def _render_frame(self) -> np.ndarray:
        # The flown path is kept only while rendering (no cost on the training hot path).
        self._trail.append((float(self._x[0]), float(self._x[1])))
        p = self.task.params
        return glider_frame(
            self._x,
            p.l_h,
            p.l_e,
            (float(self.task.x_low[0]), float(self.task.x_high[0])),
            (float(self.task.x_low[1]), float(self.task.x_high[1])),
            trail=self._trail,
            ttg_fraction=self._ttg_fraction(),
        )
