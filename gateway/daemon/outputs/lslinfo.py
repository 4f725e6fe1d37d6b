"""What an LSL stream of the gateway says of itself: its name, type, channels (label,
unit, type) and the rest of its ``desc``, by LSL's meta-data conventions (XDF's
``channels/channel/label,unit,type`` and ``synchronization`` blocks), and its
``source_id``. Built from a record's first payload and the record table
(:mod:`aspp.records`); pylsl is handed in, never imported here."""

from __future__ import annotations

from collections.abc import Mapping
from types import ModuleType
from typing import Any, NamedTuple

from aspp.records import BY_NAME, derived
from gateway.recording.tables import field_columns

STREAM_TYPES: dict[str, str] = {
    "raw_sensors": "IMU", "accel_angrate": "IMU", "delta_angle_velocity": "IMU",
    "accel_angrate_orientation": "IMU", "accel_angrate_mag": "IMU",
    "accel_angrate_mag_orientation": "IMU", "stab_accel_angrate_mag": "IMU",
    "delta_angle_velocity_mag": "IMU",
    "orientation": "Orientation", "orientation_update": "Orientation",
    "euler": "Orientation", "euler_angrate": "Orientation",
    "mag": "Magnetometer", "temperatures": "Temperature",
}
"""Each streamable record's LSL stream type: what it mainly carries (IMU: acceleration
and angular rate, or their deltas; Orientation: a matrix or Euler angles)."""
CHANNEL_TYPES: dict[str, str] = {
    "accel": "Acceleration", "stab_accel": "Acceleration", "raw_accel": "Acceleration",
    "ang_rate": "AngularVelocity", "raw_ang_rate": "AngularVelocity",
    "mag": "MagneticField", "stab_mag": "MagneticField",
    "orientation": "OrientationMatrix", "orientation_update": "OrientationMatrix",
    "roll": "Orientation", "pitch": "Orientation", "yaw": "Orientation",
    "quaternion": "OrientationQuaternion",
    "delta_angle": "DeltaAngle", "delta_velocity": "DeltaVelocity",
    "temperature": "Temperature",
}
"""Each field's channel type in ``desc/channels/channel/type``."""
UNITLESS = "normalized"
"""The unit of a field without one (an orientation matrix's direction cosines), as
XDF's meta-data conventions write a dimensionless channel's."""
LEFT_OUT = frozenset(("timer",))
"""Fields of the record table that are no channel (the link fields, lqi and rssi, and
the bookkeeping are not in the record table's fields to begin with)."""



class Channel(NamedTuple):
    """One channel of a stream: one scalar of one of the record's fields."""

    label: str
    """As ``gx2ctl export`` names its column (``accel_x``, ``orientation_12``)."""
    unit: str
    kind: str
    """Its ``type`` in the stream's desc (CHANNEL_TYPES)."""
    field: str
    index: int
    """Its element of the field's value (row-major for a matrix); -1: the value."""


def channels(record: str, payload: Mapping[str, Any]) -> list[Channel]:
    """A record's channels: its fields' scalars in the record table's order, then those
    the gateway adds to a record with a matrix (roll, pitch, yaw, the quaternion), the
    timer left out (the link fields and the bookkeeping are no fields of the table)."""
    spec = BY_NAME.get(record)
    units = {f.name: f.unit or UNITLESS for f in (*(spec.reply or ()), *derived(spec))} \
        if spec is not None else {}
    return [Channel(column, units.get(field, ""), CHANNEL_TYPES.get(field, field), field,
                    index)
            for column, field, index in field_columns(record, payload)
            if field not in LEFT_OUT]


def source_id(host: str, station: str, node: int, record: str) -> str:
    """What LabRecorder re-finds a stream by when it comes back (a gateway restarted):
    the same on every start for the same host, station, node and record."""
    return f"{host}/{station}/{node}/{record}"


def node_name(node_status: Mapping[str, Any] | None) -> str:
    """A node's name as its stream's desc says it (``gx2/name``; empty for none)."""
    return str((node_status or {}).get("name") or "")


def describe(pylsl: ModuleType, prefix: str, payload: Mapping[str, Any],
             node_status: Mapping[str, Any] | None, rate: float, host: str,
             latency_ms: float | None) -> tuple[str, Any, list[tuple[str, int]]]:
    """The StreamInfo of a node's record, from its first payload: (name, info, picks)."""
    node, record = payload["node"], payload["record"]
    station = payload.get("station", "")
    name = f"{prefix}-{node}-{record}"
    spec = BY_NAME.get(record)
    layout = channels(record, payload)
    info = pylsl.StreamInfo(name, STREAM_TYPES.get(record, "IMU"), len(layout), rate,
                            pylsl.cf_float32, source_id(host, station, node, record))
    desc = info.desc()
    desc.append_child_value("manufacturer", "MicroStrain")
    desc.append_child_value("model", "3DM-GX2")
    described = desc.append_child("channels")
    for channel in layout:
        element = described.append_child("channel")
        element.append_child_value("label", channel.label)
        element.append_child_value("unit", channel.unit)
        element.append_child_value("type", channel.kind)
    sync = desc.append_child("synchronization")
    # XDF's meta-data conventions (the "synchronization" block of a stream's desc)
    sync.append_child_value("can_drop_samples", "true")
    sync.append_child_value(
        "time_source", "sample instants: the gateway's time of each record (the node's "
        "timer through its clock line to the host's monotonic clock), less "
        "base_station.latency_ms; not when the gateway pushed it")
    # the node's clock when the stream was made (an XDF file keeps the header it was
    # given, however long the recording): its drift only once locked, as a drift still
    # settling (0.0 from the first points) was never measured; status has it now
    clock = (node_status or {}).get("clock") or {}
    locked = clock.get("locked") is True
    sync.append_child_value("clock_locked_at_start", str(locked).lower())
    if locked and clock.get("drift_ppm") is not None:
        sync.append_child_value("clock_drift_ppm_at_start", str(clock["drift_ppm"]))
    if latency_ms is not None:
        sync.append_child_value("latency_ms", str(latency_ms))
    gx2 = desc.append_child("gx2")
    gx2.append_child_value("node", str(node))
    gx2.append_child_value("name", node_name(node_status))
    gx2.append_child_value("station", str(station))
    gx2.append_child_value("record", record)
    if spec is not None:
        gx2.append_child_value("command", f"0x{spec.code:02X}")
    gx2.append_child_value("gateway", host)
    return name, info, [(channel.field, channel.index) for channel in layout]
