"""gx2ctl recordings (the catalogue) and the windows of export and plot, run as users run
them, on rotated recordings written through the recording writer a second at a time (a
chunk a second, as the recorder flushes), checked against the mcap package's reader."""

from __future__ import annotations

import csv
import json
import shutil
from datetime import UTC, datetime
from pathlib import Path

import pytest
from mcap.reader import make_reader

from gateway.recording.files import MARK
from gateway.recording.reader import read
from gateway.recording.reports import Reading
from gateway.recording.writer import RecordingWriter
from tests.helpers.processes import gx2ctl, gx2ctl_here
from tests.helpers.recorded import RATE, T0, hourly_files, make_file


@pytest.fixture
def recordings(tmp_path: Path) -> Path:
    return hourly_files(tmp_path)


def messages(paths: list[Path], start: float | None = None, end: float | None = None,
             holding_end: bool = False) -> list[tuple[str, int, dict]]:
    """What the mcap package reads of the files in [start, end) (UNIX s; [start, end]
    if ``holding_end``)."""
    ending = "ending_at" if holding_end else "ending_before"
    found = []
    for path in paths:
        with path.open("rb") as stream:
            for _, channel, message in make_reader(stream).iter_messages(
                    starting_at=None if start is None else round(start * 1e9),
                    **{ending: None if end is None else round(end * 1e9)}):
                found.append((channel.topic, message.log_time, json.loads(message.data)))
    return found


def host_times(rows: list[tuple[str, int, dict]], topic: str) -> list[float]:
    return [payload["host_time"] for t, _, payload in rows if t == topic]


def column(path: Path, name: str) -> list[float]:
    with path.open(newline="") as stream:
        return [float(row[name]) for row in csv.DictReader(stream)]


def iso(seconds: float) -> str:
    return datetime.fromtimestamp(seconds, UTC).isoformat()


# --- the catalogue ----------------------------------------------------------------------


def test_catalogue_says_what_each_file_holds_from_its_summary(recordings: Path) -> None:
    ran = gx2ctl("recordings", "--json", str(recordings))
    assert ran.status == 0, ran.stderr
    assert len(ran.stdout.splitlines()) == 1
    files = json.loads(ran.stdout)["files"]
    paths = sorted(recordings.iterdir())
    assert [f["path"] for f in files] == [str(p) for p in paths]
    for described, path in zip(files, paths, strict=True):
        read_back = messages([path])
        times = [log_time for _, log_time, _ in read_back]
        assert described["start"] == min(times) / 1e9
        assert described["end"] == max(times) / 1e9
        assert described["bytes"] == path.stat().st_size
        counts: dict[str, dict[str, int]] = {}
        for topic, _, _ in read_back:
            parts = topic.split("/")
            if parts[1].isdecimal():
                counts.setdefault(parts[1], {}).setdefault(parts[2], 0)
                counts[parts[1]][parts[2]] += 1
        assert described["nodes"] == counts
        assert described["marks"] == [{"time": p["time"], "text": p["text"],
                                       "fields": p.get("fields", {})}
                                      for t, _, p in read_back if t == MARK]
        assert described["damaged"] is False and described["indexed"] is True
        assert described["overlaps"] == [] and described["same_as"] == []
    table = gx2ctl("recordings", str(recordings))
    assert table.status == 0
    assert "mark 2026" in table.stdout and "node 11: accel_angrate 500" in table.stdout


def test_catalogue_reads_through_a_file_cut_short_and_says_repeats(tmp_path: Path,
                                                                    recordings: Path) -> None:
    cut = make_file(tmp_path / "gx2-cut.mcap", 60, 5, finish=False)
    first = sorted(recordings.iterdir())[0]
    ran = gx2ctl_here("recordings", "--json", str(first), str(cut), str(first))
    assert ran.status == 0, ran.stderr
    files = json.loads(ran.stdout)["files"]
    killed = next(f for f in files if f["path"] == str(cut))
    assert killed["indexed"] is False and killed["cut_short"] is True
    assert killed["nodes"]["11"]["accel_angrate"] == 5 * RATE
    assert killed["start"] == T0 + 60
    repeated = [f for f in files if f["path"] == str(first)]
    assert len(repeated) == 2 and all(f["same_as"] == [str(first)] for f in repeated)


# --- windows ----------------------------------------------------------------------------


@pytest.mark.parametrize("start, stop", [
    (iso(T0 + 15.5), iso(T0 + 27.25)),  # ISO 8601 across two files
    ("15.5", "27.25"),  # seconds from the recordings' start
])
def test_a_window_exports_exactly_the_messages_inside_it(recordings: Path, tmp_path: Path,
                                                         start: str, stop: str) -> None:
    out = tmp_path / "out"
    ran = gx2ctl_here("export", str(recordings), "--out", str(out), "--from", start, "--to", stop)
    assert ran.status == 0, ran.stderr
    inside = messages(sorted(recordings.iterdir()), T0 + 15.5, T0 + 27.25)
    for topic, table in [("gx2/11/accel_angrate", "11_accel_angrate"),
                         ("gx2/13/euler", "13_euler")]:
        assert column(out / f"{table}.csv", "host_time") == host_times(inside, topic)
    assert column(out / "marks.csv", "time") == [T0 + 25.0]


def test_a_window_between_marks_named_and_of_some_nodes(recordings: Path,
                                                         tmp_path: Path) -> None:
    out = tmp_path / "out"
    ran = gx2ctl_here("export", str(recordings), "--out", str(out), "--from", "stop",
                      "--to", "event", "--node", "12", "--record", "accel_angrate")
    assert ran.status == 0, ran.stderr
    inside = messages(sorted(recordings.iterdir()), T0 + 12.0, T0 + 50.5, holding_end=True)
    assert sorted(p.name for p in out.iterdir()) == ["12_accel_angrate.csv", "marks.csv"]
    assert column(out / "12_accel_angrate.csv", "host_time") == host_times(
        inside, "gx2/12/accel_angrate")
    # a window named by marks holds them: the first "stop" and the "event"
    assert column(out / "marks.csv", "time") == [T0 + 12.0, T0 + 25.0, T0 + 45.0, T0 + 50.5]


def test_trials_between_marks_each_in_their_folder(recordings: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    ran = gx2ctl_here("export", str(recordings), "--out", str(out), "--between-marks", "start",
                      "stop")
    assert ran.status == 0, ran.stderr
    folders = sorted(p.name for p in out.iterdir())
    assert folders == ["trial-1_2026-11-18T11-06-45Z", "trial-2_2026-11-18T11-07-05Z"]
    for folder, (start, stop) in zip(folders, [(5.0, 12.0), (25.0, 45.0)], strict=True):
        inside = messages(sorted(recordings.iterdir()), T0 + start, T0 + stop,
                          holding_end=True)
        assert column(out / folder / "11_accel_angrate.csv", "host_time") == host_times(
            inside, "gx2/11/accel_angrate")
        assert column(out / folder / "marks.csv", "time") == [T0 + start, T0 + stop]
    second = tmp_path / "second"
    ran = gx2ctl_here("export", str(recordings), "--out", str(second), "--between-marks",
                      "start", "stop", "--trial", "2")
    assert ran.status == 0, ran.stderr
    assert [p.name for p in second.iterdir()] == [folders[1]]


def test_a_middle_file_deleted_leaves_windows_of_exactly_what_is_left(recordings: Path,
                                                                       tmp_path: Path) -> None:
    # seconds 20 to 40 gone (deleted by hand, as a user tidying up would): the second
    # trial's start with them
    files = sorted(recordings.iterdir())
    files[1].unlink()
    left = [files[0], files[2]]
    listed = gx2ctl_here("recordings", "--json", str(recordings))
    assert [f["path"] for f in json.loads(listed.stdout)["files"]] == list(map(str, left))
    out = tmp_path / "out"
    ran = gx2ctl_here("export", str(recordings), "--out", str(out), "--from", "10", "--to", "50")
    assert ran.status == 0 and ran.stderr == "", ran.stderr
    inside = messages(left, T0 + 10, T0 + 50)
    assert column(out / "11_accel_angrate.csv", "host_time") == host_times(
        inside, "gx2/11/accel_angrate")
    assert len(host_times(inside, "gx2/11/accel_angrate")) == 20 * RATE
    assert column(out / "marks.csv", "time") == [T0 + 12.0, T0 + 45.0]
    trials = tmp_path / "trials"
    ran = gx2ctl_here("export", str(recordings), "--out", str(trials), "--between-marks",
                      "start", "stop")
    assert ran.status == 0, ran.stderr
    assert [p.name for p in trials.iterdir()] == ["trial-1_2026-11-18T11-06-45Z"]
    # a window inside the hole holds nothing: said in one line
    empty = gx2ctl_here("export", str(recordings), "--out", str(tmp_path / "none"), "--from",
                        "25", "--to", "35")
    assert empty.status == 2 and len(empty.stderr.strip().splitlines()) == 1, empty.stderr
    assert "in that window" in empty.stderr


def test_a_message_met_twice_is_exported_once(recordings: Path, tmp_path: Path) -> None:
    paths = sorted(recordings.iterdir())
    copy = tmp_path / "copy.mcap"
    shutil.copy(paths[1], copy)
    out = tmp_path / "out"
    ran = gx2ctl_here("export", str(paths[1]), str(paths[0]), str(copy), str(paths[1]),
                      "--out", str(out))
    assert ran.status == 0, ran.stderr
    once = messages(paths[:2])
    assert column(out / "11_accel_angrate.csv", "host_time") == host_times(
        once, "gx2/11/accel_angrate")
    again = messages([paths[1]])
    records = sum(topic.split("/")[1].isdecimal() for topic, _, _ in again)
    assert f"dropped {2 * len(again):,} duplicate messages, {2 * records:,} of them " \
        "records (rows)" in ran.stdout


@pytest.mark.parametrize("window, said", [
    (["--from", iso(T0 - 100), "--to", iso(T0 - 50)], "outside every file: the recordings "
     "span 2026-11-18T11:06:40.000Z to 2026-11-18T11:07:39.960Z"),
    (["--from", "nosuch"], "--from nosuch: no such mark (marks: 'start', 'stop', 'event')"),
    (["--from", "20", "--to", "10"], "is not after --from"),
    (["--from", "2026-11-18T11:06:50"], "give the time's zone"),
    (["--between-marks", "start", "nosuch"], "no trial from a mark 'start' to a mark "
     "'nosuch'"),
    (["--between-marks", "start", "stop", "--trial", "3"], "there are 2 trials"),
    (["--from", "1e300"], "--from 1e300: seconds from the recordings' start beyond"),
    (["--to=-1e300"], "--to -1e300: seconds from the recordings' start beyond"),
    # one bound alone, past the files: no blame on the bound not given
    (["--from", "1.7e10"], "the window 2565-08-03T17:20:00.000Z to (end) is outside every"),
    (["--to", "0001-01-01T00:00:00Z"], "the window (start) to 1-01-01T00:00:00.000Z is "
     "outside every file"),
])
def test_a_window_that_cannot_be_taken_is_one_line_and_exit_2(
        recordings: Path, tmp_path: Path, window: list[str], said: str) -> None:
    ran = gx2ctl_here("export", str(recordings), "--out", str(tmp_path / "out"), *window)
    assert ran.status == 2
    assert len(ran.stderr.splitlines()) == 1 and said in ran.stderr, ran.stderr
    assert not (tmp_path / "out").exists()


def test_a_damaged_file_inside_the_window_is_read_past(recordings: Path,
                                                        tmp_path: Path) -> None:
    path = sorted(recordings.iterdir())[1]
    data = bytearray(path.read_bytes())
    with path.open("rb") as stream:
        chunk = make_reader(stream).get_summary().chunk_indexes[5]  # second 25
    middle = chunk.chunk_start_offset + chunk.chunk_length // 2
    data[middle:middle + 64] = bytes(64)
    path.write_bytes(bytes(data))
    out = tmp_path / "out"
    ran = gx2ctl_here("export", str(recordings), "--out", str(out), "--from", "22", "--to", "28")
    assert ran.status == 1
    # what it held in the window, from its message indexes: its second's status, its
    # mark, 2 x 25 records and 5 of node 13
    assert "skipped 1 damaged chunk (57 messages" in ran.stderr, ran.stderr
    times = column(out / "11_accel_angrate.csv", "host_time")
    assert len(times) == 5 * RATE and not any(T0 + 25 <= t < T0 + 26 for t in times)


def test_plot_draws_a_window(recordings: Path, tmp_path: Path) -> None:
    out = tmp_path / "trial.png"
    ran = gx2ctl("plot", str(recordings), "11", "--between-marks", "start", "stop",
                 "--trial", "1", "--out", str(out))
    assert ran.status == 0, ran.stderr
    assert out.stat().st_size > 0
    several = gx2ctl("plot", str(recordings), "11", "--between-marks", "start", "stop",
                     "--out", str(out))
    assert several.status == 2 and "pick one with --trial" in several.stderr


# --- seeking ----------------------------------------------------------------------------


@pytest.mark.parametrize("finished", [True, False])
def test_a_window_read_decompresses_only_the_chunks_it_touches(tmp_path: Path,
                                                               finished: bool) -> None:
    path = make_file(tmp_path / "one.mcap", 0, 30, finish=finished)
    span = (round((T0 + 10.5) * 1e9), round((T0 + 12.5) * 1e9))
    reading = Reading()
    found = list(read(path, reading, span=span))
    assert [e.log_time for e in found] == [
        log_time for _, log_time, _ in messages([make_file(tmp_path / "whole.mcap", 0, 30)],
                                                T0 + 10.5, T0 + 12.5)]
    # seconds 10, 11 and 12 of 30; without a summary, also the chunks that define the
    # channels (second 0, and second 5 the mark's)
    assert reading.files[0].decompressed == (3 if finished else 5)
    assert not reading.partial


def test_a_file_cut_short_given_twice_is_exported_once(tmp_path: Path) -> None:
    cut = make_file(tmp_path / "gx2-cut.mcap", 0, 4, finish=False)
    copy = tmp_path / "copy.mcap"
    shutil.copy(cut, copy)
    whole = messages([make_file(tmp_path / "whole.mcap", 0, 4)])  # (the same messages)
    out = tmp_path / "out"
    ran = gx2ctl_here("export", str(cut), str(copy), "--out", str(out))
    assert ran.status == 0, ran.stderr
    assert column(out / "11_accel_angrate.csv", "host_time") == host_times(
        whole, "gx2/11/accel_angrate")
    assert f"dropped {len(whole):,} duplicate messages" in ran.stdout


def test_the_catalogue_lists_the_configured_record_directory(recordings: Path,
                                                             tmp_path: Path) -> None:
    config = tmp_path / "nodes.yaml"
    config.write_text("base_station: {port: 'sim://'}\nnodes: [{address: 11}]\n"
                      f"record: {{directory: '{recordings}'}}\n")
    ran = gx2ctl_here("--config", str(config), "recordings", "--json")
    assert ran.status == 0, ran.stderr
    assert [f["path"] for f in json.loads(ran.stdout)["files"]] == [
        str(p) for p in sorted(recordings.iterdir())]
    config.write_text("base_station: {port: 'sim://'}\nnodes: [{address: 11}]\n")
    ran = gx2ctl_here("--config", str(config), "recordings")
    assert ran.status == 2 and "does not record" in ran.stderr, ran.stderr


def test_json_before_the_command_is_json_too(recordings: Path) -> None:
    """``gx2ctl --json recordings``, as ``gx2ctl --json status`` is written."""
    before, after = (gx2ctl_here(*args) for args in (("--json", "recordings", str(recordings)),
                                                ("recordings", "--json", str(recordings))))
    assert before.status == after.status == 0, (before.stderr, after.stderr)
    assert json.loads(before.stdout) == json.loads(after.stdout)


def pdf_info(path: Path, key: str) -> str:
    """A PDF's document information ``key`` (matplotlib writes it as a literal string
    in UTF-16 with its byte order mark where it is not ASCII, ``( ) \\`` escaped)."""
    data = path.read_bytes()
    at = data.index(b"/" + key.encode() + b" (") + len(key) + 3
    text = bytearray()
    while data[at:at + 1] != b")":
        if data[at:at + 1] == b"\\":
            at += 1
            text += {b"n": b"\n", b"r": b"\r"}.get(data[at:at + 1], data[at:at + 1])
        else:
            text += data[at:at + 1]
        at += 1
    return bytes(text).decode("utf-16" if text[:2] == b"\xfe\xff" else "ascii")


@pytest.mark.parametrize("form", ["png", "pdf"])
def test_plot_of_a_trial_has_its_marks_and_only_its_losses(tmp_path: Path,
                                                           form: str) -> None:
    # node 11 at RATE Hz for 30 s; the radio lost samples at 3 s (3 of them) and at
    # 15 s (1); marks before, inside and after the trial from 10 s to 20 s
    marks = {5.0: "before", 10.0: "start", 15.2: "knock", 20.0: "stop", 25.0: "after"}
    lost = {3 * RATE, 3 * RATE + 1, 3 * RATE + 2, 15 * RATE}
    path = tmp_path / "gx2-20261125T000000.000Z.mcap"
    with path.open("wb") as output:
        writer = RecordingWriter(output)
        seq = 0
        for k in range(30 * RATE):
            at = T0 + k / RATE
            if k / RATE in marks:
                writer.message(MARK, {"time": at, "host_time": at, "nodes": [],
                                      "text": marks[k / RATE]})
            if k in lost:
                continue
            seq += 1
            writer.message("gx2/11/accel_angrate", {
                "node": 11, "record": "accel_angrate", "command": 0xC2, "seq": seq,
                "host_time": at, "time": at - 0.002, "device_time": k / RATE,
                "timer": k * 786_432, "lqi": 200, "rssi": -50, "accel": [0.0, 0.1, -1.0],
                "ang_rate": [0.1, 0.2, 0.3]})
        writer.finish()
    out = tmp_path / f"trial.{form}"
    ran = gx2ctl_here("plot", str(path), "11", "--between-marks", "start", "stop", "--out",
                      str(out))
    assert ran.status == 0, ran.stderr
    if form == "png":
        from PIL import Image
        assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        text = Image.open(out).text
        title, described = text["Title"], text["Description"]
    else:
        assert out.read_bytes()[:5] == b"%PDF-"
        title, described = pdf_info(out, "Title"), pdf_info(out, "Subject")
    # 10 s of samples (and the one with the stop mark), less the one the radio lost
    # in it; the three lost before it are not this window's
    # which trial it is, in its title too (issue 43: a folder of trials' plots could
    # not be told apart by their titles)
    assert title == (f"node 11: accel_angrate, {RATE:.1f} Hz, {10 * RATE:,} records · "
                     "trial 1 of 1: mark 'start' to mark 'stop', 2026-11-18 11:06:50.000 "
                     "to 11:07:00.000 UTC · "
                     f"radio: 1 lost ({1 / (10 * RATE + 1):.2%}) · gateway: 0 lost (0.00%)")
    assert described == "marks: start at 0.002 s, knock at 5.202 s, stop at 10.002 s"


def test_plot_to_another_format_is_one_line_and_exit_2(recordings: Path,
                                                       tmp_path: Path) -> None:
    ran = gx2ctl_here("plot", str(recordings), "11", "--out", str(tmp_path / "trial.svg"))
    assert ran.status == 2
    assert ran.stderr.strip() == (f"gx2ctl: --out {tmp_path / 'trial.svg'}: a plot is "
                                  "written as .png or .pdf (chosen by the name's ending)")
    assert not (tmp_path / "trial.svg").exists()


def test_plot_of_a_window_says_which_in_its_title(tmp_path: Path) -> None:
    """A window of --from and --to is said in the title, an open end as such."""
    from PIL import Image
    path = make_file(tmp_path / "gx2-a.mcap", 0, 10)
    for bounds, said in ((["--from", "2", "--to", "5"],
                          "window 2026-11-18 11:06:42.000 to 11:06:45.000 UTC"),
                         (["--from", "start"], "window 2026-11-18 11:06:45.000 UTC to the end")):
        out = tmp_path / "window.png"
        ran = gx2ctl_here("plot", str(path), "11", *bounds, "--out", str(out))
        assert ran.status == 0, ran.stderr
        assert Image.open(out).text["Title"].split(" · ")[1] == said
        out.unlink()
