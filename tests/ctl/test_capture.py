"""The file ``gx2ctl record`` writes, as its reader meets it while it is written: a
mark is readable as soon as it is taken (issue 43), not at the next second's flush."""

from __future__ import annotations

from pathlib import Path

from gateway.client import Recording
from gateway.ctl.record import Capture, Marked, Progress


def test_a_mark_is_readable_as_soon_as_record_takes_it(tmp_path: Path) -> None:
    target = tmp_path / "capture.mcap"
    capture = Capture(target, {})
    try:
        progress = Progress(target, terminal=False)
        capture.add(Marked({"text": "go", "time": 1_795_000_000.5,
                            "host_time": 1_795_000_000.5, "nodes": []}), progress)
        assert [mark.text for mark in Recording(target).marks()] == ["go"]
    finally:
        capture.finish()
