#!/usr/bin/env python3
"""The per-record path's small choices, each timed against its plain alternative.

Run by hand, not in CI:

    .venv/bin/python bench/micro.py

Each pair runs in interleaved rounds (A B A B ...); a round's ratio is B's time over
A's, and the table gives the median of the rounds' ratios, so a busy neighbour that
slows one round slows both sides of it. The comments beside the code these choices
live in quote the factors this prints; a factor inside the noise (0.95..1.05) is not
worth its cost in readability.
"""

from __future__ import annotations

import json
import statistics
import struct
import sys
import time
import zlib
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import zmq

from aspp import Reply, encode
from aspp.frame import encode_reply_packet
from aspp.records import BY_NAME, Record
from gateway.common.jsontext import compact, strict

ROUNDS = 9
Pair = tuple[str, Callable[[], None], Callable[[], None]]


def timed(run: Callable[[], None]) -> float:
    start = time.perf_counter()
    run()
    return time.perf_counter() - start


def loop(body: Callable[[], object], times: int = 200_000) -> Callable[[], None]:
    def run() -> None:
        for _ in range(times):
            body()
    return run


def pairs() -> list[Pair]:
    packet = encode_reply_packet(76, encode("accel_angrate", accel=(0.1, 0.2, -1.0),
                                            ang_rate=(0.01, 0.02, 0.03), timer=12345),
                                 200, -45)
    spec = BY_NAME["accel_angrate"]
    values = ((0.1, 0.2, -1.0), (0.01, 0.02, 0.03), 12345)
    new_tuple = tuple.__new__
    names = spec.field_names
    common = {"node": 76, "record": "accel_angrate", "command": 0xC2, "seq": 1,
              "host_time": 1.0, "lqi": 200, "rssi": -45}

    body = packet[1:-4]
    want = (packet[-2] << 8) | packet[-1]

    context = zmq.Context()
    pub = context.socket(zmq.PUB)
    pub.bind("inproc://micro")
    compiled = zmq.backend.Socket.send.__get__(pub)
    flags = int(zmq.NOBLOCK)
    items = spec.reply_struct.unpack(packet[7:-4])
    getter = spec.reply_getter

    def by_field() -> tuple:
        out = []
        for start, stop, f in spec.reply_slices:
            out.append(items[start:stop] if f.type.shape in ("vector", "ints")
                       else items[start])
        return tuple(out)

    record = {**dict(zip(names, values, strict=True)), **common, "device_time": 1.0,
              "time": 1.0}
    to_json = json.JSONEncoder(separators=(",", ":"), allow_nan=False).encode

    return [
        ("compact json: the map as it is (strict on failure) vs always through strict()",
         loop(lambda: compact(record)), loop(lambda: to_json(strict(record)))),
        ("record fields: one itemgetter call vs a loop over the layout",
         loop(lambda: getter(items)), loop(by_field)),
        ("Reply event: Reply(raw) vs tuple.__new__(Reply, (raw,))",
         loop(lambda: new_tuple(Reply, (packet,))), loop(lambda: Reply(packet))),
        ("Record: Record(spec, values) vs tuple.__new__",
         loop(lambda: new_tuple(Record, (spec, values))), loop(lambda: Record(spec, values))),
        ("payload: dict(zip(..., strict=True), **common) vs zip without strict=",
         loop(lambda: dict(zip(names, values), **common)),  # noqa: B905
         loop(lambda: dict(zip(names, values, strict=True), **common))),
        ("checksum: sum() & 0xFFFF vs zlib.adler32's low half",
         loop(lambda: zlib.adler32(body) & 0xFFFF == want + 1),
         loop(lambda: sum(body) & 0xFFFF == want)),
        ("header: one struct.unpack_from vs five index reads",
         loop(lambda: struct.unpack_from(">HBHBB", packet, 0)),
         loop(lambda: (packet[0], packet[1], packet[2], (packet[3] << 8) | packet[4],
                       packet[5]))),
        ("send: pyzmq's compiled send vs Socket.send",
         loop(lambda: compiled(b"gx2/76/accel_angrate", flags)),
         loop(lambda: pub.send(b"gx2/76/accel_angrate", flags))),
        writers(compact(common).encode()),
    ]


def writers(message: bytes) -> Pair:
    """The recorder's writer (issue 23): the mcap package's Python writer, which it
    uses, against foxglove-sdk's MCAP writer (Rust), each adding one JSON message to a
    file of its own; the JSON is made beforehand, as both would need it."""
    import tempfile

    import foxglove
    from mcap.writer import CompressionType, Writer

    directory = Path(tempfile.mkdtemp(prefix="gx2-micro-"))
    output = (directory / "mcap.mcap").open("wb")
    writer = Writer(output, compression=CompressionType.ZSTD)
    writer.start()
    channel_id = writer.register_channel("gx2/76/accel_angrate", "json", 0)
    context = foxglove.Context()
    sdk_file = foxglove.open_mcap(directory / "sdk.mcap", context=context)
    channel = foxglove.Channel("gx2/76/accel_angrate", message_encoding="json",
                               context=context)
    stamp = time.time_ns()
    assert channel.has_sinks(), "the SDK's file is not receiving"
    return ("recording writer: mcap's Python Writer vs foxglove-sdk's MCAP writer",
            loop(lambda: writer.add_message(channel_id, stamp, message, stamp)),
            # (sdk_file, named in the lambda, stays open as long as the lambda lives)
            loop(lambda: sdk_file and channel.log(message, log_time=stamp)))


def main() -> int:
    print(f"| choice (A vs B) | B / A, median of {ROUNDS} interleaved rounds | A per call |")
    print("|---|---|---|")
    for name, a, b in pairs():
        rounds = [(timed(a), timed(b)) for _ in range(ROUNDS)]
        ratio = statistics.median(tb / ta for ta, tb in rounds)
        per_call = min(ta for ta, _ in rounds) / 200_000 * 1e9
        print(f"| {name} | {ratio:.2f}x | {per_call:.0f} ns |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
