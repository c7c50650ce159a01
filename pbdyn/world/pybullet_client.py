"""PyBullet itself for pbdyn: its quiet import, new clients, the GUI's display check and stdout redirection around
PyBullet's C-level chatter. Every pbdyn module that needs the pybullet module takes it from here, so that its
import banner is silenced wherever it is first imported.
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator

from pbdyn.errors import ConfigError
from pbdyn.usercode import flush_c_stdout as _flush_c_stdout
from pbdyn.usercode import stdout_fd_to as _stdout_to


def stdout_to_stderr():
    """Redirect file descriptor 1 to descriptor 2 for the duration (PyBullet prints on import, connect, loadURDF)."""
    return _stdout_to(2)


def silenced_stdout():
    """Send file descriptor 1 to /dev/null for the duration (PyBullet's connect prints a bare "argv[0]=" banner that
    carries no information)."""
    return _stdout_to(None)


@contextlib.contextmanager
def _quiet_import() -> Iterator[None]:
    """Silence file descriptors 1 and 2 while PyBullet imports (its build-time banner carries no information;
    import errors still raise as Python exceptions)."""
    sys.stdout.flush()
    sys.stderr.flush()
    _flush_c_stdout()
    saved = [os.dup(1), os.dup(2)]
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
        yield
    finally:
        _flush_c_stdout()
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, devnull):
            os.close(fd)


with _quiet_import():
    import pybullet
    from pybullet_utils import bullet_client


def check_display() -> None:
    """ConfigError naming ``gui`` if PyBullet's GUI has no display to open a window on (X11 systems without DISPLAY,
    where PyBullet would end the process itself)."""
    if not sys.platform.startswith(("linux", "freebsd", "openbsd", "netbsd")):
        return
    display = os.environ.get("DISPLAY", "")
    if not display:
        raise ConfigError("gui", "needs a display and DISPLAY is not set (`gui_snapshot` FILE.png renders the final "
                          "state without one)", show_value=False)
    problem = _x_server_problem(display)
    if problem:
        raise ConfigError("gui", f"cannot reach the X server of DISPLAY={display!r} ({problem}; `gui_snapshot` "
                          "FILE.png renders the final state without one)", show_value=False)


def _x_server_problem(display: str, timeout: float = 2.0) -> str | None:
    """Why no X server answers at ``display`` ("[host]:N[.S]"), or None: a local display needs its socket
    /tmp/.X11-unix/XN to accept a connection, a remote one TCP port 6000 + N."""
    import socket

    host, _, rest = display.rpartition(":")
    number = rest.split(".")[0]
    if not number.isdigit():
        return "not a display name like :0"
    if host in ("", "unix"):
        path = f"/tmp/.X11-unix/X{number}"
        try:
            with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
                sock.settimeout(timeout)
                sock.connect(path)
        except OSError as exc:
            return f"{path}: {exc.strerror or exc}"
        return None
    try:
        with socket.create_connection((host, 6000 + int(number)), timeout=timeout):
            return None
    except OSError as exc:
        return f"{host}:{6000 + int(number)}: {exc.strerror or exc}"


def new_client(gui: bool = False):
    """A new BulletClient (DIRECT, or GUI: check_display first), its banner silenced; the caller disconnects it."""
    if gui:
        check_display()
    with silenced_stdout():
        return bullet_client.BulletClient(connection_mode=pybullet.GUI if gui else pybullet.DIRECT)
