"""The published DeepMind Control Suite scores (``benchmarks/results/dmc_published.json``): the file's format, a
source for every number, the readers and the budget rule of ``benchmarks/dmc_published.py`` that rebuild it (on small
inputs in each source's released format; the real rebuild needs clones of five repositories), and the entries read
off published tables, which the rebuild keeps as stored."""

from __future__ import annotations

import copy
import gzip
import importlib.util
import json
import re
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _load_script() -> ModuleType:
    """``benchmarks/`` is not a package: load the script as a module (registered first, as its dataclass needs)."""
    name = "benchmarks_dmc_published"
    spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / "dmc_published.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


dp = _load_script()


@pytest.fixture(scope="module")
def published() -> dict[str, Any]:
    data: dict[str, Any] = json.loads(dp.JSON_PATH.read_text())
    return data


def test_the_file_is_valid(published: dict[str, Any]) -> None:
    assert dp.validate(published) == []


def test_every_entry_names_its_source_and_how_it_was_computed(published: dict[str, Any]) -> None:
    for e in published["scores"]:
        assert e["source"].strip() and e["url"].startswith("https://github.com/"), e
        assert e["note"].startswith("Mean over"), e
        if e["from"] == "released per-seed results":
            repo = e["source"].split("@")[0]
            commit = dp.SOURCES[repo]
            assert e["source"].startswith(f"{repo}@{commit[:7]} ") and f"/blob/{commit}/" in e["url"], e
        else:
            assert e["from"] in dp.TABLE_FROM and e["per_seed"] is None, e
            assert "table" in e["source"] and re.search(r"/blob/[0-9a-f]{40}/.*#L\d+$", e["url"]), e


def test_the_file_is_what_the_specs_describe(published: dict[str, Any]) -> None:
    stored = {(e["task"], e["method"], e["env_steps"], e["observations"], e["url"]) for e in published["scores"]}
    specs = set()
    for s in dp.SPECS:
        url = f"https://github.com/{s.repo}/blob/{dp.SOURCES[s.repo]}/{s.path}"
        specs.add((s.task, s.method, s.env_steps, s.observations, url))
    for t in dp.TABLE_ENTRIES:
        specs.add((t.task, t.method, t.env_steps, t.observations, t.url))
    assert stored == specs
    assert len(published["scores"]) == len(dp.SPECS) + len(dp.TABLE_ENTRIES)


def test_the_table_entries_are_stored_as_their_tables_print_them(published: dict[str, Any]) -> None:
    stored = [e for e in published["scores"] if e["from"] in dp.TABLE_FROM]
    assert stored == [dp.table_entry(t) for t in dp.TABLE_ENTRIES]
    assert dp.validate({"scores": stored, "retrieved": published["retrieved"]}) == []
    cleanrl = {(e["task"], e["method"]): e for e in stored if e["source"].startswith("vwxyzjn/cleanrl@")}
    assert {t for t, _ in cleanrl} == set(dp.TASKS) and {m for _, m in cleanrl} == {"PPO", "RPO"}
    for e in cleanrl.values():
        assert e["seeds"] == 10 and e["env_steps"] == 8_000_000 and e["observations"] == "state", e
        assert f"({e['score']:.2f} ± " in e["note"] and "standard deviation" in e["note"], e
    assert cleanrl["cartpole-swingup", "PPO"]["score"] == 590.21
    assert cleanrl["pendulum-swingup", "RPO"]["score"] == 774.30


def test_every_task_has_scores_and_the_acrobot_has_them_at_one_million_steps(published: dict[str, Any]) -> None:
    tasks = {e["task"] for e in published["scores"]}
    assert tasks == set(dp.TASKS)
    at_1m = {e["method"] for e in published["scores"] if e["task"] == "acrobot-swingup" and e["env_steps"] == 10**6}
    assert {"TD-MPC2", "MR.Q", "SimbaV2", "DrQ-v2", "DreamerV3", "SAC"} <= at_1m


def _entry() -> dict[str, Any]:
    return {
        "task": "acrobot-swingup",
        "method": "X",
        "score": 2.0,
        "seeds": 3,
        "per_seed": [1.0, 2.0, 3.0],
        "env_steps": 1000,
        "observations": "state",
        "from": "released per-seed results",
        "source": "o/n@abc results.csv",
        "url": "https://example.org/results.csv",
        "note": "Mean over 3 seeds.",
    }


@pytest.mark.parametrize(
    ("change", "complaint"),
    [
        ({"source": " "}, "no source"),
        ({"url": "results.csv"}, "url"),
        ({"score": 2.5}, "not the mean"),
        ({"seeds": 2}, "per-seed values"),
        ({"task": "acrobot-swingup-v0"}, "task not one of"),
        ({"observations": "proprio"}, "observations not one of"),
        ({"env_steps": 1e6}, "env_steps"),
        ({"score": 1200.0, "per_seed": [1200.0], "seeds": 1}, "0..1000"),
        ({"from": "paper table", "source": "Lee et al. 2025"}, "per_seed"),
        ({"from": "paper table", "per_seed": None, "source": "Lee et al. 2025, p. 3"}, "name the table"),
        ({"from": "published table", "source": "o/n@abc page x.md, results table"}, "has per_seed"),
        ({"from": "published table", "per_seed": None, "source": "o/n@abc page x.md"}, "name the table"),
        ({"from": "blog post", "per_seed": None, "source": "o/n@abc page x.md, results table"}, "from not one of"),
    ],
)
def test_the_validator_rejects_a_broken_entry(change: dict[str, Any], complaint: str) -> None:
    data = {"scores": [_entry() | change], "retrieved": "2026-12-06"}
    errors = dp.validate(data)
    assert any(complaint in error for error in errors), errors


def test_the_validator_accepts_a_paper_table_entry_and_rejects_duplicates_and_missing_keys() -> None:
    paper = _entry() | {"from": "paper table", "per_seed": None, "source": "Lee et al. 2025, Table 9"}
    docs = _entry() | {"from": "published table", "per_seed": None, "source": "o/n@abc page x.md, results table"}
    assert dp.validate({"scores": [_entry(), paper, docs], "retrieved": "2026-12-06"}) == []
    assert any("twice" in e for e in dp.validate({"scores": [_entry(), _entry()], "retrieved": "2026-12-06"}))
    broken = _entry()
    del broken["note"]
    assert any("lacks ['note']" in e for e in dp.validate({"scores": [broken], "retrieved": "2026-12-06"}))
    assert any("retrieved" in e for e in dp.validate({"scores": [_entry()], "retrieved": "December"}))


def test_the_budget_rule_takes_each_seeds_last_evaluation_at_or_below_the_budget() -> None:
    curves = {"2": {0: 1.0, 100: 5.0, 200: 9.0}, "10": {0: 0.0, 90: 7.0}, "1": {100: 3.0, 101: 100.0}}
    values, steps = dp.score_at(curves, 100)
    assert values == [3.0, 5.0, 7.0] and steps == [100, 100, 90]
    with pytest.raises(ValueError, match="seed 1"):
        dp.score_at(curves, 50)


def test_an_entry_records_its_mean_seeds_and_steps() -> None:
    csv = b"step,reward,seed\n0,1.0,1\n100000,10.0,1\n200000,30.0,1\n0,2.0,2\n100000,20.0,2\n"
    spec = dp.Spec("acrobot-swingup", "X", 200_000, "state", "nicklashansen/tdmpc2", "r.csv", dp.read_tdmpc2_csv)
    e = dp.entry(spec, csv)
    assert e["score"] == 25.0 and e["per_seed"] == [30.0, 20.0] and e["seeds"] == 2
    assert "200,000 (1 seed), 100,000 (1 seed)" in e["note"]
    assert dp.validate({"scores": [e], "retrieved": "2026-12-06"}) == []


def _table_entry(task: str, method: str, cell: str) -> Any:
    source, url = "o/n@abc page x.md, results table", "https://github.com/o/n/blob/abc/x.md#L7"
    return dp.TableEntry(task, method, cell, 10, 8_000_000, "state", source, url, "")


def test_the_rebuild_keeps_the_table_entries_after_the_rebuilt_entries_of_their_task(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    files = {
        "results/a.csv": b"step,reward,seed\n1000,10.0,1\n1000,20.0,2\n",
        "results/b.csv": b"step,reward,seed\n1000,700.0,1\n",
    }
    shown: list[tuple[Path, str, str]] = []

    def git_show(clone: Path, commit: str, path: str) -> bytes:
        shown.append((clone, commit, path))
        return files[path]

    monkeypatch.setattr(dp, "git_show", git_show)
    repo = "nicklashansen/tdmpc2"
    specs = (
        dp.Spec("acrobot-swingup", "X", 1000, "state", repo, "results/a.csv", dp.read_tdmpc2_csv),
        dp.Spec("pendulum-swingup", "X", 1000, "state", repo, "results/b.csv", dp.read_tdmpc2_csv),
    )
    tables = (
        _table_entry("pendulum-swingup", "T", "12.50 ± 3.00"),
        _table_entry("acrobot-swingup", "T", "1.25 ± 0.50"),
        _table_entry("cartpole-swingup", "T", "600.00 ± 1.00"),
    )
    data = dp.build({repo: Path("clone")}, "2026-12-06", specs, tables)
    order = [(e["task"], e["method"], e["from"]) for e in data["scores"]]
    assert order == [
        ("acrobot-swingup", "X", "released per-seed results"),
        ("acrobot-swingup", "T", "published table"),
        ("pendulum-swingup", "X", "released per-seed results"),
        ("pendulum-swingup", "T", "published table"),
        ("cartpole-swingup", "T", "published table"),
    ]
    assert [c for _, c, _ in shown] == [dp.SOURCES[repo]] * 2
    kept = [e for e in data["scores"] if e["from"] == "published table"]
    assert sorted(kept, key=lambda e: e["score"]) == sorted(map(dp.table_entry, tables), key=lambda e: e["score"])
    acrobot = data["scores"][1]
    assert acrobot["score"] == 1.25 and acrobot["per_seed"] is None and acrobot["seeds"] == 10
    assert acrobot["url"] == "https://github.com/o/n/blob/abc/x.md#L7" and acrobot["source"].endswith("table")
    assert acrobot["note"] == "Mean over 10 seeds as the table prints it (1.25 ± 0.50)."
    assert data["scores"][0]["score"] == 15.0
    assert dp.validate(data) == []


def test_the_readers_parse_each_released_format() -> None:
    drqv2 = b",agent,task,seed,frame,episode_reward,hour\n0,DrQ-v2,acrobot_swingup,1,20000,2.5,0.1\n"
    assert dp.read_drqv2_csv(drqv2) == {"1": {20000: 2.5}}

    runs = [
        {"task": "dmc_acrobot_swingup", "method": "ppo", "seed": 0, "xs": [1000, 2000], "ys": [0.5, 1.5]},
        {"task": "dmc_cartpole_swingup", "method": "ppo", "seed": 0, "xs": [1000], "ys": [9.0]},
    ]
    scores = gzip.compress(json.dumps(runs).encode())
    assert dp.read_dreamerv3_scores(scores, "dmc_acrobot_swingup") == {"0": {1000: 0.5, 2000: 1.5}}

    mrq = (
        b"--------------------\nEnv: Dmc-visual-acrobot-swingup\nTimestep\tSeed 0\t\tSeed 1\n0\t\t9.0\t\t9.0\n"
        b"--------------------\nEnv: Dmc-acrobot-swingup\nTimestep\tSeed 0\t\tSeed 1\n0\t\t1.0\t\t2.0\n"
        b"5000\t\t3.0\t\t4.0\n"
    )
    assert dp.read_mrq_txt(mrq, "Dmc-acrobot-swingup") == {"0": {0: 1.0, 10000: 3.0}, "1": {0: 2.0, 10000: 4.0}}
    with pytest.raises(KeyError):
        dp.read_mrq_txt(mrq, "Dmc-pendulum-swingup")

    simba = (
        b",exp_name,env_name,seed,metric,env_step,value\n0,s,acrobot-swingup,1,avg_return,1000000.0,400.0\n"
        b"1,s,acrobot-swingup,1,avg_success,1000000.0,0.0\n2,s,pendulum-swingup,1,avg_return,1000000.0,800.0\n"
    )
    assert dp.read_simbav2_csv(simba, "acrobot-swingup") == {"1": {1_000_000: 400.0}}


def test_the_table_lists_every_entry(published: dict[str, Any]) -> None:
    text = dp.table(published)
    assert len(text.splitlines()) == 2 + len(published["scores"])
    assert "| acrobot-swingup | TD-MPC2 |" in text


def test_the_command_validates_and_fails_on_a_broken_file(tmp_path: Path, published: dict[str, Any]) -> None:
    assert dp.main([]) == 0
    broken = copy.deepcopy(published)
    broken["scores"][0]["source"] = ""
    path = tmp_path / "dmc_published.json"
    path.write_text(json.dumps(broken))
    assert dp.main(["--json", str(path)]) == 1
