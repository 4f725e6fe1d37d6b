"""config/stations.yaml, the four-station configuration README shows, end to end on the
embedded simulator: every node streams through its own station, a command goes through
the node's station, metrics label each link by station, ``gx2ctl top`` groups the nodes,
and the recording replays through four ``replay://`` stations with every record
identical."""

from __future__ import annotations

import os
import urllib.request
from pathlib import Path

import yaml
from prometheus_client.parser import text_string_to_metric_families

from tests.e2e.test_recording import payloads, recorded
from tests.e2e.test_stations import replays_identically
from tests.helpers.processes import STARTUP, Running

REPO = Path(__file__).resolve().parents[2]


def stations_yaml() -> list[dict]:
    return yaml.safe_load((REPO / "config" / "stations.yaml").read_text())["base_stations"]


def test_four_stations_stream_command_record_replay_top_and_metrics(gateway, tmp_path):
    stations = stations_yaml()
    assert len(stations) == 4 and all(s["port"].startswith("sim://") for s in stations)
    where = {n["address"]: s["name"] for s in stations for n in s["nodes"]}
    assert len(where) == 12
    directory = tmp_path / "recordings"
    gw = gateway(None, [], base_stations=stations, record={"directory": str(directory)},
                 metrics={})
    gw.wait_streaming(*where)

    sub = gw.subscribe("gx2/")
    sub.until(lambda m: {p.get("node") for t, p in m if t[4].isdigit()} >= set(where), 10,
              "records of all twelve nodes")
    assert {(p["node"], p["station"]) for t, p in sub.messages if t[4].isdigit()} \
        <= set(where.items())
    assert gw.control.result("poll", node=92, record="euler")["station"] == "ch20"

    metrics = gw.config["metrics"]["endpoint"]
    with urllib.request.urlopen(f"http://{metrics}/metrics", timeout=5) as response:
        families = {f.name: f for f in text_string_to_metric_families(response.read().decode())}
    up = {s.labels["station"]: s.value for s in families["gx2_link_up"].samples}
    assert up == {"ch11": 1.0, "ch15": 1.0, "ch20": 1.0, "ch25": 1.0}

    top = Running("gx2ctl", "--config", str(gw.path), "top",
                  env={**os.environ, "COLUMNS": "100"})
    try:
        top.wait_for_line(lambda line: line.startswith("ch25: up"), STARTUP)
        top.wait_for_line(lambda line: line.startswith("97 "), 5)
        top.proc.terminate()
        assert top.finish(5) == 0
    finally:
        top.kill()
    lines = "".join(top.stdout).splitlines()
    frame = lines[:lines.index(next(line for line in lines if line.startswith("97 "))) + 1]
    frame = frame[max(i for i, line in enumerate(frame) if line.startswith("gx2-gateway")):]
    heads = [line.split(":")[0] for line in frame if line.startswith("ch")]
    assert heads == ["ch11", "ch15", "ch20", "ch25"], frame
    assert "base stations 4: 4 up" in frame, frame

    assert gw.terminate()[0] == 0, gw.log()
    entries = recorded(directory)
    assert {f"serial/{name}" for name in up} <= {topic for topic, _, _ in entries}
    live = {key: payload for key, (_, payload) in payloads(entries).items()}
    assert {node for node, _ in live} == set(where)

    replays_identically(gateway, directory, live,
                        [{"name": s["name"], "nodes": s["nodes"]} for s in stations])
