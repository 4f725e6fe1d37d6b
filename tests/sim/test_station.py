"""The simulated base station without a port, on a clock the test owns: ACK and NACK,
pings, radio loss, line pacing at the baud rate, faults and reboots."""

from __future__ import annotations

import random
from itertools import pairwise

import pytest

from aspp import (
    TICKS_PER_SECOND,
    Ack,
    Decoder,
    Discarded,
    Frame,
    Nack,
    PingOk,
    Reply,
    commands,
    decode,
)
from aspp.frame import encode_command_packet, encode_ping
from aspp.timing import DEFAULT_DIVIDER, sample_period
from gateway.sim.base_station import (
    BUFFER_BYTES,
    GLUE_WAIT,
    JITTER_MAX,
    PING_TIMEOUT,
    RADIO_LATENCY,
    BaseStation,
    LineFaults,
    RadioLink,
)
from gateway.sim.node import NodeSettings, SimNode

T0 = 50.0


class Bench:
    """A station, its nodes and a decoder on the host side, on a test-owned clock."""

    def __init__(self, *settings: NodeSettings, radio=None, line=None, seed=3):
        self.now = T0
        nodes = [SimNode(s, T0, random.Random(s.address)) for s in settings]
        self.station = BaseStation(nodes, radio, line, rng=random.Random(seed))
        self.decoder = Decoder()
        self.chunks: list[bytes] = []

    def send(self, data: bytes) -> None:
        self.station.from_host(data, self.now)

    def run(self, seconds: float, step: float = 0.001) -> list:
        events = []
        end = self.now + seconds
        while self.now < end:
            self.now = min(end, self.now + step)
            self.station.advance(self.now)
            chunk = self.station.take_output(self.now)
            if chunk:
                self.chunks.append(chunk)
                events += self.decoder.feed(chunk)
        return events + self.decoder.line_idle()


def replies(events, node=None):
    return [e for e in events if type(e) is Reply and (node is None or e.node == node)]


def test_ack_then_reply_and_nack_for_malformed():
    bench = Bench(NodeSettings(76))
    bench.send(commands.poll("euler").packet(76))
    events = bench.run(0.1)
    assert type(events[0]) is Ack and decode(replies(events)[0].payload).name == "euler"
    bad = bytearray(commands.poll("euler").packet(76))
    bad[-1] ^= 0xFF
    bench.send(bytes(bad))
    assert bench.run(0.1) == [Nack()]
    assert bench.station.nodes[76].log.commands == [commands.poll("euler")]


def test_ping_answers_in_range_out_of_range_and_unknown():
    bench = Bench(NodeSettings(76), NodeSettings(77), radio={77: RadioLink(in_range=False)})
    for node, answer in ((76, PingOk()), (77, Nack()), (300, Nack())):
        bench.send(encode_ping(node))
        assert bench.run(PING_TIMEOUT * 2) == [answer], node


def test_out_of_range_node_is_acked_but_never_answers():
    bench = Bench(NodeSettings(77), radio={77: RadioLink(in_range=False)})
    bench.send(commands.poll("euler").packet(77))
    assert bench.run(0.2) == [Ack()]
    assert bench.station.stats.commands_lost == 1


def test_radio_loss_of_commands_and_data():
    bench = Bench(NodeSettings(76, stream="euler"), NodeSettings(77),
                  radio={76: RadioLink(data_loss=0.3), 77: RadioLink(command_loss=1.0)})
    bench.send(commands.poll("euler").packet(77))
    events = bench.run(2.0)
    assert replies(events, 77) == []
    got = len(replies(events, 76))
    assert 100 < got < 170  # 200 records at 100 Hz, 30% lost
    assert got + bench.station.stats.packets_lost_radio == pytest.approx(200, abs=2)


def test_stop_loss_applies_to_0xfa_only():
    bench = Bench(NodeSettings(76, stream="euler"), radio={76: RadioLink(stop_loss=1.0)})
    bench.send(commands.stop_continuous().packet(76))
    bench.run(0.2)
    assert bench.station.nodes[76].continuous == 0xCE
    bench.send(commands.stop_continuous_long().packet(76))
    events = bench.run(0.2)
    assert bench.station.nodes[76].continuous == 0
    answers = [decode(r.payload) for r in replies(events)]
    assert [r["continuous_command"] for r in answers if r.name == "continuous_mode"] == [0]


def test_the_line_is_paced_at_the_baud_rate_and_a_full_buffer_drops():
    """Three nodes at ~301 Hz of 0xCC offer ~78 kB/s; 115200 8N1 carries 11,520 B/s."""
    settings = [NodeSettings(a, stream="accel_angrate_mag_orientation", divider=170)
                for a in (76, 77, 78)]
    bench = Bench(*settings)
    bench.run(0.5)  # fill the base station's buffer
    start = sum(map(len, bench.chunks))
    bench.run(1.0)
    assert sum(map(len, bench.chunks)) - start == pytest.approx(11_520, rel=0.02)
    assert bench.station.stats.packets_dropped_full > 0
    backlog = (bench.station._line_free_at - bench.now) * 11_520
    assert backlog <= BUFFER_BYTES


def test_a_station_that_leaves_gaps_reads_under_the_baud_rate_and_one_without_bound_keeps_all():
    """The FIFO line of the fault soak's second model: a saturated output reaching 90%
    of the baud rate, and a buffer without bound that queues what the line cannot carry
    (every packet kept, however late), where a bounded one drops."""
    settings = [NodeSettings(a, stream="accel_angrate_mag_orientation", divider=170)
                for a in (76, 77, 78)]
    bench = Bench(*settings, line=LineFaults(throughput=0.9, buffer_bytes=None))
    bench.run(0.5)
    start = sum(map(len, bench.chunks))
    bench.run(1.0)
    assert sum(map(len, bench.chunks)) - start == pytest.approx(0.9 * 11_520, rel=0.02)
    assert bench.station.stats.packets_dropped_full == 0
    assert bench.station.backlog > 10 * BUFFER_BYTES
    with pytest.raises(ValueError, match="throughput"):
        LineFaults(throughput=0.0)
    with pytest.raises(ValueError, match="buffer_bytes"):
        LineFaults(buffer_bytes=0)


def test_a_buffer_with_gaps_holds_its_size_in_bytes():
    settings = [NodeSettings(a, stream="accel_angrate_mag_orientation", divider=170)
                for a in (76, 77, 78)]
    bench = Bench(*settings, line=LineFaults(throughput=0.906, buffer_bytes=16384))
    most = 0
    for _ in range(300):
        bench.run(0.01)
        most = max(most, bench.station.backlog)
    assert bench.station.stats.packets_dropped_full > 0
    assert 16384 - 200 <= most <= 16384 + 200


def test_glued_ack_arrives_in_one_chunk_with_the_next_packet():
    bench = Bench(NodeSettings(76, stream="euler"), line=LineFaults(glue_ack=True))
    bench.run(0.05)
    bench.chunks.clear()
    bench.send(commands.poll("accel_angrate").packet(76))
    events = bench.run(0.1)
    assert any(chunk.startswith(b"\xaa\xaa\x07") for chunk in bench.chunks)
    assert Ack() in events and not any(type(e) is Discarded for e in events)


def test_a_lone_glued_ack_is_not_held_forever():
    bench = Bench(NodeSettings(76), line=LineFaults(glue_ack=True))
    bench.send(commands.set_divider(512).packet(76))
    bench.send(encode_command_packet(76, b"\xfa"))
    events = bench.run(GLUE_WAIT * 3)
    assert events.count(Ack()) == 2


@pytest.mark.parametrize("fault", ["garbage", "bad_checksum", "false_header"])
def test_line_faults_are_reported_and_good_packets_survive(fault):
    bench = Bench(NodeSettings(76, stream="euler"), line=LineFaults(**{fault: 0.3}))
    events = bench.run(2.0)
    good = len(replies(events))
    injected = bench.station.stats.faults_injected
    assert injected > 20 and any(type(e) is Discarded for e in events)
    if fault == "bad_checksum":
        assert good == pytest.approx(200 - injected, abs=2)
    else:
        assert good == pytest.approx(200, abs=2)  # garbage and false headers cost nothing


def test_reboot_announces_itself_and_restarts_the_timer():
    bench = Bench(NodeSettings(76, stream="euler"), NodeSettings(77))
    bench.send(commands.set_continuous("accel_angrate").packet(77))
    bench.run(3.0)
    for address in (76, 77):
        bench.station.reboot(address, bench.now)
    events = bench.run(0.5)
    discovery = [e for e in events if type(e) is Frame]
    assert sorted(f.node for f in discovery) == [76, 77]
    assert all(f.is_discovery for f in discovery)
    after = [decode(r.payload) for r in replies(events, 76)]
    assert after[0].timer < 0.05 * 19_660_800  # timer restarted at power-up
    assert bench.station.nodes[77].continuous == 0  # set by command: lost on reboot
    assert bench.station.nodes[76].continuous == 0xCE  # auto-start from EEPROM


@pytest.mark.parametrize("late", [0.0, 0.05], ids=["on-time", "late-caller"])
def test_a_reboot_is_announced_behind_what_the_node_sent_before_it(late):
    """The discovery packet is the node's: the records it sent before it lost power,
    still in the air or not yet on the line because the simulator's thread ran late, go
    on the line first. One that overtook it read as the restarted timer (issue 24:
    test_reboot_announces_itself_and_restarts saw 0.4 s after a reboot under load)."""
    period = sample_period(DEFAULT_DIVIDER)
    for offset in range(20):  # reboots at instants spread over a cycle
        bench = Bench(NodeSettings(77, stream="euler"), radio={77: RadioLink(jitter=0.004)})
        events = bench.run(0.4 + offset * period / 20)
        bench.now += late  # the station is told of the reboot this late
        rebooted_at = bench.now
        bench.station.reboot(77, rebooted_at)
        events += bench.run(0.1)
        frame = next(i for i, e in enumerate(events) if type(e) is Frame)
        before = [decode(r.payload).timer / TICKS_PER_SECOND for r in replies(events[:frame])]
        after = [decode(r.payload).timer / TICKS_PER_SECOND for r in replies(events[frame:])]
        assert after and max(after) < 0.1, (offset, after[:3])
        # and it ran until the power went: its records up to then reached the line (its
        # timer counts from T0, when the bench powered it up)
        assert before[-1] > rebooted_at - T0 - RADIO_LATENCY - period, (offset, before[-3:])


def test_nack_fault_refuses_good_packets_without_delivering_them():
    bench = Bench(NodeSettings(76), line=LineFaults(nack=1.0))
    bench.send(commands.poll("euler").packet(76))
    assert bench.run(0.1) == [Nack()]
    assert bench.station.nodes[76].log.commands == []


def test_a_cycles_replies_keep_their_order_on_the_line():
    """The continuous record, then the polled reply: even when the polled reply's bytes
    would sort first (C4 < CE), as the long-form stop's does."""
    bench = Bench(NodeSettings(76, stream="euler"))
    bench.run(0.05)
    bench.send(commands.stop_continuous_long().packet(76))
    names = [decode(r.payload).name for r in replies(bench.run(0.2))]
    assert names[-2:] == ["euler", "continuous_mode"]


def test_a_station_that_runs_late_sends_what_a_prompt_one_would():
    """The simulator's thread runs late on a loaded machine and catches up in one go. It
    must put the same bytes on the line, in the same order, as a station that ran on
    time: a ping answer due mid-way goes behind the records that reached the station
    before it, and a command reaches its node after the cycles before it."""

    def line(step: float) -> tuple[bytes, int]:
        bench = Bench(NodeSettings(76, stream="accel_angrate"), NodeSettings(77, stream="euler"))
        bench.run(0.5085, step)  # between cycles: records reach the station at .xx3 s
        bench.send(encode_ping(77))  # answered at .5145, after the record at .513
        bench.send(commands.poll("euler").packet(77))  # reaches 77 at .5115
        bench.run(1.0, step)
        return b"".join(bench.chunks), bench.station.stats.packets_dropped_full

    (prompt, dropped_prompt), (late, dropped_late) = line(step=0.001), line(step=0.8)
    events = Decoder().feed(prompt)
    assert PingOk() in events and "euler" in [decode(r.payload).name for r in replies(events)]
    assert dropped_prompt == dropped_late == 0
    assert late == prompt


def timed_replies(bench: Bench, seconds: float, step: float = 0.0002) -> list[tuple[float, Reply]]:
    """(when its last byte left the UART, reply) for each reply over ``seconds``."""
    out = []
    end = bench.now + seconds
    while bench.now < end:
        bench.now += step
        bench.station.advance(bench.now)
        chunk = bench.station.take_output(bench.now)
        out += [(bench.now, e) for e in bench.decoder.feed(chunk) if type(e) is Reply]
    return out


def test_each_record_arrives_the_radio_floor_and_a_random_part_after_it_was_sampled():
    """The truth the sample-time tests compare with: a node's ``sampled`` holds when
    each timer reading was taken; its packet reaches the host RADIO_LATENCY, plus an
    exponential part of mean ``jitter``, plus its own time on the line, after that."""
    bench = Bench(NodeSettings(76, stream="accel_angrate", divider=1024, ppm=25.0),
                  radio={76: RadioLink(jitter=0.0005)})
    got = timed_replies(bench, 20.0)
    sampled = bench.station.nodes[76].sampled
    line_time = 40 * bench.station.byte_time  # a 0xC2 packet: 40 bytes
    delays = [at - line_time - sampled[decode(r.payload).timer] for at, r in got]
    assert len(delays) > 900
    assert min(delays) >= RADIO_LATENCY - 1e-9
    assert min(delays) <= RADIO_LATENCY + 0.0003  # (the clock's step, 0.2 ms)
    assert sum(delays) / len(delays) - RADIO_LATENCY == pytest.approx(0.0006, abs=0.0002)
    assert max(delays) <= RADIO_LATENCY + JITTER_MAX + 0.0003
    timers = [decode(r.payload).timer for _, r in got]
    assert timers == sorted(timers), "a node's packets arrive in the order it sent them"
    # the instants are the node's cycles: 1024 / 51200 s of its own clock, 25 ppm fast
    instants = [sampled[t] for t in timers]
    assert (instants[-1] - instants[0]) / (len(instants) - 1) == pytest.approx(
        0.02 / (1 + 25e-6), rel=1e-9)


def test_a_stall_holds_the_output_back_then_sends_what_it_held():
    bench = Bench(NodeSettings(76, stream="accel_angrate", divider=512, ppm=0.0),
                  radio={76: RadioLink(jitter=0.0)}, line=LineFaults(stall_rate=2.0,
                                                                     stall_ms=60.0))
    got = timed_replies(bench, 30.0)
    gaps = [b - a for (a, _), (b, _) in pairwise(got)]
    stalls = bench.station.stats.stalls
    assert 30 <= stalls <= 100  # 2 a second on average
    # at 100 Hz a packet leaves every 10 ms unless the output is held back
    assert sum(1 for gap in gaps if gap > 0.040) == pytest.approx(stalls, abs=stalls // 5)
    assert max(gaps) <= 2 * 0.060 + 0.011
    assert bench.station.stats.packets_dropped_full == 0  # (the buffer holds 60 ms)
    # (what is still held back at the end: at most a stall's worth)
    assert 0 <= bench.station.stats.packets_sent[76] - len(got) <= 7
    quiet = Bench(NodeSettings(76, stream="accel_angrate", divider=512, ppm=0.0),
                  radio={76: RadioLink(jitter=0.0)})
    assert max(b - a for (a, _), (b, _) in pairwise(timed_replies(quiet, 5.0))) < 0.011


def test_a_node_switched_off_answers_nothing_until_it_powers_up_announcing_itself():
    """``powered: false``, then ``gx2-sim power NODE on``: a node added mid-study."""
    bench = Bench(NodeSettings(76, stream="euler"), NodeSettings(81, stream="euler",
                                                                 powered=False))
    bench.send(encode_ping(81))
    bench.send(commands.poll("euler").packet(81))
    events = bench.run(1.0)
    assert replies(events, 81) == [] and len(replies(events, 76)) > 90
    assert Nack() in events and PingOk() not in events  # no answer to the ping
    assert bench.station.nodes[81].log.commands == []  # it heard nothing
    assert not bench.station.power(81, False, bench.now)  # off already
    bench.station.reboot(81, bench.now)  # SIGUSR1: a node switched off stays off
    assert not [e for e in bench.run(0.5) if type(e) is Frame]

    assert bench.station.power(81, True, bench.now)
    events = bench.run(1.0)
    frames = [e for e in events if type(e) is Frame]
    assert [(f.node, f.is_discovery) for f in frames] == [(81, True)]
    streamed = replies(events, 81)  # what it auto-starts, from its power-up
    assert len(streamed) > 90 and events.index(frames[0]) < events.index(streamed[0])
    assert decode(streamed[0].payload).timer < 0.05 * TICKS_PER_SECOND

    assert bench.station.power(81, False, bench.now)
    bench.run(0.1)  # (what it sent before, still in the air, arrives)
    assert replies(bench.run(1.0), 81) == []
    bench.send(encode_ping(81))
    assert [e for e in bench.run(0.1) if type(e) is not Reply] == [Nack()]
