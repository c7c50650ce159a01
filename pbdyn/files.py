"""Writing output files atomically: a temporary file in the target's folder, renamed over the target only once it
is complete (no partial result file is ever left behind), with the permissions an ordinary file gets (0o666 minus
the user's umask)."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path


def user_umask() -> int:
    """The process' umask (read without changing it for longer than the call)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write(path: str | Path, write: Callable[[str], None], *, make_parents: bool = False) -> Path:
    """Call ``write(tmp)`` to fill a temporary file beside ``path`` (same suffix), then rename it to ``path``; on any
    failure the temporary file is removed and the error raised. ``make_parents``: create the folder first."""
    path = Path(path)
    if make_parents:
        path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}-", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    try:
        write(tmp)
        os.chmod(tmp, 0o666 & ~user_umask())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path
