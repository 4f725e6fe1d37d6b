"""The reader's blocks (a chunk's messages at once: recording/blocks.py), held against the
messages one at a time, through real files of the recorder's writer: a window whose
edges fall inside chunks, a message met again across chunks and files, a damaged chunk
in the middle, a file still being written; and an export of some nodes across a
damaged chunk, which the blocks carry past the messages a window leaves out."""

from __future__ import annotations

from gateway.recording.blocks import Block, blocks_of, entries_of
from gateway.recording.catalogue import catalogue
from gateway.recording.reader import Entry, read, read_blocks
from gateway.recording.reports import Reading
from gateway.recording.window import Reader, Window
from gateway.recording.writer import RecordingWriter
from tests.helpers.processes import gx2ctl_here
from tests.helpers.recorded import T0, make_file
from tests.recording.test_damage import damage, three_chunks, write_chunks
from tests.recording.test_offline import payload

NS = 1_000_000_000


def ns(seconds: float) -> int:
    return round((T0 + seconds) * NS)


def flat(blocks: list[Block]) -> list[Entry]:
    return list(entries_of(blocks))


def test_a_window_whose_edges_fall_inside_chunks_keeps_exactly_its_messages(tmp_path):
    path = make_file(tmp_path / "run.mcap", 0, 5)  # (a chunk a second)
    everything = list(read(path, Reading()))
    for start, stop in [(ns(1.3), ns(3.7)), (everything[70].log_time, everything[200].log_time),
                        (ns(-1), ns(0.5)), (ns(4.5), 2 ** 64)]:
        reading = Reading()
        blocks = list(read_blocks(path, reading, span=(start, stop)))
        assert flat(blocks) == [e for e in everything if start <= e.log_time < stop]
        assert all(len(block) for block in blocks)
        # the chunks outside the window are not decompressed
        [report] = reading.files
        assert report.decompressed == len(blocks)
    euler = [e for e in everything if e.topic == "gx2/13/euler"]
    start, stop = euler[3].log_time, euler[20].log_time
    blocks = list(read_blocks(path, Reading(), ["gx2/13/euler"], (start, stop)))
    assert flat(blocks) == euler[3:20]
    assert {topic for block in blocks for topic in block.topics.values()} == {"gx2/13/euler"}


def test_a_file_being_written_is_read_up_to_its_last_flush(tmp_path):
    path = tmp_path / "run.mcap"
    with path.open("wb") as output:
        writer = RecordingWriter(output)
        for seq in range(1, 301):
            at = T0 + seq / 100
            writer.message("gx2/76/euler", payload(76, "euler", seq, at, timer=seq, roll=0.1,
                                                   pitch=0.2, yaw=0.3))
            if seq % 100 == 0:
                writer.flush()
        writer.message("gx2/76/euler", payload(76, "euler", 301, T0 + 3.01, timer=301,
                                               roll=0.1, pitch=0.2, yaw=0.3))  # not flushed
        reading = Reading()
        blocks = list(read_blocks(path, reading))
        assert [e.payload()["seq"] for e in flat(blocks)] == list(range(1, 301))
        assert flat(blocks) == list(read(path, Reading()))
        [report] = reading.files
        assert report.writing and not report.whole and not report.partial
        assert "being written: its last flush after" in reading.lines()[0]
        # a window of it: the chunks' headers say their span, no summary being written
        span = (ns(1.505), ns(2.5))
        window = list(read_blocks(path, Reading(), span=span))
        assert flat(window) == [e for e in flat(blocks) if span[0] <= e.log_time < span[1]]
        assert len(window) == 2  # (its edges inside the second chunk and the third)
        writer.flush()
        assert len(flat(list(read_blocks(path, Reading())))) == 301
        writer.finish()


def test_a_damaged_chunk_in_the_middle_is_said_by_the_block_after_it(tmp_path):
    path = tmp_path / "run.mcap"
    damage(path, three_chunks(path)[1], "content")
    reading = Reading()
    blocks = list(read_blocks(path, reading))
    assert [block.after_damage for block in blocks] == [False, True]
    assert [e.payload()["seq"] for e in flat(blocks)] == [*range(1, 101), *range(201, 301)]
    assert flat(blocks) == list(read(path, Reading()))
    assert reading.lines()[0].startswith(f"{path}: skipped 1 damaged chunk (100 messages")
    # a window that starts inside the damaged chunk: said by its first message after it
    later = list(read_blocks(path, Reading(), span=(ns(1.5), 2 ** 64)))
    assert [block.after_damage for block in later] == [True]
    assert next(later[0].entries()).payload()["seq"] == 201


def test_a_message_met_again_across_chunks_and_files_is_kept_once(tmp_path):
    folder = tmp_path / "recordings"
    folder.mkdir()
    make_file(folder / "a.mcap", 0, 10)
    make_file(folder / "b.mcap", 5, 10)  # (seconds 5 to 15, a chunk each)
    make_file(folder / "c.mcap", 0, 15)  # (read after a: its first 10 s again, then b's)
    one = list(read(make_file(tmp_path / "one.mcap", 0, 15), Reading()))
    files = catalogue(sorted(folder.iterdir()))
    for window in (Window(), Window((ns(4.3), ns(11.7))), Window(nodes=frozenset({12}))):
        reader = Reader(files, Reading())
        blocks = list(reader.blocks(window))
        kept = [e for e in one if (window.span is None or window.span[0] <= e.log_time
                                   < window.span[1]) and window.keeps(e.topic)]
        assert [(e.topic, e.log_time, e.data) for e in flat(blocks)] == [
            (e.topic, e.log_time, e.data) for e in kept]
        times = [e.log_time for e in kept]
        again = sum(t < ns(10) for t in times) + sum(t >= ns(5) for t in times)
        assert reader.duplicates == again
        assert next(Reader(files, Reading()).entries(window)) == flat(blocks)[0]


def test_an_export_of_some_nodes_says_a_damaged_stretch_past_the_messages_it_leaves_out(
        tmp_path):
    # the first message after the damaged chunk is node 77's: a window of node 76 alone
    # leaves it out, and the damage is said by node 76's next row all the same (the
    # samples across it unread, not the radio's)
    path = tmp_path / "run.mcap"

    def euler(node: int, seq: int) -> tuple[str, dict]:
        return (f"gx2/{node}/euler", payload(node, "euler", seq, T0 + seq / 100,
                                             timer=seq * 196_608, roll=0.1, pitch=0.2,
                                             yaw=0.3))
    chunks = write_chunks(path, [[euler(76, seq) for seq in range(1, 101)],
                                 [euler(76, seq) for seq in range(101, 201)],
                                 [euler(77, 201), *(euler(76, seq) for seq in range(202, 301))]])
    damage(path, chunks[1], "content")
    out = tmp_path / "out"
    ran = gx2ctl_here("export", str(path), "--node", "76", "--out", str(out))
    assert ran.status == 1, ran.stderr  # (partial: the damaged chunk)
    # seq 101 to 201: 100 in the damaged chunk, and 201 node 77's, all unread
    assert f"{out / '76_euler.csv'}  199 rows (file damaged: 101 messages, 1.0 s unread)" \
        in ran.stdout


def test_blocks_made_of_entries_give_the_entries_back(tmp_path):
    path = make_file(tmp_path / "run.mcap", 0, 3)
    damage(path, three_chunks(tmp_path / "damaged.mcap")[1], "content")
    for file in (path, tmp_path / "damaged.mcap"):
        entries = list(read(file, Reading()))
        blocks = list(blocks_of(entries, size=37))
        assert flat(blocks) == entries
        assert max(len(block) for block in blocks) == 37
