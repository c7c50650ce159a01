"""numba's njit for pbdyn's compiled functions: numba loads on the first compiled call, and its on-disk cache
(``cache=True``) never stops pbdyn from running.

Loaded on first use: importing numba and setting it up for its first compiled call costs about a CPU-second, which
a process that calls no compiled function (`pbdyn batch`'s coordinator, `pbdyn evaluate`, `pbdyn --version`) need not
pay. Until then ``njit`` and ``intrinsic`` return stand-ins that hold the function and its options. The first call
of any stand-in (or a look at a dispatcher attribute) imports numba, decorates every function registered so far
exactly as numba's own decorators would, and puts the decorated objects in place of the stand-ins in the namespaces
of the loaded modules that hold them; compiled callers therefore see numba's dispatchers as if the functions had
been decorated at import, and compile to the same code. From then on the decorators decorate at once. A stand-in
kept elsewhere still works: it calls, and numba types it as, the dispatcher it stands for.

The cache: numba caches a function beside its module (__pycache__) or in the user's cache folder; when it can write
to neither (a read-only installation with no writable HOME) it refuses to decorate the function at all. pbdyn's
functions then cache in a private folder of the system temp folder, and if that is unusable too, compile in memory
only.
"""

from __future__ import annotations

import functools
import importlib
import os
import stat
import sys
import tempfile
import threading
from pathlib import Path

_LOCK = threading.RLock()
_PENDING: list[_Deferred] = []     # stand-ins made before numba was loaded, in order
_LOADED = False                   # numba is loaded and every stand-in has been decorated


def njit(fn=None, **options):
    """numba.njit(**options), as a decorator with or without arguments; numba loads on the first compiled call and
    ``cache=True`` never fails (module doc)."""
    if fn is None:
        return lambda f: njit(f, **options)
    return _defer(fn, options, _decorate_njit)


def intrinsic(fn):
    """numba.core.extending.intrinsic(fn), loaded like njit's functions (module doc)."""
    return _defer(fn, {}, _decorate_intrinsic)


def loaded() -> bool:
    """True once numba has been loaded for pbdyn's compiled functions (a compiled function has been called)."""
    return _LOADED


def _defer(fn, options: dict, decorate):
    with _LOCK:
        if _LOADED:
            return decorate(fn, options)
        stand_in = _Deferred(fn, options, decorate)
        _PENDING.append(stand_in)
        return stand_in


class _Deferred:
    """A compiled function's stand-in until numba is loaded (module doc)."""

    def __init__(self, fn, options: dict, decorate):
        functools.update_wrapper(self, fn)
        self._fn, self._options, self._decorate, self._real = fn, options, decorate, None

    def _target(self):
        """The numba object this stand-in stands for (loading numba first if needed)."""
        if self._real is None:
            _load()
        return self._real

    def __call__(self, *args, **kwargs):
        return self._target()(*args, **kwargs)

    def __getattr__(self, name: str):     # attributes of the dispatcher (py_func, targetoptions, signatures, ...)
        if name.startswith("__") or name in ("_fn", "_options", "_decorate", "_real"):
            raise AttributeError(name)
        return getattr(self._target(), name)

    @property
    def _numba_type_(self):
        """numba's type of the object this stands for (numba.typeof reads it: a stand-in passed to, or seen as a
        global by, a compiled function is typed as its dispatcher)."""
        from numba.core.registry import cpu_target

        return cpu_target.typing_context.resolve_value_type(self._target())

    def __reduce__(self):
        return _module_attribute, (self.__module__, self.__qualname__)

    def __repr__(self) -> str:
        return f"<pbdyn.jit stand-in for {self.__module__}.{self.__qualname__}>"


def _module_attribute(module: str, qualname: str):
    obj = importlib.import_module(module)
    for part in qualname.split("."):
        obj = getattr(obj, part)
    return obj


def _load() -> None:
    """Import numba, decorate every pending stand-in's function, and put the results in place of the stand-ins in
    the namespaces of the loaded modules (pbdyn's and those that defined a stand-in)."""
    global _LOADED
    with _LOCK:
        if _LOADED:
            return
        for stand_in in _PENDING:
            if stand_in._real is None:
                stand_in._real = stand_in._decorate(stand_in._fn, stand_in._options)
        _LOADED = True
        owners = {s.__module__ for s in _PENDING}
        _PENDING.clear()
        for name, module in list(sys.modules.items()):
            if module is None or not (name == "pbdyn" or name.startswith("pbdyn.") or name in owners):
                continue
            namespace = getattr(module, "__dict__", None)
            if not isinstance(namespace, dict):
                continue
            for key, value in list(namespace.items()):
                if isinstance(value, _Deferred):
                    namespace[key] = value._real


def _decorate_intrinsic(fn, options: dict):
    from numba.core.extending import intrinsic as numba_intrinsic

    return numba_intrinsic(fn)


def _decorate_njit(fn, options: dict):
    """numba.njit(**options)(fn); with cache=True in a private temp folder, or without a cache, where numba finds
    no folder to cache in (module doc)."""
    import numba

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
