"""Replay a trial trace (`pbdyn run --trace`) as an animation or a still: `pbdyn replay TRACE --out FILE`.

Every frame is drawn headless with matplotlib (Agg) from the trace alone: the arena and its static bodies, the
obstacles at their true positions (rollout), the sensor's field of view, the tracked obstacles (mean and a 2-sigma
uncertainty ellipse around the obstacle's radius), the plan in execution, the path flown so far, start and goal, the
time, and at the end the outcome. 2D traces give a top view; 3D traces a top (x-y) and a side (x-z) view. Imported
worlds' moving bodies are drawn as their bounding circles (the trace holds their centres and bounding radii), their
still bodies as the outlines the trace holds (static_outline: 2D their cut by the flight plane, 3D their top view;
static_outline_side: 3D their side view); a trace recorded before pbdyn stored those outlines is drawn without them.
Names (the label: scenario, planner) are drawn as plain text: "$" is never read as matplotlib math.

Formats: .gif (streamed: each frame is written as it is drawn, so memory holds one frame), .mp4 (H.264 through
imageio-ffmpeg), .png (the last frame, the whole flight). Files are written atomically (a temporary file beside the
target, then renamed). Traces are checked before they are drawn (load_trace): the unpacked size of the .npz members
against MAX_TRACE_BYTES before any is read, then every array's shape, type and finiteness.
"""

from __future__ import annotations

import io
import math
import struct
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pbdyn.errors import ConfigError, check_writable_file
from pbdyn.files import atomic_write

FORMATS = (".gif", ".mp4", ".png")
FRAME_PX = 640
"""Height of a frame in pixels (2D: square; 3D: two panels side by side). A multiple of 16 (H.264 blocks)."""

COLOURS = {"obstacle": "#d62728", "static": "#4d4d4d", "mav": "#1f77b4", "path": "#1f77b4", "plan": "#2ca02c",
           "track": "#ff7f0e", "fov": "#9ecae1", "goal": "#2ca02c", "start": "#7f7f7f"}
"""Colours of what a frame shows (obstacles are drawn opaque in COLOURS["obstacle"]: tests look for it)."""

MAX_TRACE_BYTES = 2 ** 30
"""Largest unpacked size of a trace's arrays together (bytes): a flight of 10^4 steps among 10^3 obstacles in 3D is
~0.5 GB; more is a damaged or crafted file (a zip bomb), refused before it is unpacked."""
MAX_COORDINATE_M = 1e6
"""Largest |coordinate| (m) in a trace (positions, arena, plans)."""
MIN_FPS = 0.1
MAX_FPS = {".gif": 50.0, ".mp4": 120.0}
"""Fastest frame rate per format: a GIF's frame delays are whole 1/100 s and players slow delays under 2/100 s."""

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
    unreadable, lacks what a replay needs (a trace from an older pbdyn), would unpack to more than MAX_TRACE_BYTES,
    or holds arrays of the wrong shape or type, or non-finite or out-of-range values (a damaged or crafted file)."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError("TRACE", "file not found", str(path))
    try:
        with zipfile.ZipFile(p) as zf:
            _check_members(zf, str(path))
        with np.load(p, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except ConfigError:
        raise
    except Exception as exc:
        raise ConfigError("TRACE", f"is not a readable trace .npz ({type(exc).__name__})", str(path)) from None
    missing = [k for k in REQUIRED if k not in data]
    if missing:
        raise ConfigError("TRACE", f"lacks {', '.join(missing)} (record it again with this pbdyn: `trace`)",
                          str(path))
    _check_arrays(data, str(path))
    return data


def _check_members(zf: zipfile.ZipFile, shown: str) -> None:
    """ConfigError unless the members unpack to at most MAX_TRACE_BYTES together and every .npy member's header
    declares a plain (no Python objects) array no larger than the member."""
    infos = zf.infolist()
    total = sum(info.file_size for info in infos)
    if total > MAX_TRACE_BYTES:
        raise ConfigError("TRACE", f"would unpack to {total / 2 ** 20:.0f} MiB, more than a trace's "
                          f"{MAX_TRACE_BYTES / 2 ** 20:.0f} MiB (a damaged or crafted file)", shown)
    for info in infos:
        if not info.filename.endswith(".npy"):
            continue
        with zf.open(info) as fh:
            version = np.lib.format.read_magic(fh)
            if version == (1, 0):
                shape, _, dtype = np.lib.format.read_array_header_1_0(fh)
            elif version == (2, 0):
                shape, _, dtype = np.lib.format.read_array_header_2_0(fh)
            else:
                raise ValueError(f"npy format version {version}")
        nbytes = math.prod(int(n) for n in shape) * dtype.itemsize
        if dtype.hasobject:
            raise ConfigError("TRACE", f"array {info.filename[:-4]} holds Python objects (not a trace)", shown)
        if nbytes > info.file_size:
            raise ConfigError("TRACE", f"array {info.filename[:-4]} declares {nbytes} bytes but holds "
                              f"{info.file_size} (a damaged or crafted file)", shown)


def _check_arrays(tr: dict, shown: str) -> None:
    """ConfigError naming the first array of ``tr`` whose shape, type or values a trace cannot have."""
    def bad(name: str, problem: str) -> ConfigError:
        return ConfigError("TRACE", f"array {name} {problem} (a damaged or crafted trace)", shown)

    def arr(name: str, shape: tuple, kinds: str = "fiu", values: str = "finite") -> np.ndarray:
        """``tr[name]`` checked: shape (ints; None: any length >= 0), dtype kind, values "finite", "nan" (finite
        or NaN) or "any"; coordinates no larger than MAX_COORDINATE_M."""
        a = tr[name]
        if a.ndim != len(shape) or any(n is not None and a.shape[i] != n for i, n in enumerate(shape)):
            want = "[" + ", ".join("*" if n is None or n < 0 else str(n) for n in shape) + "]"
            raise bad(name, f"has shape {list(a.shape)}, expected {want}")
        if a.dtype.kind not in kinds:
            raise bad(name, f"holds {a.dtype} values")
        if values != "any" and a.dtype.kind in "fiu":
            finite = np.isfinite(a)
            if not (finite | (np.isnan(a) if values == "nan" else False)).all():
                raise bad(name, "holds infinite or NaN values")
            if np.abs(a[finite]).max(initial=0.0) > MAX_COORDINATE_M:
                raise bad(name, f"holds values beyond {MAX_COORDINATE_M:g}")
        return a

    if tr["t"].ndim != 1:
        raise bad("t", f"has shape {list(tr['t'].shape)}, expected [steps]")
    s = tr["t"].shape[0]
    if s == 0:
        raise ConfigError("TRACE", "holds no step", shown)
    arr("t", (s,))
    d = tr["p"].shape[1] if tr["p"].ndim == 2 else -1
    if d not in (2, 3):
        raise bad("p", f"has shape {list(tr['p'].shape)}, expected [{s}, 2 or 3]")
    arr("p", (s, d))
    arr("yaw", (s,))
    arr("plan", (s, None, d), values="nan")
    n = tr["obstacle_r"].shape[0] if tr["obstacle_r"].ndim == 1 else -1
    arr("obstacle_r", (n,))
    arr("obstacle_p", (None, n, d))
    if tr["obstacle_p"].shape[0] == 0:
        raise bad("obstacle_p", "holds no step")
    arr("track_mean", (s, n, d), values="nan")
    arr("track_std", (s, n, d), values="nan")
    arr("track_active", (s, n), kinds="b")
    for name in ("arena_lo", "arena_hi", "start", "goal"):
        arr(name, (d,))
    if not np.all(tr["arena_lo"] < tr["arena_hi"]):
        raise bad("arena_lo", "is not below arena_hi on every axis")
    for name in ("dt", "goal_radius", "mav_radius", "range_m", "fov_deg"):
        if arr(name, ()) < 0 or (name in ("dt", "fov_deg") and tr[name] <= 0):
            raise bad(name, f"must be {'> 0' if name in ('dt', 'fov_deg') else '>= 0'} (got {float(tr[name])!r})")
    if d == 3:
        arr("vfov_deg", ())
    arr("outcome", (), kinds="US")
    for name, shape in (("label", ()), ("final_p", (d,)), ("final_yaw", ())):
        if name in tr:
            arr(name, shape, kinds="US" if name == "label" else "fiu")
    if "label" in tr and len(str(tr["label"])) > MAX_LABEL_CHARS:
        raise bad("label", f"is longer than {MAX_LABEL_CHARS} characters ({len(str(tr['label']))})")
    if "static_kind" in tr:
        b = tr["static_kind"].shape[0] if tr["static_kind"].ndim == 1 else -1
        arr("static_kind", (b,), kinds="US")
        for name, shape in (("static_center", (b, d)), ("static_radius", (b,)), ("static_size", (b, d)),
                            ("static_yaw", (b,))):
            if name not in tr:
                raise bad(name, "is missing beside static_kind")
            arr(name, shape)
    for name in ("static_outline", "static_outline_side"):
        if name in tr:
            arr(name, (None, None, 2), values="nan")


MAX_LABEL_CHARS = 1000
"""Longest trace label drawn (pbdyn run --trace writes at most pbdyn.sim.observers.MAX_LABEL_CHARS)."""


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


def _plain_text():
    """matplotlib settings under which a frame is built and drawn: no TeX (whatever the user's matplotlibrc says)."""
    import matplotlib

    return matplotlib.rc_context({"text.usetex": False})


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
        self.title = self.fig.suptitle("", fontsize=10, parse_math=False, usetex=False)
        with _plain_text():
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
        outlines = tr.get("static_outline" if j == 1 else "static_outline_side")
        if outlines is not None and len(outlines):
            from matplotlib.collections import PolyCollection

            polys = [poly[~np.isnan(poly[:, 0])] for poly in outlines]
            ax.add_collection(PolyCollection([q for q in polys if len(q) >= 3], facecolors=COLOURS["static"],
                                             edgecolors=COLOURS["static"], linewidths=0.5, zorder=3))
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
        with _plain_text():
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


class GifStream:
    """An animated GIF (looping) written to the binary file ``fh`` frame by frame, holding one frame in memory.

    Each frame's part that changed since the previous frame is encoded by Pillow as a one-frame GIF (its own
    palette of up to 256 colours) whose image block is copied into the animation, drawn over the previous frame.
    Frame delays are whole 1/100 s chosen so that frame k ends at round(100 k / fps) (the rate holds on average).
    """

    def __init__(self, fh, fps: float):
        self.fh = fh
        self.fps = float(fps)
        self.count = 0
        self.shown_cs = 0                                 # when the last frame written ends, 1/100 s
        self.previous: np.ndarray | None = None

    def append(self, rgb: np.ndarray) -> None:
        """Add the RGB frame [H, W, 3] (uint8; every frame of one size)."""
        from PIL import Image

        h, w = rgb.shape[:2]
        if self.previous is None:
            self.fh.write(b"GIF89a" + struct.pack("<HHBBB", w, h, 0, 0, 0))    # no global colour table
            self.fh.write(b"\x21\xff\x0bNETSCAPE2.0\x03\x01\x00\x00\x00")   # loop for ever
            x0, y0, x1, y1 = 0, 0, w, h
        else:
            changed = np.any(rgb != self.previous, axis=2)
            rows, cols = np.flatnonzero(changed.any(axis=1)), np.flatnonzero(changed.any(axis=0))
            x0, y0, x1, y1 = (0, 0, 1, 1) if rows.size == 0 else (int(cols[0]), int(rows[0]), int(cols[-1]) + 1,
                                                                  int(rows[-1]) + 1)
        buf = io.BytesIO()
        Image.fromarray(np.ascontiguousarray(rgb[y0:y1, x0:x1])).save(buf, format="GIF", interlace=False)
        table, image = _first_image(buf.getvalue())
        self.count += 1
        end = math.floor(100.0 * self.count / self.fps + 0.5)
        delay, self.shown_cs = end - self.shown_cs, end
        self.fh.write(b"\x21\xf9\x04" + struct.pack("<BHBB", 1 << 2, delay, 0, 0))   # disposal: keep the frame
        size_bits = (len(table) // 3).bit_length() - 2          # a table of 2^(n + 1) colours has size bits n
        self.fh.write(b"\x2c" + struct.pack("<HHHHB", x0, y0, x1 - x0, y1 - y0, 0x80 | size_bits) + table + image)
        self.previous = rgb

    def close(self) -> None:
        """End the file (the file object itself is the caller's to close)."""
        self.fh.write(b"\x3b")


def _first_image(blob: bytes) -> tuple[bytes, bytes]:
    """(colour table, image data: the LZW code size and the data sub-blocks with their terminator) of the first
    image of a GIF file (GIF89a: header, logical screen, optional global table, extensions, image descriptor)."""
    flags, pos = blob[10], 13
    table = b""
    if flags & 0x80:
        table, pos = blob[pos:pos + 3 * (2 << (flags & 7))], pos + 3 * (2 << (flags & 7))
    while blob[pos] == 0x21:                         # extensions: a label, then sub-blocks up to an empty one
        pos += 2
        while blob[pos]:
            pos += blob[pos] + 1
        pos += 1
    if blob[pos] != 0x2C:
        raise ValueError("Pillow wrote a GIF without an image")
    iflags, pos = blob[pos + 9], pos + 10
    if iflags & 0x80:
        table, pos = blob[pos:pos + 3 * (2 << (iflags & 7))], pos + 3 * (2 << (iflags & 7))
    start, pos = pos, pos + 1
    while blob[pos]:
        pos += blob[pos] + 1
    return table, blob[start:pos + 1]


def frame_count(n_steps: int, every: int) -> int:
    """Frames written for a trace of n_steps steps at one frame every ``every`` steps (plus the final state)."""
    return len(range(0, n_steps, every)) + 1


def write_replay(trace_path: str | Path, out: str | Path, *, fps: float | None = None,
                 every: int = 1) -> ReplaySummary:
    """Render the trace at ``trace_path`` into ``out`` (.gif, .mp4: one frame every ``every`` steps and the final
    state, at ``fps`` frames per second -- at least MIN_FPS, at most MAX_FPS of the format -- default real time
    1 / (dt every) within those bounds; .png: the final state). ``out`` is checked before the trace is read."""
    suffix = check_output(out)
    if isinstance(every, bool) or not isinstance(every, int) or every < 1:
        raise ConfigError("every", "must be an integer >= 1", every)
    top = MAX_FPS.get(suffix, max(MAX_FPS.values()))
    if fps is not None and (isinstance(fps, bool) or not isinstance(fps, (int, float)) or not math.isfinite(fps)
                            or not MIN_FPS <= fps <= top):
        why = " (a GIF's frame delays are whole 1/100 s; use .mp4 for more)" if suffix == ".gif" else ""
        raise ConfigError("fps", f"must be a number in [{MIN_FPS:g}, {top:g}]{why}", fps)
    out = check_writable_file("out", out)
    trace = load_trace(trace_path)
    rate = float(fps) if fps is not None else min(max(1.0 / (float(trace["dt"]) * every), MIN_FPS), top)
    renderer = Renderer(trace)
    done: dict = {}

    def write(tmp: str) -> None:
        import imageio.v2 as iio

        if suffix == ".png":
            img = renderer.frame(renderer.n_steps)
            iio.imwrite(tmp, img, format="PNG")
            done.update(n=1, shape=img.shape)
        elif suffix == ".gif":
            with open(tmp, "wb") as fh:
                gif = GifStream(fh, rate)
                for img in renderer.frames(every):
                    gif.append(img)
                    done.update(n=done.get("n", 0) + 1, shape=img.shape)
                gif.close()
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
