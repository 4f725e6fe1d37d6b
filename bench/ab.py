#!/usr/bin/env python3
"""This checkout against an earlier commit, interleaved: A B A B ... in one run.

    .venv/bin/python bench/ab.py --base REV [--head REV] [--rounds 4] [--seconds 30]

The earlier commit (and ``--head``, if given; else this working tree) is checked out
into a temporary git worktree; each measurement runs
in a process of its own whose imports come from one tree or the other, in turn:

1. pipeline: records per CPU-second through the daemon's read path (decoder, record,
   payload, msgpack, PUB) fed perf.py's mixed stream, every record counted by a SUB in
   another process (as bench/perf.py measures it), each node's stream known to the
   gateway as it is once armed;
2. CPU at a saturated line: the gateways of both trees at the same time, each started
   as its console script would be on a gx2-sim of its own (this tree's) with 3 nodes of
   0xC2 at 96 Hz, their CPU time over ``--seconds`` (% of one core, from the kernel's
   per-thread nanoseconds). Running side by side, they share whatever the machine is
   doing: measured one after the other, rounds on this VM differed by 20% either way.
   With ``--record``, B runs with ``record:`` configured (a tree that records); with
   ``--metrics``, B serves metrics and is scraped once a second meanwhile, as a
   Prometheus server would (ten times as often as its default interval); with
   ``--live``, B serves the live view, with no viewer connected; with ``--lsl``, B
   runs ``lsl:`` and an inlet in a process of its own pulls every stream (as
   LabRecorder does), the whole run in a private network namespace with only the
   loopback up (tests/helpers/lslnet.py: LSL's multicast never leaves the machine; as
   root); with ``--mqtt``, B sends to a mosquitto this script starts on a free
   loopback port (``--mqtt-rate-hz N``: with ``rate_hz: N``), subscribed to by nobody,
   as a broker forwarding to nothing costs the gateway the same as one with
   subscribers.

The pipeline measures A then B (the order alternates each round, so neither side always
goes first); the table gives each round's figures and the median of the rounds' B/A
ratios, so a neighbour that slows the machine for a while slows both sides of a round.
"""

from __future__ import annotations

import argparse
import atexit
import os
import statistics
import subprocess
import sys
import tempfile
import time
import tomllib
import urllib.request
from pathlib import Path

import yaml
from benchutil import REPO, cpu_ns, free_port

from gateway.sim.node import NodeSettings
from gateway.sim.server import Simulator
from tests.helpers.broker import Broker

PIPELINE = r'''
import asyncio, inspect, multiprocessing, sys, time
sys.path.insert(0, sys.argv[1])
sys.path.insert(1, sys.argv[2])
import aspp, gateway  # from the tree measured, before anything puts this one first
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
except ImportError:
    from gateway.daemon import Gateway
    from gateway.config import GatewayConfig
    def feeder(gw): return gw._on_data
    CLOCKS = 1
for module in (aspp, gateway, sys.modules[Gateway.__module__]):
    assert module.__file__.startswith(sys.argv[1]), module.__file__
from perf import count_messages, until_subscribed
from decoder_throughput import mixed_stream
from benchutil import free_port
packets = int(sys.argv[3])
STREAMS = ((76, "accel_angrate"), (77, "accel_angrate_mag_orientation"), (95, "euler"))
stream = mixed_stream(packets)
chunks = [stream[o:o + 4096] for o in range(0, len(stream), 4096)]
endpoint = f"tcp://127.0.0.1:{free_port()}"
config = GatewayConfig.model_validate({
    "base_station": {"port": "loop://"},
    "publish": {"endpoint": endpoint, "high_water_mark": 10_000_000},
    "control": {"endpoint": f"tcp://127.0.0.1:{free_port()}"},
    "nodes": [{"address": a} for a in (76, 77, 95)]})
ready, result = multiprocessing.Event(), multiprocessing.Queue()
counter = multiprocessing.Process(target=count_messages, args=(endpoint, packets, ready, result))
async def run():
    gw = Gateway(config)
    feed = feeder(gw)
    for address, record in STREAMS:  # known, as after arming (both trees do the same)
        gw.nodes[address].streaming(record)
    counter.start()
    until_subscribed(lambda: getattr(gw, "outputs", gw.publisher).status({}), ready)
    cpu = time.process_time()
    for chunk in chunks:
        feed(chunk, *(time.time(),) * CLOCKS)
    gw.publisher.close(5.0)  # (what is queued may take up to 5 s to go out)
    gw._context.destroy(linger=5000)
    return time.process_time() - cpu
cpu = asyncio.run(run())
got, _ = result.get(timeout=60)
counter.join(10)
assert got == packets, (got, packets)
print(packets / cpu)
'''

def worktree(rev: str, into: Path) -> Path:
    subprocess.run(["git", "-C", str(REPO), "worktree", "add", "--detach", "-q", str(into),
                    rev], check=True)
    return into


def entry_point(tree: Path) -> str:
    """``module:function`` of the tree's gx2-gateway console script."""
    scripts = tomllib.loads((tree / "pyproject.toml").read_text())["project"]["scripts"]
    return scripts["gx2-gateway"]


def pipeline(tree: Path, packets: int) -> float:
    run = subprocess.run([sys.executable, "-c", PIPELINE, str(tree), str(REPO / "bench"),
                          str(packets)], capture_output=True, text=True, timeout=600,
                         cwd=REPO / "bench")
    if run.returncode:
        raise RuntimeError(f"pipeline in {tree} failed:\n{run.stderr}")
    return float(run.stdout.strip().splitlines()[-1])


def gateway_command(tree: Path, config: Path) -> list[str]:
    """The tree's gx2-gateway, started as its console script would be."""
    module, function = entry_point(tree).split(":")
    code = (f"import sys; sys.path.insert(0, {str(tree)!r}); import {module} as m; "
            f"sys.argv[0] = 'gx2-gateway'; sys.exit(m.{function}())")
    return [sys.executable, "-c", code, "--config", str(config), "--log-level", "WARNING"]


INLET = r'''
import sys, pylsl
prefix, count = sys.argv[1], int(sys.argv[2])
found = {}
while len(found) < count:
    for info in pylsl.resolve_streams(wait_time=1.0):
        if info.name().startswith(prefix + "-"):
            found.setdefault(info.name(), info)
inlets = [pylsl.StreamInlet(info) for info in found.values()]
while True:
    for inlet in inlets:
        inlet.pull_chunk(timeout=0.05)
'''
"""LabRecorder's part: every stream of ``prefix``, pulled until killed."""


def saturated_cpu(trees: dict[str, Path], seconds: float, record: bool,
                  metrics: bool = False, live: bool = False,
                  lsl: bool = False, mqtt: dict[str, object] | None = None
                  ) -> dict[str, float]:
    """Each tree's gateway on a simulator of its own (this tree's), all at once, so
    that they share whatever the machine is doing: % of one core over ``seconds``,
    from the kernel's nanosecond count of each process's threads."""
    started: list[tuple[str, Simulator, subprocess.Popen[bytes]]] = []
    inlets: list[subprocess.Popen[bytes]] = []
    scrapes: list[str] = []
    try:
        for side, tree in trees.items():
            work = Path(tempfile.mkdtemp(prefix=f"gx2-ab-{side}-"))
            nodes = [NodeSettings(a, divider=533, stream="accel_angrate") for a in (76, 77, 78)]
            config = {"base_station": {"port": str(work / "gx2")},
                      "publish": {"endpoint": f"tcp://127.0.0.1:{free_port()}"},
                      "control": {"endpoint": f"tcp://127.0.0.1:{free_port()}"},
                      "nodes": [{"address": n.address, "stream": "accel_angrate"}
                                for n in nodes]}
            if record and side == "B":
                config["record"] = {"directory": str(work / "recordings")}
            if metrics and side == "B":
                config["metrics"] = {"endpoint": f"127.0.0.1:{free_port()}"}
                scrapes.append(f"http://{config['metrics']['endpoint']}/metrics")
            if live and side == "B":  # (and no viewer: what serving it costs by itself)
                config["live"] = {"endpoint": f"127.0.0.1:{free_port()}"}
            if lsl and side == "B":
                config["lsl"] = {"prefix": "ab"}
                inlets.append(subprocess.Popen([sys.executable, "-c", INLET, "ab",
                                                str(len(nodes))]))
            if mqtt and side == "B":
                config["mqtt"] = mqtt
            (work / "nodes.yaml").write_text(yaml.safe_dump(config))
            sim = Simulator(nodes, link=work / "gx2").start()
            started.append((side, sim, subprocess.Popen(
                gateway_command(tree, work / "nodes.yaml"), stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL)))
        time.sleep(6.0)  # started, armed and streaming (a settling period, not a sync)
        before = {side: cpu_ns(proc.pid) for side, _, proc in started}
        t0 = time.monotonic()
        scraped = scrape_every_second(scrapes, t0 + seconds)
        time.sleep(max(0.0, t0 + seconds - time.monotonic()))
        elapsed = time.monotonic() - t0
        if scrapes and scraped < seconds - 2:
            raise RuntimeError(f"only {scraped} scrapes of {scrapes} in {seconds:g} s")
        return {side: (cpu_ns(proc.pid) - before[side]) / 1e9 / elapsed * 100
                for side, _, proc in started}
    finally:
        for _, sim, proc in started:
            proc.terminate()
            proc.wait(10)
            sim.stop()
        for inlet in inlets:
            inlet.kill()
            inlet.wait(10)


def scrape_every_second(urls: list[str], until: float) -> int:
    """GET each of ``urls`` once a second until ``until`` (time.monotonic()); how many
    rounds of scrapes succeeded. Nothing to scrape: returns at once."""
    done = 0
    while urls and time.monotonic() < until:
        due = time.monotonic() + 1.0
        for url in urls:
            with urllib.request.urlopen(url, timeout=5) as reply:
                reply.read()
        done += 1
        time.sleep(max(0.0, min(due, until) - time.monotonic()))
    return done


NAMESPACED = "GX2_BENCH_NAMESPACED"


def in_lsl_namespace() -> int:
    """This command again, in a private network namespace with only the loopback up
    and an LSL configuration of its own (tests/helpers/lslnet.py)."""
    from tests.helpers.lslnet import in_namespace, lsl_environment, namespace_refusal
    refusal = namespace_refusal()
    if refusal:
        print(f"--lsl: no private network namespace: {refusal}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="gx2-ab-lsl-") as directory:
        env = {**lsl_environment(Path(directory)), NAMESPACED: "1"}
        return subprocess.call(in_namespace([sys.executable, *sys.argv]), env=env)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", required=True, help="the commit to compare against (A)")
    parser.add_argument("--head", help="the commit measured (B; default: this working "
                        "tree, which must then not change while it runs)")
    parser.add_argument("--rounds", type=int, default=4)
    parser.add_argument("--seconds", type=float, default=30.0,
                        help="CPU measured for this long in each round")
    parser.add_argument("--packets", type=int, default=150_000)
    parser.add_argument("--record", action="store_true",
                        help="B runs with record: configured (A without)")
    parser.add_argument("--metrics", action="store_true",
                        help="B serves metrics, scraped once a second (A does not)")
    parser.add_argument("--live", action="store_true",
                        help="B serves the live view, no viewer connected (A does not)")
    parser.add_argument("--lsl", action="store_true",
                        help="B runs lsl:, an inlet pulling every stream (A does not); "
                        "all in a private network namespace (root)")
    parser.add_argument("--mqtt", action="store_true",
                        help="B sends to a local mosquitto this script starts (A does not)")
    parser.add_argument("--mqtt-rate-hz", type=float,
                        help="with --mqtt: B's mqtt.rate_hz (every record)")
    parser.add_argument("--skip-pipeline", action="store_true")
    args = parser.parse_args()
    if args.lsl and NAMESPACED not in os.environ:
        return in_lsl_namespace()
    mqtt: dict[str, object] | None = None
    if args.mqtt:
        broker = Broker(Path(tempfile.mkdtemp(prefix="gx2-ab-broker-")))
        atexit.register(broker.stop)
        mqtt = {"url": broker.url, "name": "ab"}
        if args.mqtt_rate_hz:
            mqtt["rate_hz"] = args.mqtt_rate_hz
    base_rev = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", args.base],
                              capture_output=True, text=True, check=True).stdout.strip()
    head_rev = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short",
                               args.head or "HEAD"],
                              capture_output=True, text=True, check=True).stdout.strip()
    dirty = "" if args.head else subprocess.run(
        ["git", "-C", str(REPO), "status", "--porcelain"], capture_output=True,
        text=True).stdout.strip()
    with tempfile.TemporaryDirectory(prefix="gx2-ab-base-") as temporary:
        base = worktree(args.base, Path(temporary) / "base")
        head = worktree(args.head, Path(temporary) / "head") if args.head else REPO
        trees = {"A": base, "B": head}
        rows: dict[str, list[tuple[float, float]]] = {"pipeline": [], "cpu": []}
        try:
            for round_ in range(args.rounds):
                order = ("A", "B") if round_ % 2 == 0 else ("B", "A")
                if not args.skip_pipeline:
                    got = {side: pipeline(trees[side], args.packets) for side in order}
                    rows["pipeline"].append((got["A"], got["B"]))
                got = saturated_cpu(trees, args.seconds, args.record, args.metrics,
                                    args.live, args.lsl, mqtt)
                rows["cpu"].append((got["A"], got["B"]))
                print(f"round {round_ + 1}: " + ", ".join(
                    f"{name} A {a:,.1f} B {b:,.1f}" for name, values in rows.items()
                    for a, b in values[-1:]), flush=True)
        finally:
            for tree in {base, head} - {REPO}:
                subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force",
                                str(tree)], check=False)
    print(f"\nA = {base_rev}, B = {head_rev}{' (with uncommitted changes)' if dirty else ''}"
          f"{', B records' if args.record else ''}"
          f"{', B serves metrics scraped every second' if args.metrics else ''}"
          f"{', B serves the live view (no viewer)' if args.live else ''}"
          f"{', B runs lsl: with an inlet pulling every stream' if args.lsl else ''}"
          f"{f', B sends to MQTT ({mqtt})' if mqtt else ''}; "
          f"{args.rounds} interleaved rounds")
    print("| measure | A, each round | B, each round | B / A (median of rounds) |")
    print("|---|---|---|---|")
    names = {"pipeline": "pipeline, records per CPU-second",
             "cpu": f"gateway CPU at a saturated line, % of one core over {args.seconds:g} s"}
    for name, values in rows.items():
        if values:
            a = ", ".join(f"{x:,.1f}" for x, _ in values)
            b = ", ".join(f"{y:,.1f}" for _, y in values)
            ratio = statistics.median(y / x for x, y in values)
            print(f"| {names[name]} | {a} | {b} | {ratio:.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
