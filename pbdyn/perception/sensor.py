"""The depth sensor's geometry (thesis 2-4-2, Fig. 2-4): ray fans and the field-of-view predicate.

2D: a sector of half-angle fov/2 around the yaw, radius range. 3D: an azimuth x elevation window of fov x vfov
centred on (yaw, elevation 0) -- the same angular window the ray grid covers. Angles in degrees are sensor
parameters (TOML ``*_deg``); yaw is in radians, counter-clockwise from world +x.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from pbdyn.world.geometry import wrap_angle


def _fan(fov_deg: float, resolution_deg: float, rays: int | None = None) -> np.ndarray:
    """Angles (rad, relative to the centre) of a fan: round(fov/res)+1 rays edge to edge, or round(360/res) for 360;
    with ``rays``: that many rays, edge to edge (one: the centre), or evenly spaced for 360."""
    if fov_deg <= 0 or resolution_deg <= 0:
        raise ValueError(f"fov_deg and resolution_deg must be > 0 (got {fov_deg}, {resolution_deg})")
    if rays is not None and rays < 1:
        raise ValueError(f"rays must be >= 1 (got {rays})")
    if fov_deg >= 360.0:
        n = max(1, int(round(360.0 / resolution_deg))) if rays is None else rays
        return -math.pi + 2.0 * math.pi * np.arange(n) / n
    n = int(round(fov_deg / resolution_deg)) + 1 if rays is None else rays
    half = math.radians(fov_deg) / 2.0
    return np.linspace(-half, half, n) if n > 1 else np.zeros(1)


@functools.lru_cache(maxsize=64)
def _base_directions(fov_deg: float, resolution_deg: float, dims: int, vfov_deg: float | None,
                     vresolution_deg: float | None, rays: int | None = None) -> np.ndarray:
    az = _fan(fov_deg, resolution_deg, rays)
    if dims == 2:
        out = np.stack([np.cos(az), np.sin(az)], axis=-1)
    else:
        if vfov_deg is None or vresolution_deg is None:
            raise ValueError("a 3D sensor needs vfov_deg and vresolution_deg")
        if vfov_deg <= 0 or vfov_deg > 180 or vresolution_deg <= 0:
            raise ValueError(f"vfov_deg must be in (0, 180] and vresolution_deg > 0 "
                             f"(got {vfov_deg}, {vresolution_deg})")
        n_el = int(round(vfov_deg / vresolution_deg)) + 1
        half = math.radians(vfov_deg) / 2.0
        el = np.linspace(-half, half, n_el) if n_el > 1 else np.zeros(1)
        a, e = np.meshgrid(az, el, indexing="ij")  # rays ordered azimuth-major
        out = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=-1).reshape(-1, 3)
    out.setflags(write=False)
    return out


def ray_directions(yaw: float, fov_deg: float, resolution_deg: float, dims: int, vfov_deg: float | None = None,
                   vresolution_deg: float | None = None, rays: int | None = None) -> np.ndarray:
    """Unit ray directions [R, d] (world frame) of a sensor looking along ``yaw`` (rad).

    2D: n = round(fov/res) + 1 rays from yaw - fov/2 to yaw + fov/2 inclusive; fov >= 360: round(360/res) rays
    with no duplicate. ``rays`` given: n = rays instead (the marching sensor's count). 3D: the azimuth fan above x
    n_el = round(vfov/vres) + 1 elevations in [-vfov/2, vfov/2], azimuth-major. The yaw-independent fan is cached;
    only the rotation by yaw is computed per call.
    """
    if dims not in (2, 3):
        raise ValueError(f"dims must be 2 or 3 (got {dims})")
    base = _base_directions(float(fov_deg), float(resolution_deg), int(dims),
                            None if vfov_deg is None else float(vfov_deg),
                            None if vresolution_deg is None else float(vresolution_deg),
                            None if rays is None else int(rays))
    c, s = math.cos(yaw), math.sin(yaw)
    out = np.empty_like(base)
    out[:, 0] = c * base[:, 0] - s * base[:, 1]
    out[:, 1] = s * base[:, 0] + c * base[:, 1]
    if dims == 3:
        out[:, 2] = base[:, 2]
    return out


def in_fov(yaw: float, points_rel, fov_deg: float, range_m: float, vfov_deg: float | None = None) -> np.ndarray:
    """True for each point [K, d] (relative to the sensor, m) that a sensor looking along ``yaw`` (rad) covers.

    2D: within range_m and within fov/2 of the yaw (a sector; fov >= 360 is a disc). 3D: within range_m, azimuth
    within fov/2 of the yaw and elevation within vfov/2 of the horizontal (vfov None: no elevation limit).
    The sensor's own position (distance 0) counts as covered. Bounds are inclusive.
    """
    pts = np.asarray(points_rel, dtype=float)
    if pts.ndim == 1:
        pts = pts[None, :]
    d = pts.shape[-1]
    dist2 = np.sum(pts * pts, axis=-1)
    ok = dist2 <= float(range_m) ** 2
    if fov_deg < 360.0:
        bearing = np.arctan2(pts[..., 1], pts[..., 0]) - yaw
        off = np.abs(wrap_angle(bearing))
        ok &= off <= math.radians(fov_deg) / 2.0 + 1e-12
    if d == 3 and vfov_deg is not None:
        elev = np.arctan2(pts[..., 2], np.hypot(pts[..., 0], pts[..., 1]))
        ok &= np.abs(elev) <= math.radians(vfov_deg) / 2.0 + 1e-12
    return ok | (dist2 == 0.0)
