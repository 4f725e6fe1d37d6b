"""The LSL output's parts that need no outlet (tests/e2e/test_lsl.py has the outlets,
in a network namespace of their own): every streamable record's channels and stream
type, the clock mapping, and ``take``: bounded, never a status, a mark or a command's
reply."""

from __future__ import annotations

import ctypes
import math
import time
from types import SimpleNamespace
from typing import Any

import pytest

from aspp.records import BY_CODE, BY_NAME, STREAMABLE, derived
from gateway.daemon.config import LslConfig
from gateway.daemon.outputs import Message
from gateway.daemon.outputs.guard import Guard
from gateway.daemon.outputs.lsl import LslClock, LslOutput
from gateway.daemon.outputs.lslinfo import CHANNEL_TYPES, STREAM_TYPES, channels, source_id


def payload_of(record: str, **extra: object) -> dict[str, object]:
    spec = BY_NAME[record]
    values = {f.name: (0 if f.type.shape == "int" else 0.0) if f.type.items == 1
              else [[0.0] * 3] * 3 if f.type.shape == "matrix" else [0] * f.type.items
              for f in spec.reply or ()}
    return {**values, "node": 76, "record": record, "command": spec.code, "seq": 1,
            "host_time": time.time(), "lqi": 200, "rssi": -40, "station": "station1",
            **extra}


@pytest.mark.parametrize("code", sorted(STREAMABLE))
def test_every_streamable_record_is_a_stream_of_its_scalars_less_the_timer(code: int) -> None:
    spec = BY_CODE[code]
    assert spec.name in STREAM_TYPES
    layout = channels(spec.name, payload_of(spec.name))
    assert len(layout) == sum(f.type.items for f in (*(spec.reply or ()), *derived(spec))
                              if f.name != "timer")
    assert len({c.label for c in layout}) == len(layout)
    assert all(c.unit for c in layout), layout  # (every streamed field has a unit)
    assert all(c.kind == CHANNEL_TYPES[c.field] for c in layout)


def test_a_matrix_is_nine_channels_row_major_named_as_export_names_its_columns() -> None:
    layout = channels("orientation", payload_of("orientation"))
    assert [c.label for c in layout[:9]] == [f"orientation_{r}{c}" for r in (1, 2, 3)
                                             for c in (1, 2, 3)]
    assert [c.index for c in layout[:9]] == list(range(9))
    # then the angles and the quaternion the gateway adds to a record with a matrix
    assert [c.label for c in layout[9:]] == ["roll", "pitch", "yaw", "quaternion_w",
                                             "quaternion_x", "quaternion_y", "quaternion_z"]


def test_the_source_id_is_the_same_on_every_start() -> None:
    assert source_id("lab-pc", "station1", 76, "euler") == "lab-pc/station1/76/euler"


def test_time_goes_on_lsls_clock_by_the_unix_offset_of_its_read() -> None:
    clock = LslClock(lambda: time.monotonic() + 1000.0)  # an LSL clock 1000 s ahead
    assert clock.shift == pytest.approx(1000.0, abs=1e-3)
    monotonic_instant = time.monotonic() - 0.25  # a sample taken 250 ms ago
    offset = LslClock.unix_offset()
    stamped = clock.stamp(monotonic_instant + offset, offset)
    # (through a UNIX time near 1.7e9, whose double steps by 238 ns)
    assert stamped == pytest.approx(monotonic_instant + clock.shift, abs=1e-6)


def output(queue: int = 100) -> LslOutput:
    """An output whose thread is never started: no outlet is ever made."""
    return LslOutput(LslConfig(queue=queue), {}, SimpleNamespace(local_clock=time.monotonic))


def test_take_queues_samples_up_to_its_bound_and_counts_the_rest() -> None:
    lsl = output(queue=100)
    for seq in range(150):
        lsl.take(Message(b"gx2/76/euler", payload_of("euler", seq=seq, time=time.time())))
    said = lsl.status()
    assert (said["queued"], said["dropped"], said["skipped"]) == (100, 50, 0)


def test_take_leaves_out_the_status_marks_command_replies_and_untimed_records() -> None:
    lsl = output()
    lsl.take(Message(b"gx2/gateway/status", {"gateway": {}, "nodes": []}))
    lsl.take(Message(b"gx2/marks", {"time": time.time(), "text": "go", "nodes": []}))
    lsl.take(Message(b"gx2/76/continuous_mode",
                     payload_of("continuous_mode", time=time.time())))
    lsl.take(Message(b"gx2/76/euler", payload_of("euler")))  # (no time)
    lsl.take(Message(b"gx2/76/firmware_version", payload_of("firmware_version")))
    said = lsl.status()
    assert (said["queued"], said["skipped"], said["dropped"]) == (0, 3, 0)


class FakeElement:
    """pylsl's XMLElement, as far as a desc is written."""

    def __init__(self) -> None:
        self.children: list[tuple[str, Any]] = []

    def append_child(self, name: str) -> FakeElement:
        child = FakeElement()
        self.children.append((name, child))
        return child

    def append_child_value(self, name: str, value: str) -> FakeElement:
        self.children.append((name, value))
        return self


class FakeInfo:
    def __init__(self, name: str, kind: str, count: int, rate: float, fmt: int,
                 source: str) -> None:
        self.name, self.kind, self.count, self.rate, self.source = name, kind, count, \
            rate, source
        self.element = FakeElement()

    def desc(self) -> FakeElement:
        return self.element


class FakePylsl:
    """pylsl without liblsl: what the output's thread makes and pushes, kept."""

    cf_float32 = 1

    def __init__(self) -> None:
        self.outlets: list[Any] = []
        self.local_clock = time.monotonic
        fake = self

        class StreamOutlet:
            def __init__(self, info: FakeInfo, max_buffered: int) -> None:
                self.info, self.obj, self.chunks = info, object(), []
                self.values: list[float] = []
                fake.outlets.append(self)

            def do_push_chunk_n(self, handle: Any, data: Any, count: Any, stamps: Any,
                                pushthrough: Any) -> int:
                self.chunks.append(count.value)
                self.values.extend((ctypes.c_float * count.value).from_address(data.value))
                return 0

        self.StreamOutlet = StreamOutlet
        self.StreamInfo = FakeInfo


def euler(seq: int) -> Message:
    return Message(b"gx2/76/euler", payload_of("euler", seq=seq, time=time.time()))


def report(divider: int | None, record: str | None = "euler") -> dict[str, Any]:
    return {"nodes": [{"node": 76, "name": "left", "record": record, "divider": divider,
                       "clock": {"locked": True, "drift_ppm": 12.5}}]}


def test_a_stream_waits_for_its_rate_and_is_made_anew_when_the_rate_changes() -> None:
    pylsl = FakePylsl()
    lsl = LslOutput(LslConfig(), {"station1": 3.0}, pylsl)  # type: ignore[arg-type]
    lsl.take(euler(1))
    lsl._push_queued()  # no report yet: its rate is not known, and it waits
    assert pylsl.outlets == [] and lsl.status()["waiting"] == 1
    lsl.report(report(512))
    lsl.take(euler(2))
    lsl._push_queued()
    (first,) = pylsl.outlets
    assert (first.info.name, first.info.rate, first.info.count) == ("gx2-76-euler", 100.0, 3)
    assert first.info.source.endswith("/station1/76/euler")
    assert first.chunks == [6]  # both samples, 3 channels each, in one chunk
    lsl.report(report(1024))  # gx2ctl rate 76 50
    lsl.take(euler(3))
    lsl._push_queued()
    assert [o.info.rate for o in pylsl.outlets] == [100.0, 50.0]
    assert pylsl.outlets[1].info.name == first.info.name
    assert pylsl.outlets[1].info.source == first.info.source
    assert lsl.status()["pushed"] == 3 and lsl.status()["streams"] == ["gx2-76-euler"]


def test_a_record_no_report_names_gets_an_irregular_stream(
        monkeypatch: pytest.MonkeyPatch) -> None:
    from gateway.daemon.outputs import lsl as module
    monkeypatch.setattr(module, "PENDING_S", 0.0)
    pylsl = FakePylsl()
    lsl = LslOutput(LslConfig(), {}, pylsl)  # type: ignore[arg-type]
    lsl.report(report(512, record="accel_angrate"))  # (euler polled, beside its stream)
    lsl.take(euler(1))
    lsl._push_queued()
    assert [o.info.rate for o in pylsl.outlets] == [0.0]


def synchronization(outlet: Any) -> dict[str, str]:
    """The desc/synchronization block of an outlet's stream, as written."""
    block = next(child for name, child in outlet.info.desc().children
                 if name == "synchronization")
    return dict(block.children)


@pytest.mark.parametrize(("clock", "said"), [
    ({"locked": False, "drift_ppm": 0.0}, {"clock_locked_at_start": "false"}),
    ({"locked": True, "drift_ppm": 12.5}, {"clock_locked_at_start": "true",
                                           "clock_drift_ppm_at_start": "12.5"}),
    (None, {"clock_locked_at_start": "false"}),
])
def test_the_desc_says_the_clock_at_stream_start_and_no_drift_before_it_locks(
        clock: dict[str, Any] | None, said: dict[str, str]) -> None:
    pylsl = FakePylsl()
    lsl = LslOutput(LslConfig(), {"station1": 3.0}, pylsl)  # type: ignore[arg-type]
    lsl.report({"nodes": [{"node": 76, "record": "euler", "divider": 512, "clock": clock}]})
    lsl.take(euler(1))
    lsl._push_queued()
    (outlet,) = pylsl.outlets
    sync = synchronization(outlet)
    assert {key: value for key, value in sync.items() if key.startswith("clock")} == said


def test_a_sample_with_a_nan_is_pushed_and_one_that_cannot_be_made_is_dropped_alone(
        caplog: pytest.LogCaptureFixture) -> None:
    """A field a record holds NaN in, or lacks (a replayed file of before the matrix's
    derived fields), is NaN in its channel; a record no sample can be made of (text
    where a number goes) is dropped alone, through the outputs' guard (counted, said
    once), and the batch's other samples are pushed, in one chunk."""
    pylsl = FakePylsl()
    guard = Guard()
    lsl = LslOutput(LslConfig(), {"station1": 3.0}, pylsl, guard.of("lsl"))  # type: ignore[arg-type]
    lsl.report(report(512))
    good = [euler(seq) for seq in range(4)]
    nan = Message(b"gx2/76/euler", {**good[1].payload, "roll": math.nan})
    lacking = Message(b"gx2/76/euler", {k: v for k, v in good[2].payload.items()
                                        if k != "yaw"})
    texts = [Message(b"gx2/76/euler", {**good[3].payload, "pitch": "text"})
             for _ in range(2)]
    for message in (good[0], nan, texts[0], lacking, texts[1], good[3]):
        lsl.take(message)
    lsl._push_queued()
    (outlet,) = pylsl.outlets
    assert outlet.chunks == [4 * 3]  # four samples of three channels, in one push
    pushed = [outlet.values[i:i + 3] for i in range(0, 12, 3)]
    assert math.isnan(pushed[1][0]) and math.isnan(pushed[2][2])
    assert sum(math.isnan(v) for v in outlet.values) == 2
    said = lsl.status()
    assert said["pushed"] == 4 and said["dropped"] == 2, said
    assert guard.failures == {"lsl": 2}
    lines = [r.getMessage() for r in caplog.records if "output lsl" in r.getMessage()]
    assert len(lines) == 1 and "failed to make a sample of gx2-76-euler" in lines[0], lines


def test_a_node_renamed_by_a_reload_gets_its_stream_made_anew_with_its_name() -> None:
    """A stream's desc says its node's name (``gx2/name``) and cannot change: a reload
    that renames the node makes a new stream, with the same name and source_id."""
    pylsl = FakePylsl()
    lsl = LslOutput(LslConfig(), {"station1": 3.0}, pylsl)  # type: ignore[arg-type]
    lsl.report(report(512))
    lsl.take(euler(1))
    lsl._push_queued()
    renamed = report(512)
    renamed["nodes"][0]["name"] = "right"
    lsl.report(renamed)
    lsl.take(euler(2))
    lsl._push_queued()
    lsl.take(euler(3))
    lsl._push_queued()
    named = [dict(dict(o.info.desc().children)["gx2"].children)["name"] for o in pylsl.outlets]
    assert named == ["left", "right"]
    assert len({(o.info.name, o.info.source) for o in pylsl.outlets}) == 1
    assert [o.chunks for o in pylsl.outlets] == [[3], [3, 3]]
