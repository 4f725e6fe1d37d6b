#!/usr/bin/env python3
"""The floor under the gateway's figures: the least any gateway must do per packet.

An asyncio loop reads the pty the way the gateway does (one non-blocking read each
time the fd is readable), cuts the stream into packets at their length byte, takes the
node and the 0xC2 timer from fixed offsets, and publishes ``[topic, msgpack]`` per
packet on a PUB socket: no checksum, no validation, no state. perf.py runs it where it
runs the gateway, so what the gateway costs above it is its own.

    python bench/relay.py PORT ENDPOINT
"""

from __future__ import annotations

import asyncio
import os
import signal
import struct
import sys
import tty

import msgpack
import zmq

_NODE = struct.Struct(">3xH")
_TIMER = struct.Struct(">I")
_C2_TIMER_AT = 7 + 25  # header, echo byte, six floats


async def relay(port: str, endpoint: str) -> None:
    fd = os.open(port, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    tty.setraw(fd)
    context = zmq.Context()
    pub = context.socket(zmq.PUB)
    pub.bind(endpoint)
    pack = msgpack.Packer().pack
    buffer = bytearray()

    def readable() -> None:
        buffer.extend(os.read(fd, 65536))
        while len(buffer) >= 7:
            if buffer[0] != 0xAA or buffer[1] == 0xAA:
                del buffer[0]
                continue
            size = buffer[5] + 10
            if len(buffer) < size:
                break
            node = _NODE.unpack_from(buffer)[0]
            if buffer[7] == 0xC2:
                timer = _TIMER.unpack_from(buffer, _C2_TIMER_AT)[0]
                pub.send(b"gx2/%d/accel_angrate" % node, zmq.SNDMORE | zmq.NOBLOCK)
                pub.send(pack({"node": node, "timer": timer}), zmq.NOBLOCK)
            del buffer[:size]

    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    loop.add_reader(fd, readable)
    loop.add_signal_handler(signal.SIGTERM, stop.set)
    await stop.wait()
    context.destroy(linger=0)


if __name__ == "__main__":
    asyncio.run(relay(sys.argv[1], sys.argv[2]))
