#!/usr/bin/env python3
"""Control fuzz: malformed control messages at a gateway while three nodes stream.

Runs gx2-sim (three nodes streaming at 100 Hz) behind a pty and the installed
gx2-gateway on it, subscribes to every node, and sends --messages malformed requests
(random bytes, random msgpack values, maps with wrong, missing, extra or ill-typed
fields, oversize payloads, extra frames). Each must be answered with an error or, if it
cannot carry an answer, dropped; afterwards the gateway must be alive and no record
lost (no gap in any node's seq, nothing published short of what the base station sent).

    python bench/fuzz_control.py [--messages 10000] [--seed 1]
"""

from __future__ import annotations

import argparse
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from itertools import pairwise
from pathlib import Path

import msgpack
import yaml
import zmq
from benchutil import free_port

from gateway.common.protocol import MAX_REQUEST_BYTES
from gateway.sim.node import NodeSettings
from gateway.sim.server import Simulator

OPS = ["ping", "status", "start", "stop", "poll", "eeprom_read", "eeprom_write", "rate",
       "info", "", "PING", "explode", None, 7]
VALUES = [None, True, -1, 0, 76, 65535, 70000, 2 ** 63 - 1, -(2 ** 63), 1.5, float("nan"), "", "76",
          "euler", "0xC2", "x" * 200, b"\x00\xff", [], [76, 77], {"a": 1}, [[[]]]]


MAXMSGSIZE = MAX_REQUEST_BYTES + 1024  # what gateway/control.py sets on the socket


def malformed(rng: random.Random) -> tuple[list[bytes], bool]:
    """One bad message as frames, and whether it can carry an answer."""
    kind = rng.randrange(6)
    if kind == 0:
        return [b"", bytes(rng.randrange(256) for _ in range(rng.randrange(1, 64)))], True
    if kind == 1:
        return [b"", msgpack.packb(rng.choice(VALUES))], True
    if kind == 2:  # a request with something wrong in it
        request: dict[object, object] = {"id": rng.choice([rng.randrange(1 << 30), "x"])}
        request["op"] = rng.choice(OPS)
        for key in rng.sample(["node", "nodes", "record", "address", "value", "hz", "x"],
                              rng.randrange(0, 4)):
            request[key] = rng.choice(VALUES)
        if request["op"] in ("stop", "start", "rate", "eeprom_write"):
            request["node"] = rng.choice(["76", -1, 0, 70000, None])  # never valid
        if request["op"] == "status" and len(request) == 2:
            request["extra"] = 1
        return [b"", msgpack.packb(request)], True
    if kind == 3:  # no id at all, or a map key that is not a string
        return [b"", msgpack.packb(rng.choice([{"op": "status"}, {1: 2}, {"id": []}]))], True
    if kind == 4:  # over 4 KiB: answered; over ZMQ_MAXMSGSIZE: the transport drops it
        size = rng.randrange(4100, 6000)
        return [b"", b"\x81\xa2id\x01" + b"\x00" * size], size + 5 <= MAXMSGSIZE
    return [b"a", b"b", b"c", b"d"], False  # four frames cannot be a request: dropped


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--messages", type=int, default=10_000)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    rng = random.Random(args.seed)
    work = Path(tempfile.mkdtemp(prefix="gx2-fuzz-"))
    sim = Simulator([NodeSettings(a) for a in (76, 77, 78)], link=work / "gx2").start()
    control, publish = f"tcp://127.0.0.1:{free_port()}", f"tcp://127.0.0.1:{free_port()}"
    streams = {76: "accel_angrate", 77: "euler", 78: "mag"}
    (work / "nodes.yaml").write_text(yaml.safe_dump({
        "base_station": {"port": str(work / "gx2")}, "publish": {"endpoint": publish},
        "control": {"endpoint": control},
        "nodes": [{"address": a, "stream": r} for a, r in streams.items()]}))
    script = shutil.which("gx2-gateway", path=str(Path(sys.executable).parent))
    log = (work / "log").open("w")
    gateway = subprocess.Popen([script or "gx2-gateway", "--config", str(work / "nodes.yaml"),
                                "--log-level", "WARNING"], stdout=subprocess.DEVNULL, stderr=log)
    context = zmq.Context()
    sub = context.socket(zmq.SUB)
    sub.setsockopt(zmq.SUBSCRIBE, b"gx2/")
    sub.setsockopt(zmq.RCVHWM, 0)
    sub.connect(publish)
    dealer = context.socket(zmq.DEALER)
    dealer.setsockopt(zmq.LINGER, 0)
    dealer.connect(control)
    seqs: dict[int, list[int]] = {a: [] for a in streams}

    def read_records(timeout_ms: int = 0) -> None:
        while sub.poll(timeout_ms):
            topic, payload = sub.recv_multipart()
            if not topic.startswith(b"gx2/gateway/"):
                record = msgpack.unpackb(payload)
                seqs[record["node"]].append(record["seq"])
            timeout_ms = 0

    def request(frames: list[bytes], timeout: float) -> dict | None:
        while dealer.poll(0):  # a late answer to an earlier message is not this one's
            dealer.recv_multipart()
        dealer.send_multipart(frames)
        if dealer.poll(int(timeout * 1000)):
            return msgpack.unpackb(dealer.recv_multipart()[-1])
        return None

    try:
        deadline = time.monotonic() + 20
        while not all(seqs.values()):
            if time.monotonic() > deadline:
                print("FAILED: the streams never started", file=sys.stderr)
                return 1
            request([b"", msgpack.packb({"id": "s", "op": "status"})], 0.2)
            read_records(50)
        answered = dropped = unexpected = 0
        start = time.monotonic()
        for _ in range(args.messages):
            frames, answerable = malformed(rng)
            reply = request(frames, 1.0 if answerable else 0.02)
            if reply is not None and reply.get("ok") is False:
                answered += 1
            elif reply is None and not answerable:
                dropped += 1
                # an oversize message makes ZeroMQ drop the sender's connection, and
                # what was in flight with it: wait until we are reconnected and heard
                probe = msgpack.packb({"id": "sync", "op": "status"})
                if request([b"", probe], 5.0) is None:
                    print("FAILED: the gateway stopped answering", file=sys.stderr)
                    return 1
            else:
                unexpected += 1
                print(f"unexpected: {frames!r} -> {reply!r}", file=sys.stderr)
            read_records()
        elapsed = time.monotonic() - start
        alive = request([b"", msgpack.packb({"id": "end", "op": "status"})], 5)
        for address in streams:  # stop the streams at the source, then read what is left
            sim.call(lambda station, now, a=address: setattr(station.nodes[a], "continuous", 0))
        read_records(1000)
        read_records(500)
        gaps = sum(b - a - 1 for s in seqs.values() for a, b in pairwise(s))
        status = request([b"", msgpack.packb({"id": "final", "op": "status"})], 5)
        sent = sim.station.stats.packets_sent
        short = sum(sent.get(n["node"], 0) - n["published"] for n in status["result"]["nodes"])
        print(f"control fuzz: {args.messages:,} malformed messages in {elapsed:.1f} s: "
              f"{answered:,} answered with an error, {dropped:,} dropped (no room for an "
              f"answer), {unexpected} unexpected; gateway alive: {bool(alive and alive['ok'])}; "
              f"records received {sum(len(s) for s in seqs.values()):,}, seq gaps {gaps}, "
              f"published short of sent {short} (seed {args.seed})")
        return 0 if (unexpected == 0 and alive and gaps == 0 and short == 0) else 1
    finally:
        gateway.send_signal(signal.SIGTERM)
        gateway.wait(5)
        log.close()
        sim.stop()
        context.destroy(linger=0)
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
