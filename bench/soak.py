#!/usr/bin/env python3
"""Soak: the installed gx2-gateway against gx2-sim on a saturated line, with faults,
a node reboot and a base station unplug, for as long as you like.

Three nodes stream accel_angrate (40-byte packets) at 100 Hz: 12,000 bytes/s offered
to a 115200-baud line that carries 11,520, so with 5% lost over the air the line runs
at about 99% and the base station's buffer overflows now and then (counted apart).
Faults: 1% of packets followed by garbage, 5% radio loss each way, one node rebooted
(with its discovery packet) at a third of the run, the base station unplugged for
--unplug-seconds at two thirds.

Every byte the simulator writes into the pty also goes through a tap decoder, so the
figures compare what was really delivered with what the gateway received, published
and a subscriber got; "lost in the gateway" must be 0. Run by hand (not in CI):

    python bench/soak.py --minutes 10
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml
import zmq
from benchutil import Tap, Watcher, free_port, gateway_command, gateway_losses, rss_kib

from gateway.sim.base_station import LineFaults, RadioLink
from gateway.sim.node import NodeSettings
from gateway.sim.server import Simulator

NODES = (76, 77, 78)
LINE_BYTES_PER_SECOND = 115200 / 10
WARM_UP = 10.0
"""Seconds before the first RSS sample: imports, arming and buffers settled."""


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--unplug-seconds", type=float, default=2.0)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    duration = args.minutes * 60

    work = Path(tempfile.mkdtemp(prefix="gx2-soak-"))
    link = work / "gx2"
    sim = Simulator([NodeSettings(a) for a in NODES], link=link, seed=args.seed,
                    radio={a: RadioLink(data_loss=0.05, command_loss=0.05) for a in NODES},
                    line=LineFaults(garbage=0.01)).start()
    tap = Tap(sim)
    control, publish = f"tcp://127.0.0.1:{free_port()}", f"tcp://127.0.0.1:{free_port()}"
    (work / "nodes.yaml").write_text(yaml.safe_dump({
        "base_station": {"port": str(link)}, "publish": {"endpoint": publish},
        "control": {"endpoint": control},
        "nodes": [{"address": a, "stream": "accel_angrate"} for a in NODES]}))
    log = (work / "gateway.log").open("w")
    gateway = subprocess.Popen([gateway_command(), "--config", str(work / "nodes.yaml"),
                                "--log-level", "DEBUG"],
                               stdout=log, stderr=subprocess.STDOUT)
    context = zmq.Context()
    watch = Watcher(context, publish, control)
    print(f"soak: {args.minutes:g} min, nodes {NODES} accel_angrate at 100 Hz; work dir {work}",
          flush=True)
    try:
        start = time.monotonic()
        reboot_at, unplug_at = start + duration / 3, start + 2 * duration / 3
        rebooted = unplugged = replugged = None
        reboot_back = link_back = stream_back = None
        rss: list[int] = []
        next_sample = start + WARM_UP
        bytes_at_start = sim.call(lambda station, now: station.stats.bytes_sent)
        while (now := time.monotonic()) < start + duration:
            watch.drain(0.1)
            if now >= next_sample:
                rss.append(rss_kib(gateway.pid))
                next_sample += 10.0
                minute = (now - start) / 60
                print(f"  {minute:5.1f} min  records {sum(watch.received.values()):>9,}  "
                      f"RSS {rss[-1] / 1024:.1f} MiB", flush=True)
            if rebooted is None and now >= reboot_at:
                rebooted = time.monotonic()
                sim.reboot(NODES[0])
            if rebooted and reboot_back is None and watch.last_record.get(NODES[0], 0) > \
                    rebooted + 0.05:
                status = watch.status()
                node = status and next(n for n in status["nodes"] if n["node"] == NODES[0])
                if node and node["state"] == "streaming" and node["reboots"] == 1:
                    reboot_back = time.monotonic() - rebooted
            if unplugged is None and now >= unplug_at:
                unplugged = time.monotonic()
                sim.unplug(duration=args.unplug_seconds)
                replugged = unplugged + args.unplug_seconds
            if replugged and link_back is None and now >= replugged:
                status = watch.status(0.5)
                if status and status["link"]["state"] == "up":
                    link_back = time.monotonic() - replugged
            if link_back is not None and stream_back is None and replugged and all(
                    watch.last_record.get(a, 0) > replugged for a in NODES):
                stream_back = time.monotonic() - replugged
        elapsed = time.monotonic() - start
        line_bytes = sim.call(lambda station, now: station.stats.bytes_sent) - bytes_at_start

        # stop the streams as gx2ctl stop does (a stream silenced at the source would be
        # re-armed), then let every count settle
        for address in NODES:
            watch.request("stop", node=address)
        settle = time.monotonic() + 10
        status = watch.status()
        while time.monotonic() < settle:
            watch.drain(0.5)
            status = watch.status()
            if status and sum(n["published"] for n in status["nodes"]) == sum(
                    watch.received.values()):
                break
        rss_end = rss_kib(gateway.pid)
        stats = sim.call(lambda station, now: station.stats)
    finally:
        gateway.terminate()
        gateway.wait(10)
        sim.stop()
        context.destroy(linger=0)
    assert status is not None, "the gateway stopped answering"

    nodes = {n["node"]: n for n in status["nodes"]}
    losses = gateway_losses(status, tap, watch, NODES)
    delivered, received, in_gateway = (losses["delivered"], losses["received"],
                                       losses["in_gateway"])
    rows = [
        ("duration", f"{elapsed / 60:.1f} min"),
        ("line utilisation", f"{line_bytes / (elapsed * LINE_BYTES_PER_SECOND):.1%} "
                             f"of 115200 baud ({line_bytes:,} bytes)"),
        ("packets the simulator sent", f"{sum(stats.packets_sent.values()):,}"),
        ("  delivered into the pty (tap)", f"{delivered:,}"),
        ("  received by the gateway", f"{received:,}"),
        ("  published / got by a subscriber", f"{losses['published']:,} / {losses['got']:,} "
                                              f"(seq gaps {watch.seq_gaps}; "
                                              f"{losses['before_joining']} published "
                                              "before it joined)"),
        ("lost over the air (simulator truth)", f"{stats.packets_lost_radio:,}"),
        ("  gateway's lost_radio (from timer gaps)",
         f"{sum(nodes[a]['lost_radio'] for a in NODES):,} (includes the base station's "
         f"full-buffer drops: {stats.packets_dropped_full:,})"),
        ("lost at the unplug (in the pty, or before the port was reopened)",
         f"{delivered - received:,}"),
        ("lost in the gateway", f"{in_gateway}"),
        ("line faults injected / bytes discarded",
         f"{stats.faults_injected:,} / {status['link']['discarded_bytes']:,}"),
        ("reboot: stream back after", f"{reboot_back:.2f} s" if reboot_back else "never"),
        ("unplug: link up after the replug", f"{link_back:.2f} s" if link_back else "never"),
        ("unplug: all streams back after the replug",
         f"{stream_back:.2f} s" if stream_back else "never"),
        ("reconnects / reboots counted", f"{status['link']['reconnects']} / "
                                         f"{sum(nodes[a]['reboots'] for a in NODES)}"),
        ("gateway RSS start / end / max", f"{rss[0] / 1024:.1f} / {rss_end / 1024:.1f} / "
                                          f"{max([*rss, rss_end]) / 1024:.1f} MiB"),
    ]
    width = max(len(name) for name, _ in rows)
    for name, value in rows:
        print(f"{name:<{width}}  {value}")
    ok = in_gateway == 0 and link_back is not None and reboot_back is not None
    print("PASS" if ok else f"FAIL (the gateway's log: {work / 'gateway.log'})")
    if ok:
        shutil.rmtree(work, ignore_errors=True)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
