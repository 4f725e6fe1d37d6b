#!/usr/bin/env python3
"""Sample time, measured (issue 12): one command, one table. Run by hand, not in CI:

    python bench/timesync.py            # about 80 s
    python bench/timesync.py --runs 6   # six in a row, then a line for each

gx2-sim in this process, three nodes streaming 0xC2 at 86.5 Hz (about 90% of the
115200-baud line) with crystals 40, -35 and 10 ppm off, radio delays of 3 ms plus an
exponential part (mean 0.5 ms), and the base station's output stalled for 50 ms once a
second on average; node 78's timer wraps 13 s in, node 77 reboots half way. The
installed gx2-gateway publishes; a subscriber here keeps every record. The simulator
knows when each sample was really taken; against that instant, per node and overall,
after a warm-up of each stream (its start, and after the reboot):

- ``time``: the gateway's sample time;
- ``host_time``: when the record's bytes were read;
- a fixed-gain filter on the mean offset (host - device), gain 0.01 a record: the kind
  the best existing GX2 driver uses, fed the same records in the same run.

Spread is |error - its median| (p50/p99/max); bias is the median error (the configured
``latency_ms`` matches the simulator's radio floor, 3 ms). Lock time: from a stream's
first record to the first record after which the error stays within 0.5 ms of the
settled median. Cost: aspp.clock.NodeClock.update over the recorded pairs, per record.
Last, each stream's share of packets that found the serial line free (read more than a
packet's time after the one before): a stream with almost none, its packets all
waiting behind another node's, never shows the host its floor (the run that fails the
bars is one where node 77 comes back from its reboot so).

    python bench/timesync.py --model 6  # six seeds, about 15 s

runs the simulator's line model alone in simulated time (no pty, no gateway, no
reboot; bench/linemodels.py, which bench/sweep.py runs over many draws): each packet
reaches the host exactly when its last byte leaves the base station, and goes through
the gateway's clock path (TimerUnwrapper, NodeClock). What is left is the geometry: the nodes power
up together, so their samples coincide and a node's packets queue behind another's for
tens of seconds while their crystals drift apart (the last column: each node's share
of packets that began on the line the moment the one before ended). Beside it, a
reference given each node's true drift (the line through the lowest point of the last
minute at that slope): the gap between the two is the drift estimate's.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections import deque
from dataclasses import dataclass
from itertools import pairwise
from pathlib import Path

import msgpack
import yaml
import zmq
from benchutil import free_port, gateway_command, unix_minus_monotonic
from linemodels import BYTE_TIME, feed, gx2sim_packets, update_cost

from aspp.clock import WINDOW
from aspp.frame import REPLY_OVERHEAD
from aspp.records import BY_NAME
from aspp.timing import TIMER_MODULUS, TimerUnwrapper, byte_time
from gateway.sim.base_station import RADIO_LATENCY, LineFaults
from gateway.sim.node import NodeSettings
from gateway.sim.server import Simulator

NODES = [NodeSettings(76, divider=592, stream="accel_angrate", ppm=40.0),
         NodeSettings(77, divider=592, stream="accel_angrate", ppm=-35.0),
         NodeSettings(78, divider=592, stream="accel_angrate", ppm=10.0, timer_start=205.0)]
"""3 x 86.5 Hz of 40-byte packets: 10.4 of the line's 11.5 kB/s."""
STALLS = LineFaults(stall_rate=1.0, stall_ms=50.0)
REBOOTS = 77
PACKET_TIME = (BY_NAME["accel_angrate"].reply_size + REPLY_OVERHEAD) * byte_time(115200)
"""Seconds one of the nodes' packets takes on the line."""
READ_SLACK = 0.3e-3
"""How much later than back to back a read may come and still count as queued."""
WARM_UP = 5.0
"""Seconds of each stream left out of the spread and bias."""
GAIN = 0.01
LOCKED_WITHIN = 0.5e-3


@dataclass
class Sample:
    """One published record, and when it was really taken (UNIX seconds)."""

    node: int
    segment: int
    """0 before the node's reboot, 1 after."""
    device_time: float
    host_time: float
    time: float
    truth: float = 0.0


def collect(seconds: float) -> tuple[list[Sample], int]:
    """Run the simulator and the installed gateway; return every record and the number
    of stalls."""
    work = Path(tempfile.mkdtemp(prefix="gx2-timesync-"))
    sim = Simulator(NODES, link=work / "gx2", line=STALLS).start()
    publish = f"tcp://127.0.0.1:{free_port()}"
    (work / "nodes.yaml").write_text(yaml.safe_dump({
        "base_station": {"port": str(work / "gx2"), "latency_ms": RADIO_LATENCY * 1000},
        "publish": {"endpoint": publish},
        "control": {"endpoint": f"tcp://127.0.0.1:{free_port()}"},
        "nodes": [{"address": n.address} for n in NODES]}))
    proc = subprocess.Popen([gateway_command(), "--config", str(work / "nodes.yaml"),
                             "--log-level", "WARNING"], stdout=subprocess.DEVNULL)
    context = zmq.Context()
    sub = context.socket(zmq.SUB)
    sub.setsockopt(zmq.RCVHWM, 0)
    sub.setsockopt(zmq.SUBSCRIBE, b"gx2/")
    sub.connect(publish)
    samples: list[Sample] = []
    truths: list[dict[int, dict[int, float]]] = [{}, {}]
    timers: list[int] = []
    segment = {n.address: 0 for n in NODES}
    last_timer: dict[int, int] = {}
    try:
        start = time.monotonic()
        rebooted = False
        while (now := time.monotonic()) - start < seconds:
            if not rebooted and now - start > seconds / 2:
                # keep what the node sampled before its reboot: its timer starts again
                truths[0][REBOOTS] = sim.call(
                    lambda station, _: dict(station.nodes[REBOOTS].sampled))
                sim.call(lambda station, _: station.nodes[REBOOTS].sampled.clear())
                sim.reboot(REBOOTS)
                rebooted = True
            if not sub.poll(100):
                continue
            topic, payload = sub.recv_multipart()
            record = msgpack.unpackb(payload)
            if "time" not in record or not topic.endswith(b"/accel_angrate"):
                continue
            node = record["node"]
            if record["timer"] < last_timer.get(node, 0) - TIMER_MODULUS // 2:
                pass  # its timer wrapped
            elif record["timer"] < last_timer.get(node, 0):  # its timer started again
                segment[node] += 1
            last_timer[node] = record["timer"]
            samples.append(Sample(node, segment[node], record["device_time"],
                                  record["host_time"], record["time"]))
            timers.append(record["timer"])
        for n in NODES:
            truths[1][n.address] = sim.call(
                lambda station, _, a=n.address: dict(station.nodes[a].sampled))
            truths[0].setdefault(n.address, truths[1][n.address])  # (no reboot)
        stalls = sim.station.stats.stalls
    finally:
        proc.terminate()
        proc.wait(10)
        sim.stop()
        context.destroy(linger=0)
        shutil.rmtree(work, ignore_errors=True)
    shift = unix_minus_monotonic()
    kept = []
    for sample, timer in zip(samples, timers, strict=True):
        truth = truths[sample.segment].get(sample.node, {})
        if timer in truth:
            sample.truth = truth[timer] + shift
            kept.append(sample)
    missed = len(samples) - len(kept)
    if missed:
        print(f"({missed} records without a true instant, left out)", file=sys.stderr)
    return kept, stalls


def mean_offset_filter(samples: list[Sample]) -> list[float]:
    """A fixed gain on host - device, restarted with the stream (one node's samples)."""
    out, offset, last = [], None, None
    for s in samples:
        if offset is None or (last is not None and s.device_time < last):
            offset = s.host_time - s.device_time
        offset += GAIN * (s.host_time - s.device_time - offset)
        out.append(s.device_time + offset)
        last = s.device_time
    return out


def spread(errors: list[float]) -> tuple[float, float, float, float]:
    """(p50, p99, max) of |error - median|, and the median, in ms."""
    middle = statistics.median(errors)
    d = sorted(abs(e - middle) for e in errors)
    return (d[len(d) // 2] * 1e3, d[int(0.99 * (len(d) - 1))] * 1e3, d[-1] * 1e3,
            middle * 1e3)


def lock_time(samples: list[Sample], errors: list[float]) -> float:
    """Device seconds from the first record until the error stays near its median."""
    first = samples[0].device_time
    settled = statistics.median(e for s, e in zip(samples, errors, strict=True)
                                if s.device_time - first > WARM_UP)
    last_out = first
    for s, e in zip(samples, errors, strict=True):
        if abs(e - settled) > LOCKED_WITHIN:
            last_out = s.device_time
    later = [s.device_time for s in samples if s.device_time > last_out]
    return (later[0] if later else last_out) - first


def cost_per_record(samples: list[Sample], rounds: int = 5) -> float:
    """Microseconds per NodeClock.update over the recorded (device, host) pairs."""
    streams = {}
    for s in samples:
        streams.setdefault((s.node, s.segment), []).append((s.device_time, s.host_time))
    return update_cost(streams, rounds)


class TrueDriftFloor:
    """The reference for the model: the line at the node's true drift, through the
    lowest point of the last WINDOW seconds (a sliding minimum). Only the drift is
    given; what is left of its error is what the floor itself leaves."""

    def __init__(self, ppm: float) -> None:
        self.drift = -ppm * 1e-6 / (1 + ppm * 1e-6)  # host - device against device
        self.lows: deque[tuple[float, float]] = deque()

    def update(self, device: float, host: float) -> float:
        level = host - device - self.drift * device
        while self.lows and self.lows[-1][1] >= level:
            self.lows.pop()
        self.lows.append((device, level))
        while self.lows[0][0] < device - WINDOW:
            self.lows.popleft()
        return device + self.lows[0][1] + self.drift * device


@dataclass
class ModelRun:
    """One seed of the model: each node's errors of ``time`` and of the reference
    (after WARM_UP), and its share of packets that queued (began on the line the moment
    the one before it ended)."""

    errors: dict[int, list[float]]
    true_drift: dict[int, list[float]]
    queued: dict[int, float]


def model_run(seed: int, seconds: float) -> ModelRun:
    """The simulator's line model run in simulated time (bench/linemodels.py), every
    packet through the gateway's clock path, and the reference fed the same pairs."""
    line = gx2sim_packets(seed, seconds, NODES, STALLS)
    streams = feed(line)
    references = {n.address: TrueDriftFloor(n.ppm or 0.0) for n in NODES}
    unwrappers = {n.address: TimerUnwrapper() for n in NODES}
    run = ModelRun({a: [e for _, e in streams.errors.get((a, 0), [])] for a in references},
                   {a: [] for a in references},
                   {a: streams.queued.get((a, 0), 0.0) for a in references})
    first = line.packets[0].truth
    for packet in line.packets:
        if packet.ticks is None:
            continue
        arrival = packet.read - packet.size * BYTE_TIME
        device = unwrappers[packet.node].update(packet.ticks, arrival)
        reference = references[packet.node].update(device, arrival)
        if packet.truth - first >= WARM_UP:
            run.true_drift[packet.node].append(reference - packet.truth)
    return run


def model(seeds: int, seconds: float) -> int:
    print(f"\nthe simulator's line model alone, {seconds:.0f} s of simulated time a seed")
    print("| seed | time, all: spread p50 / p99 / max (ms) | each node's bias (ms) "
          "| with the true drift: p99 / max (ms) | each node's packets queued |")
    print("|---|---|---|---|---|")
    for seed in range(1, seeds + 1):
        run = model_run(seed, seconds)
        p50, p99, worst, _ = spread([e for node in run.errors.values() for e in node])
        _, true_p99, true_worst, _ = spread([e for n in run.true_drift.values() for e in n])
        biases = ", ".join(f"{a} {statistics.median(e) * 1e3:+.3f}"
                           for a, e in run.errors.items())
        shares = ", ".join(f"{a} {share:.0%}" for a, share in run.queued.items())
        print(f"| {seed} | {p50:.3f} / {p99:.3f} / {worst:.3f} | {biases} "
              f"| {true_p99:.3f} / {true_worst:.3f} | {shares} |")
    return 0


BARS = (0.4, 1.0)
"""Issue 21's bars for ``time`` at a busy line: p99 spread and worst spread (ms)."""


def held(p99: float, worst: float) -> bool:
    return p99 <= BARS[0] and worst <= BARS[1]


def line_free(samples: list[Sample]) -> dict[tuple[int, int], float]:
    """Each stream's share of packets read more than a packet's time after the one
    before (of any node): they found the line idle. The rest began as another ended and
    may have waited behind it; a stream with none free never shows the host its floor."""
    free: dict[tuple[int, int], list[bool]] = {}
    ordered = sorted(samples, key=lambda s: s.host_time)
    for before, sample in pairwise(ordered):
        gap = sample.host_time - before.host_time
        free.setdefault((sample.node, sample.segment), []).append(
            gap > PACKET_TIME + READ_SLACK)
    return {key: sum(flags) / len(flags) for key, flags in free.items()}


def measure(seconds: float) -> tuple[float, float]:
    """One live run: its table printed; returns ``time``'s pooled p99 and worst (ms)."""
    samples, stalls = collect(seconds)
    groups: dict[tuple[int, int], list[Sample]] = {}
    for s in samples:
        groups.setdefault((s.node, s.segment), []).append(s)
    errors: dict[str, dict[tuple[int, int], list[float]]] = {
        "time": {k: [s.time - s.truth for s in g] for k, g in groups.items()},
        "host_time": {k: [s.host_time - s.truth for s in g] for k, g in groups.items()},
        f"mean-offset filter (gain {GAIN})": {
            k: [t - s.truth for t, s in zip(mean_offset_filter(g), g, strict=True)]
            for k, g in groups.items()}}

    def settled(kind: str, key: tuple[int, int]) -> list[float]:
        first = groups[key][0].device_time
        return [e for s, e in zip(groups[key], errors[kind][key], strict=True)
                if s.device_time - first > WARM_UP]

    print(f"\n{platform.node()}: {os.cpu_count()} cores, Python "
          f"{platform.python_version()}, {time.strftime('%Y-%m-%d %H:%M')}; "
          f"{len(samples):,} records in {seconds:.0f} s, {stalls} stalls of "
          f"{STALLS.stall_ms:.0f} ms")
    print("| source | node | spread p50 / p99 / max (ms) | bias (ms) | lock (s) |")
    print("|---|---|---|---|---|")
    p99: dict[str, float] = {}
    worst_time = 0.0
    medians: dict[int, float] = {}
    for kind in errors:
        pooled: list[float] = []
        for key in sorted(groups):
            values = settled(kind, key)
            pooled += values
            p50, p99_, worst, bias = spread(values)
            name = f"{key[0]}" + (" after reboot" if key[1] else "")
            lock = lock_time(groups[key], errors[kind][key])
            print(f"| {kind} | {name} | {p50:.3f} / {p99_:.3f} / {worst:.3f} | {bias:+.3f} "
                  f"| {lock:.2f} |")
            if kind == "time" and key[1] == 0:
                medians[key[0]] = bias
        p50, p99[kind], worst, bias = spread(pooled)
        if kind == "time":
            worst_time = worst
        print(f"| {kind} | all | {p50:.3f} / {p99[kind]:.3f} / {worst:.3f} | {bias:+.3f} "
              f"| |")
    shares = ", ".join(f"{node}{' after reboot' if segment else ''} {share:.0%}"
                       for (node, segment), share in sorted(line_free(samples).items()))
    print(f"\npackets that found the line free: {shares}")
    agree = max(medians.values()) - min(medians.values())
    kinds = list(errors)
    print(f"\nnodes agree within {agree * 1e3:.1f} us (spread of the nodes' biases); "
          f"p99 spread, host_time / time: {p99[kinds[1]] / p99[kinds[0]]:.0f}x, "
          f"mean-offset filter / time: {p99[kinds[2]] / p99[kinds[0]]:.0f}x; "
          f"estimator cost {cost_per_record(samples):.2f} us/record "
          f"(NodeClock.update, best of 5)")
    return p99["time"], worst_time


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=80.0)
    parser.add_argument("--runs", type=int, default=1,
                        help="live runs one after the other, then a line for each")
    parser.add_argument("--model", type=int, metavar="SEEDS",
                        help="the simulator's line model alone, for this many seeds")
    args = parser.parse_args()
    if args.model:
        return model(args.model, args.seconds)
    runs = [measure(args.seconds) for _ in range(args.runs)]
    if args.runs > 1:
        print(f"\n`time` over {args.runs} runs (bars: p99 <= {BARS[0]} ms, worst <= "
              f"{BARS[1]} ms)")
        print("| run | p99 spread (ms) | worst (ms) | bars held |")
        print("|---|---|---|---|")
        for number, (p99, worst) in enumerate(runs, 1):
            print(f"| {number} | {p99:.3f} | {worst:.3f} | "
                  f"{'yes' if held(p99, worst) else 'no'} |")
        print(f"\nthe bars held in {sum(held(*run) for run in runs)} of {args.runs} runs")
    return 0


if __name__ == "__main__":
    sys.exit(main())
