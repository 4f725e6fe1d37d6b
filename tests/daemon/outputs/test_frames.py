"""A node's frame (gx2/<address>/frame): made from its orientation records as the
gateway publishes them (Node.tally), the same rotation from the matrix as from the
euler angles of the same instant, given to the live view and the recorder and never
to ZeroMQ, and nothing for a record without an orientation."""

from __future__ import annotations

import math
from typing import Any

import pytest
from jsonschema import Draft202012Validator

from aspp.frame import encode_reply_packet
from aspp.records import decode
from aspp.timing import TICKS_PER_SECOND
from gateway.common.schemas import schema_for_topic
from gateway.daemon.config import NodeEntry
from gateway.daemon.outputs import Message, Output, Outputs
from gateway.daemon.outputs.frames import PARENT_FRAME, Frames
from gateway.daemon.station.nodes import Node
from gateway.sim.node import NodeSettings, SimNode
from gateway.sim.physics import Motion

UNIX = 1_750_000_000.0


def published(node: Node, reply: bytes, at: float) -> dict[str, Any]:
    raw = encode_reply_packet(node.address, reply)
    return node.tally(raw, decode(raw, 7, len(raw) - 4), UNIX + at, at)


def both_at_once(t: float) -> tuple[dict[str, Any], dict[str, Any]]:
    """The orientation and euler records one simulated node sends for one instant, as
    the gateway publishes them (each through a node of the gateway's own)."""
    sim = SimNode(NodeSettings(77, motion=Motion(roll=0.5, pitch=-0.4, yaw_rate=0.9,
                                                 swing=0.6)), 0.0)
    orientation = published(Node(NodeEntry(address=77)), sim.record(0xC5, t), t + 0.01)
    euler = published(Node(NodeEntry(address=77)), sim.record(0xCE, t), t + 0.01)
    assert orientation["timer"] == euler["timer"]  # (one instant)
    return orientation, euler


@pytest.mark.parametrize("t", [0.3, 2.2, 5.75])
def test_a_matrix_records_angles_are_its_euler_records_and_its_frame_the_same(t) -> None:
    orientation, euler = both_at_once(t)
    # float32 on the wire: the node's own angles and ours from its matrix, to its digits
    for angle in ("roll", "pitch", "yaw"):
        assert orientation[angle] == pytest.approx(euler[angle], abs=2e-6), angle
    w, x, y, z = orientation["quaternion"]
    assert w >= 0 and w * w + x * x + y * y + z * z == pytest.approx(1.0, abs=1e-12)
    frames = Frames({77: "right-wing"}.get)
    of_matrix = frames.maker(77, "orientation")(orientation)  # type: ignore[misc]
    of_euler = frames.maker(77, "euler")(euler)  # type: ignore[misc]
    assert of_matrix is not None and of_euler is not None
    assert of_matrix.topic == of_euler.topic == b"gx2/77/frame"
    a, b = of_matrix.payload, of_euler.payload
    assert a["rotation"] == {"x": x, "y": y, "z": z, "w": w}
    assert [a["rotation"][k] for k in "xyzw"] == pytest.approx(
        [b["rotation"][k] for k in "xyzw"], abs=2e-6)
    assert a["child_frame_id"] == "right-wing" and a["parent_frame_id"] == PARENT_FRAME
    assert a["translation"] == {"x": 0.0, "y": 0.0, "z": 0.0}
    stamp = a["timestamp"]["sec"] * 10**9 + a["timestamp"]["nsec"]
    assert stamp == round(orientation["time"] * 1e9)  # the sample's instant
    assert of_matrix.times == (orientation["host_time"], orientation["time"])
    name, schema = schema_for_topic("gx2/77/frame")  # type: ignore[misc]
    assert name == "foxglove.FrameTransform"
    Draft202012Validator(schema).validate(a)
    # the record's own schema describes what it now carries
    Draft202012Validator(schema_for_topic("gx2/77/orientation")[1]).validate(  # type: ignore[index]
        {**orientation, "orientation": [list(r) for r in orientation["orientation"]],
         "quaternion": list(orientation["quaternion"])})


def test_which_records_give_a_frame_and_its_name() -> None:
    frames = Frames({76: None, 77: "tail"}.get)
    for record in ("orientation", "accel_angrate_orientation",
                   "accel_angrate_mag_orientation", "euler", "euler_angrate"):
        assert frames.maker(76, record) is not None, record
    for record in ("accel_angrate", "orientation_update", "delta_angle_velocity", "mag"):
        assert frames.maker(76, record) is None, record
    timer = 3 * TICKS_PER_SECOND
    euler = {"roll": 0.0, "pitch": 0.0, "yaw": math.pi / 2, "timer": timer,
             "host_time": UNIX + 1, "time": UNIX + 0.5}
    assert frames.maker(76, "euler")(euler).payload["child_frame_id"] == "gx2-76"  # type: ignore[misc, union-attr]
    assert frames.maker(77, "euler")(euler).payload["child_frame_id"] == "tail"  # type: ignore[misc, union-attr]
    # no frame for what has none to give: a NaN angle, a replayed time in nanoseconds
    assert frames.maker(76, "euler")({**euler, "yaw": math.nan}) is None  # type: ignore[misc]
    assert frames.maker(76, "euler")({**euler, "time": UNIX * 1e9}) is None  # type: ignore[misc]
    assert frames.maker(76, "euler")({**euler, "roll": None}) is None  # type: ignore[misc]
    # a matrix record recorded before records carried a quaternion, replayed: its matrix's
    old = {"orientation": [[0, 1, 0], [-1, 0, 0], [0, 0, 1]], "timer": timer,
           "host_time": UNIX + 1, "time": UNIX + 0.5}
    turned = frames.maker(76, "orientation")(old).payload["rotation"]  # type: ignore[misc, union-attr]
    assert turned == pytest.approx({"x": 0, "y": 0, "z": math.sqrt(0.5), "w": math.sqrt(0.5)})


class Publication(Output):
    def __init__(self) -> None:
        self.sent: list[bytes] = []

    def send(self, topic: bytes, payload: dict[str, Any]) -> bool:
        self.sent.append(topic)
        return True


class Takes(Output):
    def __init__(self) -> None:
        self.messages: list[Message] = []

    def take(self, message: Message) -> None:
        self.messages.append(message)


def test_the_frame_goes_to_the_live_view_and_recorder_never_to_zeromq() -> None:
    publication, live, record = Publication(), Takes(), Takes()
    outputs = Outputs({"zeromq": publication, "live": live, "recording": record},
                      Frames({77: None}.get))
    orientation, _ = both_at_once(1.0)
    plain = {"accel": (0, 0, -1), "ang_rate": (0, 0, 0), "host_time": UNIX, "time": UNIX}
    assert outputs.publish(77, "orientation", orientation)
    assert outputs.publish(77, "accel_angrate", plain)
    assert publication.sent == [b"gx2/77/orientation", b"gx2/77/accel_angrate"]
    for output in (live, record):
        assert [m.topic for m in output.messages] == [
            b"gx2/77/orientation", b"gx2/77/frame", b"gx2/77/accel_angrate"]
    assert live.messages[1] is record.messages[1]  # (one message, its JSON made once)
    assert outputs.published() == {77: {"orientation": 1, "accel_angrate": 1}}


def test_a_replayed_nan_quaternion_gives_no_frame_and_the_record_is_published() -> None:
    """A recording holds NaN as null: a matrix record's quaternion replayed as four
    nulls (and its matrix as nine) gives no frame, and is published all the same, as
    the gateway published it (NaN again), to every output; the next record's frame is
    made as ever."""
    publication, live = Publication(), Takes()
    outputs = Outputs({"zeromq": publication, "live": live}, Frames({77: None}.get))
    orientation, _ = both_at_once(1.0)
    recorded = {**orientation, "orientation": [[None] * 3] * 3, "quaternion": [None] * 4,
                "roll": None, "pitch": None, "yaw": None}
    assert outputs.replayed("gx2/77/orientation", recorded)
    assert outputs.replayed("gx2/77/orientation", {
        **orientation, "orientation": [list(row) for row in orientation["orientation"]],
        "quaternion": list(orientation["quaternion"])})
    assert publication.sent == [b"gx2/77/orientation"] * 2
    assert [m.topic for m in live.messages] == [
        b"gx2/77/orientation", b"gx2/77/orientation", b"gx2/77/frame"]
    nan = live.messages[0].payload
    assert all(math.isnan(v) for v in (*nan["quaternion"], nan["roll"], nan["orientation"][1][2]))
    assert outputs.take_failures == {}


def test_a_frame_that_cannot_be_made_is_counted_and_the_record_goes_on(
        caplog: pytest.LogCaptureFixture) -> None:
    """Making a frame is guarded as a take is: a maker that raises (a bug) is counted
    under ``frames`` (status, metrics, the gateway's WARN), said once, and the record
    still reaches every output and ZeroMQ."""
    publication, live = Publication(), Takes()
    frames = Frames({77: None}.get)

    def broken(node: int, record: str) -> Any:
        def make(payload: dict[str, Any]) -> Message | None:
            raise RuntimeError("a bug in the frame")
        return make
    frames.maker = broken  # type: ignore[method-assign]
    outputs = Outputs({"zeromq": publication, "live": live}, frames)
    orientation, _ = both_at_once(1.0)
    for _ in range(3):
        assert outputs.publish(77, "orientation", dict(orientation))
    assert publication.sent == [b"gx2/77/orientation"] * 3
    assert [m.topic for m in live.messages] == [b"gx2/77/orientation"] * 3
    assert outputs.take_failures == {"frames": 3}
    assert outputs.guard_status() == {"live": {"take_failures": 0},
                                      "frames": {"take_failures": 3}}
    said = [r.getMessage() for r in caplog.records if "frame" in r.getMessage()]
    assert said == ["output frames failed to make the frame of a record: RuntimeError: a "
                    "bug in the frame (counted; not logged again for this output and "
                    "error)"]


def test_a_frame_is_named_as_its_node_is_now() -> None:
    """The child frame's name is read for each frame from the nodes' states (a reload
    names, renames or adds a node there), never fixed at the first record."""
    names: dict[int, str | None] = {77: "left"}
    make = Frames(names.get).maker(77, "orientation")
    assert make is not None
    orientation, _ = both_at_once(1.0)
    assert make(orientation).payload["child_frame_id"] == "left"  # type: ignore[union-attr]
    names[77] = "right"
    assert make(orientation).payload["child_frame_id"] == "right"  # type: ignore[union-attr]
    names[77] = None
    assert make(orientation).payload["child_frame_id"] == "gx2-77"  # type: ignore[union-attr]
