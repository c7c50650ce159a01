"""Writing output files atomically: a temporary file in the target's folder, renamed over the target only once it
is complete (no partial result file is ever left behind), with the permissions an ordinary file gets (0o666 minus
the user's umask); and where pbdyn keeps its caches (cache_dir)."""

from __future__ import annotations

import errno
import os
import secrets
from collections.abc import Callable
from pathlib import Path


def create_temp(folder: str | Path, prefix: str = "", suffix: str = "") -> tuple[int, str]:
    """tempfile.mkstemp(suffix, prefix, folder) -- (open descriptor, absolute path) of a new file -- except that the
    file gets what any new file gets, 0o666 minus the umask (applied by the system), not 0o600: it is an output."""
    flags = os.O_RDWR | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_BINARY", 0)
    for _ in range(100):
        name = os.path.abspath(os.path.join(folder, f"{prefix}{secrets.token_hex(4)}{suffix}"))
        try:
            return os.open(name, flags, 0o666), name
        except FileExistsError:
            continue
    raise FileExistsError(errno.EEXIST, "no free temporary file name", str(folder))


NAME_MAX = 255
"""Longest file name, in bytes (ext4, XFS, APFS, NTFS)."""
_RANDOM_CHARS = 8
"""Characters create_temp puts between a prefix and a suffix."""


def temp_name_parts(path: Path) -> tuple[str, str]:
    """(prefix, suffix) of the temporary file written for ``path``: ".{stem}-" and its suffix, the stem shortened
    (whole characters) so that the temporary name stays within NAME_MAX bytes even when the target's name is at the
    limit; a suffix longer than 16 bytes is left out."""
    suffix = path.suffix if len(os.fsencode(path.suffix)) <= 16 else ""
    stem = path.name[:len(path.name) - len(suffix)] if suffix else path.name
    budget = NAME_MAX - 2 - _RANDOM_CHARS - len(os.fsencode(suffix))
    while len(os.fsencode(stem)) > budget:
        stem = stem[:-1]
    return f".{stem}-", suffix


def atomic_write(path: str | Path, write: Callable[[str], None], *, make_parents: bool = False) -> Path:
    """Call ``write(tmp)`` to fill a temporary file beside ``path`` (same suffix), then rename it to ``path``; on any
    failure the temporary file is removed and the error raised. ``make_parents``: create the folder first."""
    path = Path(path)
    if make_parents:
        path.parent.mkdir(parents=True, exist_ok=True)
    prefix, suffix = temp_name_parts(path)
    fd, tmp = create_temp(path.parent, prefix, suffix)
    os.close(fd)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def atomic_write_text(path: str | Path, text: str, *, make_parents: bool = False) -> Path:
    """atomic_write of ``text`` (UTF-8)."""
    return atomic_write(path, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"), make_parents=make_parents)


def cache_dir() -> Path:
    """pbdyn's cache folder (rollouts, metrics, the native library's check): $PBDYN_CACHE, else
    $XDG_CACHE_HOME/pbdyn, else ~/.cache/pbdyn."""
    env = os.environ.get("PBDYN_CACHE")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "pbdyn"
