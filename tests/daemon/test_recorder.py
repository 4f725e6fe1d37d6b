"""The daemon's recorder on real files: the loop's side never waits, the thread
rotates and finishes files, and what it cannot write is counted."""

from __future__ import annotations

import io
import threading
import time
from pathlib import Path
from typing import Any

from mcap.reader import NonSeekingReader, make_reader

from gateway.daemon.config import RecordConfig
from gateway.daemon.recorder import Recorder
from tests.helpers.waiting import wait_for

SLACK = 0.3
"""Seconds a close may overrun its time on a loaded machine (a thread's wake-up)."""


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


class SlowDisk:
    """Files whose every write to the OS takes ``delay`` s once the disk is made slow (a
    network share, an SD card stalling); buffered as a file opened by Python is."""

    def __init__(self, delay: float) -> None:
        self.delay = delay
        self.slow = threading.Event()
        self.released = threading.Event()
        self.files: list[Path] = []

    def create(self, path: Path) -> Any:
        disk = self

        class Slow(io.FileIO):
            def write(self, data: Any) -> int:
                if disk.slow.is_set():
                    disk.released.wait(disk.delay)
                return super().write(data)
        file = io.BufferedWriter(Slow(path, "xb"))
        self.files.append(path)
        return file


def readable(path: Path) -> tuple[int, bool]:
    """(messages mcap's front-to-back reader gets, whether the file was finished)."""
    count = 0
    with path.open("rb") as stream:
        try:
            for _ in NonSeekingReader(stream).iter_messages(log_time_order=False):
                count += 1
        # the end of what reached the disk: where the reader was (a record's length, a
        # struct) says how, not whether, it was cut short
        except Exception:
            return count, False
    return count, True


def test_a_backlog_the_disk_cannot_take_in_time_is_cut_and_the_file_finished(tmp_path):
    """Far more queued than a disk taking 0.1 s a write can take in the time close() is
    given (all of it takes some 40 writes, and 0.9 s to encode here), and the thread
    writing it when close() comes: close returns in time, the file finished with what
    it took, the rest counted as dropped."""
    disk = SlowDisk(0.1)
    recorder = Recorder(RecordConfig(directory=str(tmp_path), queue=10_000_000), {},
                        create=disk.create)
    queued = 300_000
    for seq in range(queued):
        recorder.serial(b"\xaa" * 40, 1.0 + seq, 1.0)
    disk.slow.set()
    recorder.start()
    wait_for(lambda: recorder.written, 5, "the thread to be writing the backlog")
    start = time.monotonic()
    recorder.close(timeout=1.0)
    took = time.monotonic() - start
    assert took < 1.0 + SLACK, f"close took {took:.2f} s"
    assert readable(disk.files[0]) == (recorder.written, True)
    assert 0 < recorder.written < queued, recorder.written
    assert recorder.written + recorder.dropped == queued


def test_a_disk_too_slow_for_the_summary_leaves_the_file_readable_to_its_last_chunk(
        tmp_path, caplog):
    disk = SlowDisk(10.0)
    recorder = Recorder(RecordConfig(directory=str(tmp_path)), {}, create=disk.create)
    recorder.start()
    for seq in range(100):
        recorder.serial(b"\xaa" * 40, 1.0 + seq, 1.0)
    wait_for(lambda: disk.files and readable(disk.files[0])[0] == 100, 5,
             "the first chunk flushed")
    disk.slow.set()  # from now on the disk takes 10 s a write
    for seq in range(100, 150):
        recorder.serial(b"\xaa" * 40, 1.0 + seq, 1.0)
    start = time.monotonic()
    try:
        recorder.close(timeout=0.5)
        took = time.monotonic() - start
        assert took < 0.5 + SLACK, f"close took {took:.2f} s"
        assert readable(disk.files[0]) == (100, False)
        said = [r.message for r in caplog.records if "left unfinished" in r.message]
        assert len(said) == 1 and "\n" not in said[0], said
    finally:
        disk.released.set()  # the thread left behind finishes, and the test with it
        recorder._thread.join(5)
