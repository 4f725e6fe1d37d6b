"""The daemon's recorder on real files: the loop's side never waits, the thread
rotates and finishes files, and what it cannot write is counted."""

from __future__ import annotations

import asyncio
import errno
import io
import logging
import os
import threading
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from mcap.reader import NonSeekingReader, make_reader

from gateway.common.topics import MARK_TOPIC
from gateway.daemon.app import Gateway
from gateway.daemon.config import RecordConfig
from gateway.daemon.outputs import Message
from gateway.daemon.outputs import recorder as recorder_module
from gateway.daemon.outputs.recorder import MARK_KEPT_S, Recorder
from gateway.recording.files import file_name
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
        recorder.take(Message(b"gx2/76/euler", {"roll": 0.1, "host_time": time.time()}))
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


def test_a_mark_the_disk_is_too_slow_for_is_answered_in_time_said_and_its_wait_forgotten(
        tmp_path, caplog):
    """A mark on a disk whose writes take 3 s: the gateway's mark waits MARK_KEPT_S for
    it to be on the disk, then answers all the same with a warning; the wait given up
    is forgotten (issue 43 review: each mark left its waiter behind for good)."""
    caplog.set_level(logging.WARNING, "gx2.gateway")
    disk = SlowDisk(3.0)
    recorder = Recorder(RecordConfig(directory=str(tmp_path)), {}, create=disk.create)
    disk.slow.set()
    recorder.start()

    def publish(payload: dict[str, Any]) -> bool:
        recorder.take(Message(MARK_TOPIC, payload))
        return True
    gateway = SimpleNamespace(outputs=SimpleNamespace(mark=publish), recorder=recorder)

    async def marks() -> list[tuple[bool, float, int]]:
        done = []
        for n in range(2):
            start = time.monotonic()
            answered = await Gateway._mark(gateway, {  # type: ignore[arg-type]
                "text": f"m{n}", "time": time.time(), "host_time": time.time(),
                "nodes": []})
            done.append((answered, time.monotonic() - start, len(recorder._kept_waiters)))
        return done
    try:
        done = asyncio.run(marks())
    finally:
        disk.released.set()
        recorder.close()
    for answered, took, waiting in done:
        assert answered and MARK_KEPT_S <= took < MARK_KEPT_S + SLACK, done
        assert waiting == 0, done
    said = [r.message for r in caplog.records]
    assert said == [f"mark 'm{n}': not on the recording's disk yet (the disk is slow or "
                    "failing; recording.dropped counts what it loses)" for n in range(2)]


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
    wait_for(lambda: recorder.status()["queued"] < queued, 5,
             "the thread to be writing the backlog")
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


class ThrottledDisk:
    """Files on a disk that takes ``rate`` bytes a second: each write to the OS takes its
    share of a second (the disk's speed, not a synchronisation)."""

    def __init__(self, rate: float) -> None:
        self.rate = rate

    def create(self, path: Path) -> Any:
        disk = self

        class Throttled(io.FileIO):
            def write(self, data: Any) -> int:
                time.sleep(len(data) / disk.rate)
                return super().write(data)
        return io.BufferedWriter(Throttled(path, "xb"))


def test_a_queue_that_never_empties_still_flushes_rotates_and_retains(tmp_path):
    """The disk takes 1 MB/s, 1.5 MB/s comes (incompressible): the queue never empties,
    yet the flush, rotation (1 MB) and retention (2 MB) keep their second."""
    recorder = Recorder(RecordConfig(directory=str(tmp_path), rotate_mb=1, keep_gb=0.002,
                                     queue=10_000_000), {},
                        create=ThrottledDisk(1e6).create)
    stop = threading.Event()

    def stream() -> None:
        sent = 0
        start = time.monotonic()
        while not stop.is_set():
            while sent < (time.monotonic() - start) * 1000:  # 1000 reads of 1.5 kB a second
                recorder.serial(os.urandom(1500), time.time(), time.monotonic())
                sent += 1
            time.sleep(0.005)  # (a stream's pace)
    feeder = threading.Thread(target=stream)
    recorder.start()
    feeder.start()
    queued: list[int] = []

    def rotated_and_retained() -> bool:
        status = recorder.status()
        if status["files"] >= 2:  # (a backlog of more than a chunk by then)
            queued.append(status["queued"])
        return status["files"] >= 3 and len(list(tmp_path.iterdir())) < status["files"]
    try:
        wait_for(lambda: recorder.status()["queued"] > 0, 5, "a backlog")
        wait_for(rotated_and_retained, 15, "files rotated and the oldest deleted")
        status = recorder.status()
        assert min(queued) > 0, f"the queue emptied: the disk kept up after all {queued}"
        assert status["written"] > 0 and status["bytes"] > 0, status
    finally:
        stop.set()
        feeder.join()
        recorder.close()
    # the rotated files read whole by mcap's reader (the last, left to a disk too slow
    # for close()'s time, up to its last whole chunk)
    rotated = sorted(tmp_path.iterdir())[:-1]
    assert rotated and all(readable(path)[0] and readable(path)[1] for path in rotated)


class GatedDisk:
    """Files whose writes to the OS wait while ``gate`` is shut: ``entered`` is set by a
    write that found it shut (the thread is then inside a write, where a slow disk
    keeps it)."""

    def __init__(self) -> None:
        self.gate = threading.Event()
        self.gate.set()
        self.entered = threading.Event()

    def create(self, path: Path) -> Any:
        disk = self

        class Gated(io.FileIO):
            def write(self, data: Any) -> int:
                if not disk.gate.is_set():
                    disk.entered.set()
                    disk.gate.wait()
                return super().write(data)
        return io.BufferedWriter(Gated(path, "xb"))


def test_a_recorder_closing_opens_no_file_and_deletes_none(tmp_path, monkeypatch, caplog):
    """A disk slower than close()'s time: the thread finishes its file after close()
    has returned, but a rotation or retention falling due meanwhile is not carried out
    (it opened a new file and deleted the one being closed; the suite saw its log in
    the next test)."""
    monkeypatch.setattr(recorder_module, "FLUSH_S", 0.05)  # (every pass a flush: due)
    disk = GatedDisk()
    recorder = Recorder(RecordConfig(directory=str(tmp_path), rotate_mb=1e-6, keep_gb=1e-9),
                        {}, create=disk.create)
    recorder.start()
    try:
        sent = feed(recorder, 0.05)
        wait_for(lambda: recorder.status()["files"] >= 1, 5, "a file")
        disk.gate.clear()
        while not disk.entered.is_set() and sent < 10_000:  # (until a write waits)
            sent += feed(recorder, 0.05, sent)
        assert disk.entered.is_set()
        caplog.set_level(logging.INFO, "gx2.record")
        before = set(tmp_path.iterdir())
        recorder.close(timeout=0.2)
        assert recorder._thread.is_alive()  # (still in its write)
    finally:
        disk.gate.set()
    wait_for(lambda: not recorder._thread.is_alive(), 10, "the thread's end")
    assert set(tmp_path.iterdir()) == before
    assert not [r.message for r in caplog.records
                if "deleted" in r.message or "recording to" in r.message]


def test_a_rotation_close_comes_during_ends_with_the_file_it_finished(
        tmp_path, monkeypatch, caplog):
    """close() while a rotation writes the old file's summary (a slow disk): that file
    is finished and no new one is opened after close() has returned."""
    monkeypatch.setattr(recorder_module, "FLUSH_S", 0.05)
    recorder = Recorder(RecordConfig(directory=str(tmp_path), rotate_mb=1e-6), {})
    gate, inside = threading.Event(), threading.Event()
    finish = recorder._finish

    def slow_finish() -> None:  # (the summary's write, held until the test lets it go)
        if not recorder._closing and not gate.is_set():
            inside.set()
            gate.wait()
        finish()
    recorder._finish = slow_finish  # type: ignore[method-assign]
    recorder.start()
    try:
        sent = 0
        while not inside.is_set() and sent < 10_000:  # (until a rotation has begun)
            sent += feed(recorder, 0.05, sent)
        assert inside.is_set()
        caplog.set_level(logging.INFO, "gx2.record")
        before = set(tmp_path.iterdir())
        recorder.close(timeout=0.2)
        assert recorder._thread.is_alive()  # (still in the summary's write)
    finally:
        gate.set()
    wait_for(lambda: not recorder._thread.is_alive(), 10, "the thread's end")
    assert set(tmp_path.iterdir()) == before
    assert not [r.message for r in caplog.records if "recording to" in r.message]


class FullDisk:
    """Files on a disk that fills up (every write to the OS fails with ENOSPC while
    ``full`` is set) and frees again; buffered as a file opened by Python is."""

    def __init__(self) -> None:
        self.full = threading.Event()
        self.room = 0
        """Writes to the OS a full disk still takes (what it gave back)."""
        self.created: list[Path] = []

    def create(self, path: Path) -> Any:
        disk = self

        class Filling(io.FileIO):
            def write(self, data: Any) -> int:
                if disk.full.is_set():
                    if not disk.room:
                        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
                    disk.room -= 1
                return super().write(data)
        file = io.BufferedWriter(Filling(path, "xb"))
        self.created.append(path)
        return file


def feed(recorder: Recorder, seconds: float, start: int = 0) -> int:
    """Reads at a stream's pace for ``seconds``; how many."""
    sent = start
    until = time.monotonic() + seconds
    while time.monotonic() < until:
        recorder.serial(b"\xaa" * 40, 1.0 + sent, 1.0)
        sent += 1
        time.sleep(0.005)  # (a stream's pace, not a synchronisation)
    return sent - start


def test_a_full_disk_fails_loudly_leaves_no_broken_file_and_recording_resumes(
        tmp_path, monkeypatch, caplog):
    monkeypatch.setattr(recorder_module, "RETRY_S", 0.2)
    disk = FullDisk()
    recorder = Recorder(RecordConfig(directory=str(tmp_path)), {}, create=disk.create)
    recorder.start()
    sent = 0
    try:
        while not recorder.written:  # (the first flush: a second)
            sent += feed(recorder, 0.1, sent)
        assert recorder.failure == ""
        disk.full.set()
        while not recorder.failure:
            sent += feed(recorder, 0.1, sent)
        kept = recorder.written
        assert recorder.status()["failure"] == "No space left on device"
        # files tried meanwhile could not be started: removed, never left empty
        while len(disk.created) < 4:
            sent += feed(recorder, 0.1, sent)
        assert sorted(tmp_path.iterdir()) == [disk.created[0]]
        assert readable(disk.created[0]) == (kept, True)  # cut at its last flush, ended
        assert recorder.failure
        disk.full.clear()
        while recorder.failure:
            sent += feed(recorder, 0.1, sent)
    finally:
        recorder.close()
    assert recorder.written + recorder.dropped == sent
    assert recorder.lost > 0 and recorder.overflowed == 0
    paths = sorted(tmp_path.iterdir())
    assert len(paths) == 2 and paths[0] == disk.created[0], paths
    assert finished(paths[1]) == recorder.written - kept
    said = [r.message for r in caplog.records if r.name == "gx2.record"]
    assert sum("failed: No space left on device" in line for line in said) == 1, said
    resumed = [line for line in said if "recording resumed in" in line]
    assert len(resumed) == 1 and str(paths[1]) in resumed[0], said
    assert f"after {recorder.lost} messages dropped" in resumed[0]


def test_a_new_file_that_takes_one_flush_and_fails_again_is_not_resuming(
        tmp_path, monkeypatch, caplog):
    """A full disk gives back a little (the partial chunk cut off the failed file): a
    new file's header and one flush fit, the next fails. Recording has not resumed
    meanwhile: the failure stands throughout, one line says it, none says "resumed"
    until the disk takes several flushes in a row."""
    monkeypatch.setattr(recorder_module, "RETRY_S", 0.2)
    disk = FullDisk()
    recorder = Recorder(RecordConfig(directory=str(tmp_path)), {}, create=disk.create)
    recorder.start()
    sent = 0
    try:
        while not recorder.written:
            sent += feed(recorder, 0.1, sent)
        disk.full.set()
        while not recorder.failure:
            sent += feed(recorder, 0.1, sent)
        errors = recorder.errors
        disk.room = 2  # a new file's header and its first flush
        while disk.room or recorder.errors == errors:
            sent += feed(recorder, 0.1, sent)
            assert recorder.failure == "No space left on device"
        while len(disk.created) < 3:  # (a file tried after that one)
            sent += feed(recorder, 0.1, sent)
        assert recorder.failure == "No space left on device"
        disk.full.clear()
        while recorder.failure:
            sent += feed(recorder, 0.1, sent)
    finally:
        recorder.close()
    assert recorder.written + recorder.dropped == sent
    said = [r.message for r in caplog.records if r.name == "gx2.record"]
    assert sum("failed: No space left on device" in line for line in said) == 1, said
    assert sum("recording resumed in" in line for line in said) == 1, said
    # the file that took one flush is kept, cut back to it and ended there
    kept = [path for path in disk.created[1:] if path.exists()]
    assert readable(kept[0]) == (readable(kept[0])[0], True) and readable(kept[0])[0] > 0


def seed(directory: Path, ages_days: list[float], size: int) -> list[Path]:
    """Finished recordings of ``size`` bytes, last written ``ages_days`` ago, named as
    the recorder names them (by their start, an hour before)."""
    paths = []
    for age in ages_days:
        modified = time.time() - age * 86400
        path = directory / file_name(modified - 3600)
        path.write_bytes(bytes(size))
        os.utime(path, (modified, modified))
        paths.append(path)
    return paths


def test_retention_deletes_the_oldest_finished_files_never_the_current_one(
        tmp_path, caplog):
    caplog.set_level(logging.INFO, "gx2.record")
    old, newer = seed(tmp_path, [40, 20], 1000), seed(tmp_path, [2, 1], 300_000)
    foreign = tmp_path / "notes.mcap"
    foreign.write_bytes(bytes(100))
    recorder = Recorder(RecordConfig(directory=str(tmp_path), keep_days=30,
                                     keep_gb=0.0005), {})
    recorder.start()
    try:
        wait_for(lambda: not old[0].exists(), 5, "the file older than 30 days deleted")
        # 20 days old, but within the days: deleted for the space (500 kB) only
        wait_for(lambda: not newer[0].exists(), 5, "the oldest deleted for space")
        assert not old[1].exists() and newer[1].exists() and foreign.exists()
        feed(recorder, 1.5)
        status = recorder.status()
        current = Path(status["file"])
        assert current.exists() and status["oldest"] == str(newer[1])
        assert status["bytes"] >= 300_000 + current.stat().st_size - 16_384
    finally:
        recorder.close()
    deleted = [r.message for r in caplog.records if "deleted" in r.message]
    assert len(deleted) == 3 and all("\n" not in line for line in deleted), deleted
    assert deleted[0].startswith(f"recording: deleted {old[0].name} (1.0 kB, last written ") and \
        deleted[0].endswith("older than keep_days 30"), deleted
    assert "over keep_gb 0.0005" in deleted[2] and newer[0].name in deleted[2], deleted


def test_retention_never_deletes_the_file_being_written(tmp_path):
    recorder = Recorder(RecordConfig(directory=str(tmp_path), keep_gb=1e-9), {})
    recorder.start()
    try:
        feed(recorder, 2.5)
        status = recorder.status()
        assert Path(status["file"]).exists() and status["oldest"] == status["file"]
    finally:
        recorder.close()
    assert len(list(tmp_path.iterdir())) == 1


def test_a_message_that_cannot_be_written_is_counted_said_once_and_the_rest_written(
        tmp_path, caplog):
    """Times no MCAP timestamp holds (nanoseconds where seconds belong, negative), and a
    payload that cannot be encoded: each refused and counted, each kind said once, the
    thread going on with the rest."""
    recorder = Recorder(RecordConfig(directory=str(tmp_path)), {})
    recorder.start()
    bad = [(b"gx2/76/euler", {"host_time": 1.7e9, "time": 1.7e18}),
           (b"gx2/76/euler", {"host_time": -1.0}), (b"gx2/\xff", {"host_time": 1.7e9})]
    sent = 0
    for seq in range(30):
        if seq % 10 == 5:
            recorder.take(Message(*bad[seq // 10]))
        else:
            recorder.take(Message(b"gx2/76/euler", {"seq": seq, "host_time": 1.7e9 + seq}))
            sent += 1
    recorder.serial(b"\xaa", 1.7e18, 1.0)
    wait_for(lambda: recorder.status()["dropped"] == 4, 5, "the refused counted")
    assert recorder.failure == ""
    recorder.take(Message(b"gx2/76/euler", {"seq": 30, "host_time": 1.7e9 + 30}))
    recorder.close()
    (path,) = tmp_path.iterdir()
    assert finished(path) == sent + 1 == recorder.written
    said = [r for r in caplog.records if "cannot be recorded" in r.getMessage()]
    assert len(said) == 2, said
    assert said[0].getMessage().startswith(
        "recording: a message on gx2/76/euler cannot be recorded: time 1.7e+18 s is "
        "outside what a recording holds")
    assert said[1].getMessage().startswith(
        "recording: a message on gx2/\ufffd cannot be recorded: UnicodeDecodeError")
    assert said[0].exc_info is None and said[1].exc_info is not None  # (a bug's traceback)


def test_an_unexpected_error_of_the_file_fails_it_and_the_thread_goes_on(
        tmp_path, monkeypatch, caplog):
    monkeypatch.setattr(recorder_module, "RETRY_S", 0.2)
    failing = threading.Event()
    failing.set()
    flush = recorder_module.RecordingWriter.flush

    def broken(writer: Any) -> None:
        if failing.is_set():
            failing.clear()
            raise RuntimeError("a bug")
        flush(writer)
    monkeypatch.setattr(recorder_module.RecordingWriter, "flush", broken)
    recorder = Recorder(RecordConfig(directory=str(tmp_path)), {})
    recorder.start()
    try:
        sent = feed(recorder, 0.1)
        # (its count, not the failure itself: a new file comes RETRY_S after it, and a
        # loaded host's poll once missed the failure in between, beside the demo)
        wait_for(lambda: recorder.errors, 5, "the file to fail")
        assert recorder.last_error == "RuntimeError: a bug"
        deadline = time.monotonic() + 10.0
        while (recorder.failure or not recorder.written) and time.monotonic() < deadline:
            sent += feed(recorder, 0.1, sent)  # a new file, written
    finally:
        recorder.close()
    assert recorder.written + recorder.dropped == sent and recorder.written > 0
    said = [r for r in caplog.records if "failed: RuntimeError: a bug" in r.getMessage()]
    assert len(said) == 1 and said[0].exc_info is not None


def test_a_thread_that_dies_is_said_and_makes_a_failure(tmp_path, monkeypatch, caplog):
    def broken(recorder: Recorder) -> None:
        raise RuntimeError("a bug")
    monkeypatch.setattr(Recorder, "_retain", broken)
    recorder = Recorder(RecordConfig(directory=str(tmp_path)), {})
    recorder.start()
    wait_for(lambda: recorder.failure, 5, "the thread to stop")
    assert recorder.failure == "its thread stopped (RuntimeError: a bug)"
    assert recorder.status()["errors"] == 1
    said = [r for r in caplog.records if "recording stopped" in r.getMessage()]
    assert len(said) == 1 and said[0].exc_info is not None
    recorder.close()
