"""Samples missed while a base station was down, told apart from the radio's losses by
the gateway's status messages among the records (gateway.recording.losses, .outages):
pure code, fed payloads and statuses shaped as the gateway publishes them."""

from __future__ import annotations

import pytest

from gateway.recording.losses import STARTED, WINDOW, Counted, Losses
from gateway.recording.summary import Summary
from tests.recording.test_losses import STEP, sample

START = 1_780_000_000.0
"""UNIX time of sample 0."""
PERIOD = 0.01


def at(i: float) -> float:
    return START + i * PERIOD


def record(i: int, seq: int) -> dict:
    return {**sample(i, seq), "time": at(i), "host_time": at(i) + 0.004}


def status(i: float, north: tuple[str, float], south: tuple[str, float] = ("up", 0.0),
           *, several: bool = True) -> dict:
    """A status made at sample time ``i``, each station's (state, since in samples)."""
    links = {name: {"state": state, "since": at(since)}
             for name, (state, since) in (("north", north), ("south", south))}
    if not several:  # (a gateway of one base station that says only its link)
        return {"gateway": {"time": at(i)}, "link": links["north"],
                "nodes": [{"node": 76, "station": "north"}]}
    return {"gateway": {"time": at(i)},
            "link": links["north"],
            "stations": [{"name": name, **link} for name, link in links.items()],
            "nodes": [{"node": 76, "station": "north"}, {"node": 78, "station": "south"}]}


def run(events: list[tuple[int, int, dict] | dict], ahead: int) -> dict[int, list[Counted]]:
    """Each node's rows, counted from ``events`` (a record: (node, i, payload); a
    status: its payload), in order; a continuous-mode reply's row is left out."""
    losses: Losses[tuple[int, int]] = Losses(ahead)
    out: list[Counted] = []
    for event in events:
        if isinstance(event, dict):
            losses.status(event)
        else:
            node, i, payload = event
            out += losses.add(node, payload["record"], payload, (node, i))
    out += losses.finish()
    rows: dict[int, list[Counted]] = {}
    for row in sorted(out, key=lambda c: c.item):
        if row.item[1] < 0:
            continue
        rows.setdefault(row.item[0], []).append(row)
    return rows


def streams(missing: dict[int, set[int]], statuses: dict[int, dict],
            end: int = 600, replies: dict[int, float] | None = None,
            ) -> list[tuple[int, int, dict] | dict]:
    """Nodes 76 and 78 at 100 Hz, without their ``missing`` samples, a status before
    the samples given in ``statuses``, and node 76's continuous-mode reply (a start or
    a stop) at each time given in ``replies`` (in sample periods) before that sample."""
    events: list[tuple[int, int, dict] | dict] = []
    seq = {76: 0, 78: 0}
    for i in range(end):
        if i in statuses:
            events.append(statuses[i])
        if i in (replies or {}):
            seq[76] += 1
            when = replies[i]  # type: ignore[index]
            reply = {**sample(0, seq[76], STARTED, round(when * STEP)), "time": at(when)}
            events.append((76, -i, reply))
        for node in (76, 78):
            if i not in missing.get(node, set()):
                seq[node] += 1
                events.append((node, i, record(i, seq[node])))
    return events


def after(rows: list[Counted], i: int) -> Counted:
    """The row of sample ``i``."""
    return next(row for row in rows if row.item[1] == i)


OUTAGE = {
    # heartbeats, the status the moment north went (at 100.5) and the one it came back
    # (at 300.5); the nodes stream on, what was sent meanwhile never arrives
    50: status(50, ("up", 0)), 101: status(100.6, ("down", 100.5)),
    150: status(150, ("opening", 100.5)), 250: status(250, ("down", 100.5)),
    301: status(300.6, ("up", 300.5)), 400: status(400, ("up", 300.5)),
}


@pytest.mark.parametrize("ahead", [WINDOW, 0])
def test_what_a_stream_missed_while_its_station_was_down_is_not_the_radios(ahead):
    # node 76's station north is down from 100.5 to 300.5, and its stream comes back
    # 30 samples after that (its first 30 lost over the air); node 78, on south, loses
    # samples over the radio meanwhile; both lose some before and after too
    missing = {76: {*range(101, 331), 20, 21, 500}, 78: {*range(150, 160), 20, 500}}
    rows = run(streams(missing, OUTAGE), ahead)
    back = after(rows[76], 331)
    assert (back.lost, back.down, back.radio, back.gateway) == (230, 200, 30, 0)
    assert (after(rows[76], 22).radio, after(rows[76], 501).radio) == (2, 1)
    assert sum(row.down for row in rows[76]) == 200
    assert sum(row.down for row in rows[78]) == 0
    assert sum(row.radio for row in rows[78]) == 12

    summary = Summary()
    for row in rows[76]:
        summary.add(row)
    assert summary.line() == ("radio: 33 lost (5.50%), gateway: 0 lost (0.00%), "
                              "station down: 200 lost (33.33%)")
    assert summary.apart() == "station down: 200 lost"


def test_an_outage_whose_statuses_were_missed_is_told_by_the_since_of_the_next():
    # a subscriber that dropped the statuses of the outage: north was up at 50, and is
    # up at 320 since 300.5 (a heartbeat before its stream is back): it went down in
    # between, after the last status seen
    statuses = {50: status(50, ("up", 0)), 320: status(320, ("up", 300.5))}
    rows = run(streams({76: set(range(101, 331))}, statuses), WINDOW)
    back = after(rows[76], 331)
    assert (back.lost, back.down, back.radio) == (230, 200, 30)


def test_a_row_decided_before_its_station_is_seen_back_counts_the_outage_to_it():
    # counted as records come (gx2ctl record): the status of north's return was lost,
    # yet a record came through, so the station was back by then
    statuses = {50: status(50, ("up", 0)), 101: status(100.6, ("down", 100.5))}
    rows = run(streams({76: set(range(101, 331))}, statuses), 0)
    back = after(rows[76], 331)
    assert (back.lost, back.down, back.radio) == (230, 230, 0)


def test_a_gateway_of_one_station_says_its_outages_in_its_link():
    statuses = {i: {**event, "stations": None} for i, event in OUTAGE.items()}
    plain = {i: status(i, ("up", 0), several=False) for i in (50, 400)}
    plain[101] = status(100.6, ("down", 100.5), several=False)
    plain[301] = status(300.6, ("up", 300.5), several=False)
    for given in (statuses, plain):
        rows = run(streams({76: set(range(101, 331))}, given), WINDOW)
        assert (after(rows[76], 331).down, after(rows[76], 331).radio) == (200, 30)


def test_without_statuses_or_with_broken_ones_losses_are_the_radios():
    broken = {50: {"gateway": "x", "stations": [{"name": 3}, "north"], "nodes": [7, {}]},
              60: {"stations": 5, "link": [], "nodes": 9},
              101: {"stations": [{"name": "north", "state": "down", "since": "soon"}],
                    "nodes": [{"node": 76, "station": 5}]}}
    for statuses in ({}, broken):
        rows = run(streams({76: set(range(101, 331))}, statuses), WINDOW)
        assert (after(rows[76], 331).down, after(rows[76], 331).radio) == (0, 230)


@pytest.mark.parametrize("ahead", [WINDOW, 0])
def test_a_start_answered_before_the_stream_is_back_does_not_hide_the_outage(ahead):
    # north is back at 300.5 and the gateway starts node 76 again; its reply comes
    # (at 305.3) before its stream's first record (331): the node streamed on while
    # its station was down, so the silence was no stop and the gap is still counted
    rows = run(streams({76: set(range(101, 331))}, OUTAGE, replies={306: 305.3}), ahead)
    back = after(rows[76], 331)
    assert (back.lost, back.down, back.radio) == (230, 200, 30)


def test_a_stream_stopped_before_an_outage_and_started_after_it_lost_nothing():
    # a stop answered just after sample 100, north down from 100.5 to 300.5, the stream
    # started again at 330 (its reply in that cycle)
    rows = run(streams({76: set(range(101, 331))}, OUTAGE,
                       replies={101: 100.2, 331: 330.0}), WINDOW)
    back = after(rows[76], 331)
    assert (back.lost, back.down, back.radio) == (0, 0, 0)
