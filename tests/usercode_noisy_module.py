"""A motion-function module that prints when it is imported (tests/test_usercode.py)."""

import os
import sys

print("noisy module imported")
os.write(1, b"noisy module fd 1\n")
sys.stdout.flush()


def circle(t, **_):
    return [25.0, 25.0, 2.0]
