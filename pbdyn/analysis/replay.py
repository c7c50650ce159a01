"""Replay a trial trace (`pbdyn run --trace`) as an animation or a still: `pbdyn replay TRACE --out FILE`.

Every frame is drawn headless with matplotlib (Agg) from the trace alone: the arena and its static bodies, the
obstacles at their true positions (rollout), the sensor's field of view, the tracked obstacles (mean and a 2-sigma
uncertainty ellipse around the obstacle's radius), the plan in execution, the path flown so far, start and goal, the
time, and at the end the outcome. 2D traces give a top view; 3D traces a top (x-y) and a side (x-z) view. Imported
worlds' moving bodies are drawn as their bounding circles (the trace holds their centres and bounding radii).

Formats: .gif (Pillow, through imageio), .mp4 (H.264 through imageio-ffmpeg), .png (the last frame, the whole
flight). Files are written atomically (a temporary file beside the target, then renamed).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pbdyn.errors import ConfigError
from pbdyn.files import atomic_write

FORMATS = (".gif", ".mp4", ".png")
FRAME_PX = 640
"""Height of a frame in pixels (2D: square; 3D: two panels side by side). A multiple of 16 (H.264 blocks)."""

COLOURS = {"obstacle": "#d62728", "static": "#4d4d4d", "mav": "#1f77b4", "path": "#1f77b4", "plan": "#2ca02c",
           "track": "#ff7f0e", "fov": "#9ecae1", "goal": "#2ca02c", "start": "#7f7f7f"}
"""Colours of what a frame shows (obstacles are drawn opaque in COLOURS["obstacle"]: tests look for it)."""

REQUIRED = ("t", "p", "yaw", "plan", "track_mean", "track_std", "track_active", "obstacle_p", "obstacle_r", "dt",
            "arena_lo", "arena_hi", "start", "goal", "goal_radius", "mav_radius", "fov_deg", "range_m", "outcome")


@dataclass(frozen=True)
class ReplaySummary:
    """What `pbdyn replay` wrote: the file, its frame count and frame size (width, height px)."""

    path: str
    frames: int
    width: int
    height: int


def load_trace(path: str | Path) -> dict:
    """The arrays of a trace .npz written by `pbdyn run --trace`; ConfigError naming TRACE if it is missing,
    unreadable, or lacks what a replay needs (a trace from an older pbdyn)."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError("TRACE", "file not found", str(path))
    try:
        with np.load(p, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except Exception as exc:
        raise ConfigError("TRACE", f"is not a readable trace .npz ({type(exc).__name__})", str(path)) from None
    missing = [k for k in REQUIRED if k not in data]
    if missing:
        raise ConfigError("TRACE", f"lacks {', '.join(missing)} (record it again with this pbdyn: pbdyn run --trace)",
                          str(path))
    if data["t"].shape[0] == 0:
        raise ConfigError("TRACE", "holds no step", str(path))
    return data


def check_output(out: str | Path, field: str = "out") -> str:
    """The output's format (".gif", ".mp4" or ".png"); ConfigError naming ``field`` for another suffix, or for .mp4
    without imageio-ffmpeg."""
    suffix = Path(out).suffix.lower()
    if suffix not in FORMATS:
        raise ConfigError(field, f"must end in {', '.join(FORMATS)}", str(out))
    if suffix == ".mp4":
        try:
            import imageio_ffmpeg  # noqa: F401
        except ImportError:
            raise ConfigError(field, "an .mp4 needs imageio-ffmpeg (pip install imageio-ffmpeg), or use .gif",
                              str(out)) from None
    return suffix


class Renderer:
    """Draws the frames of one trace (a figure built once; each frame updates its artists)."""

    def __init__(self, trace: dict, height_px: int = FRAME_PX):
        import matplotlib

        matplotlib.use("Agg", force=False)
        from matplotlib.figure import Figure
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        self.tr = trace
        self.dims = int(trace["p"].shape[1])
        panels = [(0, 1)] if self.dims == 2 else [(0, 1), (0, 2)]
        dpi = 100
        self.fig = Figure(figsize=(height_px * len(panels) / dpi, height_px / dpi), dpi=dpi)
        self.canvas = FigureCanvasAgg(self.fig)
        self.axes = [self.fig.add_subplot(1, len(panels), i + 1) for i in range(len(panels))]
        self.panels = panels
        self.fig.subplots_adjust(left=0.11 / len(panels), right=0.98, bottom=0.15, top=0.89, wspace=0.22)
        self.title = self.fig.suptitle("", fontsize=10)
        self.artists = [self._panel(ax, axes) for ax, axes in zip(self.axes, panels)]

    # ----------------------------------------------------------------------------------------- layout
    def _panel(self, ax, axes: tuple[int, int]) -> dict:
        from matplotlib.collections import EllipseCollection
        from matplotlib.patches import Circle, Polygon, Rectangle

        tr = self.tr
        i, j = axes
        lo, hi = tr["arena_lo"], tr["arena_hi"]
        names = "xyz"
        ax.set_xlim(lo[i] - 1.0, hi[i] + 1.0)
        ax.set_ylim(lo[j] - 1.0, hi[j] + 1.0)
        ax.set_aspect("equal")
        ax.set_xlabel(f"{names[i]} (m)")
        ax.set_ylabel(f"{names[j]} (m)")
        if self.dims == 3:
            ax.set_title("top view" if j == 1 else "side view", fontsize=9)
        ax.add_patch(Rectangle((lo[i], lo[j]), hi[i] - lo[i], hi[j] - lo[j], fill=False, lw=2.0, ec="black",
                               zorder=1))
        for k in range(len(tr.get("static_kind", []))):
            self._static(ax, axes, k)
        r_obs = tr["obstacle_r"]
        n = r_obs.shape[0]
        obstacles = EllipseCollection(2 * r_obs, 2 * r_obs, np.zeros(n), units="xy", offsets=np.zeros((n, 2)),
                                      offset_transform=ax.transData, facecolors=COLOURS["obstacle"],
                                      edgecolors="none", zorder=4)
        ax.add_collection(obstacles)
        tracks = EllipseCollection(np.zeros(n), np.zeros(n), np.zeros(n), units="xy", offsets=np.zeros((n, 2)),
                                   offset_transform=ax.transData, facecolors="none", edgecolors=COLOURS["track"],
                                   linewidths=1.2, linestyles="--", zorder=5)
        ax.add_collection(tracks)
        track_mean, = ax.plot([], [], "+", color=COLOURS["track"], ms=5, zorder=6)
        fov = Polygon(np.zeros((3, 2)), closed=True, fc=COLOURS["fov"], ec="none", alpha=0.45, zorder=2)
        ax.add_patch(fov)
        start, goal = tr["start"], tr["goal"]
        ax.plot([start[i]], [start[j]], "s", color=COLOURS["start"], ms=7, zorder=3, label="start")
        ax.add_patch(Circle((goal[i], goal[j]), float(tr["goal_radius"]), fc="none", ec=COLOURS["goal"], lw=1.5,
                            zorder=3))
        ax.plot([goal[i]], [goal[j]], "*", color=COLOURS["goal"], ms=12, zorder=3, label="goal")
        path, = ax.plot([], [], "-", color=COLOURS["path"], lw=1.2, zorder=7, label="flown path")
        plan, = ax.plot([], [], "-", color=COLOURS["plan"], lw=2.0, zorder=8, label="plan")
        mav = Circle((0.0, 0.0), float(tr["mav_radius"]), fc=COLOURS["mav"], ec="black", lw=0.8, zorder=9)
        ax.add_patch(mav)
        heading, = ax.plot([], [], "-", color="black", lw=1.2, zorder=10)
        if axes == (0, 1):
            ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.09), ncol=4, fontsize=8, frameon=False)
        return {"obstacles": obstacles, "tracks": tracks, "track_mean": track_mean, "fov": fov, "path": path,
                "plan": plan, "mav": mav, "heading": heading}

    def _static(self, ax, axes: tuple[int, int], k: int) -> None:
        from matplotlib.patches import Circle, Polygon

        tr = self.tr
        i, j = axes
        kind = str(tr["static_kind"][k])
        c = tr["static_center"][k]
        if j == 1:                                   # top view: pillar discs, rotated boxes
            if kind == "pillar":
                ax.add_patch(Circle((c[0], c[1]), float(tr["static_radius"][k]), fc=COLOURS["static"], zorder=3))
                return
            sx, sy = tr["static_size"][k][:2] / 2.0
            yaw = float(tr["static_yaw"][k])
            rot = np.array([[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]])
            corners = np.array([[-sx, -sy], [sx, -sy], [sx, sy], [-sx, sy]]) @ rot.T + c[:2]
            ax.add_patch(Polygon(corners, closed=True, fc=COLOURS["static"], zorder=3))
            return
        lo, hi = self.tr["arena_lo"], self.tr["arena_hi"]     # side view: the body's x extent over its z extent
        if kind == "pillar":
            r = float(tr["static_radius"][k])
            x0, x1, z0, z1 = c[0] - r, c[0] + r, lo[2], hi[2]
        else:
            half = tr["static_size"][k] / 2.0
            yaw = float(tr["static_yaw"][k])
            ex = abs(math.cos(yaw)) * half[0] + abs(math.sin(yaw)) * half[1]
            x0, x1, z0, z1 = c[0] - ex, c[0] + ex, c[2] - half[2], c[2] + half[2]
        ax.add_patch(Polygon([[x0, z0], [x1, z0], [x1, z1], [x0, z1]], closed=True, fc=COLOURS["static"], zorder=3))

    # ----------------------------------------------------------------------------------------- frames
    @property
    def n_steps(self) -> int:
        """Steps in the trace (frames 0..n_steps: the state at each step, then the final state)."""
        return int(self.tr["t"].shape[0])

    def frame(self, s: int) -> np.ndarray:
        """The RGB image [H, W, 3] (uint8) of the state at step s (s = n_steps: the final state, with the outcome)."""
        tr = self.tr
        final = s >= self.n_steps
        s = min(s, self.n_steps)
        p = tr["final_p"] if final and "final_p" in tr else tr["p"][min(s, self.n_steps - 1)]
        yaw = float(tr["final_yaw"]) if final and "final_yaw" in tr else float(tr["yaw"][min(s, self.n_steps - 1)])
        k = min(s, self.n_steps - 1)
        obs = tr["obstacle_p"][min(s, tr["obstacle_p"].shape[0] - 1)]
        flown = np.vstack([tr["p"][:s + 1] if not final else tr["p"], p[None]])
        active = tr["track_active"][k]
        for (i, j), art in zip(self.panels, self.artists):
            art["obstacles"].set_offsets(obs[:, [i, j]])
            mean = tr["track_mean"][k][:, [i, j]]
            std = np.nan_to_num(tr["track_std"][k][:, [i, j]])
            r = tr["obstacle_r"]
            w = np.where(active, 2.0 * (r + 2.0 * std[:, 0]), 0.0)
            h = np.where(active, 2.0 * (r + 2.0 * std[:, 1]), 0.0)
            art["tracks"].set_offsets(np.nan_to_num(mean))
            art["tracks"].set_widths(w)
            art["tracks"].set_heights(h)
            art["track_mean"].set_data(mean[active, 0], mean[active, 1])
            art["path"].set_data(flown[:, i], flown[:, j])
            plan = tr["plan"][k]
            plan = plan[~np.isnan(plan[:, 0])] if not final else plan[:0]
            art["plan"].set_data(plan[:, i], plan[:, j])
            art["mav"].set_center((p[i], p[j]))
            art["fov"].set_xy(self._fov_polygon(p, yaw, i, j))
            if j == 1:
                L = 2.0 * float(tr["mav_radius"])
                art["heading"].set_data([p[0], p[0] + L * math.cos(yaw)], [p[1], p[1] + L * math.sin(yaw)])
        t = float(tr["t"][k]) + (float(tr["dt"]) if final else 0.0)
        label = str(tr["label"]) if "label" in tr else ""
        status = f"outcome: {str(tr['outcome']).replace('_', ' ')}" if final else "flying"
        self.title.set_text(f"{label}\nt = {t:5.1f} s   {status}")
        self.canvas.draw()
        return np.asarray(self.canvas.buffer_rgba())[:, :, :3].copy()

    def _fov_polygon(self, p: np.ndarray, yaw: float, i: int, j: int) -> np.ndarray:
        """The sensor's field of view in the panel (i, j): a wedge of range_m and fov_deg (top view) or the vertical
        fan's extent along the heading (side view)."""
        rng, fov = float(self.tr["range_m"]), math.radians(float(self.tr["fov_deg"]))
        if j == 1:
            half = min(fov, 2.0 * math.pi) / 2.0
            ang = yaw + np.linspace(-half, half, 41)
            pts = np.c_[p[0] + rng * np.cos(ang), p[1] + rng * np.sin(ang)]
            return pts if fov >= 2.0 * math.pi - 1e-9 else np.vstack([[p[0], p[1]], pts])
        vhalf = math.radians(float(self.tr["vfov_deg"])) / 2.0
        ang = np.linspace(-vhalf, vhalf, 21)
        along = math.cos(yaw) if fov < 2.0 * math.pi - 1e-9 else 1.0
        pts = np.c_[p[0] + rng * np.cos(ang) * along, p[2] + rng * np.sin(ang)]
        return np.vstack([[p[0], p[2]], pts])

    def frames(self, every: int = 1) -> Iterator[np.ndarray]:
        """Frames of steps 0, every, 2 every, ... and always the final state."""
        steps = list(range(0, self.n_steps, every)) + [self.n_steps]
        for s in steps:
            yield self.frame(s)


def frame_count(n_steps: int, every: int) -> int:
    """Frames written for a trace of n_steps steps at one frame every ``every`` steps (plus the final state)."""
    return len(range(0, n_steps, every)) + 1


def write_replay(trace_path: str | Path, out: str | Path, *, fps: float | None = None,
                 every: int = 1) -> ReplaySummary:
    """Render the trace at ``trace_path`` into ``out`` (.gif, .mp4: one frame every ``every`` steps and the final
    state, at ``fps`` frames per second, default real time 1 / (dt every); .png: the final state)."""
    suffix = check_output(out)
    if isinstance(every, bool) or not isinstance(every, int) or every < 1:
        raise ConfigError("every", "must be an integer >= 1", every)
    if fps is not None and (isinstance(fps, bool) or not isinstance(fps, (int, float)) or not math.isfinite(fps)
                            or not 0.1 <= fps <= 120):
        raise ConfigError("fps", "must be a number in [0.1, 120]", fps)
    trace = load_trace(trace_path)
    out = Path(out)
    if not out.parent.is_dir():
        raise ConfigError("out", "its folder does not exist", str(out))
    rate = float(fps) if fps is not None else 1.0 / (float(trace["dt"]) * every)
    renderer = Renderer(trace)
    done: dict = {}

    def write(tmp: str) -> None:
        import imageio.v2 as iio

        if suffix == ".png":
            img = renderer.frame(renderer.n_steps)
            iio.imwrite(tmp, img, format="PNG")
            done.update(n=1, shape=img.shape)
        elif suffix == ".gif":
            frames = list(renderer.frames(every))
            iio.mimwrite(tmp, frames, format="GIF", duration=1000.0 / rate, loop=0)
            done.update(n=len(frames), shape=frames[0].shape)
        else:
            writer = iio.get_writer(tmp, format="FFMPEG", fps=rate, codec="libx264", macro_block_size=16,
                                    quality=7, ffmpeg_log_level="error")
            try:
                for img in renderer.frames(every):
                    writer.append_data(img)
                    done.update(n=done.get("n", 0) + 1, shape=img.shape)
            finally:
                writer.close()

    atomic_write(out, write)
    n, shape = done["n"], done["shape"]
    return ReplaySummary(str(out), n, int(shape[1]), int(shape[0]))
