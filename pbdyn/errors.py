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
