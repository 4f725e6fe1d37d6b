"""The line's judge on line models in simulated time (bench/linequeue.py): a FIFO base
station, written apart from gx2-sim, over capacity with reads under the baud rate; host
stalls on a busy line; and the sample-time sweep's lines, which are never over it."""

from __future__ import annotations

import statistics
import sys
from itertools import pairwise
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "bench"))
try:
    import linemodels
    import linequeue
finally:
    sys.path.pop(0)

from linequeue import Stream, fifo_queue, judged

OVERLOAD = (20.0, 60.0)
"""Seconds node 78 streams the orientation matrix: 135% of the line offered."""
STREAMS = [Stream(76), Stream(77), Stream(78, "accel_angrate_orientation",
                                          start=OVERLOAD[0], stop=OVERLOAD[1])]
SAID_S = 5.0
"""Seconds from the queue's start to the line said over capacity."""


@pytest.mark.parametrize(("throughput", "buffer"), [(1.0, 4096), (0.906, 4096), (0.906, None)])
def test_an_overload_read_under_the_baud_rate_is_said_and_its_clocks_held(
        throughput: float, buffer: int | None) -> None:
    # 0.906: a base station that leaves gaps between packets, the reads at 90.6% of the
    # line while it is saturated (bytes a second never said so); None: a queue that
    # grows without bound, the nodes' packets seconds late
    model = fifo_queue(1, 170.0, STREAMS, throughput=throughput, buffer=buffer)
    run = judged(model)
    start = run.first_over()
    assert start is not None and OVERLOAD[0] < start <= OVERLOAD[0] + SAID_S
    room = run.first_room(start)
    assert room is not None and room > OVERLOAD[1]
    assert all(run.over(start, room)), "room said while the queue stood"
    assert not any(run.over(room)), "said over capacity again with the queue drained"
    assert not any(run.over(stop=OVERLOAD[0]))
    for node in (76, 77):
        errors = run.errors[node]
        # time continuous throughout: never a step against the truth of more than a
        # period's share (the clocks held, then slewed back)
        steps = [abs(b[1] - a[1]) for a, b in pairwise(errors)]
        assert max(steps) < 0.02, max(steps)
        # before the overload, and 10 s after the line had room, on the truth
        before = [e for t, e in errors if 5.0 < t < OVERLOAD[0]]
        after = [e for t, e in errors if t > room + 10.0]
        middle = statistics.median(before)
        assert max(abs(e - middle) for e in after) < 1e-3


def test_host_stalls_on_a_busy_line_are_never_over_capacity() -> None:
    # 97% of the line and stalls of 0.6, 2 and 3 s: each read back at the host's pace
    streams = [Stream(76), Stream(77), Stream(78, divider=640)]
    model = fifo_queue(2, 120.0, streams, stalls=[(30.0, 2.0), (60.0, 3.0), (90.0, 0.6)])
    assert model.load > 0.95
    assert not any(judged(model).over())


@pytest.mark.parametrize(("model", "seed"), [("gx2sim", 9), ("gx2sim", 26), ("fifo", 4)])
def test_the_sweeps_lines_are_never_over_capacity(model: str, seed: int) -> None:
    # gx2sim 9 and 26: 50 ms stalls of the base station's output bunched, a queue of up
    # to 300 ms for two seconds that drains: a queue, not a line over capacity
    assert not any(judged(linemodels.MODELS[model](seed, 60.0)).over())


def test_the_bench_runs() -> None:
    assert linequeue.main() == 0
