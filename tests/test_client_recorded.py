"""gateway.client's Recording: recordings read back as the live subscriber's messages,
windows as gx2ctl's, checked against the mcap package's reader; the offline example of
docs/subscribing.md run as written (its loop the live example's); to_pandas."""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
from mcap.reader import make_reader

from gateway.client import Message, Recording, RecordingError, WindowError, to_pandas
from gateway.recording.columns import nanoseconds
from gateway.recording.writer import RecordingWriter
from tests.helpers.recorded import MARKS, T0, hourly_files

REPO = Path(__file__).resolve().parents[1]
DOC = REPO / "docs" / "subscribing.md"


@pytest.fixture
def recordings(tmp_path: Path) -> Path:
    return hourly_files(tmp_path)


def recorded(folder: Path, start: float, end: float) -> list[tuple[str, dict]]:
    """(topic, payload) of the messages the mcap package reads with log_time in
    [start, end] (UNIX s), in the order written."""
    found = []
    for path in sorted(folder.glob("*.mcap")):
        with path.open("rb") as stream:
            for _, channel, message in make_reader(stream).iter_messages(
                    starting_at=round(start * 1e9), ending_at=round(end * 1e9),
                    log_time_order=False):
                found.append((channel.topic, json.loads(message.data)))
    return found


def loop_body(block: str) -> str:
    return block[block.index("    for message in sub:"):]


def test_the_docs_offline_example_is_the_live_loop_and_reads_the_trial(recordings: Path
                                                                        ) -> None:
    blocks = re.findall(r"```python\n(.*?)```", DOC.read_text(), re.DOTALL)
    live, offline = blocks[0], blocks[1]
    assert "Subscriber(" in live and "Recording(" in offline
    assert loop_body(offline) == loop_body(live)  # the same loop, word for word
    code = offline.replace('"/var/lib/gx2-gateway/recordings"', repr(str(recordings)))
    code = code.replace("nodes=[76, 77]", "nodes=[11, 12]")
    ran = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=60, cwd=REPO)
    assert ran.returncode == 0, ran.stderr
    (start, _), (stop, _) = MARKS[0], MARKS[1]  # the first trial
    expected = [f"{p['node']} {p['time']} {p['accel'][0]} {p['accel'][1]} {p['accel'][2]}"
                for topic, p in recorded(recordings, T0 + start, T0 + stop)
                if topic in ("gx2/11/accel_angrate", "gx2/12/accel_angrate")]
    assert len(expected) == 2 * (7 * 25 + 1)  # (the records logged with the stop mark held)
    assert ran.stdout.splitlines() == expected


def write(path: Path, payloads: list[dict]) -> Path:
    with path.open("wb") as output:
        writer = RecordingWriter(output)
        for payload in payloads:
            writer.message(f"gx2/{payload['node']}/{payload['record']}", payload)
        writer.finish()
    return path


def payload(at: int, seq: int, record: str = "accel_angrate_mag") -> dict:
    return {"node": 76, "record": record, "command": 0xC7, "seq": seq,
            "host_time": T0 + at / 100, "time": T0 + at / 100 - 0.002,
            "device_time": at / 100, "lqi": 200, "rssi": -50, "accel": [0.0, 0.1, -1.0],
            "ang_rate": [0.1, 0.2, 0.3], "mag": [math.nan] * 3, "timer": seq * 1966}


def test_messages_carry_gaps_restarts_and_nan_as_a_live_subscriber_gives_them(
        tmp_path: Path) -> None:
    # a poll took seq 3; 6 and 7 were lost; then the gateway restarted
    seqs = [1, 2, 3, 4, 5, 8, 9, 2, 3]
    payloads = [payload(i + 1, seq, "temperatures" if seq == 3 and i == 2 else
                        "accel_angrate_mag") for i, seq in enumerate(seqs)]
    path = write(tmp_path / "run.mcap", payloads)
    with Recording(path, records=["accel_angrate_mag"]) as sub:
        got = list(sub)
    assert all(isinstance(m, Message) for m in got)
    assert [m.seq for m in got] == [1, 2, 4, 5, 8, 9, 2, 3]
    # the temperatures record took seq 3: filtered out, it is no gap
    assert [m.gap for m in got] == [0, 0, 0, 0, 2, 0, 0, 0]
    assert [m.restarted for m in got] == [False] * 6 + [True, False]
    assert sub.lost == {(str(path), 76): 2}
    first = got[0]
    assert first.gateway == str(path) and first.node == 76
    assert first.host_time == T0 + 0.01 and first.device_time == 0.01 and first.rssi == -50
    assert first["accel"] == [0.0, 0.1, -1.0]
    assert all(math.isnan(v) for v in first["mag"])  # null in the file, NaN as published
    assert json.loads(first.json()) == payloads[0] | {"mag": [None] * 3}


def test_each_trial_is_counted_afresh_and_read_once(recordings: Path) -> None:
    sub = Recording([recordings, recordings], nodes=[11], between_marks=("start", "stop"))
    got = list(sub)
    assert [w.label for w in sub.windows] == ["trial-1_2026-11-18T11-06-45Z",
                                              "trial-2_2026-11-18T11-07-05Z"]
    # the seconds between the trials are not a gap; the second copy of each file is
    # not read twice
    assert all(m.gap == 0 for m in got) and sub.lost == {}
    assert sub.duplicates > 0
    expected = [p["host_time"] for (begin, _), (end, _) in (MARKS[0:2], MARKS[2:4])
                for topic, p in recorded(recordings, T0 + begin, T0 + end)
                if topic == "gx2/11/accel_angrate"]
    assert [m.host_time for m in got] == expected
    second = sub.trials()[1]
    assert [m.host_time for m in second] == [t for t in expected if t >= T0 + 25]
    assert [m.text for m in second.marks()] == ["start", "stop"]


def test_to_pandas_gives_export_columns_and_utc_times(recordings: Path) -> None:
    sub = Recording(recordings, nodes=[11], start="10", stop="12")
    frame = sub.to_pandas()
    expected = [p for topic, p in recorded(recordings, T0 + 10, T0 + 12)
                if topic == "gx2/11/accel_angrate" and p["host_time"] < T0 + 12]
    assert len(frame) == len(expected) == 50
    assert str(frame["time"].dtype) == "datetime64[ns, UTC]"
    assert str(frame["device_time"].dtype) == "timedelta64[ns]"
    assert list(frame.columns[-7:]) == ["accel_x", "accel_y", "accel_z", "ang_rate_x",
                                        "ang_rate_y", "ang_rate_z", "timer"]
    first = frame.iloc[0]
    assert first["host_time"].value == round(expected[0]["host_time"] * 1e9)
    assert first["accel_z"] == -1.0 and first["seq"] == expected[0]["seq"]
    # a live subscriber's messages make the same frame
    assert to_pandas(list(sub)).equals(frame)


def said_without(module: str, recordings: Path, method: str) -> str:
    """What ``Recording(recordings).method()`` says, in a Python without ``module``."""
    code = (f"import sys; sys.modules[{module!r}] = None\n"
            "from gateway.client import Recording, MissingExtra\n"
            f"try:\n    Recording({str(recordings)!r}).{method}()\n"
            "except MissingExtra as e:\n    print(e)\n")
    ran = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=60, check=True)
    return ran.stdout


def test_to_pandas_without_pandas_says_how_to_install_it(recordings: Path) -> None:
    assert said_without("pandas", recordings, "to_pandas") == \
        "to_pandas needs pandas: pip install 'gx2-gateway[pandas]'\n"


def test_paths_and_windows_that_cannot_be_read_say_why_in_a_line(recordings: Path,
                                                                  tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    with pytest.raises(RecordingError, match=r"no \.mcap files in this directory"):
        Recording(tmp_path / "empty")
    with pytest.raises(WindowError, match=r"--from knock: no such mark \(marks: 'start', "
                                          r"'stop', 'event'\)"):
        Recording(recordings, start="knock")


def test_a_file_of_before_the_matrixs_derived_fields_gives_them_and_its_nan(
        tmp_path: Path) -> None:
    """A file written before records with a matrix carried roll, pitch, yaw and the
    quaternion, one of its matrices NaN (null in the file): each record as the gateway
    publishes it now (gateway.common.payloads), the derived fields derived, NaN from
    the NaN matrix, and the file's nulls NaN."""
    turned = [[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]  # yaw of 90 degrees
    old = [{"node": 76, "record": "orientation", "command": 0xC5, "seq": seq,
            "host_time": T0 + seq / 100, "time": T0 + seq / 100 - 0.002,
            "device_time": seq / 100, "lqi": 200, "rssi": -50, "timer": seq * 1966,
            "orientation": [[math.nan] * 3] * 3 if seq == 2 else turned}
           for seq in range(1, 4)]
    path = write(tmp_path / "old.mcap", old)
    got = list(Recording(path))
    assert [m.seq for m in got] == [1, 2, 3]
    assert got[0]["yaw"] == pytest.approx(math.pi / 2) and got[0]["roll"] == 0.0
    assert got[0]["quaternion"] == pytest.approx([math.sqrt(0.5), 0, 0, math.sqrt(0.5)])
    nan = got[1]
    assert all(math.isnan(v) for v in (nan["roll"], nan["pitch"], nan["yaw"],
                                       *nan["quaternion"], *nan["orientation"][0]))
    assert got[0].time == T0 + 0.01 - 0.002  # (the bookkeeping as it was)


def test_to_pandas_times_are_exact_beside_an_untimed_reply(tmp_path: Path) -> None:
    """An untimed reply on a node's topic (eeprom_read: no ``time``) among timed
    records: every timed row's ``time`` is the nanoseconds its message wrote, exactly,
    and the untimed one's NaT (a column of nanoseconds with a None in it went through
    float64: off by up to 128 ns)."""
    euler = [{"node": 76, "record": "euler", "command": 0xCE, "seq": seq,
              "host_time": T0 + seq / 100 + 0.004, "time": T0 + seq / 100 + 0.000123457,
              "device_time": seq / 100 + 1e-9, "lqi": 200, "rssi": -50, "roll": 0.1,
              "pitch": 0.2, "yaw": 0.3, "timer": seq * 1966} for seq in range(1, 101)]
    reply = {"node": 76, "record": "eeprom_read", "command": 0xE5, "seq": 101,
             "host_time": T0 + 1.5, "lqi": 200, "rssi": -50, "address": 0xFCA2,
             "value": 512}
    frame = Recording(write(tmp_path / "run.mcap", [*euler[:50], reply, *euler[50:]]
                            )).to_pandas()
    timed = frame[frame["record"] == "euler"]
    assert [t.value for t in timed["time"]] == [nanoseconds(p["time"]) for p in euler]
    assert [t.value for t in timed["host_time"]] == [nanoseconds(p["host_time"])
                                                     for p in euler]
    assert [d.value for d in timed["device_time"]] == [nanoseconds(p["device_time"])
                                                       for p in euler]
    (untimed,) = frame[frame["record"] == "eeprom_read"].itertuples()
    assert untimed.time is pd.NaT and untimed.device_time is pd.NaT
    assert untimed.host_time.value == nanoseconds(reply["host_time"])


def test_to_pandas_gives_nat_for_a_time_no_timestamp_holds(tmp_path: Path) -> None:
    """A record whose device_time (1e10 s) or time is past 2262 in nanoseconds (another
    writer's file): NaT there, the rest of the frame as written (an OverflowError
    before)."""
    euler = [{"node": 76, "record": "euler", "command": 0xCE, "seq": seq,
              "host_time": T0 + seq / 100, "time": T0 + seq / 100,
              "device_time": seq / 100, "lqi": 200, "rssi": -50, "roll": 0.1,
              "pitch": 0.2, "yaw": 0.3, "timer": seq * 1966} for seq in range(1, 4)]
    euler[1] = {**euler[1], "device_time": 1e10, "time": 1e10}
    frame = Recording(write(tmp_path / "run.mcap", euler)).to_pandas()
    assert frame["device_time"].isna().tolist() == [False, True, False]
    assert frame["time"].isna().tolist() == [False, True, False]
    assert [t.value for t in frame["host_time"]] == [nanoseconds(p["host_time"])
                                                     for p in euler]


def test_records_the_recordings_do_not_hold_are_refused_as_nodes_are(tmp_path: Path
                                                                    ) -> None:
    path = write(tmp_path / "run.mcap", [payload(1, 1), payload(2, 2)])
    holds = r"\(they hold node 76: accel_angrate_mag\)"
    with pytest.raises(WindowError, match=rf"^--node 99: not in the recordings {holds}$"):
        Recording(path, nodes=[99])
    with pytest.raises(WindowError, match=rf"^--record eulr: not in the recordings {holds}$"):
        Recording(path, records=["eulr"])
    assert len(list(Recording(path, records=["accel_angrate_mag"]))) == 2
