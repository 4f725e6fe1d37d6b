"""``gx2ctl export --format ros2`` on a recording the installed gateway made of gx2-sim:
a trial between two marks as a rosbag2, read back by readers that share no code with
the gateway's writer: rosbags' own reader and CDR deserializer, and the ``mcap``
package's reader with mcap-ros2-support's ROS 2 decoder; ``metadata.yaml`` read with
PyYAML. The expected values come from the recording's JSON as the ``mcap`` package
reads it (times taken exactly as the JSON wrote them), and from the simulator's
physics: at rest on a turning body, the acceleration turned into the world is
gravity's reaction, straight up, and the magnetometer turned into the world is the
earth's field, whatever the conversion's formulas."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
from collections import Counter
from collections.abc import Iterator
from decimal import ROUND_HALF_EVEN, Decimal
from pathlib import Path
from typing import Any

import pytest
import yaml
import zmq
from mcap.reader import make_reader

from gateway.sim.node import GX2, NodeSettings
from gateway.sim.physics import EARTH_FIELD, Motion
from gateway.sim.server import Simulator
from tests.helpers.gateway import RunningGateway, gateway_config
from tests.helpers.processes import STARTUP, gx2ctl, gx2ctl_here, script
from tests.helpers.waiting import wait_for

rosbag2 = pytest.importorskip("rosbags.rosbag2")
typesys = pytest.importorskip("rosbags.typesys")
mcap_ros2 = pytest.importorskip("mcap_ros2.decoder")
Rotation = pytest.importorskip("scipy.spatial.transform").Rotation

G = 9.80665
DIVIDER = 2048  # 25 Hz: three nodes' records well within the line
SWING = Motion(roll=0.3, pitch=-0.2, yaw_rate=0.5, swing=0.4)
NODES = [{"address": 76, "name": "left-wing", "stream": "accel_angrate_mag_orientation"},
         {"address": 77, "stream": "euler_angrate"},
         {"address": 95, "name": "tail", "stream": "accel_angrate_mag"}]
ROS_NAMES = {76: "left_wing", 77: "gx2_77", 95: "tail"}
# the body frame (FLU) from the sensor's (FRD), and ENU from NED: written out here
B = ((1, 0, 0), (0, -1, 0), (0, 0, -1))
W = ((0, 1, 0), (1, 0, 0), (0, 0, -1))


def exact_ns(seconds: Decimal) -> int:
    return int((seconds * 10**9).to_integral_value(ROUND_HALF_EVEN))


def stamp_ns(header: Any) -> int:
    return header.stamp.sec * 10**9 + header.stamp.nanosec


def matmul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(3)) for j in range(3)] for i in range(3)]


def turn(r, v):
    return [sum(r[i][k] * v[k] for k in range(3)) for i in range(3)]


def matrix(q: Any) -> list[list[float]]:
    return Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix().tolist()


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Iterator[dict[str, Any]]:
    """A recording of three nodes (a 3DM-GX2 streaming its matrix and magnetometer, an
    unnamed node its Euler angles, an Inertia-Link without magnetometer), with marks
    ``start`` and ``stop`` about two seconds apart."""
    base = tmp_path_factory.mktemp("ros2")
    context = zmq.Context()
    sim = Simulator([NodeSettings(76, model=GX2, stream=NODES[0]["stream"], motion=SWING,
                                  divider=DIVIDER),
                     NodeSettings(77, stream=NODES[1]["stream"], motion=SWING,
                                  divider=DIVIDER),
                     NodeSettings(95, stream=NODES[2]["stream"], divider=DIVIDER)],
                    link=base / "gx2").start()
    directory = base / "recordings"
    gw = RunningGateway(gateway_config(sim.path, NODES, record={"directory": str(directory)}),
                        base, context)
    try:
        wait_for(lambda: (gw.control.try_call("status", timeout=0.5) or {}).get("ok"),
                 STARTUP, "the gateway to answer")
        gw.wait_streaming(76, 77, 95)
        control = ("--control", gw.control_endpoint)
        sub = gw.subscribe("gx2/7")
        sub.drain(0.5)
        assert gx2ctl(*control, "mark", "start").status == 0
        sub.drain(2.0)
        assert gx2ctl(*control, "mark", "stop").status == 0
        sub.drain(0.5)
        status, _ = gw.terminate()
        assert status == 0, gw.log()
    finally:
        gw.close()
        sim.stop()
        context.destroy(linger=0)
    yield {"base": base, "directory": directory}


def recording(directory: Path) -> tuple[dict[str, int], dict[tuple[int, int], dict]]:
    """The marks' log times, and every record a node streams by (node, exact time in ns)
    with its log time, as the ``mcap`` package reads the files (times as the JSON wrote
    them; a node's other records, as its start reply, left out)."""
    streams = {f"gx2/{n['address']}/{n['stream']}" for n in NODES}
    marks: dict[str, int] = {}
    records: dict[tuple[int, int], dict] = {}
    for path in sorted(directory.glob("*.mcap")):
        with path.open("rb") as stream:
            for _, channel, message in make_reader(stream).iter_messages():
                if channel.topic == "gx2/gateway/mark":
                    marks[json.loads(message.data)["text"]] = message.log_time
                    continue
                if channel.topic not in streams:
                    continue
                payload = json.loads(message.data, parse_float=Decimal)
                payload["log_time"] = message.log_time
                records[payload["node"], exact_ns(payload["time"])] = payload
    return marks, records


def in_trial(directory: Path) -> dict[tuple[int, int], dict]:
    """The records of the trial: read from the start mark to the stop mark."""
    marks, records = recording(directory)
    return {key: p for key, p in records.items()
            if marks["start"] <= p["log_time"] < marks["stop"]}


def export(recorded: dict[str, Any], name: str, *args: str) -> tuple[Path, Any]:
    out = recorded["base"] / name
    ran = gx2ctl("export", str(recorded["directory"]), "--out", str(out), "--format",
                 "ros2", *args)
    return out, ran


@pytest.fixture(scope="module")
def trial(recorded) -> dict[str, Any]:
    out, ran = export(recorded, "trial", "--between-marks", "start", "stop", "--trial", "1")
    assert ran.status == 0, ran.stderr
    (bag,) = out.iterdir()
    assert bag.name.startswith("trial-1_")
    return {"bag": bag, "stdout": ran.stdout, "records": in_trial(recorded["directory"])}


def read_rosbags(bag: Path) -> list[tuple[str, str, int, Any]]:
    """(topic, type, log time, message) of every message, by rosbags."""
    store = typesys.get_typestore(typesys.Stores.ROS2_JAZZY)
    found = []
    with rosbag2.Reader(bag) as reader:
        for connection, timestamp, data in reader.messages():
            found.append((connection.topic, connection.msgtype, timestamp,
                          store.deserialize_cdr(data, connection.msgtype)))
    return found


def read_mcap_ros2(bag: Path) -> list[tuple[str, str, int, Any, Any, Any]]:
    """(topic, schema name, log time, message, schema, channel) of every message, by
    the mcap package's reader and mcap-ros2-support's decoder."""
    (path,) = bag.glob("*.mcap")
    found = []
    with path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[mcap_ros2.DecoderFactory()])
        # a ROS 2 bag's MCAP (rosbag2's profile), its chunks compressed as rosbag2's are
        assert reader.get_header().profile == "ros2"
        assert {c.compression for c in reader.get_summary().chunk_indexes} == {"zstd"}
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            found.append((channel.topic, schema.name, message.log_time, decoded, schema,
                          channel))
    return found


def test_the_trial_reads_back_through_rosbags_each_record_at_its_time(trial) -> None:
    records = trial["records"]
    messages = read_rosbags(trial["bag"])
    counts = Counter((topic, kind) for topic, kind, _, _ in messages)
    per_node = Counter(node for node, _ in records)
    assert min(per_node.values()) > 20, per_node
    # every node record gives an Imu; the GX2's its field; the oriented ones a /tf each
    assert counts == {
        ("/gx2/left_wing/imu", "sensor_msgs/msg/Imu"): per_node[76],
        ("/gx2/gx2_77/imu", "sensor_msgs/msg/Imu"): per_node[77],
        ("/gx2/tail/imu", "sensor_msgs/msg/Imu"): per_node[95],
        ("/gx2/left_wing/mag", "sensor_msgs/msg/MagneticField"): per_node[76],
        ("/tf", "tf2_msgs/msg/TFMessage"): per_node[76] + per_node[77]}
    by_name = {name: node for node, name in ROS_NAMES.items()}
    seen = set()
    for topic, _, log_time, message in messages:
        if topic == "/tf":
            (moved,) = message.transforms
            header, node = moved.header, by_name[moved.child_frame_id]
            assert header.frame_id == "world"
            assert moved.transform.translation.x == moved.transform.translation.y == 0
        else:
            header, node = message.header, by_name[topic.split("/")[2]]
            assert header.frame_id == ROS_NAMES[node]
            seen.add((node, stamp_ns(header)))
        # the stamp is the sample's time to the nanosecond, and so is the bag's log time
        assert (node, stamp_ns(header)) in records, (topic, stamp_ns(header))
        assert log_time == stamp_ns(header)
    assert seen == set(records)


def test_units_frames_and_orientation_hold_to_the_records_and_the_physics(trial) -> None:
    records = trial["records"]
    checked = Counter()
    for topic, _, _, message in read_rosbags(trial["bag"]):
        if topic == "/tf":
            continue
        node = {n: a for a, n in ROS_NAMES.items()}[topic.split("/")[2]]
        record = records[node, stamp_ns(message.header)]
        number = {k: [math.nan if v is None else float(v) for v in record[k]]
                  for k in ("accel", "ang_rate", "mag") if k in record}
        if topic.endswith("/mag"):
            # gauss to tesla, the sensor's frame (FRD) to FLU
            field = message.magnetic_field
            assert [field.x, field.y, field.z] == pytest.approx(
                [v * 1e-4 for v in turn(B, number["mag"])], rel=1e-12)
            assert not message.magnetic_field_covariance.any()
            checked["mag"] += 1
            continue
        imu = message
        if "accel" in number:  # g to m/s^2, FRD to FLU
            assert [imu.linear_acceleration.x, imu.linear_acceleration.y,
                    imu.linear_acceleration.z] == pytest.approx(
                [v * G for v in turn(B, number["accel"])], rel=1e-12, abs=1e-12)
            assert not imu.linear_acceleration_covariance.any()
        else:
            assert imu.linear_acceleration_covariance[0] == -1
        assert [imu.angular_velocity.x, imu.angular_velocity.y, imu.angular_velocity.z] \
            == pytest.approx(turn(B, number["ang_rate"]), rel=1e-12, abs=1e-12)
        if "roll" not in record:  # (the Inertia-Link's accel_angrate_mag: none)
            assert imu.orientation_covariance[0] == -1
            q = imu.orientation  # (left as the message's default: the identity)
            assert (q.x, q.y, q.z, q.w) == (0, 0, 0, 1)
            checked["no orientation"] += 1
            continue
        assert not imu.orientation_covariance.any()
        r_enu = matrix(imu.orientation)
        # back to the device's frames, its Euler angles (ZYX) are the record's own
        r_ned = matmul(matmul(W, r_enu), B)
        yaw, pitch, roll = Rotation.from_matrix(r_ned).as_euler("ZYX")
        for got, want in ((roll, record["roll"]), (pitch, record["pitch"]),
                          (yaw, record["yaw"])):
            assert math.remainder(got - float(want), math.tau) == pytest.approx(0, abs=1e-5)
        if "accel" in number:
            # at rest, turned into the world (ENU), the acceleration is gravity's
            # reaction, straight up; the field the earth's (north, east, down given)
            up = turn(r_enu, [imu.linear_acceleration.x, imu.linear_acceleration.y,
                              imu.linear_acceleration.z])
            assert up == pytest.approx([0, 0, G], abs=2e-5)
            north, east, down = EARTH_FIELD
            mag_flu = [v * 1e-4 for v in turn(B, number["mag"])]
            assert turn(r_enu, mag_flu) == pytest.approx(
                [east * 1e-4, north * 1e-4, -down * 1e-4], abs=1e-9)
            checked["physics"] += 1
        checked["euler"] += 1
    assert checked["physics"] > 20 and checked["euler"] > 40 and checked["mag"] > 20
    assert checked["no orientation"] > 20


def test_the_mcap_ros2_decoder_reads_the_same_messages(trial) -> None:
    by_rosbags = read_rosbags(trial["bag"])
    by_mcap = read_mcap_ros2(trial["bag"])
    assert len(by_mcap) == len(by_rosbags)
    for _, name, log_time, decoded, schema, channel in by_mcap:
        assert (schema.encoding, channel.message_encoding) == ("ros2msg", "cdr")
        assert name == {"/tf": "tf2_msgs/msg/TFMessage"}.get(
            channel.topic, "sensor_msgs/msg/MagneticField" if channel.topic.endswith("/mag")
            else "sensor_msgs/msg/Imu")
        header = decoded.transforms[0].header if channel.topic == "/tf" else decoded.header
        assert stamp_ns(header) == log_time
    # message for message, the same values by both readers
    key = {"/tf": lambda m: (m.transforms[0].child_frame_id, stamp_ns(m.transforms[0].header))}

    def values(topic: str, m: Any) -> tuple:
        if topic == "/tf":
            r = m.transforms[0].transform.rotation
            return (r.x, r.y, r.z, r.w)
        if topic.endswith("/mag"):
            f = m.magnetic_field
            return (f.x, f.y, f.z)
        return (m.orientation.x, m.orientation.y, m.orientation.z, m.orientation.w,
                m.angular_velocity.x, m.linear_acceleration.z,
                *m.orientation_covariance, *m.linear_acceleration_covariance)

    def keyed(topic: str, m: Any) -> tuple:
        return (topic, *key.get(topic, lambda m: (stamp_ns(m.header),))(m))

    mine = {keyed(t, m): values(t, m) for t, _, _, m in by_rosbags}
    theirs = {keyed(t, m): values(t, m) for t, _, _, m, _, _ in by_mcap}
    assert len(mine) == len(by_rosbags)
    assert mine.keys() == theirs.keys()
    for k, v in mine.items():
        assert list(theirs[k]) == pytest.approx(list(v), nan_ok=True), k


def test_metadata_yaml_says_what_ros2_bag_info_shows(trial) -> None:
    bag = trial["bag"]
    messages = read_rosbags(bag)
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    stamps = [t for _, _, t, _ in messages]
    (mcap_file,) = bag.glob("*.mcap")
    assert meta["storage_identifier"] == "mcap"
    assert meta["version"] == 8
    assert meta["relative_file_paths"] == [mcap_file.name]
    assert meta["message_count"] == len(messages)
    assert meta["starting_time"]["nanoseconds_since_epoch"] == min(stamps)
    assert meta["duration"]["nanoseconds"] == max(stamps) - min(stamps)
    assert 1.5 < meta["duration"]["nanoseconds"] / 1e9 < 10
    topics = {t["topic_metadata"]["name"]: t for t in meta["topics_with_message_count"]}
    counts = Counter(topic for topic, _, _, _ in messages)
    assert {name: t["message_count"] for name, t in topics.items()} == counts
    assert {t["topic_metadata"]["serialization_format"] for t in topics.values()} == {"cdr"}
    assert topics["/tf"]["topic_metadata"]["type"] == "tf2_msgs/msg/TFMessage"
    assert topics["/gx2/left_wing/imu"]["topic_metadata"]["type"] == "sensor_msgs/msg/Imu"
    assert meta["custom_data"] == {"gx2.frame": "enu"}
    # what export said, a line a topic
    said = {line.split()[1]: int(line.split()[2].replace(",", ""))
            for line in trial["stdout"].splitlines()}
    assert said == counts


def test_frame_ned_keeps_the_devices_frames(recorded) -> None:
    out, ran = export(recorded, "ned", "--frame", "ned", "--node", "76")
    assert ran.status == 0, ran.stderr
    _, records = recording(recorded["directory"])
    messages = read_rosbags(out)
    assert {topic for topic, _, _, _ in messages} == {
        "/gx2/left_wing/imu", "/gx2/left_wing/mag", "/tf"}
    assert len(messages) == 3 * sum(node == 76 for node, _ in records)
    for topic, _, _, message in messages:
        if topic == "/tf":
            (moved,) = message.transforms
            assert moved.header.frame_id == "world_ned"
            q = moved.transform.rotation
            record = records[76, stamp_ns(moved.header)]
            # the sensor in the NED world: the rotation taking body coordinates to the
            # world's, M transposed (V_sensor = M . V_earth), by scipy, not by the
            # aspp.orientation the exporter uses; q and -q are one rotation. (The device's
            # matrix is single precision, not exactly orthonormal: scipy's nearest
            # rotation and aspp's differ by some 1e-9; a transpose's error is ~0.1 and up)
            m = [[float(v) for v in row] for row in record["orientation"]]
            transposed = [[m[j][i] for j in range(3)] for i in range(3)]
            x, y, z, w = Rotation.from_matrix(transposed).as_quat()
            sign = 1 if q.w * w + q.x * x + q.y * y + q.z * z >= 0 else -1
            assert [sign * v for v in (q.w, q.x, q.y, q.z)] == pytest.approx(
                [w, x, y, z], abs=1e-6)
            # and it turns the body's axes as M's rows say: body x is M's first row
            assert turn(matrix(q), [1, 0, 0]) == pytest.approx(m[0], abs=1e-6)
        elif topic.endswith("/imu"):
            record = records[76, stamp_ns(message.header)]
            assert message.linear_acceleration.z == pytest.approx(
                float(record["accel"][2]) * G, rel=1e-12)
            assert message.angular_velocity.y == pytest.approx(
                float(record["ang_rate"][1]), rel=1e-12)
    meta = yaml.safe_load((out / "metadata.yaml").read_text())
    assert meta["rosbag2_bagfile_information"]["custom_data"] == {"gx2.frame": "ned"}


def test_a_users_mistakes_get_one_line_and_leave_nothing(recorded, tmp_path) -> None:
    directory = str(recorded["directory"])
    existing = tmp_path / "existing"
    existing.mkdir()
    (existing / "notes.txt").write_text("mine")
    ran = gx2ctl_here("export", directory, "--out", str(existing), "--format", "ros2")
    assert ran.status == 2, ran
    assert ran.stderr == (f"gx2ctl: {existing} exists: a ROS 2 bag is a new directory: "
                          "export to a new --out, or give --force to replace an earlier "
                          "bag\n")
    # --force replaces an earlier bag, never a directory of something else
    ran = gx2ctl_here("export", directory, "--out", str(existing), "--format", "ros2", "--force")
    assert ran.status == 2 and len(ran.stderr.splitlines()) == 1, ran
    assert "holds no metadata.yaml: not a rosbag2" in ran.stderr
    assert [p.name for p in tmp_path.iterdir()] == ["existing"]
    assert [p.name for p in existing.iterdir()] == ["notes.txt"]

    bag = tmp_path / "bag"
    assert gx2ctl_here("export", directory, "--out", str(bag), "--format", "ros2",
                       "--node", "95").status == 0
    ran = gx2ctl_here("export", directory, "--out", str(bag), "--format", "ros2", "--force",
                      "--node", "77")
    assert ran.status == 0, ran
    assert {t for t, _, _, _ in read_rosbags(bag)} == {"/gx2/gx2_77/imu", "/tf"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag", "existing"]

    ran = gx2ctl_here("export", directory, "--out", str(tmp_path / "t"), "--frame", "ned")
    assert (ran.status, ran.stderr) == (2, "gx2ctl: --frame is for --format ros2 "
                                           "(--format csv keeps the device's frames, as "
                                           "recorded)\n")
    ran = gx2ctl_here("export", directory, "--out", str(tmp_path / "none"), "--format", "ros2",
                      "--record", "euler_angrate", "--node", "95")
    assert ran.status == 2 and len(ran.stderr.splitlines()) == 1, ran
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag", "existing"]


def test_an_interrupted_export_leaves_no_bag(recorded, tmp_path) -> None:
    """Every failure past the first message (here: the disk refusing a write, as it does
    when full) leaves neither the bag nor its temporary directory."""
    if shutil.which("prlimit") is None:
        pytest.skip("prlimit is missing")
    bag = tmp_path / "bag"
    ran = subprocess.run(["prlimit", "--fsize=20000", script("gx2ctl"), "export",
                          str(recorded["directory"]), "--out", str(bag),
                          "--format", "ros2"], capture_output=True, text=True, timeout=60)
    assert ran.returncode == 2 and len(ran.stderr.splitlines()) == 1, ran
    assert list(tmp_path.iterdir()) == []
