"""The LSL output of a replay, seen from outside, run in a private network namespace
(tests/helpers/lslnet.py; never in the pytest process): a recording of published
records written here by the project's own writer, played by the installed gx2-gateway
with ``lsl:``, and an independent pylsl inlet for each stream. Prints one JSON line:
each stream's channel labels, the samples pulled, and the gateway's status.

The recording: node 76's ``accel_angrate_mag`` as an Inertia-Link sends it (its
magnetometer NaN, null in the file), and node 77's ``accel_angrate_orientation`` as a
file written before the gateway added a matrix's roll, pitch, yaw and quaternion (none
in it), every fifth of its accelerations' x null. LEAD records of each first, then,
GAP_S later, SAMPLES more: the streams are made on the first (a replay's records name
no rate: PENDING_S after), and the inlets are open before the rest are played.

    python -m tests.helpers.lsl_replay_probe '{"directory": DIR}'
"""

from __future__ import annotations

import contextlib
import json
import math
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import yaml
import zmq

from aspp.orientation import matrix_from_euler
from gateway.recording.writer import RecordingWriter
from tests.helpers.gateway import Control
from tests.helpers.ports import endpoint
from tests.helpers.waiting import wait_for

LEAD = 10
GAP_S = 10.0
SAMPLES = 300
STREAMS = ("gx2-76-accel_angrate_mag", "gx2-77-accel_angrate_orientation")


def record(node: int, seq: int, at: float) -> tuple[str, dict[str, Any]]:
    common = {"node": node, "seq": seq, "host_time": at + 0.004, "time": at,
              "device_time": seq / 100, "lqi": 200, "rssi": -45, "station": "station1",
              "timer": seq * 1966, "ang_rate": [0.01, 0.02, 0.03]}
    if node == 76:
        return "gx2/76/accel_angrate_mag", {
            **common, "record": "accel_angrate_mag", "command": 0xCB,
            "accel": [0.0, 0.1, -1.0], "mag": [math.nan] * 3}
    matrix = matrix_from_euler(0.2, -0.1, seq / 100)
    return "gx2/77/accel_angrate_orientation", {
        **common, "record": "accel_angrate_orientation", "command": 0xC8,
        "accel": [math.nan if seq % 5 == 0 else 0.02, 0.1, -1.0],
        "orientation": [list(row) for row in matrix]}


def write(path: Path) -> None:
    start = time.time()
    with path.open("wb") as output:
        writer = RecordingWriter(output)
        for index in range(LEAD + SAMPLES):
            at = start + index / 100 + (GAP_S if index >= LEAD else 0.0)
            for node in (76, 77):
                writer.message(*record(node, index + 1, at))
        writer.finish()


def main() -> int:
    import pylsl  # (here, in the namespace: the test's process imports the constants)

    options = json.loads(sys.argv[1])
    work = Path(options["directory"])
    write(work / "old.mcap")
    publish, control = endpoint(), endpoint()
    (work / "nodes.yaml").write_text(yaml.safe_dump({
        "base_station": {"port": f"replay://{work / 'old.mcap'}?delay=1"},
        "publish": {"endpoint": publish}, "control": {"endpoint": control},
        "lsl": {"prefix": "gx2"}, "nodes": [{"address": 76}, {"address": 77}]}))
    script = shutil.which("gx2-gateway", path=str(Path(sys.executable).parent))
    log = (work / "gateway.log").open("w")
    proc = subprocess.Popen([script or "gx2-gateway", "--config", str(work / "nodes.yaml")],
                            stdout=log, stderr=subprocess.STDOUT)
    context = zmq.Context()
    result: dict[str, Any] = {}
    try:
        found: dict[str, Any] = {}

        def resolved() -> bool:
            if proc.poll() is not None:
                raise AssertionError(f"gateway exited {proc.returncode}")
            for info in pylsl.resolve_streams(wait_time=1.0):
                found.setdefault(info.name(), info)
            return set(STREAMS) <= set(found)
        wait_for(resolved, 20, f"LSL streams {STREAMS}")
        inlets = {name: pylsl.StreamInlet(found[name], max_buflen=60) for name in STREAMS}
        labels = {}
        for name, inlet in inlets.items():
            info, channel, labels[name] = inlet.info(timeout=5), None, []
            channel = info.desc().child("channels").child("channel")
            while not channel.empty():
                labels[name].append(channel.child_value("label"))
                channel = channel.next_sibling()
            inlet.open_stream(timeout=5)
        pulled: dict[str, list[list[float]]] = {name: [] for name in STREAMS}

        def all_pulled() -> bool:
            for name, inlet in inlets.items():
                chunk, _ = inlet.pull_chunk(timeout=0.0)
                pulled[name].extend(chunk)
            return all(len(samples) >= SAMPLES for samples in pulled.values())
        with contextlib.suppress(AssertionError):  # (the test says what is missing)
            wait_for(all_pulled, GAP_S + 20, f"{SAMPLES} samples of each stream")
        status = Control(context, control).result("status")
        result = {"labels": labels, "samples": pulled, "lsl": status["lsl"],
                  "outputs": status["outputs"]}
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
        context.destroy(linger=0)
        log.close()
    result["exit"] = proc.returncode
    result["log"] = (work / "gateway.log").read_text()[-3000:]
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
