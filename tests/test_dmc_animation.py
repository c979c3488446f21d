"""Animations of recorded suite episodes: the frames are the recorded states, drawn by MuJoCo's renderer.

The drawing runs in a subprocess with ``MUJOCO_GL=egl``: dm_control picks its OpenGL backend when it is first
imported, and another test file in this worker may have imported it with the default (GLFW, which needs a display).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("dm_control")
pytest.importorskip("shimmy")

from PIL import Image

from seagul_control.dmc import run_dmc_episode
from seagul_learn.dmc_animation import dmc_animation

DRAW = """
import json, sys
import numpy as np
from seagul_control.dmc import run_dmc_episode
from seagul_learn.dmc_animation import dmc_animation
out = sys.argv[1]
zero = run_dmc_episode("pendulum-swingup", lambda x, t: np.zeros(1), 3, record=True)
push = run_dmc_episode("pendulum-swingup", lambda x, t: np.ones(1), 3, record=True)
dmc_animation([("zero", zero), ("push", push)], out + "/two.gif", every=100, size=(64, 48))
dmc_animation([("a", zero), ("b", zero), ("c", push)], out + "/three.gif", every=250)
json.dump({"steps": zero.steps, "scores": [zero.score, push.score]}, open(out + "/info.json", "w"))
"""


@pytest.fixture(scope="module")
def drawn(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("animation")
    env = {**os.environ, "MUJOCO_GL": "egl"}
    done = subprocess.run([sys.executable, "-c", DRAW, str(out)], env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-3000:]
    return out


def test_one_frame_per_drawn_step_panels_side_by_side(drawn: Path) -> None:
    gif = Image.open(drawn / "two.gif")
    steps = json.loads((drawn / "info.json").read_text())["steps"]
    assert gif.n_frames == len(range(0, steps + 1, 100))
    assert gif.size == (2 * 64, 48 + 34)


def test_frames_are_the_recorded_states(drawn: Path) -> None:
    # The same episode drawn twice gives identical panels; another episode's panel differs once they part.
    gif = Image.open(drawn / "three.gif")
    gif.seek(gif.n_frames - 1)
    frame = np.asarray(gif.convert("RGB"))[34:]
    a, b, c = frame[:, :200], frame[:, 200:400], frame[:, 400:]
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_bad_input_is_named(tmp_path: Path) -> None:
    episode = run_dmc_episode("pendulum-swingup", lambda x, t: np.zeros(1), 0, record=True)
    with pytest.raises(ValueError, match="at least one"):
        dmc_animation([], tmp_path / "x.gif")
    with pytest.raises(ValueError, match="record=True"):
        dmc_animation([("bare", replace(episode, states=None))], tmp_path / "x.gif")
    with pytest.raises(ValueError, match="several envs"):
        other = replace(episode, env_id="dm_control/acrobot-swingup-v0")
        dmc_animation([("a", episode), ("b", other)], tmp_path / "x.gif")
    with pytest.raises(ValueError, match="every"):
        dmc_animation([("a", episode)], tmp_path / "x.gif", every=0)
    assert not (tmp_path / "x.gif").exists()
