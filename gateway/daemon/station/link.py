"""The base station's serial port, read by the event loop: the one place bytes enter.

Opened exclusively and raw (pyserial sets raw mode on a tty); each time the fd is
readable, everything waiting is read in one call and stamped with the host time, on
the UNIX clock and on the monotonic one.
Writes go straight to the non-blocking fd; what it cannot take at once waits in a
small buffer that is flushed when the fd becomes writable, so a busy host or a full
driver buffer is never mistaken for a lost port (pyserial's own write timeout counts a
scheduling stall as a timeout even after every byte was written). A read or write
error, or end of file (the USB plug pulled), closes the port, and it is reopened with
backoff in steps of at most 1 s until it comes back. What it opens comes from
:mod:`gateway.daemon.station.ports`.

Opening and closing never run on the loop: each runs in a daemon thread
(:mod:`gateway.daemon.station.offloop`), the link ``opening`` meanwhile, so a network serial
server that does not answer stalls no other base station, no request and no shutdown.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import time
from collections.abc import Callable

import serial

from .offloop import in_thread
from .ports import open_serial, why_not_open

log = logging.getLogger("gx2.link")
STAMP_NOISE = 50e-6
"""Seconds between two readings of the monotonic clock, around the UNIX one, within
which a read's pair of clocks is taken as read at one instant."""
REOPEN_STEPS = (0.1, 0.2, 0.5, 1.0)
"""Backoff between reopen attempts; it stays at the last step (1 s) until the port returns."""
READ_SIZE = 65536
MAX_UNSENT = 4096
"""Bytes the port may leave untaken before it is declared lost: the scheduler has one
packet of at most 110 bytes in flight, so this many means the port stopped taking any."""
OPEN_BOUND = 10.0
"""Seconds an open (or the close before it) is waited for before the attempt is given
up as hung: longer than pyserial's own 5 s connect timeout, so only an open that would
never end (a driver stuck in the kernel) reaches it."""


class ReadStamp:
    """Each read's instant on the UNIX clock and on the monotonic one, as one pair.

    The two clocks are read one after the other, and a host that preempts the gateway
    between the readings (a busy 2-core machine, a VM's steal) shifts the pair, and
    every record of that read, by the preemption (3-4 ms on all nodes at once in
    bench/faultsoak.py's quiet stretches). So the UNIX clock is read between two
    readings of the monotonic one, and taken with the second only when they are within
    STAMP_NOISE; else read again, TRIES times at most. The pair stays the clocks' own
    readings: a recording keeps them to the nanosecond, and a replay gives the same
    ``time`` as live (a sum of an offset and a reading did not round-trip)."""

    __slots__ = ("_monotonic", "_unix")

    TRIES = 3

    def __init__(self, unix: Callable[[], float] = time.time,
                 monotonic: Callable[[], float] = time.monotonic) -> None:
        self._unix, self._monotonic = unix, monotonic

    def __call__(self) -> tuple[float, float]:
        """(UNIX seconds, monotonic seconds) of now."""
        monotonic = self._monotonic
        for _ in range(self.TRIES):
            before = monotonic()
            unix = self._unix()
            after = monotonic()
            if after - before <= STAMP_NOISE:
                break
        return unix, after


class SerialLink:
    """Owns the port: open, read what is waiting, write, and reopen after a loss."""

    def __init__(self, port: str, baudrate: int,
                 on_data: Callable[[bytes, float, float], None],
                 on_state: Callable[[bool], None]) -> None:
        self.port = port
        self.baudrate = baudrate
        self._on_data = on_data
        self._on_state = on_state
        self._serial: serial.SerialBase | None = None
        self._fd: int | None = None
        self._poll_handle: asyncio.TimerHandle | None = None
        self._unsent = bytearray()
        self._writer_added = False
        self._reopen_task: asyncio.Task[None] | None = None
        self._opening: asyncio.Future[serial.SerialBase] | None = None
        """The open in flight, until its result is taken: one that outlived OPEN_BOUND
        is waited for again by the next attempt, never doubled."""
        self._closed: asyncio.Future[None] | None = None
        """The last close of the port, in its thread: a reopen waits for it (the
        device's lock goes with it)."""
        self.up = False
        self.since = time.time()
        self.reconnects = 0
        self._stamp = ReadStamp()
        self.bytes_read = 0
        self.last_error = ""
        self._closing = False
        self.tried = asyncio.Event()
        """Set once the first open has been tried (whether or not it opened)."""

    def _attach(self, ser: serial.SerialBase) -> None:
        """Read the port just opened on the loop from now on."""
        self._serial = ser
        loop = asyncio.get_running_loop()
        try:
            self._fd = ser.fileno()
            loop.add_reader(self._fd, self._readable)
        except (AttributeError, NotImplementedError, OSError, ValueError):
            self._fd = None  # a URL handler without an fd (loop://): poll it instead
            self._poll_handle = loop.call_later(0.005, self._poll_url)
        self._set_up(True)

    async def open(self) -> bool:
        """One attempt to open the port, off the loop; whether it is open now (if not,
        :attr:`last_error` says why)."""
        # An attempt that outlives OPEN_BOUND is given up, but its thread cannot be
        # stopped: it stays ``_opening``, and the next attempt waits for that one
        # rather than starting another, so a hung open costs one thread, and an open
        # that ends late is used (or closed, if the link closed meanwhile).
        if self._closed is not None:
            await asyncio.wait([self._closed], timeout=OPEN_BOUND)
            self._closed = None
        if self._opening is None:
            self._opening = in_thread(lambda: open_serial(self.port, self.baudrate),
                                      f"gx2-open {self.port}")
        opening = self._opening
        await asyncio.wait([opening], timeout=OPEN_BOUND)
        if not opening.done():
            self._cannot_open(f"the open did not end within {OPEN_BOUND:g} s; still waiting")
            return False
        self._opening = None
        try:
            ser = opening.result()
        except Exception as error:  # (any failure to open is a reason to say, and retry)
            self._cannot_open(why_not_open(error))
            return False
        if self._closing:
            self._close_off_loop(ser)
            return False
        self._attach(ser)
        return True

    @property
    def state(self) -> str:
        """``up``, ``opening`` (an open is in flight, or hangs) or ``down``."""
        if self.up:
            return "up"
        return "opening" if self._opening is not None else "down"

    @property
    def reopening(self) -> bool:
        """The reopen loop is alive (it ends when the port is back)."""
        return self._reopen_task is not None and not self._reopen_task.done()

    @property
    def unsent(self) -> int:
        """Bytes written that the port has not taken yet."""
        return len(self._unsent)

    def start_reopening(self, first: bool = False) -> None:
        if self._reopen_task is None or self._reopen_task.done():
            self._reopen_task = asyncio.get_running_loop().create_task(self._reopen(first))

    def start(self) -> None:
        """Open the port as soon as it can be, and keep trying until it is (a service
        must: the adapter may be plugged in, or the permission granted, later)."""
        self.start_reopening(first=True)

    def _cannot_open(self, why: str) -> None:
        """Say why the port cannot be opened, once for each new reason."""
        if why != self.last_error:
            log.warning("base station %s cannot be opened: %s; retrying every %g s",
                        self.port, why, REOPEN_STEPS[-1])
        self.last_error = why

    async def _reopen(self, first: bool) -> None:
        """Open the port again, with backoff, until it is; ``first``: the open at
        start-up, tried at once (a reconnect only if that one fails)."""
        if first:
            opened = await self.open()
            self.tried.set()
            if opened:
                return
        attempt = 0
        while not self._closing and not self.up:
            await asyncio.sleep(REOPEN_STEPS[min(attempt, len(REOPEN_STEPS) - 1)])
            attempt += 1
            if not await self.open():
                continue
            self.reconnects += 1
            self.last_error = ""
            log.info("base station %s is back after %d attempt%s", self.port, attempt,
                     "" if attempt == 1 else "s")

    def write(self, data: bytes) -> None:
        """Send ``data`` (now, or as soon as the port takes it); OSError if the port is
        not open or fails."""
        if self._serial is None:
            raise OSError("the base station is not connected")
        if self._fd is None:
            try:
                self._serial.write(data)
            except (OSError, serial.SerialException) as error:
                self._lost(f"write failed: {error}")
                raise OSError(str(error)) from None
            return
        self._unsent += data
        if len(self._unsent) > MAX_UNSENT:
            self._lost(f"the port took nothing of the last {len(self._unsent)} bytes")
            raise OSError("the base station stopped taking bytes")
        if error := self._flush():
            raise OSError(error)

    def _flush(self) -> str | None:
        """Write what the fd takes now; watch for writability while any is left. The
        error that lost the port, if one did."""
        try:
            while self._unsent:
                del self._unsent[:os.write(self._fd, self._unsent)]  # type: ignore[arg-type]
        except (BlockingIOError, InterruptedError):
            pass
        except OSError as error:
            why = f"write failed: {error.strerror or error}"
            self._lost(why)
            return why
        loop = asyncio.get_running_loop()
        if self._unsent and not self._writer_added:
            loop.add_writer(self._fd, self._flush)  # type: ignore[arg-type]
            self._writer_added = True
        elif not self._unsent and self._writer_added:
            loop.remove_writer(self._fd)  # type: ignore[arg-type]
            self._writer_added = False
        return None

    def _readable(self) -> None:
        try:
            data = os.read(self._fd, READ_SIZE)  # type: ignore[arg-type]
        except BlockingIOError:
            return
        except OSError as error:
            self._lost(f"read failed: {error.strerror or error}")
            return
        if not data:
            self._lost("the port reported end of file")
            return
        self.bytes_read += len(data)
        self._on_data(data, *self._stamp())

    def _poll_url(self) -> None:
        try:
            data = self._serial.read(READ_SIZE) if self._serial else b""  # type: ignore[union-attr]
        except (OSError, serial.SerialException) as error:
            self._lost(f"read failed: {error}")
            return
        if data:
            self.bytes_read += len(data)
            self._on_data(data, *self._stamp())
        self._poll_handle = asyncio.get_running_loop().call_later(0.005, self._poll_url)

    def _lost(self, why: str) -> None:
        if not self.up:
            return
        log.warning("base station %s lost: %s", self.port, why)
        self.last_error = why
        self._release()
        self._set_up(False)
        if not self._closing:
            self.start_reopening()

    def _release(self) -> None:
        loop = asyncio.get_running_loop()
        if self._fd is not None:
            loop.remove_reader(self._fd)
            if self._writer_added:
                loop.remove_writer(self._fd)
            self._fd = None
        self._unsent.clear()  # commands for a port that is gone; the scheduler retries
        self._writer_added = False
        if self._poll_handle is not None:
            self._poll_handle.cancel()
            self._poll_handle = None
        if self._serial is not None:
            self._closed = self._close_off_loop(self._serial)
            self._serial = None

    def _close_off_loop(self, ser: serial.SerialBase) -> asyncio.Future[None]:
        """Close ``ser`` in a thread of its own (a tty drains its output first; rfc2217
        joins its reader thread): the loop has let go of its fd already."""
        def close() -> None:
            with contextlib.suppress(Exception):  # (nothing to tell anyone: it is gone)
                ser.close()
        return in_thread(close, f"gx2-close {self.port}")

    def _set_up(self, up: bool) -> None:
        self.up = up
        self.since = time.time()
        self._on_state(up)

    def close(self) -> None:
        """Let go of the port (its close, and an open still in flight, end in their
        threads: at exit they are abandoned, never waited for)."""
        self._closing = True
        if self._reopen_task is not None:
            self._reopen_task.cancel()
        if self._opening is not None:  # what it opens later is closed, not leaked
            self._opening.add_done_callback(self._opened_too_late)
            self._opening = None
        self._release()
        self.up = False

    def _opened_too_late(self, opening: asyncio.Future[serial.SerialBase]) -> None:
        if not opening.cancelled() and opening.exception() is None:
            self._close_off_loop(opening.result())
