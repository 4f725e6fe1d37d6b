"""A column of seconds as nanoseconds (:mod:`gateway.recording.arrowtime`), value for
value what :func:`gateway.recording.columns.nanoseconds` makes of each: the decimals
past the ninth rounded half to even, as a node's ``device_time`` has them."""

from __future__ import annotations

import pyarrow as pa
import pyarrow.compute as pc
from hypothesis import given, settings
from hypothesis import strategies as st

from aspp.timing import TICKS_PER_SECOND
from gateway.recording.arrowtime import LARGEST, exact_nanoseconds
from gateway.recording.columns import nanoseconds


def _one_by_one(values: list[float | None]) -> list[int | None]:
    exact = [nanoseconds(v) for v in values]
    return [n if n is not None and abs(n) <= LARGEST else None for n in exact]


def _column(values: list[float | None]) -> list[int | None]:
    return exact_nanoseconds(pa, pc, pa.array(values, pa.float64())).to_pylist()


@settings(max_examples=300, deadline=None)  # (a busy machine: a column's compute calls)
@given(st.lists(st.one_of(st.none(), st.floats(), st.floats(-1e6, 1e6),
                          st.floats(1.7e9, 1.9e9)), max_size=50))
def test_a_column_is_each_value_as_nanoseconds_makes_it(values: list[float | None]) -> None:
    assert _column(values) == _one_by_one(values)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.integers(0, 2**40), min_size=1, max_size=50))
def test_device_times_of_a_node_s_timer(ticks: list[int]) -> None:
    values = [t / TICKS_PER_SECOND for t in ticks]
    assert _column(values) == _one_by_one(values)


def test_halves_go_to_the_even_nanosecond() -> None:
    values = [1.0000000005, 1.0000000015, -1.0000000015, 12.3456789125, 12.34567891250001,
              0.010416666666666666, 1795000000.0104167]
    assert _column(values) == _one_by_one(values) == [
        1_000_000_000, 1_000_000_002, -1_000_000_002, 12_345_678_912, 12_345_678_913,
        10_416_667, 1_795_000_000_010_416_700]
