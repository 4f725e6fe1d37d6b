"""The stream decoder, case by case: bytes in, exactly these events out.

Every case in ``CASES`` is fed whole, split in two at every split point, and byte by
byte, each followed by ``line_idle()``; all three must give exactly the expected events
(the decoder promises that chunking never matters). The expected ``Discarded`` events
are written out byte for byte with their reason, so these tests pin the rules in the
module docstring of :mod:`aspp.decoder`, not just "something was dropped".

Three rules from that docstring shape many expectations: a candidate with a plausible
reply header (flags 0x07, app type 0x00, unused byte 0x00, length 2..102, node
1..65534) is decided by its checksum alone, so a cut reply waits for the bytes it
claims; any other candidate gives way at once to a valid packet that starts inside it
and completes first. A checksum-valid packet needs a node address of 1..65534. Between
packets, 0x21 is a NACK and 0x02 a ping answer only when it stands alone: its run of
non-packet bytes (which ends at the next 0xAA, or when the line goes idle) is that one
byte. Inside a longer run they are garbage like the rest of it.
"""

from __future__ import annotations

from collections.abc import Callable

import pytest

from aspp import records
from aspp.decoder import MAX_DISCARD, Decoder
from aspp.events import (
    Ack,
    Discarded,
    DiscardReason,
    Event,
    Frame,
    Nack,
    PingOk,
    Reply,
)
from aspp.frame import (
    FLAGS_DISCOVERY,
    NACK,
    PING,
    SOP,
    checksum,
    reply_packet_size,
)
from tests.helpers.decoding import decode_chunks as run
from tests.helpers.decoding import represented, stats_for
from tests.helpers.packets import pkt, raw_packet

GARBAGE = DiscardReason.GARBAGE
BAD_CHECKSUM = DiscardReason.BAD_CHECKSUM
BAD_ADDRESS = DiscardReason.BAD_ADDRESS
TRUNCATED = DiscardReason.TRUNCATED

AA = bytes((SOP,))
NK = bytes((NACK,))
PG = bytes((PING,))

LONGEST_PACKET = reply_packet_size(0xFF)  # 265 bytes: the length byte is 0xFF
MAX_REPLY_LENGTH = 102  # the longest length byte of a plausible reply header


# --- packets used by the cases --------------------------------------------------------

ACCEL = pkt(records.encode("accel_angrate", accel=(0.0, 0.0, -1.0),
                           ang_rate=(0.01, -0.02, 0.03), timer=123456))
EULER = pkt(records.encode("euler", roll=0.1, pitch=-0.2, yaw=1.5, timer=999),
            node=77, lqi=0x50, rssi=-60)
FIRMWARE = pkt(records.encode("firmware_version", version=4105))
ORIENT = pkt(records.encode("accel_angrate_orientation", accel=(0, 0, -1),
                            ang_rate=(0, 0, 0),
                            orientation=((1, 0, 0), (0, 1, 0), (0, 0, 1)), timer=5),
             node=300)
DISCOVERY = pkt(b"\x00\x01\x02\x03", flags=FLAGS_DISCOVERY)
COMMAND_FLAGS_FRAME = pkt(b"\xe9", flags=0x0B)
NO_ECHO = pkt(b"")  # flags 0x07 but not even an echo byte: a Frame, not a Reply

# A reply whose data holds every byte that means something between packets, including
# a whole false header (AA 07 00 00 4C FF) and an ACK-looking AA AA pair.
TRICKY_DATA = pkt(b"\xc2" + b"\xaa\x21\xaa\xaa\x02\xaa\x07\x00\x00\x4c\xff\x21\x02"
                  + bytes(range(16)))
FROM_AAAA = pkt(records.encode("firmware_version", version=4105), node=0xAAAA)
LQI_RSSI_AA = pkt(records.encode("firmware_version", version=4105), lqi=0xAA, rssi=-86)
CK_LSB_AA = pkt(records.encode("eeprom_read", value=0x006E))  # checksum 0x01AA


def _frame_with_checksum(target: int, node: int = 76) -> bytes:
    """A discovery frame (flags 0x00) whose checksum is ``target``, and LQI and RSSI
    0xAA: 0xFF filler plus one odd byte. No plausible reply (length <= 102) can sum to
    0xAAAA, so this one is a long frame."""
    for filler in range(254):
        head = checksum(bytes((0x00, 0x00, node >> 8, node & 0xFF, filler + 2, 0x00)))
        rest = target - head - 0xFF * filler
        if 0 <= rest <= 0xFF:
            return pkt(b"\xff" * filler + bytes((rest,)), node=node, lqi=0xAA, rssi=-86,
                       flags=FLAGS_DISCOVERY)
    raise AssertionError(f"no frame has checksum 0x{target:04X}")


CK_AAAA = _frame_with_checksum(0xAAAA)
LONG_DISCOVERY = pkt(bytes(range(1, 61)), node=95, flags=FLAGS_DISCOVERY)
LONG_0x07 = pkt(b"\xc2" + bytes(range(1, 111)))  # length byte 112: not a plausible reply
UNUSED_BYTE_SET = raw_packet(0x07, 76, b"\xe9\x00\x00\x10\x09", unused=0x01)

# A checksum-valid packet with a real node address, to hide inside other packets' data.
EMBEDDED = raw_packet(0x00, 1, b"")  # AA 00 00 00 01 01 00 00 00 00 02
ZERO_RUN = bytes((SOP,)) + bytes(9)  # checksum-valid, length 0, node 0: BAD_ADDRESS
NODE_FFFF = raw_packet(0x07, 0xFFFF, b"\xe9\x00\x00\x10\x09")
DISCOVERY_HIDING = pkt(b"\x01\x02" + EMBEDDED + b"\x03\x04", node=95, flags=FLAGS_DISCOVERY)
REPLY_HIDING = pkt(b"\xc2" + EMBEDDED + ZERO_RUN + bytes(8))
DISCOVERY_HIDING_ZERO_RUN = pkt(b"\x01" + ZERO_RUN + b"\x03", node=95, flags=FLAGS_DISCOVERY)
PLAUSIBLE_FALSE_HEADER = ACCEL[:7]  # AA 07 00 00 4C 1E 00: claims 40 bytes
# No plausible reply header; they claim to end exactly where ACCEL after them ends, and
# one byte later.
ENDS_WITH_ACCEL = b"\xaa\x12\x34\x56\x78" + bytes((6 + len(ACCEL) - 10,))
ENDS_AFTER_ACCEL = b"\xaa\x12\x34\x56\x78" + bytes((6 + len(ACCEL) - 10 + 1,))


# Damaged packets. No fixture packet holds an 0xAA after its SOP (checked below), so a
# failed candidate's discarded run reaches exactly to the next packet's SOP.
CORRUPTED = ACCEL[:10] + b"\x55" + ACCEL[11:]          # one data byte changed
BAD_CK = ACCEL[:-1] + bytes(((ACCEL[-1] + 1) & 0xFF,))  # checksum off by one
INSERTED = ACCEL[:12] + b"\x55" + ACCEL[12:]            # one byte too many inside
FALSE_HEADER = b"\xaa\x07\x00\x00\x4c\xff"              # claims a 265-byte packet


def test_fixture_packets_are_what_the_cases_assume() -> None:
    plain = [ACCEL, EULER, FIRMWARE, ORIENT, DISCOVERY, COMMAND_FLAGS_FRAME, NO_ECHO,
             LONG_DISCOVERY, LONG_0x07, UNUSED_BYTE_SET, NODE_FFFF]
    for raw in plain:
        assert raw[0] == SOP and SOP not in raw[1:], raw.hex(" ")
    assert LONG_0x07[5] > MAX_REPLY_LENGTH and LONG_DISCOVERY[5] <= MAX_REPLY_LENGTH
    assert EMBEDDED.hex(" ") == "aa 00 00 00 01 01 00 00 00 00 02"
    assert checksum(ZERO_RUN[1:6]) == int.from_bytes(ZERO_RUN[-2:], "big")
    assert len(LONG_DISCOVERY) > 20 + len(FIRMWARE)  # a cut one ends beyond FIRMWARE
    assert len(ORIENT) == 20 + len(FIRMWARE) + len(ACCEL)
    assert len(ORIENT) > 20 + len(FIRMWARE)       # a cut ORIENT ends beyond FIRMWARE
    assert len(FIRMWARE) < 8 + len(ACCEL)         # a cut FIRMWARE ends inside ACCEL
    assert FROM_AAAA[3:5] == b"\xaa\xaa"
    assert LQI_RSSI_AA[-4:-2] == b"\xaa\xaa"
    assert CK_LSB_AA[-1] == SOP and CK_LSB_AA.count(SOP) == 2
    assert CK_AAAA[-4:] == b"\xaa\xaa\xaa\xaa" and SOP not in CK_AAAA[1:-4]
    assert SOP not in CORRUPTED[1:] and SOP not in INSERTED[1:] and SOP not in BAD_CK[1:]


# --- helpers --------------------------------------------------------------------------

def d(data: bytes, reason: DiscardReason) -> Discarded:
    return Discarded(data, reason)


# --- the table ------------------------------------------------------------------------

CASES: list[tuple[str, bytes, list[Event]]] = [
    ("single reply", ACCEL, [Reply(ACCEL)]),
    ("two replies back to back", ACCEL + EULER, [Reply(ACCEL), Reply(EULER)]),
    ("ack glued to a reply (AA AA 07 ...)", AA + ACCEL, [Ack(), Reply(ACCEL)]),
    ("reply then nack", ACCEL + NK, [Reply(ACCEL), Nack()]),
    ("ack between replies", ACCEL + AA + EULER, [Reply(ACCEL), Ack(), Reply(EULER)]),
    ("lone ack", AA, [Ack()]),
    ("lone nack", NK, [Nack()]),
    ("ping answered", PG, [PingOk()]),
    ("ping answers and nacks between packets", PG + ACCEL + NK + EULER + PG,
     [PingOk(), Reply(ACCEL), Nack(), Reply(EULER), PingOk()]),
    ("ping answers and nacks run together are garbage", PG + NK + PG,
     [d(PG + NK + PG, GARBAGE)]),
    ("ping answer between replies", ACCEL + PG + EULER,
     [Reply(ACCEL), PingOk(), Reply(EULER)]),
    ("discovery frame between replies", ACCEL + DISCOVERY + EULER,
     [Reply(ACCEL), Frame(DISCOVERY), Reply(EULER)]),
    ("other delivery flags are a frame", COMMAND_FLAGS_FRAME, [Frame(COMMAND_FLAGS_FRAME)]),
    ("flags 0x07 without an echo byte is a frame", NO_ECHO + ACCEL,
     [Frame(NO_ECHO), Reply(ACCEL)]),
    ("garbage before a packet", b"\x55\x66\x77" + ACCEL,
     [d(b"\x55\x66\x77", GARBAGE), Reply(ACCEL)]),
    ("garbage after a packet", ACCEL + b"\x55\x66",
     [Reply(ACCEL), d(b"\x55\x66", GARBAGE)]),
    # A lone 0x21 or 0x02 is one whose run of non-packet bytes is that byte alone; a
    # run ends only at the next 0xAA (or when the line goes idle).
    ("garbage runs do not stop at nack and ping bytes",
     b"\x55" + NK + b"\x66\x77" + PG + b"\x88",
     [d(b"\x55" + NK + b"\x66\x77" + PG + b"\x88", GARBAGE)]),
    ("nack inside garbage, then a packet", b"\x13\x21\x57" + ACCEL,
     [d(b"\x13\x21\x57", GARBAGE), Reply(ACCEL)]),
    ("lone nack between two packets", ACCEL + NK + EULER, [Reply(ACCEL), Nack(), Reply(EULER)]),
    ("nack then a packet", NK + ACCEL, [Nack(), Reply(ACCEL)]),
    ("nack then an ack then a packet", NK + AA + ACCEL, [Nack(), Ack(), Reply(ACCEL)]),
    ("two nacks run together are garbage", NK + NK, [d(NK + NK, GARBAGE)]),
    ("two ping answers run together are garbage", PG + PG + ACCEL,
     [d(PG + PG, GARBAGE), Reply(ACCEL)]),
    ("nack followed by garbage is garbage", NK + b"\x13", [d(NK + b"\x13", GARBAGE)]),
    ("garbage then a ping answer is garbage", ACCEL + b"\x13" + PG + EULER,
     [Reply(ACCEL), d(b"\x13" + PG, GARBAGE), Reply(EULER)]),
    ("trailing lone ping answer", ACCEL + PG, [Reply(ACCEL), PingOk()]),
    ("corrupted data byte, then a good packet", CORRUPTED + EULER,
     [d(CORRUPTED, BAD_CHECKSUM), Reply(EULER)]),
    ("byte inserted inside a packet, then a good packet", INSERTED + EULER,
     [d(INSERTED, BAD_CHECKSUM), Reply(EULER)]),
    ("bad checksum then a good packet", BAD_CK + EULER,
     [d(BAD_CK, BAD_CHECKSUM), Reply(EULER)]),
    # A failed candidate is discarded "with the bytes up to the next 0xAA", so a NACK
    # right after it goes with it.
    ("bad checksum, nack, good packet", BAD_CK + NK + EULER,
     [d(BAD_CK + NK, BAD_CHECKSUM), Reply(EULER)]),
    ("bad checksum at the end of the line", BAD_CK, [d(BAD_CK, BAD_CHECKSUM)]),
    # A cut reply keeps a plausible reply header, so it is decided by its checksum alone
    # and waits for the bytes it claims: here the line goes quiet first.
    ("cut reply, line quiet before its claimed end", ORIENT[:20] + FIRMWARE,
     [d(ORIENT[:20], TRUNCATED), Reply(FIRMWARE)]),
    ("cut reply whose claimed length is filled by what follows",
     ORIENT[:20] + FIRMWARE + ACCEL,
     [d(ORIENT[:20], BAD_CHECKSUM), Reply(FIRMWARE), Reply(ACCEL)]),
    ("cut reply whose claimed end falls inside the next packet", FIRMWARE[:8] + ACCEL,
     [d(FIRMWARE[:8], BAD_CHECKSUM), Reply(ACCEL)]),
    # A cut frame (no plausible reply header) gives way to the packet inside it.
    ("cut discovery frame gives way to the next packet", LONG_DISCOVERY[:20] + FIRMWARE,
     [d(LONG_DISCOVERY[:20], TRUNCATED), Reply(FIRMWARE)]),
    ("truncated packet at the end of the line", ACCEL + ORIENT[:30],
     [Reply(ACCEL), d(ORIENT[:30], TRUNCATED)]),
    ("header only at the end of the line", AA + b"\x07\x00", [d(AA + b"\x07\x00", TRUNCATED)]),
    ("false header (length 0xFF) then a valid packet", FALSE_HEADER + ACCEL,
     [d(FALSE_HEADER, TRUNCATED), Reply(ACCEL)]),
    ("false header inside garbage", b"\x55\xaa\x12\x34\x56\x78\xff\x99" + ACCEL,
     [d(b"\x55", GARBAGE), d(b"\xaa\x12\x34\x56\x78\xff\x99", TRUNCATED), Reply(ACCEL)]),
    ("two false headers then a valid packet", FALSE_HEADER + FALSE_HEADER + EULER,
     [d(FALSE_HEADER, TRUNCATED), d(FALSE_HEADER, TRUNCATED), Reply(EULER)]),
    ("false header, ack, valid packet", FALSE_HEADER + AA + EULER,
     [d(FALSE_HEADER, TRUNCATED), Ack(), Reply(EULER)]),
    ("trailing lone 0xAA is an ack", ACCEL + AA, [Reply(ACCEL), Ack()]),
    ("0xAA 0xAA then a packet", AA + AA + ACCEL, [Ack(), Ack(), Reply(ACCEL)]),
    ("data holding 0xAA, 0x21, 0x02 and a false header", TRICKY_DATA + NK,
     [Reply(TRICKY_DATA), Nack()]),
    ("reply from node 0xAAAA", FROM_AAAA + AA + FROM_AAAA,
     [Reply(FROM_AAAA), Ack(), Reply(FROM_AAAA)]),
    ("LQI and RSSI equal to 0xAA", LQI_RSSI_AA + EULER, [Reply(LQI_RSSI_AA), Reply(EULER)]),
    ("checksum LSB equal to 0xAA", CK_LSB_AA + CK_LSB_AA + AA,
     [Reply(CK_LSB_AA), Reply(CK_LSB_AA), Ack()]),
    ("frame whose LQI, RSSI and checksum are all 0xAA", CK_AAAA + AA + CK_AAAA,
     [Frame(CK_AAAA), Ack(), Frame(CK_AAAA)]),
    ("plausible false header then a packet", PLAUSIBLE_FALSE_HEADER + ACCEL,
     [d(PLAUSIBLE_FALSE_HEADER, BAD_CHECKSUM), Reply(ACCEL)]),
    ("flags 0x07 with a length byte above 102 is a frame", LONG_0x07 + ACCEL,
     [Frame(LONG_0x07), Reply(ACCEL)]),
    ("flags 0x07 with a nonzero unused byte is a frame", UNUSED_BYTE_SET,
     [Frame(UNUSED_BYTE_SET)]),
    ("zero run: checksum holds but node 0", ZERO_RUN + ACCEL,
     [d(ZERO_RUN, BAD_ADDRESS), Reply(ACCEL)]),
    ("checksum holds but node 0xFFFF", NODE_FFFF + EULER,
     [d(NODE_FFFF, BAD_ADDRESS), Reply(EULER)]),
    ("reply hiding a valid packet and a zero run in its data", REPLY_HIDING + NK,
     [Reply(REPLY_HIDING), Nack()]),
    ("discovery frame does not give way to a zero run (node 0)", DISCOVERY_HIDING_ZERO_RUN,
     [Frame(DISCOVERY_HIDING_ZERO_RUN)]),
    # "gives way to a valid packet that starts inside it and completes first": a packet
    # completing with the candidate's last byte does not complete first.
    ("false header ending with the packet after it", ENDS_WITH_ACCEL + ACCEL,
     [d(ENDS_WITH_ACCEL, BAD_CHECKSUM), Reply(ACCEL)]),
    ("false header ending one byte after the packet after it", ENDS_AFTER_ACCEL + ACCEL,
     [d(ENDS_AFTER_ACCEL, TRUNCATED), Reply(ACCEL)]),
    ("discovery frame gives way to a valid packet inside it", DISCOVERY_HIDING + ACCEL,
     [d(DISCOVERY_HIDING[:9], TRUNCATED), Frame(EMBEDDED), d(DISCOVERY_HIDING[20:], GARBAGE),
      Reply(ACCEL)]),
    # An 0xAA whose candidate fails is an ACK only when it stands alone; otherwise it
    # is discarded with the bytes up to the next 0xAA (decoder docstring).
    ("0xAA then garbage at the end of the line", AA + b"\x55", [d(AA + b"\x55", TRUNCATED)]),
    ("0xAA then a ping answer at the end of the line", AA + PG, [d(AA + PG, TRUNCATED)]),
    ("0xAA then garbage then a packet", AA + b"\x55" + ACCEL,
     [d(AA + b"\x55", BAD_CHECKSUM), Reply(ACCEL)]),
    ("garbage longer than MAX_DISCARD comes in pieces", b"\x55" * (MAX_DISCARD + 88),
     [d(b"\x55" * MAX_DISCARD, GARBAGE), d(b"\x55" * 88, GARBAGE)]),
    ("garbage of nacks and ping answers longer than MAX_DISCARD comes in pieces",
     (NK + PG) * 300 + ACCEL,
     [d((NK + PG) * (MAX_DISCARD // 2), GARBAGE),
      d((NK + PG) * (300 - MAX_DISCARD // 2), GARBAGE), Reply(ACCEL)]),
    ("a failed candidate's run is cut at MAX_DISCARD too",
     BAD_CK + b"\x55" * 500 + ACCEL,
     [d(BAD_CK + b"\x55" * (MAX_DISCARD - len(BAD_CK)), BAD_CHECKSUM),
      d(b"\x55" * (500 - MAX_DISCARD + len(BAD_CK)), GARBAGE), Reply(ACCEL)]),
    ("a long mixed stream",
     b"\x01" + AA + ACCEL + DISCOVERY + NK + FALSE_HEADER + EULER + BAD_CK + AA + FIRMWARE
     + PG + ORIENT[:25],
     [d(b"\x01", GARBAGE), Ack(), Reply(ACCEL), Frame(DISCOVERY), Nack(),
      d(FALSE_HEADER, TRUNCATED), Reply(EULER), d(BAD_CK, BAD_CHECKSUM), Ack(),
      Reply(FIRMWARE), PingOk(), d(ORIENT[:25], TRUNCATED)]),
]

CHUNKINGS: dict[str, Callable[[bytes], list[list[bytes]]]] = {
    "whole": lambda data: [[data]],
    "halves": lambda data: [[data[:i], data[i:]] for i in range(len(data) + 1)],
    "bytewise": lambda data: [[data[i:i + 1] for i in range(len(data))]],
}


@pytest.mark.parametrize("chunking", list(CHUNKINGS))
@pytest.mark.parametrize(("data", "expected"), [pytest.param(c[1], c[2], id=c[0])
                                                for c in CASES])
def test_case(data: bytes, expected: list[Event], chunking: str) -> None:
    assert represented(expected) == data, "the case's expectation must cover its input"
    for chunks in CHUNKINGS[chunking](data):
        events, decoder = run(chunks)
        where = [len(c) for c in chunks]
        assert events == expected, f"chunk sizes {where}"
        assert decoder.pending == 0
        assert decoder.stats == stats_for(expected)


def test_case_names_are_unique() -> None:
    names = [name for name, _, _ in CASES]
    assert len(names) == len(set(names))


# --- when events come out -------------------------------------------------------------

def test_reply_behind_false_header_comes_out_without_idle() -> None:
    decoder = Decoder()
    assert decoder.feed(FALSE_HEADER + ACCEL) == [d(FALSE_HEADER, TRUNCATED), Reply(ACCEL)]
    assert decoder.pending == 0
    assert decoder.line_idle() == []


def test_reply_behind_false_header_comes_out_on_its_last_byte() -> None:
    decoder = Decoder()
    stream = FALSE_HEADER + ACCEL
    for i, byte in enumerate(stream[:-1]):
        assert decoder.feed(bytes((byte,))) == [], f"byte {i}"
        assert decoder.pending == i + 1
    assert decoder.feed(stream[-1:]) == [d(FALSE_HEADER, TRUNCATED), Reply(ACCEL)]
    assert decoder.pending == 0


def test_reply_comes_out_on_its_last_byte() -> None:
    decoder = Decoder()
    assert decoder.feed(ACCEL[:-1]) == []
    assert decoder.pending == len(ACCEL) - 1
    assert decoder.feed(ACCEL[-1:]) == [Reply(ACCEL)]
    assert decoder.pending == 0


def test_cut_reply_delays_what_follows_by_at_most_its_claimed_length() -> None:
    decoder = Decoder()
    assert decoder.feed(ORIENT[:20] + FIRMWARE) == []
    assert decoder.pending == 20 + len(FIRMWARE)
    assert decoder.feed(ACCEL[:-1]) == []  # one byte short of ORIENT's claimed length
    assert decoder.feed(ACCEL[-1:]) == [d(ORIENT[:20], BAD_CHECKSUM), Reply(FIRMWARE),
                                        Reply(ACCEL)]
    assert decoder.pending == 0


def test_cut_frame_gives_way_without_waiting() -> None:
    decoder = Decoder()
    assert decoder.feed(LONG_DISCOVERY[:20] + FIRMWARE) == [
        d(LONG_DISCOVERY[:20], TRUNCATED), Reply(FIRMWARE)]
    assert decoder.pending == 0


def test_trailing_aa_waits_for_line_idle() -> None:
    decoder = Decoder()
    assert decoder.feed(ACCEL + AA) == [Reply(ACCEL)]
    assert decoder.pending == 1
    assert decoder.feed(b"") == []
    assert decoder.pending == 1
    assert decoder.line_idle() == [Ack()]
    assert decoder.pending == 0
    assert decoder.stats.acks == 1


def test_aa_then_aa_is_an_ack_at_once() -> None:
    decoder = Decoder()
    assert decoder.feed(AA) == []
    assert decoder.pending == 1
    assert decoder.feed(AA) == [Ack()]
    assert decoder.pending == 1  # the second 0xAA may be an SOP
    assert decoder.feed(ACCEL[1:]) == [Reply(ACCEL)]
    assert decoder.pending == 0


def test_garbage_run_waits_for_its_end() -> None:
    # A run of non-packet bytes ends at the next 0xAA: a NACK byte does not end it.
    decoder = Decoder()
    assert decoder.feed(b"\x55\x66") == []
    assert decoder.pending == 2
    assert decoder.feed(NK) == []
    assert decoder.pending == 3
    assert decoder.feed(AA) == [d(b"\x55\x66" + NK, GARBAGE)]
    assert decoder.pending == 1  # the 0xAA may be an SOP
    assert decoder.feed(ACCEL[1:]) == [Reply(ACCEL)]
    assert decoder.pending == 0
    assert decoder.stats.nacks == 0


def test_garbage_run_ends_at_line_idle() -> None:
    decoder = Decoder()
    assert decoder.feed(b"\x55" + PG) == []
    assert decoder.pending == 2
    assert decoder.line_idle() == [d(b"\x55" + PG, GARBAGE)]
    assert decoder.pending == 0
    assert decoder.stats.ping_oks == 0


def test_lone_nack_waits_for_the_next_byte() -> None:
    decoder = Decoder()
    assert decoder.feed(ACCEL + NK) == [Reply(ACCEL)]
    assert decoder.pending == 1
    assert decoder.feed(b"") == []
    assert decoder.pending == 1
    assert decoder.feed(AA) == [Nack()]
    assert decoder.pending == 1  # the 0xAA may be an SOP
    assert decoder.feed(EULER[1:]) == [Reply(EULER)]
    assert decoder.pending == 0
    assert decoder.stats.nacks == 1


def test_nack_then_packet_comes_out_without_idle() -> None:
    decoder = Decoder()
    assert decoder.feed(NK + ACCEL) == [Nack(), Reply(ACCEL)]
    assert decoder.pending == 0
    assert decoder.line_idle() == []
    assert decoder.stats.nacks == 1


def test_trailing_lone_ping_answer_waits_for_line_idle() -> None:
    decoder = Decoder()
    assert decoder.feed(PG) == []
    assert decoder.pending == 1
    assert decoder.feed(b"") == []
    assert decoder.line_idle() == [PingOk()]
    assert decoder.pending == 0
    assert decoder.stats.ping_oks == 1


def test_nack_followed_by_any_other_byte_is_garbage() -> None:
    for follower in (NK, PG, b"\x13", b"\x00"):
        decoder = Decoder()
        assert decoder.feed(NK) == []
        assert decoder.feed(follower) == [], follower.hex()
        assert decoder.pending == 2
        assert decoder.line_idle() == [d(NK + follower, GARBAGE)], follower.hex()
        assert decoder.pending == 0
        assert (decoder.stats.nacks, decoder.stats.ping_oks) == (0, 0)


def test_unfinished_packet_is_truncated_at_line_idle() -> None:
    decoder = Decoder()
    assert decoder.feed(ACCEL[:-1]) == []
    assert decoder.line_idle() == [d(ACCEL[:-1], TRUNCATED)]
    assert decoder.pending == 0
    assert decoder.feed(ACCEL) == [Reply(ACCEL)]


def test_line_idle_with_nothing_pending() -> None:
    decoder = Decoder()
    assert decoder.line_idle() == []
    assert decoder.feed(ACCEL) == [Reply(ACCEL)]
    assert decoder.line_idle() == []
    assert decoder.line_idle() == []


# --- bounded memory -------------------------------------------------------------------

def test_longest_unfinished_packet_is_held_whole() -> None:
    decoder = Decoder()
    held = FALSE_HEADER + bytes(LONGEST_PACKET - len(FALSE_HEADER) - 1)
    assert decoder.feed(held) == []
    assert decoder.pending == LONGEST_PACKET - 1
    # Complete now and its checksum fails: it is discarded with the bytes up to the
    # next 0xAA, so the run stays open until one comes.
    assert decoder.feed(b"\x00") == []
    assert decoder.pending == LONGEST_PACKET
    assert decoder.feed(ACCEL) == [d(held + b"\x00", BAD_CHECKSUM), Reply(ACCEL)]
    assert decoder.pending == 0


def test_pending_never_exceeds_max_discard() -> None:
    decoder = Decoder()
    assert decoder.feed(b"\x55" * (MAX_DISCARD - 1)) == []
    assert decoder.pending == MAX_DISCARD - 1
    assert decoder.feed(b"\x55") == [d(b"\x55" * MAX_DISCARD, GARBAGE)]
    assert decoder.pending == 0
    assert decoder.feed(b"\x55" * (3 * MAX_DISCARD + 7)) == [
        d(b"\x55" * MAX_DISCARD, GARBAGE)] * 3
    assert decoder.pending == 7


def test_pending_never_exceeds_max_discard_in_a_run_of_nack_bytes() -> None:
    decoder = Decoder()
    assert decoder.feed(NK * (MAX_DISCARD - 1)) == []
    assert decoder.pending == MAX_DISCARD - 1
    assert decoder.feed(NK) == [d(NK * MAX_DISCARD, GARBAGE)]
    assert decoder.pending == 0
    assert decoder.stats.nacks == 0


# --- stats ----------------------------------------------------------------------------

def test_stats_for_a_mixed_stream() -> None:
    stream = (b"\x01" + AA + ACCEL + DISCOVERY + NK + FALSE_HEADER + EULER + BAD_CK + AA
              + FIRMWARE + PG + ORIENT[:25])
    decoder = Decoder()
    decoder.feed(stream[:50])
    decoder.feed(stream[50:])
    decoder.line_idle()
    stats = decoder.stats
    assert (stats.replies, stats.frames, stats.acks, stats.nacks, stats.ping_oks) == (
        3, 1, 2, 1, 1)
    assert stats.packets == 4
    assert stats.discarded_bytes == {GARBAGE: 1, BAD_CHECKSUM: len(BAD_CK), BAD_ADDRESS: 0,
                                     TRUNCATED: len(FALSE_HEADER) + 25}
    assert stats.discarded_runs == {GARBAGE: 1, BAD_CHECKSUM: 1, BAD_ADDRESS: 0,
                                    TRUNCATED: 2}
    assert stats.bytes_discarded == 1 + len(BAD_CK) + len(FALSE_HEADER) + 25


def test_stats_count_garbage_pieces_as_runs() -> None:
    decoder = Decoder()
    # Two pieces of one long run, two lone NACKs, and a NACK pair that is a garbage run.
    decoder.feed(b"\x55" * (MAX_DISCARD + 1) + ACCEL + NK + EULER + NK + FIRMWARE + NK + NK)
    decoder.line_idle()
    assert decoder.stats.discarded_bytes[GARBAGE] == MAX_DISCARD + 1 + 2
    assert decoder.stats.discarded_runs[GARBAGE] == 3
    assert decoder.stats.replies == 3 and decoder.stats.nacks == 2
    assert decoder.stats.bytes_discarded == MAX_DISCARD + 1 + 2


def test_stats_keep_running_across_line_idle() -> None:
    decoder = Decoder()
    for _ in range(3):
        decoder.feed(ACCEL + AA)
        decoder.line_idle()
    assert decoder.stats.replies == 3 and decoder.stats.acks == 3
    assert decoder.stats.bytes_discarded == 0


# --- the events read back -------------------------------------------------------------

def test_reply_fields_read_from_aa_heavy_packets() -> None:
    (reply,) = Decoder().feed(FROM_AAAA)
    assert isinstance(reply, Reply)
    assert reply.node == 0xAAAA and reply.command == 0xE9
    assert records.decode(reply.payload)["version"] == 4105
    (reply,) = Decoder().feed(LQI_RSSI_AA)
    assert (reply.node, reply.lqi, reply.rssi) == (76, 0xAA, -86)
    (reply,) = Decoder().feed(ACCEL)
    assert (reply.node, reply.command, reply.lqi, reply.rssi) == (76, 0xC2, 0x64, -44)
    assert records.decode(reply.payload)["timer"] == 123456


def test_frame_fields() -> None:
    (frame,) = Decoder().feed(DISCOVERY)
    assert isinstance(frame, Frame) and frame.is_discovery
    assert (frame.flags, frame.node, frame.payload) == (0x00, 76, b"\x00\x01\x02\x03")
    (frame,) = Decoder().feed(COMMAND_FLAGS_FRAME)
    assert isinstance(frame, Frame) and not frame.is_discovery and frame.flags == 0x0B


def test_events_are_type_strict() -> None:
    assert Ack() != Nack() and Nack() != PingOk()
    assert Reply(ACCEL) != Frame(ACCEL)
    assert Discarded(b"\x55", GARBAGE) != Discarded(b"\x55", TRUNCATED)
    assert [Ack(), Reply(ACCEL)] == [Ack(), Reply(ACCEL)]


# --- input types ----------------------------------------------------------------------

@pytest.mark.parametrize("kind", [bytes, bytearray, memoryview])
def test_feed_takes_any_bytes_like(kind: type) -> None:
    stream = AA + ACCEL + NK + EULER
    decoder = Decoder()
    events = decoder.feed(kind(stream))
    assert events == [Ack(), Reply(ACCEL), Nack(), Reply(EULER)]
    assert type(events[1].raw) is bytes and type(events[3].raw) is bytes
    assert decoder.pending == 0


def test_feed_keeps_no_reference_to_a_mutable_input() -> None:
    decoder = Decoder()
    buffer = bytearray(ACCEL[:20])
    assert decoder.feed(buffer) == []
    buffer[:] = b"\x00" * 20
    events = decoder.feed(ACCEL[20:])
    assert events == [Reply(ACCEL)]
    assert type(events[0].raw) is bytes


@pytest.mark.parametrize("bad", ["\xaa\x07", "", 0xAA, None, [0xAA]])
def test_feed_of_non_bytes_raises_type_error(bad: object) -> None:
    decoder = Decoder()
    decoder.feed(ACCEL[:10])
    with pytest.raises(TypeError):
        decoder.feed(bad)  # type: ignore[arg-type]
    assert decoder.pending == 10  # nothing was taken in
    assert decoder.feed(ACCEL[10:]) == [Reply(ACCEL)]


@pytest.mark.parametrize("tail", [b"\x21", b"\x02"])
@pytest.mark.parametrize("chunk", [1, 7, 4096])
def test_a_byte_left_after_a_cut_run_is_still_garbage(tail, chunk):
    """A run longer than MAX_DISCARD comes out in pieces; a single 0x21 or 0x02 left at
    its end belongs to the run, so it is garbage, not a NACK or ping answer."""
    stream = b"\x55" * MAX_DISCARD + tail + ACCEL
    decoder = Decoder()
    events = [e for i in range(0, len(stream), chunk) for e in decoder.feed(stream[i:i + chunk])]
    events += decoder.line_idle()
    assert events == [Discarded(b"\x55" * MAX_DISCARD, DiscardReason.GARBAGE),
                      Discarded(tail, DiscardReason.GARBAGE), Reply(ACCEL)]


# --- the fast path's checksum -----------------------------------------------------------

HEAVIEST_REPLY = pkt(b"\xff" * (MAX_REPLY_LENGTH - 1), node=0xFFFE)  # the largest sum


@pytest.mark.parametrize("chunking", ["whole", "bytes"])
def test_heaviest_reply_passes_the_fast_checksum(chunking: str) -> None:
    """The fast path checks a reply's sum with Adler-32, whose low half is 1 + the sum
    only while the sum stays below 65521: the largest sum a plausible reply can have
    must still come out, and the same packet one off must not."""
    assert checksum(HEAVIEST_REPLY[1:-4]) > 0x6000
    def chunks(data: bytes) -> list[bytes]:
        return [data] if chunking == "whole" else [bytes((b,)) for b in data]

    events, _ = run(chunks(HEAVIEST_REPLY + ACCEL))
    assert events == [Reply(HEAVIEST_REPLY), Reply(ACCEL)]
    for wrong in (1, -1, 65521 & 0xFFFF, 0x8000):
        bad = HEAVIEST_REPLY[:-2] + ((checksum(HEAVIEST_REPLY[1:-4]) + wrong) & 0xFFFF
                                     ).to_bytes(2, "big")
        events, _ = run(chunks(bad + ACCEL))
        assert events == [Discarded(bad, BAD_CHECKSUM), Reply(ACCEL)], hex(wrong)
