"""The memory of nodes heard that are not configured (:mod:`gateway.daemon.station.heard`),
fed packets as the base station sends them, through the reader: what each address
sent, its stream's rate from its timer, its signal, and the bound."""

from __future__ import annotations

import time
from types import SimpleNamespace

from aspp.frame import FLAGS_DISCOVERY, encode_reply_packet
from aspp.records import encode
from aspp.timing import TICKS_PER_CLOCK
from gateway.daemon.station import heard as heard_module
from gateway.daemon.station.heard import HEARD_MAX, LOG_BURST, LOG_WINDOW, Heard
from gateway.daemon.station.reader import Reader
from tests.helpers.wired import RecordingPublisher, one_node_reader

T0 = 1_800_000_000.0


def record(node: int, sample: int, divider: int = 512, rssi: int = -50,
           name: str = "accel_angrate") -> bytes:
    """Sample number ``sample`` of ``node``'s stream of ``name`` at ``divider``."""
    fields = ({"accel": (0, 0, -1), "ang_rate": (0, 0, 0)} if name == "accel_angrate"
              else {"roll": 0.0, "pitch": 0.0, "yaw": 0.0})
    return encode_reply_packet(node, encode(name, **fields,
                                            timer=sample * divider * TICKS_PER_CLOCK),
                               lqi=200, rssi=rssi)


def discovery(node: int) -> bytes:
    return encode_reply_packet(node, b"\x01\x00\x00\x08\x41", lqi=180, rssi=-70,
                               flags=FLAGS_DISCOVERY)


def reader() -> tuple[Reader, RecordingPublisher]:
    """A reader of one station with node 76 configured and streaming."""
    return one_node_reader(station="north")


def feed(got: Reader, *packets: bytes) -> None:
    for packet in packets:
        got.on_data(packet, T0, time.monotonic())


def heard(got: Reader) -> dict[int, dict]:
    return {h["address"]: h for h in got.heard.status(time.monotonic())}


def test_a_stream_of_a_node_not_configured_is_heard_with_its_record_and_rate() -> None:
    got, publisher = reader()
    # 81 streams at 50 Hz and loses samples over the air: its rate is its timer's
    # shortest step, not what arrives; 76 is configured, and never among those heard
    feed(got, *(record(81, s, divider=1024, rssi=-60 - s % 3) for s in (1, 3, 4, 7, 8, 11)),
         *(record(76, s) for s in range(1, 20)))
    assert set(heard(got)) == {81}
    assert len(publisher.records(76)) == 19 and publisher.records(81) == []
    entry = heard(got)[81]
    assert entry["record"] == "accel_angrate" and entry["rate_hz"] == 50.0
    assert entry["packets"] == 6 and entry["last_heard"] == T0 and entry["lqi"] == 200
    assert entry["rssi"] == -61.0  # the median of -61 -60 -61 -61 -62 -62
    assert got.unknown_node_packets == 6
    assert [node.address for node, _ in got.heard.streaming(time.monotonic())] == [81]


def test_replies_to_commands_and_a_discovery_are_heard_but_are_no_stream() -> None:
    got, _ = reader()
    feed(got, discovery(82), record(83, 5), record(83, 9))  # 83: two answers to a poll
    assert heard(got)[82]["record"] is None and heard(got)[82]["rate_hz"] is None
    assert heard(got)[82]["announced"] == T0 and heard(got)[82]["rssi"] == -70
    assert heard(got)[83]["record"] == "accel_angrate" and heard(got)[83]["rate_hz"] is None
    assert got.heard.streaming(time.monotonic()) == []
    # a temperatures record is no stream of accel_angrate's: the run starts again
    temperatures = encode_reply_packet(84, encode("temperatures", temperature=(1, 2, 3, 4),
                                                  timer=100), lqi=1, rssi=-1)
    feed(got, record(84, 1), record(84, 2), temperatures, record(84, 3))
    assert heard(got)[84]["record"] == "accel_angrate" and heard(got)[84]["rate_hz"] is None


def test_a_stream_that_stops_is_still_heard_but_no_longer_streams() -> None:
    got, _ = reader()
    feed(got, *(record(81, s) for s in range(1, 10)))
    now = time.monotonic()
    assert heard(got)[81]["rate_hz"] == 100.0
    # silent for 10 periods and at least a second: as a configured node's stream falls
    assert got.heard.streaming(now + 0.9) != []
    assert got.heard.streaming(now + 1.1) == []
    assert got.heard.status(now + 1.1)[0]["rate_hz"] is None


def test_a_power_up_forgets_what_it_streamed() -> None:
    got, _ = reader()
    feed(got, *(record(81, s) for s in range(1, 10)), discovery(81))
    entry = heard(got)[81]
    assert entry["record"] is None and entry["rate_hz"] is None and entry["packets"] == 10
    assert entry["discoveries"] == 1
    # it auto-starts another stream: its new rate, not the old one's shortest step
    feed(got, *(record(81, s, divider=5120) for s in range(1, 5)))
    assert heard(got)[81]["rate_hz"] == 10.0


def test_at_most_heard_max_addresses_the_one_heard_longest_ago_forgotten() -> None:
    memory = Heard("north")
    assert 100 <= HEARD_MAX <= 1000  # "some hundreds"
    for address in range(1, HEARD_MAX + 1):
        memory.reply(record(address, 1), T0 + address)
    memory.reply(record(1, 2), T0 + 1000)  # the first heard again: now the most recent
    for address in range(1001, 1011):
        memory.reply(record(address, 1), T0 + address)
    assert len(memory) == HEARD_MAX and memory.forgotten == 10
    kept = {entry["address"] for entry in memory.status(time.monotonic())}
    assert 1 in kept and set(range(2, 12)).isdisjoint(kept)
    assert {12, HEARD_MAX, *range(1001, 1011)} <= kept


def test_records_a_silence_apart_are_no_stream(monkeypatch) -> None:
    """A node that stopped streaming, then answers two polls of that record: a run of
    three records, but the first a silence before the others."""
    got, _ = reader()
    clock = [1000.0]
    monkeypatch.setattr(time, "monotonic", lambda: clock[0])
    for sample, at in ((1, 1000.0), (2, 1000.01), (3, 1000.02), (500, 1005.0), (900, 1009.0)):
        clock[0] = at
        got.on_data(record(81, sample), T0, at)
    assert got.heard.streaming(1009.0) == []
    assert got.heard.status(1009.0)[0]["record"] == "accel_angrate"


def test_each_address_is_logged_once_and_a_flood_of_them_as_a_count(caplog,
                                                                     monkeypatch) -> None:
    got, _ = reader()
    caplog.set_level("INFO", logger="gx2.heard")
    # a stream, read by a scan (a reply breaks the run), streaming again; then powered up
    temperatures = encode_reply_packet(81, encode("temperatures", temperature=(1, 2, 3, 4),
                                                  timer=100), lqi=1, rssi=-1)
    feed(got, *(record(81, i) for i in range(3)), temperatures,
         *(record(81, i) for i in range(3, 6)), discovery(81))
    assert [r.getMessage() for r in caplog.records] == [
        "base station north: node 81, not configured, streams accel_angrate on its channel"]
    # forgotten (configured, then not again): news of it is logged again
    got.heard.forget(81)
    feed(got, discovery(81))
    assert caplog.records[-1].getMessage().endswith("node 81, not configured, powered up")
    caplog.clear()
    # 2000 addresses powering up at once: a few lines, not 2000
    feed(got, *(discovery(a) for a in range(1000, 3000)))
    assert len(caplog.records) == LOG_BURST - 2  # (81 had two)
    assert len(got.heard) == HEARD_MAX
    # the next news after the window says how many were not logged
    caplog.clear()
    later = time.monotonic() + LOG_WINDOW + 1
    monkeypatch.setattr(heard_module, "time", SimpleNamespace(monotonic=lambda: later))
    feed(got, discovery(5000))
    assert [r.getMessage() for r in caplog.records] == [
        "base station north: 1992 more addresses not configured heard in 60 s, not "
        "logged one by one (gx2ctl status lists them)",
        "base station north: node 5000, not configured, powered up"]
