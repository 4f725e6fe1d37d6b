"""gx2-sim's process side: a pseudo-terminal that looks like a USB base station, and a
loop that serves it.

The pty is put in raw mode and its slave path is what the gateway opens, exactly as it
opens /dev/ttyUSB0; an optional symlink gives it a stable name. Unplugging closes the
pty (the gateway's reads fail as they would on a real unplug) and replugging makes a
new one behind the same symlink. :class:`Simulator` runs the loop in a thread and gives
tests a thread-safe handle on it.

A pty holds only a few KiB, a host's serial driver far more, so what the pty does not
take at once waits in the simulator (up to :data:`PORT_BUFFER`) until it does: a reader
that is a moment late, or a simulator thread that was late and owes a burst, loses
nothing. A host that flushes its input (opening the port does) discards that too.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import logging
import os
import random
import selectors
import struct
import termios
import threading
import time
import tty
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

from gateway.common.threadname import name_this_thread

from .base_station import BaseStation, LineFaults, RadioLink
from .node import NodeSettings, SimNode

log = logging.getLogger("gx2.sim")
HOST_IDLE = 0.05
"""A host that stops mid-packet for this long gets a NACK for what it sent."""
PORT_BUFFER = 64 * 1024
"""Bytes kept for a host that is not reading, beyond what the pty itself holds (Linux
buffers 64 KiB for a serial port): 5.7 s of a saturated line at 115200 baud. What
arrives when it is full is lost, as on a port nobody reads."""
T = TypeVar("T")


class LinkInUse(ValueError):
    """The ``--link`` path is something that is not ours to replace."""


class PtyPort:
    """One pseudo-terminal pair standing in for the base station's USB serial port.

    Its link is made only where nothing is, or over a symlink of its own (a replug) or
    one that points at nothing (left by a simulator that was killed); never over a file,
    nor over the link of a pty that is open (another simulator's). It is removed only
    while it still points at this port's pty."""

    def __init__(self, link: str | Path | None = None) -> None:
        self.link = Path(link) if link else None
        self.master: int | None = None
        self._slave: int | None = None
        self.path = ""
        self.generation = 0
        """Counts opens: a replugged pty may get the old master's fd number back."""

    def open(self) -> None:
        master, slave = os.openpty()
        self.generation += 1
        tty.setraw(slave)  # no echo, no line discipline: bytes pass untouched
        os.set_blocking(master, False)
        # packet mode: the master also reads the host's flushes (see read)
        fcntl.ioctl(master, termios.TIOCPKT, struct.pack("i", 1))
        if self.link:
            try:
                self._check_link(self.link)
            except LinkInUse:
                os.close(master)
                os.close(slave)
                raise
        self.master, self._slave, self.path = master, slave, os.ttyname(slave)
        if self.link:
            temporary = self.link.with_name(self.link.name + ".new")
            if temporary.is_symlink():
                temporary.unlink()
            temporary.symlink_to(self.path)
            temporary.replace(self.link)  # atomic: the link never dangles mid-update

    def _check_link(self, link: Path) -> None:
        if not link.is_symlink():
            if link.exists():
                raise LinkInUse(f"{link} exists and is not a symlink: it is not replaced "
                                "(choose another --link path)")
            return
        target = os.readlink(link)
        if target != self.path and os.path.exists(target):
            raise LinkInUse(f"{link} points at {target}, a pty that is open (another "
                            "simulator's?): it is not taken over (stop that one, or "
                            "choose another --link path)")

    def close(self) -> None:
        if self.link and self.link.is_symlink() and os.readlink(self.link) == self.path:
            self.link.unlink()
        for fd in (self.master, self._slave):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self.master = self._slave = None

    @property
    def is_open(self) -> bool:
        return self.master is not None

    def write(self, data: bytes) -> int:
        """Write what the pty takes now; return how much that was."""
        assert self.master is not None
        try:
            return os.write(self.master, data)
        except BlockingIOError:
            return 0

    def read(self) -> tuple[bytes, bool]:
        """What the host wrote, and whether it flushed its input (discarding what it
        had not read) since the last read."""
        assert self.master is not None
        try:
            packet = os.read(self.master, 4097)
        except (BlockingIOError, InterruptedError):
            return b"", False
        except OSError:  # EIO: no client holds the other end; nothing to read
            return b"", False
        if not packet:
            return b"", False
        if packet[0] == termios.TIOCPKT_DATA:
            return packet[1:], False
        return b"", bool(packet[0] & termios.TIOCPKT_FLUSHREAD)  # a status byte


class Simulator:
    """A base station and its nodes behind a pty, served from a background thread."""

    def __init__(self, nodes: list[NodeSettings], *, link: str | Path | None = None,
                 radio: dict[int, RadioLink] | None = None, line: LineFaults | None = None,
                 baudrate: int = 115200, seed: int = 1,
                 first_write_failure_rate: float = 0.0) -> None:
        rng = random.Random(seed)
        now = time.monotonic()
        sim_nodes = [SimNode(s, now, random.Random(rng.random())) for s in nodes]
        for node in sim_nodes:
            node.first_write_failure_rate = first_write_failure_rate
        self.station = BaseStation(sim_nodes, radio, line, baudrate, rng)
        self.port = PtyPort(link)
        self.dropped_bytes = 0
        """Bytes lost because the host did not read them (:data:`PORT_BUFFER`)."""
        self._unsent = bytearray()  # due to the host, not yet taken by the pty
        self._lock = threading.RLock()
        self._wake_r, self._wake_w = os.pipe()
        self._stop = threading.Event()
        self._ready = threading.Event()
        self._thread: threading.Thread | None = None
        self._replug_at: float | None = None
        self.error: BaseException | None = None

    # -- life cycle --------------------------------------------------------------------

    def start(self) -> Simulator:
        self.port.open()
        self._thread = threading.Thread(target=self._run, name="gx2-sim", daemon=True)
        self._thread.start()
        self._ready.wait(5)
        return self

    def stop(self) -> None:
        """Stop serving and close the pty; calling it again does nothing."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._wake()
        if self._thread:
            self._thread.join(5)
        with self._lock:
            self.port.close()
            wake_fds, self._wake_r, self._wake_w = (self._wake_r, self._wake_w), -1, -1
        for fd in wake_fds:
            with contextlib.suppress(OSError):
                os.close(fd)

    def __enter__(self) -> Simulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def path(self) -> str:
        """What a client opens: the symlink if there is one, else the pty itself."""
        return str(self.port.link) if self.port.link else self.port.path

    # -- what tests do while it runs ------------------------------------------------------

    def call(self, action: Callable[[BaseStation, float], T]) -> T:
        """Run ``action(station, now)`` on the simulator's state, safely."""
        with self._lock:
            result = action(self.station, time.monotonic())
        self._wake()
        return result

    def node(self, address: int) -> SimNode:
        return self.station.nodes[address]

    def reboot(self, address: int) -> None:
        self.call(lambda station, now: station.reboot(address, now))

    def power(self, address: int, on: bool) -> bool:
        """Switch node ``address`` on or off (:meth:`.BaseStation.power`); whether that
        changed anything."""
        return self.call(lambda station, now: station.power(address, on, now))

    def unplug(self, duration: float | None = None) -> None:
        """Pull the USB plug; with ``duration``, plug it back in after that long."""
        with self._lock:
            self.port.close()
            self._unsent.clear()  # what was on its way goes with the device
            self._replug_at = None if duration is None else time.monotonic() + duration
        self._wake()

    def replug(self) -> None:
        with self._lock:
            if not self.port.is_open:
                self._plug_in(time.monotonic())
        self._wake()

    def _plug_in(self, at: float) -> None:
        """The plug back in at ``at``. What fell due while it was out went with the
        device, however late the loop runs: one starved of the CPU for the whole outage
        once sent the outage's records after the replug, as if the plug had stayed in (a
        full suite run: no gap in 2 s unplugged)."""
        self.station.advance(at)
        self.station.lose_output(at)
        self.port.open()
        self._replug_at = None

    def _wake(self) -> None:
        if self._wake_w >= 0:
            with contextlib.suppress(OSError):
                os.write(self._wake_w, b"!")

    # -- the loop -----------------------------------------------------------------------

    def _run(self) -> None:
        # select(2), not the default epoll: the loop sleeps until the next byte is due,
        # and epoll's timeout is whole milliseconds (Python rounds it up), so packets
        # went out 0-1 ms late by the line's model (at the host: p10 0.43, p90 1.23 ms);
        # select's is microseconds (p90 - p10: 0.15 ms). The host sees that lateness as
        # radio delay, so bench/timesync.py measured it, not the gateway's clock (issue
        # 21; tests/sim/test_line_timing.py). A handful of descriptors: select's limit
        # of 1024 is far away.
        name_this_thread("gx2-sim")
        selector = selectors.SelectSelector()
        selector.register(self._wake_r, selectors.EVENT_READ)
        registered: tuple[int | None, int] | None = None  # (fd, the port's generation)
        watching = 0  # the selector events the master is registered for
        last_host_byte: float | None = None
        self._ready.set()
        try:
            while not self._stop.is_set():
                with self._lock:
                    now = time.monotonic()
                    if self._replug_at is not None and now >= self._replug_at:
                        self._plug_in(self._replug_at)
                    master = self.port.master
                    events = selectors.EVENT_READ | (selectors.EVENT_WRITE if self._unsent else 0)
                    current = (master, self.port.generation)
                    if current != registered:  # (by fd alone a replug that got the same
                        if registered is not None and registered[0] is not None:  # number
                            selector.unregister(registered[0])  # back would stay deaf)
                        if master is not None:
                            selector.register(master, events)
                        registered, watching = current, events
                    elif master is not None and events != watching:
                        selector.modify(master, events)
                        watching = events
                    due = self.station.next_due(now)
                    if self._replug_at is not None:
                        due = min(due, self._replug_at)
                    if last_host_byte is not None:
                        due = min(due, last_host_byte + HOST_IDLE)
                try:
                    ready = selector.select(max(0.0, due - time.monotonic()))
                except OSError as error:
                    # unplugged between the registration above and the select: the
                    # port's descriptor was closed under it (the loop died with EBADF,
                    # and a replug then found nothing serving it); register afresh
                    if error.errno != errno.EBADF:
                        raise
                    with self._lock:
                        if registered is not None and registered[0] is not None:
                            selector.unregister(registered[0])
                        registered = None
                    continue
                with self._lock:
                    now = time.monotonic()
                    if self._replug_at is not None and now >= self._replug_at:
                        self._plug_in(self._replug_at)  # (due while this loop waited)
                    data = b""
                    for key, mask in ready:
                        if key.fd == self._wake_r:
                            os.read(self._wake_r, 4096)
                        elif key.fd == self.port.master and mask & selectors.EVENT_READ:
                            data, flushed = self.port.read()
                            if flushed:
                                self._unsent.clear()  # the host discarded it anyway
                    # what fell due before now goes on the line before the answer to what
                    # the host sent (a loop that ran late catches up in order, instead of
                    # putting an ACK ahead of records the UART then has no room for)
                    self.station.advance(now)
                    if data:
                        self.station.from_host(data, now)
                        last_host_byte = now
                    if last_host_byte is not None and now - last_host_byte >= HOST_IDLE:
                        self.station.host_idle(now)
                        last_host_byte = None
                    out = self.station.take_output(now)
                    if self.port.is_open:
                        self._send(out)
        except BaseException as error:  # report, don't vanish: tests check sim.error
            self.error = error
            log.exception("simulator loop failed")
            raise
        finally:
            selector.close()

    def _send(self, data: bytes) -> None:
        """Write ``data`` behind what the pty has not taken yet; keep what it does not
        take now, up to PORT_BUFFER, and lose the rest (a host not reading)."""
        self._unsent += data
        if self._unsent:
            del self._unsent[:self.port.write(self._unsent)]
        excess = len(self._unsent) - PORT_BUFFER
        if excess > 0:
            del self._unsent[PORT_BUFFER:]
            self.dropped_bytes += excess
