#!/usr/bin/env python3
"""What the reading of a message's JSON pays to find an integer orjson reads otherwise
than the standard library (gateway/recording/entry.py): microseconds a message for
orjson's own parse and each way of looking, over the messages of a recording.

    .venv/bin/python bench/jsonlong.py RECORDING.mcap [--messages 100000]

Any recording does (the demo's, recorded: README); its messages that are not JSON (the
serial reads) are left out. Each way is timed over the same messages, in turn, best of 3 rounds.
"""

from __future__ import annotations

import argparse
import contextlib
import re
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import orjson

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from gateway.recording.entry import _may_hold_a_long_integer
from gateway.recording.files import is_serial_reads
from gateway.recording.reader import read_all
from gateway.recording.reports import Reading


def walk(value: Any) -> bool:
    """The way before: a walk of orjson's values for a float past 64 bits."""
    items = [value]
    while items:
        item = items.pop()
        if isinstance(item, float):
            if not -(2.0**63) < item < 2.0**63:
                return True
        elif isinstance(item, dict):
            items.extend(item.values())
        elif isinstance(item, list):
            items.extend(item)
    return False


def per_message(call: Callable[[Any], Any], values: list[Any], rounds: int = 3) -> float:
    best = float("inf")
    for _ in range(rounds):
        started = time.perf_counter()
        for value in values:
            call(value)
        best = min(best, time.perf_counter() - started)
    return best / len(values) * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", type=Path)
    parser.add_argument("--messages", type=int, default=100_000)
    args = parser.parse_args()
    data, parsed = [], []
    for entry in read_all([args.recording], Reading()):
        if len(data) < args.messages and not is_serial_reads(entry.topic):
            with contextlib.suppress(ValueError):  # (a channel of another encoding)
                parsed.append(orjson.loads(entry.data))
                data.append(entry.data)
    digits = re.compile(rb"\d{19}")
    print(f"{len(data):,} messages of {args.recording.name}: us a message")
    print(f"  orjson.loads             {per_message(orjson.loads, data):5.2f}")
    print(f"  walk of its values       {per_message(walk, parsed):5.2f}")
    print(f"  regular expression       {per_message(digits.search, data):5.2f}")
    print(f"  digits made one, found   {per_message(_may_hold_a_long_integer, data):5.2f}")


if __name__ == "__main__":
    main()
