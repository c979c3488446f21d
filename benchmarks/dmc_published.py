"""Published DeepMind Control Suite scores on the swing-ups, each with its source, budget and seeds.

``benchmarks/results/dmc_published.json`` holds the numbers printed beside seagul's own (``dmc.json``) on the
results page. Each entry of ``SPECS`` is computed from the per-seed evaluation curves that the authors released in
their repositories, read at a pinned commit (``SOURCES``), so every such number can be recomputed (the entries read
off a published table, ``TABLE_ENTRIES``, are described below):

    python benchmarks/dmc_published.py                  # validate the JSON and print its table
    python benchmarks/dmc_published.py --rebuild \\
        --clone nicklashansen/tdmpc2=~/src/tdmpc2 --clone facebookresearch/drqv2=~/src/drqv2 \\
        --clone danijar/dreamerv3=~/src/dreamerv3 --clone facebookresearch/MRQ=~/src/MRQ \\
        --clone dojeon-ai/SimbaV2=~/src/SimbaV2 --write

``--rebuild`` reads each file with ``git -C <clone> show <commit>:<path>`` (any clone or bare mirror holding the
pinned commit will do), recomputes every entry and prints where it differs from the stored file; ``--write`` stores
the rebuilt file.

How a score is computed: for each seed, the evaluation logged at the largest step at or below the budget (the
curves are logged every 5,000-100,000 steps; the note of each entry lists the steps used), then the mean over
seeds. ``env_steps`` counts dm_control control steps (1,000 per episode, the reward summed over them is the score,
0 to 1000), i.e. the agent's decisions times its action repeat: every source here uses action repeat 2, and the
curves are stored in control steps except MR.Q's, whose ``Timestep`` column counts decisions and is doubled here
(the SimbaV2 repository's copy of the same MR.Q runs, ``results/baseline/mrq.csv``, stores the doubled step).
A single evaluation is noisy (the SAC acrobot curve moves between 14 and 78 from one 100,000-step checkpoint to
the next), so scores that differ by less than the spread of ``per_seed`` should not be ranked.

Entries whose number exists only in a published table (no per-seed data released) are stored as the table prints
them (``TABLE_ENTRIES``): ``per_seed`` null, a source naming the table and a url pinned to the commit read.
``"from": "paper table"`` marks a table printed in a paper, ``"from": "published table"`` one printed in a
repository's documentation (CleanRL's PPO and RPO results on dm_control, the table of its RPO page
``rl-algorithms/rpo.md``); both follow the same rules. ``--rebuild`` keeps these entries as they are, each after
the rebuilt entries of its task.
"""

from __future__ import annotations

import argparse
import csv
import datetime
import gzip
import io
import json
import math
import re
import subprocess
import sys
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

RESULTS = Path(__file__).resolve().parent / "results"
JSON_PATH = RESULTS / "dmc_published.json"

#: The suite's swing-up tasks as dm_control names them (``domain-task``), the tasks of ``dmc.json``.
TASKS = ("pendulum-swingup", "cartpole-swingup", "cartpole-swingup_sparse", "acrobot-swingup")
OBSERVATIONS = ("state", "pixels")
FROM = ("released per-seed results", "paper table", "published table")
#: The kinds of ``from`` whose number is read off a printed table: ``per_seed`` null, a source naming the table.
TABLE_FROM = ("paper table", "published table")
ENTRY_KEYS = (
    "task",
    "method",
    "score",
    "seeds",
    "per_seed",
    "env_steps",
    "observations",
    "from",
    "source",
    "url",
    "note",
)

#: The repositories read and the commit each was read at (the newest snapshot on 2026-12-06).
SOURCES = {
    "nicklashansen/tdmpc2": "e9f59321933cbc8e11a002b842adc7d4ffae8ff1",
    "facebookresearch/drqv2": "c0c650b76c6e5d22a7eb5f2edffd1440fe94f8ef",
    "danijar/dreamerv3": "e3f02248693a79dc8b0ebd62c93683888ddaccfe",
    "facebookresearch/MRQ": "8a44a7d4b1cf117e5da4bf8214d35b02aa68d68b",
    "dojeon-ai/SimbaV2": "14fafb27e6f78f0b65d19b8873b4433547a2193c",
}

Curves = dict[str, dict[int, float]]
"""Per seed (as the source names it), the evaluation score at each logged environment step."""


# --- readers: one per released format, each returning Curves --------------------------------------------------


def read_tdmpc2_csv(data: bytes) -> Curves:
    """nicklashansen/tdmpc2 ``results/<method>/<task>.csv``: columns ``step,reward,seed``, the mean return of the
    evaluation episodes at each step. The steps are environment steps: action repeat 2 is applied to the trainer's
    counter before the files are written (the author's answer in https://github.com/nicklashansen/tdmpc2/issues/45)."""
    curves: Curves = {}
    for row in csv.DictReader(io.StringIO(data.decode())):
        curves.setdefault(row["seed"], {})[int(float(row["step"]))] = float(row["reward"])
    return curves


def read_drqv2_csv(data: bytes) -> Curves:
    """facebookresearch/drqv2 ``curves/dmc_<task>.csv``: columns ``agent,task,seed,frame,episode_reward,hour``,
    ``frame`` being environment steps (the agent's steps times action repeat 2)."""
    curves: Curves = {}
    for row in csv.DictReader(io.StringIO(data.decode())):
        curves.setdefault(row["seed"], {})[int(row["frame"])] = float(row["episode_reward"])
    return curves


def read_dreamerv3_scores(data: bytes, task: str) -> Curves:
    """danijar/dreamerv3 ``scores/<suite>-<method>.json.gz``: a list of runs ``{task, method, seed, xs, ys}`` with
    ``task`` as ``dmc_<domain>_<task>`` and ``xs`` in environment steps."""
    curves: Curves = {}
    for run in json.loads(gzip.decompress(data)):
        if run["task"] == task:
            curves[str(run["seed"])] = {int(x): float(y) for x, y in zip(run["xs"], run["ys"], strict=True)}
    return curves


def read_mrq_txt(data: bytes, env: str, action_repeat: int = 2) -> Curves:
    """facebookresearch/MRQ ``results/dmc_results.txt``: blocks separated by dashes, each ``Env: <name>``, a header
    ``Timestep Seed 0 ... Seed 9`` and one row per evaluation. ``Timestep`` counts the agent's decisions (MR.Q's DMC
    wrapper repeats each action twice, 500,000 decisions by default), so it is multiplied by ``action_repeat``."""
    for block in data.decode().split("--------------------"):
        lines = [line for line in block.strip().splitlines() if line.strip()]
        if not lines or lines[0].split(":", 1)[-1].strip() != env:
            continue
        seeds = re.findall(r"Seed (\d+)", lines[1])
        curves: Curves = {s: {} for s in seeds}
        for line in lines[2:]:
            step, *values = line.split()
            for seed, value in zip(seeds, values, strict=True):
                curves[seed][int(step) * action_repeat] = float(value)
        return curves
    raise KeyError(f"no block 'Env: {env}'")


def read_simbav2_csv(data: bytes, env: str) -> Curves:
    """dojeon-ai/SimbaV2 ``results/**.csv``: columns ``exp_name,env_name,seed,metric,env_step,value``; the rows with
    ``metric == "avg_return"`` are the mean return of the evaluation episodes, ``env_step`` in environment steps."""
    curves: Curves = {}
    for row in csv.DictReader(io.StringIO(data.decode())):
        if row["env_name"] == env and row["metric"] == "avg_return":
            curves.setdefault(row["seed"], {})[int(float(row["env_step"]))] = float(row["value"])
    return curves


# --- the entries ------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Spec:
    """One published score: where its per-seed curves are and how to read them."""

    task: str
    method: str
    env_steps: int
    observations: str
    repo: str
    path: str
    read: Callable[[bytes], Curves]
    note: str = ""


def _tdmpc2(task: str, method: str, folder: str, env_steps: int, note: str = "") -> Spec:
    dashed = task.replace("_", "-")
    return Spec(
        task,
        method,
        env_steps,
        "state",
        "nicklashansen/tdmpc2",
        f"results/{folder}/{dashed}.csv",
        read_tdmpc2_csv,
        note,
    )


def _drqv2(task: str, env_steps: int, note: str = "") -> Spec:
    path = f"curves/dmc_{task.replace('-', '_')}.csv"
    return Spec(task, "DrQ-v2", env_steps, "pixels", "facebookresearch/drqv2", path, read_drqv2_csv, note)


def _dreamerv3_scores(task: str, method: str, file: str, env_steps: int, note: str = "") -> Spec:
    key = "dmc_" + task.replace("-", "_")
    observations = "pixels" if "vision" in file else "state"

    def read(data: bytes) -> Curves:
        return read_dreamerv3_scores(data, key)

    return Spec(task, method, env_steps, observations, "danijar/dreamerv3", f"scores/{file}.json.gz", read, note)


def _mrq(task: str, env_steps: int, note: str = "") -> Spec:
    def read(data: bytes) -> Curves:
        return read_mrq_txt(data, f"Dmc-{task}")

    return Spec(task, "MR.Q", env_steps, "state", "facebookresearch/MRQ", "results/dmc_results.txt", read, note)


def _simbav2(task: str, method: str, file: str, env_steps: int, note: str = "") -> Spec:
    def read(data: bytes) -> Curves:
        return read_simbav2_csv(data, task)

    return Spec(task, method, env_steps, "state", "dojeon-ai/SimbaV2", f"results/baseline/{file}.csv", read, note)


_TDMPC2_BASELINES = (
    "Baseline run by the TD-MPC2 authors and released with their results (Hansen, Su and Wang, 'TD-MPC2: Scalable, "
    "Robust World Models for Continuous Control', ICLR 2024)."
)
_SIMBAV2 = (
    "SimbaV2 at update-to-data ratio 2, the repository's default configuration (Lee et al., 'Hyperspherical "
    "Normalization for Scalable Deep Reinforcement Learning', arXiv:2502.15280, 2025); 1,000,000 steps is its whole "
    "DMC run."
)
_MRQ = (
    "Fujimoto et al., 'Towards General-Purpose Model-Free Reinforcement Learning', ICLR 2025: the "
    "final evaluation of the 500,000-decision run, 1,000,000 environment steps at action repeat 2. The SimbaV2 "
    "repository's copy of these runs (results/baseline/mrq.csv) gives the same per-seed values at env_step 1,000,000."
)
_DREAMERV3_OWN = (
    "DreamerV3's own runs, from the score files released with the DreamerV3 paper (Hafner et al., 'Mastering "
    "diverse control tasks through world models', Nature 2025)."
)

SPECS: tuple[Spec, ...] = (
    # acrobot-swingup at the budgets of the published numbers
    _tdmpc2("acrobot-swingup", "TD-MPC2", "tdmpc2", 4_000_000),
    _mrq("acrobot-swingup", 1_000_000, _MRQ),
    _drqv2("acrobot-swingup", 3_000_000, "The run's last evaluation is at 2,980,000 steps."),
    _tdmpc2(
        "acrobot-swingup",
        "DreamerV3",
        "dreamerv3",
        3_000_000,
        _TDMPC2_BASELINES + " DreamerV3's own score files (danijar/dreamerv3 scores/) stop at 500,000 steps "
        "(state) and 1,000,000 (pixels), so the 3,000,000-step number is this run's.",
    ),
    _tdmpc2(
        "acrobot-swingup",
        "SAC",
        "sac",
        4_000_000,
        _TDMPC2_BASELINES + " Seed 3's log stops at 3,900,000 steps: the mean of the two seeds logged at "
        "4,000,000 alone is 71.6, which is not a 3-seed score.",
    ),
    _tdmpc2("acrobot-swingup", "TD-MPC", "tdmpc", 4_000_000, _TDMPC2_BASELINES),
    _dreamerv3_scores(
        "acrobot-swingup",
        "PPO",
        "dmc_proprio-ppo_fixhp",
        500_000,
        "The DreamerV3 authors' PPO baseline ('ppo_fixhp': one fixed set of hyperparameters for every domain; "
        "Hafner et al., Nature 2025); 500,000 steps is its whole state-based DMC run.",
    ),
    # acrobot-swingup at 1,000,000 steps, the budget of the 1M-step methods
    _tdmpc2("acrobot-swingup", "TD-MPC2", "tdmpc2", 1_000_000),
    _simbav2("acrobot-swingup", "SimbaV2", "simbaV2_utd2", 1_000_000, _SIMBAV2),
    _tdmpc2("acrobot-swingup", "TD-MPC", "tdmpc", 1_000_000, _TDMPC2_BASELINES),
    _tdmpc2("acrobot-swingup", "DreamerV3", "dreamerv3", 1_000_000, _TDMPC2_BASELINES),
    _dreamerv3_scores("acrobot-swingup", "DreamerV3", "dmc_vision-dreamerv3", 1_000_000, _DREAMERV3_OWN),
    _drqv2("acrobot-swingup", 1_000_000),
    _simbav2(
        "acrobot-swingup",
        "SAC",
        "sac",
        1_000_000,
        "SAC as run for the SimbaV2 paper's baselines; a different SAC run from the TD-MPC2 authors' (10.4 at "
        "the same budget), the gap shows how much an SAC number depends on who ran it.",
    ),
    _tdmpc2("acrobot-swingup", "SAC", "sac", 1_000_000, _TDMPC2_BASELINES),
    _dreamerv3_scores(
        "acrobot-swingup",
        "PPO",
        "dmc_vision-ppo_fixhp",
        1_000_000,
        "The DreamerV3 authors' PPO baseline from pixels (the same 'ppo_fixhp' settings); 1,000,000 steps is its "
        "whole run.",
    ),
    # cartpole-swingup
    _tdmpc2("cartpole-swingup", "TD-MPC", "tdmpc", 4_000_000, _TDMPC2_BASELINES),
    _simbav2("cartpole-swingup", "SimbaV2", "simbaV2_utd2", 1_000_000, _SIMBAV2),
    _tdmpc2("cartpole-swingup", "TD-MPC2", "tdmpc2", 500_000),
    # cartpole-swingup_sparse
    _tdmpc2("cartpole-swingup_sparse", "TD-MPC2", "tdmpc2", 4_000_000, "Seed 3's log stops at 3,900,000 steps."),
    _simbav2(
        "cartpole-swingup_sparse",
        "SimbaV2",
        "simbaV2_utd2",
        1_000_000,
        _SIMBAV2 + " The unrounded mean is 848.8 (849 to the unit).",
    ),
    # pendulum-swingup
    _tdmpc2("pendulum-swingup", "TD-MPC2", "tdmpc2", 500_000, "At 4,000,000 steps the same runs score 838.0."),
    _drqv2("pendulum-swingup", 500_000, "At the runs' last evaluation (980,000 steps) the same seeds score 838.5."),
    _simbav2("pendulum-swingup", "SimbaV2", "simbaV2_utd2", 1_000_000, _SIMBAV2),
)


@dataclass(frozen=True)
class TableEntry:
    """One published score that exists only as a printed table cell (no per-seed data released), stored as printed.

    ``cell`` is the cell verbatim (``"590.21 ± 16.72"``): the score is the number before the ``±``, the whole cell goes
    into the note. ``source`` names the document and the table (and column), ``url`` the cell's line at the commit
    read; ``kind`` is the entry's ``from``."""

    task: str
    method: str
    cell: str
    seeds: int
    env_steps: int
    observations: str
    source: str
    url: str
    note: str
    kind: str = "published table"

    @property
    def score(self) -> float:
        return float(self.cell.split("±")[0])


#: vwxyzjn/cleanrl read at its newest snapshot on 2026-12-06; the dm_control table of its RPO page
#: (``rl-algorithms/rpo.md`` in the documentation folder) is unchanged since it was added with RPO (commit
#: a90742a627a678282df4318d647308d60a4bb798, 2023-01-04).
CLEANRL = ("vwxyzjn/cleanrl", "fe8d8a03c41a7ef5b523e2e354bd01c363e786bb")
_CLEANRL_RPO_PAGE = f"https://github.com/{CLEANRL[0]}/blob/{CLEANRL[1]}/docs/rl-algorithms/rpo.md"

_CLEANRL_HOW = (
    "The cell is the mean over seeds of each seed's average episodic return over its last 100 training episodes "
    "(the stochastic policy while it learns, on dm_control's own reward: the episode statistics are recorded before "
    "the reward normalization), and the ± is the standard deviation of those per-seed averages (numpy's std, ddof "
    "0), as openrlbenchmark's rlops computes its result table: https://github.com/openrlbenchmark/openrlbenchmark/"
    "blob/d67da557945475e465866071765048d8ffe1aa4a/README.md (Result table) and CleanRL's contribution guide. No "
    "per-seed numbers are released beside the table. {env} through Shimmy, one environment, no "
    "action repeat, so the 8,000,000 steps are control steps (8,000 episodes of 1,000); state observations "
    "flattened, normalized by running statistics and clipped to ±10."
)
_CLEANRL_PPO = (
    _CLEANRL_HOW + " CleanRL's ppo_continuous_action.py at tag v1.0.0-13-gcbd83f6, run by benchmark/ppo.sh with "
    "--exp-name ppo_continuous_action_8M --total-timesteps 8000000, 10 seeds. CleanRL's PPO page "
    "(rl-algorithms/ppo.md) prints another run of the script under the same tag, column "
    "'ppo_continuous_action' ({other}); its budget and seeds are not printed beside it (the script's default is "
    "1,000,000 steps), so it is not listed."
)
_CLEANRL_RPO = (
    _CLEANRL_HOW + " CleanRL's rpo_continuous_action.py at tag pr-331 ('Robust Policy Optimization in Deep "
    "Reinforcement Learning', arXiv:2212.07536): PPO whose action mean is perturbed by uniform noise in "
    "[-0.5, 0.5] (rpo_alpha 0.5) for the policy update; run by benchmark/rpo.sh, the script's default 8,000,000 "
    "steps, 10 seeds."
)


def _cleanrl(task: str, method: str, cell: str, line: int, other: str = "") -> TableEntry:
    """An entry of the dm_control table of CleanRL's RPO page; ``other`` is the PPO page's cell for the same task."""
    column = "ppo_continuous_action_8M" if method == "PPO" else "rpo_continuous_action"
    note = (_CLEANRL_PPO if method == "PPO" else _CLEANRL_RPO).format(env=f"dm_control/{task}-v0", other=other)
    return TableEntry(
        task,
        method,
        cell,
        10,
        8_000_000,
        "state",
        f"{CLEANRL[0]}@{CLEANRL[1][:7]} RPO page rl-algorithms/rpo.md, dm_control results table, column {column}",
        f"{_CLEANRL_RPO_PAGE}#L{line}",
        note,
    )


TABLE_ENTRIES: tuple[TableEntry, ...] = (
    _cleanrl("acrobot-swingup", "PPO", "26.87 ± 7.93", 148, "27.84 ± 9.25"),
    _cleanrl("acrobot-swingup", "RPO", "42.97 ± 2.71", 148),
    _cleanrl("cartpole-swingup", "PPO", "590.21 ± 16.72", 153, "640.86 ± 11.44"),
    _cleanrl("cartpole-swingup", "RPO", "613.46 ± 10.91", 153),
    _cleanrl("cartpole-swingup_sparse", "PPO", "240.14 ± 299.93", 154, "51.34 ± 58.35"),
    _cleanrl("cartpole-swingup_sparse", "RPO", "525.49 ± 185.96", 154),
    _cleanrl("pendulum-swingup", "PPO", "472.19 ± 385.47", 180, "242.81 ± 245.95"),
    _cleanrl("pendulum-swingup", "RPO", "774.30 ± 21.03", 180),
)


def score_at(curves: Curves, budget: int) -> tuple[list[float], list[int]]:
    """Per seed (in the order of ``sorted(curves, key=_seed_order)``), the score logged at the largest step at or
    below ``budget`` and that step. Raises ``ValueError`` when a seed has nothing logged at or below the budget."""
    values, steps = [], []
    for seed in sorted(curves, key=_seed_order):
        below = [s for s in curves[seed] if s <= budget]
        if not below:
            raise ValueError(f"seed {seed}: no evaluation at or below {budget} steps")
        step = max(below)
        values.append(curves[seed][step])
        steps.append(step)
    return values, steps


def _seed_order(seed: str) -> tuple[int, str]:
    return (int(seed), seed) if seed.isdigit() else (sys.maxsize, seed)


def _steps_phrase(steps: Iterable[int]) -> str:
    counts: dict[int, int] = {}
    for s in steps:
        counts[s] = counts.get(s, 0) + 1
    parts = [f"{s:,} ({n} seed{'s' if n > 1 else ''})" for s, n in sorted(counts.items(), reverse=True)]
    return ", ".join(parts)


def entry(spec: Spec, data: bytes) -> dict[str, Any]:
    """The JSON entry of ``spec`` from the bytes of its file at the pinned commit."""
    curves = spec.read(data)
    if not curves:
        raise ValueError(f"{spec.repo}/{spec.path}: no curve for {spec.task}")
    values, steps = score_at(curves, spec.env_steps)
    commit = SOURCES[spec.repo]
    how = (
        f"Mean over {len(values)} seeds of the evaluation logged at the largest step at or below "
        f"{spec.env_steps:,} environment steps; steps used: {_steps_phrase(steps)}."
    )
    return {
        "task": spec.task,
        "method": spec.method,
        "score": round(sum(values) / len(values), 1),
        "seeds": len(values),
        "per_seed": [round(v, 2) for v in values],
        "env_steps": spec.env_steps,
        "observations": spec.observations,
        "from": "released per-seed results",
        "source": f"{spec.repo}@{commit[:7]} {spec.path}",
        "url": f"https://github.com/{spec.repo}/blob/{commit}/{spec.path}",
        "note": f"{how} {spec.note}".strip(),
    }


def table_entry(t: TableEntry) -> dict[str, Any]:
    """The JSON entry of ``t``, the number as its table prints it."""
    return {
        "task": t.task,
        "method": t.method,
        "score": t.score,
        "seeds": t.seeds,
        "per_seed": None,
        "env_steps": t.env_steps,
        "observations": t.observations,
        "from": t.kind,
        "source": t.source,
        "url": t.url,
        "note": f"Mean over {t.seeds} seeds as the table prints it ({t.cell}). {t.note}".strip(),
    }


def in_task_order(rebuilt: list[dict[str, Any]], fixed: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The entries grouped by task, tasks in order of first appearance: each task's rebuilt entries (in the order of
    ``SPECS``), then its table entries (in the order of ``TABLE_ENTRIES``)."""
    tasks = list(dict.fromkeys(e["task"] for e in [*rebuilt, *fixed]))
    return [e for task in tasks for group in (rebuilt, fixed) for e in group if e["task"] == task]


def git_show(clone: Path, commit: str, path: str) -> bytes:
    """The bytes of ``path`` at ``commit`` in the git repository ``clone`` (a work tree or a bare directory).

    Raises ``RuntimeError`` with git's message when the clone lacks the commit or the file (fetch the commit, or
    clone the repository again)."""
    done = subprocess.run(["git", "-C", str(clone), "show", f"{commit}:{path}"], capture_output=True)
    if done.returncode != 0:
        raise RuntimeError(f"{clone}: cannot read {path} at {commit}: {done.stderr.decode().strip()}")
    return done.stdout


def build(
    clones: Mapping[str, Path],
    retrieved: str,
    specs: Iterable[Spec] = SPECS,
    table_entries: Iterable[TableEntry] = TABLE_ENTRIES,
) -> dict[str, Any]:
    """Every entry of ``specs`` recomputed from the clones (``owner/name -> path``) at the pinned commits, and every
    entry of ``table_entries`` as stored, in the order of ``in_task_order``."""
    cache: dict[tuple[str, str], bytes] = {}
    rebuilt = []
    for spec in specs:
        key = (spec.repo, spec.path)
        if key not in cache:
            cache[key] = git_show(clones[spec.repo], SOURCES[spec.repo], spec.path)
        rebuilt.append(entry(spec, cache[key]))
    fixed = [table_entry(t) for t in table_entries]
    return {"scores": in_task_order(rebuilt, fixed), "retrieved": retrieved}


# --- validation and the table ---------------------------------------------------------------------------------


def validate(data: Mapping[str, Any]) -> list[str]:
    """Everything wrong with ``data`` (the content of ``dmc_published.json``), one sentence each; empty when valid.

    Checks: the top-level keys; ``retrieved`` an ISO date; per entry every key of ``ENTRY_KEYS`` with its type, a
    known task, observation kind and ``from``; a non-empty ``source`` and an ``https://`` ``url``; a positive
    integer budget; for released per-seed results ``len(per_seed) == seeds`` and ``score`` their mean to the
    rounding (0.06); for tables (``TABLE_FROM``) ``per_seed`` null and a source naming the table; no (task, method,
    budget, observations, source) twice (two runs of one method by different authors are two entries).
    """
    errors: list[str] = []
    if set(data) != {"scores", "retrieved"}:
        errors.append(f"top-level keys {sorted(data)} are not ['retrieved', 'scores']")
    try:
        datetime.date.fromisoformat(str(data.get("retrieved")))
    except ValueError:
        errors.append(f"retrieved {data.get('retrieved')!r} is not a YYYY-MM-DD date")
    scores = data.get("scores")
    if not isinstance(scores, list) or not scores:
        return [*errors, "scores is not a non-empty list"]
    seen: set[tuple[Any, ...]] = set()
    for i, e in enumerate(scores):
        where = f"scores[{i}] ({e.get('task')}, {e.get('method')})" if isinstance(e, dict) else f"scores[{i}]"
        if not isinstance(e, dict):
            errors.append(f"{where} is not an object")
            continue
        missing = [k for k in ENTRY_KEYS if k not in e]
        if missing:
            errors.append(f"{where} lacks {missing}")
            continue
        if e["task"] not in TASKS:
            errors.append(f"{where}: task not one of {TASKS}")
        if e["observations"] not in OBSERVATIONS:
            errors.append(f"{where}: observations not one of {OBSERVATIONS}")
        if e["from"] not in FROM:
            errors.append(f"{where}: from not one of {FROM}")
        if not isinstance(e["source"], str) or not e["source"].strip():
            errors.append(f"{where}: no source")
        if not isinstance(e["url"], str) or not e["url"].startswith("https://"):
            errors.append(f"{where}: url is not an https:// address")
        if not isinstance(e["note"], str):
            errors.append(f"{where}: note is not a string")
        if not isinstance(e["env_steps"], int) or isinstance(e["env_steps"], bool) or e["env_steps"] <= 0:
            errors.append(f"{where}: env_steps is not a positive integer")
        score = e["score"]
        if not isinstance(score, int | float) or isinstance(score, bool) or not 0 <= score <= 1000:
            errors.append(f"{where}: score is not a number in 0..1000")
            continue
        per_seed = e["per_seed"]
        if e["from"] == "released per-seed results":
            if not isinstance(per_seed, list) or not per_seed:
                errors.append(f"{where}: released per-seed results without per_seed")
            elif e["seeds"] != len(per_seed):
                errors.append(f"{where}: seeds {e['seeds']} but {len(per_seed)} per-seed values")
            elif not math.isclose(sum(per_seed) / len(per_seed), score, abs_tol=0.06):
                errors.append(f"{where}: score {score} is not the mean of per_seed ({sum(per_seed) / len(per_seed)})")
        elif e["from"] in TABLE_FROM:
            if per_seed is not None:
                errors.append(f"{where}: a {e['from']} entry has per_seed")
            if "table" not in str(e["source"]).lower():
                errors.append(f"{where}: a {e['from']} source must name the table")
        key = (e["task"], e["method"], e["env_steps"], e["observations"], e["source"])
        if key in seen:
            errors.append(f"{where}: the same task, method, budget, observations and source twice")
        seen.add(key)
    return errors


def table(data: Mapping[str, Any]) -> str:
    """The entries as a Markdown table: task, method, score (± the standard deviation over seeds when ``per_seed``
    is released; a table entry's score as its table prints it), budget, observations, seeds, source."""
    lines = ["| task | method | score | env steps | observations | seeds | source |", "|---|---|---|---|---|---|---|"]
    for e in data["scores"]:
        spread = ""
        if e["per_seed"] and len(e["per_seed"]) > 1:
            mean = sum(e["per_seed"]) / len(e["per_seed"])
            std = math.sqrt(sum((v - mean) ** 2 for v in e["per_seed"]) / (len(e["per_seed"]) - 1))
            spread = f" ± {std:.0f}"
        shown = f"{e['score']:g}" if e["per_seed"] is None else f"{e['score']:.1f}"
        lines.append(
            f"| {e['task']} | {e['method']} | {shown}{spread} | {e['env_steps']:,} | "
            f"{e['observations']} | {e['seeds'] or ''} | {e['source']} |"
        )
    return "\n".join(lines)


def _differences(old: Mapping[str, Any], new: Mapping[str, Any]) -> list[str]:
    def by_key(d: Mapping[str, Any]) -> dict[tuple[Any, ...], Mapping[str, Any]]:
        return {(e["task"], e["method"], e["env_steps"], e["observations"], e["source"]): e for e in d["scores"]}

    a, b = by_key(old), by_key(new)
    out = [f"only in the stored file: {k}" for k in a.keys() - b.keys()]
    out += [f"only in the rebuild: {k}" for k in b.keys() - a.keys()]
    for k in a.keys() & b.keys():
        changed = [f for f in ENTRY_KEYS if a[k].get(f) != b[k].get(f)]
        if changed:
            out.append(f"{k}: {', '.join(changed)} differ")
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", type=Path, default=JSON_PATH, help="the published-scores file (default: %(default)s)")
    parser.add_argument("--rebuild", action="store_true", help="recompute every entry from the source repositories")
    parser.add_argument(
        "--clone",
        action="append",
        default=[],
        metavar="OWNER/NAME=PATH",
        help="a git clone of a source repository holding its pinned commit (one per repository)",
    )
    parser.add_argument("--write", action="store_true", help="with --rebuild: store the rebuilt file")
    parser.add_argument(
        "--retrieved",
        default=datetime.datetime.now(datetime.UTC).date().isoformat(),
        help="with --rebuild: the retrieval date stored in the file (default: today, UTC)",
    )
    args = parser.parse_args(argv)
    if args.rebuild:
        clones = {}
        for item in args.clone:
            name, _, path = item.partition("=")
            clones[name] = Path(path).expanduser()
        missing = sorted(set(SOURCES) - set(clones))
        if missing:
            parser.error(f"--rebuild needs --clone for {missing}")
        try:
            data = build(clones, args.retrieved)
        except RuntimeError as error:
            parser.exit(2, f"error: {error}\n")
        if args.json.exists():
            for line in _differences(json.loads(args.json.read_text()), data):
                print(f"differs: {line}", file=sys.stderr)
        if args.write:
            args.json.write_text(json.dumps(data, indent=1, ensure_ascii=False) + "\n")
    else:
        data = json.loads(args.json.read_text())
    errors = validate(data)
    for problem in errors:
        print(f"invalid: {problem}", file=sys.stderr)
    print(table(data))
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
