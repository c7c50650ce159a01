"""A motion-function module that calls sys.exit when it is imported (tests/test_usercode.py)."""

import sys

sys.exit(4)


def f(t, **_):  # pragma: no cover - never reached
    return [25.0, 25.0, 2.0]
