#!/usr/bin/env python3
"""Recording figures: bytes per hour per node, replay and export speed.

    .venv/bin/python bench/recording.py [--seconds 60]

1. the installed gx2-gateway records one node streaming 0xC2 (accel_angrate) at 100 Hz
   on its built-in simulator for ``--seconds``; the files' size scaled to an hour;
2. the same recording replayed by gx2-gateway with ``replay://...?speed=0&exit=true``
   (delay=0): records published per second of the replay, counted by a subscriber;
3. ``gx2ctl export`` of that recording to CSV and to Parquet: records per second.

(The CPU cost of recording at a saturated line is measured side by side by
``bench/ab.py --base HEAD --head HEAD --record --skip-pipeline``.)
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import msgpack
import yaml
import zmq
from benchutil import free_port

BIN = Path(sys.executable).parent


def config(work: Path, port: str, record: bool) -> Path:
    data = {"base_station": {"port": port},
            "publish": {"endpoint": f"tcp://127.0.0.1:{free_port()}"},
            "control": {"endpoint": f"tcp://127.0.0.1:{free_port()}"},
            "nodes": [{"address": 76, "stream": "accel_angrate"}]}
    if record:
        data["record"] = {"directory": str(work / "recordings")}
    path = work / ("record.yaml" if record else "replay.yaml")
    path.write_text(yaml.safe_dump(data))
    return path


def record(work: Path, seconds: float) -> tuple[int, int]:
    """(bytes on disk, records) of ``seconds`` of one node at 100 Hz."""
    path = config(work, "sim://", record=True)
    gateway = subprocess.Popen([BIN / "gx2-gateway", "--config", path, "--log-level",
                                "WARNING"])
    time.sleep(seconds + 2)  # (a recording's length, not a synchronisation)
    gateway.terminate()
    gateway.wait(10)
    files = sorted((work / "recordings").glob("*.mcap"))
    records = int(subprocess.run(
        [sys.executable, "-c", "import sys; from mcap.reader import make_reader; "
         "s = make_reader(open(sys.argv[1], 'rb')).get_summary(); "
         "print(sum(n for i, n in s.statistics.channel_message_counts.items() "
         "if s.channels[i].topic == 'gx2/76/accel_angrate'))", str(files[0])],
        capture_output=True, text=True, check=True).stdout)
    return sum(f.stat().st_size for f in files), records


def replay(work: Path) -> tuple[int, float]:
    """(records published, seconds from the first to the last) at speed=0."""
    path = config(work, f"replay://{work / 'recordings'}?speed=0&exit=true&delay=1", False)
    endpoint = yaml.safe_load(path.read_text())["publish"]["endpoint"]
    context = zmq.Context()
    sub = context.socket(zmq.SUB)
    sub.setsockopt(zmq.RCVHWM, 0)
    sub.setsockopt(zmq.SUBSCRIBE, b"gx2/76/")
    sub.connect(endpoint)
    gateway = subprocess.Popen([BIN / "gx2-gateway", "--config", path, "--log-level",
                                "WARNING"])
    times: list[float] = []
    while gateway.poll() is None or sub.poll(200):
        if sub.poll(100):
            msgpack.unpackb(sub.recv_multipart()[1])
            times.append(time.perf_counter())
    sub.close()
    context.term()
    return len(times), times[-1] - times[0]


def export(work: Path, form: str) -> float:
    out = work / f"tables-{form}"
    start = time.perf_counter()
    subprocess.run([BIN / "gx2ctl", "export", str(work / "recordings"), "--out", str(out),
                    "--format", form], check=True, capture_output=True)
    return time.perf_counter() - start


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="gx2-bench-recording-"))
    try:
        size, records = record(work, args.seconds)
        print(f"recorded {records} records in {size:,} bytes (serial, written, records, "
              f"status): "
              f"{size / records:.1f} bytes a record, "
              f"{size / records * 100 * 3600 / 1e6:.1f} MB an hour at 100 Hz")
        played, seconds = replay(work)
        print(f"replay, speed=0: {played} records in {seconds:.2f} s, "
              f"{played / seconds:,.0f} records/s")
        for form in ("csv", "parquet"):
            took = export(work, form)
            print(f"export {form}: {records} records in {took:.2f} s (process included), "
                  f"{records / took:,.0f} records/s")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
