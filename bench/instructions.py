#!/usr/bin/env python3
"""Instructions a record takes on the daemon's read path, counted by valgrind: a figure
that does not move with the machine's load, for changes too small for wall-clock
timing to see (each choice on the per-record path that carries a factor in its comment
was measured with this).

    .venv/bin/python bench/instructions.py [TREE ...]   # default: this checkout

For each tree (a checkout of the project: another commit's worktree, say), the read
path (decoder, record, tally, publish to a PUB with no subscriber, supervision,
scheduler) runs under ``valgrind --tool=callgrind`` over 20,000 and over 40,000
records of perf.py's mixed stream, each node's stream known as it is once armed; the
difference of the two counts over 20,000 is the cost of one record, start-up excluded.
PYTHONHASHSEED is fixed, so the count repeats to within a few instructions.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parent
RUN = r'''
import asyncio, inspect, sys
tree, packets = sys.argv[1], int(sys.argv[2])
sys.path.insert(0, tree)
import aspp, gateway
try:
    from gateway.daemon.app import Gateway
    from gateway.daemon.config import GatewayConfig
    try:  # (a tree from before the daemon's station/ package: its flat reader)
        from gateway.daemon.station.reader import Reader
    except ImportError:
        from gateway.daemon.reader import Reader
    # a gateway of base stations: its first station's reader (before: the gateway's)
    def feeder(gw): return (gw.stations[0] if hasattr(gw, "stations") else gw).reader.on_data
    # a read's UNIX time, and its monotonic time where the reader takes one too
    CLOCKS = 2 if "monotonic" in inspect.signature(Reader.on_data).parameters else 1
except ImportError:  # a tree from before the daemon's package
    from gateway.daemon import Gateway
    from gateway.config import GatewayConfig
    def feeder(gw): return gw._on_data
    CLOCKS = 1
sys.path.insert(1, sys.argv[3])
from decoder_throughput import mixed_stream
stream = mixed_stream(40000)
chunks = [stream[o:o + 4096] for o in range(0, len(stream), 4096)]
chunks = chunks[:len(chunks) * packets // 40000]
config = GatewayConfig.model_validate({
    "base_station": {"port": "loop://"},
    "publish": {"endpoint": "inproc://instructions", "high_water_mark": 10_000_000},
    "control": {"endpoint": "inproc://control"},
    "nodes": [{"address": a} for a in (76, 77, 95)]})
async def run():
    gw = Gateway(config)
    feed = feeder(gw)
    for address, record in ((76, "accel_angrate"), (77, "accel_angrate_mag_orientation"),
                            (95, "euler")):
        gw.nodes[address].streaming(record)
    # reads of the host's clock advancing with the stream's own timers (100 Hz a node),
    # so that a node's clock estimate sees the pairs it sees on a line
    seconds_a_byte = 40000 * 0.01 / 3 / len(stream)
    for index, chunk in enumerate(chunks):
        feed(chunk, *(1.7e9 + (index + 1) * 4096 * seconds_a_byte,) * CLOCKS)
    gw.publisher.close()
    gw._context.destroy(linger=0)
asyncio.run(run())
'''


def instructions(tree: Path, packets: int) -> int:
    run = subprocess.run(
        ["valgrind", "--tool=callgrind", "--callgrind-out-file=/dev/null", sys.executable,
         "-c", RUN, str(tree), str(packets), str(BENCH)],
        capture_output=True, text=True, env={**os.environ, "PYTHONHASHSEED": "0"},
        timeout=1800)
    found = re.search(r"Collected : (\d+)", run.stderr)
    if run.returncode or not found:
        raise RuntimeError(f"{tree}: {run.stderr[-2000:]}")
    return int(found.group(1))


def main() -> int:
    if shutil.which("valgrind") is None:
        print("valgrind is not installed (Debian: apt install valgrind)", file=sys.stderr)
        return 1
    trees = [Path(t).resolve() for t in sys.argv[1:]] or [BENCH.parent]
    print("| tree | instructions per record |\n|---|---|")
    for tree in trees:
        per_record = (instructions(tree, 40000) - instructions(tree, 20000)) / 20000
        print(f"| {tree} | {per_record:,.0f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
