"""Errors pbdyn reports to users as one line (the CLI exits with status 2 on them)."""

from __future__ import annotations

import math
import os
import tempfile
import unicodedata
from pathlib import Path


class PbdynError(Exception):
    """Base class of every error pbdyn reports as a one-line message (str() escapes control characters)."""

    def __str__(self) -> str:
        return one_line_text(super().__str__())


class ConfigError(PbdynError, ValueError):
    """An invalid scenario, world file or command-line value.

    The message always names the field and the offending value, e.g.
    ``obstacles.radius: must be > 0 (got -1.0)``. It names another option by its library name in backticks
    (``pass `rerun_changed```), never by a flag: the command line writes the flag (pbdyn.cli._cli_words).
    """

    def __init__(self, field: str, problem: str, value: object = None, *, show_value: bool = True):
        self.field = field
        self.problem = problem
        self.value = value
        self.show_value = show_value
        text = f"{field}: {problem}"
        if show_value:
            text += f" (got {_safe_repr(value)})"
        super().__init__(one_line_text(text))

    def renamed(self, field: str) -> "ConfigError":
        """The same error naming ``field`` instead (the CLI names its flags where the library names parameters)."""
        return ConfigError(field, self.problem, self.value, show_value=self.show_value)


def one_line_text(text: str) -> str:
    """``text`` with every control or line-breaking character (newline, carriage return, escape, U+2028, ...)
    written as its escape sequence, so that a message is always exactly one line of plain text."""
    if text.isprintable():
        return text
    out = []
    for ch in text:
        if ch == " " or unicodedata.category(ch) not in ("Cc", "Cf", "Zl", "Zp", "Cs"):
            out.append(ch)
        else:
            out.append(ch.encode("unicode_escape", "backslashreplace").decode("ascii"))
    return "".join(out)


def _safe_repr(value: object) -> str:
    """repr(value) that never raises and never recurses without end (a value from a user's file or code)."""
    try:
        text = repr(value)
    except RecursionError:
        return f"<{type(value).__name__} nested too deeply>"
    except Exception as exc:  # a user object whose __repr__ fails
        return f"<{type(value).__name__}: repr failed ({type(exc).__name__})>"
    return text if len(text) <= 400 else text[:400] + "..."


def non_finite_path(value: object, depth: int = 0) -> str | None:
    """Where a non-finite float (NaN, +-inf) sits in ``value`` (a number, or lists / tuples / dicts of them):
    "" for ``value`` itself, "[2]" or ".key[0]" inside it; None if there is none."""
    if isinstance(value, float):
        return None if math.isfinite(value) else ""
    if depth > 64:
        return None
    if isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            sub = non_finite_path(v, depth + 1)
            if sub is not None:
                return f"[{i}]{sub}"
    elif isinstance(value, dict):
        for k, v in value.items():
            sub = non_finite_path(v, depth + 1)
            if sub is not None:
                return f".{k}{sub}"
    else:
        try:  # numpy scalars and arrays
            import numpy as np

            if isinstance(value, (np.floating, np.ndarray)) and value.dtype.kind in "fc":
                arr = np.asarray(value).reshape(-1)
                bad = np.flatnonzero(~np.isfinite(arr))
                if bad.size:
                    return "" if np.ndim(value) == 0 else f"[{int(bad[0])}]"
        except ImportError:  # pragma: no cover - numpy is a dependency
            pass
    return None


def check_finite_params(params: dict, field: str) -> None:
    """ConfigError naming ``field``.<key> if a parameter value is or holds a non-finite float (NaN, +-inf)."""
    for key, value in params.items():
        where = non_finite_path(value)
        if where is not None:
            raise ConfigError(f"{field}.{key}", "must be finite (no NaN or infinity)", value)


class PbdynWarning(UserWarning):
    """Input pbdyn accepts but that will probably not do what the user wants, naming the field (``field``) like
    ConfigError; the command line prints it as one line ``pbdyn: warning: ...``."""

    def __init__(self, field: str, problem: str):
        self.field = field
        self.problem = problem
        super().__init__(one_line_text(f"{field}: {problem}"))

    def renamed(self, field: str) -> "PbdynWarning":
        """The same warning naming ``field`` instead."""
        return PbdynWarning(field, self.problem)


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


MAX_MESSAGE_CHARS = 300
"""Longest text of a user exception (or returned value) quoted in a one-line error."""


def shorten(text: str, limit: int = MAX_MESSAGE_CHARS) -> str:
    """``text`` with its whitespace (line breaks included) collapsed to single spaces, other control characters
    escaped, and cut to ``limit`` characters ("..." marks a cut)."""
    text = " ".join(text.split())
    if not text.isprintable():
        text = "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def one_line(exc: BaseException) -> str:
    """``exc`` as one line: "Type: message" with the message's whitespace collapsed (and cut; an exception whose
    str() fails is named by its type)."""
    try:
        text = shorten(str(exc))
    except KeyboardInterrupt:
        raise
    except BaseException:  # user exceptions may fail to print themselves
        text = "<unprintable>"
    name = getattr(type(exc), "__name__", "exception")
    return f"{name}: {text}" if text else name


_PACKAGE_DIR = os.path.dirname(os.path.abspath(__file__)) + os.sep


def _library_dirs() -> tuple[str, ...]:
    import sysconfig

    paths = sysconfig.get_paths()
    dirs = {os.path.abspath(paths[k]) + os.sep for k in ("stdlib", "platstdlib", "purelib", "platlib") if k in paths}
    return tuple(sorted(dirs))


def user_location(exc: BaseException) -> str | None:
    """"file:line" where user code raised ``exc``: the innermost traceback frame outside the pbdyn package and
    outside Python's library folders (standard library, site-packages), looked for in ``exc`` and then in the
    exceptions it was raised from; None if there is no such frame (e.g. pbdyn's own bug)."""
    import traceback

    libs = _library_dirs()
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        for frame in reversed(traceback.extract_tb(exc.__traceback__)):
            name = frame.filename
            if name.startswith("<frozen "):
                continue
            path = os.path.abspath(name) if not name.startswith("<") else name
            if not path.startswith(_PACKAGE_DIR) and not path.startswith(libs):
                return f"{name}:{frame.lineno}"
        exc = exc.__cause__ or (None if exc.__suppress_context__ else exc.__context__)
    return None


def import_module(module_name: str, field: str, name: str | None = None):
    """Import the user module ``module_name``; ConfigError naming ``field`` (and showing ``name``, default the
    module name) on any exception or exit while importing it (SystemExit, custom BaseExceptions; not
    KeyboardInterrupt). What the module prints while it is imported goes to stderr (Python and C level), never to
    pbdyn's stdout."""
    import importlib

    from pbdyn.usercode import quiet_user_code

    try:
        with quiet_user_code():
            return importlib.import_module(module_name)
    except KeyboardInterrupt:
        raise
    except BaseException as exc:  # any failure while importing user code is a configuration problem
        raise ConfigError(field, f"cannot import module {module_name!r} ({one_line(exc)})",
                          module_name if name is None else name) from None


def import_object(name: str, field: str):
    """The object named by "package.module:attr[.attr...]" (user plug-ins, motion functions); ConfigError naming
    ``field`` if the module cannot be imported (see import_module) or has no such attribute."""
    module_name, _, attr = name.partition(":")
    obj = import_module(module_name, field, name)
    for part in attr.split("."):
        try:
            obj = getattr(obj, part)
        except KeyboardInterrupt:
            raise
        except BaseException:  # AttributeError, or a module __getattr__ that fails
            raise ConfigError(field, f"module {module_name!r} has no attribute {attr!r}", name) from None
    return obj


# ---------------------------------------------------------------------------------------- paths pbdyn writes to
NAME_MAX = 255
"""Longest file or folder name, in bytes (ext4, XFS, APFS, NTFS)."""
PATH_MAX = 4096
"""Longest path, in bytes (Linux)."""


def check_path_length(field: str, path) -> None:
    """ConfigError naming ``field`` if a component of ``path`` is longer than NAME_MAX bytes or the absolute path
    longer than PATH_MAX bytes, or if it is not UTF-8 text (bytes such as b"\\xff", decoded by os.fsdecode into
    surrogates, which no store, card or JSON summary can hold)."""
    p = Path(path)
    try:
        str(p).encode("utf-8")
    except UnicodeEncodeError:
        raise ConfigError(field, "is not valid UTF-8 text (a byte such as 0xff in the name); give a UTF-8 name",
                          str(path)) from None
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


def _check_named(field: str, path, what: str) -> Path:
    """``path`` as a Path; ConfigError naming ``field`` if it is empty (which would mean the current folder), holds
    a NUL character, or has a name or length beyond the file system's limits."""
    text = os.fspath(path)
    if isinstance(text, bytes):
        text = os.fsdecode(text)
    if not text.strip():
        raise ConfigError(field, f"is empty; give a {what}", text)
    if "\0" in text:
        raise ConfigError(field, "holds a NUL character", text)
    check_path_length(field, text)
    return Path(text)


def _check_folder_accepts(field: str, folder: Path, shown, make_parents: bool) -> None:
    """ConfigError naming ``field`` unless new files can be made in ``folder`` (``make_parents``: or in the folders
    that would be created down to it): its nearest existing ancestor is a folder where a temporary file can be
    created (and is removed at once)."""
    anc = folder
    while not os.path.lexists(anc):
        if not make_parents:
            raise ConfigError(field, f"its folder {folder} does not exist", str(shown))
        anc = anc.parent
    if not anc.is_dir():
        raise ConfigError(field, f"cannot be written: {anc} is a file, not a folder", str(shown))
    try:
        fd, tmp = tempfile.mkstemp(prefix=".pbdyn-write-test-", dir=anc)
        os.close(fd)
        os.unlink(tmp)
    except OSError as exc:
        raise ConfigError(field, f"cannot be written: the folder {anc} does not accept new files "
                          f"({exc.strerror or exc})", str(shown)) from None


def check_writable_file(field: str, path, *, make_parents: bool = False) -> Path:
    """``path`` as a Path a new file can be written at, checked before any work and creating nothing; ConfigError
    naming ``field`` if it is empty, ends in a path separator, names a folder, has too long a name, or its folder is
    missing (``make_parents``: the folders to create are blocked by a file), or does not accept new files (a
    read-only folder or file system), or the file exists and is not writable."""
    p = _check_named(field, path, "file name")
    if os.fsdecode(os.fspath(path)).endswith(("/", os.sep)) or p.is_dir():
        raise ConfigError(field, "is a folder; give a file name", str(path))
    _check_folder_accepts(field, p.absolute().parent, path, make_parents)
    if p.exists() and not os.access(p, os.W_OK):
        raise ConfigError(field, "exists and is not writable", str(path))
    return p


def check_writable_folder(field: str, path) -> Path:
    """``path`` as a Path of a folder files can be written into (it, and the folders above it, are created by the
    writer when missing), checked before any work and creating nothing; ConfigError naming ``field`` if it is
    empty, too long, a file, blocked by a file on the way, or in a folder that does not accept new files."""
    p = _check_named(field, path, "folder")
    if os.path.lexists(p) and not p.is_dir():
        raise ConfigError(field, "is a file; give a folder", str(path))
    _check_folder_accepts(field, p.absolute(), path, make_parents=True)
    return p
