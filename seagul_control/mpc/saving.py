"""Saving controllers to one file and rebuilding them without torch, in the spirit of stable-baselines3's zip format.

``LimitedLookaheadMPC.save(path)`` (and ``FullHorizonMPC.save``, ``LQRPolicy.save``) write one zip archive:

* ``data.json``: ``{"format": "seagul-mpc", "version": 1, "class", "horizon", "options", "model_params",
  "estimate_robot", "task_name", "task_fingerprint", "seagul_version", "value_function"}``; ``options`` is
  the controller's resolved :class:`~seagul_control.mpc.MPCOptions` (``to_dict``), with the trust box in use;
* ``value_function/<form>.casadi``: every CasADi form the value function offers (``"scalar"`` always;
  ``"matrix"``, ``"taylor"`` and ``"taylor_model"`` when it has them), as ``casadi.Function.serialize()`` text;
* ``value_function/parameters.npy``: the parameters ``theta`` the MPC feeds them (``casadi_parameters()``);
* ``value_function/network.pt``: the value function's own file when it has a ``save(path)`` method (a
  ``seagul_learn.ValueNetwork`` or ``ValueEnsemble``), so the network itself can be had back
  (:func:`extract_value_function_file`, then ``ValueNetwork.load``).

:func:`load_mpc` rebuilds the controller from the CasADi forms alone (no torch, no ``seagul_learn``): the value
function becomes a :class:`SavedValueFunction`, which gives the MPC the very same functions and parameters, so the
loaded controller solves the same NLPs and acts like the saved one. The task is given or made from its stored name
(``seagul_envs.make_task``); a task whose fingerprint differs from the stored one (a same-named variant) raises a
ValueError naming both. What a controller learns while running is not saved: warm starts, step statistics, the
robot given to ``set_robot`` and online estimates start afresh.
"""

from __future__ import annotations

import copy
import inspect
import io
import json
import os
import tempfile
import zipfile
from collections.abc import Mapping
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from seagul_control.io import atomic_write_bytes
from seagul_control.mpc.options import FullHorizonOptions, MPCOptions
from seagul_envs import make_task
from seagul_envs.tasks.base import Task
from seagul_envs.tasks.parameters import log_features

FORMAT_TAG = "seagul-mpc"
FORMAT_VERSION = 1
#: The CasADi forms of a value function, in the order they are looked for.
FORMS = ("scalar", "matrix", "taylor", "taylor_model")
_VF_DIR = "value_function"
_NETWORK_FILE = f"{_VF_DIR}/network.pt"


# ---------------------------------------------------------------------------------------------- the archive
def seagul_version() -> str:
    """The installed seagul distribution's version (``"0+unknown"`` when it is not installed)."""
    try:
        return version("seagul")
    except PackageNotFoundError:
        return "0+unknown"


def _json_default(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"{type(value).__name__} {value!r} is not JSON-serialisable")


def write_archive(path: str | os.PathLike[str], data: Mapping[str, Any], members: Mapping[str, bytes]) -> Path:
    """Write ``data.json`` (``data``) and ``members`` into one zip file at ``path``, atomically; returns the path."""
    path = Path(path)
    try:
        text = json.dumps(data, indent=2, sort_keys=True, default=_json_default)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"cannot save to {str(path)!r}: a setting is not JSON-serialisable ({exc})") from exc
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("data.json", text)
        for name, blob in members.items():
            archive.writestr(name, blob)
    atomic_write_bytes(path, buffer.getvalue())
    return path


def read_archive(path: str | os.PathLike[str], tag: str) -> tuple[dict[str, Any], dict[str, bytes]]:
    """``(data, members)`` of a file written by :func:`write_archive` with format ``tag``.

    Raises:
        ValueError: the file is missing, not a zip archive, has no ``data.json``, another format or version.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"controller file {str(path)!r} does not exist")
    try:
        with zipfile.ZipFile(path) as archive:
            members = {name: archive.read(name) for name in archive.namelist()}
    except zipfile.BadZipFile as exc:
        raise ValueError(f"{str(path)!r} is not a seagul controller file (not a zip archive: {exc})") from exc
    if "data.json" not in members:
        raise ValueError(f"{str(path)!r} is not a seagul controller file (no data.json)")
    data = json.loads(members.pop("data.json"))
    if not isinstance(data, dict) or data.get("format") != tag:
        raise ValueError(f"{str(path)!r} is not a {tag!r} file (format {data.get('format')!r})")
    if data.get("version") != FORMAT_VERSION:
        raise ValueError(
            f"{str(path)!r} has {tag} format version {data.get('version')!r}; "
            f"this seagul reads version {FORMAT_VERSION}"
        )
    return data, members


def resolve_saved_task(data: Mapping[str, Any], task: Task | None, path: str | os.PathLike[str]) -> Task:
    """The task to rebuild a saved controller for: ``task``, else ``make_task`` of the stored name; its fingerprint
    must equal the stored one.

    Raises:
        ValueError: the fingerprints differ (the message names both and what to do).
    """
    if task is None:
        task = make_task(str(data["task_name"]))
    stored, actual = str(data["task_fingerprint"]), task.fingerprint()
    if stored != actual:
        raise ValueError(
            f"{os.fspath(path)!r} was saved for task {data['task_name']!r} with fingerprint {stored}, but the task "
            f"given ({task.name!r}) has fingerprint {actual}: another variant of the task (parameters, bounds, costs "
            "or profile differ). Pass the task the controller was built for as load(path, task=...), or build a new "
            "controller for this task."
        )
    return task


# ------------------------------------------------------------------------------------------ value function
class SavedValueFunction:
    """A value function read back from a controller file: its CasADi forms and parameters, without torch.

    It implements :class:`~seagul_control.value_function.CasadiValueFunction` with the forms the saved value
    function offered (:meth:`casadi_function`), its parameters (:meth:`casadi_parameters`), the training box the
    MPC derived from it (:meth:`training_box`) and the task's name and fingerprint it recorded. A value function over
    robots (``n_params > 0``) keeps the positions of its condition in the parameters, so :meth:`condition` (called
    by the MPC's ``set_robot``) works as the original's did.
    """

    def __init__(
        self,
        forms: Mapping[str, ca.Function],
        parameters: np.ndarray,
        *,
        task_name: str = "",
        task_fingerprint: str = "",
        training_box: tuple[np.ndarray, np.ndarray] | None = None,
        condition_index: list[list[int]] | None = None,
        network_file: bytes | None = None,
        condition_exponents: list[list[float]] | None = None,
    ) -> None:
        if "scalar" not in forms:
            raise ValueError("a saved value function needs its scalar form")
        self.forms = dict(forms)
        self.parameters = np.asarray(parameters, dtype=float).ravel().copy()
        self.task_name = task_name
        self.task_fingerprint = task_fingerprint
        self._box = training_box
        self.condition_index = condition_index
        self.condition_exponents = None if condition_exponents is None else np.asarray(condition_exponents, dtype=float)
        """The exponent rows ``E`` of a value function fed its robot's features ``log(theta) @ E.T`` (the
        original's ``config.theta_features``; entry ``i`` of :attr:`condition_index` then holds feature ``i``), or
        None: the condition is stored as is."""
        self.n_params = 0 if condition_index is None else len(condition_index)
        self.network_file = network_file
        """The original value function's own file (``ValueNetwork.save``), or None."""

    def casadi_function(self, form: str = "scalar") -> ca.Function:
        """The saved form ``form``; ``"matrix"`` falls back to the scalar form when the original had only that one
        (as the MPC treats a value function without forms); a missing Taylor form raises a ValueError."""
        if form in self.forms:
            return self.forms[form]
        if form == "matrix":
            return self.forms["scalar"]
        raise ValueError(f"the saved value function has no {form!r} form (it has {sorted(self.forms)})")

    def casadi_parameters(self) -> np.ndarray:
        """The parameters ``theta`` (a copy)."""
        return self.parameters.copy()

    def training_box(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The box the MPC derived from the original value function (its trust box), or None."""
        return self._box

    def condition(self, theta: Any) -> None:
        """Condition a value function over robots on the robot ``theta`` (writes it into the parameters)."""
        if self.condition_index is None:
            raise ValueError("condition() needs a value function over physical parameters (n_params > 0)")
        arr = np.asarray(theta, dtype=float).ravel()
        if arr.shape != (self.n_params,) or not np.all(np.isfinite(arr)):
            raise ValueError(f"theta must be {self.n_params} finite numbers, got {np.asarray(theta).tolist()}")
        stored = arr if self.condition_exponents is None else log_features(arr, self.condition_exponents)
        for j, positions in enumerate(self.condition_index):
            self.parameters[positions] = stored[j]

    def __deepcopy__(self, memo: dict[int, Any]) -> SavedValueFunction:
        # The CasADi functions are immutable and shared; the parameters are the copy's own.
        return SavedValueFunction(
            self.forms,
            self.parameters,
            task_name=self.task_name,
            task_fingerprint=self.task_fingerprint,
            training_box=self._box,
            condition_index=self.condition_index,
            network_file=self.network_file,
            condition_exponents=None if self.condition_exponents is None else self.condition_exponents.tolist(),
        )


def _forms_of(vf: Any) -> dict[str, ca.Function]:
    """Every CasADi form ``vf`` offers (its scalar form always; the others when it takes ``form=`` and has them)."""
    forms = {"scalar": vf.casadi_function()}
    if "form" in inspect.signature(vf.casadi_function).parameters:
        for form in FORMS[1:]:
            try:
                fn = vf.casadi_function(form=form)
            except ValueError:
                continue
            if isinstance(fn, ca.Function):
                forms[form] = fn
    return forms


def _condition_exponents(vf: Any) -> np.ndarray | None:
    """The exponent rows ``E`` of a value function fed ``log(theta) @ E.T`` (``config.theta_features`` of a
    ``seagul_learn`` network or ensemble, or a saved one's), or None."""
    if isinstance(vf, SavedValueFunction):
        return vf.condition_exponents
    rows = getattr(getattr(vf, "config", None), "theta_features", ())
    return np.asarray(rows, dtype=float) if rows else None


def _condition_index(vf: Any, robot: np.ndarray, exponents: np.ndarray | None) -> list[list[int]]:
    """Where a value function over robots keeps its condition in ``casadi_parameters()``: probed on a copy by
    conditioning on robots that change one stored entry at a time (``robot`` itself, or with ``exponents`` one of
    its features ``log(theta) @ E.T``; each must be stored as is). A feature of a zero row never changes and keeps
    no positions."""
    probe = copy.deepcopy(vf)
    probe.condition(robot)
    base = np.asarray(probe.casadi_parameters(), dtype=float).ravel()
    index: list[list[int]] = []
    for j in range(robot.size):
        if exponents is None:
            changed = robot.copy()
            changed[j] = robot[j] + 1.0 + abs(robot[j])
            expected = changed[j]
        elif not np.any(exponents[j]):
            index.append([])
            continue
        else:  # move log(theta) so that feature j alone changes, by 0.1
            changed = robot * np.exp(0.1 * np.linalg.pinv(exponents)[:, j])
            expected = float(log_features(changed, exponents[j]))
        probe.condition(changed)
        params = np.asarray(probe.casadi_parameters(), dtype=float).ravel()
        positions = np.flatnonzero(params != base)
        if positions.size == 0 or not np.allclose(params[positions], expected, rtol=1e-12, atol=1e-12):
            raise ValueError(
                "cannot save a value function over robots whose condition is not stored as is in its CasADi parameters"
            )
        index.append(positions.tolist())
        probe.condition(robot)
    return index


def _value_function_members(mpc: Any) -> tuple[dict[str, Any] | None, dict[str, bytes]]:
    """``data.json``'s ``value_function`` entry and the archive members of ``mpc``'s value function."""
    vf = mpc.value_function
    if vf is None:
        return None, {}
    forms = _forms_of(vf)
    members = {f"{_VF_DIR}/{form}.casadi": fn.serialize().encode() for form, fn in forms.items()}
    params = np.asarray(vf.casadi_parameters(), dtype=float).ravel()
    buffer = io.BytesIO()
    np.save(buffer, params, allow_pickle=False)
    members[f"{_VF_DIR}/parameters.npy"] = buffer.getvalue()
    n_params = int(getattr(vf, "n_params", 0) or 0)
    exponents = _condition_exponents(vf) if n_params > 0 else None
    condition = _condition_index(vf, mpc.task.theta, exponents) if n_params > 0 else None
    network: bytes | None = getattr(vf, "network_file", None) if isinstance(vf, SavedValueFunction) else None
    save = getattr(vf, "save", None)
    if network is None and callable(save):
        with tempfile.TemporaryDirectory(prefix="seagul_save_") as tmp:
            written = save(Path(tmp) / "network.pt")
            network = Path(written if written is not None else Path(tmp) / "network.pt").read_bytes()
    if network is not None:
        members[_NETWORK_FILE] = network
    low, high = mpc._trust_box(vf)
    entry = {
        "class": type(vf).__name__,
        "task_name": str(getattr(vf, "task_name", "") or ""),
        "task_fingerprint": str(getattr(vf, "task_fingerprint", "") or ""),
        "forms": sorted(forms),
        "n_parameters": int(params.size),
        "training_box": [np.asarray(low).tolist(), np.asarray(high).tolist()],
        "condition_index": condition,
        "condition_exponents": None if exponents is None else exponents.tolist(),
        "network_file": _NETWORK_FILE if network is not None else None,
    }
    return entry, members


def _read_value_function(entry: Mapping[str, Any], members: Mapping[str, bytes]) -> SavedValueFunction:
    forms = {form: ca.Function.deserialize(members[f"{_VF_DIR}/{form}.casadi"].decode()) for form in entry["forms"]}
    params = np.load(io.BytesIO(members[f"{_VF_DIR}/parameters.npy"]), allow_pickle=False)
    low, high = entry["training_box"]
    return SavedValueFunction(
        forms,
        params,
        task_name=str(entry.get("task_name", "")),
        task_fingerprint=str(entry.get("task_fingerprint", "")),
        training_box=(np.asarray(low, dtype=float), np.asarray(high, dtype=float)),
        condition_index=entry.get("condition_index"),
        network_file=members.get(_NETWORK_FILE),
        condition_exponents=entry.get("condition_exponents"),  # files of value functions fed theta itself: None
    )


# ---------------------------------------------------------------------------------------------- the MPCs
def save_mpc(mpc: Any, path: str | os.PathLike[str]) -> Path:
    """Write a :class:`~seagul_control.mpc.LimitedLookaheadMPC` or :class:`~seagul_control.mpc.FullHorizonMPC` to
    one zip file (module docstring); returns the path.

    Raises:
        ValueError: a setting is not JSON-serialisable (e.g. an exotic ``solver_options`` value).
    """
    # The controller modules import this one at module level (their save/load methods): import cycle.
    from seagul_control.mpc.full_horizon import FullHorizonMPC
    from seagul_control.mpc.lookahead import LimitedLookaheadMPC

    data: dict[str, Any] = {
        "format": FORMAT_TAG,
        "version": FORMAT_VERSION,
        "class": type(mpc).__name__,
        "horizon": int(mpc.horizon),
        "model_params": bool(mpc.model_params),
        "task_name": mpc.task.name,
        "task_fingerprint": mpc.task.fingerprint(),
        "seagul_version": seagul_version(),
    }
    members: dict[str, bytes] = {}
    if isinstance(mpc, LimitedLookaheadMPC):
        options = mpc.options
        if mpc.value_function is not None:
            low, high = mpc.trust_box
            options = options.replace(trust_box=(low, high))
        entry, members = _value_function_members(mpc)
        data.update(options=options.to_dict(), estimate_robot=mpc.estimate_robot, value_function=entry)
    elif isinstance(mpc, FullHorizonMPC):
        data.update(options=mpc.options.to_dict(), estimate_robot=False, value_function=None)
    else:
        raise TypeError(f"save_mpc saves a LimitedLookaheadMPC or a FullHorizonMPC, not a {type(mpc).__name__}")
    return write_archive(path, data, members)


def load_mpc(path: str | os.PathLike[str], task: Task | None = None) -> Any:
    """Rebuild the controller :func:`save_mpc` wrote to ``path`` (no torch needed).

    Args:
        path: the file.
        task: the task to build it for; default ``seagul_envs.make_task`` of the stored name. Its fingerprint must
            equal the stored one.

    Raises:
        ValueError: not a seagul MPC file, another format version, or a task whose fingerprint differs.
    """
    from seagul_control.mpc.full_horizon import FullHorizonMPC
    from seagul_control.mpc.lookahead import LimitedLookaheadMPC

    data, members = read_archive(path, FORMAT_TAG)
    task = resolve_saved_task(data, task, path)
    if data["class"] == "LimitedLookaheadMPC":
        entry = data.get("value_function")
        vf = None if entry is None else _read_value_function(entry, members)
        estimate = data.get("estimate_robot", False)
        return LimitedLookaheadMPC(
            task,
            vf,
            int(data["horizon"]),
            MPCOptions.from_dict(data["options"]),
            model_params=bool(data["model_params"]),
            estimate_robot=estimate if isinstance(estimate, (bool, dict)) else False,
        )
    if data["class"] == "FullHorizonMPC":
        options = FullHorizonOptions.from_dict(data["options"])
        return FullHorizonMPC(task, options, horizon=int(data["horizon"]), model_params=bool(data["model_params"]))
    raise ValueError(f"{os.fspath(path)!r} holds an unknown controller class {data['class']!r}")


def extract_value_function_file(path: str | os.PathLike[str], dest: str | os.PathLike[str]) -> Path:
    """Write the value function's own file stored in the controller file ``path`` to ``dest`` (then
    ``seagul_learn.ValueNetwork.load(dest)`` gives the network back); returns ``dest``.

    Raises:
        ValueError: ``path`` is not a seagul MPC file or holds no value-function file (a value function without a
            ``save`` method, or none).
    """
    _, members = read_archive(path, FORMAT_TAG)
    if _NETWORK_FILE not in members:
        raise ValueError(f"{os.fspath(path)!r} holds no value-function file (its value function had no save method)")
    dest = Path(dest)
    atomic_write_bytes(dest, members[_NETWORK_FILE])
    return dest


__all__ = [
    "FORMAT_TAG",
    "FORMAT_VERSION",
    "SavedValueFunction",
    "extract_value_function_file",
    "load_mpc",
    "read_archive",
    "resolve_saved_task",
    "save_mpc",
    "write_archive",
]
