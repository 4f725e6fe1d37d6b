#!/usr/bin/env python3
"""Decoder throughput on one core over a realistic mixed stream.

The stream: 3 nodes streaming 0xC2, 0xCC and 0xCE records in turn, an ACK before every
tenth packet (glued to the next SOP, as a base station sends it), and 1% of the bytes
random garbage between packets. The stream is built once, then fed to a fresh decoder
in fixed-size reads, several times; the best run is reported, and every run must
decode every packet or the script fails.

    python bench/decoder_throughput.py [--packets N] [--chunk BYTES] [--repeat R]
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import random
import sys
import time

from aspp.decoder import Decoder
from aspp.events import Reply
from aspp.frame import encode_reply_packet
from aspp.orientation import matrix_from_euler
from aspp.records import encode
from aspp.timing import seconds_to_ticks

NODES = (76, 77, 95)


def record_for(node_index: int, t: float) -> bytes:
    """A physically plausible record: a body rotating slowly about z."""
    yaw = 0.2 * t
    timer = seconds_to_ticks(t)
    accel, rate = (0.0, 0.0, -1.0), (0.0, 0.0, 0.2)
    if node_index == 0:
        return encode(0xC2, accel=accel, ang_rate=rate, timer=timer)
    if node_index == 1:
        return encode(0xCC, accel=accel, ang_rate=rate, mag=(math.nan,) * 3,
                      orientation=matrix_from_euler(0.0, 0.0, yaw), timer=timer)
    return encode(0xCE, roll=0.0, pitch=0.0, yaw=yaw, timer=timer)


def mixed_stream(packets: int, seed: int = 1, garbage_fraction: float = 0.01) -> bytes:
    rng = random.Random(seed)
    out = bytearray()
    garbage_due = 0.0
    for i in range(packets):
        node = i % 3
        packet = encode_reply_packet(NODES[node], record_for(node, i * 0.01 / 3),
                                     lqi=rng.randrange(100, 255), rssi=rng.randrange(-90, -30))
        if i % 10 == 0:
            out.append(0xAA)  # the ACK of a command, glued to this packet's SOP
        out += packet
        garbage_due += garbage_fraction / (1 - garbage_fraction) * len(packet)
        if garbage_due >= 8 or i == packets - 1:
            run = round(garbage_due)
            out += bytes(rng.randrange(256) for _ in range(run))
            garbage_due -= run
    return bytes(out)


def run_once(stream: bytes, chunk: int) -> tuple[float, int]:
    decoder = Decoder()
    feed = decoder.feed
    replies = 0
    start = time.perf_counter()
    for offset in range(0, len(stream), chunk):
        for event in feed(stream[offset:offset + chunk]):
            if type(event) is Reply:
                replies += 1
    for event in decoder.line_idle():
        if type(event) is Reply:
            replies += 1
    return time.perf_counter() - start, replies


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--packets", type=int, default=300_000)
    parser.add_argument("--chunk", type=int, default=4096, help="bytes per read")
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core
    stream = mixed_stream(args.packets)
    best = math.inf
    for _ in range(args.repeat):
        elapsed, replies = run_once(stream, args.chunk)
        if replies != args.packets:
            print(f"FAILED: decoded {replies} of {args.packets} packets", file=sys.stderr)
            return 1
        best = min(best, elapsed)
    rate = args.packets / best
    print(f"decoder: {rate:,.0f} packets/s on one core "
          f"({args.packets:,} packets, {len(stream):,} bytes, {args.chunk}-byte reads, "
          f"best of {args.repeat}; Python {platform.python_version()}, "
          f"{platform.machine()})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
