"""Errors pbdyn reports to users as one line (the CLI exits with status 2 on them)."""

from __future__ import annotations


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
