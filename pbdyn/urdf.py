"""Validation of URDF files named by a scenario (the MAV model, imported bodies) before anything loads them.

check_urdf is the one gate: pbdyn.config runs it on ``drone.urdf`` and every ``bodies[i].urdf`` when a scenario or
world file is loaded, and pbdyn.world (shapes.body_primitives, bullet.load_scaled_urdf) runs it again before reading
or loading a file, so a URDF that would crash PyBullet, give NaN distances or a body of zero size never reaches a
rollout, a metric or a trial. Errors are ConfigError naming the scenario field, the file and the URDF element.

What it checks (URDF elements as PyBullet reads them; sizes after the scenario's per-axis scale). Each rule keeps
out a text that Python's XML parser reads but PyBullet 3.2 rejects, crashes on (a segfault) or silently misreads,
found by loading each case in PyBullet (tests/test_urdf_pybullet.py):
- the file exists, is UTF-8 text with no line longer than MAX_LINE_BYTES (PyBullet reads a URDF in chunks of about
  8 KiB and splits a longer line, which changes a number, breaks a name or crashes), and is XML without a DOCTYPE
  (PyBullet expands no entities) or processing instructions, nested at most MAX_NESTING (pbdyn.limits) elements
  deep, no attribute longer than MAX_ATTRIBUTE_CHARS;
- its root is <robot name> with at least one <link>; every <link> and <joint> has a name of 1 to MAX_NAME_CHARS
  characters (longer joint names crash PyBullet), unique among its kind;
- every <joint> has a type PyBullet knows (JOINT_TYPES; revolute and prismatic ones with a <limit>), an <axis xyz>
  if any of 3 numbers, and a <parent> and <child> naming links of the file; the links form one tree: one root
  link, no link the child of two joints, every link reachable from the root;
- every number is a plain decimal (``1``, ``-0.5``, ``2e-3``: no units, underscores, hex or non-ASCII digits,
  which Python and PyBullet read differently), numbers of a vector separated by spaces;
- every <origin> has xyz and rpy of 3 finite numbers; an <inertial> has a <mass value>, a finite number >= 0, and an
  <inertia> with the six attributes ixx ixy ixz iyy iyz izz, finite numbers;
- every <visual> and <collision> has a <geometry> holding exactly one of <box size="x y z">, <sphere radius>,
  <cylinder radius length>, <mesh filename [scale]>, with every size, radius, length and mesh scale finite and > 0
  (also after scaling); a sphere needs a uniform scale and a cylinder equal x and y scales; a mesh file is a path
  (not a URL such as package://) to an existing file (relative names: the URDF's folder);
- the model has at least one <collision> geometry (its collision shape is what trials and metrics use).
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Sequence

from pbdyn.errors import ConfigError
from pbdyn.limits import MAX_NESTING

SHAPES = ("box", "sphere", "cylinder", "mesh")
MESH_SUFFIXES = (".obj", ".stl", ".ply", ".off", ".gltf", ".glb")
"""Mesh formats both PyBullet and open3d read (by file suffix)."""
MAX_LINE_BYTES = 8000
"""Longest line PyBullet's URDF reader takes whole (it reads about 8 KiB at a time and splits longer lines)."""
MAX_NAME_CHARS = 255
"""Longest robot, link or joint name (PyBullet keeps names in 1024-byte buffers; longer joint names crash it)."""
MAX_ATTRIBUTE_CHARS = 4096
"""Longest attribute value (a file path's length at most)."""
JOINT_TYPES = ("fixed", "revolute", "continuous", "prismatic", "floating", "planar")
"""The joint types PyBullet's URDF parser knows."""
INERTIA = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
_NUMBER = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|[+-]?(?:nan|inf)", re.IGNORECASE)
"""A plain decimal number as both Python and PyBullet read it (nan and inf parse, to be refused as not finite)."""


class _Refused(Exception):
    """Raised by _Builder while parsing: the text holds a construct PyBullet does not read as Python does."""


class _Builder(ET.TreeBuilder):
    """An ElementTree builder that stops at a DOCTYPE (entities) or a processing instruction."""

    def doctype(self, name, pubid, system):
        raise _Refused("has a DOCTYPE (PyBullet expands no entities; remove it)")

    def pi(self, target, text=None):
        raise _Refused(f"has a processing instruction <?{target} ...?> (PyBullet cannot parse it; remove it)")


def _numbers(text: str | None, n: tuple[int, ...]) -> list[float] | None:
    """The floats of ``text`` if it holds one of the counts ``n`` of finite numbers, else None."""
    if text is None:
        return None
    parts = [v for v in text.split(" ") if v]
    if not all(_NUMBER.fullmatch(v) for v in parts):
        return None
    vals = [float(v) for v in parts]
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
        data = path.read_bytes()
    except OSError as exc:
        raise ConfigError(field, f"cannot read the URDF ({exc.strerror or exc})", str(path)) from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(field, f"{name}: not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start:,})",
                          str(path)) from None
    for number, line in enumerate(data.split(b"\n"), 1):
        if len(line) > MAX_LINE_BYTES:
            raise ConfigError(field, f"{name}: line {number} is {len(line):,} bytes long, more than PyBullet's URDF "
                              f"reader takes whole ({MAX_LINE_BYTES:,}: it splits a longer line, changing its "
                              "values); break it into lines", str(path))
    parser = ET.XMLParser(target=_Builder())
    try:
        parser.feed(text)
        root = parser.close()
    except _Refused as exc:
        raise ConfigError(field, f"{name}: {exc}", str(path)) from None
    except (ET.ParseError, ValueError) as exc:
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
    for el in root.iter():
        for k, v in el.attrib.items():
            if len(v) > MAX_ATTRIBUTE_CHARS:
                raise ConfigError(field, f"{name}: <{el.tag} {k}> is {len(v):,} characters long, more than "
                                  f"{MAX_ATTRIBUTE_CHARS:,}", str(path))
    _check_name(root, "robot", name, field, path)
    links = [_check_name(link, "link", name, field, path) for link in root.findall("link")]
    if not links:
        raise ConfigError(field, f"{name}: has no <link>", str(path))
    _unique(links, "link", name, field, path)
    _check_joints(root, links, name, field, path)

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
            v = None if mass is None else _numbers(mass.get("value"), (1,))
            if v is None or v[0] < 0:
                raise ConfigError(field, f"{where(link, inertial)} needs a <mass value> that is a finite number >= 0",
                                  None if mass is None else mass.get("value"))
            inertia = inertial.find("inertia")
            if inertia is None:
                raise ConfigError(field, f"{where(link, inertial)} needs an <inertia> ({' '.join(INERTIA)})",
                                  str(path))
            for k in INERTIA:
                if k not in inertia.attrib:
                    raise ConfigError(field, f"{where(link, inertial)} <inertia> needs {k} (PyBullet requires "
                                      f"{' '.join(INERTIA)})", str(path))
            for k, value in inertia.attrib.items():
                if _numbers(value, (1,)) is None:
                    raise ConfigError(field, f"{where(link, inertial)} <inertia {k}> must be a finite number",
                                      value)
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


def _check_name(el: ET.Element, kind: str, name: str, field: str, path: Path) -> str:
    """The name attribute of ``el``, checked: 1 to MAX_NAME_CHARS characters."""
    text = el.get("name")
    if not text or len(text) > MAX_NAME_CHARS:
        what = "has no name" if text is None else "has an empty name" if not text else \
            f"has a name of {len(text):,} characters, more than {MAX_NAME_CHARS}"
        raise ConfigError(field, f"{name}: a <{kind}> {what} (PyBullet needs names of 1 to {MAX_NAME_CHARS} "
                          "characters)", str(path) if not text else text[:40] + "...")
    return text


def _unique(names: list[str], kind: str, name: str, field: str, path: Path) -> None:
    seen = set()
    for n in names:
        if n in seen:
            raise ConfigError(field, f"{name}: two <{kind}> elements are named {n!r} (names must be unique)",
                              str(path))
        seen.add(n)


def _check_joints(root: ET.Element, links: list[str], name: str, field: str, path: Path) -> None:
    """The joints' names, types, axes and links, and that the links form one tree."""
    parent_of: dict[str, tuple[str, str]] = {}
    joints = []
    for joint in root.findall("joint"):
        jname = _check_name(joint, "joint", name, field, path)
        joints.append(jname)
        jtype = joint.get("type")
        if jtype not in JOINT_TYPES:
            raise ConfigError(field, f"{name}: joint {jname!r} needs a type, one of {', '.join(JOINT_TYPES)}", jtype)
        if jtype in ("revolute", "prismatic") and joint.find("limit") is None:
            raise ConfigError(field, f"{name}: joint {jname!r} of type {jtype} needs a <limit>", str(path))
        axis = joint.find("axis")
        if axis is not None and _numbers(axis.get("xyz"), (3,)) is None:
            raise ConfigError(field, f"{name}: joint {jname!r} <axis xyz> must be 3 finite numbers", axis.get("xyz"))
        ends = []
        for tag in ("parent", "child"):
            el = joint.find(tag)
            if el is None or el.get("link") not in links:
                raise ConfigError(field, f"{name}: joint {jname!r} <{tag} link> must name a link of the file",
                                  None if el is None else el.get("link"))
            ends.append(el.get("link"))
        parent, child = ends
        if child in parent_of:
            raise ConfigError(field, f"{name}: link {child!r} is the child of two joints ({parent_of[child][1]!r} "
                              f"and {jname!r}; the links must form a tree)", str(path))
        parent_of[child] = (parent, jname)
    _unique(joints, "joint", name, field, path)
    roots = [n for n in links if n not in parent_of]
    if len(roots) != 1:
        raise ConfigError(field, f"{name}: must have exactly one root link (a link no joint has as its child), "
                          f"has {len(roots)}" + (f": {', '.join(map(repr, roots[:5]))}" if roots else ""), str(path))
    reached, frontier = {roots[0]}, [roots[0]]
    children: dict[str, list[str]] = {}
    for child, (parent, _) in parent_of.items():
        children.setdefault(parent, []).append(child)
    while frontier:
        for child in children.get(frontier.pop(), ()):
            if child not in reached:
                reached.add(child)
                frontier.append(child)
    lost = [n for n in links if n not in reached]
    if lost:
        raise ConfigError(field, f"{name}: link {lost[0]!r} is not connected to the root link {roots[0]!r} (its "
                          "joints form a loop)", str(path))


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
        if "://" in mesh:
            raise ConfigError(field, f"{where}: the mesh filename must be a file path, not a URL", mesh)
        try:
            found = (path.parent / mesh).is_file()
        except (OSError, ValueError):
            found = False
        if not found:
            raise ConfigError(field, f"{where}: mesh file not found", mesh)
        if Path(mesh).suffix.lower() not in MESH_SUFFIXES:
            raise ConfigError(field, f"{where}: not a mesh file (readable: {', '.join(MESH_SUFFIXES)})", mesh)
    else:
        raise ConfigError(field, f"{where}: unsupported geometry (supported: {', '.join(SHAPES)})", shape.tag)
