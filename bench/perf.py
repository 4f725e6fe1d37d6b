#!/usr/bin/env python3
"""Performance, measured: one command, one table (issue 6). Run by hand, not in CI:

    python bench/perf.py            # about 4 minutes on a 2-core machine

1. decoder: packets/s on one core over the mixed stream of decoder_throughput.py,
   next to a naive decoder in the shape of typical drivers, in the same run;
2. pipeline: records/s through everything after the serial read (the daemon's own
   reader: decoder, record, payload, msgpack, PUB) to a SUB in another process;
3. latency: from the simulator writing a packet's last byte into the pty to a
   subscriber holding its message, through the installed gx2-gateway: at a saturated
   115200-baud line (3 nodes of 0xC2 at 96 Hz) and in an unpaced burst;
4. cost at the saturated line: gateway CPU (% of one core) and RSS over 60 s;
5. scale: the same cost with 100 configured nodes (3 streaming) and with 10 subscribers;
and beside 3 and 4 the floor: bench/relay.py, which only reads and publishes, on the
same line in the same run.
"""

from __future__ import annotations

import argparse
import asyncio
import multiprocessing
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import msgpack
import yaml
import zmq
from benchutil import free_port, rss_kib, tap_writes
from decoder_throughput import mixed_stream

from aspp import Decoder, Reply, decode
from gateway.sim.node import NodeSettings
from gateway.sim.server import Simulator

try:
    from gateway.common.topics import STATUS_TOPIC
except ImportError:  # a tree from before gateway.common (bench/ab.py measures old ones)
    from gateway.publisher import STATUS_TOPIC  # type: ignore[no-redef]

TICKS = os.sysconf("SC_CLK_TCK")
Row = tuple[str, str, str]
"""(what, figure, target)"""


# --- 1. decoder ---------------------------------------------------------------------------

class TypicalDriver:
    """The naive baseline, in the shape of typical serial drivers (the public Python
    parsers for MicroStrain's later GX models look like this): find 0xAA, read the fixed
    header and its length, add up the bytes in a loop to check the sum, cut the packet
    off the front of the buffer; on a bad sum step one byte. No look-ahead: an ACK glued
    to a SOP costs it one resync step."""

    def __init__(self) -> None:
        self.buffer = b""

    def feed(self, chunk: bytes) -> list[bytes]:
        buffer = self.buffer + chunk
        packets = []
        while True:
            i = buffer.find(b"\xaa")
            if i < 0:
                buffer = b""
                break
            if len(buffer) - i < 7:
                buffer = buffer[i:]
                break
            size = 7 + buffer[i + 5] - 1 + 4
            if len(buffer) - i < size:
                buffer = buffer[i:]
                break
            packet = buffer[i:i + size]
            total = 0
            for byte in packet[1:-4]:
                total += byte
            if packet[1] == 0x07 and total & 0xFFFF == (packet[-2] << 8) | packet[-1]:
                packets.append(packet)
                buffer = buffer[i + size:]
            else:
                buffer = buffer[i + 1:]
        self.buffer = buffer
        return packets


class TunedNaive:
    """The same naive shape with the easy wins taken (a bytearray cut once per read, the
    sum by sum() in C): the strongest baseline this shape allows, shown for honesty."""

    def __init__(self) -> None:
        self.buffer = bytearray()

    def feed(self, chunk: bytes) -> list[bytes]:
        data = self.buffer
        data += chunk
        packets, i = [], 0
        while True:
            i = data.find(b"\xaa", i)
            if i < 0 or i + 7 > len(data):
                break
            if data[i + 1] != 0x07:
                i += 1
                continue
            size = 7 + data[i + 5] - 1 + 4
            if i + size > len(data):
                break
            body_end = i + size - 4
            if sum(data[i + 1:body_end]) & 0xFFFF == (data[body_end + 2] << 8) | \
                    data[body_end + 3]:
                packets.append(bytes(data[i + 6:body_end]))
                i += size
            else:
                i += 1
        del data[:i if i >= 0 else len(data)]
        return packets


def seconds_for(run: Callable[[], None]) -> float:
    start = time.perf_counter()
    run()
    return time.perf_counter() - start


def decoder_rows(packets: int = 200_000) -> list[Row]:
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    stream = mixed_stream(packets)
    chunks = [stream[o:o + 4096] for o in range(0, len(stream), 4096)]

    def ours() -> None:  # (each side only feeds; the lists are what a caller iterates)
        decoder = Decoder()
        for chunk in chunks:
            decoder.feed(chunk)
        assert decoder.stats.replies == packets, f"decoded {decoder.stats.replies}"

    def naive(driver_class: type) -> Callable[[], None]:
        def run() -> None:
            driver, found = driver_class(), 0
            for chunk in chunks:
                found += len(driver.feed(chunk))
            assert found >= packets * 0.99, f"{driver_class.__name__} found {found}"
        return run

    # interleaved rounds: the ratio is the median of each round's own ratio (both sides
    # of a round share the machine's mood); the rate is the best round's
    rounds = [(seconds_for(ours), seconds_for(naive(TypicalDriver)),
               seconds_for(naive(TunedNaive))) for _ in range(7)]
    os.sched_setaffinity(0, set(range(os.cpu_count() or 1)))
    return [("decoder, packets/s on one core (mixed stream, 1% garbage)",
             f"{packets / min(r[0] for r in rounds):,.0f}", ">= 200,000"),
            ("naive baseline: a typical driver (find 0xAA, fixed length, sum in a loop)",
             f"{packets / min(r[1] for r in rounds):,.0f}", ""),
            ("decoder / naive baseline (median of 7 interleaved rounds)",
             f"{statistics.median(r[1] / r[0] for r in rounds):.2f}x", ">= 2x"),
            ("(the naive shape tuned: bytearray, sum() in C) decoder / tuned naive",
             f"{statistics.median(r[2] / r[0] for r in rounds):.2f}x", "")]


# --- 2. pipeline --------------------------------------------------------------------------

def count_messages(endpoint: str, expected: int, ready, result) -> None:
    """In a process of its own: count the nodes' records until ``expected`` of them
    came (or 10 s of silence). ``ready`` is set once a status message has arrived: from
    then on the subscription is in place and no record can be missed."""
    context = zmq.Context()
    sub = context.socket(zmq.SUB)
    sub.setsockopt(zmq.RCVHWM, 0)
    for prefix in (b"gx2/76/", b"gx2/77/", b"gx2/95/", STATUS_TOPIC):
        sub.setsockopt(zmq.SUBSCRIBE, prefix)
    sub.connect(endpoint)
    got = 0
    while got < expected and sub.poll(10_000):
        if sub.recv_multipart()[0] == STATUS_TOPIC:
            ready.set()  # (the probes before the records, which are not counted)
        else:
            got += 1
    result.put((got, time.perf_counter()))
    context.destroy(linger=0)


def until_subscribed(probe, ready, timeout: float = 10.0) -> None:
    """Publish ``probe()`` (a status message) until the counter has one: ZeroMQ's slow
    joiner waited for by the event itself, not by a guess of its time."""
    deadline = time.monotonic() + timeout
    while not ready.wait(0.01):
        if time.monotonic() > deadline:
            raise RuntimeError("the counting subscriber never received a probe")
        probe()


def pipeline_round(chunks: list[bytes], packets: int) -> tuple[float, float]:
    """One run: (records per CPU-second of this process, records/s to the SUB)."""
    from gateway.daemon.app import Gateway
    from gateway.daemon.config import GatewayConfig
    endpoint = f"tcp://127.0.0.1:{free_port()}"
    config = GatewayConfig.model_validate({
        "base_station": {"port": "loop://"},
        "publish": {"endpoint": endpoint, "high_water_mark": 10_000_000},
        "control": {"endpoint": f"tcp://127.0.0.1:{free_port()}"},
        "nodes": [{"address": a} for a in (76, 77, 95)]})
    ready, result = multiprocessing.Event(), multiprocessing.Queue()
    counter = multiprocessing.Process(target=count_messages,
                                      args=(endpoint, packets, ready, result))

    async def run() -> tuple[float, float]:
        gateway = Gateway(config)
        counter.start()
        until_subscribed(lambda: getattr(gateway, "outputs", gateway.publisher).status({}), ready)
        start, cpu = time.perf_counter(), time.process_time()
        for chunk in chunks:
            gateway.stations[0].reader.on_data(chunk, time.time(), time.monotonic())
        gateway.publisher.close(5.0)  # (what is queued may take up to 5 s to go out)
        gateway._context.destroy(linger=5000)  # returns once every message is out
        return start, time.process_time() - cpu
    start, cpu = asyncio.run(run())
    got, end = result.get(timeout=60)
    counter.join(10)
    assert got == packets, f"the subscriber got {got} of {packets}"
    return packets / cpu, packets / (end - start)


def pipeline_rows(packets: int = 150_000, rounds: int = 3) -> list[Row]:
    """The daemon's own read callback fed the mixed stream as fast as it takes it, a SUB
    in another process counting every record. Per core: records per CPU-second of this
    process (ZeroMQ's I/O thread included), which a busy machine does not change; the
    wall-clock rate to the subscriber is shown beside it. Best of ``rounds``."""
    stream = mixed_stream(packets)
    chunks = [stream[o:o + 4096] for o in range(0, len(stream), 4096)]
    per_cpu, per_wall = zip(*(pipeline_round(chunks, packets) for _ in range(rounds)),
                            strict=True)
    return [("pipeline, records/s per core (decode, payload, msgpack, PUB; per CPU-second)",
             f"{max(per_cpu):,.0f}", ">= 50,000"),
            ("pipeline, records/s received by a SUB in another process (wall clock)",
             f"{max(per_wall):,.0f}", "")]


# --- 3-5. the installed gateway on a simulator ------------------------------------------

Key = tuple[int, int]
"""A 0xC2 record by (node, timer): unique within a run."""


@dataclass
class Written:
    """When the simulator wrote each 0xC2 packet's last byte (time.monotonic())."""

    at: dict[Key, float] = field(default_factory=dict)

    def tap(self, sim: Simulator) -> None:
        def seen(reply: Reply, now: float) -> None:
            if reply.command == 0xC2:
                self.at[(reply.node, decode(reply.payload)["timer"])] = now
        tap_writes(sim, seen)

    def latencies(self, received: dict[Key, float]) -> list[float]:
        """Seconds from each record's write to its receipt (``received``: subscribe's)."""
        written = dict(self.at)
        return [at - written[key] for key, at in received.items() if key in written]


def subscribe(endpoints: list[str], subscribers: int, settle: float, seconds: float,
              measuring, result) -> None:
    """In a process of its own, so that the simulator's thread never holds its GIL:
    ``subscribers`` SUB sockets, each connected to every one of ``endpoints``; after
    ``settle`` s, count every message for ``seconds`` and time each 0xC2 record the first
    one gets (time.monotonic(), one clock for every process on the machine)."""
    context = zmq.Context()
    subs = []
    for _ in range(subscribers):
        sub = context.socket(zmq.SUB)
        sub.setsockopt(zmq.RCVHWM, 0)
        sub.setsockopt(zmq.SUBSCRIBE, b"gx2/")
        for endpoint in endpoints:
            sub.connect(endpoint)
        subs.append(sub)
    poller = zmq.Poller()
    for sub in subs:
        poller.register(sub, zmq.POLLIN)
    got, received, counting = 0, {}, False
    start = time.monotonic()
    deadline = start + settle
    while (left := deadline - time.monotonic()) > 0 or not counting:
        if left <= 0:
            counting, deadline = True, time.monotonic() + seconds
            measuring.set()
            continue
        for sub, _ in poller.poll(max(1, int(left * 1000))):
            while True:
                try:
                    topic, payload = sub.recv_multipart(zmq.NOBLOCK)
                except zmq.Again:
                    break
                now = time.monotonic()
                if not counting:
                    continue
                got += 1
                if sub is subs[0] and topic.endswith(b"/accel_angrate"):
                    message = msgpack.unpackb(payload)
                    received[(message["node"], message["timer"])] = now
    result.put((got, received))
    context.destroy(linger=0)


def relay_command(port: Path, endpoint: str) -> list[str]:
    """The floor, bench/relay.py, reading ``port`` and publishing on ``endpoint``."""
    return [sys.executable, str(Path(__file__).with_name("relay.py")), str(port), endpoint]


@dataclass
class Measured:
    records_per_s: float
    latencies: list[float]
    cpu: float
    """Of one core."""
    rss_mib: tuple[float, float]


class Bench:
    """gx2-sim in this process; the installed gx2-gateway, or the floor relay, as a
    subprocess; subscribers in another."""

    def __init__(self, nodes: list[NodeSettings], *, baudrate: int = 115200,
                 configured: list[int] | None = None, relay: bool = False) -> None:
        self.work = Path(tempfile.mkdtemp(prefix="gx2-perf-"))
        self.sim = Simulator(nodes, link=self.work / "gx2", baudrate=baudrate).start()
        self.written = Written()
        self.written.tap(self.sim)
        self.publish = f"tcp://127.0.0.1:{free_port()}"
        streaming = {n.address for n in nodes if n.stream}
        (self.work / "nodes.yaml").write_text(yaml.safe_dump({
            "base_station": {"port": str(self.work / "gx2"), "baudrate": baudrate},
            "publish": {"endpoint": self.publish},
            "control": {"endpoint": f"tcp://127.0.0.1:{free_port()}"},
            "nodes": [{"address": a, **({"stream": "accel_angrate"} if a in streaming else {})}
                      for a in configured or sorted(n.address for n in nodes)]}))
        if relay:
            command = relay_command(self.work / "gx2", self.publish)
        else:
            script = shutil.which("gx2-gateway", path=str(Path(sys.executable).parent))
            command = [script or "gx2-gateway", "--config", str(self.work / "nodes.yaml"),
                       "--log-level", "WARNING"]
        self.proc = subprocess.Popen(command, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL)

    def measure(self, seconds: float, subscribers: int = 1, settle: float = 8.0) -> Measured:
        """Settle (started, armed, subscribers joined), then measure for ``seconds``."""
        measuring, result = multiprocessing.Event(), multiprocessing.Queue()
        process = multiprocessing.Process(target=subscribe, args=(
            [self.publish], subscribers, settle, seconds, measuring, result))
        process.start()
        if not measuring.wait(settle + 30):
            raise RuntimeError("the subscribers never started measuring")
        self.written.at.clear()
        cpu0, rss0, t0 = self.cpu_seconds(), self.rss_mib(), time.monotonic()
        got, received = result.get(timeout=seconds + 60)
        elapsed = time.monotonic() - t0
        cpu, rss1 = (self.cpu_seconds() - cpu0) / elapsed, self.rss_mib()
        process.join(10)
        latencies = self.written.latencies(received)
        return Measured(got / seconds / subscribers, latencies, cpu, (rss0, rss1))

    def cpu_seconds(self) -> float:
        fields = Path(f"/proc/{self.proc.pid}/stat").read_text().rpartition(")")[2].split()
        return (int(fields[11]) + int(fields[12])) / TICKS

    def rss_mib(self) -> float:
        return rss_kib(self.proc.pid) / 1024

    def close(self) -> None:
        self.proc.terminate()
        self.proc.wait(10)
        self.sim.stop()
        shutil.rmtree(self.work, ignore_errors=True)


def measure(nodes: list[NodeSettings], seconds: float, *, subscribers: int = 1,
            baudrate: int = 115200, configured: list[int] | None = None,
            relay: bool = False) -> Measured:
    bench = Bench(nodes, baudrate=baudrate, configured=configured, relay=relay)
    try:
        return bench.measure(seconds, subscribers)
    finally:
        bench.close()


def quantile(values: list[float], q: float) -> float:
    """The ``q`` quantile of ``values`` (sorted), nearest rank."""
    return values[min(len(values) - 1, int(q * len(values)))]


def percentiles(values: list[float]) -> str:
    values = sorted(values)
    if not values:
        return "no samples"

    def at(q: float) -> float:
        return quantile(values, q) * 1000
    return (f"p50 {at(0.5):.2f} / p99 {at(0.99):.2f} / max {values[-1] * 1000:.2f} ms "
            f"({len(values):,} records)")


SATURATING = [NodeSettings(a, divider=533, stream="accel_angrate") for a in (76, 77, 78)]
"""3 nodes streaming 0xC2 at 96 Hz: 3 x 96 x 40 bytes fill a 115200-baud line."""
BURST = [NodeSettings(a, divider=170, stream="accel_angrate") for a in range(76, 86)]
"""10 nodes at 301 Hz on a 4 Mbaud line: the simulator writes as fast as it can."""


def latency_and_cost_rows(seconds: float) -> list[Row]:
    gateway = measure(SATURATING, seconds)
    floor = measure(SATURATING, min(seconds, 30.0), relay=True)
    burst = measure(BURST, 15.0, baudrate=4_000_000)
    rss0, rss1 = gateway.rss_mib
    return [
        ("latency, saturated 115200 line (3 x 96 Hz 0xC2), write -> SUB",
         percentiles(gateway.latencies), "p99 <= 2 ms"),
        ("(floor: the relay, which only cuts and publishes, on the same line)",
         percentiles(floor.latencies), ""),
        (f"gateway CPU at the saturated line ({gateway.records_per_s:.0f} records/s)",
         f"{gateway.cpu:.1%} of one core", "<= 2%"),
        ("(floor: the relay's CPU on the same line)", f"{floor.cpu:.1%} of one core", ""),
        (f"gateway RSS over {seconds:.0f} s", f"{rss0:.1f} -> {rss1:.1f} MiB "
         f"({(rss1 - rss0) * 1024:+.0f} KiB)", "growth < 1 MB"),
        (f"latency, unpaced burst (10 x 301 Hz, {burst.records_per_s:.0f} records/s)",
         percentiles(burst.latencies), ""),
    ]


def scale_rows(seconds: float) -> list[Row]:
    rows: list[Row] = []
    cases = [("100 configured nodes, 3 streaming",
              measure(SATURATING, seconds, configured=list(range(76, 176)))),
             ("3 nodes, 10 subscribers", measure(SATURATING, seconds, subscribers=10))]
    for name, result in cases:
        rows.append((f"scale: {name}", f"CPU {result.cpu:.1%}, RSS {result.rss_mib[0]:.1f}"
                     f" -> {result.rss_mib[1]:.1f} MiB", ""))
    return rows


def cpu_steal(since: tuple[int, int] | None = None) -> float | tuple[int, int]:
    """(steal, total) jiffies of all CPUs from /proc/stat; given an earlier reading,
    the share stolen since (a virtual machine's neighbours taking its cores)."""
    fields = [int(x) for x in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    now = (fields[7] if len(fields) > 7 else 0, sum(fields[:8]))
    if since is None:
        return now
    return (now[0] - since[0]) / max(1, now[1] - since[1])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0,
                        help="how long the saturated-line cost is measured")
    args = parser.parse_args()
    steal0 = cpu_steal()
    rows = decoder_rows() + pipeline_rows() + latency_and_cost_rows(args.seconds) + \
        scale_rows(min(args.seconds, 20.0))
    print(f"\n{platform.node()}: {platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} cores, Python {platform.python_version()}, "
          f"{time.strftime('%Y-%m-%d')}; CPU time stolen by the hypervisor during the "
          f"run: {cpu_steal(steal0):.0%}")
    print("| measure | figure | target |\n|---|---|---|")
    for what, figure, target in rows:
        print(f"| {what} | {figure} | {target} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
