"""numba's njit for pbdyn's compiled functions, whose on-disk cache (``cache=True``) never stops pbdyn from running.

numba caches a function beside its module (__pycache__) or in the user's cache folder; when it can write to neither
(a read-only installation with no writable HOME) it refuses to decorate the function at all. pbdyn's functions then
cache in a private folder of the system temp folder, and if that is unusable too, compile in memory only.
"""

from __future__ import annotations

import functools
import os
import stat
import tempfile
from pathlib import Path

import numba


def njit(fn=None, **options):
    """numba.njit(**options), as a decorator with or without arguments; see the module doc for ``cache=True``."""
    if fn is None:
        return lambda f: njit(f, **options)
    try:
        return numba.njit(**options)(fn)
    except RuntimeError:            # "cannot cache function ...: no locator available"
        if not options.get("cache"):
            raise
    folder = _private_cache_folder()
    if folder is not None:
        saved, numba.config.CACHE_DIR = numba.config.CACHE_DIR, folder   # read when the cache is located
        try:
            return numba.njit(**options)(fn)
        except RuntimeError:
            pass
        finally:
            numba.config.CACHE_DIR = saved
    return numba.njit(**{**options, "cache": False})(fn)


@functools.cache
def _private_cache_folder() -> str | None:
    """<temp>/pbdyn-numba-<uid>, created 0700 if missing, if it is a folder only this user can write; else None
    (a shared temp folder must not hand us another user's compiled code)."""
    uid = os.getuid() if hasattr(os, "getuid") else None
    path = Path(tempfile.gettempdir()) / f"pbdyn-numba-{uid if uid is not None else 'user'}"
    try:
        path.mkdir(mode=0o700, exist_ok=True)
        st = os.lstat(path)
    except OSError:
        return None
    if not stat.S_ISDIR(st.st_mode) or (uid is not None and st.st_uid != uid) or st.st_mode & 0o022:
        return None
    return str(path)
