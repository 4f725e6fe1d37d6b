"""The daemon's recorder on real files: the loop's side never waits, the thread
rotates and finishes files, and what it cannot write is counted."""

from __future__ import annotations

import time
from pathlib import Path

from mcap.reader import make_reader

from gateway.daemon.config import RecordConfig
from gateway.daemon.recorder import Recorder
from tests.helpers.waiting import wait_for


def finished(path: Path) -> int:
    """The message count of a finished file (its summary says)."""
    with path.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None, f"{path} was not finished"
    return summary.statistics.message_count


def test_files_rotate_by_age_and_close_finishes_the_last(tmp_path):
    recorder = Recorder(RecordConfig(directory=str(tmp_path / "r"), rotate_minutes=0.01),
                        {"version": "test"})
    recorder.start()
    start = time.monotonic()
    sent = 0
    while time.monotonic() - start < 2.0:
        recorder.serial(b"\xaa" * 40, time.time(), time.monotonic())
        recorder.published(b"gx2/76/euler", {"roll": 0.1, "host_time": time.time()})
        sent += 2
        time.sleep(0.01)  # (a stream's pace, not a synchronisation)
    recorder.close()
    paths = sorted((tmp_path / "r").glob("*.mcap"))
    assert len(paths) >= 2, "no rotation by age (0.6 s) in 2 s"
    assert sum(finished(p) for p in paths) == sent == recorder.written
    assert recorder.dropped == 0


def test_a_full_queue_drops_and_counts_without_waiting(tmp_path):
    recorder = Recorder(RecordConfig(directory=str(tmp_path), queue=100), {})
    # not started: nothing drains the queue, as when the disk has stalled
    start = time.perf_counter()
    for _ in range(10_000):
        recorder.serial(b"x", 1.0, 1.0)
    assert time.perf_counter() - start < 0.5
    assert recorder.overflowed == 9_900 and recorder.status()["queued"] == 100
    recorder.start()
    recorder.close()
    assert recorder.written == 100 and recorder.status()["dropped"] == 9_900


def test_a_directory_that_cannot_be_made_is_counted_and_said_once(tmp_path, caplog):
    blocker = tmp_path / "file"
    blocker.write_text("a file where the directory should be")
    recorder = Recorder(RecordConfig(directory=str(blocker / "r")), {})
    recorder.start()
    for _ in range(50):
        recorder.serial(b"x", 1.0, 1.0)
    wait_for(lambda: recorder.lost == 50, 5, "the messages to be counted lost")
    recorder.close()
    assert recorder.errors >= 1 and recorder.status()["error"]
    assert sum("recording to" in r.message for r in caplog.records) == 1
