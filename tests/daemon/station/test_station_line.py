"""A station's line and its nodes' clocks together: held and released as the line's
judge says, whatever the nodes a reload added or removed meanwhile (pure: the station
is not opened; its reads are handed in as the link would)."""

from __future__ import annotations

import types

from gateway.daemon.config import NodeEntry, StationConfig
from gateway.daemon.station.station import Station


class Line:
    """A station of nodes 76 and 77, each read once a second with the wait given."""

    def __init__(self) -> None:
        config = StationConfig(port="/dev/ttyUSB9",
                               nodes=[NodeEntry(address=76), NodeEntry(address=77)])
        self.station = Station(config, types.SimpleNamespace(publish=lambda *a: True),
                               channels=("r", "w"), replays_marks=False,
                               on_link_state=lambda *a: None, on_replay_end=lambda *a: None,
                               floor_unseen_s=60.0)
        self.station.link = types.SimpleNamespace(bytes_read=0)
        self.station._on_data = lambda *a: None
        self.now = 0.0
        for node in self.station.nodes.values():
            node.clock.update(0.0, 0.0)  # (a first packet that did not wait: a floor)

    def second(self, wait: float) -> None:
        """A second of reads in which every node's fastest packet waited ``wait``."""
        for node in self.station.nodes.values():
            node._least_wait = wait
        self.now += 1.0
        self.station.link.bytes_read += 10000
        self.station._read(b"x" * 10000, self.now, self.now)


def test_a_node_added_while_the_line_is_held_is_held_and_released_with_it() -> None:
    line = Line()
    for wait in [0.0, 0.0, 0.0, 0.0, 0.2, 0.3, 0.3, 0.3]:
        line.second(wait)
    station = line.station
    assert station.line.over and all(n.clock.held for n in station.nodes.values())
    added = station.add_node(NodeEntry(address=78))  # a reload, meanwhile
    assert added.clock.held  # (it would learn the queue)
    for wait in [0.0, 0.0]:
        line.second(wait)  # the queue drained: released, no clock asked twice
    assert not station.line.over
    assert not any(n.clock.held for n in station.nodes.values())


def test_a_release_leaves_a_clock_that_is_not_held_as_it_is() -> None:
    """A release of a clock that was never held raised (ClockStateError): out of the
    loop that judged the line, or out of a lost link before it was reopened."""
    line = Line()
    for wait in [0.0, 0.0, 0.0, 0.0, 0.2, 0.3, 0.3, 0.3]:
        line.second(wait)
    station = line.station
    station.nodes[77].clock.release()  # (as a node whose clock is not held)
    station.line.link_down()
    station._line_changed()
    assert not any(n.clock.held for n in station.nodes.values())


def test_a_held_line_that_falls_silent_has_room_again() -> None:
    """Every stream stopped while the line was held: nothing more is read to close a bin
    with, and the line stayed over capacity for good. A live line reading nothing for
    two seconds of the gateway's once-a-second sampling has no queue."""
    line = Line()
    for wait in [0.0, 0.0, 0.0, 0.0, 0.2, 0.3, 0.3, 0.3]:
        line.second(wait)
    station = line.station
    station.link = types.SimpleNamespace(bytes_read=station.link.bytes_read)
    station.replaying = False
    station.sample()  # (the first: its count taken)
    station.sample()  # a second with nothing read: after a host stall, maybe the backlog
    assert station.line.over  # (not yet read)
    station.sample()
    assert not station.line.over
    assert not any(n.clock.held for n in station.nodes.values())


def test_the_clocks_learn_nothing_while_a_queue_is_being_confirmed(caplog) -> None:
    """Bins of the queue's evidence before CONFIRM: the clocks paused (a young line
    steps onto the queue's slope otherwise, before anything is said), then held from
    the line as it stood; a stall's one bin of waiting, then falling waits, lets them
    learn again at once, and a lost link takes the suspicion with the queue."""
    line = Line()
    station = line.station
    clocks = [n.clock for n in station.nodes.values()]
    for wait in [0.0, 0.0, 0.0, 0.0]:
        line.second(wait)
    assert not any(c.paused for c in clocks)
    line.second(0.2)
    assert station.line.suspect and all(c.paused and not c.held for c in clocks)
    for clock in clocks:  # a packet faster than the line: a learning line lowers to it
        clock.update(4.0, 3.999)
        assert clock.estimate().offset == 0.0
    assert station.add_node(NodeEntry(address=78)).clock.paused  # (a reload, meanwhile)
    clocks = [n.clock for n in station.nodes.values()]
    assert "room again" not in caplog.text  # (nothing was said: nothing is unsaid)
    station._link_state(False)
    assert not station.line.suspect and not any(c.paused for c in clocks)
    station.scheduler.link_up = True
    line.second(0.2)  # (the first bin after a replug has no last wait to stand on)
    line.second(0.2)
    assert all(c.paused for c in clocks)
    line.second(0.1)  # falling: a stall's backlog, not a queue
    assert not station.line.suspect and not any(c.paused for c in clocks)
    learner = clocks[0]
    learner.update(8.0, 7.998)
    assert learner.estimate().offset < 0.0
    for wait in [0.2, 0.3, 0.3]:
        line.second(wait)
    assert station.line.over and not station.line.suspect
    assert all(c.held and not c.paused for c in clocks)


def test_a_clock_held_before_its_line_locked_says_so_at_once() -> None:
    """A node a reload adds while the queue is being confirmed anchors its line on its
    first packet, which waited in the queue; held from there, its ``time`` is late by
    the queue while the held line's allowance grows from 0. Its health says so from
    the hold, as a node's rebooted into the queue does (it once said nothing for 15 s:
    an outside review)."""
    from gateway.daemon.health import LINE_OVER_CAPACITY, clock_reasons
    line = Line()
    station = line.station
    for wait in [0.0, 0.0, 0.0, 0.0, 0.2]:
        line.second(wait)
    assert station.line.suspect
    added = station.add_node(NodeEntry(address=78))
    for i in range(50):  # half a second of its packets, each 0.2 s behind the queue
        added.clock.update(i / 100, line.now + i / 100 + 0.2, waited=True)
    for wait in [0.3, 0.3]:
        line.second(wait)
    assert station.line.over and added.clock.held and not added.clock.locked
    assert added.clock.held_error() < 0.5e-3  # (the line's movement only: not its offset)
    assert clock_reasons(added) == [LINE_OVER_CAPACITY]



def test_a_line_silent_while_a_queue_is_confirmed_lets_its_clocks_learn_after() -> None:
    """Every stream stopped (or the host stalled) while the queue was being confirmed:
    the bins the next read closes, nothing read in them, end the suspicion, and the
    clocks are told (they once stayed paused for good, as the change went unreported:
    an outside review)."""
    for silence in (3.0, 10.0):
        line = Line()
        for wait in [0.0, 0.0, 0.0, 0.0, 0.2]:
            line.second(wait)
        station = line.station
        assert station.line.suspect
        line.now += silence  # (nothing read meanwhile)
        line.second(0.0)
        assert not station.line.suspect and not station.line.over
        assert not any(n.clock.paused for n in station.nodes.values()), silence
