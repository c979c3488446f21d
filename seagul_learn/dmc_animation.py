"""Side-by-side animations of DeepMind Control Suite episodes, rendered by MuJoCo from the recorded physics states.

An episode run with ``record=True`` (:func:`seagul_control.dmc.run_dmc_episode`) keeps the physics state
``[qpos, qvel]`` before every control step. :func:`dmc_animation` puts each state back into one dm_control physics
of the env and renders it with the suite's own camera, so what is drawn is exactly the episode that was scored;
nothing is simulated again. Each panel's strip names the controller and shows its return so far (dm_control's
reward summed up to the frame), and its final score once the episode has ended.

Rendering needs an OpenGL backend for MuJoCo. dm_control picks it when it is first imported, from ``MUJOCO_GL``;
on a machine without a display set ``MUJOCO_GL=egl`` (or ``osmesa``) before that import (``benchmarks/
animate_dmc.py`` does). Without a usable backend :func:`dmc_animation` raises a ``RuntimeError`` that says so.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, ImageDraw

from seagul_control.dmc import DMCEpisode, dmc_env_id, make_dmc_env, physics_of
from seagul_control.io import atomic_write_bytes

__all__ = ["dmc_animation"]


def _frames(episode: DMCEpisode, physics: Any, every: int, size: tuple[int, int], camera_id: int) -> list[Image.Image]:
    """Every ``every``-th recorded state of ``episode`` drawn by ``physics`` (a dm_control ``Physics``)."""
    states = np.asarray(episode.states, dtype=float)
    nq = int(physics.model.nq)
    frames = []
    for k in range(0, len(states), every):
        with physics.reset_context():
            physics.data.qpos[:] = states[k, :nq]
            physics.data.qvel[:] = states[k, nq:]
        pixels = physics.render(height=size[1], width=size[0], camera_id=camera_id)
        frames.append(Image.fromarray(np.asarray(pixels, dtype=np.uint8)))
    return frames


def dmc_animation(
    episodes: Sequence[tuple[str, DMCEpisode]],
    path: str | Path,
    *,
    every: int = 2,
    size: tuple[int, int] = (200, 200),
    camera_id: int = 0,
    speed: float = 1.0,
) -> Path:
    """Write an animated GIF of recorded suite episodes side by side (module docstring).

    ``episodes``: ``(label, episode)`` pairs, all of one env and each recorded (``record=True``); usually from the
    same reset seed, so the panels start from the same state. ``every``: draw every that-many control steps;
    ``size``: one panel's ``(width, height)`` in pixels; ``camera_id``: the suite camera; ``speed``: playback
    relative to real time. Written atomically; returns the path.

    Raises ``ValueError`` for no episodes, episodes of different envs or an episode recorded without its states.
    """
    if not episodes:
        raise ValueError("dmc_animation needs at least one (label, episode) pair")
    env_ids = {dmc_env_id(e.env_id) for _, e in episodes}
    if len(env_ids) != 1:
        raise ValueError(
            f"dmc_animation: the episodes are of several envs {sorted(env_ids)}; animate one env at a time"
        )
    for label, episode in episodes:
        if episode.states is None:
            raise ValueError(f"dmc_animation: episode {label!r} was run without record=True (no states to draw)")
    if not isinstance(every, int) or every < 1:
        raise ValueError(f"dmc_animation: every must be an integer >= 1, got {every!r}")
    if not speed > 0:
        raise ValueError(f"dmc_animation: speed must be > 0, got {speed!r}")
    env = make_dmc_env(env_ids.pop())
    try:
        env.reset(seed=0)
        physics = physics_of(env)
        try:
            physics.render(height=8, width=8, camera_id=camera_id)
        except Exception as error:  # dm_control chose a backend that cannot open a context here (e.g. GLFW headless)
            raise RuntimeError(
                f"dmc_animation: MuJoCo cannot render ({type(error).__name__}: {error}); on a machine without a "
                "display set MUJOCO_GL=egl (or osmesa) before dm_control is first imported"
            ) from error
        panels = [_frames(e, physics, every, size, camera_id) for _, e in episodes]
    finally:
        env.close()
    strip, width, height = 34, size[0] * len(panels), size[1] + 34
    n = max(len(p) for p in panels)
    out = []
    for k in range(n):
        canvas = Image.new("RGB", (width, height), "white")
        draw = ImageDraw.Draw(canvas)
        for i, ((label, episode), frames) in enumerate(zip(episodes, panels, strict=True)):
            x = i * size[0]
            canvas.paste(frames[min(k, len(frames) - 1)], (x, strip))
            step = min(k * every, episode.steps)
            done = step >= episode.steps
            so_far = float(np.sum(episode.rewards[:step]))
            status = (
                f"score {episode.score:.0f}" if done else f"t = {step * episode.control_dt:4.1f} s, return {so_far:.0f}"
            )
            draw.text((x + 6, 3), label, fill="black")
            draw.text((x + 6, 18), status, fill="darkgreen" if done else "dimgray")
        out.append(canvas.convert("P", palette=Image.Palette.ADAPTIVE, colors=96))
    dt_ms = round(1000.0 * every * float(episodes[0][1].control_dt) / speed)
    durations = [dt_ms] * (n - 1) + [2000]  # hold the final frame before the loop restarts
    buffer = io.BytesIO()
    out[0].save(buffer, format="GIF", save_all=True, append_images=out[1:], duration=durations, loop=0)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, buffer.getvalue())
    return path
