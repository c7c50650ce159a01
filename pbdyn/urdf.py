"""Validation of URDF files named by a scenario (the MAV model, imported bodies) before anything loads them.

check_urdf is the one gate: pbdyn.config runs it on ``drone.urdf`` and every ``bodies[i].urdf`` when a scenario or
world file is loaded, and pbdyn.world (shapes.body_primitives, bullet.load_scaled_urdf) runs it again before reading
or loading a file, so a URDF that would crash PyBullet, give NaN distances or a body of zero size never reaches a
rollout, a metric or a trial. Errors are ConfigError naming the scenario field, the file and the URDF element.

What it checks (URDF elements as PyBullet reads them; sizes after the scenario's per-axis scale):
- the file exists and is XML, nested at most MAX_NESTING (pbdyn.limits) elements deep, whose root is <robot> with at least one <link>, exactly one root link, and joints
  whose <parent>/<child> name links of the file;
- every <origin> has xyz and rpy of 3 finite numbers; every <mass value> is a finite number >= 0 and every
  <inertia> attribute a finite number;
- every <visual> and <collision> has a <geometry> holding exactly one of <box size="x y z">, <sphere radius>,
  <cylinder radius length>, <mesh filename [scale]>, with every size, radius, length and mesh scale finite and > 0
  (also after scaling); a sphere needs a uniform scale and a cylinder equal x and y scales; a mesh file must exist
  (relative names: the URDF's folder);
- the model has at least one <collision> geometry (its collision shape is what trials and metrics use).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Sequence

from pbdyn.errors import ConfigError
from pbdyn.limits import MAX_NESTING

SHAPES = ("box", "sphere", "cylinder", "mesh")
MESH_SUFFIXES = (".obj", ".stl", ".ply", ".off", ".gltf", ".glb")
"""Mesh formats both PyBullet and open3d read (by file suffix)."""


def _numbers(text: str | None, n: tuple[int, ...]) -> list[float] | None:
    """The floats of ``text`` if it holds one of the counts ``n`` of finite numbers, else None."""
    if text is None:
        return None
    try:
        vals = [float(v) for v in text.split()]
    except ValueError:
        return None
    if len(vals) not in n or not all(math.isfinite(v) for v in vals):
        return None
    return vals


def _depth(root: ET.Element) -> int:
    """Levels of elements below and including ``root`` (iterative: no recursion limit)."""
    deepest, stack = 0, [(root, 1)]
    while stack:
        el, d = stack.pop()
        deepest = max(deepest, d)
        if d <= MAX_NESTING:
            stack.extend((child, d + 1) for child in el)
    return deepest


def check_urdf(path: str | Path, field: str, scale: Sequence[float] = (1.0, 1.0, 1.0)) -> ET.Element:
    """The parsed root of the URDF at ``path`` after the checks of the module docstring, with the model scaled by
    ``scale`` (sx, sy, sz); ConfigError naming ``field`` otherwise."""
    path = Path(path)
    name = path.name
    if not path.is_file():
        raise ConfigError(field, "file not found", str(path))
    try:
        root = ET.fromstring(path.read_text(encoding="utf-8"))
    except (ET.ParseError, UnicodeDecodeError, OSError, ValueError) as exc:
        raise ConfigError(field, f"cannot read the URDF ({' '.join(str(exc).split())})", str(path)) from None
    except RecursionError:
        raise ConfigError(field, "cannot read the URDF (nested too deeply)", str(path)) from None
    depth = _depth(root)
    if depth > MAX_NESTING:
        raise ConfigError(field, f"{name}: XML nested {depth} levels deep, more than the limit of {MAX_NESTING} "
                          "(pbdyn.limits)", str(path))
    s = [float(v) for v in scale]
    if len(s) != 3 or not all(math.isfinite(v) and v > 0 for v in s):
        raise ConfigError(field, "the scale must be 3 finite numbers > 0", list(scale))
    if root.tag != "robot":
        raise ConfigError(field, f"{name}: the root element must be <robot>, not <{root.tag}>", str(path))
    links = [link.get("name") for link in root.findall("link")]
    if not links:
        raise ConfigError(field, "has no <link>", str(path))
    children = set()
    for joint in root.findall("joint"):
        jname = joint.get("name", "?")
        for tag in ("parent", "child"):
            el = joint.find(tag)
            if el is None or el.get("link") not in links:
                raise ConfigError(field, f"{name}: joint {jname!r} <{tag} link> must name a link of the file",
                                  None if el is None else el.get("link"))
        children.add(joint.find("child").get("link"))
    if len([n for n in links if n not in children]) != 1:
        raise ConfigError(field, "must have exactly one root link", str(path))

    def where(link, elem, shape=None) -> str:
        text = f"{name}: link {link.get('name')!r}"
        if elem is not None and elem is not link:
            text += f" <{elem.tag}>"
        return text + (f" <{shape}>" if shape else "")

    for parent in root.iter():
        for origin in parent.findall("origin"):
            for attr in ("xyz", "rpy"):
                text = origin.get(attr)
                if text is not None and _numbers(text, (3,)) is None:
                    raise ConfigError(field, f"{name}: <{parent.tag} name={parent.get('name')!r}> <origin {attr}> "
                                      "must be 3 finite numbers", text)
    n_collision = 0
    for link in root.findall("link"):
        inertial = link.find("inertial")
        if inertial is not None:
            mass = inertial.find("mass")
            if mass is not None:
                v = _numbers(mass.get("value"), (1,))
                if v is None or v[0] < 0:
                    raise ConfigError(field, f"{where(link, inertial)} <mass value> must be a finite number >= 0",
                                      mass.get("value"))
            inertia = inertial.find("inertia")
            if inertia is not None:
                for k, text in inertia.attrib.items():
                    if _numbers(text, (1,)) is None:
                        raise ConfigError(field, f"{where(link, inertial)} <inertia {k}> must be a finite number",
                                          text)
        for holder in list(link.findall("visual")) + list(link.findall("collision")):
            geom = holder.find("geometry")
            shapes = [] if geom is None else list(geom)
            if len(shapes) != 1:
                raise ConfigError(field, f"{where(link, holder)} must have a <geometry> with exactly one shape "
                                  f"({', '.join(SHAPES)})", str(path))
            _check_shape(shapes[0], s, path, field, where(link, holder, shapes[0].tag))
            n_collision += holder.tag == "collision"
    if n_collision == 0:
        raise ConfigError(field, "has no collision geometry (a model needs at least one <collision> shape)",
                          str(path))
    return root


def _check_shape(shape: ET.Element, s: list[float], path: Path, field: str, where: str) -> None:
    def positive(attr: str, counts: tuple[int, ...], factors: Sequence[float], default: str | None = None):
        text = shape.get(attr, default)
        if text is None:
            raise ConfigError(field, f"{where} needs a {attr} attribute", str(path))
        vals = _numbers(text, counts)
        if vals is not None and len(vals) == 1 and len(factors) == 3:
            vals = vals * 3
        if vals is None or not all(v > 0 and math.isfinite(v * f) and v * f > 0 for v, f in zip(vals, factors)):
            what = f"{counts[-1]} finite numbers" if counts[-1] > 1 else "a finite number"
            raise ConfigError(field, f"{where} {attr} must be {what} > 0", text)

    if shape.tag == "box":
        positive("size", (3,), s)
    elif shape.tag == "sphere":
        positive("radius", (1,), s[:1])
        if not (math.isclose(s[0], s[1], rel_tol=1e-12) and math.isclose(s[0], s[2], rel_tol=1e-12)):
            raise ConfigError(field, f"{where} needs a uniform scale", s)
    elif shape.tag == "cylinder":
        positive("radius", (1,), s[:1])
        positive("length", (1,), s[2:])
        if not math.isclose(s[0], s[1], rel_tol=1e-12):
            raise ConfigError(field, f"{where} needs equal x and y scales", s)
    elif shape.tag == "mesh":
        positive("scale", (1, 3), s, default="1 1 1")
        mesh = shape.get("filename", "")
        if not mesh:
            raise ConfigError(field, f"{where} needs a filename", str(path))
        if "://" not in mesh and not (path.parent / mesh).is_file():
            raise ConfigError(field, f"{where}: mesh file not found", mesh)
        if Path(mesh).suffix.lower() not in MESH_SUFFIXES:
            raise ConfigError(field, f"{where}: not a mesh file (readable: {', '.join(MESH_SUFFIXES)})", mesh)
    else:
        raise ConfigError(field, f"{where}: unsupported geometry (supported: {', '.join(SHAPES)})", shape.tag)
