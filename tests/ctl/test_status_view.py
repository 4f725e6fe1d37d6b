"""gx2ctl status read by a person: it fits the terminal's width (columns give way in
the stated order, lines above the table break between items), groups nodes by base
station with each line's share, and --check fails if any base station is down."""

from __future__ import annotations

import pytest

from gateway.ctl.statusview import GIVE_WAY, NODE_COLUMNS, status_lines, unhealthy

NOW = 1_800_000_000.0


def node(address: int, station: str, health: str = "OK", **more) -> dict:
    return {"node": address, "name": f"wing-{address}-long-name", "station": station,
            "state": "streaming", "record": "accel_angrate_orientation",
            "configured": "accel_angrate", "desired": "accel_angrate_orientation",
            "rate_hz": 99.8, "packets": 123456, "published": 123450, "lost_radio": 12,
            "lost_gateway": 0, "reboots": 1, "silences": 0, "lqi": 255, "rssi": -44,
            "last_seen": NOW - 0.2, "clock": {"drift_ppm": 12.3, "locked": True},
            "health": health, "reasons": [] if health == "OK" else ["radio loss 6.0%"],
            **more}


def link(name: str, state: str = "up", share: float = 0.87) -> dict:
    return {"name": name, "port": f"/dev/gx2-base-{name}", "state": state,
            "since": NOW - 65, "reconnects": 0, "bytes_read": 1234567,
            "discarded_bytes": 7, "bytes_per_s": share * 11520, "line_bytes_per_s": 11520,
            "over_capacity": share >= 0.95}


def status(*stations: dict, nodes: list[dict]) -> dict:
    return {"gateway": {"version": "9.9.9", "uptime": 3725,
                        "publish_endpoint": "tcp://127.0.0.1:5555",
                        "control_endpoint": "tcp://127.0.0.1:5556", "health": "OK",
                        "reasons": []},
            "link": stations[0], "stations": list(stations), "nodes": nodes,
            "recording": {"directory": "/var/lib/gx2-gateway/recordings", "written": 10,
                          "dropped": 0, "bytes": 12e6, "oldest": "/r/gx2-1.mcap"}}


TWO = status(link("north"), link("south", share=0.97),
             nodes=[node(76, "north"), node(78, "south", "WARN"), node(77, "north")])


def headers(lines: list[str]) -> list[str]:
    """The column headers of the table (the line after the blank one)."""
    row = lines[lines.index("") + 1]
    return [c.header for c in NODE_COLUMNS if f" {c.header} " in f" {row} "
            or row.startswith(c.header + " ") or row.endswith(" " + c.header)]


@pytest.mark.parametrize("width", [40, 60, 80, 100, 120, 160])
def test_no_line_is_wider_than_the_terminal(width: int) -> None:
    lines = status_lines(TWO, NOW, width)
    assert max(len(line) for line in lines) <= width, "\n".join(lines)
    # node and health stay at any width: which node, and whether it is well
    assert {"node", "health"} <= set(headers(lines))


def test_columns_give_way_in_the_stated_order() -> None:
    at_80, at_120 = headers(status_lines(TWO, NOW, 80)), headers(status_lines(TWO, NOW, 120))
    assert at_80 == ["node", "name", "state", "record", "rate Hz", "lost radio", "LQI",
                     "RSSI", "health"], at_80
    assert set(at_80) < set(at_120)
    # what is shown at 120 is what survives GIVE_WAY's first steps: the configured and
    # desired records and the silences counter go first
    assert not {"configured", "desired", "silences"} & set(at_120), at_120
    assert {"lost gateway", "reboots", "clock"} <= set(at_120), at_120
    wide = headers(status_lines(TWO, NOW, None))
    assert wide == [c.header for c in NODE_COLUMNS]
    assert {header for header, _ in GIVE_WAY} <= set(wide)


def test_lines_above_the_table_break_between_items_never_inside_one() -> None:
    lines = status_lines(TWO, NOW, 60)
    first = lines[:lines.index("")]
    assert first[0].startswith("gateway  version 9.9.9, up 1 h 02 min,")
    assert any(line.strip() == "control tcp://127.0.0.1:5556," or
               line.strip().startswith("control tcp://127.0.0.1:5556") for line in first)
    for line in first[1:]:
        assert not line.startswith(" ") or line.startswith(" " * 9), line
    joined = " ".join(line.strip() for line in first)
    assert "/dev/gx2-base-north, up for 1 min 05 s, line 87% of 11,520 B/s" in joined


def test_nodes_are_grouped_by_base_station_with_its_line_share() -> None:
    lines = status_lines(TWO, NOW, None)
    table = lines[lines.index("") + 1:]
    north = table.index("-- north (up, line 87% of 11,520 B/s)")
    south = table.index("-- south (up, line 97% of 11,520 B/s OVER CAPACITY)")
    assert [row.split()[0] for row in table[north + 1:south]] == ["76", "77"]
    assert table[south + 1].split()[0] == "78"
    assert "78 WARN: radio loss 6.0%" in table
    # each station's line above the table, named
    assert any(line.startswith("north    /dev/gx2-base-north, up") for line in lines)
    assert any(line.startswith("south    /dev/gx2-base-south, up") for line in lines)


def test_one_station_is_shown_as_ever() -> None:
    one = status(link("station1"), nodes=[node(76, "station1")])
    one.pop("stations")
    lines = status_lines(one, NOW, None)
    assert lines[1].startswith("link     /dev/gx2-base-station1, up for 1 min 05 s, "
                               "line 87% of 11,520 B/s, reconnects 0")
    assert not any(line.startswith("--") for line in lines)


def test_check_fails_if_any_base_station_is_down() -> None:
    nodes = [node(76, "north"), node(78, "south")]
    assert unhealthy(status(link("north"), link("south"), nodes=nodes)) is None
    down = status(link("north"), link("south", "down"), nodes=nodes)
    assert unhealthy(down) == "1 of 2 base stations not up: south down"
    # the first station (the old link) up is not enough
    assert down["link"]["state"] == "up"


def test_a_long_port_cut_to_the_width_keeps_the_state_and_why() -> None:
    port = "/dev/serial/by-id/usb-FTDI_FT232R_USB_UART_A1B2C3D4-if00-port0-" + "x" * 40
    down = {**link("station1", "down"), "port": port, "error": "No such file or directory"}
    lines = status_lines(status(down, nodes=[node(76, "station1")]), NOW, 80)
    assert max(len(line) for line in lines) <= 80
    at = next(i for i, line in enumerate(lines) if line.startswith("link "))
    assert lines[at].startswith("link     /dev/serial/by-id/") and lines[at].endswith("…")
    assert lines[at + 1].strip().startswith("down for 1 min 05 s (No such file or directory)")


def test_the_nodes_a_station_heard_are_under_its_line_streaming_first_then_the_latest():
    heard = [{"address": a, "record": None, "rate_hz": None, "rssi": -70.0, "lqi": 99,
              "packets": 1, "last_heard": NOW - (a - 100), "announced": NOW - (a - 100)}
             for a in range(100, 110)]
    heard.insert(3, {"address": 81, "record": "accel_angrate", "rate_hz": 100.0,
                     "rssi": -61.4, "lqi": 180.0, "packets": 900, "last_heard": NOW - 0.3})
    heard.append({"address": 95, "record": "firmware_version", "rate_hz": None,
                  "rssi": None, "lqi": None, "packets": 1, "last_heard": NOW - 0.5})
    lines = status_lines(status(link("north"), {**link("south"), "heard": heard},
                                nodes=[node(76, "north")]), NOW)
    south = next(i for i, line in enumerate(lines) if line.startswith("south"))
    recording = next(i for i, line in enumerate(lines) if line.startswith("record"))
    assert lines[south + 1:recording] == [
        "         heard, not configured: 81 streaming accel_angrate at 100 Hz, RSSI -61, "
        "last 0.3 s ago",
        "         heard, not configured: 100 powered up (a discovery packet), RSSI -70, "
        "last 0.0 s ago",
        "         heard, not configured: 95 sent firmware_version, last 0.5 s ago",
        *(f"         heard, not configured: {a} powered up (a discovery packet), RSSI -70, "
          f"last {a - 100}.0 s ago" for a in range(101, 106)),
        "         and 4 more heard (gx2ctl --json status lists them)"], lines
    assert not any("heard" in line for line in lines[:south])  # north heard none


def test_several_gateways_share_one_table_fitted_to_the_width() -> None:
    """One header over every gateway's nodes (the columns aligned across them), each
    gateway's nodes under its name and by station, a gateway without an answer a line
    in its place; nothing wider than the terminal; reasons named by gateway."""
    from gateway.ctl.client import CtlError
    from gateway.ctl.sitestatus import Answer
    from gateway.ctl.sitestatus import status_lines as several_lines
    from gateway.ctl.where import Endpoints, Gateway

    def gateway(name: str) -> Gateway:
        return Gateway(name, Endpoints(f"tcp://{name}:5556", None))
    one = status(link("ch11"), nodes=[node(90, "ch11")])
    answers = [Answer(gateway("hall-a"), TWO), Answer(gateway("hall-b"), one),
               Answer(gateway("hall-c"), None, CtlError("no answer from hall-c", 3))]
    lines = several_lines(answers, NOW, 80)
    assert max(len(line) for line in lines) <= 80
    table = lines[lines.index("") + 1:]
    assert [line.split()[0] for line in table if line[:1].isdigit()] == ["76", "77", "78",
                                                                          "90"]
    assert sum(1 for line in table if line.startswith("node ")) == 1
    a, b = table.index("== hall-a"), table.index("== hall-b")
    assert table[a + 1].startswith("-- north (up, line 87%") and "-- ch11" not in table[b + 1]
    assert table[-2:] == ["== hall-c: no answer from hall-c", "hall-a/78 WARN: radio loss 6.0%"]
    assert len({line.index(" streaming ") for line in table if " streaming " in line}) == 1


def test_the_mqtt_output_is_a_line_saying_whether_it_is_connected_and_what_it_dropped(
        ) -> None:
    said = {**TWO, "mqtt": {"url": "mqtt://broker:1883", "topic": "gx2/hall",
                            "connected": False, "error": "the broker refused the "
                            "connection: Not authorized", "sent": 1200,
                            "dropped": {"queue": 3, "offline": 450}}}
    lines = status_lines(said, NOW, None)
    line = next(line for line in lines if line.startswith("mqtt"))
    assert line == ("mqtt     mqtt://broker:1883 gx2/hall/, not connected (the broker "
                    "refused the connection: Not authorized), sent 1200, dropped 3 (queue "
                    "full), 450 (broker away)"), line
    assert not any(line.startswith("mqtt") for line in status_lines(TWO, NOW, None))
