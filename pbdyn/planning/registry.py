"""Planner registry: built-in names -> classes, and user plug-ins given as "package.module:Class" (duck typing).

A built-in planner's module is imported when its name is first looked up, so a process loads only the planners it
flies (the MPC's convex solver, the global planner's search, ... stay unloaded otherwise)."""

from __future__ import annotations

import functools
import importlib
import inspect
from collections.abc import Iterator, MutableMapping

from pbdyn.errors import ConfigError, check_finite_params, import_object, one_line, user_location
from pbdyn.planning.protocols import PlannerContext


class _Registry(MutableMapping):
    """name -> planner class, each built-in given as "module:Class" and imported on first lookup; entries can be
    added, replaced and removed like a dict's (tests and benchmarks add their own planners)."""

    def __init__(self, entries: dict[str, str]):
        self._entries: dict[str, object] = dict(entries)

    def __getitem__(self, name: str) -> type:
        value = self._entries[name]
        if isinstance(value, str):
            module, _, attr = value.partition(":")
            value = getattr(importlib.import_module(module), attr)
            self._entries[name] = value
        return value

    def __setitem__(self, name: str, cls: type) -> None:
        self._entries[name] = cls

    def __delitem__(self, name: str) -> None:
        del self._entries[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._entries)

    def __len__(self) -> int:
        return len(self._entries)

    def __contains__(self, name: object) -> bool:
        return name in self._entries

    def __repr__(self) -> str:
        return f"{type(self).__name__}({sorted(self._entries)})"


_P = "pbdyn.planning."
TRAJECTORY_PLANNERS: MutableMapping[str, type] = _Registry({
    "local_primitives": _P + "primitives.local:LocalPrimitives", "straight_line": _P + "straight_line:StraightLine",
    "mpc": _P + "mpc.planner:MPC", "global_primitives": _P + "primitives.global_astar:GlobalPrimitives",
    "local_primitives_minjerk": _P + "primitives.minjerk:LocalPrimitivesMinJerk"})
GAZE_PLANNERS: MutableMapping[str, type] = _Registry({
    "lookahead": _P + "gaze.rules:LookAhead", "fullrange": _P + "gaze.rules:FullRange",
    "lookgoal": _P + "gaze.rules:LookGoal", "lookgoal_unexplored": _P + "gaze.rules:LookGoalUnexplored",
    "rotating": _P + "gaze.rules:Rotating", "finean": _P + "gaze.finean:Finean", "owl": _P + "gaze.owl:Owl"})

_TRAJECTORY_METHODS = ("replan_check", "plan")
_GAZE_METHODS = ("yaw_rate",)


def _resolve(name: object, field: str, kind: str, registry: dict[str, type], methods: tuple[str, ...]) -> type:
    if not isinstance(name, str) or not name:
        raise ConfigError(field, f"must be a {kind} planner name or 'package.module:Class'", name)
    if name in registry:
        return registry[name]
    if ":" not in name:
        known = ", ".join(sorted(registry))
        raise ConfigError(field, f"unknown {kind} planner (known: {known}; or 'package.module:Class')", name)
    module_name, _, attr = name.partition(":")
    if not module_name or not attr:
        raise ConfigError(field, "a plug-in must be given as 'package.module:Class'", name)
    obj = import_object(name, field)
    if not callable(obj):
        raise ConfigError(field, f"{attr!r} is not a class or factory", name)
    missing = [m for m in methods if not callable(getattr(obj, m, None))]
    if missing:
        raise ConfigError(field, f"{attr!r} is not a {kind} planner: missing method(s) {', '.join(missing)}", name)
    return obj


def resolve_trajectory_planner(name: str, field: str = "trajectory") -> type:
    """The trajectory planner class for a registry name or "package.module:Class"; ConfigError naming ``field``."""
    return _resolve(name, field, "trajectory", TRAJECTORY_PLANNERS, _TRAJECTORY_METHODS)


def resolve_gaze_planner(name: str, field: str = "gaze") -> type:
    """The gaze planner class for a registry name or "package.module:Class"; ConfigError naming ``field``."""
    return _resolve(name, field, "gaze", GAZE_PLANNERS, _GAZE_METHODS)


def build_planner(cls: type, context: PlannerContext, params: dict | None, field: str):
    """Instantiate ``cls(context, **params)``; unknown or invalid params raise ConfigError naming ``field``: an
    unknown key, a non-finite float (NaN, +-inf, also inside lists, tuples and tables; named ``field``.<key>), or
    any exception the constructor raises (built-in planners check their own ranges; a plug-in's is located at the
    file:line of its code, pbdyn.errors.user_location)."""
    params = dict(params or {})
    name = getattr(cls, "__name__", repr(cls))
    try:
        accepted = _accepted_params(cls)
    except TypeError:                      # not hashable: ask for its signature every time
        accepted = _accepted_params.__wrapped__(cls)
    if accepted is not None:
        for key in params:
            if key not in accepted:
                hint = ", ".join(accepted) if accepted else "none"
                raise ConfigError(f"{field}.{key}", f"unknown parameter of {name} (accepted: {hint})", params[key])
    check_finite_params(params, field)
    try:
        return cls(context, **params)
    except ConfigError:
        raise
    except Exception as exc:  # any failure of a planner's constructor (built-in or user code) is a bad entry
        where = user_location(exc)
        err = ConfigError(field, f"invalid parameters for {name} ({one_line(exc)})"
                          + (f" (at {where})" if where else ""), params)
        err.location = where
        raise err from exc


@functools.lru_cache(maxsize=256)
def _accepted_params(cls) -> tuple[str, ...] | None:
    """The keyword parameters a planner class takes after its context (from its signature), or None when it takes
    any (``**kwargs``) or has no readable signature; cached per class (a trial builds two planners)."""
    try:
        sig = inspect.signature(cls)
    except (TypeError, ValueError):
        return None
    ps = list(sig.parameters.values())
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in ps):
        return None
    return tuple(p.name for p in ps[1:]
                 if p.kind in (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY))


def _entry_module(name: str) -> str:
    """The module a registry name's planner lives in (its entry's "module:Class", or the class put there)."""
    for reg in (TRAJECTORY_PLANNERS, GAZE_PLANNERS):
        if name in reg:
            value = reg._entries[name] if isinstance(reg, _Registry) else reg[name]
            return value.partition(":")[0] if isinstance(value, str) else getattr(value, "__module__", "")
    raise KeyError(name)


@functools.lru_cache(maxsize=None)
def planner_fingerprint(name: str) -> str:
    """What code a planner name runs, by content (docs/design.md "Code identity"; pbdyn.codeid): "pbdyn:" + the
    identity of a built-in's module and the pbdyn modules it uses; for a plug-in "package.module:Class" (or a class
    a caller put in the registry), "sha256:" + the identity of its package, or of its module and the user modules
    it imports, with the module that defines the object. Cached per process (``planner_fingerprint.cache_clear()``
    with pbdyn.codeid.clear_cache() after an edit). Unknown names raise ConfigError."""
    from pbdyn import codeid

    if name in TRAJECTORY_PLANNERS or name in GAZE_PLANNERS:
        module = _entry_module(name)
        if module == "pbdyn" or module.startswith("pbdyn."):
            return "pbdyn:" + codeid.identity((module,))
        modules = (module,)
    else:
        if not isinstance(name, str) or ":" not in name:
            raise ConfigError("planner", "unknown planner (a registry name or 'package.module:Class')", name)
        obj = import_object(name, "planner")
        module = name.partition(":")[0]
        modules = (module, getattr(obj, "__module__", None) or module)
    try:
        return "sha256:" + codeid.user_identity(*dict.fromkeys(modules))
    except (OSError, ValueError) as exc:
        raise ConfigError("planner", f"its code cannot be identified ({one_line(exc)})", name) from None


def pair_fingerprint(trajectory: str, gaze: str) -> str:
    """The code fingerprint of a (trajectory, gaze) entry's rows: "<trajectory's>+<gaze's>+core:<the trial core's
    identity>" (planner_fingerprint, pbdyn.codeid.core_identity): an edit of either planner or of the code every
    trial runs through gives rows a new fingerprint."""
    from pbdyn import codeid

    return f"{planner_fingerprint(trajectory)}+{planner_fingerprint(gaze)}+core:{codeid.core_identity()}"


def recorded_fingerprint(trajectory: str, gaze: str) -> str:
    """pair_fingerprint as a row records it: "" where the pair's code cannot be identified (e.g. a planner class
    defined inside a function, which cannot be imported by its name)."""
    try:
        return pair_fingerprint(trajectory, gaze)
    except Exception:
        return ""
