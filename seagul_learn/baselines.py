"""Reinforcement-learning baselines: stable-baselines3 PPO and SAC on the seagul envs, set up by the book.

A run is one :class:`SB3Config` (CleanRL style); its settings come from the tuned entry of its Gymnasium id in
``seagul_learn/hyperparams/{ppo,sac}.yml`` (rl-baselines3-zoo's format, kept as data: :func:`tuned`), with the
config's ``algo_overrides`` and ``view_overrides`` over it. :func:`train_sb3` trains it:

* **The learner's view** is :func:`seagul_envs.wrappers.learner_env`: ``(cos, sin)`` of the periodic angles, the
  time to go scaled to ``[0, 1]``, actions in ``[-1, 1]``, a bounded success-aware reward and the horizon's end as
  a termination; then ``VecNormalize`` on observations only (the reward is bounded already).
* **The learning curve** is measured every ``eval_every`` environment steps on a validation set of starts drawn
  from X0 with their own stream (:func:`validation_starts`: never the evaluation grid, never the held-out starts):
  success by the task's rule, median final distance and the median miss of the rule in units of its tolerances.
* **Checkpoint selection**: the checkpoint with the highest validation success (ties: the lower median miss) is
  kept in ``best/`` (``model.zip``, ``vecnormalize.pkl``, ``view.json``); the final model in the run directory.
  A saved model runs on the raw env through :class:`seagul_learn.policies.SB3Policy`, which applies the view
  and the statistics stored beside it.

Reports judge every policy by the task's own cost and success rule, never by the learner's reward.

Imports are at module level except stable-baselines3 and torch, imported by the functions that train or load a
model: this module's settings, views and statistics are used without them (``seagul_learn.commands``, reports).
"""

from __future__ import annotations

import copy
import json
import shutil
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields, replace
from functools import partial
from pathlib import Path
from typing import Annotated, Any

import gymnasium as gym
import numpy as np
import tyro
import yaml  # type: ignore[import-untyped]
from tyro.constructors import PrimitiveConstructorSpec

import seagul_envs  # noqa: F401  (registers the envs)
from seagul_control.evaluation import run_policy_episode
from seagul_control.io import atomic_write_json
from seagul_envs.wrappers import LearnerView, RandomRobot, learner_env
from seagul_learn.commands._json import JsonObject

ALGOS = ("PPO", "SAC")

#: Seed of the RL validation starts (checkpoint selection); distinct from the held-out starts' seed.
VALIDATION_SEED = 20220214

#: Where the tuned settings live (one YAML file per algorithm, keyed by Gymnasium id).
HYPERPARAMS_DIR = Path(__file__).resolve().parent / "hyperparams"

#: Keys of a tuned entry that are not SB3 constructor arguments.
_RUN_KEYS = ("n_timesteps", "n_envs", "normalize", "eval_every", "policy", "learner_view")


def tuned(algo: str, env_id: str) -> dict[str, Any]:
    """The tuned entry of ``env_id`` in ``hyperparams/<algo>.yml`` (its ``default`` entry for an id it lacks)."""
    if algo not in ALGOS:
        raise ValueError(f"unknown algo {algo!r}; choose one of {list(ALGOS)}")
    path = HYPERPARAMS_DIR / f"{algo.lower()}.yml"
    entries = yaml.safe_load(path.read_text())
    entry = entries.get(env_id, entries.get("default"))
    if entry is None:
        raise ValueError(f"{path} has no entry for {env_id!r} and no 'default' entry")
    return copy.deepcopy(entry)


_ALGO_FLAG = PrimitiveConstructorSpec(
    nargs=1,
    metavar="{" + ",".join(ALGOS) + "}",
    instance_from_str=lambda args: args[0],
    is_instance=lambda value: isinstance(value, str),
    str_from_instance=lambda value: [value],
    choices=ALGOS,
)
"""``--algo``: one of :data:`ALGOS` (the field stays a ``str``)."""


@dataclass
class SB3Config:
    """Everything that defines an RL baseline run (the example's and the benchmark's command lines derive from it:
    :func:`config_from_args`, with tyro; the dict fields take a JSON object on the command line)."""

    algo: Annotated[str, _ALGO_FLAG] = "PPO"
    """``"PPO"`` or ``"SAC"``."""
    env_id: str = "SeagulAcrobot-v0"
    """Gymnasium id to train in (any registered seagul env); its tuned entry gives the settings."""
    total_timesteps: int = 0
    """Environment steps over all envs (0: the tuned entry's ``n_timesteps``)."""
    seed: int = 0
    """Seed of the envs, the networks and the exploration."""
    algo_overrides: JsonObject = field(default_factory=dict)
    """SB3 constructor arguments (and ``n_envs``, ``normalize``) over the tuned entry, e.g. ``{"ent_coef": 0.01}``."""
    view_overrides: JsonObject = field(default_factory=dict)
    """:class:`~seagul_envs.wrappers.LearnerView` settings over the tuned entry's ``learner_view``."""
    eval_every: int = 0
    """Environment steps between two validation points of the learning curve (0: the tuned entry's)."""
    n_validation: int = 50
    """Validation starts (checkpoint selection and the learning curve)."""
    domain_randomization: bool = False
    """Train on robots drawn from the task's box Theta, one per episode (:class:`~seagul_envs.wrappers.RandomRobot`:
    the policy does not see the robot); each validation start is then flown on its own robot from Theta
    (:func:`validation_robots`). The tuned entry is the env's own: randomisation changes the data, not the
    algorithm's settings."""
    progress: bool = False
    """Show SB3's progress bar."""

    def __post_init__(self) -> None:
        if self.algo not in ALGOS:
            raise ValueError(f"unknown algo {self.algo!r}; choose one of {list(ALGOS)}")
        for name in ("total_timesteps", "eval_every"):
            if int(getattr(self, name)) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if int(self.n_validation) < 1:
            raise ValueError(f"n_validation must be >= 1, got {self.n_validation}")
        bad = sorted(set(self.algo_overrides) & {"policy", "learner_view", "n_timesteps", "eval_every"})
        if bad:
            raise ValueError(f"algo_overrides cannot set {bad}: use view_overrides, total_timesteps or eval_every")

    def resolved(self) -> dict[str, Any]:
        """The settings actually used: the tuned entry with the overrides over it (``total_timesteps``,
        ``eval_every`` resolved; ``learner_view`` the view's settings)."""
        entry = tuned(self.algo, self.env_id)
        view = {**entry.get("learner_view", {}), **self.view_overrides}
        entry = {**entry, **self.algo_overrides, "learner_view": view}
        entry["n_timesteps"] = int(self.total_timesteps or entry["n_timesteps"])
        entry["eval_every"] = int(self.eval_every or entry["eval_every"])
        return entry

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (``config.json``)."""
        return asdict(self)


def task_of_env(env_id: str) -> Any:
    """The Task an env id simulates (its ``unwrapped.task``)."""
    env = gym.make(env_id)
    try:
        return env.unwrapped.task  # type: ignore[attr-defined]
    finally:
        env.close()


def validation_starts(task: Any, n: int = 50) -> np.ndarray:
    """``n`` starts drawn uniformly from X0 with :data:`VALIDATION_SEED`: the RL runs' checkpoint selection set,
    disjoint in its stream from the held-out starts and never the evaluation grid."""
    return np.asarray(task.sample_x0(np.random.default_rng(VALIDATION_SEED), int(n)))


def validation_robots(task: Any, n: int = 50) -> np.ndarray:
    """``n`` robots drawn uniformly from the task's box Theta with stream ``VALIDATION_SEED + 1``: the robots of the
    validation starts when a run trains over robots (``SB3Config.domain_randomization``), never the evaluation's."""
    if task.parameters is None:
        raise ValueError(f"{task.name} declares no physical parameters (Task.parameters): no robots to validate on")
    return np.asarray(task.parameters.sample(np.random.default_rng(VALIDATION_SEED + 1), int(n)))


def learner_view(env_id: str, settings: dict[str, Any]) -> Any:
    """The :class:`~seagul_envs.wrappers.LearnerView` of ``env_id`` with ``settings`` (a tuned ``learner_view``)."""
    env = gym.make(env_id)
    try:
        return LearnerView.for_env(env, **settings, extra={"env_id": env_id})
    finally:
        env.close()


class ZeroPolicy:
    """The zero-input policy (the curves' floor: what doing nothing achieves)."""

    def __init__(self, nu: int) -> None:
        self.nu = int(nu)

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None, deterministic: bool = True):
        return np.zeros(self.nu, dtype=np.float32), None


class LivePolicy:
    """A model being trained behind the predictor protocol on the raw env (view, statistics, action scaling)."""

    def __init__(self, model: Any, view: Any, venv: Any) -> None:
        self.model, self.view, self.venv = model, view, venv

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None, deterministic: bool = True):
        obs = self.view.observe(observation)
        if self.venv is not None:
            obs = self.venv.normalize_obs(obs)
        action, _ = self.model.predict(obs, deterministic=deterministic)
        return self.view.action(action), None


def episode_stats(
    task: Any, policy: Any, starts: np.ndarray, env_id: str | None = None, robots: np.ndarray | None = None
) -> dict[str, float]:
    """Success rate (the task's rule), mean return (minus the task's trajectory cost), mean and median final
    distance ``||x(T) - x*||`` and mean and median miss of the success rule (``SuccessRule.violation`` of the final
    state in units of its tolerances; 0 where it succeeds) of ``policy`` from ``starts`` (each on its robot of
    ``robots`` when given)."""
    if robots is not None and len(robots) != len(starts):
        raise ValueError(f"episode_stats: {len(robots)} robots for {len(starts)} starts")
    results = [
        run_policy_episode(task, policy, x0, index=i, env_id=env_id, robot=None if robots is None else robots[i])[0]
        for i, x0 in enumerate(starts)
    ]
    rule = task.profile.success
    misses = [float(rule.violation(task, np.asarray(r.final_state))) for r in results]
    distances = [r.final_distance for r in results]
    return {
        "success_rate": float(np.mean([r.success for r in results])),
        "mean_return": float(np.mean([-r.cost for r in results])),
        "mean_final_distance": float(np.mean(distances)),
        "median_final_distance": float(np.median(distances)),
        "mean_miss": float(np.mean(misses)),
        "median_miss": float(np.median(misses)),
    }


def _randomised_learner_env(env: gym.Env, view: Any) -> gym.Env:
    """``learner_env`` over :class:`~seagul_envs.wrappers.RandomRobot`: a robot from Theta per episode."""
    return learner_env(RandomRobot(env), view)


def training_env(config: SB3Config, view: Any) -> Any:
    """The vectorised env ``config`` trains in: ``n_envs`` seeded copies of ``env_id``, each ``Monitor``-ed (episode
    returns in the task's units), seen through ``learner_env(view)``, then ``VecNormalize`` on observations."""
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    settings = config.resolved()
    wrapper = partial(_randomised_learner_env if config.domain_randomization else learner_env, view=view)
    venv: Any = make_vec_env(
        config.env_id, n_envs=int(settings["n_envs"]), seed=config.seed, vec_env_cls=DummyVecEnv, wrapper_class=wrapper
    )
    if settings.get("normalize", True):
        venv = VecNormalize(venv, norm_obs=True, norm_reward=False, gamma=float(settings["gamma"]))
    return venv


def _make_model(config: SB3Config, venv: Any) -> Any:
    import stable_baselines3

    settings = config.resolved()
    kwargs = {k: v for k, v in settings.items() if k not in _RUN_KEYS}
    policy_kwargs = dict(kwargs.pop("policy_kwargs", {}) or {})
    if "net_arch" in policy_kwargs:
        policy_kwargs["net_arch"] = [int(w) for w in policy_kwargs["net_arch"]]
    cls = getattr(stable_baselines3, config.algo)
    return cls(
        settings.get("policy", "MlpPolicy"),
        venv,
        policy_kwargs=policy_kwargs,
        seed=config.seed,
        device="cpu",
        verbose=0,
        **kwargs,
    )


def quiet_logger(model: Any) -> None:
    """Give ``model`` a logger that writes nothing. With ``verbose=0`` and no tensorboard folder, SB3's
    ``learn()`` otherwise configures its default logger, which creates an empty ``SB3-<date>`` folder in the
    system's temporary directory on every call."""
    from stable_baselines3.common.logger import Logger

    model.set_logger(Logger(folder=None, output_formats=[]))


def _better(row: dict[str, Any], best: dict[str, Any] | None) -> bool:
    """Whether a curve point beats the best so far: higher validation success, ties by the lower median miss."""
    if best is None:
        return True
    if row["success_rate"] != best["success_rate"]:
        return bool(row["success_rate"] > best["success_rate"])
    return bool(row["median_miss"] < best["median_miss"])


def save_policy(model: Any, venv: Any, view: Any, out: Path) -> None:
    """``model.zip``, ``vecnormalize.pkl`` (if any) and ``view.json`` into ``out``: what
    :class:`seagul_learn.policies.SB3Policy` loads."""
    out.mkdir(parents=True, exist_ok=True)
    model.save(out / "model.zip")
    if venv is not None:
        venv.save(str(out / "vecnormalize.pkl"))
    view.save(out / "view.json")


def train_sb3(
    config: SB3Config,
    out: str | Path,
    on_point: Callable[[dict[str, Any]], None] | None = None,
) -> dict[str, Any]:
    """Train ``config`` into ``out``; returns the run's summary (also ``curve.json``).

    Every ``eval_every`` environment steps a point of the learning curve is measured on the validation starts
    (``env_steps``, ``wall_s`` of training so far, ``success_rate``, ``median_final_distance``, ``median_miss``,
    ``mean_return``); a point that beats the best so far (:func:`_better`) saves the model into ``out/best``.
    ``on_point`` sees each point; ``curve.partial.json`` holds the points so far until the run completes. The
    summary's ``best`` is the selected point and ``model`` the selected model's path.

    **Extending a run.** When ``out`` holds a completed run of the same config with a smaller ``total_timesteps``
    (:func:`extendable_run`), training continues from its final model and normalisation statistics up to the new
    budget (the curve, the best point and the training time carry over; the learning rate is constant in the tuned
    entries, so the extension is the same schedule); otherwise a run already in ``out`` is replaced. An off-policy
    run (SAC) also continues from its replay buffer, saved at the end of every such run (``replay_buffer.pkl``): a
    run without one is refused rather than extended from an empty buffer, which would learn on its first few
    transitions.
    """
    import torch
    from stable_baselines3.common.callbacks import BaseCallback

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(1)  # small networks: one thread is fastest and keeps runs machine-independent
    task = task_of_env(config.env_id)
    settings = config.resolved()
    view = learner_view(config.env_id, settings["learner_view"])
    venv = training_env(config, view)
    previous = extendable_run(config, out)
    if previous is not None and _off_policy(config.algo) and not (out / REPLAY_BUFFER).is_file():
        raise ValueError(
            f"{out}: the completed {config.algo} run has no {REPLAY_BUFFER} (it was trained before runs saved "
            "their replay buffer), so extending it would restart learning from an empty buffer; train the "
            f"{config.total_timesteps:,} steps in another directory"
        )
    model = _make_model(config, venv) if previous is None else _load_model(config, venv, out)
    if previous is not None:
        venv = model.get_env()
    normalizer = venv if settings.get("normalize", True) else None
    starts = validation_starts(task, config.n_validation)
    robots = validation_robots(task, config.n_validation) if config.domain_randomization else None
    live = LivePolicy(model, view, normalizer)
    curve: list[dict[str, Any]] = [] if previous is None else list(previous["curve"])
    state: dict[str, Any] = {
        "train": 0.0 if previous is None else float(previous["train_wall_s"]),
        "since": time.perf_counter(),
        "best": None if previous is None else previous["best"],
    }
    # New best checkpoints go to best.partial/ and replace best/ only when the run completes, so an interrupted
    # extension leaves the stored run (curve.json, best/, model.zip) exactly as it was.
    candidate = out / "best.partial"
    shutil.rmtree(candidate, ignore_errors=True)
    _write_json(out / "config.json", {"config": config.to_dict(), "resolved": settings})

    def point() -> None:
        state["train"] += time.perf_counter() - state["since"]
        row: dict[str, Any] = {"env_steps": int(model.num_timesteps), "wall_s": round(state["train"], 1)}
        row.update(episode_stats(task, live, starts, robots=robots))
        if _better(row, state["best"]):
            save_policy(model, normalizer, view, candidate)
            state["best"] = row
        curve.append(row)
        _write_json(out / "curve.partial.json", {"config": config.to_dict(), "complete": False, "curve": curve})
        if on_point is not None:
            on_point(row)
        state["since"] = time.perf_counter()

    class Curve(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            every = int(settings["eval_every"])
            self.next_point = (int(model.num_timesteps) // every + 1) * every  # past the extended run's last point

        def _on_step(self) -> bool:
            # The last point is taken after learn() returns: PPO still updates on the rollout that ends there.
            if self.next_point <= self.num_timesteps < total:
                point()
                self.next_point += int(settings["eval_every"])
            return True

    total = int(settings["n_timesteps"])
    if previous is not None:
        model.set_random_seed(config.seed + int(model.num_timesteps))  # a fresh, reproducible stream per extension
    quiet_logger(model)
    model.learn(
        total_timesteps=total - int(model.num_timesteps),
        callback=Curve(),
        progress_bar=config.progress,
        reset_num_timesteps=previous is None,
    )
    point()
    save_policy(model, normalizer, view, out)
    if _off_policy(config.algo):  # what an extension continues from (train_sb3's docstring)
        model.save_replay_buffer(out / REPLAY_BUFFER)
    if candidate.is_dir():
        shutil.rmtree(out / "best", ignore_errors=True)
        candidate.rename(out / "best")
    summary = {
        "config": config.to_dict(),
        "resolved": settings,
        "view": view.to_dict(),
        "env_steps": int(model.num_timesteps),
        "train_wall_s": curve[-1]["wall_s"],
        "curve": curve,
        "best": state["best"],
        "model": str(out / "best" / "model.zip"),
        "final_model": str(out / "model.zip"),
        "extended_from": None if previous is None else int(previous["env_steps"]),
    }
    _write_json(out / "curve.json", summary)
    (out / "curve.partial.json").unlink(missing_ok=True)
    return summary


def extendable_run(config: SB3Config, out: str | Path) -> dict[str, Any] | None:
    """The completed run in ``out`` that ``config`` extends (its ``curve.json`` summary), or ``None``.

    A run is extendable when its config equals ``config`` in every field but ``total_timesteps`` and ``progress``,
    it stopped below ``config.total_timesteps``, and its final ``model.zip`` is there.
    """
    out = Path(out)
    path = out / "curve.json"
    if not (path.is_file() and (out / "model.zip").is_file()):
        return None
    stored = json.loads(path.read_text())
    mine = {k: v for k, v in config.to_dict().items() if k not in ("total_timesteps", "progress")}
    theirs = {k: v for k, v in stored.get("config", {}).items() if k not in ("total_timesteps", "progress")}
    theirs.setdefault("domain_randomization", False)  # runs stored before the field existed
    if mine != theirs or int(stored.get("env_steps", 0)) >= int(config.resolved()["n_timesteps"]):
        return None
    return dict(stored)


REPLAY_BUFFER = "replay_buffer.pkl"
"""An off-policy run's replay buffer at its end, beside its final ``model.zip`` (SB3's ``save_replay_buffer``)."""


def _off_policy(algo: str) -> bool:
    import stable_baselines3
    from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

    return issubclass(getattr(stable_baselines3, algo), OffPolicyAlgorithm)


def _load_model(config: SB3Config, venv: Any, out: Path) -> Any:
    """The final model of the run in ``out`` on ``venv`` (its ``VecNormalize`` statistics and, off-policy, its
    replay buffer restored)."""
    import stable_baselines3
    from stable_baselines3.common.vec_env import VecNormalize

    if isinstance(venv, VecNormalize):
        venv = VecNormalize.load(str(out / "vecnormalize.pkl"), venv.venv)
        venv.training = True
    cls = getattr(stable_baselines3, config.algo)
    model = cls.load(out / "model.zip", env=venv, device="cpu")
    if _off_policy(config.algo):
        model.load_replay_buffer(out / REPLAY_BUFFER)
    return model


def _write_json(path: Path, payload: Any) -> None:
    atomic_write_json(path, payload, indent=1)


@dataclass
class SB3Run(SB3Config):
    """An SB3 baseline run from the command line: the :class:`SB3Config` fields, where to write it, and a CI switch."""

    out: Annotated[Path | None, tyro.conf.arg(metavar="DIR")] = None
    """Run directory (default: ``runs/<algo>_<env id>``)."""
    test: bool = False
    """A seconds-long run (CI smoke test): :func:`smoke_config` of the config."""


def config_from_args(argv: list[str] | None = None, description: str = "") -> tuple[SB3Config, Path]:
    """``(config, out)`` from the command line (``argv``; default ``sys.argv[1:]``): tyro derives one ``--flag``
    per :class:`SB3Config` field (``--env-id``, ``--total-timesteps``, ...; help from the field docstrings; the dict
    fields take a JSON object, ``--algo-overrides '{"ent_coef": 0.01}'``), plus ``--out DIR`` and ``--test`` (a
    seconds-long run for CI: :func:`smoke_config`).

    Raises:
        SystemExit: a bad flag or value (status 2: tyro's message naming it, :class:`SB3Config`'s checks included)
            or ``--help`` (status 0).
    """
    command = tyro.cli(SB3Run, args=argv, description=description or "Train an SB3 baseline on a seagul env.")
    config = SB3Config(**{f.name: getattr(command, f.name) for f in fields(SB3Config)})
    if command.test:
        config = smoke_config(config)
    out = command.out or Path("runs") / f"{config.algo.lower()}_{config.env_id}"
    return config, out


def smoke_config(config: SB3Config) -> SB3Config:
    """``config`` shrunk to a seconds-long run (CI): tiny budget and networks, 4 validation starts."""
    small: dict[str, Any] = (
        {"n_steps": 64, "batch_size": 32, "n_epochs": 1, "n_envs": 2}
        if config.algo == "PPO"
        else {"learning_starts": 64, "batch_size": 32, "buffer_size": 1000}
    )
    small["policy_kwargs"] = {"net_arch": [16]}
    return replace(
        config,
        total_timesteps=256,
        eval_every=128,
        n_validation=4,
        algo_overrides={**config.algo_overrides, **small},
    )
