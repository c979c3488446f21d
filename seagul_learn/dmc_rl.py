"""stable-baselines3 PPO and SAC on the DeepMind Control Suite swing-ups, set up as their reference implementations
are, scored by :func:`seagul_control.dmc.run_dmc_episode` on the same episodes as every seagul controller.

Settings are data: ``seagul_learn/hyperparams/dmc.yml`` (:func:`dmc_settings`), one entry per algorithm and env id,
each value with its source (CleanRL's ``ppo_continuous_action.py`` for PPO, ``denisyarats/pytorch_sac`` for SAC)
and the places SB3 differs from it.

:func:`train_dmc_sb3` trains one (algorithm, env, seed) into a directory:

* the agent sees the env as shimmy makes it, its observation dict flattened (``FlattenObservation``), through
  ``VecNormalize`` (observations and rewards, clipped to 10) when the entry's ``normalize`` says so;
* every ``eval_every`` environment steps a validation point is measured: ``validation_episodes`` deterministic
  episodes run by :func:`~seagul_control.dmc.run_dmc_episode` from reset seeds ``1000, 1001, ...``
  (:data:`VALIDATION_SEED`; never the scoring seeds 0-9), scored by dm_control's return; a point with a higher
  mean than every earlier one saves the model and its normalisation statistics into ``best/`` (the selected model);
* at every validation point a checkpoint (model, statistics, SAC's replay buffer, the curve so far) is written to
  ``checkpoint/``; a run interrupted later resumes from it (from that point on, not bit-identical to an
  uninterrupted run: the episode in progress restarts and the random streams are new); a finished run
  (``curve.json`` with the same settings) is returned as it is, not trained again;
* ``curve.json``: the settings, the validation curve (``env_steps``, ``train_wall_s``, ``scores``, ``mean``), the
  best point, the training wall time (validation excluded) and the environment steps.

:func:`evaluate_sb3_dmc` scores a saved model (``best/`` by default) on given reset seeds, acting deterministically
on dm_control's flattened observation (:class:`SB3DMCController`, ``observation = "dm_control"``).

stable-baselines3 and torch are imported by the functions that need them.
"""

from __future__ import annotations

import copy
import json
import shutil
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml  # type: ignore[import-untyped]

from seagul_control.dmc import dmc_env_id, make_dmc_env, run_dmc_episode, run_dmc_episodes
from seagul_control.io import atomic_write_json
from seagul_learn.baselines import quiet_logger

__all__ = [
    "ALGOS",
    "HYPERPARAMS",
    "VALIDATION_SEED",
    "SB3DMCController",
    "dmc_settings",
    "evaluate_sb3_dmc",
    "load_sb3_dmc",
    "measure_throughput",
    "train_dmc_sb3",
    "validation_seeds",
]

#: The algorithms (keys of ``dmc.yml``).
ALGOS: tuple[str, ...] = ("ppo", "sac")

#: The settings file.
HYPERPARAMS = Path(__file__).resolve().parent / "hyperparams" / "dmc.yml"

#: First reset seed of the validation episodes (checkpoint selection); the scoring seeds are 0-9.
VALIDATION_SEED = 1000

#: Offset of the training envs' first reset seed (the training seed is added): training starts are a stream of
#: their own too.
TRAIN_ENV_SEED = 1_000_000

#: Keys of an entry that are not SB3 constructor arguments.
RUN_KEYS: tuple[str, ...] = (
    "n_timesteps",
    "n_envs",
    "normalize",
    "anneal_lr",
    "eval_every",
    "validation_episodes",
    "policy",
)

_ACTIVATIONS = ("tanh", "relu", "elu", "leaky_relu")


def _algo(algo: str) -> str:
    name = str(algo).lower()
    if name not in ALGOS:
        raise ValueError(f"unknown algo {algo!r}; choose one of {list(ALGOS)}")
    return name


def dmc_settings(algo: str, env_id: str, overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """The entry of ``env_id`` (or its short form) under ``algo`` (``"ppo"``/``"sac"``, any case) in
    :data:`HYPERPARAMS` (its ``default`` entry for an id it lacks), with ``overrides`` over it (top-level keys
    replace; ``policy_kwargs`` is merged key by key). Unknown algo or env: ``ValueError`` naming it."""
    name = _algo(algo)
    full = dmc_env_id(env_id)
    entries = yaml.safe_load(HYPERPARAMS.read_text())[name]
    entry = copy.deepcopy(entries.get(full, entries["default"]))
    for key, value in (overrides or {}).items():
        if key == "policy_kwargs" and isinstance(value, dict):
            entry["policy_kwargs"] = {**entry.get("policy_kwargs", {}), **copy.deepcopy(value)}
        else:
            entry[key] = copy.deepcopy(value)
    for key in ("n_timesteps", "n_envs", "eval_every", "validation_episodes"):
        if not isinstance(entry.get(key), int) or isinstance(entry.get(key), bool) or int(entry[key]) < 1:
            raise ValueError(f"setting {key} must be a positive integer, got {entry.get(key)!r}")
    activation = entry.get("policy_kwargs", {}).get("activation_fn")
    if activation is not None and activation not in _ACTIVATIONS:
        raise ValueError(f"policy_kwargs.activation_fn must be one of {list(_ACTIVATIONS)}, got {activation!r}")
    return entry


def validation_seeds(settings: dict[str, Any]) -> list[int]:
    """The reset seeds of a validation point: ``VALIDATION_SEED + i`` for ``i < validation_episodes``."""
    return [VALIDATION_SEED + i for i in range(int(settings["validation_episodes"]))]


def _flat_env(env_id: str) -> Callable[[], Any]:
    def make() -> Any:
        from gymnasium.wrappers import FlattenObservation

        return FlattenObservation(make_dmc_env(env_id))

    return make


def _training_env(env_id: str, seed: int, settings: dict[str, Any]) -> Any:
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    venv: Any = make_vec_env(
        _flat_env(env_id), n_envs=int(settings["n_envs"]), seed=TRAIN_ENV_SEED + seed, vec_env_cls=DummyVecEnv
    )
    if settings.get("normalize"):
        venv = VecNormalize(
            venv, norm_obs=True, norm_reward=True, clip_obs=10.0, clip_reward=10.0, gamma=float(settings["gamma"])
        )
    return venv


def _constructor_kwargs(settings: dict[str, Any]) -> dict[str, Any]:
    import torch
    from stable_baselines3.common.utils import LinearSchedule

    kwargs = {k: v for k, v in settings.items() if k not in RUN_KEYS}
    policy_kwargs = copy.deepcopy(kwargs.pop("policy_kwargs", {}) or {})
    activation = policy_kwargs.get("activation_fn")
    if activation is not None:
        policy_kwargs["activation_fn"] = {
            "tanh": torch.nn.Tanh,
            "relu": torch.nn.ReLU,
            "elu": torch.nn.ELU,
            "leaky_relu": torch.nn.LeakyReLU,
        }[activation]
    if settings.get("anneal_lr"):
        kwargs["learning_rate"] = LinearSchedule(float(settings["learning_rate"]), 0.0, 1.0)
    kwargs["policy_kwargs"] = policy_kwargs
    return kwargs


class SB3DMCController:
    """A saved or live SB3 model as a :func:`~seagul_control.dmc.run_dmc_episode` controller: it declares
    ``observation = "dm_control"``, normalises the flattened observation with ``obs_rms`` (VecNormalize's running
    statistics, clipped to ``clip_obs``) when given, and returns the deterministic action."""

    observation = "dm_control"

    def __init__(self, model: Any, normalizer: Any = None, name: str = "sb3") -> None:
        self.model = model
        self.normalizer = normalizer
        self.name = name

    def __call__(self, obs: np.ndarray, t: float) -> np.ndarray:
        batch = np.asarray(obs, dtype=np.float64)[None, :]
        if self.normalizer is not None:
            batch = self.normalizer.normalize_obs(batch)
        action, _ = self.model.predict(batch.astype(np.float32), deterministic=True)
        return np.asarray(action, dtype=float).reshape(-1)


def _save_policy(model: Any, venv: Any, out: Path, meta: dict[str, Any]) -> None:
    """``model.zip``, ``vecnormalize.pkl`` (with normalisation) and ``policy.json`` into ``out``, via a sibling
    temporary directory renamed over it."""
    tmp = out.with_name(out.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    model.save(tmp / "model.zip")
    if venv is not None:
        venv.save(str(tmp / "vecnormalize.pkl"))
    atomic_write_json(tmp / "policy.json", meta, indent=1)
    shutil.rmtree(out, ignore_errors=True)
    tmp.rename(out)


def load_sb3_dmc(model_dir: str | Path) -> SB3DMCController:
    """The controller of a saved model directory (``model.zip``, ``policy.json``, ``vecnormalize.pkl`` if the run
    normalised observations), the statistics frozen."""
    import stable_baselines3
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    model_dir = Path(model_dir)
    meta_path = model_dir / "policy.json"
    if not meta_path.is_file():
        raise FileNotFoundError(f"{model_dir} holds no saved model (no policy.json)")
    meta = json.loads(meta_path.read_text())
    cls = getattr(stable_baselines3, meta["algo"].upper())
    model = cls.load(model_dir / "model.zip", device="cpu")
    normalizer = None
    if (model_dir / "vecnormalize.pkl").is_file():
        normalizer = VecNormalize.load(str(model_dir / "vecnormalize.pkl"), DummyVecEnv([_flat_env(meta["env_id"])]))
        normalizer.training = False
        normalizer.norm_reward = False
    return SB3DMCController(model, normalizer, name=f"{meta['algo']}-seed{meta['seed']}")


def evaluate_sb3_dmc(model_dir: str | Path, env_id: str, seeds: Sequence[int]) -> dict[str, Any]:
    """Score the model saved in ``model_dir`` (a run directory's ``best/`` or ``final/``; a run directory itself
    means its ``best/``) in ``env_id`` on each reset seed: deterministic actions on dm_control's flattened
    observation, one episode per seed by :func:`~seagul_control.dmc.run_dmc_episodes`. Returns ``env_id``,
    ``model``, ``seeds``, ``scores``, ``mean``, ``std``, ``decision_ms_median``."""
    full = dmc_env_id(env_id)
    path = Path(model_dir)
    if not (path / "policy.json").is_file() and (path / "best" / "policy.json").is_file():
        path = path / "best"
    controller = load_sb3_dmc(path)
    meta = json.loads((path / "policy.json").read_text())
    if meta["env_id"] != full:
        raise ValueError(f"the model in {path} was trained in {meta['env_id']}, not {full}")
    seeds = [int(s) for s in seeds]
    if not seeds:
        raise ValueError("seeds must name at least one reset seed")
    episodes = run_dmc_episodes(full, controller, seeds)
    scores = [e.score for e in episodes]
    return {
        "env_id": full,
        "model": str(path),
        "seeds": seeds,
        "scores": scores,
        "mean": float(np.mean(scores)),
        "std": float(np.std(scores)),
        "decision_ms_median": float(np.median([e.decision_ms_median for e in episodes])),
    }


def _config(algo: str, env_id: str, seed: int, steps: int, settings: dict[str, Any]) -> dict[str, Any]:
    return {"algo": algo, "env_id": env_id, "seed": seed, "steps": steps, "settings": settings}


def _same(path: Path, config: dict[str, Any]) -> dict[str, Any] | None:
    if not path.is_file():
        return None
    stored = json.loads(path.read_text())
    return stored if stored.get("config") == config else None


def train_dmc_sb3(
    algo: str,
    env_id: str,
    seed: int,
    steps: int,
    out: str | Path,
    settings: dict[str, Any] | None = None,
    progress: bool = False,
    on_point: Callable[[dict[str, Any]], None] | None = None,
) -> dict[str, Any]:
    """Train ``algo`` (``"ppo"``/``"sac"``) in ``env_id`` with training seed ``seed`` for ``steps`` environment
    steps into ``out`` (see the module docstring); ``settings`` overrides the entry of ``dmc.yml``
    (:func:`dmc_settings`). Returns the run's summary, also written to ``out/curve.json``: ``config``, ``curve``,
    ``best``, ``env_steps``, ``train_wall_s``, ``wall_s``, ``model`` (``best/``), ``final_model``, ``resumed_from``
    and ``reused`` (True when a finished run of the same config was found and returned).

    ``on_point`` sees each validation point; ``progress`` shows SB3's progress bar."""
    name = _algo(algo)
    full = dmc_env_id(env_id)
    if not isinstance(steps, (int, np.integer)) or isinstance(steps, bool) or steps < 1:
        raise ValueError(f"steps must be a positive integer number of environment steps, got {steps!r}")
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    resolved = dmc_settings(name, full, settings)
    resolved["n_timesteps"] = int(steps)
    config = _config(name, full, int(seed), int(steps), resolved)
    out = Path(out)
    finished = _same(out / "curve.json", config)
    if finished is not None and (out / "best" / "model.zip").is_file():
        return {**finished, "reused": True}

    import stable_baselines3
    import torch
    from stable_baselines3.common.callbacks import BaseCallback

    torch.set_num_threads(1)  # small batches: one thread per run, runs side by side on a multi-core machine
    out.mkdir(parents=True, exist_ok=True)
    checkpoint = out / "checkpoint"
    partial = _same(checkpoint / "state.json", config) if (checkpoint / "model.zip").is_file() else None
    venv = _training_env(full, int(seed), resolved)
    cls = getattr(stable_baselines3, name.upper())
    if partial is None:
        for stale in ("best", "final", "checkpoint", "curve.json"):
            target = out / stale
            if target.is_dir():
                shutil.rmtree(target)
            else:
                target.unlink(missing_ok=True)
        model = cls(
            resolved.get("policy", "MlpPolicy"), venv, seed=int(seed), device="cpu", verbose=0,
            **_constructor_kwargs(resolved),
        )  # fmt: skip
        state: dict[str, Any] = {"curve": [], "best": None, "train_wall_s": 0.0, "wall_s": 0.0}
    else:
        if resolved.get("normalize"):
            from stable_baselines3.common.vec_env import VecNormalize

            venv = VecNormalize.load(str(checkpoint / "vecnormalize.pkl"), venv.venv)
            venv.training = True
        model = cls.load(checkpoint / "model.zip", env=venv, device="cpu")
        if name == "sac" and (checkpoint / "replay_buffer.pkl").is_file():
            model.load_replay_buffer(checkpoint / "replay_buffer.pkl")
        model.set_random_seed(int(seed) + int(model.num_timesteps))  # a fresh, reproducible stream from here
        state = {k: partial[k] for k in ("curve", "best", "train_wall_s", "wall_s")}
    resumed_from = int(model.num_timesteps) if partial is not None else None
    normalizer = venv if resolved.get("normalize") else None
    meta = {"algo": name, "env_id": full, "seed": int(seed), "settings": resolved}
    val_seeds = validation_seeds(resolved)
    val_env = make_dmc_env(full)
    clock = {"since": time.perf_counter(), "wall0": time.perf_counter() - float(state["wall_s"])}

    def point(final: bool) -> None:
        state["train_wall_s"] += time.perf_counter() - clock["since"]
        live = SB3DMCController(model, normalizer, name=f"{name}-live")
        scores = [run_dmc_episode(full, live, s, env=val_env).score for s in val_seeds]
        row: dict[str, Any] = {
            "env_steps": int(model.num_timesteps),
            "train_wall_s": round(float(state["train_wall_s"]), 2),
            "scores": [round(s, 3) for s in scores],
            "mean": round(float(np.mean(scores)), 3),
        }
        if state["best"] is None or row["mean"] > state["best"]["mean"]:
            _save_policy(model, normalizer, out / "best", {**meta, "point": row})
            state["best"] = row
        state["curve"].append(row)
        state["wall_s"] = time.perf_counter() - clock["wall0"]
        if not final:
            _checkpoint()
        if on_point is not None:
            on_point(row)
        clock["since"] = time.perf_counter()

    def _checkpoint() -> None:
        tmp = out / "checkpoint.tmp"
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir()
        model.save(tmp / "model.zip")
        if normalizer is not None:
            normalizer.save(str(tmp / "vecnormalize.pkl"))
        if name == "sac":
            model.save_replay_buffer(tmp / "replay_buffer.pkl")
        atomic_write_json(tmp / "state.json", {"config": config, **state}, indent=1)
        shutil.rmtree(checkpoint, ignore_errors=True)
        tmp.rename(checkpoint)

    every = int(resolved["eval_every"])

    class Validation(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.next_point = (int(model.num_timesteps) // every + 1) * every

        def _on_step(self) -> bool:
            if self.next_point <= self.num_timesteps < steps:
                point(final=False)
                self.next_point += every
            return True

    quiet_logger(model)
    try:
        if int(model.num_timesteps) < steps:
            model.learn(
                total_timesteps=steps - int(model.num_timesteps),
                callback=Validation(),
                progress_bar=progress,
                reset_num_timesteps=partial is None,
            )
        point(final=True)
    finally:
        val_env.close()
    _save_policy(model, normalizer, out / "final", {**meta, "point": state["curve"][-1]})
    summary = {
        "config": config,
        "curve": state["curve"],
        "best": state["best"],
        "env_steps": int(model.num_timesteps),
        "train_wall_s": round(float(state["train_wall_s"]), 2),
        "wall_s": round(float(state["wall_s"]), 2),
        "steps_per_s": round(int(model.num_timesteps) / max(float(state["train_wall_s"]), 1e-9), 2),
        "model": str(out / "best"),
        "final_model": str(out / "final"),
        "resumed_from": resumed_from,
        "reused": False,
    }
    atomic_write_json(out / "curve.json", summary, indent=1)
    shutil.rmtree(checkpoint, ignore_errors=True)
    return summary


def measure_throughput(algo: str, env_id: str, seconds: float, seed: int = 0) -> dict[str, Any]:
    """Train ``algo`` with its full settings in ``env_id`` for about ``seconds`` of wall time (no validation, nothing
    saved) and return the environment steps per second: ``steps_per_s`` over the whole time and
    ``learning_steps_per_s`` from the first gradient step on (SAC's ``learning_starts`` random steps excluded;
    for PPO the whole run), with ``env_steps``, ``wall_s``, ``random_wall_s`` (the time before the first gradient
    step), ``torch_threads``."""
    name = _algo(algo)
    full = dmc_env_id(env_id)
    if not seconds > 0:
        raise ValueError(f"seconds must be positive, got {seconds!r}")
    import stable_baselines3
    import torch
    from stable_baselines3.common.callbacks import BaseCallback

    torch.set_num_threads(1)
    resolved = dmc_settings(name, full)
    venv = _training_env(full, int(seed), resolved)
    cls = getattr(stable_baselines3, name.upper())
    model = cls(resolved.get("policy", "MlpPolicy"), venv, seed=int(seed), device="cpu", verbose=0,
                **_constructor_kwargs(resolved))  # fmt: skip
    starts = int(resolved.get("learning_starts", 0))
    marks: dict[str, float] = {"t0": time.perf_counter()}

    class Stop(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps == starts + 1 and "learn0" not in marks:
                marks["learn0"] = time.perf_counter()
            return time.perf_counter() - marks["t0"] < seconds

    quiet_logger(model)
    model.learn(total_timesteps=int(resolved["n_timesteps"]), callback=Stop())
    wall = time.perf_counter() - marks["t0"]
    steps = int(model.num_timesteps)
    learn0 = marks.get("learn0", marks["t0"]) if starts else marks["t0"]
    learning = (steps - starts) / (time.perf_counter() - learn0) if steps > starts else float("nan")
    venv.close()
    return {
        "algo": name,
        "env_id": full,
        "env_steps": steps,
        "wall_s": round(wall, 2),
        "steps_per_s": round(steps / wall, 2),
        "learning_steps_per_s": round(learning, 2),
        "learning_starts": starts,
        "random_wall_s": round(learn0 - marks["t0"], 2),
        "torch_threads": torch.get_num_threads(),
    }
