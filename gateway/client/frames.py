"""Records as a pandas DataFrame, the same live and offline: a row per record, the
columns ``gx2ctl export`` gives (vectors as ``accel_x``.., matrices as
``orientation_11``..), ``time`` and ``host_time`` as UTC timestamps (to the
nanosecond the message wrote; NaT where a record has none, as an untimed reply, or one
no timestamp holds, past the year 2262),
``device_time`` a duration; a Recording's with its time refined, ``time_placed`` and
``time_bound_ms`` after ``time``, as export's. pandas is optional.

The instants are whole nanoseconds from start to end, never a float: a column of
nanoseconds holding one None (an untimed record's ``time``) would be made float64 by
pandas before it became timestamps, and a UNIX time in nanoseconds as a double is off
by up to 128 ns."""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

from gateway.recording.columns import nanoseconds
from gateway.recording.parquetfile import MissingExtra
from gateway.recording.tables import BOUND, PLACED, element, field_columns

from .messages import Event, Message

if TYPE_CHECKING:
    import pandas

INSTALL_PANDAS = "pip install 'gx2-gateway[pandas]'"
LEADING = ("gateway", "node", "record", "seq", "gap", "restarted", "time", "host_time",
           "device_time", "lqi", "rssi")
"""The columns every row has, before the record's fields."""
INSTANTS = {"time": "datetime64[ns]", "host_time": "datetime64[ns]",
            "device_time": "timedelta64[ns]"}
"""The columns of nanoseconds, and what they become."""
NOT_A_TIME = -(2 ** 63)
"""numpy's NaT as an int64: a record without the time."""


def _pandas() -> Any:
    try:
        import pandas
    except ImportError:
        raise MissingExtra(f"to_pandas needs pandas: {INSTALL_PANDAS}") from None
    return pandas


def to_pandas(events: Iterable[Event]) -> pandas.DataFrame:
    """A DataFrame of the messages among ``events`` (a :class:`Recording`, a list of
    what a Subscriber gave; heartbeats are left out), in their order. MissingExtra,
    saying how to install it, without pandas."""
    pd = _pandas()
    import numpy as np

    layouts: dict[str, list[tuple[str, str, int]]] = {}
    rows = []
    instants: dict[str, list[int]] = {name: [] for name in INSTANTS}
    for event in events:
        if not isinstance(event, Message):
            continue
        layout = layouts.get(event.record)
        if layout is None:
            layout = layouts[event.record] = field_columns(event.record, event.payload)
        for name, value in (("time", event.time),
                            ("host_time", event.payload.get("host_time")),
                            ("device_time", event.device_time)):
            found = nanoseconds(value)
            instants[name].append(found if found is not None and NOT_A_TIME < found < -NOT_A_TIME
                                  else NOT_A_TIME)  # (none, or past what a timestamp holds)
        row = {"gateway": event.gateway, "node": event.node, "record": event.record,
               "seq": event.seq, "gap": event.gap, "restarted": event.restarted,
               "time": None}  # (the instants in their places, set below)
        if PLACED in event.payload:  # (a Recording's, its time refined: export's columns)
            row[PLACED], row[BOUND] = event.payload[PLACED], event.payload[BOUND]
        row.update(host_time=None, device_time=None, lqi=event.lqi, rssi=event.rssi)
        for column, name, index in layout:
            row[column] = element(event.payload.get(name), index)
        rows.append(row)
    frame = pd.DataFrame(rows, columns=None if rows else list(LEADING))
    for name, kind in INSTANTS.items():
        exact = np.array(instants[name], dtype=np.int64).view(kind)
        frame[name] = pd.Series(exact, index=frame.index)
    frame["time"] = frame["time"].dt.tz_localize("UTC")
    frame["host_time"] = frame["host_time"].dt.tz_localize("UTC")
    return frame
