"""UNIX seconds (doubles, as the messages' JSON holds them) as whole nanoseconds, a
column at a time and exactly as :func:`.columns.nanoseconds` takes one value: from the
decimal the JSON wrote, the double's shortest form (Arrow's cast of a double to text
is that form, as Python's ``repr``), rounded half to even at the ninth decimal, not
``round(seconds * 1e9)``, which is off by up to 128 ns for a UNIX time.

Why: ``nanoseconds`` costs 1.6 us a value (``decimal``); a column of them, about 0.1 us
(bench/exportformats.py). A value whose text is not plain digits (an exponent: very
large or very small) is taken by ``nanoseconds`` one at a time. A value of more than 9
decimals (a node's ``device_time``, its timer's ticks over 19,660,800: every row of a
real recording) is rounded here, a column at a time: about 1.5 us a value, against 6.5
one at a time (bench/dataset.py's hourly files: about 2 s less of an hour's 18).
"""

from __future__ import annotations

from typing import Any

from .columns import nanoseconds

_PLAIN = r"^(?P<sign>-?)(?P<whole>\d{1,10})(?:\.(?P<part>\d{1,9})(?P<rest>\d*))?$"
"""Up to 10 whole digits, 9 decimals and the rest (rounded): the ns are integers;
anything else goes to ``nanoseconds``."""
LARGEST = 9_223_372_036_854_775_807
"""The latest time a ``timestamp[ns]`` holds (int64)."""
WHOLE = LARGEST // 1_000_000_000 - 1
"""Whole seconds whose ns, whatever their decimals, an int64 holds (the year 2262)."""


def exact_nanoseconds(pa: Any, pc: Any, seconds: Any) -> Any:
    """An int64 array of the nanoseconds of a float64 array (null where it is null, not
    finite, or beyond an int64 of ns)."""
    text = pc.cast(seconds, pa.string())
    parts = pc.extract_regex(text, _PLAIN)
    plain = pc.fill_null(pc.is_valid(parts), False)
    whole = pc.cast(pc.if_else(plain, pc.struct_field(parts, "whole"), "0"), pa.int64())
    plain = pc.and_(plain, pc.less_equal(whole, WHOLE))
    whole = pc.if_else(plain, whole, 0)
    part = pc.if_else(plain, pc.struct_field(parts, "part"), "")
    fraction = pc.cast(pc.utf8_rpad(part, 9, "0"), pa.int64())
    magnitude = pc.add(pc.multiply(whole, 1_000_000_000), fraction)
    # half to even, as nanoseconds' Decimal: up past a half, or at one if it is odd
    rest = pc.if_else(plain, pc.struct_field(parts, "rest"), "")
    first = pc.utf8_slice_codeunits(rest, 0, 1)
    past_half = pc.or_(pc.greater(first, "5"), pc.and_(pc.equal(first, "5"), pc.or_(
        pc.match_substring_regex(pc.utf8_slice_codeunits(rest, 1, 64), "[1-9]"),
        pc.equal(pc.bit_wise_and(magnitude, 1), 1))))
    magnitude = pc.add(magnitude, pc.cast(past_half, pa.int64()))
    negative = pc.equal(pc.if_else(plain, pc.struct_field(parts, "sign"), ""), "-")
    ns = pc.if_else(negative, pc.negate(magnitude), magnitude)
    ns = pc.if_else(plain, ns, None)
    odd = pc.and_(pc.is_valid(seconds), pc.invert(plain)).to_numpy(zero_copy_only=False)
    if odd.any():  # (exponents, inf, NaN: rare)
        values = ns.to_pylist()
        for i in odd.nonzero()[0]:
            exact = nanoseconds(seconds[int(i)].as_py())
            values[i] = exact if exact is not None and abs(exact) <= LARGEST else None
        ns = pa.array(values, pa.int64())
    return ns
