"""Opening the base station from its URL: the one place the daemon reaches beyond a
plain serial device.

- a device path (``/dev/ttyUSB0``, ``/dev/gx2-basestation``): opened exclusively and raw;
- a pyserial URL (``rfc2217://host:port``, ``socket://``, ``loop://``), for a base
  station behind a network serial server;
- ``replay://PATH[?speed=N&exit=true]``: a recording played back
  (:mod:`gateway.daemon.station.replay`; its URL: :mod:`.replayurl`);
- ``sim://[?faults]``: gx2-sim, run inside the gateway for the configured nodes behind
  a pty with a private path, so the daemon opens it exactly as it opens hardware. Query
  parameters select faults: ``sim://?data_loss=0.05&garbage=0.01&stop_loss=0.5``.
"""

from __future__ import annotations

import errno
import os
import shutil
import stat
import tempfile
from pathlib import Path

import serial

from .replayurl import SCHEME as REPLAY_SCHEME
from .replayurl import Replay

SIM_SCHEME = "sim://"
PLAIN_REASONS = {
    errno.EAGAIN: "port held by another process (another gateway?)",
    errno.EBUSY: "port busy (another program has it open)",
    errno.ENOENT: "no such device (not plugged in?)",
    errno.ENODEV: "no such device (unplugged?)",
    errno.ENXIO: "no such device (unplugged?)",
    errno.EACCES: "permission denied (is the gateway's user in the dialout group?)",
    errno.EPERM: "permission denied (is the gateway's user in the dialout group?)",
    errno.EISDIR: "a directory, not a serial port",
    errno.ENOTTY: "not a serial port (inappropriate ioctl for device)",
    errno.ECONNREFUSED: "connection refused (is the network serial server running?)",
    errno.ETIMEDOUT: "no answer from the network serial server (timed out)",
    errno.EHOSTUNREACH: "host unreachable",
    errno.ENETUNREACH: "network unreachable",
}
"""What a user reads for the usual reasons a port cannot be opened, by errno: pyserial's
own texts (``[Errno 11] Could not exclusively lock port /dev/ttyUSB0: [Errno 11]
Resource temporarily unavailable``) say it twice and never say what to do."""


def check_url(url: str, nodes: list[int]) -> str:
    """``url`` if the gateway can open it for ``nodes``; ValueError (one line) if not.
    Nothing is opened or started: ``gx2-gateway --check`` runs exactly this."""
    if url.startswith(SIM_SCHEME):
        from gateway.sim.config import from_url
        from_url(url, nodes)
    elif url.startswith(REPLAY_SCHEME):
        Replay.from_url(url)
    elif "://" in url:
        try:
            serial.serial_for_url(url, do_not_open=True)
        except (ValueError, serial.SerialException) as error:
            raise ValueError(f"{url!r} is not a device path, sim:// or a pyserial URL: "
                             f"{error}") from None
    return url


def open_serial(path: str, baudrate: int) -> serial.SerialBase:
    """Open the base station's port (a device path or a pyserial URL): a device
    exclusively and raw. It may block for seconds (a network serial server that does not
    answer): the link calls it off the loop (:mod:`gateway.daemon.station.offloop`)."""
    is_device = "://" not in path
    # write_timeout applies only to URL handlers without an fd (loop://)
    return serial.serial_for_url(path, baudrate, timeout=0, write_timeout=0.1,
                                 exclusive=True if is_device else None)


def why_not_open(error: BaseException) -> str:
    """Why a port could not be opened, in plain words: :data:`PLAIN_REASONS` for the
    errno under pyserial's exception (its own, or the OS error it was raised from),
    else the OS's text, else the exception's."""
    cause = error.__context__
    number = error.errno if isinstance(getattr(error, "errno", None), int) else None
    if number is None and isinstance(cause, OSError):
        number = cause.errno
    elif number is None and cause is not None and cause.args and isinstance(cause.args[0], int):
        number = cause.args[0]  # termios.error: (errno, text)
    if isinstance(error, TimeoutError) or isinstance(cause, TimeoutError):
        number = errno.ETIMEDOUT
    if number in PLAIN_REASONS:
        return PLAIN_REASONS[number]
    if number is not None:
        return os.strerror(number)
    return str(error) or type(error).__name__


def nothing_to_play(url: str, station: str | None) -> str | None:
    """Why a ``replay://`` URL has nothing to play for the base station named
    ``station`` (None: one the configuration does not name, its one-station form) (None
    if it has, or is no replay): its recordings are read up to their
    first message that can be played."""
    replay = Port.replay_of(url)
    return (replay.nothing_to_play(station) or None) if replay is not None else None


def never_serial(url: str) -> str | None:
    """Why ``url`` can never be a serial port (a regular file, a directory), or None.
    A path that does not exist now is not flagged: the adapter may be plugged in later.
    Nothing is opened (a running gateway holds the port exclusively)."""
    if "://" in url:
        return None
    try:
        mode = os.stat(url).st_mode
    except FileNotFoundError:
        return None
    except OSError as error:
        return f"{url}: {error.strerror}"
    if stat.S_ISCHR(mode):
        return None
    kind = ("a directory" if stat.S_ISDIR(mode) else "a regular file" if stat.S_ISREG(mode)
            else "not a character device")
    return f"{url} is {kind}, not a serial port"


class Port:
    """A base station's port: what the link opens, and what must run for it to be
    there (the embedded simulator)."""

    def __init__(self, url: str, nodes: list[int]) -> None:
        self.url = url
        self.path = url
        """What pyserial opens."""
        self._directory: Path | None = None
        self._simulator = None
        self.replay = self.replay_of(url)
        """A recording to play instead of a port."""
        if url.startswith(SIM_SCHEME):
            from gateway.sim.cli import simulator_from
            from gateway.sim.config import from_url
            self._directory = Path(tempfile.mkdtemp(prefix="gx2-sim-"))
            self.path = str(self._directory / "base-station")
            self._simulator = simulator_from(from_url(url, nodes), self.path)

    @staticmethod
    def replay_of(url: str) -> Replay | None:
        return Replay.from_url(url) if url.startswith(REPLAY_SCHEME) else None

    def start(self) -> None:
        if self._simulator is not None:
            self._simulator.start()

    def close(self) -> None:
        if self._simulator is not None:
            self._simulator.stop()
        if self._directory is not None:
            shutil.rmtree(self._directory, ignore_errors=True)
