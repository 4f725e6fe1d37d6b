"""Recordings that are damaged, cut short, empty or not recordings at all, read by
gx2ctl export and plot and by a replay as users run them: what can be read is read
(records after a damaged chunk included), what cannot is said in one line per file,
and the run exits 1 ("partial"). Ctrl-C during an export leaves no table cut."""

from __future__ import annotations

import math
import struct
from pathlib import Path

import pytest
from mcap.reader import make_reader

from gateway.common.jsontext import compact_bytes
from gateway.recording import export, tables
from gateway.recording.files import FOOTER_BYTES, RECORD_HEAD, RecordingError, message_times
from gateway.recording.plot import picture, records_of
from gateway.recording.reader import Entry, read_all
from gateway.recording.reports import Reading
from gateway.recording.writer import RecordingWriter
from tests.helpers.processes import gx2ctl, gx2ctl_here, interrupted, script
from tests.helpers.waiting import wait_for
from tests.recording.test_offline import T0, payload, rows

TOPIC = "gx2/76/euler"
PER_CHUNK = 100


def euler(seq: int) -> dict:
    at = T0 + (seq - 1) / 100
    return payload(76, "euler", seq, at, timer=seq, roll=0.1, pitch=0.2, yaw=0.3)


def write_chunks(path: Path, chunks: list[list[tuple[str, dict]]],
                 finished: bool = True) -> list[tuple[int, int]]:
    """Each list of messages a chunk of its own; (offset, length) of each chunk. A file
    not finished is what a writer killed after its last flush leaves."""
    with path.open("wb") as output:
        writer = RecordingWriter(output)
        for chunk in chunks:
            for topic, data in chunk:
                writer.message(topic, data)
            writer.flush()
        writer.finish()
    with path.open("rb") as stream:
        indexes = make_reader(stream).get_summary().chunk_indexes
    if not finished:
        last = indexes[-1]
        with path.open("r+b") as stream:
            stream.truncate(last.chunk_start_offset + last.chunk_length
                            + last.message_index_length)
    return [(index.chunk_start_offset, index.chunk_length) for index in indexes]


def three_chunks(path: Path, finished: bool = True) -> list[tuple[int, int]]:
    return write_chunks(path, [[(TOPIC, euler(seq)) for seq in range(start, start + PER_CHUNK)]
                               for start in (1, 101, 201)], finished)


def damage(path: Path, chunk: tuple[int, int], how: str) -> None:
    """``content``: bytes in the middle of its compressed data flipped; ``framing``:
    its record's length overwritten, so that no record starts where it says it ends."""
    offset, length = chunk
    data = bytearray(path.read_bytes())
    if how == "content":
        for at in range(offset + length // 2, offset + length // 2 + 8):
            data[at] ^= 0xFF
    else:
        data[offset + 1:offset + 9] = b"\x37" * 8
    path.write_bytes(bytes(data))


def seqs(table: Path) -> list[int]:
    return [int(row["seq"]) for row in rows(table)]


@pytest.mark.parametrize("finished", [True, False], ids=["finished", "cut"])
@pytest.mark.parametrize("how", ["content", "framing"])
def test_a_damaged_chunk_is_skipped_and_the_rows_after_it_are_read(tmp_path, how, finished):
    path = tmp_path / "run.mcap"
    chunks = three_chunks(path, finished)
    damage(path, chunks[1], how)
    reading = Reading()
    read = [entry.payload()["seq"] for entry in read_all([path], reading)]
    assert read == [*range(1, 101), *range(201, 301)]
    assert reading.partial
    [line] = reading.lines()
    assert line.startswith(f"{path}: skipped 1 damaged chunk (")
    # the messages lost: counted exactly from a finished file's summary, or from the
    # message index after the chunk when only its content is damaged
    if finished or how == "content":
        assert "(100 messages," in line
    else:
        assert "how many messages is not known" in line
    assert "nothing from 2026-11-18 11:06:40.994 UTC to 11:06:42.004 UTC, 1.010 s" in line
    assert ("ends early" in line) == (not finished)


def test_export_of_a_damaged_file_writes_the_rows_before_and_after_and_exits_1(tmp_path):
    path = tmp_path / "run.mcap"
    damage(path, three_chunks(path)[1], "content")
    ran = gx2ctl("export", str(path), "--out", str(tmp_path / "out"))
    assert ran.status == 1, ran
    assert seqs(tmp_path / "out" / "76_euler.csv") == [*range(1, 101), *range(201, 301)]
    [line] = ran.stderr.splitlines()
    assert line.startswith(f"gx2ctl: {path}: skipped 1 damaged chunk (100 messages"), line
    assert line.endswith("; read the rest")
    assert "200 rows" in ran.stdout


def test_a_file_cut_short_is_said_but_not_partial(tmp_path):
    path = tmp_path / "run.mcap"
    three_chunks(path, finished=False)
    ran = gx2ctl_here("export", str(path), "--out", str(tmp_path / "out"))
    assert ran.status == 0, ran
    assert ran.stderr == (f"gx2ctl: {path}: ends early after 2026-11-18 11:06:42.994 UTC "
                          "(its writer was stopped without warning); read up to there\n")
    assert seqs(tmp_path / "out" / "76_euler.csv") == list(range(1, 301))


def test_a_lost_channel_definition_loses_no_message_of_a_finished_file(tmp_path):
    # the channel is defined in the chunk of its first message: a finished file's
    # summary defines it again, a file cut short loses its later messages (counted)
    for finished, later in ((True, [*range(101, 301)]), (False, [])):
        path = tmp_path / f"run-{finished}.mcap"
        damage(path, three_chunks(path, finished)[0], "content")
        reading = Reading()
        assert [e.payload()["seq"] for e in read_all([path], reading)] == later
        [line] = reading.lines()
        if finished:
            assert "skipped 1 damaged chunk (100 messages," in line
        else:
            assert "skipped 1 damaged chunk and 200 messages on channels defined in what " \
                   "was lost (100 messages," in line


def test_empty_and_foreign_files_in_a_directory_are_skipped_with_a_line_each(tmp_path):
    directory = tmp_path / "recordings"
    directory.mkdir()
    three_chunks(directory / "gx2-a.mcap")
    (directory / "gx2-b.mcap").write_bytes(b"")  # what a full disk leaves, every 5 s
    (directory / "gx2-c.mcap").write_text("not a recording")
    write_chunks(directory / "gx2-d.mcap", [[(TOPIC, euler(301))]])
    ran = gx2ctl_here("export", str(directory), "--out", str(tmp_path / "out"))
    assert ran.status == 1, ran
    assert ran.stderr.splitlines() == [f"gx2ctl: {directory / 'gx2-b.mcap'}: skipped: empty",
                                       f"gx2ctl: {directory / 'gx2-c.mcap'}: skipped: "
                                       "not an MCAP file"]
    assert seqs(tmp_path / "out" / "76_euler.csv") == list(range(1, 302))
    drawn = gx2ctl_here("plot", str(directory), "76", "--out", str(tmp_path / "76.png"))
    assert drawn.status == 1, drawn
    assert len(drawn.stderr.splitlines()) == 2 and (tmp_path / "76.png").stat().st_size
    # nothing readable at all: a usage error, one line
    for bad in ("gx2-a.mcap", "gx2-d.mcap"):
        (directory / bad).unlink()
    ran = gx2ctl_here("export", str(directory), "--out", str(tmp_path / "out"))
    assert ran.status == 2, ran
    assert ran.stderr == (f"gx2ctl: {directory / 'gx2-b.mcap'}: empty (and 1 more that "
                          "cannot be read)\n")


def test_ctrl_c_just_as_a_table_s_file_is_made_leaves_no_temporary(tmp_path, monkeypatch):
    """The moment the test above sends its Ctrl-C (a file appears in ``out``): the
    temporary existed before the export's clean-up knew of it, and was left (seen once
    in a full run)."""
    path = tmp_path / "one.mcap"
    with path.open("wb") as output:
        writer = RecordingWriter(output)
        writer.message(TOPIC, {**euler(1), "seq": 1})
        writer.finish()

    def made_then_interrupted(file: Path, columns: list[str]) -> tables.Writer:
        file.write_text("")
        raise KeyboardInterrupt

    monkeypatch.setitem(export.WRITERS, "csv", made_then_interrupted)
    out = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt):
        export.export([path], out, Reading())
    assert list(out.iterdir()) == []


def test_ctrl_c_during_export_leaves_no_table_cut(tmp_path):
    # (450,000 rows: an export a batch at a time takes about a second after its first
    # table appears, on a quiet machine; the JSON made ahead, the times given: the file
    # written in a third of the time each message's own took)
    path = tmp_path / "big.mcap"
    base = euler(1)
    times = message_times(base)
    with path.open("wb") as output:
        writer = RecordingWriter(output)
        for seq in range(1, 450_001):
            writer.message(TOPIC, base, compact_bytes({**base, "seq": seq}), times)
            if seq % 3000 == 0:
                writer.message("gx2/77/euler", base, compact_bytes(
                    {**base, "node": 77, "seq": seq // 3000}), times)
        writer.finish()
    out = tmp_path / "out"
    out.mkdir()
    earlier = out / "76_euler.csv"
    whole = "time,seq\n1.5,1\n"
    earlier.write_text(whole)  # an earlier export's: --force removes it before writing

    def writing() -> bool:
        """Anything but the earlier table in ``out``: the export has begun writing its
        tables."""
        return any(p != earlier for p in out.iterdir())
    status, stdout, stderr = interrupted(
        [script("gx2ctl"), "export", str(path), "--out", str(out), "--force"], writing,
        "the export to begin writing")
    assert status == 130, (stdout, stderr)
    [line] = stderr.splitlines()
    assert line.startswith("gx2ctl: interrupted: wrote "), line
    assert line.endswith(f"; nothing else was left in {out}"), line
    # (the signal lands while the file is read: "wrote no table"; were the machine so
    # slow that it came while the tables were renamed, those named must be whole)
    last = {"76_euler.csv": 450_000, "77_euler.csv": 150}
    for table in out.iterdir():  # (the earlier table among them only if written anew)
        assert not table.name.startswith("."), f"a temporary is left: {table}"
        assert str(table) in line, f"{table} is not said to be written"
        assert seqs(table)[-1] == last[table.name], f"{table} is cut"


def mark(text: str, at: float, nodes: list[int]) -> tuple[str, dict]:
    return "gx2/gateway/mark", {"text": text, "time": at, "nodes": nodes,
                                "host_time": at + 0.25}


def test_marks_are_exported_and_drawn_as_labelled_lines(tmp_path):
    path = tmp_path / "run.mcap"
    records = [(TOPIC, euler(seq)) for seq in range(1, 301)]
    marks = [mark("start, engine on", T0 + 0.5, []), mark("left wing tapped", T0 + 1.0, [76]),
             mark("right wing tapped", T0 + 1.5, [77, 78]), mark("after", T0 + 60, [])]
    write_chunks(path, [records[:100] + marks[:2], records[100:] + marks[2:]])
    ran = gx2ctl_here("export", str(path), "--out", str(tmp_path / "out"))
    assert ran.status == 0, ran
    assert rows(tmp_path / "out" / "marks.csv") == [
        {"time": repr(data["time"]), "host_time": repr(data["host_time"]),
         "nodes": " ".join(map(str, data["nodes"])), "text": data["text"]}
        for _, data in marks]
    assert f"{tmp_path / 'out' / 'marks.csv'}  4 marks" in ran.stdout
    found = records_of([path], 76, None, Reading())
    image = picture(76, found.record, found.payloads, found.name, found.marks)
    # node 76's own mark and the experiment's, within the samples' time
    assert image.marks == [(pytest.approx(0.5), "start, engine on"),
                           (pytest.approx(1.0), "left wing tapped")]
    drawn = gx2ctl_here("plot", str(path), "76", "--out", str(tmp_path / "76.png"))
    assert drawn.status == 0, drawn
    assert (tmp_path / "76.png").read_bytes()[:4] == b"\x89PNG"


def test_a_replay_skips_what_it_cannot_read_and_exits_1(gateway, tmp_path):
    directory = tmp_path / "recordings"
    directory.mkdir()
    reads = [(b"\x00" * 16, T0 + i / 100) for i in range(300)]
    with (directory / "gx2-a.mcap").open("wb") as output:
        writer = RecordingWriter(output)
        for i, (data, at) in enumerate(reads):
            writer.serial(data, at, 1000 + at - T0)
            if i % PER_CHUNK == PER_CHUNK - 1:
                writer.flush()
        writer.finish()
    with (directory / "gx2-a.mcap").open("rb") as stream:
        chunk = make_reader(stream).get_summary().chunk_indexes[1]
    damage(directory / "gx2-a.mcap", (chunk.chunk_start_offset, chunk.chunk_length),
           "content")
    (directory / "gx2-b.mcap").write_bytes(b"")
    replay = gateway(f"replay://{directory}?speed=0&exit=true&delay=0", [{"address": 76}],
                     wait=False)
    wait_for(lambda: replay.proc.poll() is not None, 30, "the replay to end (exit=true)")
    log = replay.log()
    assert replay.proc.returncode == 1, log
    assert "gx2-a.mcap: skipped 1 damaged chunk (100 messages" in log
    assert "gx2-b.mcap: skipped: empty" in log
    assert "replay finished: 200 reads" in log


def damage_footer(path: Path, how: str, chunks: list[tuple[int, int]]) -> None:
    """The footer's summary start (the first of its fields) with its highest bit set
    flipped (``bit``: it then points into the data), or set to where a chunk begins."""
    data = bytearray(path.read_bytes())
    field = len(data) - FOOTER_BYTES + RECORD_HEAD.size
    (start,) = struct.unpack_from("<Q", data, field)
    wrong = start ^ (1 << (start.bit_length() - 1)) if how == "bit" else chunks[4][0]
    assert wrong < chunks[-1][0]  # (so the old reader stopped before the last chunk)
    struct.pack_into("<Q", data, field, wrong)
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("how", ["bit", "boundary"])
def test_a_damaged_footer_loses_no_message_and_is_said(tmp_path, how):
    path = tmp_path / "run.mcap"
    chunks = write_chunks(path, [[(TOPIC, euler(seq)) for seq in range(start, start + 100)]
                                 for start in range(1, 1001, 100)])
    damage_footer(path, how, chunks)
    ran = gx2ctl_here("export", str(path), "--out", str(tmp_path / "out"))
    assert ran.status == 0, ran  # nothing was skipped: every message is in the tables
    assert seqs(tmp_path / "out" / "76_euler.csv") == list(range(1, 1001))
    assert ran.stderr == (f"gx2ctl: {path}: its footer is damaged (it points to the wrong "
                          "place for the summary, found by reading the records); read "
                          "every message\n")
    assert "1,000 rows" in ran.stdout


def test_a_damaged_footer_and_a_damaged_chunk_are_both_said_and_counted(tmp_path):
    # the summary found by the records still counts the messages a damaged chunk held
    path = tmp_path / "run.mcap"
    chunks = write_chunks(path, [[(TOPIC, euler(seq)) for seq in range(start, start + 100)]
                                 for start in range(1, 1001, 100)])
    damage(path, chunks[7], "content")
    damage_footer(path, "boundary", chunks)
    reading = Reading()
    read = [entry.payload()["seq"] for entry in read_all([path], reading)]
    assert read == [*range(1, 701), *range(801, 1001)]
    [line] = reading.lines()
    assert line.startswith(f"{path}: its footer is damaged (it points to the wrong place "
                           "for the summary, found by reading the records); skipped 1 "
                           "damaged chunk (100 messages,"), line


def test_messages_a_damaged_file_lost_are_said_as_the_files_not_the_gateways(tmp_path):
    # 1,000 samples at 100 Hz: the radio lost two (no seq for them), the gateway one (its
    # seq missing too), and 200 bytes zeroed in the middle of the sixth chunk lose the
    # 100 samples it held, which were recorded: the file's loss, said apart
    path = tmp_path / "run.mcap"
    samples, seq = [], 0
    for i in range(1000):
        seq += 1
        if i in (50, 51):
            seq -= 1
            continue
        if i == 300:
            continue
        samples.append((TOPIC, payload(76, "euler", seq, T0 + i / 100, timer=i * 196_608,
                                       roll=0.1, pitch=0.2, yaw=0.3)))
    chunks = write_chunks(path, [samples[start:start + 100]
                                 for start in range(0, len(samples), 100)])
    data = bytearray(path.read_bytes())
    offset, length = chunks[5]
    data[offset + length // 2:offset + length // 2 + 200] = bytes(200)
    path.write_bytes(bytes(data))
    ran = gx2ctl_here("export", str(path), "--out", str(tmp_path / "out"))
    assert ran.status == 1, ran
    assert ran.stdout == (f"{tmp_path / 'out' / '76_euler.csv'}  897 rows "
                          "(file damaged: 100 messages, 1.0 s unread)\n"
                          f"{tmp_path / 'out' / 'marks.csv'}  0 marks\n")
    assert "skipped 1 damaged chunk (100 messages" in ran.stderr
    found = records_of([path], 76, None, Reading())
    image = picture(76, found.record, found.payloads, found.name, found.marks, found.counts)
    assert image.title.splitlines()[1] == ("radio: 2 lost (0.20%) · gateway: 1 lost "
                                           "(0.10%) · file damaged: 100 messages, 1.0 s "
                                           "unread")
    drawn = gx2ctl_here("plot", str(path), "76", "--out", str(tmp_path / "76.png"))
    assert drawn.status == 1, drawn
    assert (tmp_path / "76.png").read_bytes()[:4] == b"\x89PNG"


def test_a_damaged_summary_is_not_used_and_loses_no_message(tmp_path):
    path = tmp_path / "run.mcap"
    write_chunks(path, [[(TOPIC, euler(seq)) for seq in range(start, start + 100)]
                        for start in range(1, 301, 100)])
    data = bytearray(path.read_bytes())
    (start,) = struct.unpack_from("<Q", data, len(data) - FOOTER_BYTES + RECORD_HEAD.size)
    data[start] = 0x7F  # the summary's first record: an opcode no record has
    path.write_bytes(bytes(data))
    reading = Reading()
    assert [e.payload()["seq"] for e in read_all([path], reading)] == list(range(1, 301))
    assert not reading.partial
    assert reading.lines() == [f"{path}: its summary is damaged (not used); read every "
                               "message"]


def test_a_message_orjson_refuses_is_read_as_the_standard_library_reads_it() -> None:
    """The reader parses with orjson, which refuses what another writer may have put in
    a recording and the standard library reads (a NaN, the infinities, an int past 64
    bits): such a message is read as it always was; one that is not JSON, or not an
    object, is a RecordingError either way."""
    def parsed(data: bytes) -> dict:
        return Entry("gx2/76/accel_angrate", 0, 0, data).payload()
    nan = parsed(b'{"a": NaN, "b": -Infinity, "n": 123456789012345678901234567890}')
    assert math.isnan(nan["a"]) and nan["b"] == -math.inf
    assert nan["n"] == 123456789012345678901234567890
    # (orjson reads an integer past 64 bits as a float, without refusing it: an outside
    # review's finding)
    for big in (2**64, -(2**63) - 1, 123456789012345678901234567890, 2**64 - 1, -(2**63)):
        assert parsed(b'{"seq": %d}' % big) == {"seq": big}
        assert type(parsed(b'{"seq": %d}' % big)["seq"]) is int
    assert parsed(b'{"t": 0.12345678901234567890123}') == {"t": 0.12345678901234568}
    assert parsed(b'{"x": 0.1, "s": "\\u00e9"}') == {"x": 0.1, "s": "\u00e9"}
    for broken in (b'{"a": ', b"[1, 2]", b"\xff"):
        with pytest.raises(RecordingError):
            parsed(broken)
