"""Seeing a trial in PyBullet (`pbdyn run --gui`, `--gui-snapshot`): a camera that frames the arena (or follows the
MAV), the MAV in a bright colour, debug lines for the field of view, the plan and the goal, real-time pacing, and a
headless screenshot through PyBullet's TinyRenderer.

Nothing here changes a trial: markers are visual-only bodies (no collision shape, so rays and contact queries never
see them) created after the trial's last query, debug lines exist only in the GUI, and the MAV's colour is a visual
property.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pbdyn.files import atomic_write

MAV_RGBA = (1.0, 0.75, 0.0, 1.0)        # the MAV, drawn bright so it stands out from the obstacles (red/grey)
GOAL_RGBA = (0.1, 0.75, 0.2, 1.0)
PLAN_RGBA = (0.1, 0.45, 0.95, 1.0)
CAMERA_FOV_DEG = 60.0                   # PyBullet's debug camera and the snapshot's projection
SNAPSHOT_PX = 640
PLAN_SEGMENTS = 24


@dataclass(frozen=True)
class Camera:
    """A camera looking at ``target`` [3] (m) from ``distance`` (m) at ``yaw``/``pitch`` (deg, PyBullet's debug
    camera convention)."""

    target: tuple[float, float, float]
    distance: float
    yaw: float = 0.0
    pitch: float = -89.9


def arena_camera(size, flight_height: float, dims: int, margin: float = 1.08) -> Camera:
    """The camera that shows the whole arena from above: centred on it, far enough that the arena's larger side
    (times ``margin``) fills the vertical field of view CAMERA_FOV_DEG. 3D: looking down at 60 deg so heights show."""
    size = np.asarray(size, dtype=float)
    half = 0.5 * float(max(size[0], size[1])) * margin
    z = flight_height if dims == 2 else 0.5 * float(size[2])
    distance = half / math.tan(math.radians(CAMERA_FOV_DEG / 2.0)) + (0.0 if dims == 2 else 0.5 * float(size[2]))
    pitch = -89.9 if dims == 2 else -60.0
    return Camera((0.5 * float(size[0]), 0.5 * float(size[1]), float(z)), float(distance), 0.0, pitch)


def view_projection(client, camera: Camera, width: int, height: int) -> tuple[list, list]:
    """PyBullet view and projection matrices (column-major lists) of ``camera`` for a width x height image."""
    view = client.computeViewMatrixFromYawPitchRoll(cameraTargetPosition=list(camera.target), distance=camera.distance,
                                                   yaw=camera.yaw, pitch=camera.pitch, roll=0.0, upAxisIndex=2)
    proj = client.computeProjectionMatrixFOV(fov=CAMERA_FOV_DEG, aspect=width / height, nearVal=0.1,
                                             farVal=camera.distance * 3.0 + 100.0)
    return view, proj


def project(view, proj, points, width: int, height: int) -> np.ndarray:
    """Pixel (row, column) [n, 2] of world points [n, 3] in an image rendered with ``view``, ``proj``."""
    v = np.asarray(view, dtype=float).reshape(4, 4).T
    p = np.asarray(proj, dtype=float).reshape(4, 4).T
    pts = np.c_[np.asarray(points, dtype=float).reshape(-1, 3), np.ones(len(points))]
    clip = (p @ v @ pts.T).T
    ndc = clip[:, :3] / clip[:, 3:4]
    col = (ndc[:, 0] + 1.0) * 0.5 * width
    row = (1.0 - ndc[:, 1]) * 0.5 * height
    return np.c_[row, col]


def highlight_mav(world) -> None:
    """Draw the MAV in MAV_RGBA (every link), and in 3D make the ceiling see-through (a visual change only)."""
    c = world.client
    for link in range(-1, c.getNumJoints(world.mav_id)):
        c.changeVisualShape(world.mav_id, link, rgbaColor=list(MAV_RGBA))
    if world.dims == 3:
        top = float(world.arena_size[2])
        for wall in world.wall_ids.tolist():
            if c.getAABB(wall)[0][2] >= top - 1e-6:
                c.changeVisualShape(wall, -1, rgbaColor=[0.6, 0.6, 0.62, 0.0])


class GuiView:
    """Observer of a GUI trial: frames the arena (or, with ``follow``, keeps the MAV in the middle), draws the field
    of view, the plan and the goal as debug lines, and paces the trial to real time (the wall clock, not a sleep
    added to each step's compute)."""

    def __init__(self, dt: float, *, follow: bool = False, real_time: bool = True):
        self.dt = float(dt)
        self.follow = follow
        self.real_time = real_time
        self.items: dict[str, int] = {}
        self.t0 = None
        self.steps = 0
        self.slept = 0.0          # s of wall clock spent waiting for real time (the rest of the trial is compute)

    def _line(self, client, name: str, a, b, rgba, width: float = 2.0) -> None:
        old = self.items.get(name, -1)
        self.items[name] = client.addUserDebugLine(list(map(float, a)), list(map(float, b)), list(rgba[:3]),
                                                   lineWidth=width, replaceItemUniqueId=old)

    def start(self, state) -> None:
        world = state.world
        c = world.client
        sc = state.spec.scenario
        highlight_mav(world)
        cam = arena_camera(sc.world.size, world.flight_height, state.dims)
        focal = float(c.getDebugVisualizerCamera()[3][5]) if c.getConnectionInfo()["connectionMethod"] == 1 else 0.0
        if focal > 0.0:       # the window's own vertical field of view: fit the arena to it (GUI connection = 1)
            scale = focal * math.tan(math.radians(CAMERA_FOV_DEG / 2.0))
            cam = Camera(cam.target, cam.distance * scale, cam.yaw, cam.pitch)
        c.resetDebugVisualizerCamera(cam.distance, cam.yaw, cam.pitch, list(cam.target))
        g = world.to_world3(state.goal)
        r = float(state.goal_radius)
        for k, (dx, dy) in enumerate(((r, 0.0), (0.0, r))):
            self._line(c, f"goal{k}", g - [dx, dy, 0.0], g + [dx, dy, 0.0], GOAL_RGBA, 4.0)
        self._line(c, "goal_post", g, g + [0.0, 0.0, 3.0], GOAL_RGBA, 4.0)
        self.disc = _disc(c, world.to_world3(state.position), world.mav_radius, MAV_RGBA)
        self.t0 = time.perf_counter()

    def on_step(self, state, agent, decision, record) -> None:
        world = state.world
        c = world.client
        if self.t0 is None:
            self.start(state)
        p = world.to_world3(state.position)
        c.resetBasePositionAndOrientation(self.disc, p.tolist(), [0.0, 0.0, 0.0, 1.0])
        rng, half = float(state.spec.scenario.sensor.range), math.radians(min(float(state.fov_deg), 359.9)) / 2.0
        for k, side in enumerate((-1.0, 1.0)):
            a = state.yaw + side * half
            self._line(c, f"fov{k}", p, p + rng * np.array([math.cos(a), math.sin(a), 0.0]), (0.3, 0.6, 1.0, 1.0))
        traj = getattr(agent, "trajectory", None)
        plan = world.to_world3(traj.remaining(state.t).p) if traj is not None else p[None]
        idx = np.unique(np.linspace(0, plan.shape[0] - 1, min(PLAN_SEGMENTS + 1, plan.shape[0])).astype(int))
        for k in range(PLAN_SEGMENTS):                    # the plan as polyline segments (debug items are reused)
            a, b = (plan[idx[k]], plan[idx[k + 1]]) if k + 1 < idx.shape[0] else (p, p)
            self._line(c, f"plan{k}", a, b, PLAN_RGBA, 3.0)
        if self.follow:
            cam = c.getDebugVisualizerCamera()
            c.resetDebugVisualizerCamera(cam[10], cam[8], cam[9], p.tolist())
        self.pace(state.done)

    def pace(self, done: bool) -> None:
        """Count a step and, in real time, sleep until the wall clock reaches steps x dt since the start (a step's own
        compute time is part of its dt, not added to it)."""
        if self.t0 is None:
            self.t0 = time.perf_counter()
        self.steps += 1
        if self.real_time and not done:
            wait = self.t0 + self.steps * self.dt - time.perf_counter()
            if wait > 0:
                time.sleep(wait)
                self.slept += wait

    def on_end(self, state, agent) -> None:
        pass


class Snapshot:
    """Observer that writes a screenshot of the trial's final state to ``path`` (.png) with PyBullet's TinyRenderer
    (no display needed): the arena framed from above, the MAV in MAV_RGBA, the goal as a green sphere, the last plan
    as blue beads. ``image`` holds the RGB array [H, W, 3] afterwards, ``view``/``proj`` its matrices."""

    def __init__(self, path: str | Path, size: int = SNAPSHOT_PX):
        self.path = Path(path)
        self.size = int(size)
        self.image = None
        self.view = self.proj = None

    def on_step(self, state, agent, decision, record) -> None:
        self.last = (getattr(agent, "trajectory", None), record.t)   # the plan in execution and when: drawn at the end

    def on_end(self, state, agent) -> None:
        world = state.world
        c = world.client
        world.set_mav_pose(state.position, state.yaw)
        highlight_mav(world)
        markers = [_marker(c, world.to_world3(state.goal), max(0.6, 0.6 * float(state.goal_radius)), GOAL_RGBA),
                   _disc(c, world.to_world3(state.position), world.mav_radius, MAV_RGBA)]
        traj, t = getattr(self, "last", (None, 0.0))
        plan = None if traj is None else traj.remaining(t).p
        if plan is not None and plan.shape[0] > 1:
            for q in world.to_world3(plan[1::max(1, plan.shape[0] // 8)]):
                markers.append(_marker(c, q, 0.3, PLAN_RGBA))
        try:
            cam = arena_camera(state.spec.scenario.world.size, world.flight_height, state.dims)
            self.view, self.proj = view_projection(c, cam, self.size, self.size)
            _, _, rgba, _, _ = c.getCameraImage(self.size, self.size, self.view, self.proj,
                                                renderer=c.ER_TINY_RENDERER)
            self.image = np.asarray(rgba, dtype=np.uint8).reshape(self.size, self.size, 4)[:, :, :3].copy()
        finally:
            for m in markers:
                c.removeBody(m)
        write_png(self.path, self.image)


def _marker(client, position, radius: float, rgba) -> int:
    """A visual-only sphere (no collision shape: rays and contact queries never meet it)."""
    vs = client.createVisualShape(client.GEOM_SPHERE, radius=float(radius), rgbaColor=list(rgba))
    return client.createMultiBody(baseMass=0.0, baseCollisionShapeIndex=-1, baseVisualShapeIndex=vs,
                                  basePosition=list(map(float, position)))


def _disc(client, position, radius: float, rgba) -> int:
    """A visual-only flat disc (radius m, 0.2 m thick) marking the MAV from above."""
    vs = client.createVisualShape(client.GEOM_CYLINDER, radius=float(radius), length=0.2, rgbaColor=list(rgba))
    return client.createMultiBody(baseMass=0.0, baseCollisionShapeIndex=-1, baseVisualShapeIndex=vs,
                                  basePosition=list(map(float, position)))


def write_png(path: Path, image: np.ndarray) -> None:
    """Write an RGB image as PNG, atomically."""
    import imageio.v2 as iio

    atomic_write(path, lambda tmp: iio.imwrite(tmp, image, format="PNG"))
