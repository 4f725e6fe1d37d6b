#!/usr/bin/env python3
"""A message's JSON (what the recorder and the live view write), encoded by the
standard library (gateway.common.jsontext.compact as it was) against orjson, over the
payloads the gateway publishes.

    .venv/bin/python bench/jsonenc.py

The payloads are the gateway's own: perf.py's mixed stream fed through a gateway's
read path (loop://), every message the outputs are given kept; a copy of them with
a NaN magnetometer (an Inertia-Link's) besides. Each side encodes all of them, in
interleaved rounds (A B A B ...); the table gives the median of the rounds' B/A
ratios. Before timing, every payload's two encodings are checked to parse back to
the same value (NaN as null, floats equal, keys in the same order).
"""

from __future__ import annotations

import asyncio
import json
import math
import statistics
import sys
import time
from pathlib import Path
from typing import Any

BENCH = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH.parent))
sys.path.insert(0, str(BENCH))

import orjson  # noqa: E402
from decoder_throughput import mixed_stream  # noqa: E402

from gateway.common.jsontext import strict  # noqa: E402
from gateway.daemon.app import Gateway  # noqa: E402
from gateway.daemon.config import GatewayConfig  # noqa: E402

ROUNDS = 9
_std = json.JSONEncoder(ensure_ascii=False, separators=(",", ":"), allow_nan=False).encode
_std_loose = json.JSONEncoder(ensure_ascii=False, separators=(",", ":")).encode


def stdlib(value: dict[str, Any]) -> bytes:
    try:
        return _std(value).encode()
    except (ValueError, TypeError):
        return _std_loose(strict(value)).encode()


def with_orjson(value: dict[str, Any]) -> bytes:
    try:
        return orjson.dumps(value)
    except TypeError:
        return orjson.dumps(strict(value))


def payloads() -> list[dict[str, Any]]:
    config = GatewayConfig.model_validate({
        "base_station": {"port": "loop://"},
        "publish": {"endpoint": "inproc://jsonenc"}, "control": {"endpoint": "inproc://c"},
        "nodes": [{"address": a} for a in (76, 77, 95)]})
    got: list[dict[str, Any]] = []

    async def run() -> None:
        gw = Gateway(config)
        gw.publisher.send = lambda topic, payload: got.append(payload) or True  # type: ignore[method-assign]
        for address, record in ((76, "accel_angrate"),
                                (77, "accel_angrate_mag_orientation"), (95, "euler")):
            gw.nodes[address].streaming(record)
        stream = mixed_stream(6000)
        for index in range(0, len(stream), 4096):
            gw.stations[0].reader.on_data(stream[index:index + 4096],
                                          1.7e9 + index / 11520, 100 + index / 11520)
        gw.publisher.close()
        gw._context.destroy(linger=0)
    asyncio.run(run())
    nan = [{**p, "mag": [math.nan] * 3} for p in got if "mag" in p]
    return got + nan


def same(a: Any, b: Any) -> bool:
    if isinstance(a, dict):
        return isinstance(b, dict) and list(a) == list(b) and all(
            same(a[k], b[k]) for k in a)
    if isinstance(a, list):
        return isinstance(b, list) and len(a) == len(b) and all(map(same, a, b))
    return a == b and type(a) is type(b)


def main() -> int:
    messages = payloads()
    for payload in messages:
        a, b = stdlib(payload), with_orjson(payload)
        assert same(json.loads(a), json.loads(b)), (a, b)
        assert b"NaN" not in b and b"Infinity" not in b
    print(f"{len(messages)} payloads ({sum(1 for m in messages if 'mag' in m)} with mag); "
          "each encoding parses back to the same value")

    finite = [m for m in messages if not any(isinstance(v, list) and any(
        isinstance(x, float) and math.isnan(x) for x in v) for v in m.values())]
    with_nan = [m for m in messages if m not in finite]
    print("| payloads | json (stdlib), ns a message | orjson | orjson faster by |")
    print("|---|---|---|---|")
    for name, group in (("as published", finite), ("with a NaN magnetometer", with_nan)):
        def side(encode: Any, group: list[dict[str, Any]] = group) -> float:
            start = time.perf_counter()
            for payload in group:
                encode(payload)
            return time.perf_counter() - start
        rounds = [(side(stdlib), side(with_orjson)) for _ in range(ROUNDS)]
        ratio = statistics.median(a / b for a, b in rounds)
        per = min(a for a, _ in rounds) / len(group) * 1e9
        per_o = min(b for _, b in rounds) / len(group) * 1e9
        print(f"| {name} ({len(group)}) | {per:.0f} | {per_o:.0f} | {ratio:.1f}x |")
    print(f"(median of {ROUNDS} interleaved rounds; ns: the best round's)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
