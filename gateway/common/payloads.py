"""A recorded record's payload made again as the gateway published it: the one
normalisation of what comes back from a recording, for everything that reads one as
records (gateway.client's :class:`~gateway.client.Recording`, and a replay's
republished messages, given to every output of the replaying gateway).

A recording's JSON holds NaN as null (strict JSON has no NaN), so a sample's NaN (an
Inertia-Link's magnetometer, a matrix the node could not compute) comes back as None,
where the gateway published a float; and a file written before the gateway added a
matrix's roll, pitch, yaw and quaternion (:data:`aspp.records.DERIVED_FROM_MATRIX`)
has none of them. What reads it back as records gets the floats and the fields it
would have got live: the nulls of a record's own fields NaN again, the derived fields
derived from the matrix where the file lacks them (absent where there is no matrix to
derive them from, or none a float holds). The bookkeeping's nulls stay None: an
untimed record's ``time`` is no NaN.
"""

from __future__ import annotations

import math
from typing import Any

BOOKKEEPING = frozenset(("node", "record", "command", "seq", "host_time", "time",
                         "device_time", "lqi", "rssi", "time_placed", "time_bound_ms"))
"""Keys every record carries besides its own fields (and the two a recording's record
read with its time refined after the fact gains: gateway.recording.refined)."""
MATRIX = "orientation"
"""The field of the records with an orientation matrix (:data:`aspp.records.ORIENTED`),
the one the derived fields are computed from."""


def as_published(payload: dict[str, Any]) -> dict[str, Any]:
    """``payload`` (a recorded record's, changed in place and returned) as the gateway
    published it: its own fields' nulls NaN again, in lists too (a vector, a matrix);
    a matrix's derived fields computed where it lacks them."""
    for name, value in payload.items():
        if name not in BOOKKEEPING:
            payload[name] = _nan(value)
    if MATRIX in payload:
        _derive(payload)
    return payload


def _nan(value: Any) -> Any:
    if value is None:
        return math.nan
    if isinstance(value, list):
        return [_nan(item) for item in value]
    return value


def _derive(payload: dict[str, Any]) -> None:
    """The fields :meth:`Node.tally <gateway.daemon.station.nodes.Node.tally>` adds to a
    record with a matrix, where the payload lacks them; none if the matrix is not one
    or no float holds it (a foreign file's: ``10**400``), so that reading a record
    never fails (a replay stopped there for good)."""
    # (imported here: gateway.client's live subscriber never pays for the record table)
    from aspp.orientation import euler_from_matrix, quaternion_from_matrix
    from aspp.records import DERIVED_FROM_MATRIX

    if all(field.name in payload for field in DERIVED_FROM_MATRIX):
        return
    matrix = payload[MATRIX]
    if not (isinstance(matrix, list) and len(matrix) == 3 and all(
            isinstance(row, list) and len(row) == 3 and all(
                isinstance(cell, float | int) and not isinstance(cell, bool)
                for cell in row) for row in matrix)):
        return
    # (DERIVED_FROM_MATRIX's order: the three angles, then the quaternion)
    try:
        values = (*euler_from_matrix(matrix), list(quaternion_from_matrix(matrix)))
    except (ArithmeticError, ValueError, TypeError):  # (an int no float holds)
        return
    for field, value in zip(DERIVED_FROM_MATRIX, values, strict=True):
        payload.setdefault(field.name, value)
