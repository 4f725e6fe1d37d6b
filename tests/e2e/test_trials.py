"""``gx2ctl mark --field`` and ``gx2ctl trials`` through the real gateway on the
simulator: the fields recorded with the mark (read back by the ``mcap`` package), and
every trial listed from the file still being written, the open one last, its rows
counted as the ``mcap`` package counts them (issue 44)."""

from __future__ import annotations

import json
from pathlib import Path

from mcap.reader import make_reader

from gateway.sim.node import NodeSettings
from tests.helpers.processes import Ran, gx2ctl
from tests.helpers.waiting import wait_for

NODES = [{"address": 76, "stream": "accel_angrate"}]


def _messages(path: Path) -> list[tuple[str, int, bytes]]:
    """(topic, log_time, data) of a file, by the ``mcap`` package (never our reader)."""
    with path.open("rb") as stream:
        return [(channel.topic, message.log_time, message.data)
                for _, channel, message in make_reader(stream).iter_messages(
                    log_time_order=False)]


def test_marks_carry_fields_and_trials_are_listed(simulator, gateway, tmp_path):
    sim = simulator(NodeSettings(76))
    directory = tmp_path / "recordings"
    gw = gateway(sim.path, NODES, record={"directory": str(directory),
                                          "rotate_minutes": 60})
    gw.wait_streaming(76)
    samples = gw.subscribe("gx2/76/")
    control = ("--control", gw.control_endpoint)

    def mark(*words: str) -> dict:
        made = gx2ctl(*control, "--json", "mark", *words)
        assert made.status == 0, made
        samples.until(lambda m: m and m[-1][1]["time"] > json.loads(made.stdout)["time"]
                      + 0.2, 10, "records after the mark")
        return json.loads(made.stdout)

    first = mark("start", "--field", "subject=S01", "--field", "condition=fast")
    assert first["fields"] == {"subject": "S01", "condition": "fast"}
    shown = gx2ctl(*control, "mark", "note", "--field", "who=A B")
    assert shown.status == 0 and shown.stdout.endswith("note  who=A B\n"), shown
    mark("stop")
    mark("start", "--field", "subject=S02")
    # a field that is not KEY=VALUE is the user's mistake: one line, exit 2, nothing made
    wrong = gx2ctl(*control, "mark", "start", "--field", "subject")
    assert wrong.status == 2 and len(wrong.stderr.splitlines()) == 1, wrong
    assert "KEY=VALUE" in wrong.stderr and "Traceback" not in wrong.stderr, wrong
    # a key given twice: the last would have won unseen
    twice = gx2ctl(*control, "mark", "start", "--field", "subject=S1", "--field", "subject=S2")
    assert twice.status != 0 and len(twice.stderr.splitlines()) == 1, twice
    assert "subject given more than once" in twice.stderr, twice

    # listed from the file the gateway is writing, once the open trial's rows are on
    # the disk (a mark's chunk is flushed as the mark is taken, the rows after it with
    # the next second's flush); then read back whole when it is done
    def listing() -> Ran | None:
        ran = gx2ctl("trials", "--json", str(directory))
        assert ran.status == 0, ran
        return ran if json.loads(ran.stdout)["trials"][-1]["nodes"] else None

    listed = wait_for(listing, 10, "the open trial's rows on the disk")
    table = gx2ctl("trials", str(directory))
    later = gx2ctl("trials", "--json", str(directory), "--from", "stop")
    catalogued = json.loads(gx2ctl("recordings", "--json", str(directory)).stdout)
    assert gw.terminate()[0] == 0, gw.log()
    one, two = json.loads(listed.stdout)["trials"]
    [recording] = directory.glob("*.mcap")
    messages = _messages(recording)
    marks = [(at, json.loads(data)) for topic, at, data in messages
             if topic == "gx2/gateway/mark"]
    assert [p["fields"] for _, p in marks] == [
        {"subject": "S01", "condition": "fast"}, {"who": "A B"}, {}, {"subject": "S02"}]
    (start, _), (stop, _) = marks[0], marks[2]
    rows = sum(1 for topic, at, _ in messages
               if topic == "gx2/76/accel_angrate" and start <= at <= stop)
    assert rows > 10
    assert one == {"trial": 1, "start": start / 1e9, "stop": stop / 1e9,
                   "start_mark": "start", "stop_mark": "stop",
                   "fields": {"subject": "S01", "condition": "fast"},
                   "nodes": {"76": {"accel_angrate": rows}}, "files": [str(recording)]}
    assert (two["trial"], two["stop"], two["stop_mark"], two["fields"]) == (
        2, None, None, {"subject": "S02"})
    assert two["nodes"]["76"]["accel_angrate"] > 0
    assert table.status == 0 and "subject=S01  condition=fast" in table.stdout, table
    assert "(open: no mark yet)" in table.stdout, table
    # --from after the first trial leaves the second alone
    assert [t["trial"] for t in json.loads(later.stdout)["trials"]] == [2], later
    assert catalogued["files"][0]["marks"][0]["fields"] == first["fields"]


def test_trials_of_no_recording_is_one_line(tmp_path):
    ran = gx2ctl("trials", str(tmp_path / "nothing"))
    assert ran.status == 2 and len(ran.stderr.splitlines()) == 1, ran
    assert "Traceback" not in ran.stderr
