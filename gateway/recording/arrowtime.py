"""UNIX seconds (doubles, as the messages' JSON holds them) as whole nanoseconds, a
column at a time and exactly as :func:`.columns.nanoseconds` takes one value: from the
decimal the JSON wrote, the double's shortest form (Arrow's cast of a double to text
is that form, as Python's ``repr``), rounded half to even at the ninth decimal, not
``round(seconds * 1e9)``, which is off by up to 128 ns for a UNIX time.

How: the text's digits without its point read as one integer (exact: at most 18 of
them), then scaled by its count of decimals in integers, the decimals past the ninth
rounded half to even by the remainder. Why: ``nanoseconds`` costs 1.6 us a value
(``decimal``), 6.5 with more than 9 decimals (a node's ``device_time``, its timer's
ticks over 19,660,800: every row of a real recording); the text's parts taken apart
by a regular expression, 0.65 us; this, 0.27 (2.4x: 100,000 UNIX times or device
times a column, the same machine, issue 44). A value whose text is not plain digits
(an exponent: very large or very small; more than 18 digits) is taken by
``nanoseconds`` one at a time.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .columns import nanoseconds

LARGEST = 9_223_372_036_854_775_807
"""The latest time a ``timestamp[ns]`` holds (int64)."""
WHOLE = LARGEST // 1_000_000_000 - 1
"""Whole seconds whose ns, whatever their decimals, an int64 holds (the year 2262)."""
DIGITS = 18
"""Digits an int64 always holds."""
EXPONENT_FROM, EXPONENT_BELOW = 1e9, 1e-5
"""Between these, Arrow writes a double positionally (2 million values from 1e-6 to 1e10
held: none with an exponent)."""
_TENS = 10 ** np.arange(DIGITS + 1, dtype=np.int64)


def exact_nanoseconds(pa: Any, pc: Any, seconds: Any) -> Any:
    """An int64 array of the nanoseconds of a float64 array (null where it is null, not
    finite, or beyond an int64 of ns)."""
    text = pc.cast(seconds, pa.string())
    point = pc.find_substring(text, ".")
    digits = pc.replace_substring(text, ".", "")
    length = _numpy(pc.fill_null(pc.binary_length(digits), 0))
    negative = pc.starts_with(text, "-")
    values = _numpy(seconds)  # (a null: NaN)
    size = np.abs(values)
    # plain: digits, a point perhaps and a sign (not an exponent, inf or nan), at most
    # DIGITS of them, and whole seconds an int64 of ns holds
    kept = np.isfinite(values) & (size < WHOLE + 1) & (length - (values < 0) <= DIGITS)
    kept &= ~exponent(pa, pc, text, size)
    plain = pa.array(kept)
    minus = _numpy(pc.fill_null(negative, False))
    whole = np.abs(_numpy(pc.if_else(plain, digits, "0").cast(pa.int64())))
    point = _numpy(pc.fill_null(point, -1))
    decimals = np.where(kept & (point >= 0), length - point, 0)  # (the point removed)
    short = decimals <= 9
    ns = np.where(short, whole * _TENS[np.where(short, 9 - decimals, 0)], 0)
    # more than 9 decimals: divided down, the remainder rounded half to even
    scale = _TENS[np.where(short, 0, decimals - 9)]
    quotient, remainder = np.divmod(whole, scale)
    half = scale // 2
    up = (remainder > half) | ((remainder == half) & (quotient % 2 == 1))
    ns = np.where(short, ns, quotient + up)
    ns = np.where(minus, -ns, ns)
    result = pa.array(ns, pa.int64(), mask=~kept)
    odd = ~np.isnan(values) & ~kept
    if odd.any():  # (exponents, inf, NaN: rare)
        values = result.to_pylist()
        for i in odd.nonzero()[0]:
            exact = nanoseconds(seconds[int(i)].as_py())
            values[i] = exact if exact is not None and abs(exact) <= LARGEST else None
        result = pa.array(values, pa.int64())
    return result


def exponent(pa: Any, pc: Any, text: Any, size: np.ndarray) -> np.ndarray:
    """Which of Arrow's texts of doubles (of magnitude ``size``) have an exponent: only
    from EXPONENT_FROM or below EXPONENT_BELOW are they looked at (a search of every
    text cost as much as the rest of a column's conversion)."""
    found = np.zeros(len(size), bool)
    looked = np.flatnonzero((size >= EXPONENT_FROM) | (size < EXPONENT_BELOW))
    if len(looked):
        found[looked] = _numpy(pc.fill_null(pc.match_substring(
            text.take(pa.array(looked)), "e"), False))
    return found


def _numpy(array: Any) -> np.ndarray:
    return array.to_numpy(zero_copy_only=False)
