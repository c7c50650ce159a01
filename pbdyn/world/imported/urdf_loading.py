"""URDF files loaded into PyBullet, scaled per axis (docs/scenarios.md "Imported worlds"): the project's own models
(urdf_path), the rewriting of a URDF's geometry for a scale (scale_urdf_text; pbdyn.world.shapes reads the same
scaled text, so the shapes pbdyn measures are the ones PyBullet collides) and loading the result (load_scaled_urdf).
A scenario's URDFs are validated when it is loaded (pbdyn.urdf.check_urdf).
"""

from __future__ import annotations

import functools
import math
import os
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from pbdyn import resources
from pbdyn.errors import ConfigError
from pbdyn.urdf import MAX_LINE_BYTES, check_urdf
from pbdyn.world.pybullet_client import pybullet, stdout_to_stderr

IDENTITY_QUATERNION = (0.0, 0.0, 0.0, 1.0)
"""The identity orientation (x, y, z, w)."""


def urdf_path(name: str) -> str:
    """Absolute path of one of the project's URDF models (unit size, scaled at load), e.g. ``urdf_path("pillar")``."""
    return str(resources.urdf_path(name))


def _floats(text: str) -> np.ndarray:
    return np.array([float(x) for x in text.split()], dtype=float)


def _fmt(values) -> str:
    return " ".join(repr(float(v)) for v in values)


def scale_urdf_text(text: str, scale_xyz: Sequence[float], base_dir: str | Path | None = None, *,
                    cylinders_as_spheres: bool = False) -> str:
    """Rewrite URDF text so its geometry is scaled per axis by ``scale_xyz`` = (sx, sy, sz).

    Scales <box size>, <cylinder radius> (by sx; needs sx == sy) and <cylinder length> (by sz), <sphere radius>
    (needs sx == sy == sz), <mesh scale>, and every <origin xyz>. Relative mesh filenames are made absolute against
    ``base_dir`` so the text can be loaded from anywhere. Masses and inertias are kept. Origins with a rotation are
    only exact under uniform scale. ``cylinders_as_spheres`` turns each *collision* cylinder into the sphere of its
    (scaled) radius at the same origin (the 2D slice-equivalent shape; see pbdyn.world.bullet's docstring).
    Raises ValueError on a scale the geometry cannot take.
    """
    s = np.asarray(scale_xyz, dtype=float).reshape(3)
    if np.any(s <= 0) or not np.all(np.isfinite(s)):
        raise ValueError(f"URDF scale must be finite and > 0 (got {tuple(s)})")
    uniform = bool(np.allclose(s, s[0], rtol=1e-12, atol=0.0))
    root = ET.fromstring(text)
    for origin in root.iter("origin"):
        xyz = origin.get("xyz")
        if xyz is not None:
            origin.set("xyz", _fmt(_floats(xyz) * s))
    for holder in root.iter():
        if holder.tag not in ("visual", "collision"):
            continue
        geometry = holder.find("geometry")
        if geometry is None:
            continue
        for shape in list(geometry):
            if shape.tag == "box":
                shape.set("size", _fmt(_floats(shape.get("size", "1 1 1")) * s))
            elif shape.tag == "cylinder":
                if not math.isclose(s[0], s[1], rel_tol=1e-12):
                    raise ValueError(f"a cylinder needs equal x and y scale (got {tuple(s)})")
                radius = float(shape.get("radius", "1")) * s[0]
                if cylinders_as_spheres and holder.tag == "collision":
                    geometry.remove(shape)
                    ET.SubElement(geometry, "sphere", {"radius": repr(float(radius))})
                else:
                    shape.set("radius", repr(float(radius)))
                    shape.set("length", repr(float(float(shape.get("length", "1")) * s[2])))
            elif shape.tag == "sphere":
                if not uniform:
                    raise ValueError(f"a sphere needs a uniform scale (got {tuple(s)})")
                shape.set("radius", repr(float(float(shape.get("radius", "1")) * s[0])))
            elif shape.tag == "mesh":
                shape.set("scale", _fmt(_floats(shape.get("scale", "1 1 1")) * s))
                name = shape.get("filename", "")
                if base_dir is not None and name and "://" not in name and not os.path.isabs(name):
                    shape.set("filename", str(Path(base_dir, name).resolve()))
    ET.indent(root)   # one element a line: PyBullet splits lines longer than ~8 KiB (pbdyn.urdf.MAX_LINE_BYTES)
    return ET.tostring(root, encoding="unicode")


@functools.lru_cache(maxsize=256)
def _scaled_text(path: str, scale: tuple[float, float, float], cylinders_as_spheres: bool) -> str:
    check_urdf(path, "urdf", scale)   # scenarios' URDFs were checked at load time naming their field: a backstop
    text = Path(path).read_text(encoding="utf-8")
    text = scale_urdf_text(text, scale, Path(path).parent, cylinders_as_spheres=cylinders_as_spheres)
    longest = max(len(line.encode("utf-8")) for line in text.split("\n"))
    if longest > MAX_LINE_BYTES:
        raise ConfigError("urdf", f"{Path(path).name}: scaled for PyBullet it has a line of {longest:,} bytes, more "
                          f"than PyBullet's URDF reader takes whole ({MAX_LINE_BYTES:,}); shorten its attributes", path)
    return text


def load_scaled_urdf(client, path: str | Path, scale_xyz: Sequence[float], position: Sequence[float],
                     orientation: Sequence[float] = IDENTITY_QUATERNION, *, cylinders_as_spheres: bool = False,
                     use_fixed_base: bool = False) -> int:
    """Load the URDF at ``path`` scaled per axis by ``scale_xyz`` at ``position`` (m) / ``orientation`` (xyzw).

    The rewritten text (see scale_urdf_text; cached by (path, scale)) goes to a temporary file in the system temp
    directory, which is deleted right after loading. Collision cylinders are loaded as implicit (exact) cylinders.
    PyBullet's stdout chatter is sent to stderr. Returns the body id.
    """
    key = (str(Path(path).resolve()), tuple(float(x) for x in np.asarray(scale_xyz, dtype=float).reshape(3)))
    text = _scaled_text(key[0], key[1], bool(cylinders_as_spheres))
    fd, tmp = tempfile.mkstemp(prefix="pbdyn-", suffix=".urdf")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        with stdout_to_stderr():
            body = client.loadURDF(tmp, basePosition=[float(x) for x in position],
                                   baseOrientation=[float(x) for x in orientation],
                                   useFixedBase=bool(use_fixed_base), flags=pybullet.URDF_USE_IMPLICIT_CYLINDER)
    finally:
        os.unlink(tmp)
    if body < 0:
        raise RuntimeError(f"PyBullet could not load {path}")
    return int(body)
