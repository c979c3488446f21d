"""`seagul reproduce`: the whole pipeline on the smoke preset, its report, and resume after SIGKILL."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from seagul_learn.cli import main
from seagul_learn.experiment import Experiment, ExperimentConfig


@pytest.fixture(scope="module")
def smoke_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    out = tmp_path_factory.mktemp("reproduce") / "run"
    import contextlib
    import io

    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        code = main(["reproduce", "acrobot", "--preset", "smoke", "--out", str(out), "--workers", "1", "--no-progress"])
    assert code == 0
    return out, stdout.getvalue()


def test_reproduce_writes_report_with_figures_and_tables(smoke_run: tuple[Path, str]) -> None:
    out, stdout = smoke_run
    report = out / "report.md"
    assert stdout.strip().splitlines()[-1] == str(report)  # the last line is the report's path
    text = report.read_text()
    for heading in ("## Summary", "## Value-function learning", "## Closed loop", "## Timings", "## Library versions"):
        assert heading in text
    for policy in ("SEAGuL MPC", "uniform MPC", "LQR", "full-horizon MPC"):
        assert f"| {policy} |" in text
    for figure in ("validation_curves.png", "closed_loop/main/heatmap.png", "closed_loop/reference/heatmap.png"):
        assert f"]({figure})" in text
        assert (out / figure).stat().st_size > 1000
    assert "data:image/png;base64," in (out / "report.html").read_text()
    learning = json.loads((out / "learning.json").read_text())
    assert len(learning["mse_initial"]["adversarial"]) == len(learning["mse_initial"]["uniform"]) == 2
    stored = json.loads((out / "experiment.json").read_text())
    assert {"validation set", "training", "closed-loop evaluation", "total"} <= set(stored["timings"])


def test_reproduce_refuses_to_overwrite_and_checks_resume_dir(smoke_run: tuple[Path, str], tmp_path: Path) -> None:
    out, _ = smoke_run
    with pytest.raises(FileExistsError, match="--resume"):
        Experiment.create(ExperimentConfig(task="acrobot", preset="smoke"), out)
    with pytest.raises(FileNotFoundError, match=r"no experiment\.json"):
        Experiment.resume(tmp_path)
    assert main(["reproduce", "glider", "--resume", str(out)]) == 2  # a run of another task


def test_resume_of_finished_run_changes_nothing(smoke_run: tuple[Path, str]) -> None:
    out, _ = smoke_run
    before = (out / "learning.json").read_text(), (out / "closed_loop" / "summary.json").read_text()
    assert main(["reproduce", "acrobot", "--resume", str(out), "--no-progress"]) == 0
    after = (out / "learning.json").read_text(), (out / "closed_loop" / "summary.json").read_text()
    assert before == after


def _strip_times(summary: dict) -> dict:
    for row in summary["policies"]:
        for key in ("median_step_ms", "p95_step_ms", "max_step_ms"):
            row.pop(key, None)
    return summary


def test_sigkill_then_resume_gives_the_uninterrupted_results(smoke_run: tuple[Path, str], tmp_path: Path) -> None:
    reference, _ = smoke_run
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "seagul_learn.cli", "reproduce", "acrobot", "--preset", "smoke", "--workers", "1"]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen([*cmd, "--out", str(out), "--no-progress"], env=env, stdout=subprocess.DEVNULL)
    # Kill in the middle of training: once the first run has checkpointed but before everything is done.
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline and proc.poll() is None:
        if any((out / "train").glob("*/checkpoint.pt")):
            break
        time.sleep(0.05)
    assert proc.poll() is None, "the run finished before it could be interrupted"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not (out / "report.md").exists()
    done = subprocess.run([*cmd, "--resume", str(out), "--no-progress"], env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == str(out / "report.md")
    assert json.loads((out / "learning.json").read_text()) == json.loads((reference / "learning.json").read_text())
    killed = _strip_times(json.loads((out / "closed_loop" / "summary.json").read_text()))
    uninterrupted = _strip_times(json.loads((reference / "closed_loop" / "summary.json").read_text()))
    assert killed == uninterrupted
