"""``gx2ctl dataset`` (by gx2ctl's entry point in this process, the installed program
where the process itself is the subject: tests/helpers/processes.py, gx2ctl_here),
queried as its users query it:
DuckDB and Polars on the Hive-partitioned Parquet, counts and values held against the
recordings read by the ``mcap`` package (never our reader); incremental runs; the
trials table (issue 44)."""

from __future__ import annotations

import json
import re
from collections import Counter
from pathlib import Path

import duckdb
import polars as pl
import pyarrow.parquet as pq
import pytest
from mcap.reader import make_reader

from gateway.recording.columns import nanoseconds
from tests.helpers.processes import gx2ctl, gx2ctl_here
from tests.helpers.recorded import FILE_SECONDS, make_file


def _records(paths: list[Path]) -> list[tuple[str, dict]]:
    """(topic, payload) of the nodes' records, by the ``mcap`` package."""
    found = []
    for path in paths:
        with path.open("rb") as stream:
            for _, channel, message in make_reader(stream).iter_messages(
                    log_time_order=False):
                if channel.topic.startswith("gx2/") and channel.topic.split("/")[1].isdigit():
                    found.append((channel.topic, json.loads(message.data)))
    return found


@pytest.fixture
def recordings(tmp_path: Path) -> Path:
    folder = tmp_path / "recordings"
    folder.mkdir()
    for k in range(2):
        make_file(folder / f"gx2-2026112{k}T000000.000Z.mcap", k * FILE_SECONDS, FILE_SECONDS)
    return folder


def test_the_dataset_is_what_the_recordings_hold(recordings: Path, tmp_path: Path) -> None:
    out = tmp_path / "dataset"
    ran = gx2ctl("dataset", str(recordings), str(out))
    assert ran.status == 0 and "2 converted, 0 up to date" in ran.stdout, ran
    messages = _records(sorted(recordings.glob("*.mcap")))
    expected = Counter((topic.split("/")[2], int(topic.split("/")[1])) for topic, _ in messages)
    glob = f"{out}/record=*/**/*.parquet"
    counted = duckdb.sql(
        f"SELECT record, node, count(*) FROM read_parquet('{glob}', hive_partitioning=true, "
        "union_by_name=true) GROUP BY record, node").fetchall()
    assert {(r, int(n)): c for r, n, c in counted} == dict(expected)
    # every time to the ns, as the message wrote it; DuckDB's timestamps are us: Polars
    frame = pl.scan_parquet(f"{out}/record=accel_angrate/**/*.parquet",
                            hive_partitioning=True).filter(pl.col("node") == 11).sort(
        "time").collect()
    wanted = sorted(nanoseconds(p["time"]) for t, p in messages if t == "gx2/11/accel_angrate")
    assert frame["time"].dt.epoch("ns").to_list() == wanted
    assert frame["ang_rate_z"].to_list()[:3] == [0.0, 1.0, 2.0]
    # the types of export --format parquet, column for column
    exported = tmp_path / "exported"
    assert gx2ctl("export", str(recordings), "--out", str(exported), "--format",
                  "parquet").status == 0
    [part] = (out / "record=euler" / "node=13").glob("date=*/part-*20T*.parquet")
    assert pq.read_schema(part).equals(pq.read_schema(exported / "13_euler.parquet"),
                                       check_metadata=True)
    # two nodes joined on time (the recordings' nodes 11 and 12 sample together)
    joined = duckdb.sql(
        f"SELECT count(*) FROM read_parquet('{out}/record=accel_angrate/node=11/**/*.parquet')"
        f" a JOIN read_parquet('{out}/record=accel_angrate/node=12/**/*.parquet') b "
        "USING (time)").fetchall()
    assert joined == [(expected[("accel_angrate", 11)],)]
    trials = duckdb.sql(f"SELECT trial, start_mark, stop_mark, stop IS NULL FROM "
                        f"read_parquet('{out}/trials.parquet') ORDER BY trial").fetchall()
    # (the second trial's stop is in a file not yet recorded: open)
    assert trials == [(1, "start", "stop", False), (2, "start", None, True)]


def test_a_second_run_converts_only_what_is_new(recordings: Path, tmp_path: Path) -> None:
    out = tmp_path / "dataset"
    assert gx2ctl_here("dataset", str(recordings), str(out)).status == 0
    parts = {p: p.stat().st_mtime_ns for p in out.rglob("part-*.parquet")}
    again = gx2ctl_here("dataset", str(recordings), str(out))
    assert again.status == 0 and "0 converted, 2 up to date" in again.stdout, again
    make_file(recordings / "gx2-20261122T000000.000Z.mcap", 2 * FILE_SECONDS, FILE_SECONDS)
    third = gx2ctl_here("dataset", str(recordings), str(out))
    assert third.status == 0 and "1 converted, 2 up to date" in third.stdout, third
    assert {p: p.stat().st_mtime_ns for p in parts} == parts  # (untouched)
    # retention deletes a recording: its parts stay
    (recordings / "gx2-20261120T000000.000Z.mcap").unlink()
    assert gx2ctl_here("dataset", str(recordings), str(out)).status == 0
    total = duckdb.sql(f"SELECT count(*) FROM read_parquet('{out}/record=euler/**/*.parquet')"
                       ).fetchall()
    assert total == [(3 * FILE_SECONDS * 5,)]
    assert not list(out.rglob(".*partial"))


def test_no_recording_is_one_line(tmp_path: Path) -> None:
    ran = gx2ctl_here("dataset", str(tmp_path / "nothing"), str(tmp_path / "out"))
    assert ran.status == 2 and len(ran.stderr.splitlines()) == 1, ran
    assert "Traceback" not in ran.stderr


def test_the_queries_of_the_docs_run_as_written(recordings: Path, tmp_path: Path) -> None:
    """docs/recording.md, "Analysing a study": every SQL block run by DuckDB on a dataset
    in ``dataset/``, each giving rows; the trial's counts are the recordings'."""
    assert gx2ctl_here("dataset", str(recordings), str(tmp_path / "dataset")).status == 0
    text = (Path(__file__).resolve().parents[2] / "docs" / "recording.md").read_text()
    section = text[text.index("## Analysing a study"):]
    queries = re.findall(r"```sql\n(.*?)```", section, re.S)
    assert len(queries) == 4
    connection = duckdb.connect()
    connection.execute(f"SET file_search_path = '{tmp_path}'")
    results = [connection.sql(query.replace("'dataset/", f"'{tmp_path}/dataset/")).fetchall()
               for query in queries]
    assert all(results), results
    trial, _, losses, joined = results
    # trial 1: marks at 5 s and 12 s; nodes 11 and 12 at 25 Hz, sampled 2 ms before
    # they were read (time, against the marks' time): 5.038 .. 11.998 s
    assert [(node, rows) for node, rows, *_ in trial] == [(11, 175), (12, 175)]
    assert {node for node, *_ in losses} == {11, 12, 13}
    assert len(joined) == 2 * FILE_SECONDS * 25
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    rows = eval(code.splitlines()[1].split("=", 1)[1].replace(  # (the scan, then its query)
        '"dataset/', f'"{tmp_path}/dataset/'), {"pl": pl})
    assert rows.filter(pl.col("node") == 13).collect().height == 2 * FILE_SECONDS * 5


def test_a_name_with_glob_characters_deletes_no_other_recording_parts(tmp_path: Path) -> None:
    """``s[12].mcap`` converted: the parts of ``s1.mcap`` stay (a name is no pattern)."""
    folder = tmp_path / "recordings"
    folder.mkdir()
    make_file(folder / "s1.mcap", 0, FILE_SECONDS)
    make_file(folder / "s[12].mcap", FILE_SECONDS, FILE_SECONDS)
    out = tmp_path / "dataset"
    assert gx2ctl_here("dataset", str(folder), str(out)).status == 0
    assert {p.name for p in out.rglob("part-*")} == {"part-s1.parquet", "part-s[12].parquet"}
    total = duckdb.sql(f"SELECT count(*) FROM read_parquet('{out}/record=euler/**/*.parquet')"
                       ).fetchall()
    assert total == [(2 * FILE_SECONDS * 5,)]


def _not_an_object(path: Path) -> None:
    """A recording one of whose messages is not a JSON object (RecordingError)."""
    from mcap.writer import Writer
    with path.open("wb") as stream:
        writer = Writer(stream)
        writer.start(profile="", library="another")
        channel = writer.register_channel("gx2/11/euler", "json", schema_id=0)
        at = 1_795_000_021_000_000_000
        writer.add_message(channel, at, json.dumps(
            {"node": 11, "record": "euler", "seq": 0, "host_time": at / 1e9,
             "roll": 0.0}).encode(), at)
        writer.add_message(channel, at + 1, b"[1, 2]", at + 1)
        writer.finish()


def test_an_unreadable_recording_is_one_line_and_the_rest_are_converted(
        tmp_path: Path) -> None:
    folder = tmp_path / "recordings"
    folder.mkdir()
    make_file(folder / "gx2-20261120T000000.000Z.mcap", 0, FILE_SECONDS)
    odd = folder / "gx2-20261121T000000.000Z.mcap"
    _not_an_object(odd)
    make_file(folder / "gx2-20261122T000000.000Z.mcap", FILE_SECONDS, FILE_SECONDS)
    out = tmp_path / "dataset"
    for run in range(2):  # (left unstamped: tried again, and said again)
        ran = gx2ctl_here("dataset", str(folder), str(out))
        assert ran.status == 1, ran
        [line] = ran.stderr.splitlines()
        assert str(odd) in line and "not a JSON object" in line, ran
        assert f"{2 - 2 * run} converted, {2 * run} up to date, 1 not converted" in ran.stdout
    assert {p.name for p in out.rglob("part-*")} == {
        "part-gx2-20261120T000000.000Z.parquet", "part-gx2-20261122T000000.000Z.parquet"}
    assert odd.name not in json.loads((out / "_converted.json").read_text())["files"]


def test_a_recording_deleted_during_the_run_is_skipped(
        recordings: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """Retention deletes a recording between the catalogue and its conversion: it is
    said gone and skipped, the rest converted (the run blamed OUT, and stopped)."""
    import gateway.recording.dataset as dataset
    from gateway.ctl import cli
    first = recordings / "gx2-20261120T000000.000Z.mcap"
    catalogue = dataset.catalogue

    def then_retention(*args: object, **kwargs: object) -> object:
        found = catalogue(*args, **kwargs)
        first.unlink()
        return found
    monkeypatch.setattr(dataset, "catalogue", then_retention)
    out = tmp_path / "dataset"
    assert cli.main(["dataset", str(recordings), str(out)]) == 0
    said = capsys.readouterr()
    assert f"{first}  gone" in said.out and "1 converted" in said.out, said
    assert {p.name for p in out.rglob("part-*")} == {"part-gx2-20261121T000000.000Z.parquet"}


def test_out_s_trouble_names_the_file(recordings: Path, tmp_path: Path) -> None:
    out = tmp_path / "dataset"
    out.mkdir()
    (out / "record=euler").write_text("not a folder")
    ran = gx2ctl_here("dataset", str(recordings), str(out))
    assert ran.status == 2 and len(ran.stderr.splitlines()) == 1, ran
    assert f"{out}/record=euler/node=13" in ran.stderr, ran


def test_a_mark_time_beyond_timestamp_ns_is_null_in_trials(tmp_path: Path) -> None:
    """A foreign mark's ``time`` of 1e10 s (the year 2286): null, as export writes it
    (every run ended in an OverflowError, trials.parquet never written)."""
    from gateway.recording.files import MARK
    from gateway.recording.writer import RecordingWriter
    folder = tmp_path / "recordings"
    folder.mkdir()
    t0 = 1_795_000_000.0
    with (folder / "gx2-20261120T000000.000Z.mcap").open("wb") as stream:
        writer = RecordingWriter(stream)
        writer.message(MARK, {"time": 1e10, "host_time": t0, "nodes": [], "text": "start"})
        writer.message("gx2/11/euler", {"node": 11, "record": "euler", "seq": 0,
                                        "host_time": t0 + 0.5, "time": t0 + 0.5,
                                        "roll": 0.0, "pitch": 0.0, "yaw": 0.0})
        writer.finish()
    out = tmp_path / "dataset"
    ran = gx2ctl_here("dataset", str(folder), str(out))
    assert ran.status == 0 and "1 trials" in ran.stdout, ran
    assert pq.read_table(out / "trials.parquet").to_pylist() == [
        {"trial": 1, "start": None, "stop": None, "start_mark": "start", "stop_mark": None}]


def test_a_second_run_at_once_says_so_and_does_nothing(recordings: Path, tmp_path: Path
                                                       ) -> None:
    """The timer's run and one by hand on one OUT: the second finds OUT/.lock held."""
    import fcntl
    out = tmp_path / "dataset"
    out.mkdir()
    with (out / ".lock").open("w") as held:
        fcntl.flock(held, fcntl.LOCK_EX)  # (as a run converting holds it)
        ran = gx2ctl("dataset", str(recordings), str(out))
    assert ran.status == 75 and ran.stdout == "", ran
    [line] = ran.stderr.splitlines()
    assert "another gx2ctl dataset is converting" in line, ran
    assert not list(out.rglob("*.parquet"))
    assert gx2ctl("dataset", str(recordings), str(out)).status == 0  # (released)


def test_a_run_clears_what_a_killed_run_left(recordings: Path, tmp_path: Path) -> None:
    """A run stopped (SIGTERM) mid-recording, its recording then deleted by retention:
    the next run removes its work folder and partial files."""
    out = tmp_path / "dataset"
    left = [out / ".converting" / "gx2-20261119T000000.000Z" / "11_euler.parquet",
            out / "._converted.json.partial", out / ".trials.parquet.partial",
            out / "record=euler" / "node=13" / "date=2026-11-18" / ".part-gone.parquet.partial"]
    for path in left:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(b"PAR1 half")
    assert gx2ctl_here("dataset", str(recordings), str(out)).status == 0
    hidden = [p for p in out.rglob("*") if p.name.startswith(".") and p.name != ".lock"]
    assert hidden == []


def test_trials_are_kept_when_retention_deletes_their_recording(
        recordings: Path, tmp_path: Path) -> None:
    """trials.parquet merges each run's trials into the earlier ones: an open trial gets
    its stop, keeping its number; a trial whose recording is deleted keeps its row and
    number (it was dropped, and the next renumbered 1)."""
    out = tmp_path / "dataset"
    query = (f"SELECT trial, epoch_ns(start), stop IS NULL FROM "
             f"read_parquet('{out}/trials.parquet') ORDER BY trial")
    assert gx2ctl_here("dataset", str(recordings), str(out)).status == 0
    first = duckdb.sql(query).fetchall()
    assert [(n, open_) for n, _, open_ in first] == [(1, False), (2, True)]
    make_file(recordings / "gx2-20261122T000000.000Z.mcap", 2 * FILE_SECONDS, FILE_SECONDS)
    assert gx2ctl_here("dataset", str(recordings), str(out)).status == 0
    second = duckdb.sql(query).fetchall()
    assert second == [(1, first[0][1], False), (2, first[1][1], False)]
    (recordings / "gx2-20261120T000000.000Z.mcap").unlink()  # (retention)
    ran = gx2ctl_here("dataset", str(recordings), str(out))
    assert ran.status == 0 and "2 trials" in ran.stdout, ran
    assert duckdb.sql(query).fetchall() == second


def test_a_second_recordings_directory_into_one_out_is_refused(tmp_path: Path) -> None:
    """Two gateways' directories, a recording of the same name in each: the second
    directory is refused in one line (its recording replaced the first's parts)."""
    name = "gx2-20261120T000000.000Z.mcap"
    one, other = tmp_path / "roomA", tmp_path / "roomB"
    for k, folder in enumerate((one, other)):
        folder.mkdir()
        make_file(folder / name, k * FILE_SECONDS, FILE_SECONDS)
    out = tmp_path / "dataset"
    assert gx2ctl_here("dataset", str(one), str(out)).status == 0
    ran = gx2ctl_here("dataset", str(other), str(out))
    assert ran.status == 2 and len(ran.stderr.splitlines()) == 1, ran
    assert f"holds the recordings of {one}" in ran.stderr, ran
    seqs = duckdb.sql(f"SELECT min(seq), max(seq), count(*) FROM read_parquet("
                      f"'{out}/record=accel_angrate/node=11/**/*.parquet')").fetchall()
    assert seqs == [(0, FILE_SECONDS * 25 - 1, FILE_SECONDS * 25)]
    state = json.loads((out / "_converted.json").read_text())
    assert state["recordings"] == str(one) and list(state["files"]) == [name]
    # a file of the same directory given alone is that directory's
    assert gx2ctl_here("dataset", str(one / name), str(out)).status == 0


def test_an_earlier_version_s_converted_list_is_read(recordings: Path, tmp_path: Path
                                                     ) -> None:
    out = tmp_path / "dataset"
    assert gx2ctl_here("dataset", str(recordings), str(out)).status == 0
    state = json.loads((out / "_converted.json").read_text())
    (out / "_converted.json").write_text(json.dumps(state["files"]))  # ({NAME: STAMP})
    ran = gx2ctl_here("dataset", str(recordings), str(out))
    assert ran.status == 0 and "0 converted, 2 up to date" in ran.stdout, ran


def test_a_copy_is_skipped_and_an_overlap_said(tmp_path: Path) -> None:
    """A recording twice (a copy under another name, the catalogue's same_as): its rows
    once, the copy said skipped; a recording overlapping one converted: a line said."""
    import shutil
    folder = tmp_path / "recordings"
    folder.mkdir()
    first = make_file(folder / "gx2-20261120T000000.000Z.mcap", 0, FILE_SECONDS)
    shutil.copy2(first, folder / "gx2-20261120T000000.000Z-copy.mcap")
    out = tmp_path / "dataset"
    ran = gx2ctl_here("dataset", str(folder), str(out))
    assert ran.status == 0 and "1 converted, 0 up to date, 1 the same as" in ran.stdout, ran
    assert "skipped" in ran.stdout and ran.stderr == "", ran
    counted = duckdb.sql(f"SELECT count(*), count(DISTINCT seq) FROM read_parquet("
                         f"'{out}/record=accel_angrate/node=11/**/*.parquet')").fetchall()
    assert counted == [(FILE_SECONDS * 25, FILE_SECONDS * 25)]
    later = make_file(folder / "gx2-20261120T000010.000Z.mcap", FILE_SECONDS // 2,
                      FILE_SECONDS)
    ran = gx2ctl_here("dataset", str(folder), str(out))
    assert ran.status == 0 and "1 converted, 2 up to date" in ran.stdout, ran
    [line] = ran.stderr.splitlines()
    assert f"{later} overlaps" in line and "twice" in line, ran


_PEAK = """
import sys
from pathlib import Path
import pyarrow as pa
from gateway.recording.dataset import convert
from gateway.recording.reports import Reading
from tests.helpers.recorded import make_file
folder = Path(sys.argv[1])
recording = make_file(folder / "gx2-20261120T000000.000Z.mcap", 0, int(sys.argv[2]))
convert([recording], folder / "dataset", Reading())
print(pa.default_memory_pool().max_memory())
"""


def test_memory_does_not_grow_with_the_recording(tmp_path: Path) -> None:
    """A recording four times as long converts in about the same Arrow memory (a batch
    at a time, as export: a table read whole, then filtered per day, took memory in
    proportion to the recording). Each in a process of its own: the pool's peak is the
    conversion's."""
    import subprocess
    import sys
    peaks = []
    for seconds in (800, 3200):
        folder = tmp_path / str(seconds)
        folder.mkdir()
        ran = subprocess.run([sys.executable, "-c", _PEAK, str(folder), str(seconds)],
                             capture_output=True, text=True, timeout=120,
                             cwd=Path(__file__).resolve().parents[2])
        assert ran.returncode == 0, ran.stderr
        peaks.append(int(ran.stdout))
    assert peaks[1] < 1.4 * peaks[0], peaks
