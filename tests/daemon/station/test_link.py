"""SerialLink against a real pseudo-terminal: the far end (the test) plays the base
station, reading and writing the master side exactly as the USB adapter would."""

from __future__ import annotations

import asyncio
import contextlib
import os
import threading
import tty
from collections.abc import Iterator

import pytest
import serial

from gateway.daemon.station import link as link_module
from gateway.daemon.station.link import ReadStamp, SerialLink
from tests.helpers.waiting import wait_for_async


@pytest.fixture
def pty_pair() -> Iterator[tuple[int, str]]:
    master, slave = os.openpty()
    tty.setraw(master)
    path = os.ttyname(slave)
    os.close(slave)  # the link opens the path itself, as it opens /dev/ttyUSB0
    yield master, path
    with contextlib.suppress(OSError):  # a test may have closed it: the plug pulled
        os.close(master)


def read_available(master: int) -> bytes:
    os.set_blocking(master, False)
    try:
        return os.read(master, 1 << 16)
    except BlockingIOError:
        return b""


def test_a_port_that_does_not_take_bytes_yet_is_not_lost(pty_pair) -> None:
    """The base station's side stops reading until the pty's buffer is full: the link
    keeps the rest, stays up, and delivers every byte in order once it is read again
    (pyserial's write timeout would have called the port lost here)."""
    master, path = pty_pair
    states: list[bool] = []

    async def scenario() -> bytes:
        link = SerialLink(path, 115200, lambda data, t, m: None, states.append)
        assert await link.open()
        sent = bytearray()
        packet = bytes(range(100))
        while not link.unsent:  # fill the pty until the fd refuses bytes
            link.write(packet)
            sent += packet
            assert len(sent) < 1 << 20, "the pty never filled"
        assert link.up and states == [True]
        received = bytearray()
        await wait_for_async(lambda: received.extend(read_available(master)) or
                             len(received) == len(sent), 5, "every byte to arrive")
        await wait_for_async(lambda: link.unsent == 0, 5, "the buffer to empty")
        assert link.up and states == [True]
        link.close()
        return bytes(received) == bytes(sent)

    assert asyncio.run(scenario())


def test_a_port_that_takes_nothing_at_all_is_lost(pty_pair, monkeypatch) -> None:
    """Beyond MAX_UNSENT untaken bytes the port is declared lost (and reopening starts)."""
    _master, path = pty_pair
    monkeypatch.setattr(link_module, "MAX_UNSENT", 200)
    states: list[bool] = []

    async def scenario() -> None:
        link = SerialLink(path, 115200, lambda data, t, m: None, states.append)
        assert await link.open()
        with pytest.raises(OSError, match="stopped taking bytes"):
            while True:
                link.write(bytes(100))
        assert states == [True, False] and not link.up and link.reopening
        assert "took nothing" in link.last_error
        link.close()

    asyncio.run(scenario())


def test_the_master_closing_is_a_lost_port(pty_pair) -> None:
    """The plug pulled: reads fail, the link goes down once and starts reopening."""
    master, path = pty_pair
    states: list[bool] = []

    async def scenario() -> None:
        link = SerialLink(path, 115200, lambda data, t, m: None, states.append)
        assert await link.open()
        os.close(master)
        await wait_for_async(lambda: not link.up, 5, "the link to go down")
        assert states == [True, False] and link.reopening
        link.close()

    asyncio.run(scenario())


def test_an_open_that_hangs_is_given_up_waited_for_once_and_used_when_it_ends(
        pty_pair, monkeypatch) -> None:
    """An open beyond OPEN_BOUND: the link says ``opening`` and why, the next attempt
    waits for the same open rather than starting another thread, and when the open
    ends at last the port is used."""
    _master, path = pty_pair
    monkeypatch.setattr(link_module, "OPEN_BOUND", 0.1)
    release = threading.Event()
    opens: list[str] = []

    def hanging_open(port: str, baudrate: int):
        opens.append(port)
        release.wait(10)
        return serial.serial_for_url(port, baudrate, timeout=0, exclusive=True)
    monkeypatch.setattr(link_module, "open_serial", hanging_open)
    states: list[bool] = []

    async def scenario() -> None:
        link = SerialLink(path, 115200, lambda data, t, m: None, states.append)
        link.start()
        await wait_for_async(lambda: "did not end within" in link.last_error, 5,
                             "the open given up")
        assert link.state == "opening" and not link.up
        # several attempts' worth of time (each gives up after OPEN_BOUND): none of them
        # may start a second open beside the hung one
        await asyncio.sleep(5 * link_module.OPEN_BOUND)
        assert link.reopening
        assert opens == [path], "a second thread was started for the hung open"
        release.set()
        await wait_for_async(lambda: link.up, 5, "the port up once the open ended")
        assert link.state == "up" and states == [True] and opens == [path]
        link.close()

    asyncio.run(scenario())


def test_close_while_an_open_hangs_returns_at_once(pty_pair, monkeypatch) -> None:
    """Shutdown during a hung open: close() returns at once, and the port the open
    yields later is closed, not leaked."""
    _master, path = pty_pair
    release = threading.Event()
    opened: list[serial.SerialBase] = []

    def hanging_open(port: str, baudrate: int):
        release.wait(10)
        opened.append(serial.serial_for_url(port, baudrate, timeout=0))
        return opened[-1]
    monkeypatch.setattr(link_module, "open_serial", hanging_open)

    async def scenario() -> None:
        link = SerialLink(path, 115200, lambda data, t, m: None, lambda up: None)
        link.start()
        await wait_for_async(lambda: link.state == "opening", 5, "the open under way")
        link.close()
        assert link.state == "down"
        release.set()
        await wait_for_async(lambda: opened and not opened[0].is_open, 5,
                             "the late port closed")

    asyncio.run(scenario())


def test_a_read_preempted_between_its_two_clocks_reads_them_again() -> None:
    """A read's UNIX time and monotonic time are one instant even when the host
    preempted the gateway between reading the two (bench/faultsoak.py: every record of
    such a read was 3-4 ms early, all nodes at once); the pair stays the clocks' own
    readings (a recording keeps them, and a replay must give the same times)."""
    readings = iter([100.0, 1000.0, 100.00001,  # a clean pair
                     200.0, 1100.0, 200.004,  # 4 ms between the monotonic readings
                     200.005, 1100.005, 200.00501,  # read again: clean
                     300.0, 1200.0, 300.1, 301.0, 1201.0, 301.1, 302.0, 1202.0, 302.1])
    stamp = ReadStamp(unix=lambda: next(readings), monotonic=lambda: next(readings))
    assert stamp() == (1000.0, 100.00001)
    assert stamp() == (1100.005, 200.00501)
    assert stamp() == (1202.0, 302.1)  # (never clean: the last pair, no loop for ever)
