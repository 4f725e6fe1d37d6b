"""Windows of recordings at their edges, run as users run them: a file whose framing
breaks, times no recording can hold, nodes and records the files do not hold, and the
lines that say what was read."""

from __future__ import annotations

import json
import struct
from pathlib import Path

from mcap.reader import make_reader
from mcap.writer import IndexType, Writer

from gateway.recording.catalogue import catalogue
from gateway.recording.files import MARK, RECORD_HEAD
from gateway.recording.reader import read
from gateway.recording.reports import Reading
from gateway.recording.window import Reader, Window
from gateway.recording.writer import RecordingWriter
from tests.helpers.processes import gx2ctl, gx2ctl_here
from tests.helpers.recorded import MARKS, RATE, T0, foreign_file, make_file
from tests.recording.test_windows import column, iso

CHUNK = 0x06


def break_framing(path: Path, nth: int) -> None:
    """Overwrite the length of the ``nth`` chunk record (from 1): the records after it
    can only be found by scanning past it."""
    data = bytearray(path.read_bytes())
    at, seen = 8, 0
    while at < len(data):
        opcode, length = RECORD_HEAD.unpack_from(data, at)
        if opcode == CHUNK:
            seen += 1
            if seen == nth:
                struct.pack_into("<Q", data, at + 1, 0xFF_FFFF_FFFF)
                path.write_bytes(bytes(data))
                return
        at += RECORD_HEAD.size + length
    raise AssertionError(f"no chunk {nth} in {path}")


def test_a_window_reads_past_broken_framing_and_says_partial(tmp_path: Path) -> None:
    folder = tmp_path / "recordings"
    folder.mkdir()
    broken = make_file(folder / "gx2-a.mcap", 0, 15, finish=False)
    break_framing(broken, 5)  # second 4: seconds 5 to 14 are past it
    make_file(folder / "gx2-b.mcap", 20, 10)
    out = tmp_path / "out"
    ran = gx2ctl("export", str(folder), "--out", str(out), "--from", iso(T0 + 6),
                 "--to", iso(T0 + 25))
    assert ran.status == 1, ran.stderr
    # where the damage is in the file, not where the window starts
    assert "gx2-a.mcap: skipped 1 damaged chunk (how many messages is not known, " in \
        ran.stderr and ("nothing from 2026-11-18 11:06:43.960 UTC to 11:06:45.000 UTC, "
                        "1.040 s)") in ran.stderr, ran.stderr
    times = column(out / "11_accel_angrate.csv", "host_time")
    assert len(times) == 9 * RATE + 5 * RATE and min(times) == T0 + 6
    alone = gx2ctl("export", str(broken), "--out", str(tmp_path / "alone"), "--from", "10")
    assert alone.status == 1, alone.stderr
    assert len(column(tmp_path / "alone" / "11_accel_angrate.csv", "host_time")) == 5 * RATE


def test_nodes_and_records_the_files_do_not_hold_are_one_line_and_exit_2(
        tmp_path: Path) -> None:
    finished = make_file(tmp_path / "gx2-a.mcap", 0, 3)
    cut = make_file(tmp_path / "gx2-b.mcap", 3, 3, finish=False)
    holds = "(they hold node 11: accel_angrate; node 12: accel_angrate; node 13: euler)"
    for files, asked in (([finished], ["--node", "99"]),
                         ([finished, cut], ["--node", "99"]),  # one told only once read
                         ([finished], ["--node", "11", "--record", "euler"])):
        out = tmp_path / "out"
        ran = gx2ctl_here("export", *map(str, files), "--out", str(out), *asked)
        assert ran.status == 2, ran.stderr
        said = ran.stderr.splitlines()[-1]
        assert said == f"gx2ctl: {' '.join(asked)}: not in the recordings {holds}"
        assert not out.exists() or not list(out.iterdir())  # (not even marks.csv)


def test_overlapping_files_of_other_nodes_remember_only_what_both_hold(
        tmp_path: Path) -> None:
    """Two gateways' files of one hour in one directory: only the topics both hold
    (the status) are remembered to tell duplicates, not every message of the overlap."""
    ours = make_file(tmp_path / "gx2-a.mcap", 0, 10)
    theirs = tmp_path / "gx2-b.mcap"
    with theirs.open("wb") as output:
        writer = RecordingWriter(output)
        for second in range(2, 12):
            writer.message("gx2/gateway/status", {"gateway": {"time": T0 + second},
                                                  "nodes": []})
            for i in range(RATE):
                writer.message("gx2/21/euler", {"node": 21, "record": "euler", "seq": i,
                                                "host_time": T0 + second + i / RATE})
            writer.flush()
        writer.finish()
    reader = Reader(catalogue([ours, theirs], whole=False), Reading())
    read = list(reader.entries(Window()))
    held = sum(1 for _ in make_reader(ours.open("rb")).iter_messages())
    # their statuses of seconds 2 to 9 are ours again (the same status, at the same time)
    assert reader.duplicates == 8 and len(read) == held + 10 * RATE + 2
    assert reader.remembered == 8  # ours' statuses from 2 s on: the topic both hold
    twice = Reader(catalogue([ours, ours], whole=False), Reading())
    assert len(list(twice.entries(Window()))) == held and twice.duplicates == held


def test_a_trial_started_and_never_stopped_is_said(tmp_path: Path) -> None:
    path = make_file(tmp_path / "gx2-a.mcap", 0, 30)  # start 5, stop 12, start 25
    ran = gx2ctl_here("export", str(path), "--out", str(tmp_path / "out"), "--between-marks",
                      "start", "stop")
    assert ran.status == 0, ran.stderr
    assert ran.stderr == ("gx2ctl: the mark 'start' at 2026-11-18T11:07:05.000Z has no "
                          "mark 'stop' after it: not a trial\n")
    assert [p.name for p in (tmp_path / "out").iterdir()] == [
        "trial-1_2026-11-18T11-06-45Z"]


def test_a_finished_file_without_statistics_is_spanned_by_its_chunks(tmp_path: Path) -> None:
    euler = [("gx2/11/euler", {"node": 11, "record": "euler", "seq": i,
                               "host_time": T0 + i / RATE}) for i in range(20 * RATE)]
    path = foreign_file(tmp_path / "other.mcap", euler, use_statistics=False,
                        chunk_size=4096)
    listed = gx2ctl_here("recordings", "--json", str(path))
    assert listed.status == 0, listed.stderr
    (described,) = json.loads(listed.stdout)["files"]
    assert (described["start"], described["end"]) == (T0, T0 + (20 * RATE - 1) / RATE)
    assert described["nodes"] == {"11": {"euler": 20 * RATE}}
    out = tmp_path / "out"
    ran = gx2ctl_here("export", str(path), "--out", str(out), "--from", "5", "--to", "6")
    assert ran.status == 0, ran.stderr
    assert column(out / "11_euler.csv", "host_time") == [T0 + 5 + i / RATE
                                                        for i in range(RATE)]


def test_a_window_of_a_file_cut_short_says_where_the_file_ends(tmp_path: Path) -> None:
    cut = make_file(tmp_path / "gx2-cut.mcap", 0, 10, finish=False)
    ran = gx2ctl_here("export", str(cut), "--out", str(tmp_path / "out"), "--from", "0",
                      "--to", "1")
    assert ran.status == 0, ran.stderr
    # its last message (second 9's last record), not the window's
    assert "ends early after 2026-11-18 11:06:49.960 UTC" in ran.stderr, ran.stderr


def test_a_window_of_a_file_without_message_indexes_keeps_its_channels(
        tmp_path: Path) -> None:
    """Another writer's file, killed (no summary), without message indexes: its only
    channel defined in its first chunk, which a window from 10 s passes over."""
    path = tmp_path / "other.mcap"
    with path.open("wb") as stream:
        writer = Writer(stream, chunk_size=2000, index_types=IndexType.NONE)
        writer.start(profile="", library="another")
        channel = writer.register_channel("gx2/11/euler", "json", schema_id=0)
        for i in range(20 * RATE):
            at = T0 + i / RATE
            writer.add_message(channel, round(at * 1e9), json.dumps(
                {"node": 11, "record": "euler", "seq": i, "host_time": at}).encode(),
                round(at * 1e9))
        stream.flush()  # (not finished: its writer killed)
    whole = gx2ctl_here("export", str(path), "--out", str(tmp_path / "whole"))
    assert whole.status == 0, whole.stderr
    held = [t for t in column(tmp_path / "whole" / "11_euler.csv", "host_time")
            if t >= T0 + 10]
    out = tmp_path / "out"
    ran = gx2ctl_here("export", str(path), "--out", str(out), "--from", "10")
    assert ran.status == 0, ran.stderr
    assert "channels defined in what was lost" not in ran.stderr
    assert column(out / "11_euler.csv", "host_time") == held and len(held) > 5 * RATE


def test_the_file_a_writer_holds_open_is_being_written_not_cut_short(
        tmp_path: Path) -> None:
    path = tmp_path / "gx2-now.mcap"
    with path.open("wb") as output:
        writer = RecordingWriter(output)
        for second in range(5):
            for i in range(RATE):
                writer.message("gx2/11/euler", {"node": 11, "record": "euler", "seq": i,
                                                "host_time": T0 + second + i / RATE})
            writer.flush()
        listed = gx2ctl_here("recordings", "--json", str(path))
        table = gx2ctl_here("recordings", str(path))
        exported = gx2ctl_here("export", str(path), "--out", str(tmp_path / "out"))
    assert listed.status == 0, listed.stderr
    (described,) = json.loads(listed.stdout)["files"]
    assert described["writing"] is True and described["cut_short"] is False
    assert (described["start"], described["end"]) == (T0, T0 + 4 + (RATE - 1) / RATE)
    assert "note: being written: its span from its chunks' headers" in table.stdout
    assert exported.status == 0, exported.stderr
    assert "being written: its last flush after 2026-11-18 11:06:44.960 UTC" in \
        exported.stderr and "stopped without warning" not in exported.stderr
    assert len(column(tmp_path / "out" / "11_euler.csv", "host_time")) == 5 * RATE
    killed = json.loads(gx2ctl_here("recordings", "--json", str(path)).stdout)["files"][0]
    assert killed["writing"] is False and killed["cut_short"] is True


def test_a_file_read_for_each_trial_is_said_once(tmp_path: Path) -> None:
    """Each trial reads the files it touches: a file being written, read for two
    trials, is one line, as one read of it is (issue 43: the line came twice)."""
    path = tmp_path / "gx2-now.mcap"
    with path.open("wb") as output:
        writer = RecordingWriter(output)
        for second in range(6):
            if second in (1, 3):
                writer.message(MARK, {"time": T0 + second, "host_time": T0 + second,
                                      "nodes": [], "text": "go"})
            if second in (2, 4):
                writer.message(MARK, {"time": T0 + second, "host_time": T0 + second,
                                      "nodes": [], "text": "halt"})
            for i in range(RATE):
                writer.message("gx2/11/euler", {"node": 11, "record": "euler", "seq": i,
                                                "host_time": T0 + second + i / RATE})
            writer.flush()
        exported = gx2ctl_here("export", str(path), "--out", str(tmp_path / "out"),
                               "--between-marks", "go", "halt")
    assert exported.status == 0, exported.stderr
    assert exported.stdout.count("11_euler.csv") == 2, exported.stdout
    assert exported.stderr == (f"gx2ctl: {path}: being written: its last flush after "
                               "2026-11-18 11:06:45.960 UTC; read up to there\n")


def test_plot_takes_its_node_as_export_does(tmp_path: Path) -> None:
    path = make_file(tmp_path / "gx2-a.mcap", 0, 3)
    out = tmp_path / "11.png"
    ran = gx2ctl_here("plot", str(path), "--node", "11", "--out", str(out))
    assert ran.status == 0, ran.stderr
    assert out.stat().st_size > 0
    for asked in ([], ["11", "--node", "12"]):
        refused = gx2ctl_here("plot", str(path), *asked, "--out", str(out))
        assert refused.status == 2
        assert refused.stderr == "gx2ctl: plot: give one node, as NODE or --node N\n"


def test_the_marks_of_a_file_without_summary_are_read_from_their_chunks(
        tmp_path: Path) -> None:
    """A file being written (no summary) read for its marks: only the chunks whose
    message indexes name the mark channel, or a channel not yet defined, are
    decompressed (issue 43: recordings could list the marks of a file being written
    only by reading an hour of it); the same marks as a read of every message."""
    path = make_file(tmp_path / "gx2-now.mcap", 0, 20, finish=False)
    everything = [e for e in read(path, Reading()) if e.topic == MARK]
    reading = Reading()
    marks = list(read(path, reading, [MARK]))
    assert marks == everything and [e.log_time for e in marks] == [
        round((T0 + at) * 1e9) for at, _ in MARKS if at < 20]
    # the first chunk (its channels), the two that hold a mark (the first of them also
    # defines the mark channel), and the last (at the end of the data, its index list
    # may be cut short: a writer killed as it flushed), of 20
    assert reading.files[0].decompressed == 4
    assert not reading.partial


def test_marks_of_another_writers_file_without_indexes_are_all_read(
        tmp_path: Path) -> None:
    """Without message indexes a chunk cannot say what it holds: each is read."""
    path = tmp_path / "other.mcap"
    with path.open("wb") as stream:
        writer = Writer(stream, chunk_size=2000, index_types=IndexType.NONE)
        writer.start(profile="", library="another")
        euler = writer.register_channel("gx2/11/euler", "json", schema_id=0)
        marked = writer.register_channel(MARK, "json", schema_id=0)
        for i in range(10 * RATE):
            at = round((T0 + i / RATE) * 1e9)
            writer.add_message(euler, at, json.dumps(
                {"node": 11, "record": "euler", "seq": i, "host_time": at / 1e9}).encode(),
                at)
            if i % (3 * RATE) == 0:
                writer.add_message(marked, at, json.dumps(
                    {"text": f"m{i}", "time": at / 1e9, "nodes": []}).encode(), at)
        stream.flush()  # (not finished: its writer killed)
    texts = [json.loads(e.data)["text"] for e in read(path, Reading(), [MARK])]
    assert texts == [f"m{i}" for i in range(0, 10 * RATE, 3 * RATE)]
