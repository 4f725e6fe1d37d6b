"""Retention through the real gateway and gx2-sim, under small limits
(``record.keep_gb``, ``record.keep_days``): finished recordings deleted oldest first,
each deletion logged, never the file being written nor a file the gateway did not
name; status says what the recordings take and which is the oldest kept."""

from __future__ import annotations

import os
import re
import time
from pathlib import Path

from mcap.reader import make_reader

from gateway.recording.files import file_name
from gateway.sim.node import NodeSettings
from tests.helpers.waiting import wait_for

NODES = [{"address": 76, "stream": "accel_angrate"}]
KEEP_BYTES = 30_000
ROTATE_BYTES = 5_000
DELETED = re.compile(r"recording: deleted (\S+) \(.*\): (.*)$", re.M)


def seed(directory: Path, age_days: float, size: int) -> Path:
    """A finished recording of ``size`` bytes last written ``age_days`` ago."""
    modified = time.time() - age_days * 86400
    path = directory / file_name(modified - 3600)
    path.write_bytes(bytes(size))
    os.utime(path, (modified, modified))
    return path


def test_retention_keeps_the_newest_recordings_within_the_limits(simulator, gateway,
                                                                   tmp_path):
    directory = tmp_path / "recordings"
    directory.mkdir()
    ancient = seed(directory, 40, 1_000)
    recent = [seed(directory, 1, 10_000), seed(directory, 0.5, 10_000)]
    foreign = directory / "calibration.mcap"
    foreign.write_bytes(bytes(50_000))
    sim = simulator(NodeSettings(76))
    gw = gateway(sim.path, NODES, record={
        "directory": str(directory), "keep_days": 10, "keep_gb": KEEP_BYTES / 1e9,
        "rotate_mb": ROTATE_BYTES / 1e6})
    gw.wait_streaming(76)
    wait_for(lambda: not ancient.exists(), 5, "the file older than 10 days deleted")
    # then files it wrote itself, rotated every few kB, are deleted for the space
    wait_for(lambda: len(DELETED.findall(gw.log())) >= 5, 20, "its own files deleted")
    status = gw.status()["recording"]
    current = Path(status["file"])
    kept = sorted(p for p in directory.glob("gx2-*.mcap"))
    assert current.exists() and kept[-1] == current
    assert status["oldest"] == str(kept[0])
    assert status["bytes"] <= KEEP_BYTES + 2 * ROTATE_BYTES, status
    assert foreign.exists(), "a file the gateway did not name was deleted"
    state, _ = gw.terminate()
    assert state == 0

    deleted = DELETED.findall(gw.log())
    names = [name for name, _ in deleted]
    assert names[:3] == [ancient.name, *(p.name for p in recent)], deleted
    assert names == sorted(names), "not oldest first"
    assert deleted[0][1] == "older than keep_days 10"
    assert all(re.fullmatch(r"the recordings took \d+\.\d kB, over keep_gb 3e-05", why)
               for _, why in deleted[1:]), deleted
    # what is left: the newest, each finished and readable
    left = sorted(directory.glob("gx2-*.mcap"))
    assert left and set(names).isdisjoint(p.name for p in left)
    assert sum(p.stat().st_size for p in left) <= KEEP_BYTES + 3 * ROTATE_BYTES
    for path in left:
        with path.open("rb") as stream:
            assert make_reader(stream).get_summary() is not None, path
