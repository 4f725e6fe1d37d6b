"""Why a port cannot be opened, in words a user can act on: pyserial's real exceptions
(a path that is not there, a regular file, a pty another process holds, a refused
connection) and the errnos that need a privilege this suite does not drop."""

from __future__ import annotations

import errno
import os
import socket
from pathlib import Path

import pytest
import serial

from gateway.daemon.station.ports import PLAIN_REASONS, open_serial, why_not_open


def failure(path: str) -> BaseException:
    with pytest.raises(Exception) as caught:
        open_serial(path, 115200)
    return caught.value


def test_the_usual_reasons_are_said_plainly(tmp_path: Path) -> None:
    assert why_not_open(failure(str(tmp_path / "ttyUSB9"))) == \
        "no such device (not plugged in?)"
    plain = tmp_path / "plain"
    plain.write_text("")
    assert why_not_open(failure(str(plain))) == \
        "not a serial port (inappropriate ioctl for device)"
    assert why_not_open(failure(str(tmp_path))) == "a directory, not a serial port"
    with socket.socket() as unused:  # a port nothing listens on: refused
        unused.bind(("127.0.0.1", 0))
        port = unused.getsockname()[1]
    assert why_not_open(failure(f"socket://127.0.0.1:{port}")).startswith(
        "connection refused")


def test_a_port_held_exclusively_is_said_to_be_held() -> None:
    master, slave = os.openpty()
    path = os.ttyname(slave)
    held = open_serial(path, 115200)
    try:
        assert why_not_open(failure(path)) == \
            "port held by another process (another gateway?)"
    finally:
        held.close()
        os.close(slave)
        os.close(master)


@pytest.mark.parametrize("number, said", [
    (errno.EACCES, "permission denied (is the gateway's user in the dialout group?)"),
    (errno.ENODEV, "no such device (unplugged?)"),
    (errno.EIO, os.strerror(errno.EIO))])
def test_errnos_root_cannot_meet(number: int, said: str) -> None:
    """pyserial raises SerialException(errno, text) from open(2)'s OSError."""
    try:
        try:
            raise OSError(number, os.strerror(number))
        except OSError as cause:
            raise serial.SerialException(number, f"could not open port x: {cause}") from cause
    except serial.SerialException as error:
        assert why_not_open(error) == said
    assert number in PLAIN_REASONS or said == os.strerror(number)
