"""The LSL output seen from outside, run in a private network namespace
(tests/helpers/lslnet.py; never in the pytest process): gx2-sim in this process, the
installed gx2-gateway with ``lsl:``, a ZeroMQ subscriber and an independent pylsl
inlet for each stream. Prints one JSON line: each stream's metadata, and each inlet
sample matched to the ZeroMQ record it is (by its values, in order).

    python -m tests.helpers.lsl_probe '{"directory": DIR, "seconds": 3,
        "nodes": [{"address": 76, "stream": "accel_angrate"}], "prefix": "gx2"}'
"""

from __future__ import annotations

import itertools
import json
import math
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pylsl
import yaml
import zmq

from gateway.recording.tables import field_columns
from gateway.sim.base_station import RadioLink
from gateway.sim.node import NodeSettings
from gateway.sim.server import Simulator
from tests.helpers.gateway import Control
from tests.helpers.ports import endpoint
from tests.helpers.waiting import wait_for

RESOLVE_S = 10.0
WAVE_S = 1.0
"""Seconds of one resolve (half a second found nothing across processes here)."""


def lsl_minus_unix() -> float:
    """LSL's clock less the UNIX clock, here (the median of bracketed reads)."""
    def once() -> float:
        before = time.time()
        lsl = pylsl.local_clock()
        return lsl - (before + time.time()) / 2
    return statistics.median(once() for _ in range(9))


def lsl_minus_monotonic() -> float:
    def once() -> float:
        before = time.monotonic()
        lsl = pylsl.local_clock()
        return lsl - (before + time.monotonic()) / 2
    return statistics.median(once() for _ in range(9))


def stream_meta(info: Any) -> dict[str, Any]:
    channels, channel = [], info.desc().child("channels").child("channel")
    while not channel.empty():
        channels.append({key: channel.child_value(key) for key in ("label", "unit", "type")})
        channel = channel.next_sibling()
    sync = info.desc().child("synchronization")
    return {"name": info.name(), "type": info.type(), "channel_count": info.channel_count(),
            "nominal_srate": info.nominal_srate(), "source_id": info.source_id(),
            "channel_format": info.channel_format(), "channels": channels,
            "synchronization": {key: sync.child_value(key) for key in (
                "can_drop_samples", "time_source", "clock_locked_at_start", "latency_ms")},
            "node": info.desc().child("gx2").child_value("node")}


def values_of(record: dict[str, Any]) -> list[float]:
    """A ZeroMQ record's channel values as float32, in the stream's order."""
    out: list[float] = []
    for _, name, index in field_columns(record["record"], record):
        if name == "timer":
            continue
        value = record[name]
        if index < 0:
            out.append(value)
        elif isinstance(value[0], list):
            out.append(value[index // 3][index % 3])
        else:
            out.append(value[index])
    return np.asarray(out, dtype=np.float32).tolist()


def main() -> int:
    options = json.loads(sys.argv[1])
    work = Path(options["directory"])
    nodes = options["nodes"]
    sim = Simulator([NodeSettings(n["address"], stream=n["stream"],
                                  **({"divider": n["divider"]} if "divider" in n else {}))
                     for n in nodes], link=work / "gx2",
                    radio={n["address"]: RadioLink(data_loss=n["data_loss"])
                           for n in nodes if "data_loss" in n}).start()
    publish, control = endpoint(), endpoint()
    (work / "nodes.yaml").write_text(yaml.safe_dump({
        "base_station": {"port": str(work / "gx2")},
        "publish": {"endpoint": publish}, "control": {"endpoint": control},
        "lsl": {"prefix": options.get("prefix", "gx2")},
        "nodes": [{"address": n["address"], "stream": n["stream"]} for n in nodes]}))
    script = shutil.which("gx2-gateway", path=str(Path(sys.executable).parent))
    log = (work / "gateway.log").open("w")
    proc = subprocess.Popen([script or "gx2-gateway", "--config", str(work / "nodes.yaml")],
                            stdout=log, stderr=subprocess.STDOUT)
    context = zmq.Context()
    sub = context.socket(zmq.SUB)
    sub.setsockopt(zmq.RCVHWM, 0)
    sub.setsockopt(zmq.SUBSCRIBE, b"gx2/")
    sub.connect(publish)
    records: list[dict[str, Any]] = []
    result: dict[str, Any] = {}
    try:
        names = {f"{options.get('prefix', 'gx2')}-{n['address']}-{n['stream']}"
                 for n in nodes}
        found: dict[str, Any] = {}

        def resolved() -> bool:
            if proc.poll() is not None:
                raise AssertionError(f"gateway exited {proc.returncode}")
            for info in pylsl.resolve_streams(wait_time=WAVE_S):
                found.setdefault(info.name(), info)
            return names <= set(found)
        wait_for(resolved, RESOLVE_S * 2, f"LSL streams {sorted(names)}")
        inlets = {name: pylsl.StreamInlet(found[name], max_buflen=60) for name in names}
        metas = {name: stream_meta(inlet.info(timeout=5)) for name, inlet in inlets.items()}
        for inlet in inlets.values():
            inlet.open_stream(timeout=5)
        start = time.monotonic()
        pulled: dict[str, list[tuple[list[float], float]]] = {name: [] for name in names}
        while time.monotonic() - start < options.get("seconds", 3.0):
            while sub.poll(0):
                _, payload = sub.recv_multipart()
                records.append(msgpack.unpackb(payload))
            for name, inlet in inlets.items():
                chunk, stamps = inlet.pull_chunk(timeout=0.0)
                pulled[name].extend(zip(chunk, stamps, strict=True))
            time.sleep(0.01)
        for name, inlet in inlets.items():  # what is on its way still
            chunk, stamps = inlet.pull_chunk(timeout=0.2)
            pulled[name].extend(zip(chunk, stamps, strict=True))
        drained_by = time.monotonic() + 0.5  # (the records of the last samples pulled)
        while (left := drained_by - time.monotonic()) > 0:
            if sub.poll(int(left * 1000) + 1):
                records.append(msgpack.unpackb(sub.recv_multipart()[1]))
        corrections = {name: inlet.time_correction(timeout=5) for name, inlet in inlets.items()}
        truths = {n["address"]: sim.call(lambda station, _, a=n["address"]:
                                         dict(station.nodes[a].sampled)) for n in nodes}
        to_unix, lsl_mono = -lsl_minus_unix(), lsl_minus_monotonic()
        streams = {}
        for name in names:
            node = int(metas[name]["node"])
            mine = [r for r in records if r.get("node") == node and "time" in r
                    and f"{r['record']}" == name.rsplit("-", 1)[1]]
            streams[name] = match(pulled[name], mine, corrections[name], to_unix,
                                  truths[node], lsl_mono)
        status = Control(context, control).result("status")
        result = {"streams": metas, "matched": streams, "corrections": corrections,
                  "lsl_minus_monotonic": lsl_mono, "status": status}
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
        sim.stop()
        context.destroy(linger=0)
        log.close()
    result["exit"] = proc.returncode
    result["log"] = (work / "gateway.log").read_text()[-3000:]
    print(json.dumps(result))
    return 0


def match(samples: list[tuple[list[float], float]], records: list[dict[str, Any]],
          correction: float, to_unix: float, truth: dict[int, float],
          lsl_mono: float) -> dict[str, Any]:
    """Each inlet sample against the ZeroMQ record it is: the first aligned by its
    values (and the nearest ``time``), the rest in order. What the comparison found."""
    out: dict[str, Any] = {"samples": len(samples), "records": len(records)}
    if not samples or not records:
        return out
    values = [values_of(r) for r in records]
    first_values, first_stamp = samples[0]
    first_unix = first_stamp + correction + to_unix
    candidates = [i for i, v in enumerate(values) if v == first_values]
    if not candidates:
        out["error"] = "the first inlet sample matches no ZeroMQ record"
        return out
    at = min(candidates, key=lambda i: abs(records[i]["time"] - first_unix))
    pairs = list(zip(samples, records[at:], values[at:], strict=False))
    out["matched"] = len(pairs)
    out["values_differ"] = sum(1 for (v, _), _, w in pairs if v != w)
    errors = [stamp + correction + to_unix - record["time"] for (_, stamp), record, _ in pairs]
    out["time_error_max_s"] = max(abs(e) for e in errors)
    out["missing_inlet"] = missing([stamp for (_, stamp), _, _ in pairs])
    out["missing_records"] = missing([record["device_time"] for _, record, _ in pairs])
    seqs = [record["seq"] for _, record, _ in pairs]
    out["seq_first"], out["seq_last"] = seqs[0], seqs[-1]
    known = [(stamp, record) for (_, stamp), record, _ in pairs if record["timer"] in truth]
    if known:  # (gx2-sim's own instant of each sample, on the monotonic clock)
        out["truth"] = errors_of([stamp + correction - (truth[record["timer"]] + lsl_mono)
                                  for stamp, record in known])
        out["zmq_truth"] = errors_of([record["time"] - to_unix
                                      - (truth[record["timer"]] + lsl_mono)
                                      for _, record in known])
    return out


def missing(instants: list[float]) -> int:
    """Samples missing between ``instants``, by their steps against the usual one."""
    steps = [b - a for a, b in itertools.pairwise(instants)]
    if not steps:
        return 0
    period = statistics.median(steps)
    return sum(max(0, round(step / period) - 1) for step in steps)


def errors_of(errors: list[float]) -> dict[str, float]:
    """Errors against the truth: their median (the bias: the radio's delay against
    latency_ms) and the spread about it, p99 and max, in ms."""
    middle = statistics.median(errors)
    spread = sorted(abs(e - middle) for e in errors)
    return {"n": len(spread), "bias_ms": middle * 1e3,
            "p99_ms": spread[min(len(spread) - 1, math.ceil(0.99 * len(spread)) - 1)] * 1e3,
            "max_ms": spread[-1] * 1e3}


if __name__ == "__main__":
    sys.exit(main())
