"""The protocol by which value functions cross layers (``seagul_control`` never imports torch)."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import casadi as ca
import numpy as np


@runtime_checkable
class CasadiValueFunction(Protocol):
    """Anything the MPC can use as a terminal cost ``Vhat(x, tau)``.

    ``casadi_function()`` returns a CasADi Function ``(x[nx], tau[1], theta[n_params]) -> V[1]`` whose structure
    depends only on the architecture; ``casadi_parameters()`` returns the current numeric ``theta`` (weights and
    normalisation). The MPC feeds ``theta`` as NLP parameters, so a newly trained network never rebuilds a solver.

    Optionally ``casadi_function(form="matrix")`` returns the same function as an MX graph of matrix products: a
    compiled MPC (``jit=True``) then generates its lookahead unexpanded, which keeps large networks' exact Hessians
    small and fast (``seagul_learn.ValueNetwork`` and ``ValueEnsemble`` offer it). A value function without the
    ``form`` argument is used in its one (scalar) form.

    Optionally ``task_fingerprint`` is the :meth:`~seagul_envs.tasks.base.Task.fingerprint` of the task the value
    function was trained for (``seagul_learn.ValueNetwork`` stores it in its file). The MPC refuses a value function
    whose fingerprint differs from its task's (a same-named variant: another mass, other bounds or costs) and accepts
    one without it (absent or ``""``), so it is not part of the protocol's required members.
    """

    task_name: str

    def casadi_function(self) -> ca.Function: ...

    def casadi_parameters(self) -> np.ndarray: ...
