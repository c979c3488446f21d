"""Every example runs top to bottom with --test (shrunk to seconds of solving) in a fresh interpreter.

Two examples spend minutes on a cold solver cache and are marked ``slow`` (run them with ``pytest -m slow``):
``quickstart.py`` compiles the acrobot's trajectory-optimization solvers and the MPC's terminal cost, labels the
200-start validation set and trains (6 minutes measured from a cold cache on a loaded 2-core machine);
``custom_system.py`` also starts Ray (1 minute). What they do is covered by faster tests: the solve, its gradients
and labels by tests/test_trajopt.py, training by tests/test_training.py, the network as the MPC's terminal cost and
SB3's ``evaluate_policy`` by tests/test_mpc.py, the predict protocol of the MPC and the LQR reference on every task
by tests/test_conformance.py; the custom cart-pole through every layer (training, its resume, the MPC, evaluation,
``--task file.py:factory``) by tests/test_custom_system.py and on Ray by tests/test_conformance.py. In the default
suite each of them still starts with ``--help``: every name it imports must exist (a moved module or a renamed
function fails here first).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = sorted((Path(__file__).resolve().parents[1] / "examples").glob("*.py"))
SLOW = {"quickstart.py", "custom_system.py"}
"""Examples that compile solvers and train for minutes (see the module docstring for the tests covering them)."""


def _run(script: Path, *args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(script), *args], capture_output=True, text=True, timeout=900, cwd=cwd)


def test_examples_are_found() -> None:
    assert {p.name for p in EXAMPLES} >= {"quickstart.py", "train_sb3.py", "custom_system.py"} | SLOW


@pytest.mark.parametrize(
    "script", [pytest.param(p, marks=pytest.mark.slow) if p.name in SLOW else p for p in EXAMPLES], ids=lambda p: p.name
)
def test_example_runs_with_test_flag(script: Path, tmp_path: Path) -> None:
    done = _run(script, "--test", "--out", str(tmp_path / "out"), cwd=tmp_path)
    assert done.returncode == 0, f"{script.name} failed:\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"


@pytest.mark.parametrize("script", [p for p in EXAMPLES if p.name in SLOW], ids=lambda p: p.name)
def test_a_slow_example_imports_what_it_uses_and_parses_its_arguments(script: Path, tmp_path: Path) -> None:
    done = _run(script, "--help", cwd=tmp_path)
    assert done.returncode == 0, f"{script.name} --help failed:\n{done.stderr[-3000:]}"
    assert "--test" in done.stdout
