"""Strict JSON for published values: what gx2ctl prints and recordings hold.

msgpack carries NaN, infinities, bytes and integer keys; strict JSON has none of them,
and a parser that follows the standard rejects a file that uses them. NaN is common
(an Inertia-Link's magnetometer is NaN in every record), so it becomes ``null``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

import orjson

_encode = json.JSONEncoder(ensure_ascii=False, separators=(",", ":")).encode
_encode_strictly = json.JSONEncoder(ensure_ascii=False, separators=(",", ":"),
                                    allow_nan=False).encode


def strict(value: Any) -> Any:
    """A value JSON can carry strictly: NaN and infinities become null, bytes hex, keys
    strings (msgpack allows all of these; strict JSON parsers reject them)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if value is None or isinstance(value, (bool, int, str)):
        return value
    if isinstance(value, Mapping):
        return {str(key): strict(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [strict(item) for item in value]
    if isinstance(value, (bytes, bytearray, memoryview)):
        return bytes(value).hex()
    return str(value)


def compact(value: Mapping[str, Any]) -> str:
    """One strict JSON object, without spaces: a recorded message.

    The encoder runs on the map as it is and only a map it cannot carry (a NaN, bytes)
    is rebuilt through :func:`strict`: for a record without NaN that is 1.95x faster
    (bench/micro.py, "compact json")."""
    try:
        return _encode_strictly(value)
    except (ValueError, TypeError):
        return _encode(strict(value))


def compact_bytes(value: Mapping[str, Any]) -> bytes:
    """One strict JSON object, without spaces, as UTF-8: what a recording and the live
    view hold of a message.

    orjson, 16x faster than the standard library's encoder for the gateway's payloads
    (bench/jsonenc.py: 0.6 against 10 us a record, interleaved rounds; 18x for one
    with a NaN magnetometer). What it writes parses back to what :func:`compact`'s
    does (the bench checks every payload): NaN and the infinities as null (orjson's
    own rule, as :func:`strict`'s), floats in their shortest round-tripping form, keys
    in the map's order. What orjson refuses (bytes, keys that are not strings, an int
    past 64 bits) is rebuilt through :func:`strict`, as :func:`compact` does."""
    try:
        return orjson.dumps(value)
    except TypeError:  # (orjson.JSONEncodeError is one)
        return _encode(strict(value)).encode()


def json_line(value: Any) -> str:
    """One strict JSON object on one line (never NaN, never a newline inside)."""
    return json.dumps(strict(value), allow_nan=False, ensure_ascii=False)
