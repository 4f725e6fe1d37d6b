"""A window of recordings as a ROS 2 bag (``gx2ctl export --format ros2``): a rosbag2
directory, ``metadata.yaml`` and one ``.mcap`` (storage ``mcap``, serialization
``cdr``, ``ros2msg`` schemas), written whole by rosbags' own writer (its Writer
makes the MCAP file and ``metadata.yaml`` as rosbag2 does; its typestore serializes
the messages): the optional extra ``gx2-gateway[ros2]``.

Per node, named in ROS's terms (:func:`ros_name`):

- ``sensor_msgs/msg/Imu`` on ``/gx2/<name>/imu`` for each record with an acceleration,
  an angular rate or an orientation (:data:`GIVES`): ``linear_acceleration`` in m/s^2,
  ``angular_velocity`` in rad/s, ``orientation`` from the record's matrix or Euler
  angles; what the record lacks, or has as NaN (any element of a vector or matrix), is
  unset (the message's defaults: zero, the identity), its covariance's element 0 -1
  (REP-145);
- ``sensor_msgs/msg/MagneticField`` on ``/gx2/<name>/mag`` (tesla) for each record with
  a finite ``mag``;
- ``tf2_msgs/msg/TFMessage`` on ``/tf``: the node's frame in the world frame, for each
  record with an orientation.

Frames and units: :mod:`.rep103` (REP-103's ENU/FLU, or the device's NED/FRD with
``frame="ned"``). Covariances are zero, which ROS reads as unknown: the GX2's
protocol reference gives no noise figures to fill them with. Every message's
``header.stamp`` is the sample's ``time`` to the nanosecond the recording wrote
(:func:`~.columns.nanoseconds`), and so is its log time in the bag; ``frame_id`` the
node's name. A record without a ``time`` (a reply with no timer) gives nothing.

The bag is written under a temporary directory beside it and moved into place when it
is whole: an export that fails or is interrupted leaves no cut bag, and replaces an
earlier bag (``--force``) only with a whole one.
"""

from __future__ import annotations

import contextlib
import json
import re
import shutil
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gateway.common.payloads import as_published
from gateway.common.topics import parse

from . import rep103
from .columns import nanoseconds
from .files import METADATA, STATUS, RecordingError
from .parquetfile import MissingExtra
from .reader import Entry, read_all
from .reports import Reading
from .tables import TEMPORARY

INSTALL_ROS2 = "pip install 'gx2-gateway[ros2]'"
IMU = "sensor_msgs/msg/Imu"
MAG = "sensor_msgs/msg/MagneticField"
TF = "tf2_msgs/msg/TFMessage"
TF_TOPIC = "/tf"
BAG_VERSION = 8
"""rosbag2's metadata version: 8 keeps each topic's offered QoS profiles as one YAML
string (as every version before it did), which later rosbag2s read too."""
METADATA_FILE = "metadata.yaml"
SECONDS_LIMIT = 2**31
"""builtin_interfaces/Time's ``sec`` is an int32: a later stamp is none."""


@dataclass(frozen=True)
class Gives:
    """What one record gives ROS: the fields behind each part of its messages."""

    accel: str | None = None
    rate: str | None = None
    orientation: str | None = None
    """``orientation`` (its matrix), ``euler`` (roll, pitch, yaw), or None."""
    mag: str | None = None

    @property
    def imu(self) -> bool:
        return bool(self.accel or self.rate or self.orientation)


GIVES: dict[str, Gives] = {
    "accel_angrate": Gives("accel", "ang_rate"),
    "accel_angrate_orientation": Gives("accel", "ang_rate", "orientation"),
    "accel_angrate_mag": Gives("accel", "ang_rate", mag="mag"),
    "accel_angrate_mag_orientation": Gives("accel", "ang_rate", "orientation", "mag"),
    "orientation": Gives(orientation="orientation"),
    "euler": Gives(orientation="euler"),
    "euler_angrate": Gives(rate="ang_rate", orientation="euler"),
    "mag": Gives(mag="mag"),
    "delta_angle_velocity_mag": Gives(mag="mag"),
}
"""The records that give ROS messages. Not these: the delta records' integrals over a
cycle (not an instant's rate or acceleration), the complementary filter's estimates
(``stab_accel``, ``stab_mag``: gravity's direction and the earth's field, not what
was measured), raw A/D codes, biases and settings."""


class BagError(Exception):
    """A bag that cannot be written where asked: one line for the user."""


class NoMessages(BagError):
    """A window none of whose records gives a ROS 2 message: nothing was written."""


def ros2_modules() -> tuple[Any, Any, Any]:
    """rosbags' writer, its typestore and numpy; MissingExtra saying how to install."""
    try:
        import numpy
        from rosbags import rosbag2
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise MissingExtra(f"ROS 2 export needs rosbags: {INSTALL_ROS2}") from None
    return rosbag2, get_typestore(Stores.ROS2_JAZZY), numpy


def ros_name(name: str | None, address: int) -> str:
    """A node's name as a ROS name token: its configured name (``gx2-<address>`` for one
    without, as the live view's frames name it), each run of characters ROS does not
    take (all but letters, digits and ``_``) one ``_``, none at its ends, and ``gx2_``
    before one that would start with a digit: ``left-wing`` is ``left_wing``,
    ``gx2-76`` ``gx2_76``."""
    token = re.sub(r"[^A-Za-z0-9]+", "_", name or f"gx2-{address}").strip("_")
    if not token or token[0].isdigit():
        token = f"gx2_{token}" if token else f"gx2_{address}"
    return token


def configured_names(paths: Iterable[Path]) -> dict[int, str]:
    """Each node's name as the files' gateways were configured (their metadata record,
    at a file's start; a later file's over an earlier's); a file without one (``gx2ctl
    record``'s), or that cannot be read, names none."""
    from mcap.records import Chunk, Message, Metadata
    from mcap.stream_reader import StreamReader
    names: dict[int, str] = {}
    for path in paths:
        with contextlib.suppress(Exception), path.open("rb") as stream:
            for record in StreamReader(stream).records:
                if isinstance(record, (Chunk, Message)):
                    break
                if isinstance(record, Metadata) and record.name == METADATA:
                    for node in json.loads(record.metadata.get("nodes") or "[]"):
                        if isinstance(node, dict) and isinstance(node.get("address"), int) \
                                and node.get("name"):
                            names[node["address"]] = str(node["name"])
                    break
    return names


@dataclass
class Bag:
    """What one bag holds: each topic's type and count, in the order first written."""

    path: Path
    frame: str
    topics: dict[str, tuple[str, int]] = field(default_factory=dict)
    records: dict[tuple[int, str], int] = field(default_factory=dict)
    """The records read, by (node, record), those that gave nothing included."""

    @property
    def messages(self) -> int:
        return sum(count for _, count in self.topics.values())

    def gave_nothing(self) -> str:
        """Which records were read, for a bag that would be empty."""
        return "; ".join(f"node {node}: {record} ({count:,})"
                         for (node, record), count in sorted(self.records.items()))


class BagWriter:
    """One bag, written under its temporary directory and moved into place whole."""

    def __init__(self, path: Path, frame: str, names: Mapping[int, str],
                 force: bool = False) -> None:
        self.rosbag2, self.types, numpy = ros2_modules()
        check_target(path, force)
        self.bag = Bag(path, frame)
        self._names = dict(names)
        """Names as configured (or as a status said them), by address."""
        self._nodes: dict[int, str] = {}
        """Each node's ROS name, fixed by its first record in the bag."""
        self._connections: dict[str, Any] = {}
        t = self.types.types
        self._time, self._header = t["builtin_interfaces/msg/Time"], t["std_msgs/msg/Header"]
        self._quaternion = t["geometry_msgs/msg/Quaternion"]
        self._vector = t["geometry_msgs/msg/Vector3"]
        self._imu, self._mag, self._tf = t[IMU], t[MAG], t[TF]
        self._transform = t["geometry_msgs/msg/Transform"]
        self._stamped = t["geometry_msgs/msg/TransformStamped"]
        self._unknown = numpy.zeros(9)
        """Covariance not known (all zero, REP-145): the reference gives no figures."""
        self._absent = numpy.array([-1.0] + [0.0] * 8)
        """The quantity is not in the message (element 0 -1, REP-145)."""
        self._world = rep103.WORLD[frame]
        self._temporary = path.parent / TEMPORARY.format(name=path.name)
        self._writer: Any = None
        try:  # (a Ctrl-C while the bag is opened, its temporary made: nothing left)
            if self._temporary.exists():  # (a killed export's: the name is its own)
                shutil.rmtree(self._temporary)
            self._temporary.mkdir(parents=True)
            self._open(path, frame)
        except BaseException:
            self.discard()
            raise

    def _open(self, path: Path, frame: str) -> None:
        self._writer = self.rosbag2.Writer(self._temporary / path.name, version=BAG_VERSION,
                                           storage_plugin=self.rosbag2.StoragePlugin.MCAP)
        self._writer.set_custom_data("gx2.frame", frame)
        # each chunk of the MCAP file zstd-compressed, as rosbag2's own mcap presets do
        # (a quarter of the size; every MCAP reader decompresses chunks)
        self._writer.set_compression(self.rosbag2.CompressionMode.STORAGE,
                                     self.rosbag2.CompressionFormat.ZSTD)
        self._writer.open()

    def named(self, status: Mapping[str, Any]) -> None:
        """A status's names of its nodes (for nodes not yet in the bag)."""
        nodes = status.get("nodes")
        for listed in nodes if isinstance(nodes, list) else ():
            if isinstance(listed, dict) and isinstance(listed.get("node"), int) \
                    and listed.get("name"):
                self._names[listed["node"]] = str(listed["name"])

    def _ros_name(self, address: int) -> str:
        name = self._nodes.get(address)
        if name is None:
            name = ros_name(self._names.get(address), address)
            # (two names ROS would make one; or the world frame's, either frame's so a
            # node's name does not hang on --frame: its /tf would be a loop on itself)
            if name in self._nodes.values() or name in rep103.WORLD.values():
                name = f"{name}_{address}"
            self._nodes[address] = name
        return name

    def add(self, node: int, record: str, payload: dict[str, Any]) -> None:
        """One record: the messages it gives, if any."""
        self.bag.records[node, record] = self.bag.records.get((node, record), 0) + 1
        gives = GIVES.get(record)
        stamp = nanoseconds(payload.get("time"))
        if gives is None or stamp is None or not 0 <= stamp < SECONDS_LIMIT * 10**9:
            return
        payload = as_published(payload)
        frame = self.bag.frame
        name = self._ros_name(node)
        header = self._header(stamp=self._time(sec=stamp // 10**9, nanosec=stamp % 10**9),
                              frame_id=name)
        turned = self._orientation(gives, payload)
        if gives.imu:
            accel = _vector(payload, gives.accel)
            rate = _vector(payload, gives.rate)
            zero = self._vector(x=0.0, y=0.0, z=0.0)
            imu = self._imu(
                header=header,  # (unset: the message's defaults, a zero vector and the
                # identity, beside the covariance that says it is not there)
                orientation=self._quaternion(x=turned[1], y=turned[2], z=turned[3],
                                             w=turned[0])
                if turned else self._quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
                orientation_covariance=self._unknown if turned else self._absent,
                angular_velocity=(self._vector(*rep103.body(rate, frame)) if rate
                                  else zero),
                angular_velocity_covariance=self._unknown if rate else self._absent,
                linear_acceleration=(self._vector(*rep103.acceleration(accel, frame))
                                     if accel else zero),
                linear_acceleration_covariance=self._unknown if accel else self._absent)
            self._write(f"/gx2/{name}/imu", IMU, imu, stamp)
        mag = _vector(payload, gives.mag)
        if mag:
            field_ = self._mag(header=header,
                               magnetic_field=self._vector(*rep103.magnetic_field(mag, frame)),
                               magnetic_field_covariance=self._unknown)
            self._write(f"/gx2/{name}/mag", MAG, field_, stamp)
        if turned:
            moved = self._stamped(
                header=self._header(stamp=header.stamp, frame_id=self._world),
                child_frame_id=name,
                transform=self._transform(
                    translation=self._vector(x=0.0, y=0.0, z=0.0),
                    rotation=self._quaternion(x=turned[1], y=turned[2], z=turned[3],
                                              w=turned[0])))
            self._write(TF_TOPIC, TF, self._tf(transforms=[moved]), stamp)

    def _orientation(self, gives: Gives, payload: Mapping[str, Any]
                     ) -> tuple[float, float, float, float] | None:
        """The record's orientation in the frames asked (w, x, y, z); None if it has
        none, or a NaN."""
        if gives.orientation == "orientation":
            matrix = payload.get("orientation")
            if not (isinstance(matrix, list) and len(matrix) == 3
                    and all(isinstance(row, list) and len(row) == 3
                            and rep103.finite(row) for row in matrix)):
                return None
            turned = rep103.orientation(matrix, self.bag.frame)
        elif gives.orientation == "euler":
            angles = [payload.get(key) for key in ("roll", "pitch", "yaw")]
            if not rep103.finite(angles):  # type: ignore[arg-type]
                return None
            turned = rep103.orientation_of_euler(*angles, self.bag.frame)  # type: ignore[misc]
        else:
            return None
        return turned if rep103.finite(turned) else None

    def _write(self, topic: str, kind: str, message: Any, stamp: int) -> None:
        connection = self._connections.get(topic)
        if connection is None:
            connection = self._connections[topic] = self._writer.add_connection(
                topic, kind, typestore=self.types)
        self._writer.write(connection, stamp, self.types.serialize_cdr(message, kind))
        _, count = self.bag.topics.get(topic, (kind, 0))
        self.bag.topics[topic] = (kind, count + 1)

    def finish(self) -> Bag:
        """The bag closed (``metadata.yaml`` written) and moved into place."""
        self._writer.close()
        self._writer = None
        path = self.bag.path
        if path.exists():  # (an earlier bag, --force: check_target)
            path.rename(self._replaced)
        (self._temporary / path.name).rename(path)
        shutil.rmtree(self._temporary, ignore_errors=True)
        return self.bag

    @property
    def _replaced(self) -> Path:
        """Where finish puts an earlier bag while the new one moves into its place."""
        return self._temporary / ".replaced"

    def discard(self) -> None:
        """Nothing left of the bag: its temporary directory goes (the writer first); an
        earlier bag finish had moved aside, its place still empty, goes back."""
        if self._writer is not None:
            with contextlib.suppress(Exception):
                self._writer.close()
        path = self.bag.path
        if self._replaced.exists() and not (path.exists() or path.is_symlink()):
            with contextlib.suppress(OSError):
                self._replaced.rename(path)
        shutil.rmtree(self._temporary, ignore_errors=True)


def _vector(payload: Mapping[str, Any], name: str | None) -> list[float] | None:
    """The field ``name`` as a vector; None (not in the message, REP-145's -1) if it is
    not three finite numbers: a NaN (a null in the recording) is no reading."""
    value = payload.get(name) if name else None
    if isinstance(value, list) and len(value) == 3 and rep103.finite(value):
        return value
    return None


def check_target(path: Path, force: bool) -> None:
    """BagError, saying what to do, if a bag may not be written at ``path``: something
    is there (a bag is a new directory, as ``ros2 bag record`` makes one), unless
    ``force`` and it is an earlier bag (:func:`replaceable`)."""
    if not (path.exists() or path.is_symlink()):
        return
    if not force:
        raise BagError(f"{path} exists: a ROS 2 bag is a new directory: export to a new "
                       "--out, or give --force to replace an earlier bag")
    why = replaceable(path)
    if why is not None:
        raise BagError(f"{path} {why}: --force replaces only an earlier bag; export to a "
                       "new --out")


def replaceable(path: Path) -> str | None:
    """Why ``--force`` may not replace ``path`` (None: it may): only a bag is replaced,
    a directory holding ``metadata.yaml`` and storage files (``.mcap``, ``.db3``, and
    their compressed forms), nothing else."""
    if path.is_symlink() or not path.is_dir():
        return "is not a directory"
    contents = [p.name for p in path.iterdir()]
    if METADATA_FILE not in contents:
        return f"holds no {METADATA_FILE}: not a rosbag2"
    others = [name for name in contents if name != METADATA_FILE
              and not re.search(r"\.(mcap|db3)(\.zstd)?$", name)]
    if others:
        return f"holds more than a bag ({others[0]})"
    return None


def export_bag(paths: Iterable[Path], out: Path, reading: Reading, frame: str = "enu",
               progress: Callable[[int], None] | None = None,
               entries: Iterable[Entry] | None = None, names: Mapping[int, str] = (),
               force: bool = False) -> Bag:
    """The records of ``paths`` (or ``entries``, a window of them) as a bag at ``out``;
    BagError, and nothing written, if no record gives a message (the line says which
    records there were); MissingExtra without rosbags. ``names``: the nodes' names
    (:func:`configured_names`). On any error, or Ctrl-C, no bag is left cut."""
    paths = list(paths)
    writer = BagWriter(out, frame, names or {}, force)
    try:
        for entry in read_all(paths, reading) if entries is None else entries:
            if progress is not None:
                progress(len(entry.data))
            if entry.topic == STATUS:
                with contextlib.suppress(RecordingError):
                    writer.named(entry.payload())
                continue
            where = parse(entry.topic)
            if where is None:
                continue
            writer.add(*where, entry.payload())
        if not writer.bag.messages:
            read_ = writer.bag.gave_nothing()
            raise NoMessages("no record gives a ROS 2 message (Imu, MagneticField, /tf)"
                           + (f": the window holds {read_}" if read_ else
                              ": the window holds no record"))
        return writer.finish()
    except BaseException:
        writer.discard()
        raise


__all__ = ["GIVES", "Bag", "BagError", "NoMessages", "check_target", "configured_names",
           "export_bag", "replaceable", "ros2_modules", "ros_name"]
