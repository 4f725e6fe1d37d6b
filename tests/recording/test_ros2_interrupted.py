"""``gx2ctl export --format ros2`` stopped by Ctrl-C in the middle of a bag: exit 130,
one line, no bag and no temporary left, and an earlier bag that ``--force`` was to
replace untouched (it is replaced only by a whole one)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from tests.helpers.processes import interrupted, script

pytest.importorskip("rosbags.rosbag2")

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
try:
    from exportformats import recording  # (the bench's 60,000-row recording, made alike)
finally:
    sys.path.pop(0)


def test_ctrl_c_leaves_no_bag_and_the_earlier_one_whole(tmp_path: Path) -> None:
    source = recording(tmp_path / "big.mcap", 60_000)
    bag = tmp_path / "bag"
    bag.mkdir()
    earlier = {"metadata.yaml": "rosbag2_bagfile_information: {version: 8}\n",
               "bag.mcap": "an earlier export's"}
    for name, text in earlier.items():
        (bag / name).write_text(text)
    temporary = tmp_path / ".bag.partial"
    status, stdout, stderr = interrupted(
        [script("gx2ctl"), "export", str(source), "--out", str(bag), "--format", "ros2",
         "--force"], temporary.exists, "the export to begin its bag")
    assert (status, stdout) == (130, ""), stderr
    assert stderr == f"gx2ctl: interrupted: nothing was left at {bag}\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag", "big.mcap"]
    assert {p.name: p.read_text() for p in bag.iterdir()} == earlier
