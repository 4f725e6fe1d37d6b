"""The ROS 2 bag's edges an outside review found (issue 47): a NaN reading, an earlier
bag --force replaces when the export is stopped between finish's two renames, the
library's ``export`` asked for ``ros2``, a node named as the world frame."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from gateway.recording.reports import Reading
from gateway.recording.writer import RecordingWriter

rosbag2 = pytest.importorskip("rosbags.rosbag2")
typesys = pytest.importorskip("rosbags.typesys")

from gateway.recording.rosbag import export_bag  # noqa: E402

I3 = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]
T0 = 1_795_000_000.5


def recording(path: Path, *records: tuple[int, str, dict]) -> Path:
    with path.open("wb") as output:
        writer = RecordingWriter(output)
        for i, (node, record, fields) in enumerate(records):
            at = T0 + i / 10
            writer.message(f"gx2/{node}/{record}", {
                "node": node, "record": record, "seq": i + 1, "host_time": at,
                "device_time": i / 10, "timer": i, "time": at, **fields})
        writer.finish()
    return path


def read(bag: Path) -> list[tuple[str, object]]:
    store = typesys.get_typestore(typesys.Stores.ROS2_JAZZY)
    with rosbag2.Reader(bag) as reader:
        return [(c.topic, store.deserialize_cdr(data, c.msgtype))
                for c, _, data in reader.messages()]


def test_a_nan_component_makes_the_vector_absent_not_a_reading(tmp_path: Path) -> None:
    source = recording(tmp_path / "r.mcap", (76, "accel_angrate_orientation", {
        "accel": [None, 0.0, -1.0], "ang_rate": [0.1, None, 0.0], "orientation": I3}))
    bag = tmp_path / "bag"
    export_bag([source], bag, Reading(), names={76: "n"})
    (imu,) = [m for topic, m in read(bag) if topic == "/gx2/n/imu"]
    for vector, covariance in ((imu.linear_acceleration, imu.linear_acceleration_covariance),
                               (imu.angular_velocity, imu.angular_velocity_covariance)):
        assert [vector.x, vector.y, vector.z] == [0.0, 0.0, 0.0]
        assert all(math.isfinite(v) for v in (vector.x, vector.y, vector.z))
        assert list(covariance) == [-1.0] + [0.0] * 8
    # the orientation, whole, is there
    assert list(imu.orientation_covariance) == [0.0] * 9


def test_stopped_between_finishs_renames_the_earlier_bag_survives(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    source = recording(tmp_path / "r.mcap", (76, "accel_angrate", {
        "accel": [0.0, 0.0, -1.0], "ang_rate": [0.0, 0.0, 0.0]}))
    bag = tmp_path / "bag"
    export_bag([source], bag, Reading())
    earlier = {p.name: p.read_bytes() for p in bag.iterdir()}
    real, calls = Path.rename, []

    def rename(self: Path, target: Path) -> Path:
        calls.append(self)
        if len(calls) == 2:  # Ctrl-C just after the earlier bag was moved aside
            raise KeyboardInterrupt
        return real(self, target)

    monkeypatch.setattr(Path, "rename", rename)
    with pytest.raises(KeyboardInterrupt):
        export_bag([source], bag, Reading(), force=True)
    monkeypatch.undo()
    assert calls[0] == bag  # (the earlier bag was moved aside first)
    assert {p.name: p.read_bytes() for p in bag.iterdir()} == earlier
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag", "r.mcap"]


@pytest.mark.parametrize("form", ["ros2", "xlsx"])
def test_the_librarys_export_refuses_a_format_not_a_tables_before_writing(
        tmp_path: Path, form: str) -> None:
    from gateway.recording.export import export
    source = recording(tmp_path / "r.mcap", (76, "accel_angrate", {
        "accel": [0.0, 0.0, -1.0], "ang_rate": [0.0, 0.0, 0.0]}))
    with pytest.raises(ValueError, match="export_bag" if form == "ros2" else "csv, parquet"):
        export([source], tmp_path / "out", Reading(), form=form)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("frame", ["enu", "ned"])
def test_a_node_named_as_a_world_frame_gets_its_address(tmp_path: Path, frame: str) -> None:
    source = recording(tmp_path / "r.mcap", (77, "orientation", {"orientation": I3}),
                       (78, "orientation", {"orientation": I3}))
    bag = tmp_path / "bag"
    export_bag([source], bag, Reading(), frame=frame, names={77: "world", 78: "world-ned"})
    moved = [m.transforms[0] for topic, m in read(bag) if topic == "/tf"]
    assert [(t.header.frame_id, t.child_frame_id) for t in moved] == [
        ("world" if frame == "enu" else "world_ned", name)
        for name in ("world_77", "world_ned_78")]
    assert {topic for topic, _ in read(bag)} == {
        "/tf", "/gx2/world_77/imu", "/gx2/world_ned_78/imu"}


def test_stopped_while_the_bag_is_opened_leaves_no_temporary(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """(test_ros2_interrupted's Ctrl-C, sent when the temporary appears, can land here:
    it left ``.bag.partial`` now and then.)"""
    source = recording(tmp_path / "r.mcap", (76, "accel_angrate", {
        "accel": [0.0, 0.0, -1.0], "ang_rate": [0.0, 0.0, 0.0]}))

    def interrupted(self: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(rosbag2.Writer, "open", interrupted)
    with pytest.raises(KeyboardInterrupt):
        export_bag([source], tmp_path / "bag", Reading())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.mcap"]
