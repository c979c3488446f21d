"""Headless rendering: a tiny numpy rasteriser for the seagul envs, plus an optional matplotlib window.

``rgb_array`` frames are drawn with numpy only (anti-aliased discs and thick segments), so rendering works on CI
machines with no display, no GPU and no OpenGL (MuJoCo's own renderer needs EGL/OSMesa, which may be missing;
both acrobots therefore share this drawing, which also keeps their pictures identical).

``human`` mode shows the same frames in a matplotlib window when an interactive backend is available (a display
exists); on a headless machine the frames are still drawn but nothing is shown, so ``render_mode="human"`` never
crashes an experiment that was started without a display.

Imports: module level, except matplotlib, imported only when a ``human`` window is opened (the envs import this
module, and ``rgb_array`` frames and headless runs never need matplotlib's start-up cost).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

Color = tuple[int, int, int]
Point = Sequence[float] | np.ndarray
"""A world point ``(x, y)``: a pair of floats or a length-2 array."""

BACKGROUND: Color = (255, 255, 255)
LINK: Color = (0, 102, 204)
JOINT: Color = (204, 77, 0)
GOAL: Color = (0, 160, 0)
MUTED: Color = (170, 170, 170)
BODY: Color = (40, 40, 40)


class Canvas:
    """An RGB image with a world-to-pixel map (world y up, pixel rows down)."""

    def __init__(self, width: int, height: int, x_range: tuple[float, float], y_range: tuple[float, float]) -> None:
        self.width = int(width)
        self.height = int(height)
        self.image = np.empty((self.height, self.width, 3), dtype=np.uint8)
        self.image[:] = BACKGROUND
        x0, x1 = x_range
        y0, y1 = y_range
        # One isotropic scale so circles stay round; centre the world box in the image.
        self.scale = min(self.width / (x1 - x0), self.height / (y1 - y0))
        self.x_mid = 0.5 * (x0 + x1)
        self.y_mid = 0.5 * (y0 + y1)

    def to_pixel(self, point: Point) -> tuple[float, float]:
        """World ``(x, y)`` to pixel ``(column, row)`` (floats, pixel centres at integers)."""
        col = (point[0] - self.x_mid) * self.scale + 0.5 * self.width - 0.5
        row = -(point[1] - self.y_mid) * self.scale + 0.5 * self.height - 0.5
        return col, row

    def _blend(self, rows: slice, cols: slice, coverage: np.ndarray, color: Color) -> None:
        patch = self.image[rows, cols].astype(np.float32)
        alpha = coverage[..., None]
        patch = patch * (1.0 - alpha) + np.asarray(color, dtype=np.float32) * alpha
        self.image[rows, cols] = np.clip(patch + 0.5, 0, 255).astype(np.uint8)

    def segment(self, p0: Point, p1: Point, width_px: float, color: Color) -> None:
        """A thick segment with round caps between two world points (anti-aliased)."""
        a = np.array(self.to_pixel(p0))
        b = np.array(self.to_pixel(p1))
        r = 0.5 * width_px
        lo = np.floor(np.minimum(a, b) - r - 1).astype(int)
        hi = np.ceil(np.maximum(a, b) + r + 1).astype(int)
        c0, r0 = max(lo[0], 0), max(lo[1], 0)
        c1, r1 = min(hi[0], self.width - 1), min(hi[1], self.height - 1)
        if c0 > c1 or r0 > r1:
            return  # entirely off-screen
        cols, rows = np.meshgrid(np.arange(c0, c1 + 1), np.arange(r0, r1 + 1))
        d = b - a
        length2 = float(d @ d)
        if length2 > 0.0:
            t = np.clip(((cols - a[0]) * d[0] + (rows - a[1]) * d[1]) / length2, 0.0, 1.0)
        else:
            t = np.zeros(cols.shape)
        dist = np.hypot(cols - (a[0] + t * d[0]), rows - (a[1] + t * d[1]))
        coverage = np.clip(r + 0.5 - dist, 0.0, 1.0).astype(np.float32)
        self._blend(slice(r0, r1 + 1), slice(c0, c1 + 1), coverage, color)

    def disc(self, center: Point, radius_px: float, color: Color) -> None:
        """A filled disc (a zero-length segment)."""
        self.segment(center, center, 2.0 * radius_px, color)

    def dashed(self, p0: Point, p1: Point, width_px: float, color: Color, dashes: int = 20) -> None:
        """A dashed segment made of ``dashes`` pieces."""
        a, b = np.asarray(p0, dtype=float), np.asarray(p1, dtype=float)
        for i in range(dashes):
            self.segment(a + (b - a) * (i / dashes), a + (b - a) * ((i + 0.5) / dashes), width_px, color)

    def bar(self, fraction: float, color: Color, height_px: int = 6) -> None:
        """A progress bar along the bottom edge (used for the time to go)."""
        n = round(float(np.clip(fraction, 0.0, 1.0)) * self.width)
        if n > 0:
            self.image[self.height - height_px :, :n] = color


def acrobot_frame(
    th1: float, th2: float, l1: float, l2: float, u: float = 0.0, u_max: float = 1.0, ttg_fraction: float = 0.0
) -> np.ndarray:
    """Draw the acrobot (``th1 = 0`` hanging down) as a 500 x 500 RGB frame."""
    reach = l1 + l2
    canvas = Canvas(500, 500, (-1.1 * reach, 1.1 * reach), (-1.1 * reach, 1.1 * reach))
    canvas.dashed((-reach, reach), (reach, reach), 2, GOAL)  # the height the tip reaches when upright
    p1 = (l1 * np.sin(th1), -l1 * np.cos(th1))
    p2 = (p1[0] + l2 * np.sin(th1 + th2), p1[1] - l2 * np.cos(th1 + th2))
    canvas.segment((0.0, 0.0), p1, 12, LINK)
    canvas.segment(p1, p2, 12, LINK)
    # Elbow torque as a bar next to the elbow: its length is |u| / u_max, its side the sign.
    canvas.segment(p1, (p1[0] + 0.5 * np.clip(u / u_max, -1, 1), p1[1]), 5, JOINT)
    canvas.disc((0.0, 0.0), 8, BODY)
    canvas.disc(p1, 7, JOINT)
    canvas.bar(ttg_fraction, MUTED)
    return canvas.image


def glider_frame(
    state: np.ndarray,
    l_h: float,
    l_e: float,
    x_bounds: tuple[float, float],
    z_bounds: tuple[float, float],
    trail: Sequence[tuple[float, float]] = (),
    ttg_fraction: float = 0.0,
) -> np.ndarray:
    """Draw the perching glider in the x-z plane (perch at the origin) as a 720 x 360 RGB frame."""
    x, z, th, phi = (float(v) for v in state[:4])
    canvas = Canvas(720, 360, (x_bounds[0] - 0.2, x_bounds[1] + 0.2), (z_bounds[0] - 0.2, z_bounds[1] + 0.2))
    # Flight box (leaving it ends the episode) and the perch.
    x0, x1 = x_bounds
    z0, z1 = z_bounds
    for a, b in (((x0, z0), (x1, z0)), ((x1, z0), (x1, z1)), ((x1, z1), (x0, z1)), ((x0, z1), (x0, z0))):
        canvas.segment(a, b, 1, MUTED)
    canvas.segment((0.0, 0.0), (0.0, z1), 2, MUTED)  # the string the glider perches on
    canvas.disc((0.0, 0.0), 5, GOAL)
    for i in range(1, len(trail)):
        canvas.segment(trail[i - 1], trail[i], 1, MUTED)
    # Drawn 3x enlarged: the real airframe (0.3 m) is a few pixels long at this scale.
    k = 3.0
    body = np.array([np.cos(th), np.sin(th)])
    hinge = np.array([x, z]) - k * l_h * body
    e = th + phi
    tail = hinge - k * 2.0 * l_e * np.array([np.cos(e), np.sin(e)])
    nose = np.array([x, z]) + k * 0.08 * body
    canvas.segment(nose, hinge, 4, BODY)
    canvas.segment((x - k * 0.06 * body[0], z - k * 0.06 * body[1]), nose, 7, LINK)  # wing (flat plate at the COM)
    canvas.segment(hinge, tail, 5, JOINT)  # elevator
    canvas.bar(ttg_fraction, MUTED)
    return canvas.image


class HumanViewer:
    """Shows RGB frames in a matplotlib window; silently draws nothing when no interactive backend exists."""

    def __init__(self, title: str, fps: float) -> None:
        self.title = title
        self.fps = float(fps)
        self._fig: Any = None
        self._artist: Any = None
        self._plt: Any = None
        self.available = _interactive_backend()

    def show(self, frame: np.ndarray) -> None:
        if not self.available:
            return
        if self._fig is None:
            import matplotlib.pyplot as plt

            self._plt = plt
            plt.ion()
            self._fig, ax = plt.subplots(num=self.title)
            ax.set_axis_off()
            self._artist = ax.imshow(frame)
            self._fig.tight_layout()
        else:
            self._artist.set_data(frame)
        self._plt.pause(1.0 / self.fps)

    def close(self) -> None:
        if self._fig is not None:
            self._plt.close(self._fig)
            self._fig = None


def _interactive_backend() -> bool:
    """True when matplotlib can open a window (a display and an interactive backend)."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return False
    try:
        import matplotlib
        from matplotlib.backends import backend_registry
    except ImportError:
        return False
    backend = matplotlib.get_backend().lower()
    try:
        # The enum lives in the registry module (the registry object has no ``BackendFilter`` attribute).
        from matplotlib.backends.registry import BackendFilter
    except ImportError:  # older matplotlib without the registry API
        return backend not in {"agg", "pdf", "ps", "svg", "cairo", "template", "pgf"}
    return backend not in backend_registry.list_builtin(BackendFilter.NON_INTERACTIVE)
