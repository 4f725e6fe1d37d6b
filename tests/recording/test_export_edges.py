"""Exports of foreign recordings at the formats' edges, run as users run them: times no
typed column holds, and field names MATLAB maps onto each other."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from scipy.io import loadmat

from tests.helpers.processes import gx2ctl, gx2ctl_here
from tests.helpers.recorded import T0, foreign_file

EULER = {"node": 11, "record": "euler", "command": 0xCE, "seq": 0, "host_time": T0,
         "roll": 0.1, "pitch": 0.2, "yaw": 0.3}


@pytest.mark.parametrize("time", [1_795_000_000_000, 1e10, 10**400],
                         ids=["ms", "1e10 s", "10**400"])
def test_a_time_no_typed_column_holds_is_missing_not_a_crash(tmp_path: Path,
                                                             time: float) -> None:
    path = foreign_file(tmp_path / "odd.mcap", [("gx2/11/euler", {**EULER, "time": time}),
                                         ("gx2/11/euler", {**EULER, "seq": 1,
                                                           "time": T0 + 1})])
    for form in ("csv", "parquet", "mat"):
        ran = gx2ctl("export", str(path), "--out", str(tmp_path / form), "--format", form)
        assert ran.status == 0 and not ran.stderr, ran.stderr
    with (tmp_path / "csv" / "11_euler.csv").open() as table:
        assert [row["time"] for row in csv.DictReader(table)][1] == repr(T0 + 1)
    times = pq.read_table(tmp_path / "parquet" / "11_euler.parquet").column("time")
    assert times[0].as_py() is None and times[1].as_py().timestamp() == T0 + 1
    struct = loadmat(tmp_path / "mat" / "11_euler.mat", simplify_cells=True)["n11_euler"]
    assert struct["roll"].tolist() == [0.1, 0.1]
    if time == 10**400:
        assert math.isnan(struct["time"][0]) and struct["time"][1] == T0 + 1


def test_mat_keeps_every_column_whose_names_collide(tmp_path: Path) -> None:
    custom = {"node": 11, "record": "custom", "seq": 0, "host_time": T0, "a-b": 1.0,
              "a_b": 2.0, "units": 3.0, "descriptions": "text"}
    path = foreign_file(tmp_path / "names.mcap", [("gx2/11/custom", custom)])
    ran = gx2ctl_here("export", str(path), "--out", str(tmp_path), "--format", "mat")
    assert ran.status == 0, ran.stderr
    struct = loadmat(tmp_path / "11_custom.mat", simplify_cells=True)["n11_custom"]
    assert struct["a_b"] == 1.0 and struct["a_b_2"] == 2.0 and struct["units_2"] == 3.0
    assert struct["descriptions_2"] == "text"
    assert struct["units"]["rssi"] == "dBm" and "a_b_2" in struct["units"]


def test_a_window_without_marks_has_its_marks_table_all_the_same(tmp_path: Path) -> None:
    """docs/recording.md says export writes the marks: a window that holds none gets
    the table's header alone, in every format (issue 43: no marks.csv at all)."""
    path = foreign_file(tmp_path / "unmarked.mcap", [("gx2/11/euler", EULER)])
    for form in ("csv", "parquet", "mat"):
        out = tmp_path / form
        ran = gx2ctl_here("export", str(path), "--out", str(out), "--format", form)
        assert ran.status == 0 and not ran.stderr, ran.stderr
        assert f"{out / f'marks.{form}'}  0 marks\n" in ran.stdout, ran.stdout
    with (tmp_path / "csv" / "marks.csv").open() as table:
        assert list(csv.reader(table)) == [["time", "host_time", "nodes", "text"]]
    marks = pq.read_table(tmp_path / "parquet" / "marks.parquet")
    assert marks.num_rows == 0 and marks.column_names == ["time", "host_time", "nodes",
                                                          "text"]
    struct = loadmat(tmp_path / "mat" / "marks.mat", simplify_cells=True)["marks"]
    assert {"time", "host_time", "nodes", "text", "units"} <= set(struct)
    assert len(struct["time"]) == 0


def test_an_earlier_exports_tables_are_replaced_only_with_force(tmp_path: Path) -> None:
    """As record refuses an existing file, export refuses to replace an earlier
    export's tables: one line, exit 2, nothing touched (issue 43: it replaced them
    without a word); --force replaces them. Another format's tables, and files that are
    no export's, are no reason to refuse."""
    path = foreign_file(tmp_path / "a.mcap", [("gx2/11/euler", EULER)])
    out = tmp_path / "out"
    first = gx2ctl_here("export", str(path), "--out", str(out))
    assert first.status == 0, first
    (out / "notes.txt").write_text("mine")
    assert gx2ctl_here("export", str(path), "--out", str(out), "--format", "parquet").status == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    (out / "11_euler.csv").write_text("edited by hand\n")
    again = gx2ctl_here("export", str(path), "--out", str(out))
    assert again.status == 2 and again.stdout == "", again
    assert again.stderr == (f"gx2ctl: {out / '11_euler.csv'} exists (and 1 more tables): "
                            "export to a new --out, or give --force to replace an earlier "
                            "export's tables\n"), again
    assert (out / "11_euler.csv").read_text() == "edited by hand\n"
    assert not [p for p in out.iterdir() if p.name.startswith(".")]
    forced = gx2ctl_here("export", str(path), "--out", str(out), "--force")
    assert forced.status == 0, forced
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_only_an_exports_own_tables_are_refused_and_force_removes_every_one(
        tmp_path: Path) -> None:
    """Files that are no export's table (a user's ``2024_budget.csv``: a number, ``_``
    and a name that is no record) are no reason to refuse, and --force leaves them;
    --force removes every table of an earlier export before writing, so that the
    tables of a node not exported now are not left beside the new ones (issue 43
    review: ``2024_budget.csv`` made export refuse, and ``12_euler.csv`` stayed)."""
    path = foreign_file(tmp_path / "a.mcap", [
        ("gx2/11/euler", EULER), ("gx2/12/euler", {**EULER, "node": 12})])
    out = tmp_path / "out"
    out.mkdir()
    mine = {"2024_budget.csv": "mine", "11_notes.csv": "mine too", "marks.txt": "and this"}
    for name, text in mine.items():
        (out / name).write_text(text)
    first = gx2ctl_here("export", str(path), "--out", str(out))
    assert first.status == 0 and first.stderr == "", first
    assert gx2ctl_here("export", str(path), "--out", str(out), "--format", "parquet").status == 0
    one = gx2ctl_here("export", str(path), "--out", str(out), "--node", "11", "--force")
    assert one.status == 0 and one.stderr == "", one
    assert sorted(p.name for p in out.iterdir()) == sorted([
        *mine, "11_euler.csv", "marks.csv",  # (12_euler.csv: the earlier export's, gone)
        "11_euler.parquet", "12_euler.parquet", "marks.parquet"])  # (another format's)
    assert {name: (out / name).read_text() for name in mine} == mine
