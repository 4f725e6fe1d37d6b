#!/usr/bin/env python3
"""LSL timestamps, measured (issue 36): what an independent pylsl inlet receives from
the gateway's ``lsl:`` output against the ZeroMQ stream's ``time`` for the same record,
and both against gx2-sim's true sample instants. Run by hand, as root:

    .venv/bin/python bench/lsltime.py [--seconds 20]

tests/helpers/lsl_probe.py does the work (gx2-sim with 3 nodes streaming 0xC2 at
96 Hz, a saturated 115200-baud line; the installed gx2-gateway; a ZeroMQ subscriber;
a pylsl inlet per stream, its timestamps taken with time_correction()), in a private
network namespace with only the loopback up (tests/helpers/lslnet.py): LSL's
multicast never leaves the machine. Spread is |error - its median|; bias is the median
(the simulator's radio delay against ``latency_ms``, 3 ms: the same for both).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from benchutil import REPO  # noqa: F401  (the suite's helpers on the path)

from tests.helpers.lslnet import namespace_refusal, run_probe

NODES = [{"address": a, "stream": "accel_angrate", "divider": 533} for a in (76, 77, 78)]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0)
    args = parser.parse_args()
    refusal = namespace_refusal()
    if refusal:
        print(f"no private network namespace: {refusal}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="gx2-lsltime-") as directory:
        found = run_probe("tests.helpers.lsl_probe",
                          {"seconds": args.seconds, "nodes": NODES},
                          Path(directory), timeout=args.seconds + 120)
    print(f"{args.seconds:g} s of inlet samples, 3 nodes of 0xC2 at 96 Hz (a saturated "
          "line)")
    print("| stream | samples | inlet - time, max (us) | inlet - truth: bias / p99 / max "
          "(ms) | time - truth: bias / p99 / max (ms) |")
    print("|---|---|---|---|---|")
    for name, m in sorted(found["matched"].items()):
        lsl, zmq = m["truth"], m["zmq_truth"]
        print(f"| {name} | {m['matched']} | {m['time_error_max_s'] * 1e6:.1f} | "
              f"{lsl['bias_ms']:.3f} / {lsl['p99_ms']:.3f} / {lsl['max_ms']:.3f} | "
              f"{zmq['bias_ms']:.3f} / {zmq['p99_ms']:.3f} / {zmq['max_ms']:.3f} |")
    print(f"time_correction(): {found['corrections']}; local_clock() - time.monotonic(): "
          f"{found['lsl_minus_monotonic'] * 1e6:.2f} us")
    return 0


if __name__ == "__main__":
    sys.exit(main())
