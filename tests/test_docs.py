"""The manual and the record: generated results are current, the README stays a front page, every path the docs
name exists, and nothing in the repository narrates how it was developed."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import seagul_learn

ROOT = Path(__file__).resolve().parents[1]
#: The markers around README's generated results table (``BEGIN, END`` of scripts/make_results.py).
RESULTS_BEGIN, RESULTS_END = "<!-- results:begin -->", "<!-- results:end -->"


def make_results(root: Path, *args: str) -> subprocess.CompletedProcess[str]:
    """``python scripts/make_results.py ARGS`` of the tree ``root``, run as a user runs it (scripts are not
    imported by the tests)."""
    script = root / "scripts" / "make_results.py"
    return subprocess.run([sys.executable, str(script), *args], capture_output=True, text=True, timeout=300)


def tracked_files() -> list[Path]:
    try:
        out = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    return [ROOT / line for line in out.splitlines() if line]


def text_files() -> list[Path]:
    suffixes = {".py", ".md", ".toml", ".yml", ".yaml", ".sh", ".json", ".txt", ".cfg", ".xml", ".csv"}
    return [p for p in tracked_files() if p.suffix in suffixes and p.exists()]


def test_generated_results_are_current():
    """README's table, docs/results.md and the result indexes are what scripts/make_results.py makes of the JSON."""
    done = make_results(ROOT, "--check")
    assert done.returncode == 0, f"run: python scripts/make_results.py\n{done.stderr}"


def test_check_fails_when_a_generated_number_is_edited(tmp_path):
    """--check is not a tautology: in a copy of the inputs and outputs that passes, a hand-edited number in
    docs/results.md is reported (and only that file)."""
    for name in ("scripts/make_results.py", "README.md", "docs/results.md", "docs/figures/dmc/animations.json"):
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / name, tmp_path / name)
    shutil.copytree(ROOT / "scripts" / "results_docs", tmp_path / "scripts" / "results_docs")
    shutil.copytree(ROOT / "benchmarks" / "results", tmp_path / "benchmarks" / "results")
    assert make_results(tmp_path, "--check").returncode == 0  # the copy is complete
    page = tmp_path / "docs" / "results.md"
    text = page.read_text()
    assert "99.25 %" in text
    page.write_text(text.replace("99.25 %", "99.5 %", 1))
    done = make_results(tmp_path, "--check")
    assert done.returncode == 1 and done.stderr.strip().endswith(
        "out of date (run python scripts/make_results.py): docs/results.md"
    )


def test_readme_is_a_front_page():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 200
    quick = text.split("## Quick start", 1)[1].split("\n## ", 1)[0]
    block = quick.split("```bash", 1)[1].split("```", 1)[0]
    commands = [line for line in block.splitlines() if line.strip()]
    assert [c.split("#")[0].strip() for c in commands] == ["bash scripts/reproduce.sh", "bash scripts/test.sh"]
    assert RESULTS_BEGIN in text and RESULTS_END in text


def test_every_figure_the_results_page_shows_exists():
    page = (ROOT / "docs" / "results.md").read_text()
    images = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", page)
    assert images, "the results page shows no figure"
    for image in images:
        assert (ROOT / "docs" / image).is_file(), image


#: Paths the text of tracked files names: docs pages and result files.
PATH_PATTERN = re.compile(r"(?<![\w/.-])((?:docs|benchmarks/results)/[\w./+-]*\w)")


def test_every_docs_and_results_path_named_in_the_repository_exists():
    missing = []
    for path in text_files():
        if path.is_relative_to(ROOT / "benchmarks" / "results"):
            continue  # result files record where they were written by the run that made them
        for line_no, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            for match in PATH_PATTERN.finditer(line):
                name, after = match.group(1), line[match.end() : match.end() + 1]
                if after in ("<", "{", "*") or "DIR" in name:
                    continue  # a pattern such as seed<N>.json or controllers_{task}.json, not a path
                if not (ROOT / name).exists():
                    missing.append(f"{path.relative_to(ROOT)}:{line_no}: {name}")
    assert not missing, "paths that do not exist:\n" + "\n".join(missing)


ORDINALS = (
    "first|second|third|fourth|fifth|sixth|seventh|eighth|ninth|tenth|eleventh|twelfth|thirteenth|fourteenth|"
    "fifteenth|sixteenth|seventeenth|eighteenth|nineteenth|twentieth|twenty-first|twenty-second"
)
#: Narration of the development: work sessions or rounds by number, numbers of tracker items, "this" session.
NARRATION = re.compile(
    rf"\b(?:(?:{ORDINALS})(?:\s+(?:and|to)\s+(?:{ORDINALS}))?\s+sessions?|sessions?\s+\d+|"
    r"(?:this|last|next|previous|earlier)\s+(?:session|work\s+round)|work\s+rounds?|issues?\s+#?\d+)\b",
    re.IGNORECASE,
)


def test_narration_pattern_finds_what_it_must():
    session, issue = "session", "issue"  # kept apart: this file must not itself read as narration
    narrations = (
        f"the twelfth {session}'s recipe",
        f"{session}s 15-17",
        f"{issue} 12",
        f"{issue.title()} #10",
        f"this {session}",
        f"the fifteenth to seventeenth {session}s",
    )
    for text in narrations:
        assert NARRATION.search(text), text
    for text in ("10 closed-loop rounds", "the first round", "a Ray session", "first use", "session_id"):
        assert not NARRATION.search(text), text


def test_nothing_in_the_repository_narrates_its_development():
    hits = []
    for path in text_files():
        rel = path.relative_to(ROOT)
        if NARRATION.search(str(rel)):
            hits.append(f"file name: {rel}")
        for line_no, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            if NARRATION.search(line):
                hits.append(f"{rel}:{line_no}: {line.strip()[:120]}")
    assert not hits, "development narration:\n" + "\n".join(hits)


def test_changelog_follows_keep_a_changelog():
    text = (ROOT / "CHANGELOG.md").read_text()
    versions = re.findall(r"^## \[(\d+\.\d+\.\d+)\] - \d{4}-\d{2}-\d{2}$", text, re.MULTILINE)
    assert versions, "no version sections"
    assert versions[0] == seagul_learn.__version__, "the newest changelog entry is not the package version"
    for section in re.findall(r"^### (\w+)$", text, re.MULTILINE):
        assert section in {"Added", "Changed", "Deprecated", "Removed", "Fixed", "Security"}, section
