#!/usr/bin/env python3
"""Decoder fuzz: many generated inputs, each fed in random chunks to a fresh decoder.

Inputs: random bytes; valid mixed streams mutated (bit flips, inserted, deleted and
duplicated bytes); streams cut at random points; false headers (0xAA and a bogus
length) before valid packets; runs of 0x21/0x02/0xAA. For every input it checks what
the decoder promises: no exception, at most 265 + 512 bytes held between feeds, and
every byte fed accounted for exactly once (packets, control bytes, discarded runs).
Memory is sampled as the process's peak RSS before and after.

    python bench/fuzz_decoder.py [--inputs 1000000] [--seed 1]
"""

from __future__ import annotations

import argparse
import random
import resource
import sys
import time

from aspp import Decoder
from aspp.decoder import MAX_DISCARD
from aspp.events import stream_bytes
from aspp.frame import encode_reply_packet

MAX_PENDING = 265 + MAX_DISCARD


def packet(rng: random.Random) -> bytes:
    size = rng.choice((2, 6, 13, 17, 29, 41, 65, 77, rng.randrange(1, 120)))
    body = bytes([rng.choice((0xC2, 0xCC, 0xCE, 0xE5, rng.randrange(256)))])
    body += bytes(rng.choice((0, 0xAA, 0x21, 0x02, rng.randrange(256)))
                  for _ in range(size - 1))
    flags = 0x07 if rng.random() < 0.9 else rng.choice((0x00, 0x0B, rng.randrange(0xAA)))
    return encode_reply_packet(rng.randrange(1, 65535), body, rng.randrange(256),
                               rng.randrange(-128, 128), flags=flags)


def stream(rng: random.Random) -> bytes:
    out = bytearray()
    for _ in range(rng.randrange(1, 6)):
        out += packet(rng)
        if rng.random() < 0.3:
            out += rng.choice((b"\xaa", b"\x21", b"\x02"))
    return bytes(out)


def mutate(rng: random.Random, data: bytes) -> bytes:
    buf = bytearray(data)
    for _ in range(rng.randrange(1, 6)):
        action = rng.randrange(5)
        at = rng.randrange(len(buf) + 1)
        if action == 0 and buf and at < len(buf):
            buf[at] ^= 1 << rng.randrange(8)
        elif action == 1:
            buf[at:at] = bytes([rng.choice((0xAA, 0x21, 0x02, rng.randrange(256)))])
        elif action == 2 and at < len(buf):
            del buf[at:at + rng.randrange(1, 8)]
        elif action == 3:
            buf[at:at] = buf[at:at + rng.randrange(1, 40)]
        else:
            buf = buf[:at]
    return bytes(buf)


def generate(rng: random.Random) -> bytes:
    kind = rng.randrange(5)
    if kind == 0:
        return bytes(rng.randrange(256) for _ in range(rng.randrange(0, 300)))
    if kind == 1:
        return mutate(rng, stream(rng))
    if kind == 2:
        data = stream(rng)
        return data[:rng.randrange(len(data) + 1)]
    if kind == 3:
        header = bytes((0xAA, rng.randrange(256), rng.randrange(256), rng.randrange(256),
                        rng.randrange(256), rng.randrange(0x80, 0x100)))
        return header + bytes(rng.randrange(256) for _ in range(rng.randrange(6))) + stream(rng)
    return bytes(rng.choice((0xAA, 0x21, 0x02, 0x07, 0x00)) for _ in range(rng.randrange(600)))



def check(rng: random.Random, data: bytes) -> str | None:
    decoder = Decoder()
    events = []
    at = 0
    while at < len(data):
        step = rng.choice((1, 2, 7, 64, 4096))
        events += decoder.feed(data[at:at + step])
        at += step
        if decoder.pending > MAX_PENDING:
            return f"holds {decoder.pending} bytes"
    events += decoder.line_idle()
    if decoder.pending:
        return f"{decoder.pending} bytes left after line_idle()"
    if b"".join(stream_bytes(e) for e in events) != data:
        return "the events do not account for every byte exactly once"
    return None


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--inputs", type=int, default=1_000_000)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    rng = random.Random(args.seed)
    failures = exceptions = total_bytes = 0
    start, rss_start = time.monotonic(), peak_rss_mb()
    for index in range(args.inputs):
        data = generate(rng)
        total_bytes += len(data)
        try:
            problem = check(rng, data)
        except Exception as error:  # the property under test: there must be none
            exceptions += 1
            problem = f"{type(error).__name__}: {error}"
        if problem:
            failures += 1
            if failures <= 5:
                print(f"input {index}: {problem}: {data.hex()}", file=sys.stderr)
        if index and index % 100_000 == 0:
            print(f"  {index:,} inputs, {failures} failures, peak RSS {peak_rss_mb():.1f} MB",
                  flush=True)
    elapsed = time.monotonic() - start
    print(f"decoder fuzz: {args.inputs:,} inputs ({total_bytes:,} bytes), {exceptions} "
          f"exceptions, {failures} failed checks, peak RSS {rss_start:.1f} -> "
          f"{peak_rss_mb():.1f} MB, {elapsed:.0f} s (seed {args.seed})")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
