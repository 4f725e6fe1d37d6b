"""``gx2-sim unplug NAME`` / ``replug NAME``: one station of a running gx2-sim pulled out
and plugged back, from another shell; ``gx2-sim power NODE on|off``: one node switched
on (it powers up, as a node added mid-study) or off.

A signal carries no name, so SIGUSR2 can only unplug every station. Each running
gx2-sim therefore listens on a UNIX socket of its own, ``<pid>.sock`` in a directory of
the user's (:func:`directory`), for one line a connection: ``unplug NAME SECONDS``
(0: until a replug), ``replug NAME`` or ``power NODE on|off``, answered by one line,
``ok ...`` or ``error ...`` (``stations`` and ``nodes`` list what it has). The command
finds the simulator that has a station of that NAME (a node of that address) among
those running; ``--pid`` picks one where several have it.
"""

from __future__ import annotations

import contextlib
import os
import socket
import socketserver
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path

REPLY_TIMEOUT = 2.0
"""Seconds the command waits for a simulator to answer (it answers at once)."""
MAX_LINE = 256


def directory() -> Path:
    """Where running simulators' sockets are: ``$XDG_RUNTIME_DIR/gx2-sim``, else
    ``gx2-sim-<uid>`` in the temporary directory (this user's alone)."""
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    if runtime:
        return Path(runtime) / "gx2-sim"
    return Path(tempfile.gettempdir()) / f"gx2-sim-{os.getuid()}"


class ControlError(Exception):
    """The command cannot be done (one line for the user)."""


Handler = Callable[[list[str]], str]
"""A command's words to the answer line (``ok ...``), or ControlError."""


class ControlServer:
    """The running simulator's end: answers each connection's one line in a thread."""

    def __init__(self, handle: Handler) -> None:
        where = directory()
        where.mkdir(mode=0o700, parents=True, exist_ok=True)
        if where.stat().st_uid != os.getuid():  # (another user's, made to catch ours)
            raise ControlError(f"{where} belongs to another user")
        self.path = where / f"{os.getpid()}.sock"
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()  # (left by a killed process whose pid came back)

        class Line(socketserver.StreamRequestHandler):
            def handle(self) -> None:
                words = self.rfile.readline(MAX_LINE).decode(errors="replace").split()
                try:
                    answer = handle(words)
                except ControlError as error:
                    answer = f"error {error}"
                self.wfile.write(answer.encode() + b"\n")

        self._server = socketserver.UnixStreamServer(str(self.path), Line)
        self._thread = threading.Thread(target=self._server.serve_forever,
                                        name="gx2-sim-control", daemon=True)

    def start(self) -> ControlServer:
        self._thread.start()
        return self

    def close(self) -> None:
        self._server.shutdown()
        self._server.server_close()
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()


def ask(path: Path, line: str) -> str:
    """One line to the simulator at ``path``, its answer (OSError: none listens)."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as client:
        client.settimeout(REPLY_TIMEOUT)
        client.connect(str(path))
        client.sendall(line.encode() + b"\n")
        return client.makefile("rb").readline(MAX_LINE).decode(errors="replace").strip()


def running(pid: int | None = None) -> dict[int, Path]:
    """The simulators that answer (by pid); a socket nobody listens on any more (a
    simulator that was killed) is removed. ``pid``: that one only."""
    where = directory()
    found: dict[int, Path] = {}
    paths = [where / f"{pid}.sock"] if pid is not None else sorted(where.glob("*.sock"))
    for path in paths:
        if not path.stem.isdecimal():
            continue
        try:
            ask(path, "stations")
        except FileNotFoundError:
            continue
        except ConnectionRefusedError:
            with contextlib.suppress(OSError):
                path.unlink()
            continue
        except OSError:
            continue
        found[int(path.stem)] = path
    return found


def _running(pid: int | None) -> dict[int, Path]:
    """:func:`running`, or ControlError when none is."""
    sims = running(pid)
    if not sims:
        raise ControlError(f"no gx2-sim with pid {pid} is running" if pid is not None
                           else "no gx2-sim is running (as this user)")
    return sims


def _done(path: Path, line: str) -> str:
    """``line`` to the simulator at ``path``: what it did, or ControlError."""
    answer = ask(path, line)
    if not answer.startswith("ok"):
        raise ControlError(answer.removeprefix("error ").strip() or "no answer")
    return answer.removeprefix("ok").strip()


def send(action: str, name: str | None, seconds: float | None, pid: int | None) -> str:
    """Do ``action`` (unplug, replug) to station ``name`` (None: a simulator's only one)
    of the running simulator that has it; the simulator's answer, or ControlError."""
    sims = _running(pid)
    target = name or "-"
    having = {p: path for p, path in sims.items()
              if target in ask(path, "stations").split()[1:]}
    if not having:
        names = sorted({n for path in sims.values() for n in ask(path, "stations").split()[1:]
                        if n != "-"})
        raise ControlError((f"no running gx2-sim has a station {name}" if name else
                            "name a station: the running gx2-sim has several")
                           + (f" (stations: {', '.join(names)})" if names else ""))
    if len(having) > 1:
        raise ControlError(f"gx2-sims {', '.join(map(str, sorted(having)))} all have "
                           f"{'a station ' + name if name else 'one station'}: "
                           "give --pid")
    path = next(iter(having.values()))
    words = [action, target] + ([f"{seconds:g}"] if seconds is not None else [])
    return _done(path, " ".join(words))


def power(address: int, on: bool, pid: int | None) -> str:
    """Switch node ``address`` of the running simulator that has it on or off; the
    simulator's answer, or ControlError."""
    sims = _running(pid)
    having = [path for path in sims.values()
              if str(address) in ask(path, "nodes").split()[1:]]
    if not having:
        raise ControlError(f"no running gx2-sim has a node {address}")
    if len(having) > 1:
        raise ControlError(f"gx2-sims {', '.join(p.stem for p in having)} all have a node "
                           f"{address}: give --pid")
    return _done(having[0], f"power {address} {'on' if on else 'off'}")
