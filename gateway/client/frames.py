"""Records as a pandas DataFrame, the same live and offline: a row per record, the
columns ``gx2ctl export`` gives (vectors as ``accel_x``.., matrices as
``orientation_11``..), ``time`` and ``host_time`` as UTC timestamps (to the
nanosecond the message wrote), ``device_time`` a duration. pandas is optional."""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

from gateway.recording.columns import nanoseconds
from gateway.recording.export import element, field_columns
from gateway.recording.parquetfile import MissingExtra

from .messages import Event, Message

if TYPE_CHECKING:
    import pandas

INSTALL_PANDAS = "pip install 'gx2-gateway[pandas]'"
LEADING = ("gateway", "node", "record", "seq", "gap", "restarted", "time", "host_time",
           "device_time", "lqi", "rssi")
"""The columns every row has, before the record's fields."""


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
    layouts: dict[str, list[tuple[str, str, int]]] = {}
    rows = []
    for event in events:
        if not isinstance(event, Message):
            continue
        layout = layouts.get(event.record)
        if layout is None:
            layout = layouts[event.record] = field_columns(event.record, event.payload)
        row = {"gateway": event.gateway, "node": event.node, "record": event.record,
               "seq": event.seq, "gap": event.gap, "restarted": event.restarted,
               "time": nanoseconds(event.time),
               "host_time": nanoseconds(event.payload.get("host_time")),
               "device_time": nanoseconds(event.device_time), "lqi": event.lqi,
               "rssi": event.rssi}
        for column, name, index in layout:
            row[column] = element(event.payload.get(name), index)
        rows.append(row)
    frame = pd.DataFrame(rows, columns=None if rows else list(LEADING))
    for name in ("time", "host_time"):
        frame[name] = pd.to_datetime(frame[name], unit="ns", utc=True)
    frame["device_time"] = pd.to_timedelta(frame["device_time"], unit="ns")
    return frame
