"""Pictures of an episode: a top view and a side view, and a helper that writes videos.

``Renderer.frame`` draws with matplotlib's Agg canvas (no window, no global pyplot
state) and returns an H x W x 3 uint8 array: obstacles, workspace boundary, waypoints
(goal as a star), each vehicle (its bounding circle), each arm (joint chain), the
object and the object's path so far. ``Renderer.show`` puts the same picture in a
window when a display exists and otherwise warns once and does nothing, so "human"
rendering is safe on headless machines. ``save_video`` writes frames to GIF or MP4.

Views in NED: the top view looks down the z axis (x north to the right, y east
downwards), the side view looks along -y (x to the right, depth z downwards).

May import: numpy, matplotlib (lazily), imageio (optional), ``uvms_env.dynamics``,
``uvms_env.navigation`` and ``uvms_env.scenarios`` (types).
"""

from __future__ import annotations

import os
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from uvms_env.dynamics.spatial import rot_zyx
from uvms_env.dynamics.uvms import default_model
from uvms_env.navigation import Cylinder

if TYPE_CHECKING:
    from uvms_env.scenarios import Scenario

FIGSIZE = (9.0, 4.5)  # inches
DPI = 80  # 720 x 360 pixels: enough to read, cheap to draw and store
_NON_INTERACTIVE = {"agg", "pdf", "ps", "svg", "pgf", "cairo", "template"}


class Renderer:
    """Draws frames of one scenario (see module docstring)."""

    def __init__(
        self, scenario: Scenario, segments: Sequence[tuple[np.ndarray, np.ndarray]]
    ) -> None:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        self.scenario = scenario
        self.segments = np.array([[a, b] for a, b in segments])  # (S, 2, 3) object frame
        self.uvms = default_model()
        self.r_vehicle = self.uvms.params.vehicle.bounding_radius
        self.figure = Figure(figsize=FIGSIZE, dpi=DPI, layout="constrained")
        self.canvas = FigureCanvasAgg(self.figure)
        self.top, self.side = self.figure.subplots(1, 2, width_ratios=(1.0, 1.0))
        self._window: Any = None
        self._warned = False
        self._static()
        n = scenario.n_agents
        colors = [f"C{i % 10}" for i in range(n)]
        self._vehicles = [
            [ax.add_patch(_circle(self.r_vehicle, c)) for ax in (self.top, self.side)]
            for c in colors
        ]
        self._arms = [
            [ax.plot([], [], "-", color=c, lw=2)[0] for ax in (self.top, self.side)] for c in colors
        ]
        self._object = [ax.plot([], [], "-", color="k", lw=3)[0] for ax in (self.top, self.side)]
        self._path = [ax.plot([], [], ":", color="k", lw=1)[0] for ax in (self.top, self.side)]
        self._title = self.figure.suptitle("")

    def _static(self) -> None:
        from matplotlib.patches import Circle, Rectangle

        s = self.scenario
        c, r = np.asarray(s.workspace.center), s.workspace.radius
        wp = np.asarray(s.waypoints)
        start = np.asarray(s.object_start)
        for ax, (i, j) in ((self.top, (0, 1)), (self.side, (0, 2))):
            ax.add_patch(Circle((c[i], c[j]), r, fill=False, ls="--", color="0.6"))
            for obs in s.obstacles:
                if isinstance(obs, Cylinder):
                    if j == 1:
                        ax.add_patch(Circle((obs.x, obs.y), obs.radius, color="0.5", alpha=0.6))
                    else:  # infinite in z: a band in the side view
                        ax.add_patch(
                            Rectangle(
                                (obs.x - obs.radius, c[2] - r),
                                2 * obs.radius,
                                2 * r,
                                color="0.5",
                                alpha=0.3,
                            )
                        )
                else:
                    ax.add_patch(
                        Circle((obs.center[i], obs.center[j]), obs.radius, color="0.5", alpha=0.6)
                    )
            ax.plot(wp[:-1, i], wp[:-1, j], "o", color="tab:green", ms=6, mfc="none")
            ax.plot(wp[-1, i], wp[-1, j], "*", color="tab:green", ms=12)
            ax.plot(start[i], start[j], "s", color="0.3", ms=5, mfc="none")
            ax.set_aspect("equal", adjustable="box")
            ax.grid(alpha=0.3)
        # NED: y east and z depth point down on the page (inverted y limits)
        pts = [start[:3], *wp[:, :3]]
        for obs in s.obstacles:  # the whole of every obstacle in view
            centre = (obs.x, obs.y, start[2]) if isinstance(obs, Cylinder) else obs.center
            pts += [np.asarray(centre) - obs.radius, np.asarray(centre) + obs.radius]
        lo, hi = np.min(pts, axis=0) - 3.0, np.max(pts, axis=0) + 3.0
        self.top.set(xlim=(lo[0], hi[0]), ylim=(hi[1], lo[1]), xlabel="x north [m]")
        self.top.set_ylabel("y east [m]")
        self.top.set_title("top view")
        self.side.set(xlim=(lo[0], hi[0]), ylim=(hi[2] + 1.0, lo[2] - 1.0), xlabel="x north [m]")
        self.side.set_ylabel("z depth [m]")
        self.side.set_title("side view")

    def frame(self, q: np.ndarray, x_o: np.ndarray, path: np.ndarray, t: float) -> np.ndarray:
        """H x W x 3 uint8 picture of the state (q (N, 10), true x_O) and the path (M, 3)."""
        for i, qi in enumerate(q):
            pts = np.array(self.uvms.body_points(qi)).T  # (6, 3): vehicle, joints, ee
            for ax_k, (a, b) in enumerate(((0, 1), (0, 2))):
                self._vehicles[i][ax_k].set_center((pts[0, a], pts[0, b]))
                self._arms[i][ax_k].set_data(pts[:, a], pts[:, b])
        rot = np.array(rot_zyx(x_o[3:]))
        seg = x_o[:3] + self.segments @ rot.T  # (S, 2, 3)
        # one polyline with NaN breaks between segments
        line = np.concatenate([seg, np.full((len(seg), 1, 3), np.nan)], axis=1).reshape(-1, 3)
        path = np.asarray(path).reshape(-1, 3)
        for ax_k, (a, b) in enumerate(((0, 1), (0, 2))):
            self._object[ax_k].set_data(line[:, a], line[:, b])
            self._path[ax_k].set_data(path[:, a], path[:, b])
        self._title.set_text(f"{self.scenario.name}: t = {t:6.2f} s")
        self.canvas.draw()
        return np.asarray(self.canvas.buffer_rgba())[:, :, :3].copy()

    def show(self, image: np.ndarray) -> None:
        """Show a frame in a window, or warn once when no display exists."""
        if self._window is None:
            if not _has_display():
                if not self._warned:
                    warnings.warn(
                        "render_mode='human' needs a display; none found, so nothing is "
                        "shown (use render_mode='rgb_array' to get frames)",
                        stacklevel=3,
                    )
                    self._warned = True
                return
            import matplotlib.pyplot as plt

            if plt.get_backend().lower() in _NON_INTERACTIVE:
                self._warned = True
                return
            fig = plt.figure(figsize=FIGSIZE, dpi=DPI)
            ax = fig.add_axes((0, 0, 1, 1))
            ax.set_axis_off()
            self._window = (plt, ax.imshow(image))
            plt.show(block=False)
        plt, im = self._window
        im.set_data(image)
        plt.pause(0.001)

    def close(self) -> None:
        if self._window is not None:
            plt, im = self._window
            plt.close(im.figure)
            self._window = None


def _circle(radius: float, color: str) -> Any:
    from matplotlib.patches import Circle

    return Circle((np.nan, np.nan), radius, fill=False, color=color, lw=1.5)


def _has_display() -> bool:
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def save_video(frames: Sequence[np.ndarray], path: str | Path, fps: float = 8.0) -> Path:
    """Write frames (H x W x 3 uint8) to ``path``: ``.gif`` (imageio, else Pillow) or
    ``.mp4`` (needs imageio with its ffmpeg plugin). Returns the path."""
    path = Path(path)
    if not frames:
        raise ValueError("save_video needs at least one frame")
    suffix = path.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise ValueError(f"unsupported video format {suffix!r}: use .gif or .mp4")
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        import imageio.v2 as imageio
    except ImportError:
        imageio = None
    if suffix == ".mp4":
        if imageio is None:
            raise ImportError("writing .mp4 needs imageio and imageio-ffmpeg (pip install ...)")
        imageio.mimwrite(path, list(frames), fps=fps)
    elif imageio is not None:
        imageio.mimwrite(path, list(frames), duration=1000.0 / fps, loop=0)
    else:
        from PIL import Image

        images = [Image.fromarray(np.asarray(f, dtype=np.uint8)) for f in frames]
        images[0].save(path, save_all=True, append_images=images[1:], duration=1000.0 / fps, loop=0)
    return path
