#!/usr/bin/env python3
"""Several saturated base stations in one gateway against as many bare relays (issue 22).

    .venv/bin/python bench/stations.py [--stations 1 2 4] [--rounds 2] [--seconds 20]
    .venv/bin/python bench/stations.py --stations 1 --live --viewer   # the live view too

For each number of stations N and each round, two sides on fresh lines, one after the
other (the order alternating from one measurement to the next, and the N interleaved
within a round, so that a neighbour slowing the machine for a while slows both sides):

A. N relays (bench/relay.py, the floor: read, cut, publish), one process per line;
B. one gx2-gateway (started as bench/ab.py starts it) with N stations in
   ``base_stations:``, recording to a temporary directory and serving metrics, scraped
   once a second by this process (as bench/ab.py does, ten times Prometheus' default);
   with ``--live``, serving the live view too, and with ``--viewer``, to a Foxglove
   viewer (tests/helpers/viewer.py, a process of its own) subscribed to every channel.

Each line is a gx2-sim Simulator in this process, its own pty, with perf.py's saturating
load: 3 nodes of 0xC2 at 96 Hz (288 records/s fill 115200 baud), node addresses numbered
on across the stations. After a settling period (started, armed, subscriber joined), for
``--seconds``: CPU time of the measured processes (every thread, from the kernel's
nanosecond count; A's relays summed) as % of one core, and per station (/N); the
gateway's RSS at the start of the window; and latency, from the simulator writing a
packet into its pty (perf.py's tap, the instant the write returned) to a subscriber
holding its message. The subscriber is perf.py's: a process of its own (never this
process's GIL, which the simulators hold), one SUB socket connected to every publishing
endpoint (the gateway's one, or the N relays'), so it receives the same records from A
and B and costs both the same. The figures are the median of the rounds (ratios: the
median of each round's own B/A); the latency percentiles are over every round's records.

What 2 cores mean for the figures. At N=4 the machine runs 4 simulator threads (this
process, whose CPU is printed beside the table as "bench"), the measured processes, the
subscriber and the metrics scrapes on 2 cores: the total can exceed one core, and the
measured processes then wait for a core at times. CPU time is what a process used, not
how long it waited, so the CPU figures hold; latency includes waiting for a core, so at
N=4 it is an upper bound on what a machine with a core to spare would show. The write
instants are taken in the simulator threads once each write returns; a thread that
waits for this process's GIL after its write stamps late, which shortens a latency by
that wait (how often: about the share of a core this process uses, shown as "bench").
The relays' side is N processes, the gateway's one: at N=4 the relays can use both
cores, the gateway's event loop one (its ZeroMQ and recorder threads another).

``--priority NICE`` (for example -10; lowering a nice value needs root) runs the
measuring side at that nice value: this process (the simulators and their write taps)
and the subscriber, while the measured processes (relays, gateway) run at 0. The
simulators then write, and the subscriber receives, as soon as they are due, so what
is left of the latency is the measured side's own, its waits for a core included;
the difference from a run without it is what the measuring side's waits added.
"""

from __future__ import annotations

import argparse
import dataclasses
import multiprocessing
import os
import platform
import shlex
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import yaml
from ab import gateway_command, scrape_every_second
from benchutil import REPO, cpu_ns, free_port, rss_kib
from perf import SATURATING, Written, cpu_steal, quantile, relay_command, subscribe

from gateway.sim.node import NodeSettings
from gateway.sim.server import Simulator

SIDES = {"A": "relays", "B": "gateway"}


def nice_zero() -> None:
    """In a measured process, before it runs: nice 0, whatever the bench's own is."""
    os.setpriority(os.PRIO_PROCESS, 0, 0)


def station_nodes(index: int) -> list[NodeSettings]:
    """perf.py's saturating line for the station at ``index`` (from 0), its addresses
    moved past the stations before it: a node address is one node across the gateway."""
    return [dataclasses.replace(node, address=node.address + index * len(SATURATING))
            for node in SATURATING]


@dataclass
class Run:
    """One side's measurement at N stations."""

    cpu: float
    """% of one core: the gateway, or every relay summed."""
    bench_cpu: float
    """% of one core used by this process (the simulators) meanwhile."""
    rss_mib: float
    """The gateway's, or every relay's summed, at the start of the window."""
    latencies: list[float]
    records_per_s: float
    """0xC2 records the subscriber got and whose write was seen, a second."""


class Lines:
    """N simulated base stations and what reads them: N relays (A) or one gateway (B)."""

    def __init__(self, stations: int, side: str, live: bool = False,
                 viewer: bool = False) -> None:
        self.live = f"127.0.0.1:{free_port()}" if live and side == "B" else None
        self.viewing = viewer and self.live is not None
        self.stations = stations
        self.work = Path(tempfile.mkdtemp(prefix=f"gx2-stations-{side}-"))
        self.written = Written()
        self.sims: list[Simulator] = []
        self.procs: list[subprocess.Popen[bytes]] = []
        self.scrapes: list[str] = []
        links = [self.work / f"gx2-{index}" for index in range(stations)]
        for index, link in enumerate(links):
            self.sims.append(Simulator(station_nodes(index), link=link).start())
            self.written.tap(self.sims[-1])
        if side == "A":
            self.endpoints = [f"tcp://127.0.0.1:{free_port()}" for _ in links]
            commands = [relay_command(link, endpoint)
                        for link, endpoint in zip(links, self.endpoints, strict=True)]
        else:
            self.endpoints = [f"tcp://127.0.0.1:{free_port()}"]
            commands = [gateway_command(REPO, self.gateway_config(links))]
        for index, command in enumerate(commands):
            with open(self.work / f"stderr-{index}", "wb") as stderr:
                self.procs.append(subprocess.Popen(command, stdout=subprocess.DEVNULL,
                                                   stderr=stderr, preexec_fn=nice_zero))

    def gateway_config(self, links: list[Path]) -> Path:
        metrics = f"127.0.0.1:{free_port()}"
        self.scrapes.append(f"http://{metrics}/metrics")
        config = {
            "base_stations": [
                {"name": f"s{index + 1}", "port": str(link),
                 "nodes": [{"address": node.address, "stream": "accel_angrate"}
                           for node in station_nodes(index)]}
                for index, link in enumerate(links)],
            "publish": {"endpoint": self.endpoints[0]},
            "control": {"endpoint": f"tcp://127.0.0.1:{free_port()}"},
            "record": {"directory": str(self.work / "recordings")},
            "metrics": {"endpoint": metrics}}
        if self.live is not None:
            config["live"] = {"endpoint": self.live}
        path = self.work / "gateway.yaml"
        path.write_text(yaml.safe_dump(config))
        return path

    def measure(self, seconds: float, settle: float) -> Run:
        """Settle (started, armed, the subscriber joined), then measure for ``seconds``."""
        measuring, result = multiprocessing.Event(), multiprocessing.Queue()
        subscriber = multiprocessing.Process(target=subscribe, args=(
            self.endpoints, 1, settle, seconds, measuring, result))
        viewer = (multiprocessing.Process(target=watch, args=(
            f"ws://{self.live}", 3 * self.stations + 1, settle + seconds + 5), daemon=True)
            if self.viewing else None)
        if viewer is not None:
            viewer.start()
        subscriber.start()
        if not measuring.wait(settle + 30):
            raise RuntimeError("the subscriber never started measuring")
        self.check_running()
        self.written.at.clear()
        pids = [proc.pid for proc in self.procs]
        rss = sum(rss_kib(pid) for pid in pids) / 1024
        cpu0, bench0, t0 = sum(cpu_ns(pid) for pid in pids), cpu_ns(os.getpid()), \
            time.monotonic()
        scraped = scrape_every_second(self.scrapes, t0 + seconds)
        time.sleep(max(0.0, t0 + seconds - time.monotonic()))
        elapsed = time.monotonic() - t0
        cpu1, bench1 = sum(cpu_ns(pid) for pid in pids), cpu_ns(os.getpid())
        if self.scrapes and scraped < seconds - 2:
            raise RuntimeError(f"only {scraped} scrapes of {self.scrapes} in {seconds:g} s")
        _, received = result.get(timeout=60)
        subscriber.join(10)
        if viewer is not None:
            if not viewer.is_alive():
                raise RuntimeError("the viewer ended early (see its error above)")
            viewer.terminate()
        latencies = self.written.latencies(received)
        if not latencies:
            raise RuntimeError(f"no record reached the subscriber from {self.endpoints}")
        return Run((cpu1 - cpu0) / 1e9 / elapsed * 100, (bench1 - bench0) / 1e9 / elapsed * 100,
                   rss, latencies, len(latencies) / seconds)

    def check_running(self) -> None:
        for index, proc in enumerate(self.procs):
            if proc.poll() is not None:
                error = (self.work / f"stderr-{index}").read_text(errors="replace")
                raise RuntimeError(f"{shlex.join(proc.args)} exited {proc.returncode}:\n"
                                   f"{error[-2000:]}")

    def close(self) -> None:
        for proc in self.procs:
            proc.terminate()
        for proc in self.procs:
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        for sim in self.sims:
            sim.stop()
        shutil.rmtree(self.work, ignore_errors=True)


def watch(url: str, channels: int, seconds: float) -> None:
    """A viewer of the live view, in a process of its own: subscribed to every channel
    once ``channels`` are advertised, reading everything for ``seconds``."""
    sys.path.insert(0, str(REPO))
    from tests.helpers.viewer import Viewer  # (the tests' independent Foxglove client)
    deadline = time.monotonic() + 30
    while True:  # (started beside the gateway: its live view may not listen yet)
        try:
            viewer = Viewer(url)
            break
        except ConnectionRefusedError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)
    viewer.until(lambda v: len(v.channels) >= channels, 30, f"{channels} channels")
    viewer.subscribe(*viewer.channels)
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        viewer.read(1.0)
        viewer.messages.clear()


def measure(stations: int, side: str, seconds: float, settle: float, live: bool = False,
            viewer: bool = False) -> Run:
    lines = Lines(stations, side, live, viewer)
    try:
        return lines.measure(seconds, settle)
    finally:
        lines.close()


Runs = dict[int, dict[str, list[Run]]]
"""Each N's runs, by side, in round order."""


def p99_ms(runs: list[Run]) -> float:
    return quantile(sorted(x for run in runs for x in run.latencies), 0.99) * 1000


def median_of(runs: list[Run], figure: str) -> float:
    return statistics.median(getattr(run, figure) for run in runs)


def table(runs: Runs) -> list[str]:
    """The summary: one row per N, with each target's figure."""
    one = min(runs)
    gateway_1, relay_1, rss_1 = (median_of(runs[one]["B"], "cpu") / one,
                                 median_of(runs[one]["A"], "cpu") / one,
                                 median_of(runs[one]["B"], "rss_mib"))
    rows = ["| stations | relays CPU | gateway CPU | gateway / relays | gateway CPU a "
            f"station, / {one} station | relays CPU a line, / {one} line | gateway RSS "
            "| RSS growth a station | latency p99 gateway | latency p99 relays "
            "| bench CPU (A / B) |",
            "|---|---|---|---|---|---|---|---|---|---|---|"]
    for n, sides in runs.items():
        relays, gateway = median_of(sides["A"], "cpu"), median_of(sides["B"], "cpu")
        ratio = statistics.median(b.cpu / a.cpu for a, b in zip(sides["A"], sides["B"],
                                                                  strict=True))
        rss = median_of(sides["B"], "rss_mib")
        growth = f"{(rss - rss_1) / (n - one):+.1f} MiB" if n != one else ""
        rows.append(
            f"| {n} | {relays:.1f}% | {gateway:.1f}% | {ratio:.2f}x "
            f"| {gateway / n / gateway_1:.2f} | {relays / n / relay_1:.2f} "
            f"| {rss:.1f} MiB | {growth} | {p99_ms(sides['B']):.2f} ms "
            f"| {p99_ms(sides['A']):.2f} ms | {median_of(sides['A'], 'bench_cpu'):.0f}% / "
            f"{median_of(sides['B'], 'bench_cpu'):.0f}% |")
    return rows


def rounds_table(runs: Runs) -> list[str]:
    """Every measurement, so that a round's outlier shows."""
    rows = ["| stations | side | round | CPU | bench CPU | RSS | records/s | "
            "latency p50 / p99 |", "|---|---|---|---|---|---|---|---|"]
    for n, sides in runs.items():
        for side, measured in sides.items():
            for index, run in enumerate(measured):
                values = sorted(run.latencies)
                rows.append(f"| {n} | {SIDES[side]} | {index + 1} | {run.cpu:.1f}% | "
                            f"{run.bench_cpu:.0f}% | {run.rss_mib:.1f} MiB | "
                            f"{run.records_per_s:.0f} | {quantile(values, 0.5) * 1000:.2f} / "
                            f"{quantile(values, 0.99) * 1000:.2f} ms |")
    return rows


def command_line() -> str:
    python = Path(sys.executable)
    if python.is_relative_to(REPO):
        python = python.relative_to(REPO)
    return shlex.join([str(python), *sys.argv])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stations", type=int, nargs="+", default=[1, 2, 4],
                        choices=range(1, 33), metavar="N",
                        help="numbers of stations measured (default: 1 2 4); the first "
                        "is the one the others are compared to")
    parser.add_argument("--rounds", type=int, default=2, choices=range(1, 101),
                        metavar="ROUNDS", help="interleaved rounds (default: 2)")
    parser.add_argument("--seconds", type=float, default=20.0,
                        help="each measurement's window after settling (default: 20)")
    parser.add_argument("--live", action="store_true",
                        help="the gateway serves the live view too (no viewer)")
    parser.add_argument("--viewer", action="store_true",
                        help="with --live: a Foxglove viewer subscribed to every channel")
    parser.add_argument("--settle", type=float, default=8.0,
                        help="seconds from start to the window (default: 8)")
    parser.add_argument("--priority", type=int, default=0, choices=range(-20, 20),
                        metavar="NICE", help="the simulators' and the subscriber's nice "
                        "value, the measured processes at 0 (default: 0; below 0 needs "
                        "root)")
    args = parser.parse_args()
    if args.seconds < 3 or args.settle < 1:
        parser.error("--seconds must be at least 3 and --settle at least 1")
    try:
        # Linux keeps a nice value per thread; set here, before any simulator thread
        # or subscriber process starts, every one of them inherits it.
        os.setpriority(os.PRIO_PROCESS, 0, args.priority)
    except PermissionError:
        parser.error(f"--priority {args.priority}: lowering a nice value needs root")
    loads, steal0 = os.getloadavg(), cpu_steal()
    runs: Runs = {n: {"A": [], "B": []} for n in args.stations}
    turn = 0
    for round_ in range(args.rounds):
        for n in args.stations:
            for side in ("A", "B") if turn % 2 == 0 else ("B", "A"):
                runs[n][side].append(measure(n, side, args.seconds, args.settle,
                                             args.live, args.viewer))
            turn += 1
            a, b = runs[n]["A"][-1], runs[n]["B"][-1]
            print(f"round {round_ + 1}, {n} station{'s' if n > 1 else ''}: relays "
                  f"{a.cpu:.1f}%, gateway {b.cpu:.1f}% ({b.cpu / a.cpu:.2f}x), bench "
                  f"{a.bench_cpu:.0f}% / {b.bench_cpu:.0f}%", flush=True)
    print(f"\n{platform.node()}: {platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} cores, Python {platform.python_version()}, "
          f"{time.strftime('%Y-%m-%d')}; load average at the start {loads[0]:.2f}; CPU time "
          f"stolen by the hypervisor during the run: {cpu_steal(steal0):.0%}")
    print(f"`{command_line()}`: {args.rounds} interleaved rounds of {args.seconds:g} s after "
          f"{args.settle:g} s settling; each station 3 nodes of 0xC2 at 96 Hz (115200 baud, "
          "saturated); gateway recording, metrics scraped every second"
          f"{', live view served' if args.live else ''}"
          f"{' to a viewer of every channel' if args.viewer else ''}"
          f"{f'; simulators and subscriber at nice {args.priority}' if args.priority else ''}"
          "; CPU in % of one "
          "core (relays summed), medians of the rounds; bench = this process (the "
          "simulators)\n")
    print("\n".join(table(runs)))
    print("\nEach measurement:\n")
    print("\n".join(rounds_table(runs)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
