"""An ensemble of value networks whose disagreement the MPC pays for: :class:`ValueEnsemble`.

``K`` :class:`~seagul_learn.value_network.ValueNetwork` members of one architecture are fitted to the same data and
differ in their initial weights (and, in training, their minibatches). Training metrics and the samplers use their
mean; the MPC optimises ``mean + pessimism * spread`` (:func:`seagul_learn.value_casadi.ensemble_network`), which
makes the states where the networks extrapolate expensive instead of attractive (docs/experiments/closed-loop.md).
An ensemble is saved in the value-network file format (:mod:`seagul_learn.value_files`, tag
``"seagul-value-ensemble"``) and :meth:`ValueNetwork.load <seagul_learn.value_network.ValueNetwork.load>` returns it.

:data:`ValueModel` (a network or an ensemble) is what training, the samplers and the MPC accept. Both names still
import from :mod:`seagul_learn.value_network`, where they lived first.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TypeAlias, cast

import casadi as ca
import numpy as np
import torch
from torch import nn

from seagul_learn.value_casadi import CasadiForm, ensemble_network
from seagul_learn.value_files import ENSEMBLE_FORMAT_TAG, ValueNetworkFileError, check_version, write_value_file
from seagul_learn.value_network import (
    ValueNetwork,
    ValueNetworkConfig,
    _predict,
    _value_and_grad,
    _value_and_grads,
)

__all__ = ["ValueEnsemble", "ValueModel"]


class ValueEnsemble(nn.Module):
    """``K`` value networks fitted to the same data; the MPC sees a *pessimistic* value where they disagree.

    ``predict``/``value_and_grad`` (training metrics, samplers) use the ensemble mean ``m(x, tau)``. The CasADi form
    the MPC optimises is ``m + beta * s`` with ``s = sqrt(mean_k (V_k - m)^2 + eps^2) - eps`` the (smoothed) spread
    over members and ``beta = pessimism`` an NLP parameter (the last entry of ``theta``). The members agree where
    the data are dense and disagree where a network extrapolates, which is where the MPC's optimizer finds
    under-estimates (docs/experiments/closed-loop.md); the spread term makes those states expensive instead of
    attractive. Members differ in their initial weights (and, in training, their minibatches).
    """

    #: Smoothing of the spread (value units): keeps ``sqrt`` differentiable where all members agree.
    SPREAD_EPS = 1e-3

    def __init__(
        self,
        nx: int,
        hidden: Sequence[int] = (32,),
        members: int = 5,
        pessimism: float = 1.0,
        task_name: str = "",
        seed: int | None = None,
        n_params: int = 0,
        theta: Any = None,
        task_fingerprint: str = "",
        periodic: Sequence[int] = (),
        theta_features: Sequence[Sequence[float]] = (),
    ) -> None:
        """``members`` networks of one architecture (arguments as for :class:`ValueNetwork`; ``periodic``: the
        state indices every member feeds as ``(cos q, sin q)``; ``theta_features``: what every member sees of the
        robot)."""
        super().__init__()
        if int(members) < 2:
            raise ValueError(f"an ensemble needs >= 2 members, got {members}")
        if not (np.isfinite(pessimism) and pessimism >= 0):
            raise ValueError(f"pessimism must be a finite number >= 0, got {pessimism}")
        base = 0 if seed is None else int(seed)
        self.members = nn.ModuleList(
            ValueNetwork(
                nx,
                hidden,
                task_name=task_name,
                seed=None if seed is None else 1000 * base + k,
                n_params=n_params,
                theta=theta,
                task_fingerprint=task_fingerprint,
                periodic=periodic,
                theta_features=theta_features,
            )
            for k in range(int(members))
        )
        self.pessimism = float(pessimism)
        self.task_name = str(task_name)
        self.task_fingerprint = str(task_fingerprint)
        """Fingerprint of the task the ensemble is trained for ("" if unknown; stored in its file)."""
        self.config: ValueNetworkConfig = self.networks[0].config

    @property
    def networks(self) -> list[ValueNetwork]:
        """The members in order (``self.members`` typed: ``nn.ModuleList`` yields plain modules)."""
        return cast("list[ValueNetwork]", list(self.members))

    @property
    def nx(self) -> int:
        """State dimension."""
        return self.config.nx

    @property
    def n_params(self) -> int:
        """Number of physical parameters among the inputs."""
        return self.config.n_params

    @property
    def periodic(self) -> tuple[int, ...]:
        """State indices the members feed as ``(cos q, sin q)``."""
        return self.config.periodic

    @property
    def theta(self) -> np.ndarray:
        """The members' condition (:meth:`ValueNetwork.condition`)."""
        return self.networks[0].theta

    def condition(self, theta: Any) -> None:
        """Set every member's condition."""
        for m in self.networks:
            m.condition(theta)

    @property
    def in_mean(self) -> torch.Tensor:
        """Input standardisation (shared by the members)."""
        return self.networks[0].in_mean

    @property
    def in_std(self) -> torch.Tensor:
        """Input standardisation scale (shared by the members)."""
        return self.networks[0].in_std

    def set_normalization(
        self, x: np.ndarray, tau: np.ndarray, value: np.ndarray, theta: np.ndarray | None = None
    ) -> None:
        """The same standardisation for every member."""
        for m in self.networks:
            m.set_normalization(x, tau, value, theta)

    def renormalize(self, x: np.ndarray, tau: np.ndarray, value: np.ndarray, theta: np.ndarray | None = None) -> None:
        """:meth:`ValueNetwork.renormalize` for every member (the function of each is unchanged)."""
        for m in self.networks:
            m.renormalize(x, tau, value, theta)

    def forward(self, x: torch.Tensor, tau: torch.Tensor, theta: torch.Tensor | None = None) -> torch.Tensor:
        """The ensemble mean."""
        return torch.stack([m(x, tau, theta) for m in self.members]).mean(dim=0)

    def subset(self, indices: Sequence[int], pessimism: float | None = None) -> ValueEnsemble:
        """A new ensemble of copies of the members ``indices`` (in that order; at least 2, no repeats), with this
        ensemble's pessimism unless ``pessimism`` is given."""
        idx = [int(i) for i in indices]
        if len(idx) < 2 or len(set(idx)) != len(idx) or not all(0 <= i < len(self.members) for i in idx):
            raise ValueError(f"subset needs >= 2 distinct member indices in 0..{len(self.members) - 1}, got {idx}")
        out = ValueEnsemble(
            self.nx,
            self.config.hidden,
            len(idx),
            self.pessimism if pessimism is None else float(pessimism),
            task_name=self.task_name,
            n_params=self.n_params,
            task_fingerprint=self.task_fingerprint,
            periodic=self.periodic,
            theta_features=self.config.theta_features,
        )
        for k, i in enumerate(idx):
            out.members[k].load_state_dict(self.members[i].state_dict())
        return out

    def spread(self, x: Any, tau: Any, theta: Any = None) -> np.ndarray:
        """Standard deviation over members at a batch (NumPy); ``theta``: the robots of an ensemble over robots."""
        with torch.no_grad():
            x_t = torch.as_tensor(np.atleast_2d(np.asarray(x, dtype=np.float64)))
            t_t = torch.tensor(np.broadcast_to(np.asarray(tau, dtype=np.float64).reshape(-1), (x_t.shape[0],)).copy())
            th_t = None
            if theta is not None:
                th_t = torch.as_tensor(np.asarray(theta, dtype=np.float64)).reshape(x_t.shape[0], -1)
            values = torch.stack([m(x_t, t_t.clone(), th_t) for m in self.members])
            return values.std(dim=0, unbiased=False).numpy()

    def value_and_grad(self, x: Any, tau: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """NumPy helper: ``(mean, dmean/dx, dmean/dtau)``, as :meth:`ValueNetwork.value_and_grad`."""
        return _value_and_grad(self.forward, x, tau)

    def predict(self, x: Any, tau: Any, theta: Any = None) -> np.ndarray:
        """NumPy values of the ensemble mean for a batch."""
        return _predict(self.forward, x, tau, theta)

    def value_and_grads(
        self, x: Any, tau: Any, theta: Any = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(mean, dmean/dx, dmean/dtau, dmean/dtheta)``, as :meth:`ValueNetwork.value_and_grads`."""
        return _value_and_grads(self, x, tau, theta)

    # ----------------------------------------------------------------- casadi
    def casadi_parameters(self) -> np.ndarray:
        """``theta``: every member's parameters in order, then ``pessimism``."""
        return np.concatenate([*(m.casadi_parameters() for m in self.networks), [self.pessimism]])

    def casadi_function(self, form: CasadiForm = "scalar") -> ca.Function:
        """CasADi ``(x, tau, theta) -> mean + pessimism * spread``; depends only on the architecture and ``K``.
        ``form`` as for :meth:`ValueNetwork.casadi_function` (``"matrix"``: MX, for compiled code)."""
        return ensemble_network(
            self.nx, self.config.hidden, len(self.members), form, self.n_params, self.SPREAD_EPS, self.periodic
        )

    # -------------------------------------------------------------------- i/o
    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the ensemble to ``path`` atomically; :meth:`ValueNetwork.load` reads it back."""
        config: dict[str, Any] = {
            "nx": self.config.nx,
            "hidden": list(self.config.hidden),
            "members": len(self.members),
            "pessimism": self.pessimism,
            "n_params": self.n_params,
        }
        if self.periodic:  # only then: other files keep their layout
            config["periodic"] = list(self.periodic)
        if self.config.theta_features:  # likewise
            config["theta_features"] = [list(row) for row in self.config.theta_features]
        return write_value_file(path, ENSEMBLE_FORMAT_TAG, self.task_name, config, self, self.task_fingerprint)

    @classmethod
    def _from_payload(cls, payload: dict[str, Any], path: Path) -> ValueEnsemble:
        check_version(payload, path)
        try:
            c = payload["config"]
            ens = cls(
                int(c["nx"]),
                tuple(c["hidden"]),
                int(c["members"]),
                float(c["pessimism"]),
                task_name=str(payload["task_name"]),
                n_params=int(c.get("n_params", 0)),
                task_fingerprint=str(payload.get("task_fingerprint", "")),  # older files have none
                periodic=tuple(c.get("periodic", ())),  # files of ensembles without periodic angles have none
                theta_features=c.get("theta_features", ()),  # files of ensembles fed theta itself have none
            )
            ens.load_state_dict(payload["state_dict"])
        except Exception as exc:
            raise ValueNetworkFileError(
                f"value ensemble file {str(path)!r} is inconsistent ({type(exc).__name__}: {exc})"
            ) from exc
        return ens

    def extra_repr(self) -> str:
        return f"task={self.task_name!r}, members={len(self.members)}, pessimism={self.pessimism}"


ValueModel: TypeAlias = ValueNetwork | ValueEnsemble
"""What training, the samplers and the MPC accept as a learned value function: a network or an ensemble."""
