"""gx2-sim end to end: a client on the real pseudo-terminal, as the gateway would be.

Every test opens the simulator's pty (or its symlink) with pyserial at 115200 baud,
writes command packets and raw pings, and decodes what comes back with
:class:`aspp.Decoder`. The simulator's objects are not used to learn what was sent; they
are read afterwards (node state, station statistics) to check that the bytes on the line
and the simulated world agree, and touched only to act as the world would (a reboot, an
unplug, a stream ended so that the line falls quiet).
"""

from __future__ import annotations

import contextlib
import itertools
import math
import os
import time
from collections import Counter
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import serial

from aspp import (
    TICKS_PER_SECOND,
    Ack,
    Decoder,
    Discarded,
    DiscardReason,
    Event,
    Frame,
    Nack,
    PingOk,
    Reply,
    TimerUnwrapper,
    decode,
)
from aspp import commands as gx2
from aspp.frame import encode_ping
from aspp.stop import GaveUp, SendStop, Stopped, StopPolicy, WaitUntil
from aspp.timing import TIMER_MODULUS
from gateway.sim.base_station import BaseStation, LineFaults, RadioLink
from gateway.sim.node import FIRMWARE_VERSION, GX2, INERTIA_LINK, NodeSettings
from gateway.sim.physics import EARTH_FIELD
from gateway.sim.server import Simulator
from tests.helpers.waiting import wait_for

BAUD = 115200
LINE_BYTES_PER_SECOND = BAUD / 10  # 8N1
READ_SLICE = 0.01
"""Each read waits at most this long; an empty read means the line was quiet."""
DEADLINE = 10.0
"""Seconds a test waits for what normally arrives within milliseconds. Only a broken
simulator reaches it: a loaded CI machine stalls a thread for a second or more, and a
stall must delay a test, not fail it."""

Predicate = Callable[[list[Event]], bool]


# -- the client ---------------------------------------------------------------------------


class Client:
    """A host on the pty: short pyserial reads, fed to one decoder; keeps a log of every
    read and every event with the monotonic time its read returned."""

    def __init__(self, path: str | Path) -> None:
        self.ser = serial.Serial(str(path), BAUD, timeout=READ_SLICE)
        self.decoder = Decoder()
        self.reads: list[tuple[float, bytes]] = []
        self.log: list[tuple[float, Event]] = []

    def send(self, data: bytes) -> None:
        self.ser.write(data)

    def read_once(self) -> list[Event]:
        """One read of at most READ_SLICE; a quiet line resolves what the decoder holds."""
        data = self.ser.read(4096)
        now = time.monotonic()
        if data:
            self.reads.append((now, data))
            events = self.decoder.feed(data)
        else:
            events = self.decoder.line_idle()
        self.log.extend((now, event) for event in events)
        return events

    def read_events(self, until: Predicate | None = None,
                    timeout: float = DEADLINE) -> list[Event]:
        """Read until ``until(events read by this call)`` holds and return those events;
        raise TimeoutError at the deadline. Without ``until``: read for ``timeout`` s."""
        deadline = time.monotonic() + timeout
        seen: list[Event] = []
        while True:
            seen.extend(self.read_once())
            if until is not None and until(seen):
                return seen
            if time.monotonic() >= deadline:
                if until is None:
                    return seen
                raise TimeoutError(f"condition not met within {timeout} s; got {summary(seen)}")

    def close(self) -> None:
        self.ser.close()


def summary(events: list[Event]) -> str:
    counts: Counter[str] = Counter()
    for e in events:
        if isinstance(e, Reply):
            counts[f"Reply({e.node}, 0x{e.command:02X})"] += 1
        elif isinstance(e, Frame):
            counts[f"Frame({e.node}, flags 0x{e.flags:02X})"] += 1
        elif isinstance(e, Discarded):
            counts[f"Discarded({e.reason})"] += 1
        else:
            counts[type(e).__name__] += 1
    return ", ".join(f"{k} x{v}" for k, v in counts.items()) or "nothing"


def is_reply(event: Event, node: int, command: int | None = None) -> bool:
    return (isinstance(event, Reply) and event.node == node
            and (command is None or event.command == command))


def replies(events: list[Event], node: int, command: int | None = None) -> list[Reply]:
    return [e for e in events if is_reply(e, node, command)]  # type: ignore[misc]


def reply_from(node: int, command: int | None = None, count: int = 1) -> Predicate:
    return lambda events: len(replies(events, node, command)) >= count


def has(kind: type) -> Predicate:
    return lambda events: any(isinstance(e, kind) for e in events)


def transact(client: Client, node: int, command: gx2.Command,
             timeout: float = DEADLINE) -> tuple[list[Event], Reply]:
    """Send ``command`` to ``node``; read until the node's reply (echo = command byte)."""
    client.send(command.packet(node))
    events = client.read_events(reply_from(node, command.code), timeout)
    return events, replies(events, node, command.code)[0]


def start_streaming(client: Client, node: int, record: str) -> Reply:
    """0xC4 with a record; returns the 0xC4 echo after checking it."""
    events, echo = transact(client, node, gx2.set_continuous(record))
    assert echo.command == 0xC4 and Ack() in events
    rec = decode(echo.payload)
    assert rec.name == "continuous_mode"
    assert rec["continuous_command"] == gx2.lookup(record).code
    return echo


def norm(v: object) -> float:
    return math.sqrt(sum(x * x for x in v))  # type: ignore[attr-defined]


def start_streams(sim: Simulator, addresses: tuple[int, ...], record: str) -> float:
    """Start ``record`` streaming at the nodes themselves (as auto-start would) from now
    on, all in step; return when. For a test that counts bytes from the moment its client
    opened the port: opening flushes what was waiting, and a pty nobody read is full."""
    command = gx2.set_continuous(record)

    def start(station: BaseStation, now: float) -> float:
        for address in addresses:
            node = station.nodes[address]
            node.run_until(now)  # an idle node's cycles before now produce nothing
            node.execute(command, now)
        return now

    return sim.call(start)


# -- fixtures -----------------------------------------------------------------------------


class Sims:
    """Starts simulators; each is stopped (once) and checked for a loop error."""

    def __init__(self) -> None:
        self.running: list[Simulator] = []

    def start(self, nodes: list[NodeSettings], **kwargs: object) -> Simulator:
        sim = Simulator(nodes, **kwargs).start()  # type: ignore[arg-type]
        self.running.append(sim)
        return sim

    def stop(self, sim: Simulator) -> None:
        self.running.remove(sim)
        sim.stop()
        assert sim.error is None, f"simulator loop failed: {sim.error!r}"


class Clients:
    def __init__(self) -> None:
        self.open_clients: list[Client] = []

    def open(self, path: str | Path) -> Client:
        client = Client(path)
        self.open_clients.append(client)
        return client

    def close(self, client: Client) -> None:
        self.open_clients.remove(client)
        client.close()


@pytest.fixture
def sims() -> Iterator[Sims]:
    pool = Sims()
    yield pool
    errors = []
    for sim in list(pool.running):
        pool.running.remove(sim)
        sim.stop()
        if sim.error is not None:
            errors.append(sim.error)
    assert errors == [], f"simulator loop failed: {errors!r}"


@pytest.fixture
def clients(sims: Sims) -> Iterator[Clients]:  # closed before the simulators stop
    pool = Clients()
    yield pool
    for client in pool.open_clients:
        client.close()


# -- 1. polled commands -------------------------------------------------------------------


IL, G2 = 76, 77  # an Inertia-Link and a 3DM-GX2, both polled


@pytest.fixture
def polled(sims: Sims, clients: Clients) -> tuple[Simulator, Client]:
    sim = sims.start([NodeSettings(IL), NodeSettings(G2, model=GX2, divider=1024,
                                                      serial="SN-0077")])
    return sim, clients.open(sim.path)


def polled_reply(client: Client, node: int, command: gx2.Command) -> Reply:
    """A polled node answers with the ACK, then exactly one reply echoing the command."""
    events, reply = transact(client, node, command)
    assert events == [Ack(), reply], summary(events)
    assert reply.command == command.code
    assert reply.lqi > 0 and -128 <= reply.rssi < 0
    return reply


def test_polled_data_records_are_plausible(polled: tuple[Simulator, Client]) -> None:
    sim, client = polled
    for node in (IL, G2):
        motion = sim.node(node).settings.motion
        rec = decode(polled_reply(client, node, gx2.poll("accel_angrate")).payload)
        assert rec.name == "accel_angrate"
        assert norm(rec["accel"]) == pytest.approx(1.0, abs=0.01)
        assert norm(rec["ang_rate"]) == pytest.approx(motion.yaw_rate, abs=0.01)
        since_power_up = time.monotonic() - sim.node(node).powered_at
        assert 0 < rec.timer / TICKS_PER_SECOND <= since_power_up

        rec = decode(polled_reply(client, node, gx2.poll("euler")).payload)
        assert rec.name == "euler"
        assert rec["roll"] == pytest.approx(motion.roll, abs=1e-4)
        assert rec["pitch"] == pytest.approx(motion.pitch, abs=1e-4)
        assert -math.pi <= rec["yaw"] <= math.pi

        rec = decode(polled_reply(client, node, gx2.poll(
            "accel_angrate_mag_orientation")).payload)
        m = rec["orientation"]
        for i in range(3):  # orthonormal: M M^T = I
            for j in range(3):
                dot = sum(m[i][k] * m[j][k] for k in range(3))
                assert dot == pytest.approx(1.0 if i == j else 0.0, abs=1e-5)
        # at rest the accelerometers see gravity: M . (0, 0, -1 g)
        assert rec["accel"] == pytest.approx([-m[0][2], -m[1][2], -m[2][2]], abs=1e-5)
        if node == IL:
            assert all(math.isnan(x) for x in rec["mag"]), "an Inertia-Link has no magnetometer"
        else:
            assert all(math.isfinite(x) for x in rec["mag"])
            assert norm(rec["mag"]) == pytest.approx(norm(EARTH_FIELD), abs=1e-4)
    # nothing more arrives: each command was answered exactly once
    assert client.read_events(timeout=0.06) == []
    assert sim.station.stats.acks == 6 and sim.station.stats.nacks == 0


def test_polled_identity_and_eeprom(polled: tuple[Simulator, Client]) -> None:
    sim, client = polled
    for node, model, name, divider in ((IL, INERTIA_LINK, "Inertia-Link", 512),
                                       (G2, GX2, "3DM-GX2", 1024)):
        assert sim.node(node).settings.model == model
        rec = decode(polled_reply(client, node, gx2.firmware_version()).payload)
        assert rec.name == "firmware_version" and rec["version"] == FIRMWARE_VERSION
        texts = {}
        for selector in range(4):
            rec = decode(polled_reply(client, node, gx2.device_id(selector)).payload)
            assert rec.name == "device_id" and rec["selector"] == selector
            text = rec["text"]
            assert isinstance(text, str) and text and text == text.rstrip(" \x00")
            texts[selector] = text
        assert texts[2] == name
        rec = decode(polled_reply(client, node, gx2.read_eeprom(gx2.EEPROM_DIVIDER)).payload)
        assert rec.name == "eeprom_read" and rec["value"] == divider
    assert texts[1] == "SN-0077"  # the configured serial number, node 77

    rec = decode(polled_reply(client, IL, gx2.write_eeprom(0x0100, 0xBEEF)).payload)
    assert rec.name == "eeprom_write" and rec["value"] == 0xBEEF
    rec = decode(polled_reply(client, IL, gx2.read_eeprom(0x0100)).payload)
    assert rec["value"] == 0xBEEF
    rec = decode(polled_reply(client, G2, gx2.read_eeprom(0x0100)).payload)
    assert rec["value"] != 0xBEEF, "the write went to node 76 only"
    assert client.read_events(timeout=0.06) == []


# -- 2. continuous mode at a known rate ---------------------------------------------------


def stream_timing(client: Client, since: int, node: int, command: int
                  ) -> tuple[list[float], list[int]]:
    """Arrival times and timers of ``node``'s ``command`` records logged after ``since``."""
    times, timers = [], []
    for t, e in client.log[since:]:
        if is_reply(e, node, command):
            times.append(t)
            timers.append(decode(e.payload).timer)
    return times, timers


def check_rate(times: list[float], timers: list[int], divider: int) -> None:
    """Every record of the stream, one period apart in the node's own time, over most
    of the second the test read for.

    Arrival times are not checked: on a loaded machine a stalled reader gets a burst
    later, and the rate they imply swings by 20%. The node's timer is the sim's clock,
    and nothing is lost between it and the pty (the tests check no drops), so timer
    steps of exactly one period are the rate."""
    period_ticks = round(divider / 51200 * TICKS_PER_SECOND)
    steps = [(b - a) % TIMER_MODULUS for a, b in itertools.pairwise(timers)]
    assert steps and all(abs(s - period_ticks) <= 1 for s in steps), \
        f"timer steps {sorted(set(steps))} are not all {period_ticks} (lost or repeated records)"
    assert len(times) == len(timers)
    assert sum(steps) / TICKS_PER_SECOND > 0.8, "a second's records, not a few"


def has_records(node: int, command: int, count: int) -> Predicate:
    return lambda events: len(replies(events, node, command)) >= count


def test_two_streams_at_their_rates_and_a_poll_in_between(sims: Sims, clients: Clients) -> None:
    sim = sims.start([NodeSettings(76, divider=512), NodeSettings(77, model=GX2, divider=1024),
                      NodeSettings(78)])
    client = clients.open(sim.path)
    start_streaming(client, 76, "accel_angrate")
    start_streaming(client, 77, "euler")
    assert (sim.node(76).continuous, sim.node(77).continuous) == (0xC2, 0xCE)
    mark = len(client.log)

    client.read_events(has_records(77, 0xCE, 25))  # half a second
    events, reply = transact(client, 78, gx2.poll("accel_angrate_orientation"))
    assert events.count(Ack()) == 1
    assert replies(events, 78) == [reply]
    assert decode(reply.payload).name == "accel_angrate_orientation"
    client.read_events(has_records(77, 0xCE, 30))  # and 0.6 s more

    logged = [e for _, e in client.log[mark:]]
    assert replies(logged, 78) == [reply], "node 78 answered once and does not stream"
    assert sim.node(78).continuous == 0
    check_rate(*stream_timing(client, mark, 76, 0xC2), divider=512)
    check_rate(*stream_timing(client, mark, 77, 0xCE), divider=1024)
    for rec in map(decode, (e.payload for e in replies(logged, 77, 0xCE))):
        assert rec["roll"] == pytest.approx(sim.node(77).settings.motion.roll, abs=1e-4)
    assert not [e for e in logged if not isinstance(e, (Reply, Ack))], summary(logged)


def test_rate_follows_an_eeprom_divider_write(sims: Sims, clients: Clients) -> None:
    """What ``gx2ctl rate`` does: write 0xFCA2, then the stream runs at 51200/x Hz."""
    sim = sims.start([NodeSettings(76)])
    client = clients.open(sim.path)
    rec = decode(polled_reply(client, 76, gx2.set_divider(256)).payload)
    assert rec["value"] == 256
    start_streaming(client, 76, "accel_angrate")
    mark = len(client.log)
    client.read_events(has_records(76, 0xC2, 200))  # a second's worth
    check_rate(*stream_timing(client, mark, 76, 0xC2), divider=256)


# -- 3. stop under 0xFA loss --------------------------------------------------------------


def read_up_to_date(sim: Simulator, client: Client) -> float:
    """Read until the client has every byte the simulator has written, written at a
    moment the simulator had sent everything due (its thread was not behind); return
    that moment. Needs a client that has had every byte since the sim started (nothing
    flushed on opening). A stalled reader or simulator thread only delays the return."""

    def written_when_caught_up(station: BaseStation, now: float) -> tuple[float | None, int]:
        caught_up = now if station.next_due(now) > now else None
        return caught_up, station.stats.bytes_sent - sim.dropped_bytes

    deadline = time.monotonic() + DEADLINE
    while True:
        caught_up, written = sim.call(written_when_caught_up)
        while sum(len(data) for _, data in client.reads) < written:
            if time.monotonic() >= deadline:
                raise TimeoutError(f"{written} bytes written, not all read in {DEADLINE} s")
            client.read_once()
        if caught_up is not None:
            return caught_up
        if time.monotonic() >= deadline:
            raise TimeoutError(f"the simulator did not catch up in {DEADLINE} s")


def drive_stop(sim: Simulator, client: Client, node: int, timeout: float = 3 * DEADLINE
               ) -> Stopped | GaveUp:
    """Run the gateway's stop policy against the real line until it decides.

    The policy proves a stop by silence, so it is never handed a time past the silence
    it waits for unless that silence is real: every byte the simulator wrote has been
    read (a stalled reader has records waiting in the pty) and the simulator has written
    everything due (a stalled simulator thread has records still to send). Packets are
    reported at the time their read returned."""
    policy = StopPolicy(sample_period=sim.node(node).period)
    reported = len(client.log)

    def report_packets() -> float | None:
        """Tell the policy about the node's packets read since last time; when the last
        was read, or None."""
        nonlocal reported
        last = None
        for t, e in client.log[reported:]:
            if not is_reply(e, node):
                continue
            rec = decode(e.payload)
            if rec.name == "continuous_mode" and rec["continuous_command"] == 0:
                policy.stop_confirmed(t)
            else:
                policy.packet_seen(t)
            last = t
        reported = len(client.log)
        return last

    give_up = time.monotonic() + timeout
    now = time.monotonic()
    while time.monotonic() < give_up:
        action = policy.next_action(now)
        if isinstance(action, (Stopped, GaveUp)):
            return action
        if isinstance(action, SendStop):
            client.send(action.command.packet(node))
            continue  # the policy now waits, from the same now
        assert isinstance(action, WaitUntil)
        client.read_once()
        packet_at = report_packets()
        clock = time.monotonic()
        if packet_at is not None:
            now = packet_at
        elif clock < action.deadline:
            now = clock
        else:  # the silence has lasted, as far as this thread can tell: make sure
            quiet_until = read_up_to_date(sim, client)
            packet_at = report_packets()
            now = quiet_until if packet_at is None else packet_at
    raise AssertionError("the stop policy did not decide in time")


def test_stop_is_retried_until_the_stream_is_silent(sims: Sims, clients: Clients) -> None:
    attempts_by_seed = {}
    for seed in range(1, 15):
        sim = sims.start([NodeSettings(76)], radio={76: RadioLink(stop_loss=0.5)}, seed=seed)
        client = clients.open(sim.path)
        start_streams(sim, (76,), "accel_angrate")  # as auto-start would, once the host reads
        client.read_events(reply_from(76, 0xC2, count=3))
        result = drive_stop(sim, client, 76)
        assert isinstance(result, Stopped), result
        assert sim.node(76).continuous == 0
        after = client.read_events(timeout=0.25)
        assert replies(after, 76) == [], f"seed {seed}: still streaming: {summary(after)}"

        # a ping answered: the base station has handled every command sent before it
        client.send(encode_ping(76))
        client.read_events(has(PingOk))
        stats = sim.station.stats
        stops = [c for c in sim.node(76).log.commands if c.code in (0xFA, 0xC4)]
        assert stats.acks == result.attempts, "every attempt was sent and ACKed"
        assert [e for _, e in client.log].count(Ack()) == result.attempts
        assert stats.commands_lost + len(stops) == result.attempts
        attempts_by_seed[seed] = result.attempts
        clients.close(client)
        sims.stop(sim)
        if result.attempts > 1:
            break
    assert max(attempts_by_seed.values()) > 1, \
        f"with half the stops lost, some seed must need a retry: {attempts_by_seed}"


# -- 4. ping ------------------------------------------------------------------------------


def test_ping_in_and_out_of_range(sims: Sims, clients: Clients) -> None:
    sim = sims.start([NodeSettings(76), NodeSettings(95, stream="accel_angrate")],
                     radio={95: RadioLink(in_range=False)})
    client = clients.open(sim.path)

    def ping(node: int) -> list[Event]:
        client.send(encode_ping(node))
        return client.read_events(lambda ev: bool(ev))

    assert ping(76) == [PingOk()]
    assert ping(95) == [Nack()]
    assert ping(1234) == [Nack()]  # no such node
    assert ping(76) == [PingOk()]
    assert sim.station.stats.pings == 4

    client.send(gx2.poll("accel_angrate").packet(95))
    events = client.read_events(has(Ack))
    events += client.read_events(timeout=0.2)
    assert events == [Ack()], "accepted by the base station, never answered by the node"
    assert sim.node(95).log.commands == []
    assert sim.station.stats.commands_lost == 1
    assert all(getattr(e, "node", None) != 95 for _, e in client.log), "95 is out of range"


# -- 5. NACK ------------------------------------------------------------------------------


def test_malformed_packets_are_nacked_and_not_delivered(sims: Sims, clients: Clients) -> None:
    sim = sims.start([NodeSettings(76)])
    client = clients.open(sim.path)
    node = sim.node(76)

    good = gx2.poll("accel_angrate").packet(76)
    bad_checksum = good[:-1] + bytes(((good[-1] + 1) & 0xFF,))
    # a bad SOP; this command's bytes hold no 0xAA or 0x02, where the station would resync
    bad_sop = b"\xab" + gx2.device_id(3).packet(76)[1:]
    assert not set(bad_sop[1:]) & {0xAA, 0x02}
    truncated = good[:5]  # the host stops mid-packet

    for bad in (bad_checksum, bad_sop, truncated):
        client.send(bad)
        events = client.read_events(has(Nack))
        events += client.read_events(timeout=0.05)
        assert events == [Nack()], f"{bad.hex(' ')}: {summary(events)}"
    assert node.log.commands == []
    assert sim.station.stats.commands_delivered == 0
    assert sim.station.stats.nacks == 3

    # a good packet right behind a bad one, in one write: NACK, ACK, and the reply
    client.send(bad_checksum + good)
    events = client.read_events(reply_from(76, 0xC2))
    assert events[:2] == [Nack(), Ack()] and is_reply(events[2], 76, 0xC2), summary(events)
    assert len(node.log.commands) == 1
    polled_reply(client, 76, gx2.poll("euler"))


# -- 6. the ACK glued to the next SOP -----------------------------------------------------


def test_ack_glued_to_the_next_packet(sims: Sims, clients: Clients) -> None:
    sim = sims.start([NodeSettings(76, stream="accel_angrate"), NodeSettings(77)],
                     line=LineFaults(glue_ack=True))
    client = clients.open(sim.path)
    client.read_events(reply_from(76, 0xC2, count=3))
    for node in (76, 77):
        first_read, first_event = len(client.reads), len(client.log)
        transact(client, node, gx2.firmware_version())
        reads = [data for _, data in client.reads[first_read:]]
        assert any(b"\xaa\xaa\x07" in data for data in reads), \
            "the ACK and the next packet's SOP arrive back to back in one read"
        assert b"\xaa" not in reads, "the ACK is never written alone"
        events = [e for _, e in client.log[first_event:]]
        assert events.count(Ack()) == 1
        after_ack = events[events.index(Ack()) + 1]
        assert isinstance(after_ack, Reply), summary(events)
        assert not [e for e in events if isinstance(e, (Discarded, Nack, Frame))]
    assert sim.station.stats.acks == 2


def test_pipelined_commands_get_one_glued_ack_each(sims: Sims, clients: Clients) -> None:
    sim = sims.start([NodeSettings(77)], line=LineFaults(glue_ack=True))
    client = clients.open(sim.path)
    client.send(gx2.firmware_version().packet(77) + gx2.device_id(0).packet(77))
    events = client.read_events(lambda ev: len(replies(ev, 77)) >= 2)
    events += client.read_events(timeout=0.1)
    assert events.count(Ack()) == 2, "one ACK after every command packet"
    assert [e.command for e in replies(events, 77)] == [0xE9, 0xEA]
    assert any(b"\xaa\xaa\xaa\x07" in data for _, data in client.reads)


# -- 7. line faults -----------------------------------------------------------------------


@pytest.mark.parametrize("bad_checksum", [0.0, 0.2], ids=["no-bad-checksums", "bad-checksums"])
def test_valid_packets_survive_line_faults(sims: Sims, clients: Clients,
                                           bad_checksum: float) -> None:
    sim = sims.start([NodeSettings(76)], seed=7,
                     line=LineFaults(garbage=0.2, bad_checksum=bad_checksum, false_header=0.2))
    client = clients.open(sim.path)  # (opening a port flushes what was waiting in it)
    start = gx2.set_continuous("accel_angrate")  # at the node, as if by auto-start
    sim.call(lambda station, now: station.nodes[76].execute(start, now))
    client.read_events(lambda ev: sim.station.stats.packets_sent.get(76, 0) >= 100, timeout=10)
    sim.call(lambda station, now: setattr(station.nodes[76], "continuous", 0))
    # read until all the station sent has arrived and it has nothing left to send (a
    # byte lost in the pty never arrives, so this fails at its deadline)
    deadline = time.monotonic() + 10
    while sim.call(lambda station, now: (station.backlog, station.stats.bytes_sent)) != (
            0, sum(len(data) for _, data in client.reads)):
        assert time.monotonic() < deadline, "the pty passes every byte, untouched"
        client.read_events(timeout=0.05)
    client.read_events(timeout=0.05)  # the line is idle: a lone trailing byte resolves
    events = [e for _, e in client.log]
    stats = sim.station.stats

    assert sim.dropped_bytes == 0 and stats.packets_dropped_full == 0
    received = sum(len(data) for _, data in client.reads)

    good = replies(events, 76, 0xC2)
    for reply in good:
        assert norm(decode(reply.payload)["accel"]) == pytest.approx(1.0, abs=0.01)
    timers = [decode(r.payload).timer for r in good]
    period_ticks = round(sim.node(76).period * TICKS_PER_SECOND)
    steps = [b - a for a, b in itertools.pairwise(timers)]
    assert all(s > 0 and s % period_ticks in (0, 1, period_ticks - 1) for s in steps)
    spanned = round((timers[-1] - timers[0]) / period_ticks) + 1
    sent = stats.packets_sent[76]
    assert sent >= 80

    discarded = [e for e in events if isinstance(e, Discarded)]
    reasons = {d.reason for d in discarded}
    assert {DiscardReason.GARBAGE, DiscardReason.TRUNCATED} <= reasons, summary(events)
    assert stats.faults_injected > 0
    if bad_checksum == 0:
        assert len(good) == sent, "every packet was valid, so every one is decoded"
        assert spanned == sent
    else:
        assert DiscardReason.BAD_CHECKSUM in reasons
        lost = sent - len(good)
        assert 0 < lost <= stats.faults_injected
        assert len(good) >= 0.6 * sent
        assert spanned - len(good) <= lost, "a missing record is a gap, never a duplicate"
    # everything read is accounted for: packets, control bytes, discarded runs
    accounted = sum(len(e.raw) for e in events if isinstance(e, (Reply, Frame)))
    accounted += sum(len(d.data) for d in discarded)
    accounted += sum(1 for e in events if isinstance(e, (Ack, Nack, PingOk)))
    assert accounted == received


# -- 8. unplug, replug, reboot -------------------------------------------------------------


def test_unplug_and_return(sims: Sims, clients: Clients, tmp_path: Path) -> None:
    link = tmp_path / "gx2"
    sim = sims.start([NodeSettings(76, stream="accel_angrate")], link=link)
    assert sim.path == str(link)
    client = clients.open(link)
    client.read_events(reply_from(76, 0xC2, count=5))
    old_pty = os.readlink(link)
    assert old_pty == sim.port.path and old_pty.startswith("/dev/")

    unplugged_at = time.monotonic()
    sim.unplug(duration=0.5)
    assert not link.is_symlink() and not link.exists(), "the link goes with the device"
    # Linux: the pty's other end is gone, select() says readable and read() returns
    # nothing, which pyserial reports as a SerialException (not a timeout, not b"")
    with pytest.raises(serial.SerialException, match="returned no data"):
        client.read_events(lambda ev: False)

    wait_for(link.is_symlink, timeout=DEADLINE, what="the link reappears")
    back_at = time.monotonic()
    assert back_at - unplugged_at >= 0.45
    new_pty = os.readlink(link)
    assert new_pty == sim.port.path and os.path.exists(new_pty)
    # a new device: the old one (still held open here) stays dead
    assert new_pty != old_pty
    with pytest.raises(serial.SerialException):
        client.read_once()
    clients.close(client)

    client = clients.open(link)  # the same path as before
    client.read_events(reply_from(76, 0xC2, count=5))
    polled_reply_among_stream(client, 76, gx2.firmware_version())
    assert sim.error is None


def test_what_fell_due_while_unplugged_is_lost_however_late_the_loop(
        sims: Sims, clients: Clients, tmp_path: Path) -> None:
    """The simulator's loop kept from running for the whole outage (as the CPU once
    starved it): the records due while the plug was out are not sent after it is back."""
    link = tmp_path / "gx2"
    sim = sims.start([NodeSettings(76, stream="accel_angrate")], link=link)
    client = clients.open(link)
    client.read_events(reply_from(76, 0xC2, count=5))
    with sim._lock:  # (the loop takes it at every turn: it waits out the outage)
        unplugged = sim.station.nodes[76].timer_at(time.monotonic())
        sim.unplug()
        time.sleep(0.3)
        sim.replug()
        back = sim.station.nodes[76].timer_at(time.monotonic())
        clients.close(client)
        client = clients.open(link)  # (before the loop writes: opening flushes the pty)
    client.read_events(reply_from(76, 0xC2, count=5))
    timers = [decode(e.payload).timer for _, e in client.log if is_reply(e, 76, 0xC2)]
    # (a sample taken just before the replug may reach the line after it: 3 ms of radio
    # and 3.5 ms on the UART)
    inside = [t for t in timers if unplugged < t < back - 0.01 * TICKS_PER_SECOND]
    assert inside == [], f"{len(inside)} records due while unplugged were sent after"


def polled_reply_among_stream(client: Client, node: int, command: gx2.Command) -> Reply:
    events, reply = transact(client, node, command)
    assert events.count(Ack()) == 1 and len(replies(events, node, command.code)) == 1
    return reply


def test_reboot_announces_itself_and_restarts(sims: Sims, clients: Clients) -> None:
    sim = sims.start([NodeSettings(76), NodeSettings(77, stream="euler")])
    client = clients.open(sim.path)
    start_streaming(client, 76, "accel_angrate")
    client.read_events(lambda ev: len(replies(ev, 76, 0xC2)) >= 20)  # timers well past 0
    unwrap = TimerUnwrapper()
    for t, e in client.log:
        if is_reply(e, 77, 0xCE):
            unwrap.update(decode(e.payload).timer, t)

    # 76 was started by the host: a reboot ends its stream
    rebooted_by = time.monotonic()
    sim.reboot(76)
    events = client.read_events(has(Frame))
    frame = next(e for e in events if isinstance(e, Frame))
    assert frame.node == 76 and frame.flags == 0x00 and frame.is_discovery
    assert sim.node(76).continuous == 0
    after = client.read_events(timeout=0.15)
    assert replies(after, 76) == [], "no records from 76 after its discovery packet"
    reply = polled_reply_among_stream(client, 76, gx2.poll("accel_angrate"))
    timer = decode(reply.payload).timer / TICKS_PER_SECOND
    assert 0 < timer <= time.monotonic() - rebooted_by, "the timer restarted"

    # 77 streams from power-up (auto-start): after a reboot it streams again, from 0
    sim.reboot(77)

    def streaming_again(events: list[Event]) -> bool:
        # records sent before the reboot may still be on their way: count from the frame
        frames = [i for i, e in enumerate(events) if isinstance(e, Frame)]
        return bool(frames) and len(replies(events[frames[0]:], 77, 0xCE)) >= 5

    events = client.read_events(streaming_again)
    frames = [e for e in events if isinstance(e, Frame)]
    assert [f.node for f in frames] == [77] and frames[0].is_discovery
    after_frame = replies(events[events.index(frames[0]):], 77, 0xCE)
    timers = [decode(r.payload).timer for r in after_frame]
    assert timers[0] / TICKS_PER_SECOND < 0.1 and timers == sorted(timers)
    assert sim.node(77).continuous == 0xCE
    device_times = [unwrap.update(timer, time.monotonic()) for timer in timers]
    assert unwrap.resets == 1 and device_times == sorted(device_times)


# -- 9. timer wrap ------------------------------------------------------------------------


def test_timer_wraps_and_unwraps_monotonically(sims: Sims, clients: Clients) -> None:
    sim = sims.start([NodeSettings(76, stream="accel_angrate", timer_start=218.0)])
    client = clients.open(sim.path)
    # the node powers up (again) once the host listens, so its stream starts 0.45 s
    # before the wrap however long the port took to open
    sim.reboot(76)

    def since_power_up(log: list[tuple[float, Event]]) -> list[tuple[float, int]]:
        """(arrival, timer) of 76's records after its discovery packet."""
        frame = next((i for i, (_, e) in enumerate(log) if isinstance(e, Frame)), len(log))
        return [(t, decode(e.payload).timer) for t, e in log[frame:] if is_reply(e, 76, 0xC2)]

    def wrapped_and_more(_: list[Event]) -> bool:
        timers = [timer for _, timer in since_power_up(client.log)]
        drops = [i for i, (a, b) in enumerate(itertools.pairwise(timers)) if b < a]
        return bool(drops) and len(timers) - drops[0] > 10

    client.read_events(wrapped_and_more)
    seen = since_power_up(client.log)
    raw = [timer for _, timer in seen]
    assert max(raw) > TIMER_MODULUS - 0.1 * TICKS_PER_SECOND and min(raw) < 0.5 * TICKS_PER_SECOND
    unwrap = TimerUnwrapper()
    device = [unwrap.update(timer, t) for t, timer in seen]
    steps = [b - a for a, b in itertools.pairwise(device)]
    assert all(s == pytest.approx(sim.node(76).period, abs=2 / TICKS_PER_SECOND) for s in steps)
    assert unwrap.resets == 0
    assert device[0] == pytest.approx(218.0, abs=0.5) and device[-1] > 2**32 / TICKS_PER_SECOND


# -- 10. pacing ---------------------------------------------------------------------------


SATURATED_BAUD = 115200
"""The baud rate of the tests that saturate the line."""
SATURATED_BYTES_PER_SECOND = SATURATED_BAUD / 10  # 8N1


def saturating_nodes() -> list[NodeSettings]:
    """Three nodes that offer 3 * (51200 / 170) 88-byte packets a second, about 80 kB/s."""
    return [NodeSettings(a, model=GX2, divider=170) for a in (76, 77, 78)]


def test_a_saturated_line_is_paced_at_the_baud_rate(sims: Sims, clients: Clients) -> None:
    sim = sims.start(saturating_nodes(), baudrate=SATURATED_BAUD)
    assert 3 * (51200 / 170) * 88 > 5 * SATURATED_BYTES_PER_SECOND
    client = clients.open(sim.path)  # (opening a port flushes what was waiting in it)
    idle_before = sim.call(lambda station, now: station.stats.line_idle)
    started = start_streams(sim, (76, 77, 78), "accel_angrate_mag_orientation")

    def a_second_of_line_time_and_drops(_: list[Event]) -> bool:
        received = sum(len(data) for _, data in client.reads)
        return (received >= SATURATED_BYTES_PER_SECOND
                and sim.station.stats.packets_dropped_full > 0)

    client.read_events(a_second_of_line_time_and_drops)
    last = client.reads[-1][0]
    received = sum(len(data) for _, data in client.reads)
    # no byte leaves the UART before its time: a hard bound since the streams started
    assert received <= SATURATED_BYTES_PER_SECOND * (last - started) * 1.01 + 100
    # and the line is kept busy: its UART never waited for data while saturated
    # (model time: how promptly the test's threads run does not enter into it)
    assert sim.call(lambda station, now: station.stats.line_idle) == idle_before
    assert sim.dropped_bytes == 0, "the pty passed every byte the base station sent"
    events = [e for _, e in client.log]
    assert all(isinstance(e, Reply) for e in events), "whole packets are dropped, never parts"
    assert {e.node for e in events} == {76, 77, 78}  # type: ignore[union-attr]


@pytest.mark.parametrize("glue_ack", [False, True], ids=["separate-ack", "glued-ack"])
def test_commands_are_acked_on_a_saturated_line(sims: Sims, clients: Clients,
                                                glue_ack: bool) -> None:
    """The base station's buffer is full, so it drops packets from the nodes; the host
    still gets one ACK for each command it sends (the contract: after every command
    packet, one byte), behind the backlog (at most 4096 bytes)."""
    sim = sims.start([*saturating_nodes(), NodeSettings(79)], baudrate=SATURATED_BAUD,
                     line=LineFaults(glue_ack=glue_ack))
    client = clients.open(sim.path)
    start_streams(sim, (76, 77, 78), "accel_angrate_mag_orientation")
    client.read_events(lambda ev: sim.station.stats.packets_dropped_full > 0)
    seen: list[Event] = []
    for _ in range(8):
        client.send(gx2.firmware_version().packet(79))
        seen += client.read_events(timeout=0.03)
    try:
        client.read_events(lambda ev: (seen + ev).count(Ack()) >= 8)
    except TimeoutError:
        acked = [e for _, e in client.log].count(Ack())
        pytest.fail(f"8 commands sent, {acked} ACKs arrived (the station counted "
                    f"{sim.station.stats.acks}; the pty dropped {sim.dropped_bytes} bytes)")


# -- the Simulator object itself ------------------------------------------------------------


def test_stopping_twice_leaves_other_descriptors_alone(tmp_path: Path) -> None:
    link = tmp_path / "gx2"
    with Simulator([NodeSettings(76)], link=link) as sim:
        assert link.is_symlink()
    assert not link.is_symlink() and sim.error is None
    r, w = os.pipe()  # likely reuses the numbers the simulator's descriptors had
    try:
        sim.stop()  # again, as a fixture's teardown after a with block would
        try:
            os.write(w, b"x")
            assert os.read(r, 1) == b"x"
        except OSError as error:
            pytest.fail(f"a second stop() closed descriptors it no longer owns: {error}")
    finally:
        for fd in (r, w):
            with contextlib.suppress(OSError):
                os.close(fd)
