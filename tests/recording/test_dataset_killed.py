"""``gx2ctl dataset`` killed (SIGKILL: no clean-up of its own) half way through its
recordings: every part DuckDB and Polars then see is whole, held against the ``mcap``
package's reading of its recording; the partition folders hold nothing but parts (a
Polars scan of a folder reads every file in it, hidden or not); and the next run
completes the dataset exactly as a run never killed makes it; likewise a part whose write
fails half way (issue 44)."""

from __future__ import annotations

import errno
import json
import signal
import subprocess
from collections import defaultdict
from datetime import UTC, datetime
from pathlib import Path

import duckdb
import polars as pl
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from mcap.reader import make_reader

from gateway.recording.columns import nanoseconds
from gateway.recording.dataset import convert
from gateway.recording.reports import Reading
from tests.helpers.processes import gx2ctl, script
from tests.helpers.recorded import make_file
from tests.helpers.waiting import wait_for

SECONDS = 120
"""Each recording's length: a few hundred ms of a run each, time for a kill to land
between its first part and its last recording."""
FILES = 4
RUN = 60.0
"""Seconds allowed for a run (a loaded machine)."""

Part = tuple[str, str, int, str]
"""(recording's stem, record, node, date): one part of the dataset."""


def _expected(paths: list[Path]) -> dict[Part, list[int]]:
    """Each part's rows as the ``mcap`` package reads them: their ``time`` (else
    ``host_time``) in ns, in the order recorded."""
    parts: dict[Part, list[int]] = defaultdict(list)
    for path in paths:
        with path.open("rb") as stream:
            for _, channel, message in make_reader(stream).iter_messages(
                    log_time_order=False):
                _, node, record = [*channel.topic.split("/"), "", ""][:3]
                if not node.isdigit():
                    continue
                payload = json.loads(message.data)
                when = payload.get("time", payload["host_time"])
                day = datetime.fromtimestamp(when, UTC).strftime("%Y-%m-%d")
                parts[(path.stem, record, int(node), day)].append(nanoseconds(when))
    return dict(parts)


def _part(path: Path) -> Part:
    date, node, record = (p.split("=", 1)[1] for p in path.parts[-2:-5:-1])
    return path.name.removeprefix("part-").removesuffix(".parquet"), record, int(node), date


def _visible(out: Path) -> dict[Part, int]:
    """Each part a query of the documented glob reads, and its rows, by DuckDB; Polars,
    by the glob and by a scan of each record's folder, reads as many."""
    glob = f"{out}/record=*/**/*.parquet"
    if not list(out.glob("record=*/**/*.parquet")):
        return {}
    counted = duckdb.sql(f"SELECT filename, count(*) FROM read_parquet('{glob}', "
                         "hive_partitioning = true, union_by_name = true, filename = true) "
                         "GROUP BY filename").fetchall()
    seen = {_part(Path(name)): rows for name, rows in counted}
    polars = pl.scan_parquet(glob, hive_partitioning=True, missing_columns="insert",
                             extra_columns="ignore", include_file_paths="file").group_by(
        "file").len().collect()
    assert {_part(Path(f)): n for f, n in polars.iter_rows()} == seen
    for folder in out.glob("record=*"):
        if not any(path.is_file() for path in folder.rglob("*")):
            continue  # (its first part's folders made, the kill before the part: no files)
        scanned = pl.scan_parquet(folder, hive_partitioning=True).select(pl.len()).collect().item()
        assert scanned == sum(n for p, n in seen.items() if p[1] == folder.name[7:])
    return seen


def _only_whole_parts(out: Path, seen: dict[Part, int], wanted: dict[Part, list[int]]
                      ) -> None:
    """Nothing in the partition folders but the parts the queries read, each holding
    its recording's rows of its node, record and day, to the ns, in the order recorded."""
    for path in out.glob("record=*/**/*"):
        assert path.is_dir() or _part(path) in seen, path
        if path.is_file():
            table = pq.read_table(path, columns=["time", "host_time"])
            times = [t if t is not None else h for t, h in zip(
                table["time"].cast("int64").to_pylist(),
                table["host_time"].cast("int64").to_pylist(), strict=True)]
            assert times == wanted[_part(path)], path


@pytest.fixture(scope="module")
def recordings(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("killed") / "recordings"
    folder.mkdir()
    for k in range(FILES):
        make_file(folder / f"gx2-2026112{k}T000000.000Z.mcap", k * SECONDS, SECONDS)
    return folder


@pytest.fixture(scope="module")
def clean(recordings: Path) -> Path:
    """The dataset a run never killed makes."""
    out = recordings.parent / "clean"
    ran = gx2ctl("dataset", str(recordings), str(out), timeout=RUN)
    assert ran.status == 0 and f"{FILES} converted" in ran.stdout, ran
    return out


def _found(out: Path, pattern: str, deep: bool = False) -> bool:
    """Whether ``pattern`` matches under ``out`` now; not yet, when a directory the run
    renames or removes went as it was looked through (FileNotFoundError from scandir:
    one full run of five)."""
    try:
        return any(out.rglob(pattern) if deep else out.glob(pattern))
    except FileNotFoundError:
        return False


def _first_part(out: Path) -> bool:
    return _found(out, "record=*/node=*/date=*/part-*.parquet")


def _first_temporary(out: Path) -> bool:
    return _found(out, ".*.partial", deep=True)


def _a_part_being_written(out: Path) -> bool:
    """A part's temporary, waited for from when the first recording's tables are
    exported (the wait's polls start short again: a part takes milliseconds)."""
    if not _found(out, ".*/*/*.parquet"):
        return False
    wait_for(lambda: _found(out, ".part-*.partial", deep=True)
             or _found(out, ".*.part-*.partial", deep=True) or _first_part(out), RUN, "a part")
    return True


@pytest.mark.parametrize("sign", [_first_temporary, _a_part_being_written],
                         ids=["at-the-first-temporary", "at-a-part-being-written"])
def test_a_killed_run_leaves_whole_parts_and_the_next_completes_it(
        recordings: Path, clean: Path, tmp_path: Path, sign) -> None:
    out = tmp_path / "dataset"
    run = subprocess.Popen([script("gx2ctl"), "dataset", str(recordings), str(out)],
                           stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                           stderr=subprocess.DEVNULL)
    try:
        wait_for(lambda: sign(out) or run.poll() is not None, RUN, "the run under way")
        run.send_signal(signal.SIGKILL)
    finally:
        run.kill()
        run.wait(RUN)
    assert run.returncode == -signal.SIGKILL, "the run ended before it was killed"
    converted = json.loads((out / "_converted.json").read_text())["files"] \
        if (out / "_converted.json").exists() else {}
    assert len(converted) < FILES  # (killed half way, not after)

    wanted = _expected(sorted(recordings.glob("*.mcap")))
    seen = _visible(out)
    for part, rows in seen.items():
        assert rows == len(wanted[part]), part
    _only_whole_parts(out, seen, wanted)

    again = gx2ctl("dataset", str(recordings), str(out), timeout=RUN)
    assert again.status == 0, again
    assert f"{FILES - len(converted)} converted, {len(converted)} up to date" in again.stdout
    assert _visible(out) == _visible(clean) == {p: len(t) for p, t in wanted.items()}
    assert sorted(p.relative_to(out) for p in out.rglob("*")) == sorted(
        p.relative_to(clean) for p in clean.rglob("*"))  # (no work left behind)
    assert pq.read_table(out / "trials.parquet").equals(pq.read_table(clean / "trials.parquet"))
    assert json.loads((out / "_converted.json").read_text()) == json.loads(
        (clean / "_converted.json").read_text())


def test_a_part_failing_half_written_leaves_nothing_in_its_partition(
        recordings: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The same, deterministic: the second part's write fails half way (a disk full),
    as a kill lands on it at times above."""
    written: list[Path] = []

    class HalfThenFull(pq.ParquetWriter):  # (a part is written a batch at a time)
        def __init__(self, where: Path, schema: pa.Schema, **options: object) -> None:
            super().__init__(where, schema, **options)
            if ".part-" in Path(where).name:  # (not export's own files)
                written.append(Path(where))
            self.full = len(written) == 2 and ".part-" in Path(where).name

        def write_batch(self, batch: pa.RecordBatch, *args: object, **options: object
                        ) -> None:
            if self.full:
                super().write_batch(batch.slice(0, batch.num_rows // 2))
                raise OSError(errno.ENOSPC, "No space left on device")
            super().write_batch(batch, *args, **options)

    monkeypatch.setattr(pq, "ParquetWriter", HalfThenFull)
    out = tmp_path / "dataset"
    with pytest.raises(OSError, match="No space"):
        convert(sorted(recordings.glob("*.mcap")), out, Reading())
    wanted = _expected(sorted(recordings.glob("*.mcap")))
    seen = _visible(out)
    assert len(seen) == 1  # (the first part)
    _only_whole_parts(out, seen, wanted)
    assert not list(out.rglob("*.partial"))
