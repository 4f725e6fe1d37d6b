"""A recording disk that fills and frees again, and one that is read-only, under the
real gateway and gx2-sim (issue 20): the gateway itself is an ERROR while it cannot
write (status, ``gx2ctl status --check``, the metric), publishing goes on, no empty or
unreadable file is left, and recording resumes in a new file by itself.

The disk is a real 1 MiB tmpfs in a mount namespace of its own (unshare(1), as root;
tests/helpers/smalldisk.py),
held by a process that lives as long as the test: the gateway joins that namespace
(setns(2), before it starts), and the test reaches the same tmpfs through the holder's
``/proc/PID/root``. The tmpfs fills with a file the test writes until the kernel says
ENOSPC, and frees when the test deletes it: the gateway meets the very error a full
disk gives. Files are read back with the ``mcap`` package's own readers and
``gx2ctl export``, while the holder keeps the tmpfs after the gateway has stopped.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Iterator
from pathlib import Path

import pytest
from mcap.reader import NonSeekingReader, make_reader
from mcap.writer import Writer

from gateway.sim.node import NodeSettings
from tests.e2e.test_watching import Scraper
from tests.helpers.ports import free_port
from tests.helpers.processes import gx2ctl
from tests.helpers.smalldisk import PAGE, SmallDisk, Unavailable
from tests.helpers.waiting import wait_for

NODES = [{"address": 76, "stream": "accel_angrate"}]
TOPIC = "gx2/76/accel_angrate"


def small(tmp_path: Path, options: str) -> SmallDisk:
    try:
        return SmallDisk(tmp_path, options)
    except Unavailable as why:
        pytest.skip(str(why))


@pytest.fixture
def small_disk(tmp_path: Path) -> Iterator[SmallDisk]:
    disk = small(tmp_path, "size=1m")
    yield disk
    disk.close()


@pytest.fixture
def read_only_disk(tmp_path: Path) -> Iterator[SmallDisk]:
    disk = small(tmp_path, "ro")
    yield disk
    disk.close()


def readable_to_its_end(path: Path) -> int:
    """Messages in ``path`` by mcap's front-to-back reader, which raises on a file that
    stops short of its footer."""
    with path.open("rb") as stream:
        return sum(1 for _ in NonSeekingReader(stream).iter_messages(log_time_order=False))


def records_of(path: Path, topic: str) -> int:
    with path.open("rb") as stream:
        return sum(1 for _, channel, _ in make_reader(stream).iter_messages()
                   if channel.topic == topic)


def test_a_full_disk_makes_the_gateway_an_error_and_recording_resumes_when_it_frees(
        simulator, gateway, small_disk, tmp_path):
    sim = simulator(NodeSettings(76))
    metrics = f"127.0.0.1:{free_port()}"
    recordings = small_disk.inside / "recordings"
    gw = gateway(sim.path, NODES, record={"directory": str(recordings)},
                 metrics={"endpoint": metrics}, preexec=small_disk.enter)
    scrape = Scraper(metrics)
    gw.wait_streaming(76)
    wait_for(lambda: gw.status()["recording"]["written"], 10, "the first flush")
    assert gw.status()["recording"]["errors"] == 0

    small_disk.fill()
    wait_for(lambda: gw.status()["recording"]["errors"], 10, "the disk to refuse")
    small_disk.fill()  # (the file cut short gave back its last, partial chunk)
    check = gx2ctl("--config", str(gw.path), "status", "--check")
    assert check.status == 1, check
    assert gw.status()["gateway"]["reasons"] == ["recording failed: No space left on device"]
    assert "the gateway is ERROR: recording failed: No space left on device" in check.stderr
    assert "health ERROR (recording failed: No space left on device)" in check.stdout
    assert scrape.value("gx2_gateway_health") == 2.0
    assert scrape.value("gx2_recording_failing") == 1.0  # (what Gx2RecordingFailed reads)
    # publishing goes on; a file tried meanwhile could not be started: removed
    sub = gw.subscribe("gx2/76/")
    sub.until(lambda m: len(m) > 50, 10, "records published while nothing is recorded")
    wait_for(lambda: "removed: nothing of it reached the disk" in gw.log(), 10,
             "a new file tried, and removed")
    files = sorted((small_disk.outside / "recordings").iterdir())
    assert len(files) == 1 and files[0].stat().st_size > 0, files

    small_disk.free()
    wait_for(lambda: gw.status()["gateway"]["health"] == "OK", 15, "recording to resume")
    wait_for(lambda: scrape.value("gx2_gateway_health") == 0.0, 5, "the metric to follow")
    resumed = [line for line in gw.log().splitlines() if "recording resumed in" in line]
    assert len(resumed) == 1 and "messages dropped (No space left on device)" in resumed[0]
    written = gw.status()["recording"]["written"]
    wait_for(lambda: gw.status()["recording"]["written"] > written, 5, "more recorded")
    status, _ = gw.terminate()
    assert status == 0, gw.log()

    # two files: the first cut short at its last flush and ended there, the second
    # finished; each read whole by mcap's own reader, nothing empty
    files = sorted((small_disk.outside / "recordings").iterdir())
    assert len(files) == 2, files
    cut, whole = files
    assert str(cut.name) in gw.log() and "cut short" in gw.log()
    assert readable_to_its_end(cut) > 0 and readable_to_its_end(whole) > 0
    with whole.open("rb") as stream:
        assert make_reader(stream).get_summary() is not None
    recorded = sum(records_of(path, "gx2/76/accel_angrate") for path in files)
    # export reads every record that was written, and skips nothing
    out = tmp_path / "out"
    run = gx2ctl("export", str(small_disk.outside / "recordings"), "--out", str(out))
    assert run.status == 0, run
    with (out / "76_accel_angrate.csv").open() as table:
        assert sum(1 for _ in csv.DictReader(table)) == recorded > 100


def test_a_disk_that_takes_a_flush_and_is_full_again_has_not_resumed(
        simulator, gateway, small_disk):
    """What a full disk gives back takes a new file's header and a flush or two, then
    the disk is full again: the gateway stays ERROR throughout and never says recording
    resumed (it flapped: "resumed", OK for a second, ERROR again); it does once the disk
    keeps taking what comes."""
    sim = simulator(NodeSettings(76))
    recordings = small_disk.inside / "recordings"
    gw = gateway(sim.path, NODES, record={"directory": str(recordings)},
                 preexec=small_disk.enter)
    gw.wait_streaming(76)
    wait_for(lambda: gw.status()["recording"]["written"], 10, "the first flush")
    # what a file's header and its first flush or two take (the header holds every
    # channel's JSON Schema, and grows with what the status describes), in whole pages
    (first,) = (small_disk.outside / "recordings").glob("*.mcap")
    taken = -(-first.stat().st_size // PAGE) * PAGE + PAGE  # (and a page: a new file's
    # first flush holds what waited while it was opened)
    small_disk.fill()
    wait_for(lambda: gw.status()["recording"]["errors"], 10, "the disk to refuse")
    small_disk.fill()  # (the file cut short gave back its last, partial chunk)
    errors = gw.status()["recording"]["errors"]
    small_disk.free(taken)  # a header and a flush or two, not the stream from then on

    def full_again() -> bool:
        status = gw.status()
        assert status["gateway"]["health"] == "ERROR", status["gateway"]
        # (the new file kept what it flushed: cut short, as the first was)
        return status["recording"]["errors"] > errors and gw.log().count("cut short") == 2
    wait_for(full_again, 15, "a new file to take a flush into what was freed and fail")
    assert "recording resumed" not in gw.log()

    small_disk.free()
    wait_for(lambda: gw.status()["gateway"]["health"] == "OK", 20, "recording to resume")
    resumed = [line for line in gw.log().splitlines() if "recording resumed in" in line]
    assert len(resumed) == 1, gw.log()
    status, _ = gw.terminate()
    assert status == 0, gw.log()


def test_a_read_only_directory_makes_the_gateway_an_error_and_leaves_nothing(
        simulator, gateway, read_only_disk):
    sim = simulator(NodeSettings(76))
    gw = gateway(sim.path, NODES, record={"directory": str(read_only_disk.inside)},
                 preexec=read_only_disk.enter)
    gw.wait_streaming(76)
    wait_for(lambda: gw.status()["recording"]["errors"], 10, "the directory to refuse")
    check = gx2ctl("--control", gw.control_endpoint, "status", "--check")
    assert check.status == 1 and "Read-only file system" in check.stderr, check
    assert gw.status()["gateway"]["reasons"] == ["recording failed: Read-only file system"]
    assert list(read_only_disk.outside.iterdir()) == []
    status, _ = gw.terminate()
    assert status == 0


def foreign_recording(path: Path, count: int, absurd: int) -> None:
    """A recording of published records made by another tool (mcap's own writer), whose
    message ``absurd`` gives its ``time`` in nanoseconds rather than seconds."""
    with path.open("wb") as output:
        writer = Writer(output)
        writer.start(profile="", library="another tool")
        channel = writer.register_channel(TOPIC, "json", 0)
        for seq in range(1, count + 1):
            when = 1.7e9 + seq / 100
            payload = {"node": 76, "seq": seq, "host_time": when,
                       "time": when * 1e9 if seq == absurd else when,
                       "accel": [0.0, 0.0, 1.0], "angrate": [0.0, 0.0, 0.0]}
            writer.add_message(channel, int(when * 1e9), json.dumps(payload).encode(),
                               int(when * 1e9), seq)
        writer.finish()


def test_a_message_whose_time_cannot_be_recorded_is_counted_and_the_rest_recorded(
        gateway, tmp_path):
    source = tmp_path / "foreign.mcap"
    foreign_recording(source, 51, absurd=26)
    recordings = tmp_path / "recordings"
    gw = gateway(f"replay://{source}?speed=0&delay=0", NODES,
                 record={"directory": str(recordings)})
    wait_for(lambda: gw.status()["replay"]["finished"], 10, "the replay to end")
    wait_for(lambda: gw.status()["recording"]["dropped"] == 1, 5, "the message counted")
    recording = gw.status()["recording"]
    assert recording["failure"] == "" and gw.status()["gateway"]["health"] == "OK", recording
    status, _ = gw.terminate()
    assert status == 0, gw.log()
    # every other message recorded, in a file mcap's reader reads whole
    files = sorted(recordings.iterdir())
    assert len(files) == 1, files
    with files[0].open("rb") as stream:
        seqs = [json.loads(message.data)["seq"] for _, channel, message
                in make_reader(stream).iter_messages(log_time_order=False)
                if channel.topic == TOPIC]
    assert seqs == [seq for seq in range(1, 52) if seq != 26]
    said = [line for line in gw.log().splitlines() if "cannot be recorded" in line]
    assert len(said) == 1 and TOPIC in said[0], gw.log()
