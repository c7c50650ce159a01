"""URDF texts Python's XML parser reads but PyBullet does not (pbdyn/urdf.py check_urdf, docs/limits.md).

Each case below is refused by check_urdf with a reason naming the file; the slow test loads each one in a real
PyBullet DIRECT client (a child process: some crash it) and confirms that PyBullet crashes, refuses it or reads
something other than what the text says -- the reason the check exists. The accepted cases load in PyBullet as
written.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import pytest

from pbdyn.errors import ConfigError
from pbdyn.urdf import MAX_LINE_BYTES, check_urdf
from tests.conftest import ROOT
from tests.fuzz_io import cli

INERTIAL = ('<inertial><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial>')


def _link(name='base', size="1 1 1", origin='<origin xyz="0 0 0" rpy="0 0 0"/>', inertial=INERTIAL):
    attr = "" if name is None else f' name="{name}"'
    return (f'<link{attr}>{inertial}<collision>{origin}<geometry><box size="{size}"/></geometry></collision>'
            '</link>\n')


def _joint(parent="a", child="b", name="j", kind="fixed", extra=""):
    return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>{extra}</joint>\n')


def _robot(body, name="r", head='<?xml version="1.0"?>\n'):
    return f'{head}<robot name="{name}">\n{body}</robot>\n'


_LONG_LINE = _robot("".join(_link(f"l{i}") + (_joint(f"l{i - 1}", f"l{i}", f"j{i}") if i else "")
                             for i in range(100)).replace("\n", "") + "\n")

# (id, URDF text, a fragment of the reason, what PyBullet does with the text: "crash", "error", or "misread": it
# loads, but not as the text means (MEANS, default: a unit box at the origin, no joints))
REFUSED = [
    ("link_without_name", _robot(_link(None)), "has no name", "error"),
    ("link_empty_name", _robot(_link("")), "empty name", "crash"),
    ("joint_without_name", _robot(_link("a") + _link("b") + _joint().replace(' name="j"', "")), "has no name",
     "error"),
    ("joint_without_type", _robot(_link("a") + _link("b") + _joint().replace(' type="fixed"', "")), "needs a type",
     "crash"),
    ("joint_unknown_type", _robot(_link("a") + _link("b") + _joint(kind="hinge")), "needs a type", "error"),
    ("revolute_without_limit", _robot(_link("a") + _link("b") + _joint(kind="revolute")), "needs a <limit>",
     "error"),
    ("joint_axis_two_numbers", _robot(_link("a") + _link("b") + _joint(kind="revolute", extra=(
        '<axis xyz="1 0"/><limit lower="0" upper="1" effort="1" velocity="1"/>'))), "<axis xyz>", "error"),
    ("duplicate_joint_names", _robot(_link("a") + _link("b") + _link("c") + _joint() + _joint("b", "c")),
     "two <joint> elements are named 'j'", "crash"),
    ("duplicate_link_names", _robot(_link("a") + _link("a")), "two <link> elements are named 'a'", "error"),
    ("joint_parent_names_no_link", _robot(_link("a") + _link("b") + _joint(parent="zz")), "<parent link>", "error"),
    ("two_root_links", _robot(_link("a") + _link("b")), "exactly one root link", "crash"),
    ("link_child_of_two_joints", _robot(_link("r") + _link("a") + _link("b") + _joint("r", "b", "j1")
                                        + _joint("a", "b", "j2") + _joint("r", "a", "j3")), "child of two joints",
     "crash"),
    ("links_in_a_loop", _robot(_link("r") + _link("a") + _link("b") + _joint("a", "b", "j1") + _joint("b", "a", "j2")),
     "not connected to the root", "misread"),
    ("empty_robot", _robot(""), "has no <link>", "error"),
    ("robot_without_name", _robot(_link()).replace(' name="r"', ""), "has no name", "error"),
    ("joint_name_too_long", _robot(_link("a") + _link("b") + _joint(name="j" * 2000)), "more than 255", "crash"),
    ("origin_xyz_two_numbers", _robot(_link(origin='<origin xyz="1 2"/>')), "3 finite numbers", "misread"),
    ("inertia_without_izz", _robot(_link(inertial=INERTIAL.replace(' izz="1"', ""))), "needs izz", "error"),
    ("inertial_without_inertia", _robot(_link(inertial='<inertial><mass value="1"/></inertial>')),
     "needs an <inertia>", "error"),
    ("inertial_without_mass", _robot(_link(inertial=INERTIAL.replace('<mass value="1"/>', ""))), "<mass value>",
     "error"),
    ("size_with_underscore", _robot(_link(size="1_0 1 1")), "size must be 3 finite numbers", "misread"),
    ("size_non_breaking_space", _robot(_link(size="1\u00a01 1")), "size must be 3 finite numbers", "misread"),
    ("size_fullwidth_digit", _robot(_link(size="\uff11 1 1")), "size must be 3 finite numbers", "misread"),
    ("size_newline_reference", _robot(_link(size="1&#10;1 1")), "size must be 3 finite numbers", "misread"),
    ("doctype_entity", _robot(_link(size="&s;"), head='<?xml version="1.0"?>\n<!DOCTYPE robot [<!ENTITY s "1 1 1">]>\n'),
     "DOCTYPE", "misread"),
    ("processing_instruction", _robot(_link() + "<?tool run?>\n"), "processing instruction", "error"),
    ("mesh_url", _robot(_link().replace('<box size="1 1 1"/>', '<mesh filename="package://pkg/m.obj"/>')),
     "not a URL", "error"),
    ("line_longer_than_pybullet_reads", _LONG_LINE, f"more than PyBullet's URDF reader takes whole "
                                                    f"({MAX_LINE_BYTES:,}", "error"),
    ("ten_mb_attribute", _robot(_link("b" * 10_000_000)), "bytes long", "crash"),
]
MEANS = {"links_in_a_loop": {"joints": 2}, "origin_xyz_two_numbers": {"center": [1.0, 2.0, 0.0]},
         "size_with_underscore": {"half": [5.0, 0.5, 0.5]}}
"""What a misread text means where it is not a unit box at the origin with no joints (Python's reading)."""

ACCEPTED = [
    ("box", _robot(_link())),
    ("two_links", _robot(_link("a") + _link("b") + _joint())),
    ("revolute_with_limit", _robot(_link("a") + _link("b") + _joint(
        kind="revolute", extra='<axis xyz="0 0 1"/><limit lower="0" upper="1" effort="1" velocity="1"/>'))),
    ("non_ascii_names", _robot(_link("bäse"), name="röbot")),
    ("plain_numbers", _robot(_link(size="+1 1.0 1e0", origin='<origin xyz=".0 -0 0" rpy="0 0 0"/>'))),
]


def _write(tmp_path, name, text):
    path = tmp_path / f"{name}.urdf"
    path.write_bytes(text.encode("utf-8"))
    return path


@pytest.mark.parametrize("name,text,reason,_pybullet", REFUSED, ids=[c[0] for c in REFUSED])
def test_check_urdf_refuses_what_pybullet_cannot_read_naming_the_file(tmp_path, name, text, reason, _pybullet):
    path = _write(tmp_path, name, text)
    with pytest.raises(ConfigError) as err:
        check_urdf(path, "bodies[0].urdf")
    message = str(err.value)
    assert message.startswith("bodies[0].urdf: ") and f"{name}.urdf" in message and reason in message, message
    assert "\n" not in message and len(message) < 400, message


@pytest.mark.parametrize("name,text", ACCEPTED, ids=[c[0] for c in ACCEPTED])
def test_check_urdf_accepts_what_pybullet_reads(tmp_path, name, text):
    check_urdf(_write(tmp_path, name, text), "urdf")


def test_the_cli_refuses_a_world_whose_urdf_has_a_line_pybullet_cannot_read(tmp_path):
    (tmp_path / "body.urdf").write_text(_LONG_LINE)
    world = tmp_path / "world.toml"
    world.write_text('[world]\ndims = 3\nsize = [50.0, 50.0, 20.0]\ntime_limit = 2.0\n\n'
                     '[[bodies]]\nname = "b"\nurdf = "body.urdf"\nposition = [25.0, 25.0, 10.0]\n')
    code, out, err, _ = cli(["rollout", str(world), "--out", str(tmp_path / "r.npz")])
    assert code == 2 and out == "" and err.count("\n") == 1, (code, err)
    assert err.startswith("pbdyn: error: bodies[0].urdf: body.urdf: line 3 is ") and "Traceback" not in err, err
    assert not (tmp_path / "r.npz").exists()


def test_pbdyns_scaled_rewrite_keeps_one_element_a_line(tmp_path):
    from pbdyn.world.imported.urdf_loading import scale_urdf_text

    text = _robot(_link("a") + _link("b") + _joint()).replace("\n", "")
    out = scale_urdf_text(text, (0.3, 0.3, 0.3), tmp_path)
    assert max(len(line) for line in out.splitlines()) < 200 and out.count("\n") > 10


_PROBE = textwrap.dedent("""
    import json, sys
    from pbdyn.world.pybullet_client import pybullet, bullet_client, stdout_to_stderr
    c = bullet_client.BulletClient(connection_mode=pybullet.DIRECT)
    try:
        with stdout_to_stderr():
            body = c.loadURDF(sys.argv[1])
    except pybullet.error:
        print(json.dumps({"loaded": False}))
    else:
        lo, hi = c.getAABB(body, -1)
        print(json.dumps({"loaded": True, "half": [(h - l) / 2 for l, h in zip(lo, hi)],
                          "center": [(h + l) / 2 for l, h in zip(lo, hi)], "joints": c.getNumJoints(body)}))
""")


def _pybullet_loads(path) -> dict:
    """What a PyBullet DIRECT client in a child process makes of the URDF at ``path``."""
    proc = subprocess.run([sys.executable, "-c", _PROBE, str(path)], capture_output=True, text=True, timeout=120,
                          cwd=ROOT)
    if proc.returncode < 0:
        return {"crash": -proc.returncode}
    assert proc.returncode == 0, proc.stderr[-500:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _as_written(got: dict, means: dict) -> bool:
    """Whether PyBullet loaded what the text means (``means``: half, center, joints; an AABB margin aside)."""
    half, center = means.get("half", [0.5] * 3), means.get("center", [0.0] * 3)
    return (got.get("loaded") is True and all(abs(g - h) < 2e-3 for g, h in zip(got["half"], half))
            and all(abs(g - c) < 2e-3 for g, c in zip(got["center"], center)) and got["joints"] == means.get("joints", 0))


@pytest.mark.slow
@pytest.mark.parametrize("name,text,_reason,pybullet", REFUSED, ids=[c[0] for c in REFUSED])
def test_pybullet_crashes_refuses_or_misreads_each_refused_text(tmp_path, name, text, _reason, pybullet):
    got = _pybullet_loads(_write(tmp_path, name, text))
    if pybullet == "crash":
        assert "crash" in got, got
    elif pybullet == "error":
        assert got == {"loaded": False}, got
    else:
        assert "crash" not in got and got["loaded"] and not _as_written(got, MEANS.get(name, {})), got


@pytest.mark.slow
@pytest.mark.parametrize("name,text", ACCEPTED, ids=[c[0] for c in ACCEPTED])
def test_pybullet_loads_each_accepted_text_as_written(tmp_path, name, text):
    got = _pybullet_loads(_write(tmp_path, name, text))
    assert _as_written(got, {"joints": text.count("<joint")}), got
