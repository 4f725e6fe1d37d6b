"""``gx2ctl top``'s frames on their own: what fits in a width, what gives way, what the
header says when the gateway goes quiet (tests/e2e/test_top.py runs it in tmux)."""

from __future__ import annotations

from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st
from rich.cells import cell_len

from gateway.client import Status
from gateway.ctl.columns import fit, sized
from gateway.ctl.top import Watch, frame
from gateway.ctl.toptable import COLUMNS, GIVE_WAY, table

NOW = 1_800_000_000.0


def node(address: int = 76, **changes: Any) -> dict[str, Any]:
    entry = {"node": address, "name": "left-wing", "state": "streaming",
             "record": "accel_angrate", "rate_hz": 99.1, "expected_hz": 100.0,
             "recent": {"lost_radio": 12, "lost_radio_percent": 0.2}, "lost_gateway": 0,
             "reboots": 1, "lqi": 201, "rssi": -45, "clock": {"drift_ppm": 40.06,
                                                           "locked": True},
             "last_seen": NOW - 0.04, "health": "OK", "reasons": []}
    entry.update(changes)
    return entry


def status(*nodes: dict[str, Any]) -> dict[str, Any]:
    return {"gateway": {"version": "1.2.3", "uptime": 3725.0, "time": NOW},
            "link": {"port": "/dev/gx2", "state": "up", "since": NOW - 300,
                     "reconnects": 1, "bytes_per_s": 9519.0, "line_bytes_per_s": 11520.0,
                     "discarded_bytes": 62, "discarded": {"garbage": 60, "truncated": 2,
                                                          "bad_address": 0}},
            "nodes": list(nodes)}


def lines(watch: Watch, width: int, silent_for: float = 0.5) -> list[str]:
    return [line.plain for line in frame(watch, NOW, silent_for, width)]


def test_a_wide_terminal_shows_every_column_whole() -> None:
    shown = lines(Watch("tcp://gw:5555", status=status(node())), 120)
    header = next(line for line in shown if line.startswith("node "))
    assert header.split() == [c.header for c in COLUMNS]
    row = next(line for line in shown if line.startswith("76 "))
    assert row.split() == ["76", "left-wing", "streaming", "accel_angrate", "99.1/100", "12",
                           "0.2%", "0", "1", "201", "-45", "+40.1", "0.0s", "OK"]


def test_80_columns_cut_the_record_and_drop_lqi_and_losses_in_the_gateway_first() -> None:
    watch = Watch("tcp://gw:5555", status=status(node(), node(77, name="right-wing",
                                                               record="euler")))
    shown = lines(watch, 80)
    assert all(cell_len(line) <= 80 for line in shown)
    header = next(line for line in shown if line.startswith("node "))
    assert "LQI" not in header and " gw " not in header
    assert " boots " in header and " clock " in header
    assert next(line for line in shown if line.startswith("76 ")).startswith(
        "76 left-wing  streaming accel_ang… 99.1/100")


def test_what_gives_way_keeps_the_node_and_its_health() -> None:
    rows = [[c.cell(node(), NOW) for c in COLUMNS]]
    for width in (10, 25, 40, 60, 79, 80, 100):
        kept = [COLUMNS[i].header for i, _ in fit(COLUMNS, rows, width, GIVE_WAY)]
        assert kept[0] == "node" and kept[-1] == "health", (width, kept)
    # the room left once the record and the rate are gone takes back RSSI, whole
    assert fit(COLUMNS, rows, 30, GIVE_WAY) == [(0, 8), (1, 9), (8, 4), (11, 6)]


def test_a_table_without_nodes_is_its_header() -> None:
    assert [line.plain.split() for line in table([], NOW, 80)] == [
        [c.header for c in COLUMNS]]


def test_cells_are_cut_by_terminal_cells_not_characters() -> None:
    assert sized("左翼ノード", 6) == "左翼… "  # (each of these takes two cells)
    assert sized("76 left-wing", 4) == "76…" + " "
    assert sized("76", 5, right=True) == "   76"


def test_health_is_coloured_and_the_reasons_follow_the_table() -> None:
    watch = Watch("tcp://gw:5555", status=status(
        node(), node(77, health="WARN", reasons=["radio loss 9.8% in 60 s", "RSSI -93 dBm"]),
        node(95, state="silent", health="ERROR", reasons=["silent"])))
    drawn = frame(watch, NOW, 0.5, 100)
    styles = {line.plain.split()[0]: {(line.plain[span.start:span.end], str(span.style))
                                      for span in line.spans}
              for line in drawn if line.plain[:2] in ("76", "77", "95") and ":" not in
              line.plain}  # (the table's rows, not the reasons under it)
    assert styles == {"76": {("OK", "green")}, "77": {("WARN", "bold yellow")},
                      "95": {("ERROR", "bold red")}}
    plain = [line.plain for line in drawn]
    assert "77 WARN: radio loss 9.8% in 60 s; RSSI -93 dBm" in plain
    assert "95 ERROR: silent" in plain
    assert plain[0].startswith("gx2-gateway 1.2.3 up 1 h 02 min  nodes 1 OK 1 WARN 1 ERROR")


def test_the_link_line_says_how_much_of_the_line_is_used() -> None:
    link = lines(Watch("tcp://gw:5555", status=status(node())), 120)[1]
    assert link.startswith("link up 5 min 00 s  9,519 B/s = 83% of 11,520 B/s  "
                           "reconnects 1  /dev/gx2"), link
    assert lines(Watch("gw", status=status(node())), 120)[2] == \
        "discarded 62 B: garbage 60, truncated 2"


def test_a_quiet_gateway_is_shown_as_gone_and_a_restart_is_noticed() -> None:
    watch = Watch("tcp://gw:5555", silence=3.0)
    assert "waiting for the gateway's heartbeat on tcp://gw:5555" in lines(watch, 100)[3]
    watch.take(Status("tcp://gw:5555", status(node())))
    assert lines(watch, 100)[3] == ""
    gone = frame(watch, NOW, 4.0, 100)
    assert gone[3].plain.startswith(
        "no heartbeat for 4 s from tcp://gw:5555: is gx2-gateway running?")
    row = next(line for line in gone if line.plain.startswith("76 "))
    assert (0, len(row.plain), "dim") in [(sp.start, sp.end, str(sp.style))  # stale
                                          for sp in row.spans], row.spans
    watch.take(Status("tcp://gw:5555", status(node()), restarted=True))
    assert frame(watch, watch.now() + 5, 0.5, 100)[3].plain == \
        "the gateway restarted 5.0 s ago"


def test_a_missed_heartbeat_greys_every_row_and_says_how_old_it_is() -> None:
    """Issue 31, defect 17: a stopped gateway's rows stayed green OK until it was taken
    for gone (5 s), and then too."""
    watch = Watch("tcp://gw:5555", silence=5.0)
    watch.take(Status("tcp://gw:5555", status(node(), node(77, health="WARN",
                                                        reasons=["1 reboot in 60 s"]))))
    fresh = frame(watch, NOW, 1.2, 100)  # (within a quarter of an interval: jitter)
    assert fresh[3].plain == "" and " OK" in fresh[5].plain
    stale = frame(watch, NOW, 1.3, 100)
    assert stale[3].plain == ("no heartbeat for 1.3 s (one is due every 1 s) from "
                              "tcp://gw:5555: what is shown is 1.3 s old"), stale[3].plain
    for address in (76, 77):
        row = next(line for line in stale if line.plain.startswith(f"{address} "))
        assert row.plain.endswith(" stale 1.3s"), row.plain
        assert [str(span.style) for span in row.spans] == ["dim"], row.spans  # grey
    assert "green" not in {str(span.style) for line in stale for span in line.spans}
    assert "77 WARN: 1 reboot in 60 s" in [line.plain for line in stale]
    gone = frame(watch, NOW, 6.0, 100)
    assert gone[3].plain.startswith("no heartbeat for 6 s from tcp://gw:5555: is "
                                    "gx2-gateway running?")
    assert next(line.plain for line in gone if line.plain.startswith("76 ")).endswith(
        " stale 6.0s")
    # the interval is the gateway's own: one every 5 s is not missed after 1.3 s
    slow = status(node())
    slow["gateway"]["heartbeat_s"] = 5.0
    watch = Watch("tcp://gw:5555", silence=15.0)  # (three of them: gone)
    watch.take(Status("tcp://gw:5555", slow))
    assert lines(watch, 100, 1.3)[3] == "" and lines(watch, 100, 6.3)[3].startswith(
        "no heartbeat for 6.3 s (one is due every 5 s)")


def test_ages_are_on_the_gateways_clock_not_this_hosts() -> None:
    watch = Watch("gw")
    skewed = status(node(last_seen=NOW - 42.0))  # this host's clock is a day off
    watch.take(Status("gw", skewed))
    assert abs(watch.now() - NOW) < 1
    row = next(line for line in lines(watch, 120) if line.startswith("76 "))
    assert " 42s " in row, row


def test_without_utf_8_the_ellipsis_is_a_tilde() -> None:
    watch = Watch("gw", status=status(node(name="a very long name for a node")))
    shown = [line.plain for line in frame(watch, NOW, 0.5, 40, ellipsis="~")]
    assert all(line.isascii() for line in shown), shown
    assert any("~" in line for line in shown)


def test_only_the_nodes_asked_for_are_drawn() -> None:
    watch = Watch("gw", nodes=(77,), status=status(node(), node(77)))
    assert [line[:3] for line in lines(watch, 100) if line[:2].isdigit()] == ["77 "]


TEXT = st.text(st.characters(blacklist_categories=("Cs", "Cc")), max_size=40)
ANYTHING = st.one_of(st.none(), st.booleans(), st.integers(-10**9, 10**9),
                     st.floats(allow_nan=True), TEXT)


@settings(max_examples=150, deadline=None)
@given(nodes=st.lists(st.fixed_dictionaries({"node": ANYTHING, "name": ANYTHING,
                                             "state": ANYTHING, "record": ANYTHING,
                                             "rate_hz": ANYTHING, "expected_hz": ANYTHING,
                                             "rssi": ANYTHING, "last_seen": ANYTHING,
                                             "health": ANYTHING, "reasons": ANYTHING}),
                      max_size=4),
       width=st.integers(20, 200), port=TEXT, made=ANYTHING, silent=st.booleans())
def test_no_line_is_ever_wider_than_the_terminal(nodes: list[dict[str, Any]], width: int,
                                                 port: str, made: Any, silent: bool) -> None:
    """Whatever a gateway (of any version) sends, nothing wraps and nothing fails."""
    report = status(*nodes)
    report["link"]["port"] = port
    report["gateway"]["time"] = made
    watch = Watch("tcp://gw:5555")
    watch.take(Status("tcp://gw:5555", report))
    for line in frame(watch, watch.now(), 10.0 if silent else 0.5, width):
        assert cell_len(line.plain) <= width, (width, line.plain)
        assert "\n" not in line.plain


def test_nodes_that_do_not_fit_the_terminals_height_are_counted_not_dropped() -> None:
    """Issue 21: 30 nodes at 80x24 lost nodes 119-129 with no sign, and the 'q quits'
    line with them: the frame keeps to the height less the footer's line, its last row
    counting what it could not show."""
    nodes = [node(100 + i) for i in range(30)]
    drawn = [line.plain for line in frame(Watch("tcp://gw:5555", status=status(*nodes)),
                                          NOW, 0.5, 80, height=24)]
    assert len(drawn) <= 23
    shown = [line for line in drawn if line[:3].isdigit()]
    assert drawn[-1] == f"+{30 - len(shown)} more"
    assert [int(line.split()[0]) for line in shown] == list(range(100, 100 + len(shown)))


def test_reasons_give_way_to_nodes_and_a_frame_that_fits_is_whole() -> None:
    nodes = [node(76), node(77, health="WARN", reasons=["RSSI -93 dBm"])]
    watch = Watch("tcp://gw:5555", status=status(*nodes))
    whole = [line.plain for line in frame(watch, NOW, 0.5, 100)]
    assert [line.plain for line in frame(watch, NOW, 0.5, 100, height=40)] == whole
    tight = [line.plain for line in frame(watch, NOW, 0.5, 100, height=len(whole))]
    assert "77 WARN: RSSI -93 dBm" not in tight and tight[-1].startswith("77 ")
