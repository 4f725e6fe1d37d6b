"""``gx2ctl export --format ros2`` stopped by Ctrl-C in the middle of a bag: exit 130,
one line, no bag and no temporary left, and an earlier bag that ``--force`` was to
replace untouched (it is replaced only by a whole one)."""

from __future__ import annotations

import signal
import subprocess
from pathlib import Path

import pytest

from gateway.recording.writer import RecordingWriter
from tests.helpers.processes import script
from tests.helpers.waiting import wait_for

pytest.importorskip("rosbags.rosbag2")

T0 = 1_795_000_000.0


def recording(path: Path, rows: int) -> Path:
    with path.open("wb") as output:
        writer = RecordingWriter(output)
        for i in range(rows):
            at = T0 + i / 100
            writer.message("gx2/76/accel_angrate_mag", {
                "accel": [0.001 * i, 0.002, -1.0], "ang_rate": [0.01, 0.02, 0.03],
                "mag": [0.2, 0.1, 0.4], "timer": i * 196_608, "node": 76,
                "record": "accel_angrate_mag", "command": 0xCB, "seq": i + 1,
                "host_time": at + 0.004, "lqi": 200, "rssi": -50,
                "device_time": i / 100, "time": at})
        writer.finish()
    return path


def test_ctrl_c_leaves_no_bag_and_the_earlier_one_whole(tmp_path: Path) -> None:
    source = recording(tmp_path / "big.mcap", 60_000)
    bag = tmp_path / "bag"
    bag.mkdir()
    earlier = {"metadata.yaml": "rosbag2_bagfile_information: {version: 8}\n",
               "bag.mcap": "an earlier export's"}
    for name, text in earlier.items():
        (bag / name).write_text(text)
    temporary = tmp_path / ".bag.partial"
    run = subprocess.Popen([script("gx2ctl"), "export", str(source), "--out", str(bag),
                            "--format", "ros2", "--force"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        wait_for(lambda: run.poll() is not None or temporary.exists(), 30,
                 "the export to begin its bag")
        run.send_signal(signal.SIGINT)
        stdout, stderr = run.communicate(timeout=30)
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
    assert (run.returncode, stdout) == (130, ""), stderr
    assert stderr == f"gx2ctl: interrupted: nothing was left at {bag}\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag", "big.mcap"]
    assert {p.name: p.read_text() for p in bag.iterdir()} == earlier
