"""Code identity by content: which code produced a row, a rollout or a metric value (docs/design.md "Code identity").

An identity is the sha256 (first IDENTITY_CHARS hex digits) over the source files of a set of modules: the modules
named and, for pbdyn's own modules, every pbdyn module they import, found by reading the import statements of each
file (at module level and inside functions; ``importlib.import_module("pbdyn...")`` with a literal name too), with
the packages that contain them (their ``__init__.py`` runs on import) and the C/C++ sources beside a compiled part
(SOURCE_SUFFIXES). Nothing is imported to compute it. Any edit of one of those files gives a new identity, and
reverting the edit gives back the old one, so a store, a rollout or a metric cache keyed by it never mixes the
results of two versions of the code, and serves the old values again after a revert.

What identifies what (pbdyn.planning.registry, pbdyn.world.rollout, pbdyn.metrics.cached):
- a built-in planner: its module and the pbdyn modules it uses;
- the trial core (every row): pbdyn.sim.trial and the pbdyn modules it uses, less the obstacle motion models
  (a map's rollout identifies those);
- a rollout: pbdyn.world.rollout and the modules it uses, less the motion models, plus the map's own model;
- a metric value: the metric's module and its survivability backend's, with the modules they use;
- a plug-in ("package.module:Class"): user_identity -- its package's files, or, for a lone module, the module and
  the user modules it imports (outside the standard library and installed packages), with the pbdyn modules any of
  them uses.

Cost: one read and sha256 per file, cached per installed build on disk (``<cache>/code/``, keyed by the folder and
each file's size and modification time, as Python's own bytecode cache is) and per process; docs/performance.md
has the measured figures. This module imports only pbdyn.files (the cache folder, atomic writes).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import sys
import sysconfig
import threading
from pathlib import Path

from pbdyn.files import atomic_write_text, cache_dir

IDENTITY_CHARS = 16
"""Hex digits of an identity (64 bits: two different versions of the code never meet under one identity)."""

PACKAGE_DIR = Path(__file__).resolve().parent
"""The folder of the pbdyn package whose code is identified."""

_OWN_PREFIX = str(PACKAGE_DIR) + os.sep

SOURCE_SUFFIXES = (".cpp", ".cc", ".c", ".h", ".hpp")
"""Non-Python sources of a package (a compiled part's C++), part of the package's identity."""

MOTION_MODELS = ("pbdyn.motion.cvm", "pbdyn.motion.rvo")
"""The obstacle motion models' modules (pbdyn.motion.registry.MODELS; a test keeps the two in step): a rollout's
identity holds only its own model's, and the core's none (a row's world fingerprint identifies its rollout)."""

CORE_ROOTS = ("pbdyn.sim.trial",)
"""The trial core's entry: every row is flown through pbdyn.sim.trial.fly_trials."""

MAX_USER_FILES = 5_000
"""A plug-in's package may hold at most this many source files (a path that points at a whole drive is an error,
not a long wait)."""

_IMPORT = re.compile(
    r"^[ \t]*(?:from[ \t]+(?P<base>\.*[\w.]*)[ \t]+import[ \t]+(?P<names>\([^)]*\)|[^\n#]*)"
    r"|import[ \t]+(?P<mods>[^\n#]*))", re.M)
_DYNAMIC = re.compile(r"""import_module\(\s*["']([\w.]+)["']""")
_lock = threading.Lock()
_files: dict[str, tuple] = {}          # absolute path -> (size, mtime_ns, sha256 hex, imports)
_seen: dict[str, tuple] = {}          # this process's answers for pbdyn's files: read (or checked) once per process
_dirty = False
_loaded = False


def _record_path() -> Path:
    tag = hashlib.sha256(str(PACKAGE_DIR).encode()).hexdigest()[:16]
    return cache_dir() / "code" / f"files-{tag}.json"


def _load_record() -> None:
    global _loaded
    if _loaded:
        return
    _loaded = True
    try:
        doc = json.loads(_record_path().read_text(encoding="utf-8"))
        if isinstance(doc, dict):
            for path, entry in doc.items():
                if isinstance(entry, list) and len(entry) == 4:
                    _files.setdefault(path, (entry[0], entry[1], entry[2], tuple(entry[3])))
    except (OSError, ValueError):
        pass


def save_record() -> None:
    """Write the per-file digests learnt by this process to the cache (atomic; a read-only cache is skipped)."""
    global _dirty
    with _lock:
        if not _dirty:
            return
        doc = {p: [e[0], e[1], e[2], list(e[3])] for p, e in _files.items() if p.startswith(str(PACKAGE_DIR))}
        _dirty = False
    try:
        atomic_write_text(_record_path(), json.dumps(doc, sort_keys=True), make_parents=True)
    except OSError:
        pass


def _imports(text: str, module: str, is_package: bool) -> tuple[str, ...]:
    """Dotted names a module's text imports (absolute; relative imports resolved against ``module``)."""
    out: list[str] = []
    for m in _IMPORT.finditer(text):
        if m.group("mods") is not None:
            out += [part.split(" as ")[0].strip() for part in m.group("mods").split(",")]
            continue
        base = m.group("base")
        level = len(base) - len(base.lstrip("."))
        if level:
            pkg = module.split(".") if is_package else module.split(".")[:-1]
            pkg = pkg[:len(pkg) - level + 1]
            rest = base.lstrip(".")
            base = ".".join(pkg + ([rest] if rest else []))
        out.append(base)
        names = m.group("names").strip("() \t\n")
        out += [f"{base}.{n.split(' as ')[0].strip()}" for n in names.replace("\n", ",").split(",")
                if n.strip() and n.strip() != "*"]
    out += _DYNAMIC.findall(text)
    return tuple(dict.fromkeys(n for n in out if n))


def _file(path: Path, module: str = "", is_package: bool = False) -> tuple[str, tuple[str, ...]]:
    """(sha256 hex of the file's bytes, the modules it imports) of one file, from the caches when its size and
    modification time are unchanged."""
    global _dirty
    key = str(path)
    seen = _seen.get(key)
    if seen is not None:
        return seen
    st = path.stat()
    own = key.startswith(_OWN_PREFIX)
    with _lock:
        _load_record()
        hit = _files.get(key)
        if hit is not None and hit[0] == st.st_size and hit[1] == st.st_mtime_ns:
            if own:
                _seen[key] = (hit[2], hit[3])
            return hit[2], hit[3]
    data = path.read_bytes()
    digest = hashlib.sha256(data.replace(b"\r\n", b"\n")).hexdigest()
    imports = _imports(data.decode("utf-8", "replace"), module, is_package) if path.suffix == ".py" else ()
    with _lock:
        _files[key] = (st.st_size, st.st_mtime_ns, digest, imports)
        if own:
            _seen[key] = (digest, imports)
        _dirty = own or _dirty
    return digest, imports


_index: dict[str, tuple[Path, bool]] = {}


def _pbdyn_file(module: str) -> tuple[Path, bool] | None:
    """(source file, is a package) of a pbdyn module name, or None if no such module exists (the package's files
    are listed once per process)."""
    if not _index:
        for folder, dirs, names in os.walk(PACKAGE_DIR):
            dirs[:] = sorted(d for d in dirs if d != "__pycache__")
            rel = Path(folder).relative_to(PACKAGE_DIR).parts
            for n in names:
                if n.endswith(".py"):
                    if n == "__init__.py":
                        _index[".".join(("pbdyn",) + rel)] = (Path(folder) / n, True)
                    else:
                        _index.setdefault(".".join(("pbdyn",) + rel + (n[:-3],)), (Path(folder) / n, False))
    return _index.get(module)


def pbdyn_closure(roots, exclude=()) -> list[str]:
    """The pbdyn modules ``roots`` import, directly or not (with their packages), less ``exclude`` (not followed
    either), sorted; names that are not pbdyn modules (attributes imported from one) are dropped."""
    seen: set[str] = set()
    todo = [r for r in roots]
    excluded = set(exclude)
    while todo:
        name = todo.pop()
        if name in seen or name in excluded:
            continue
        found = _pbdyn_file(name)
        if found is None:
            continue
        seen.add(name)
        path, is_package = found
        _, imports = _file(path, name, is_package)
        parent = name.rpartition(".")[0]
        if name != "pbdyn":              # the package root imports the api only when a name of it is asked for
            todo += [n for n in imports if n.startswith("pbdyn.") or n == "pbdyn"]
        if parent:
            todo.append(parent)
    return sorted(seen)


def _digest(entries) -> str:
    h = hashlib.sha256()
    for name, digest in entries:
        h.update(name.encode() + b"\0" + digest.encode() + b"\n")
    return h.hexdigest()[:IDENTITY_CHARS]


def _module_entries(modules) -> list[tuple[str, str]]:
    out = []
    for name in modules:
        path, is_package = _pbdyn_file(name)
        out.append((name, _file(path, name, is_package)[0]))
        if is_package:
            out += [(f"{name}/{p.name}", _file(p)[0]) for p in sorted(path.parent.iterdir())
                    if p.suffix in SOURCE_SUFFIXES and p.is_file()]
    return out


_identities: dict[tuple, str] = {}


def identity(roots, exclude=()) -> str:
    """The identity (IDENTITY_CHARS hex digits) of pbdyn modules ``roots`` and everything of pbdyn they import, less
    ``exclude`` (module doc); cached per process (clear_cache() forgets it)."""
    key = (tuple(roots), tuple(exclude))
    got = _identities.get(key)
    if got is None:
        got = _identities[key] = _digest(_module_entries(pbdyn_closure(roots, exclude)))
        save_record()
    return got


def core_identity() -> str:
    """The trial core's identity: CORE_ROOTS and what they use, less the motion models (module doc)."""
    return identity(CORE_ROOTS, MOTION_MODELS)


def _installed_dirs() -> tuple[str, ...]:
    """Folders whose modules are not a user's own: the standard library and installed packages."""
    paths = sysconfig.get_paths()
    dirs = {paths.get(k) for k in ("stdlib", "platstdlib", "purelib", "platlib")}
    dirs |= {p for p in sys.path if p and os.path.basename(p.rstrip(os.sep)) in ("site-packages", "dist-packages")}
    return tuple(sorted(str(Path(d).resolve()) + os.sep for d in dirs if d))


def _user_file(name: str) -> tuple[Path, bool] | None:
    """(source file, is a package) of a module outside pbdyn, the standard library and installed packages, found
    without importing it (a module already imported is read from sys.modules)."""
    import importlib.util

    mod = sys.modules.get(name)
    origin = getattr(mod, "__file__", None) if mod is not None else None
    is_package = hasattr(mod, "__path__") if mod is not None else False
    if origin is None and mod is None:
        try:
            spec = importlib.util.find_spec(name)
        except (ImportError, ValueError, AttributeError):
            return None
        if spec is None or not spec.origin or not spec.has_location:
            return None
        origin, is_package = spec.origin, spec.submodule_search_locations is not None
    if not origin or not origin.endswith(".py"):
        return None
    path = Path(origin).resolve()
    if str(path).startswith(_installed_dirs()) or str(path).startswith(str(PACKAGE_DIR) + os.sep):
        return None
    return path, is_package


def user_identity(module: str, *extra: str) -> str:
    """The identity of a plug-in's code: for a module inside a package of the user's, every source file of the
    top-level package; for a lone module, its file and the user modules it imports, transitively; with the pbdyn
    modules any of them imports. ``extra``: further modules (the one that defines the plug-in's class). Modules of
    the standard library and of installed packages count by name only (their versions are the installer's)."""
    files: dict[Path, str] = {}
    pbdyn_used: list[str] = []
    named = [module, *extra]
    todo = list(named)
    seen: set[str] = set()
    tops: set[str] = set()
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        if name == "pbdyn" or name.startswith("pbdyn."):
            pbdyn_used.append(name)
            continue
        top = name.split(".")[0]
        if top in tops or top in sys.stdlib_module_names:
            continue
        found = _user_file(top)                   # a top-level name is found without importing anything
        if found is None and name in named:       # a plug-in in a namespace package: its own file
            found = _user_file(name)
            top = name
        if found is None:
            continue
        tops.add(top)
        path, is_package = found
        if not is_package:                        # a lone module: its file, then the modules it imports
            digest, imports = _file(path, top, False)
            files[path] = f"{top}\0{digest}"
            todo += list(imports)
            continue
        root = path.parent                        # a package of the user's: all of it
        sources = [p for p in sorted(root.rglob("*")) if p.suffix in (".py",) + SOURCE_SUFFIXES
                   and "__pycache__" not in p.parts and p.is_file()]
        if len(sources) > MAX_USER_FILES:
            raise ValueError(f"package {top!r} ({root}) holds more than {MAX_USER_FILES:,} source files")
        for p in sources:
            rel = ".".join((top,) + p.relative_to(root).with_suffix("").parts).removesuffix(".__init__")
            digest, imports = _file(p, rel, p.name == "__init__.py")
            files[p] = f"{top}/{p.relative_to(root).as_posix()}\0{digest}"
            todo += list(imports)
    entries = [(v, "") for v in sorted(files.values())]
    entries += _module_entries(pbdyn_closure(pbdyn_used))
    out = _digest(entries)
    save_record()
    return out


def clear_cache() -> None:
    """Forget this process's identities and file answers (after an edit in this process; files are then read
    again where their size or modification time changed)."""
    _identities.clear()
    _seen.clear()
    _index.clear()
