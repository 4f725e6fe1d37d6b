"""The batch counting (:mod:`gateway.recording.batchsteps`) held against the row-by-row
stream it stands in for (:class:`gateway.recording.losses.Stream`): the same rows
decided the same way, whatever the batches, restarts, short steps, gaps in ``seq``,
damaged stretches and continuous-mode replies between them."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from aspp.timing import TICKS_PER_SECOND
from gateway.recording.batchsteps import NONE, Decided, Rows, add_many, flush
from gateway.recording.losses import Stream
from gateway.recording.outages import Outages

PERIOD = 512 / 51200


def _stream(outages: Outages) -> Stream[int]:
    return Stream(outage=lambda after, at: outages.back(76, after, at))


@st.composite
def recordings(draw: st.DrawFn) -> tuple[list[dict], list[int], list[str]]:
    """Rows of one stream, where batches end, and what happens between batches."""
    rows: list[dict] = []
    device, timer, seq = 0.0, 0, 0
    # how often a sample is lost: up to where a one-period step stops being the most
    # common among the window's (the edge of the window then decides the period)
    lossy = draw(st.integers(0, 30))
    for count in range(1, draw(st.integers(1, 200)) + 1):
        kind = draw(st.sampled_from(["step"] * 12 + ["lost"] * lossy + [
            "short", "reboot", "seqgap", "polled", "notimer"]))
        samples = draw(st.integers(2, 3)) if kind == "lost" else 1
        advance = samples * PERIOD
        if kind == "short":
            advance = 0.001
        elif kind == "polled":
            advance = draw(st.floats(0.01, 2.0))
        ticks = round(advance * TICKS_PER_SECOND)
        timer = 0 if kind == "reboot" else (timer + ticks) % (1 << 32)
        device += advance
        seq += 1 + (draw(st.integers(1, 3)) if kind == "seqgap" else 0)
        rows.append({"device_time": round(device, 9),
                     "timer": None if kind == "notimer" else timer, "seq": seq,
                     "time": 1_795_000_000.0 + device, "count": count})
    cuts = sorted(draw(st.lists(st.integers(1, len(rows)), max_size=8, unique=True)))
    events = draw(st.lists(st.sampled_from(["", "", "unread", "started"]),
                           min_size=len(cuts), max_size=len(cuts)))
    return rows, cuts, events


def _rows(part: list[dict]) -> Rows:
    def ints(key: str) -> np.ndarray:
        return np.array([NONE if r[key] is None else r[key] for r in part], np.int64)
    return Rows(np.array([r["device_time"] for r in part], np.float64), ints("timer"),
                ints("seq"), ints("count"), np.array([r["time"] for r in part]))


@settings(max_examples=150, deadline=None)
@given(recordings())
def test_batches_decide_as_rows_do(recording: tuple[list[dict], list[int], list[str]]
                                   ) -> None:
    rows, cuts, events = recording
    outages = Outages()
    by_row, by_batch = _stream(outages), _stream(outages)
    expected = []
    decided = Decided()
    start = 0
    for cut, event in [*zip(cuts, events, strict=True), (len(rows), "")]:
        part = rows[start:cut]
        for number, row in enumerate(part, start):
            expected += by_row.add(row, number, row["count"])
        add_many(by_batch, _rows(part), decided, start)
        start = cut
        if event == "unread":
            by_row.unread()
            by_batch.unread()
        elif event == "started" and part:
            reply = {**part[-1], "device_time": part[-1]["device_time"] + 0.2}
            by_row.started(reply, part[-1]["count"])
            by_batch.started(reply, part[-1]["count"])
    expected += by_row.flush()
    flush(by_batch, decided)
    items, lost, gateway, unread, down = decided.arrays()
    assert [c.item for c in expected] == items.tolist()
    assert [NONE if c.lost is None else c.lost for c in expected] == lost.tolist()
    assert [c.gateway for c in expected] == gateway.tolist()
    assert [c.unread for c in expected] == unread.tolist()
    assert [c.down for c in expected] == down.tolist()
    assert by_row.period == by_batch.period


def test_a_lossy_stream_is_counted() -> None:
    """The property above is not vacuous: a stream losing one sample in ten says so."""
    device = np.array([i * PERIOD for i in range(1000) if i % 10 != 5])
    n = len(device)
    rows = Rows(device, np.rint(device * TICKS_PER_SECOND).astype(np.int64),
                np.arange(1, n + 1), np.arange(1, n + 1), device + 1.795e9)
    decided = Decided()
    stream: Stream[int] = Stream()
    add_many(stream, rows, decided)
    flush(stream, decided)
    lost = decided.arrays()[1]
    assert lost[0] == NONE and lost[1:].sum() == 100 and stream.period == 512
