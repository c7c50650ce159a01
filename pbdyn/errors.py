"""Errors pbdyn reports to users as one line (the CLI exits with status 2 on them)."""

from __future__ import annotations

import math
import unicodedata


class PbdynError(Exception):
    """Base class of every error pbdyn reports as a one-line message (str() escapes control characters)."""

    def __str__(self) -> str:
        return one_line_text(super().__str__())


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
