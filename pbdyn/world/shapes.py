"""The real shapes of imported bodies as signed-distance fields (docs/scenarios.md "Imported worlds").

A body's collision geometry is read from its URDF (every link's <collision> elements, links placed by their joint
origins at joint position 0, i.e. "joints stay fixed"), scaled as pbdyn.world.imported.urdf_loading scales it,
and expressed in the frame PyBullet calls the body's base: the root link's inertial frame. Signed distances
(m, negative inside) are exact closed forms for URDF boxes, spheres and cylinders; <mesh> geometry goes through
open3d's RaycastingScene (imported lazily; meshes must be closed for the sign to be meaningful). PyBullet itself
collides a URDF mesh through its convex hull, so the two agree for convex meshes.

Everything is vectorised over points; a ShapeField evaluates many points at many rollout steps in one call.
A moving body's bounding sphere (bounding_sphere) is the disc/ball trackers, planners and the analytic
backends see of it; outlines of the still bodies are drawn by replays (still_body_outlines).
"""

from __future__ import annotations

import itertools
import math
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pbdyn.errors import ConfigError
from pbdyn.urdf import check_urdf
from pbdyn.usercode import stdout_fd_to

PRIMITIVES = ("box", "sphere", "cylinder", "mesh")


# ------------------------------------------------------------------------------------------------ rotations
def quat_from_rpy(rpy) -> np.ndarray:
    """Quaternion xyzw [4] of URDF/PyBullet roll-pitch-yaw (rad): R = Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = (0.5 * float(a) for a in rpy)
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array([sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
                     cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy])


def rotation_from_quat(q) -> np.ndarray:
    """Rotation matrices [..., 3, 3] of unit quaternions xyzw [..., 4]."""
    q = np.asarray(q, dtype=float)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    out = np.empty(q.shape[:-1] + (3, 3))
    out[..., 0, 0] = 1 - 2 * (y * y + z * z)
    out[..., 0, 1] = 2 * (x * y - z * w)
    out[..., 0, 2] = 2 * (x * z + y * w)
    out[..., 1, 0] = 2 * (x * y + z * w)
    out[..., 1, 1] = 1 - 2 * (x * x + z * z)
    out[..., 1, 2] = 2 * (y * z - x * w)
    out[..., 2, 0] = 2 * (x * z - y * w)
    out[..., 2, 1] = 2 * (y * z + x * w)
    out[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return out


def _transform(xyz, rpy) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = rotation_from_quat(quat_from_rpy(rpy))
    t[:3, 3] = np.asarray(xyz, dtype=float)
    return t


def _origin(elem) -> np.ndarray:
    o = elem.find("origin") if elem is not None else None
    if o is None:
        return np.eye(4)
    xyz = [float(v) for v in o.get("xyz", "0 0 0").split()]
    rpy = [float(v) for v in o.get("rpy", "0 0 0").split()]
    return _transform(xyz, rpy)


# ------------------------------------------------------------------------------------------------ primitives
@dataclass(frozen=True)
class Primitive:
    """One collision element in its body's base frame.

    kind: box | sphere | cylinder | mesh. size: box full extents [3] (m); radius (sphere, cylinder; m); length
    (cylinder along its local z; m); mesh: file path and per-axis scale [3]. pose: 4x4 transform primitive -> base.
    """

    kind: str
    pose: np.ndarray
    size: tuple[float, float, float] = (0.0, 0.0, 0.0)
    radius: float = 0.0
    length: float = 0.0
    mesh: str = ""
    mesh_scale: tuple[float, float, float] = (1.0, 1.0, 1.0)

    def local_sdf(self, x: np.ndarray) -> np.ndarray:
        """Signed distance (m) of points [K, 3] given in this primitive's own frame."""
        if self.kind == "sphere":
            return np.sqrt(np.einsum("ij,ij->i", x, x)) - self.radius
        if self.kind == "box":
            q = np.abs(x) - 0.5 * np.asarray(self.size)
            return np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)
        if self.kind == "cylinder":
            d = np.stack([np.hypot(x[:, 0], x[:, 1]) - self.radius, np.abs(x[:, 2]) - 0.5 * self.length], axis=1)
            return np.linalg.norm(np.maximum(d, 0.0), axis=1) + np.minimum(d.max(axis=1), 0.0)
        return _mesh_scene(self.mesh, self.mesh_scale).signed_distance(x)

    def local_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Exact axis-aligned bounds (lo [3], hi [3]) of the primitive in the base frame (m)."""
        rot, t = self.pose[:3, :3], self.pose[:3, 3]
        if self.kind == "sphere":
            half = np.full(3, self.radius)
        elif self.kind == "box":
            half = np.abs(rot) @ (0.5 * np.asarray(self.size))
        elif self.kind == "cylinder":
            axis = rot[:, 2]
            half = self.radius * np.sqrt(np.maximum(1.0 - axis * axis, 0.0)) + 0.5 * self.length * np.abs(axis)
        else:
            v = _mesh_scene(self.mesh, self.mesh_scale).vertices @ rot.T + t
            return v.min(axis=0), v.max(axis=0)
        return t - half, t + half

    def reach(self, centre: np.ndarray, planar: bool) -> float:
        """The largest distance (m) from ``centre`` [3] (base frame) to a point of the primitive: in 3D, or with
        ``planar`` in the x-y plane only (the body's footprint, for yaw-only 2D bodies). Exact for spheres, boxes
        and meshes (their vertices); cylinders from 720 points per rim circle plus the sampling's worst case."""
        rot, t = self.pose[:3, :3], self.pose[:3, 3]
        k = 2 if planar else 3

        def far(pts: np.ndarray) -> float:
            d = pts[:, :k] - centre[None, :k]
            return float(np.sqrt(np.max(np.einsum("ij,ij->i", d, d))))

        if self.kind == "sphere":
            return float(np.linalg.norm((t - centre)[:k])) + self.radius
        if self.kind == "box":
            signs = np.array(list(itertools.product((-0.5, 0.5), repeat=3)))
            return far(t[None, :] + (signs * np.asarray(self.size)[None, :]) @ rot.T)
        if self.kind == "cylinder":
            th = np.linspace(0.0, 2.0 * math.pi, 720, endpoint=False)
            ring = np.stack([self.radius * np.cos(th), self.radius * np.sin(th), np.zeros_like(th)], axis=1)
            rims = np.concatenate([ring + [0.0, 0.0, z] for z in (-0.5 * self.length, 0.5 * self.length)])
            slack = self.radius * (1.0 - math.cos(math.pi / 720)) / math.cos(math.pi / 720)
            return far(t[None, :] + rims @ rot.T) + slack
        v = _mesh_scene(self.mesh, self.mesh_scale).vertices @ rot.T + t
        return far(v)

    def volume(self) -> float:
        """Exact volume (m^3): box product of extents, sphere 4/3 pi r^3, cylinder pi r^2 L, mesh open3d's volume of
        the closed mesh."""
        if self.kind == "sphere":
            return 4.0 / 3.0 * math.pi * self.radius ** 3
        if self.kind == "box":
            return float(np.prod(self.size))
        if self.kind == "cylinder":
            return math.pi * self.radius ** 2 * self.length
        return _mesh_scene(self.mesh, self.mesh_scale).volume


class _MeshScene:
    """An open3d RaycastingScene of one closed triangle mesh (float32 queries)."""

    def __init__(self, path: str, scale: tuple[float, float, float]):
        import open3d as o3d  # lazy: only worlds with <mesh> geometry need it

        o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)  # its warnings off the terminal
        with stdout_fd_to(2):   # open3d prints its read warnings on stdout
            mesh = o3d.io.read_triangle_mesh(path)
        if len(mesh.triangles) == 0:
            raise ConfigError("mesh", "has no triangles (or cannot be read)", path)
        v = np.asarray(mesh.vertices, dtype=float) * np.asarray(scale, dtype=float)
        mesh.vertices = o3d.utility.Vector3dVector(v)
        self.vertices = v
        self.volume = float(abs(mesh.get_volume())) if mesh.is_watertight() else float("nan")
        self._o3d = o3d
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))

    def signed_distance(self, x: np.ndarray) -> np.ndarray:
        pts = self._o3d.core.Tensor(np.ascontiguousarray(x, dtype=np.float32))
        return self.scene.compute_signed_distance(pts).numpy().astype(float)


_MESHES: dict[tuple, _MeshScene] = {}


def _mesh_scene(path: str, scale: tuple[float, float, float]) -> _MeshScene:
    key = (path, tuple(scale))
    if key not in _MESHES:
        _MESHES[key] = _MeshScene(path, scale)
    return _MESHES[key]


def _floats(text: str | None, n: int, default: float) -> list[float]:
    if text is None:
        return [default] * n
    vals = [float(v) for v in text.split()]
    return vals if len(vals) == n else [vals[0]] * n


def body_primitives(urdf: str | Path, scale: Sequence[float], field: str = "urdf") -> tuple[Primitive, ...]:
    """The collision primitives of the URDF at ``urdf`` scaled by ``scale`` (sx, sy, sz), in its base frame.

    ConfigError naming ``field`` for a missing or unreadable file, an unknown geometry or no collision geometry, or
    any geometry pbdyn.urdf.check_urdf refuses (non-positive or non-finite sizes, bad origins, ...).
    """
    from pbdyn.world.imported.urdf_loading import scale_urdf_text   # (imports PyBullet: only when reading a URDF)

    path = Path(urdf)
    check_urdf(path, field, tuple(scale))
    try:
        root = ET.fromstring(scale_urdf_text(path.read_text(encoding="utf-8"), tuple(scale), path.parent))
    except (ET.ParseError, ValueError, UnicodeDecodeError) as exc:
        raise ConfigError(field, f"cannot read the URDF ({' '.join(str(exc).split())})", str(urdf)) from None
    links = {link.get("name"): link for link in root.findall("link")}
    children: dict[str, list] = {}
    child_names = set()
    for joint in root.findall("joint"):
        parent, child = joint.find("parent"), joint.find("child")
        if parent is None or child is None:
            continue
        children.setdefault(parent.get("link"), []).append((child.get("link"), _origin(joint)))
        child_names.add(child.get("link"))
    roots = [name for name in links if name not in child_names]
    if len(roots) != 1:
        raise ConfigError(field, "must have exactly one root link", str(urdf))
    base_inertial = _origin(links[roots[0]].find("inertial"))
    to_base = np.linalg.inv(base_inertial)
    prims: list[Primitive] = []
    stack = [(roots[0], np.eye(4))]
    while stack:
        name, link_pose = stack.pop(0)
        link = links.get(name)
        if link is None:
            continue
        for coll in link.findall("collision"):
            geom = coll.find("geometry")
            if geom is None or len(geom) == 0:
                continue
            shape = geom[0]
            pose = to_base @ link_pose @ _origin(coll)
            if shape.tag == "box":
                prims.append(Primitive("box", pose, size=tuple(_floats(shape.get("size"), 3, 1.0))))
            elif shape.tag == "sphere":
                prims.append(Primitive("sphere", pose, radius=float(shape.get("radius", "1"))))
            elif shape.tag == "cylinder":
                prims.append(Primitive("cylinder", pose, radius=float(shape.get("radius", "1")),
                                       length=float(shape.get("length", "1"))))
            elif shape.tag == "mesh":
                mesh_file = shape.get("filename", "")
                if not Path(mesh_file).is_file():
                    raise ConfigError(field, f"mesh file not found: {mesh_file}", str(urdf))
                prims.append(Primitive("mesh", pose, mesh=mesh_file,
                                       mesh_scale=tuple(_floats(shape.get("scale"), 3, 1.0))))
            else:
                raise ConfigError(field, f"unsupported collision geometry <{shape.tag}>", str(urdf))
        for child, joint_pose in children.get(name, []):
            stack.append((child, link_pose @ joint_pose))
    if not prims:
        raise ConfigError(field, "has no collision geometry (a body needs at least one <collision> shape)",
                          str(urdf))
    return tuple(prims)


def body_sdf(prims: Sequence[Primitive], x_base: np.ndarray) -> np.ndarray:
    """Signed distance (m) of points [K, 3] in the base frame to the union of ``prims`` (min over primitives)."""
    out = np.full(x_base.shape[0], np.inf)
    for p in prims:
        rot, t = p.pose[:3, :3], p.pose[:3, 3]
        out = np.minimum(out, p.local_sdf((x_base - t) @ rot))
    return out


def bounds_of(prims: Sequence[Primitive]) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounds (lo [3], hi [3]) of a body's primitives in its base frame (m)."""
    los, his = zip(*(p.local_bounds() for p in prims))
    return np.min(los, axis=0), np.max(his, axis=0)


BOUNDING_RULE = "farthest-point-1"
"""Version of the bounding-sphere rule (bounding_sphere), part of every body's fingerprint
(pbdyn.world.imported.bodies.bodies_fingerprint): rollouts and trials of imported worlds made with another rule are
never reused."""


def bounding_sphere(prims: Sequence[Primitive], dims: int, yaw_only: bool, where: str,
                    max_m: float) -> tuple[np.ndarray, float]:
    """(centre [3] in the base frame (m), radius m) of a body's bounding sphere (2D worlds, bodies that only ever turn
    about z: the bounding circle of their footprint, the disc covering their cut by the flight plane): centred on
    the bounding box of ``prims``, the radius reaching the farthest point of the real shape (a sphere's own radius,
    not its box's half-diagonal), at least 1e-6 m. ConfigError naming ``where`` for geometry that is not finite or
    whose radius exceeds ``max_m`` (m)."""
    lo, hi = bounds_of(prims)
    with np.errstate(all="ignore"):      # non-finite or huge geometry: reported below, not as RuntimeWarnings
        centre = 0.5 * (lo + hi)
        finite = bool(np.all(np.isfinite(centre)) and np.all(np.isfinite(hi - lo)))
        radius = max(p.reach(centre, dims == 2 and yaw_only) for p in prims) if finite else float("inf")
    if not (np.all(np.isfinite(centre)) and math.isfinite(radius) and radius <= max_m):
        raise ConfigError(where, f"the body's collision geometry (scaled) must have a finite size of at most "
                          f"{max_m:g} m (bounding box {lo.tolist()} .. {hi.tolist()} m)", None,
                          show_value=False)
    return centre, max(radius, 1e-6)


# ------------------------------------------------------------------------------------------------ outlines
OUTLINE_SEGMENTS = 48
"""Points per circle in the outlines of spheres and cylinders."""


def _convex_points(prim: Primitive) -> np.ndarray:
    """Points [K, 3] in the base frame whose convex hull is the primitive (not a sphere): a box's corners, a
    cylinder's two rims, a mesh's vertices (PyBullet collides a mesh as its convex hull)."""
    rot, t = prim.pose[:3, :3], prim.pose[:3, 3]
    if prim.kind == "box":
        local = np.array(list(itertools.product((-0.5, 0.5), repeat=3))) * np.asarray(prim.size)
    elif prim.kind == "cylinder":
        th = np.linspace(0.0, 2.0 * math.pi, OUTLINE_SEGMENTS, endpoint=False)
        ring = np.stack([prim.radius * np.cos(th), prim.radius * np.sin(th), np.zeros_like(th)], axis=1)
        local = np.concatenate([ring + [0.0, 0.0, z] for z in (-0.5 * prim.length, 0.5 * prim.length)])
    else:
        local = np.asarray(_mesh_scene(prim.mesh, prim.mesh_scale).vertices, dtype=float)
    return local @ rot.T + t


def _hull(points: np.ndarray) -> np.ndarray | None:
    """The convex hull's vertices of points [K, 2] or [K, 3] (2D: counter-clockwise); None if they span no area
    (volume)."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        return points[ConvexHull(points).vertices]
    except (QhullError, ValueError):
        return None


def body_outlines(field: ShapeField, b: int, axes: tuple[int, int], cut_z: float | None = None,
                  step: int = 0) -> list[np.ndarray]:
    """Outlines [V, 2] (world, m) of body b's collision elements at ``step`` in the plane of world ``axes`` ((0, 1):
    x-y, (0, 2): x-z): each element's projection, or with ``cut_z`` its cut by the plane z = cut_z (axes x-y;
    elements that do not reach the plane give none)."""
    rot, pos = field.rot[step, b], field.bodies.position[step, b]
    ax = list(axes)
    out = []
    for prim in field.prims[b]:
        if prim.kind == "sphere":
            c, r = pos + rot @ prim.pose[:3, 3], prim.radius
            if cut_z is not None:
                if abs(cut_z - c[2]) >= r:
                    continue
                r = math.sqrt(r * r - (cut_z - c[2]) ** 2)
            th = np.linspace(0.0, 2.0 * math.pi, OUTLINE_SEGMENTS, endpoint=False)
            out.append(np.c_[c[ax[0]] + r * np.cos(th), c[ax[1]] + r * np.sin(th)])
            continue
        pts = _convex_points(prim) @ rot.T + pos
        if len(pts) > 64:                                  # a mesh: its hull's vertices suffice
            hull = _hull(pts)
            pts = pts if hull is None else hull
        if cut_z is not None:      # the cut of a convex hull: where its points' connecting segments cross the plane
            lo, hi = pts[pts[:, 2] <= cut_z], pts[pts[:, 2] >= cut_z]
            if not len(lo) or not len(hi):
                continue
            a, d = lo[:, None, :], hi[None, :, :] - lo[:, None, :]
            s = np.divide(cut_z - a[..., 2], d[..., 2], out=np.zeros(d.shape[:2]), where=d[..., 2] > 0)
            pts = (a + s[..., None] * d).reshape(-1, 3)
        poly = _hull(pts[:, ax])
        if poly is not None:
            out.append(poly)
    return out


def still_body_outlines(bodies, dims: int, flight_height: float) -> dict[str, np.ndarray]:
    """The outlines of an imported world's still (static) bodies, NaN-padded to one array [P, V, 2] (m) per view:
    "static_outline" -- 2D: their cut by the flight plane z = flight_height, 3D: their top view (x-y projection) --
    and in 3D "static_outline_side" (x-z projection). Empty arrays [0, 0, 2] when there is none."""
    field = None if bodies is None or bool(np.all(bodies.moving)) else bodies.field()
    views = {"static_outline": ((0, 1), flight_height if dims == 2 else None)}
    if dims == 3:
        views["static_outline_side"] = ((0, 2), None)
    out = {}
    for key, (axes, cut) in views.items():
        polys = [] if field is None else [poly for b in field.indices("static")
                                          for poly in body_outlines(field, b, axes, cut)]
        arr = np.full((len(polys), max([0] + [len(p) for p in polys]), 2), np.nan)
        for i, poly in enumerate(polys):
            arr[i, :len(poly)] = poly
        out[key] = arr
    return out


# ------------------------------------------------------------------------------------------------ fields
class ShapeField:
    """Signed distances to the imported bodies of a rollout at its steps.

    bodies: a pbdyn.world.imported.bodies.WorldBodies (base positions [T, B, 3], orientations [T, B, 4], URDF paths and
    scales). Distances are 3D Euclidean from points [K, 3] (2D worlds: points in the flight plane z = h).
    """

    def __init__(self, bodies):
        self.bodies = bodies
        self.prims = [body_primitives(u, s, f"bodies[{i}].urdf")
                      for i, (u, s) in enumerate(zip(bodies.urdf, bodies.scale.tolist()))]
        self.rot = rotation_from_quat(bodies.orientation)            # [T, B, 3, 3]

    def indices(self, which: str) -> list[int]:
        """Body indices: "all", "static" or "moving"."""
        moving = self.bodies.moving
        if which == "all":
            return list(range(len(self.prims)))
        if which == "static":
            return [i for i in range(len(self.prims)) if not moving[i]]
        return [i for i in range(len(self.prims)) if moving[i]]

    def body_distance(self, b: int, points3: np.ndarray, steps) -> np.ndarray:
        """Signed distance (m) of points [K, 3] to body b at rollout steps (an int or int [K])."""
        steps = np.asarray(steps)
        p = self.bodies.position[steps, b]                            # [3] or [K, 3]
        rot = self.rot[steps, b]                                      # [3, 3] or [K, 3, 3]
        rel = points3 - p
        local = rel @ rot if steps.ndim == 0 else np.einsum("kj,kji->ki", rel, rot)
        return body_sdf(self.prims[b], local)

    def distance(self, points3, steps=0, which: str = "all") -> np.ndarray:
        """Signed distance (m) of points [K, 3] to the nearest body of ``which`` at ``steps``; +inf with none."""
        pts = np.asarray(points3, dtype=float).reshape(-1, 3)
        out = np.full(pts.shape[0], np.inf)
        for b in self.indices(which):
            out = np.minimum(out, self.body_distance(b, pts, steps))
        return out

    def world_bounds(self, b: int, step: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """World axis-aligned bounds (lo [3], hi [3]) of body b at ``step`` (m)."""
        lo, hi = bounds_of(self.prims[b])
        c, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
        rot = self.rot[step, b]
        centre = self.bodies.position[step, b] + rot @ c
        ext = np.abs(rot) @ half
        return centre - ext, centre + ext

    def march(self, origins3: np.ndarray, dirs3: np.ndarray, inflate: float, max_dist: np.ndarray, step: int,
              which: str = "all", tol: float = 1e-4, max_iter: int = 400) -> np.ndarray:
        """Distance (m) along each ray (origins [K, 3], unit dirs [K, 3]) until the ball of radius ``inflate``
        around the moving point touches a body (sphere tracing on the exact field, to ``tol``), capped at max_dist
        [K]; 0 for a ray that starts in contact."""
        t = np.zeros(origins3.shape[0])
        active = np.arange(origins3.shape[0])
        for _ in range(max_iter):
            if active.size == 0:
                break
            d = self.distance(origins3[active] + t[active, None] * dirs3[active], step, which) - inflate
            done = d <= tol
            t[active] = np.where(done, t[active], t[active] + d)
            over = t[active] >= max_dist[active]
            t[active[over]] = max_dist[active[over]]
            active = active[~(done | over)]
        return np.minimum(t, max_dist)
