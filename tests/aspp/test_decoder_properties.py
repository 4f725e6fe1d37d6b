"""Property tests for the stream decoder and the record/command codecs (hypothesis).

The decoder must never raise, hold bounded memory, give the same events however a
stream is chunked, account for every byte exactly once, and let every valid packet
through garbage; every reply record and every command must survive a round trip
through the codecs (and, for replies, through a packet and the decoder).
"""

from __future__ import annotations

from itertools import pairwise

import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from aspp import commands, records
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
from aspp.fields import Field
from aspp.frame import (
    ACK,
    FLAGS_REPLY,
    MAX_NODE,
    MIN_NODE,
    NACK,
    PING,
    SOP,
    checksum,
    decode_command_packet,
    encode_reply_packet,
    reply_packet_size,
)
from tests.helpers.decoding import decode_chunks, represented, stats_for
from tests.helpers.packets import raw_packet

PENDING_BOUND = max(reply_packet_size(0xFF), MAX_DISCARD)
"""The decoder docstring: an unfinished packet (at most 265 bytes) or an unfinished
discarded run (at most MAX_DISCARD bytes)."""

MAX_REPLY_LENGTH = 102
"""Longest length byte of a plausible reply header (decoder docstring)."""


def fast(max_examples: int) -> settings:
    """Few enough examples that the whole file runs in seconds on a small CI machine."""
    return settings(deadline=None, max_examples=max_examples,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


# --- helpers --------------------------------------------------------------------------

def split(data: bytes, cuts: list[int]) -> list[bytes]:
    bounds = [0, *sorted(cuts), len(data)]
    return [data[a:b] for a, b in pairwise(bounds)]


def plausible_reply(raw: bytes) -> bool:
    """The decoder docstring's plausible reply header."""
    node = (raw[3] << 8) | raw[4]
    return (raw[1] == FLAGS_REPLY and raw[2] == 0 and raw[6] == 0
            and 2 <= raw[5] <= MAX_REPLY_LENGTH and MIN_NODE <= node <= MAX_NODE)


def packet_event(raw: bytes) -> Event:
    return Reply(raw) if plausible_reply(raw) else Frame(raw)


def hides_a_packet(raw: bytes) -> bool:
    """Does a valid packet start inside ``raw`` and complete before it does? A packet
    without a plausible reply header gives way to such a packet (decoder docstring)."""
    for j in range(1, len(raw) - 10):
        if raw[j] != SOP or raw[j + 1] == SOP:
            continue
        end = j + raw[j + 5] + 10
        node = (raw[j + 3] << 8) | raw[j + 4]
        if (end <= len(raw) - 1 and MIN_NODE <= node <= MAX_NODE
                and checksum(raw[j + 1:end - 4]) == int.from_bytes(raw[end - 2:end], "big")):
            return True
    return False


# --- strategies -----------------------------------------------------------------------

def _heat(sop: bool) -> bytes:
    """A translation table that makes the bytes a decoder cares about common: each of
    SOP, NACK, PING, 0x07 and 0xFF stands in for 16 byte values (0x00 is common anyway).
    Without ``sop``, 0xAA never comes out."""
    table = bytearray(range(256))
    for i, hot in enumerate((SOP, NACK, PING, FLAGS_REPLY, 0xFF)):
        table[0xB0 + 16 * i:0xC0 + 16 * i] = bytes((hot,)) * 16
    if not sop:
        table = table.replace(bytes((SOP,)), b"\x55")
    return bytes(table)


_HOT = _heat(sop=True)
_HOT_NO_SOP = _heat(sop=False)


def octets(min_size: int = 0, max_size: int = 40, sop: bool = True) -> st.SearchStrategy[bytes]:
    """Bytes rich in 0xAA, 0x21, 0x02, 0x07, 0xFF and 0x00 (no 0xAA unless ``sop``).
    st.binary and a translation: drawing byte by byte is several times slower."""
    table = _HOT if sop else _HOT_NO_SOP
    return st.binary(min_size=min_size, max_size=max_size).map(lambda b: b.translate(table))


@st.composite
def addressless_packets(draw: st.DrawFn) -> bytes:
    """Checksum-valid but with node 0 or 0xFFFF; a run of zeros after an 0xAA in float
    data is one (AA 00 00 00 00 00 00 00 00 00)."""
    node = draw(st.sampled_from((0, 0xFFFF)))
    flags = draw(st.sampled_from((0x00, FLAGS_REPLY)))
    return raw_packet(flags, node, draw(octets(0, 6)))


@st.composite
def small_packets(draw: st.DrawFn) -> bytes:
    """Short valid packets of any flags, to hide inside other packets' data."""
    node = draw(st.sampled_from((MIN_NODE, 76, 0xAAAA)))
    flags = draw(st.sampled_from((0x00, FLAGS_REPLY, 0x0B)))
    return encode_reply_packet(node, draw(octets(0, 6)), flags=flags)


def insert(draw: st.DrawFn, payload: bytes, inner: bytes) -> bytes:
    at = draw(st.integers(0, len(payload)))
    return payload[:at] + inner + payload[at:]


@st.composite
def packets(draw: st.DrawFn, plausible_only: bool = False) -> bytes:
    """A valid packet from the base station: mostly a reply (flags 0x07, 1..101 record
    bytes that may hold 0xAA and even a whole packet), sometimes another frame (other
    flags or lengths, so no plausible reply header), which may hide a packet too."""
    node = draw(st.one_of(st.integers(MIN_NODE, MAX_NODE),
                          st.sampled_from((MIN_NODE, 76, 0xAAAA, 0x21AA, MAX_NODE))))
    lqi = draw(st.integers(0, 255))
    rssi = draw(st.integers(-128, 127))
    hidden = st.one_of(st.just(b""), small_packets(), addressless_packets())
    if plausible_only or draw(st.integers(0, 9)) < 8:
        flags = FLAGS_REPLY
        inner = draw(hidden)
        room = 101 - len(inner)  # a reply carries at most 101 record bytes
        payload = insert(draw, draw(octets(min(1, room), room)), inner)
    else:
        flags = draw(st.one_of(st.sampled_from((FLAGS_REPLY, 0x00, 0x0B)),
                               st.integers(0, 255).filter(lambda f: f != SOP)))
        inner = draw(hidden)
        long = draw(st.integers(0, 3)) == 0  # beyond any plausible reply
        room = 254 - len(inner)  # a packet carries at most 254 bytes
        sizes = (min(100, room), room) if long else (0, min(40, room))
        payload = insert(draw, draw(octets(*sizes)), inner)
    return encode_reply_packet(node, payload, lqi=lqi, rssi=rssi, flags=flags)


@st.composite
def truncated_packets(draw: st.DrawFn) -> bytes:
    raw = draw(packets())
    return raw[:draw(st.integers(1, len(raw) - 1))]


@st.composite
def false_headers(draw: st.DrawFn, bogus_length: bool = False) -> bytes:
    """An 0xAA inside data followed by header-like bytes and a length; with
    ``bogus_length``, none of its bytes is another 0xAA and the length is large."""
    body = draw(octets(4, 4, sop=not bogus_length))
    length = draw(st.integers(0xC8, 0xFF) if bogus_length else st.integers(0, 255))
    return bytes((SOP,)) + body + bytes((length,))


STREAM_PIECES = st.one_of(
    packets(),
    packets(),
    addressless_packets(),
    st.sampled_from((bytes((ACK,)), bytes((NACK,)), bytes((PING,)))),
    octets(1, 12),
    truncated_packets(),
    false_headers(),
)


@st.composite
def streams(draw: st.DrawFn, max_pieces: int = 10) -> bytes:
    return b"".join(draw(st.lists(STREAM_PIECES, min_size=1, max_size=max_pieces)))


@st.composite
def chunked(draw: st.DrawFn, data: st.SearchStrategy[bytes]) -> tuple[bytes, list[int]]:
    """Bytes and where to cut them (repeated cuts make empty chunks)."""
    stream = draw(data)
    return stream, draw(st.lists(st.integers(0, len(stream)), max_size=10))


_HOSTILE = bytes((SOP, 0x00, 0x01, 0x07, 0x4C, 0xFF, NACK, PING)) * 32
"""Every byte value onto eight that headers, ACKs and answers are made of."""

ARBITRARY = st.one_of(
    st.binary(max_size=1500),
    st.binary(min_size=MAX_DISCARD - 8, max_size=3 * MAX_DISCARD).map(
        lambda b: b.translate(None, bytes((SOP,)))),  # garbage runs to cut
    st.binary(max_size=1500).map(lambda b: b.translate(_HOSTILE)),
    streams(max_pieces=20),
)


# --- the decoder ----------------------------------------------------------------------

@fast(200)
@given(chunked(ARBITRARY))
def test_never_raises_and_holds_bounded_memory(case: tuple[bytes, list[int]]) -> None:
    data, cuts = case
    decoder = Decoder()
    events: list[Event] = []
    for chunk in split(data, cuts):
        new = decoder.feed(chunk)
        assert isinstance(new, list)
        events += new
        assert 0 <= decoder.pending <= PENDING_BOUND
    events += decoder.line_idle()
    assert decoder.pending == 0
    assert all(isinstance(e, (Reply, Frame, Ack, Nack, PingOk, Discarded)) for e in events)
    assert all(len(e.data) <= MAX_DISCARD for e in events if isinstance(e, Discarded))
    assert represented(events) == data


@fast(150)
@given(chunked(streams()))
def test_events_do_not_depend_on_chunking(case: tuple[bytes, list[int]]) -> None:
    data, cuts = case
    whole, whole_decoder = decode_chunks([data])
    bytewise, bytewise_decoder = decode_chunks(data[i:i + 1] for i in range(len(data)))
    pieces, pieces_decoder = decode_chunks(split(data, cuts))
    assert bytewise == whole
    assert pieces == whole
    assert bytewise_decoder.stats == whole_decoder.stats == pieces_decoder.stats


@fast(150)
@given(chunked(streams()))
def test_every_byte_is_accounted_for_exactly_once(case: tuple[bytes, list[int]]) -> None:
    data, cuts = case
    decoder = Decoder()
    events: list[Event] = []
    fed = 0
    for chunk in split(data, cuts):
        events += decoder.feed(chunk)
        fed += len(chunk)
        # What came out plus what is pending is exactly what went in.
        assert represented(events) == data[:fed - decoder.pending]
    events += decoder.line_idle()
    assert represented(events) == data
    assert decoder.pending == 0
    assert decoder.stats == stats_for(events)
    for event in events:
        if isinstance(event, Discarded):
            assert 1 <= len(event.data) <= MAX_DISCARD
        elif isinstance(event, (Reply, Frame)):
            assert len(event.raw) == reply_packet_size(event.raw[5])
            assert checksum(event.raw[1:-4]) == int.from_bytes(event.raw[-2:], "big")
            assert MIN_NODE <= event.node <= MAX_NODE
            assert isinstance(event, Reply) == plausible_reply(event.raw)


def garbage_events(garbage: bytes) -> list[Event]:
    """Bytes between packets, none of them 0xAA, so one run (it ends at the next packet's
    SOP or when the line goes idle): a NACK or a ping answer when the run is that byte
    alone, otherwise garbage, cut in MAX_DISCARD pieces (decoder docstring)."""
    if garbage == bytes((NACK,)):
        return [Nack()]
    if garbage == bytes((PING,)):
        return [PingOk()]
    return [Discarded(garbage[i:i + MAX_DISCARD], DiscardReason.GARBAGE)
            for i in range(0, len(garbage), MAX_DISCARD)]


GARBAGE_BETWEEN_PACKETS = st.one_of(
    octets(0, 16, sop=False),  # rich in 0x21 and 0x02, so runs often hold them
    st.sampled_from((bytes((NACK,)), bytes((PING,)))),  # and often are one alone
)


@fast(120)
@given(st.lists(st.tuples(GARBAGE_BETWEEN_PACKETS, st.booleans(),
                          packets()), min_size=1, max_size=6),
       GARBAGE_BETWEEN_PACKETS, st.lists(st.integers(0, 2000), max_size=8))
def test_every_valid_packet_survives_garbage(
        parts: list[tuple[bytes, bool, bytes]], tail: bytes, cuts: list[int]) -> None:
    # Garbage here holds no 0xAA: with one it could start a false header whose claimed
    # bytes overlap a packet and, by chance, hold a valid checksum. Each packet may have
    # an ACK glued to its SOP. A frame without a plausible reply header that hides a
    # valid packet rightly gives way to it, so it is left out here (an addressless
    # look-alike inside it is not a valid packet and must not matter).
    for _, _, raw in parts:
        assume(plausible_reply(raw) or not hides_a_packet(raw))
    data = b"".join(garbage + bytes((ACK,)) * ack + raw for garbage, ack, raw in parts) + tail
    expected: list[Event] = []
    for garbage, ack, raw in parts:
        expected += garbage_events(garbage) + [Ack()] * ack + [packet_event(raw)]
    expected += garbage_events(tail)
    decoder = Decoder()
    before_idle: list[Event] = []
    for chunk in split(data, [c for c in cuts if c <= len(data)]):
        before_idle += decoder.feed(chunk)
    # Every packet is out as soon as its last byte is in, before line_idle().
    packets_out = [e for e in before_idle if isinstance(e, (Reply, Frame))]
    assert packets_out == [packet_event(raw) for _, _, raw in parts]
    assert before_idle + decoder.line_idle() == expected


@fast(100)
@given(st.lists(st.one_of(false_headers(bogus_length=True), octets(1, 8, sop=False)),
                min_size=1, max_size=6),
       packets(plausible_only=True))
def test_packet_behind_false_headers_comes_out_on_its_last_byte(
        prefix_pieces: list[bytes], raw: bytes) -> None:
    prefix = b"".join(prefix_pieces)
    data = prefix + raw
    # Every false header claims more bytes than the stream holds: none can complete.
    assert len(data) < reply_packet_size(0xC8)
    whole = Decoder()
    events = whole.feed(data)
    assert events[-1] == Reply(raw)
    assert represented(events) == data and whole.pending == 0
    bytewise = Decoder()
    for i in range(len(data) - 1):
        assert Reply(raw) not in bytewise.feed(data[i:i + 1])
    last = bytewise.feed(data[-1:])
    assert last[-1] == Reply(raw) and bytewise.pending == 0


# --- reply records: encode -> packet -> decoder -> decode -------------------------------

F32 = st.floats(width=32)  # NaN and infinities included
FINITE_F32 = st.floats(width=32, allow_nan=False, allow_infinity=False)
LATIN1 = st.text(alphabet=st.characters(min_codepoint=0, max_codepoint=255), max_size=16)


def value_strategy(f: Field) -> st.SearchStrategy[object]:
    shape = f.type.shape
    if shape == "int":
        return st.integers(0, f.type.max_int)
    if shape == "float":
        return F32
    if shape == "vector":
        return st.tuples(F32, F32, F32)
    if shape == "matrix":
        return st.tuples(*[st.tuples(F32, F32, F32)] * 3)
    if shape == "ints":
        return st.tuples(*[st.integers(0, f.type.max_int)] * f.type.items)
    if shape == "text":
        return LATIN1
    raise AssertionError(f"no strategy for {f.name} ({shape})")


def decoded_value(f: Field, value: object) -> object:
    """What decode gives back for ``value``: text loses trailing spaces and NULs."""
    return value.rstrip(" \x00") if f.type.shape == "text" else value  # type: ignore[union-attr]


@st.composite
def record_values(draw: st.DrawFn, spec: records.CommandSpec) -> dict[str, object]:
    return {f.name: draw(value_strategy(f)) for f in spec.reply or ()}


REPLY_SPECS = [spec for spec in records.all_specs() if spec.reply is not None]


@pytest.mark.parametrize("spec", REPLY_SPECS, ids=lambda s: s.name)
@fast(25)
@given(data=st.data(), node=st.integers(MIN_NODE, MAX_NODE), lqi=st.integers(0, 255),
       rssi=st.integers(-128, 127))
def test_reply_record_round_trip(spec: records.CommandSpec, data: st.DataObject, node: int,
                                 lqi: int, rssi: int) -> None:
    values = data.draw(record_values(spec), label="values")
    payload = records.encode(spec.code, **values)
    assert payload[0] == spec.code and len(payload) == spec.reply_size
    if spec.reply_may_run_long:  # 0xFB: trust the packet's length byte, not the table
        payload += data.draw(st.binary(max_size=6), label="extra")
    raw = encode_reply_packet(node, payload, lqi=lqi, rssi=rssi)
    decoder = Decoder()
    assert decoder.feed(raw) == [Reply(raw)]
    assert decoder.line_idle() == [] and decoder.pending == 0
    reply = Reply(raw)
    assert (reply.node, reply.command, reply.lqi, reply.rssi) == (node, spec.code, lqi, rssi)
    assert reply.payload == payload
    record = records.decode(reply.payload)
    expected = records.Record(spec, tuple(decoded_value(f, values[f.name])
                                          for f in spec.reply or ()))
    assert record.same_as(expected), (record, expected)


# --- commands: build -> parse ---------------------------------------------------------

U16 = st.integers(0, 0xFFFF)
ARGUMENTS: dict[str, st.SearchStrategy[dict[str, object]]] = {
    "continuous_mode": st.fixed_dictionaries(
        {"continuous_command": st.sampled_from(sorted({0} | records.STREAMABLE))}),
    "accel_bias": st.fixed_dictionaries(
        {"accel_bias": st.tuples(FINITE_F32, FINITE_F32, FINITE_F32)}),
    "gyro_bias": st.fixed_dictionaries(
        {"gyro_bias": st.tuples(FINITE_F32, FINITE_F32, FINITE_F32)}),
    "capture_gyro_bias": st.fixed_dictionaries({"sampling_time": st.integers(1, 0xFFFF)}),
    "store_nonvolatile": st.fixed_dictionaries({"quantity": st.sampled_from((1, 2))}),
    "eeprom_write": st.fixed_dictionaries({"address": U16, "value": U16}),
    "eeprom_read": st.fixed_dictionaries({"address": U16}),
    "device_id": st.fixed_dictionaries({"selector": st.integers(0, 3)}),
    "built_in_test": st.fixed_dictionaries({"test_config": st.integers(0, 255)}),
}
"""Valid arguments for every command that takes some."""

ARGUMENT_SPECS = [spec for spec in records.all_specs() if spec.arguments]


def test_every_command_with_arguments_has_a_strategy() -> None:
    assert {spec.name for spec in ARGUMENT_SPECS} == set(ARGUMENTS)


@pytest.mark.parametrize("spec", ARGUMENT_SPECS, ids=lambda s: s.name)
@fast(40)
@given(data=st.data(), node=st.integers(MIN_NODE, MAX_NODE))
def test_command_build_parse_round_trip(spec: records.CommandSpec, data: st.DataObject,
                                        node: int) -> None:
    arguments = data.draw(ARGUMENTS[spec.name], label="arguments")
    command = commands.build(spec.code, **arguments)
    assert commands.parse(command.data) == command
    assert commands.build(spec.name, **arguments) == command
    assert dict(command.arguments) == arguments
    assert command.data[0] == spec.code and len(command.data) == spec.request_size
    assert decode_command_packet(command.packet(node)) == (node, command.data)


@pytest.mark.parametrize("spec", [s for s in records.all_specs() if not s.request],
                         ids=lambda s: s.name)
def test_command_without_arguments_round_trip(spec: records.CommandSpec) -> None:
    command = commands.build(spec.code)
    assert command.data == bytes((spec.code,))
    assert commands.parse(command.data) == command
