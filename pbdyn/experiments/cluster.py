"""Reaching a Dask scheduler for `pbdyn batch --scheduler`: parsing its address, probing it, connecting a Client.

A tcp address is probed before dask sees it (a Dask comm sends its handshake as soon as it accepts), so a silent port
or a web server is refused within PROBE_TIMEOUT_S instead of hanging; every failure is one ConfigError naming
--scheduler (docs/experiments.md, "Dask").
"""

from __future__ import annotations

import threading
import time

from pbdyn.errors import ConfigError, one_line

CONNECT_TIMEOUT_S = 10.0
"""How long connect() may take by default, in s (the probe and the Client together)."""
SCHEMES = ("tcp", "tls", "inproc", "ucx")
"""The address schemes --scheduler accepts (tls only as a Client made in Python)."""
PROBE_TIMEOUT_S = 3.0
"""How long a scheduler address may take to send Dask's handshake after accepting a connection, in s."""
_MAX_HANDSHAKE = 1 << 24


def _scheduler_error(problem: str, address: str) -> ConfigError:
    return ConfigError("scheduler", problem, address)


def parse_scheduler(address: str) -> tuple[str, str, int | None]:
    """(scheme, host, port) of a Dask scheduler address "SCHEME://HOST:PORT" (scheme tcp, tls, inproc or ucx;
    "HOST:PORT" means tcp); ConfigError naming --scheduler otherwise."""
    from urllib.parse import urlsplit

    if not isinstance(address, str) or not address.strip():
        raise _scheduler_error("must be a Dask scheduler address like tcp://host:8786", address)
    text = address.strip()
    if "://" not in text:
        text = "tcp://" + text
    try:
        u = urlsplit(text)
        port = u.port
    except ValueError as exc:
        raise _scheduler_error(f"is not an address like tcp://host:8786 ({exc})", address) from None
    scheme = u.scheme.lower()
    if scheme in ("http", "https"):
        raise _scheduler_error("is an HTTP address; give the scheduler's own address, like tcp://host:8786 (the "
                               "dashboard on :8787 is not the scheduler)", address)
    if scheme not in SCHEMES:
        raise _scheduler_error(f"has scheme {scheme!r}; use one of {', '.join(s + '://' for s in SCHEMES)}", address)
    if scheme == "inproc":
        return scheme, text[len("inproc://"):], None
    if u.path not in ("", "/") or u.query or u.fragment or u.username or u.password:
        raise _scheduler_error("must be SCHEME://HOST:PORT with nothing after the port", address)
    if not u.hostname:
        raise _scheduler_error("has no host (like tcp://host:8786)", address)
    if port is None or not 1 <= port <= 65535:
        raise _scheduler_error("needs a port in 1..65535 (like tcp://host:8786)", address)
    return scheme, u.hostname, port


def _in_thread(fn, timeout: float):
    """fn() in a daemon thread: ("ok", value), ("error", exception) or ("timeout", None) after ``timeout`` s (the
    thread is then abandoned; it cannot block the process' exit)."""
    box: list = []

    def target():
        try:
            box.append(("ok", fn()))
        except BaseException as exc:  # noqa: BLE001 - handed to the caller
            box.append(("error", exc))

    t = threading.Thread(target=target, name="pbdyn-connect", daemon=True)
    t.start()
    t.join(timeout)
    return box[0] if box else ("timeout", None)


def _probe(host: str, port: int, timeout: float) -> str | None:
    """None if a Dask comm listens at host:port (it sends the first frame of its handshake, an 8-byte length and
    a small message, as soon as it accepts), else what is wrong, in words."""
    import socket
    import struct

    try:
        sock = socket.create_connection((host, port), timeout=timeout)
    except socket.gaierror as exc:
        return f"cannot resolve the host ({exc.strerror or exc})"
    except (TimeoutError, socket.timeout):
        return f"no answer to a connection within {timeout:g} s"
    except OSError as exc:
        return f"cannot connect ({exc.strerror or exc})"
    with sock:
        deadline = time.monotonic() + timeout
        head = b""
        try:
            while len(head) < 8:
                sock.settimeout(max(0.01, deadline - time.monotonic()))
                chunk = sock.recv(8 - len(head))
                if not chunk:
                    return "the peer closed the connection without a Dask handshake"
                head += chunk
        except (TimeoutError, socket.timeout):
            what = _http_reply(sock)
            return (f"accepts connections but sent no Dask handshake within {timeout:g} s"
                    + (" (it answers HTTP: a web server, perhaps the dashboard, not the scheduler port)" if what else
                       " (not a Dask scheduler?)"))
        except OSError as exc:
            return f"the connection failed ({exc.strerror or exc})"
        if head[:4] in (b"HTTP", b"SSH-") or head[:1] == b"<":
            return f"answers like another protocol ({head[:8]!r}), not a Dask scheduler"
        (n,) = struct.unpack("<Q", head)
        if not 0 < n <= _MAX_HANDSHAKE:
            return f"sent a frame of {n} bytes where Dask's handshake is a small message (not a Dask scheduler?)"
    return None


def _http_reply(sock) -> bool:
    """After a silent wait: does the peer answer an HTTP request (with "HTTP/") within 0.5 s?"""
    try:
        sock.settimeout(0.5)
        sock.sendall(b"GET / HTTP/1.0\r\nHost: pbdyn\r\n\r\n")
        return sock.recv(5) == b"HTTP/"
    except OSError:
        return False


def connect(address: str, timeout: float | None = None):
    """A dask.distributed Client of the scheduler at ``address``. The address is checked (scheme tcp, tls, inproc
    or ucx; host; port 1..65535); a tcp address is probed first (a Dask comm sends its handshake on accept: a
    silent port or a web server is refused without handing it to dask, whose own timeout does not cover a peer
    that never answers); the Client is then created under an overall deadline. ``timeout``: seconds (default
    CONNECT_TIMEOUT_S). Every failure is a one-line ConfigError naming --scheduler; tls:// needs a
    dask.distributed Security object, so it is only accepted as a Client (run_batch(scheduler=Client(...)))."""
    timeout = CONNECT_TIMEOUT_S if timeout is None else float(timeout)
    scheme, host, port = parse_scheduler(address)
    if scheme == "tls":
        raise _scheduler_error("tls:// needs TLS certificates (a dask.distributed Security object), which a command "
                               "line address cannot carry: create the Client in Python and pass it, "
                               "pbdyn.run_batch(..., scheduler=Client(address, security=Security(...)))", address)
    t0 = time.monotonic()
    if scheme == "tcp":
        status, why = _in_thread(lambda: _probe(host, port, min(PROBE_TIMEOUT_S, timeout)), timeout)
        if status == "timeout":
            why = f"no answer within {timeout:g} s (host name lookup or connection hangs)"
        elif status == "error":
            why = one_line(why)
        if why:
            raise _scheduler_error(f"cannot reach a Dask scheduler there: {why}", address)
    left = max(1.0, timeout - (time.monotonic() - t0))
    target = f"{scheme}://{host}:{port}" if scheme != "inproc" else address.strip()

    def make():
        from dask.distributed import Client

        return Client(target, timeout=left)

    status, value = _in_thread(make, left + 2.0)
    if status == "ok":
        return value
    if status == "timeout":
        raise _scheduler_error(f"cannot reach a Dask scheduler there: no client connection within {left + 2.0:g} s",
                               address)
    raise _scheduler_error(f"cannot reach a Dask scheduler there ({one_line(value)[:200]})", address)
