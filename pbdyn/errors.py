"""Errors pbdyn reports to users as one line (the CLI exits with status 2 on them)."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path


class PbdynError(Exception):
    """Base class of every error pbdyn reports as a one-line message."""


class ConfigError(PbdynError, ValueError):
    """An invalid scenario, world file or command-line value.

    The message always names the field and the offending value, e.g.
    ``obstacles.radius: must be > 0 (got -1.0)``.
    """

    def __init__(self, field: str, problem: str, value: object = None, *, show_value: bool = True):
        self.field = field
        self.problem = problem
        self.value = value
        self.show_value = show_value
        text = f"{field}: {problem}"
        if show_value:
            text += f" (got {value!r})"
        super().__init__(text)

    def renamed(self, field: str) -> "ConfigError":
        """The same error naming ``field`` instead (the CLI names its flags where the library names parameters)."""
        return ConfigError(field, self.problem, self.value, show_value=self.show_value)


class HorizonError(PbdynError, IndexError):
    """A time was asked of a rollout past its horizon."""


def check_positive(field: str, value: object) -> float:
    """``value`` as a float; ConfigError naming ``field`` unless it is a finite number > 0."""
    try:
        v = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ConfigError(field, "must be a number", value) from None
    if not (v == v and abs(v) != float("inf")) or v <= 0:
        raise ConfigError(field, "must be a finite number > 0", value)
    return v


def one_line(exc: BaseException) -> str:
    """``exc`` as one line: "Type: message" with the message's whitespace collapsed."""
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def import_object(name: str, field: str):
    """The object named by "package.module:attr[.attr...]" (user plug-ins, motion functions); ConfigError naming
    ``field`` if the module cannot be imported or has no such attribute."""
    import importlib

    module_name, _, attr = name.partition(":")
    try:
        obj = importlib.import_module(module_name)
    except Exception as exc:  # any failure while importing user code is a configuration problem
        raise ConfigError(field, f"cannot import module {module_name!r} ({one_line(exc)})", name) from None
    for part in attr.split("."):
        if not hasattr(obj, part):
            raise ConfigError(field, f"module {module_name!r} has no attribute {attr!r}", name)
        obj = getattr(obj, part)
    return obj


# ---------------------------------------------------------------------------------------- paths pbdyn writes to
NAME_MAX = 255
"""Longest file or folder name, in bytes (ext4, XFS, APFS, NTFS)."""
PATH_MAX = 4096
"""Longest path, in bytes (Linux)."""


def check_path_length(field: str, path) -> None:
    """ConfigError naming ``field`` if a component of ``path`` is longer than NAME_MAX bytes or the absolute path
    longer than PATH_MAX bytes."""
    p = Path(path)
    for part in p.parts:
        if len(os.fsencode(part)) > NAME_MAX:
            raise ConfigError(field, f"has a name longer than {NAME_MAX} bytes ({len(os.fsencode(part))} bytes: "
                              f"{part[:40]}...)", _short(path), show_value=True)
    full = len(os.fsencode(str(p.absolute())))
    if full > PATH_MAX:
        raise ConfigError(field, f"is longer than {PATH_MAX} bytes ({full} bytes)", _short(path))


def _short(path) -> str:
    text = str(path)
    return text if len(text) <= 120 else text[:60] + "..." + text[-40:]


def check_writable_file(field: str, path) -> Path:
    """``path`` as a Path whose folder exists and accepts a new file (a temporary file is created and removed
    there); ConfigError naming ``field`` otherwise."""
    p = Path(path)
    check_path_length(field, p)
    if p.is_dir():
        raise ConfigError(field, "is a folder; give a file name", str(path))
    folder = p.absolute().parent
    if not folder.is_dir():
        raise ConfigError(field, "folder does not exist", str(p.parent))
    try:
        fd, tmp = tempfile.mkstemp(prefix=".pbdyn-write-test-", dir=folder)
        os.close(fd)
        os.unlink(tmp)
    except OSError as exc:
        raise ConfigError(field, f"cannot be written: the folder {folder} does not accept new files "
                          f"({exc.strerror or exc})", str(path)) from None
    if p.exists() and not os.access(p, os.W_OK):
        raise ConfigError(field, "exists and is not writable", str(path))
    return p
