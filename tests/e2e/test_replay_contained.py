"""One output's trouble with a message stays its own: a replayed message msgpack cannot
pack (an int over 64 bits) is refused by ZeroMQ alone, counted and logged once; the live
view still shows it (its ``time``, no float, taken as absent) and everything after it;
and the replay plays on to its end and exits as asked, a matrix no float holds
included."""

from __future__ import annotations

import json
from pathlib import Path

from mcap.reader import make_reader

from aspp.orientation import matrix_from_euler
from gateway.recording.writer import RecordingWriter
from tests.helpers.ports import free_port
from tests.helpers.viewer import Viewer
from tests.helpers.waiting import wait_for

TOPIC = "gx2/76/accel_angrate"
NODES = [{"address": 76, "stream": "accel_angrate"}]
HUGE = 10**400
"""A JSON number no float holds and msgpack cannot pack."""


def recording(path: Path, count: int, huge: set[int]) -> None:
    """``count`` published records at 100 Hz; those at ``huge`` with a ``time`` of HUGE
    (as a foreign program may have written them)."""
    with path.open("wb") as output:
        writer = RecordingWriter(output, {})
        for seq in range(count):
            at = 1.7e9 + seq / 100
            payload = {"node": 76, "record": "accel_angrate", "seq": seq,
                       "host_time": at, "time": at}
            data = json.dumps({**payload, "time": HUGE}).encode() if seq in huge else None
            writer.message(TOPIC, payload, data)
        writer.finish()


def test_a_message_zeromq_cannot_pack_is_refused_alone_counted_and_logged_once(
        gateway, tmp_path):
    path = tmp_path / "huge.mcap"
    recording(path, 300, {100, 200})
    gw = gateway(f"replay://{path}?speed=0&delay=1", NODES)
    sub = gw.subscribe(TOPIC)  # (its recv takes exactly two frames: topic, payload)
    sub.until(lambda got: any(p["seq"] == 299 for _, p in got), 10, "the last record")
    assert [p["seq"] for p in sub.records(76)] == [s for s in range(300) if s not in (100, 200)]
    assert gw.status()["gateway"]["publish_failures"] == 2
    assert gw.log().count("msgpack cannot pack") == 1, gw.log()
    assert "Traceback" not in gw.log(), gw.log()


def test_a_message_zeromq_refuses_is_still_shown_live_and_the_replay_ends(
        gateway, tmp_path):
    """Its ``time`` no float holds is taken as absent (the message is shown at the
    instant it was read, as any message without a time), not a failure of the live
    view: the viewer sees it and every record after it, ZeroMQ refuses it alone, and the
    replay plays on to its end."""
    path = tmp_path / "huge.mcap"
    recording(path, 300, {200})
    gw = gateway(f"replay://{path}?speed=1&delay=1&exit=true", NODES,
                 live={"endpoint": f"127.0.0.1:{free_port()}"})
    sub = gw.subscribe(TOPIC)
    viewer = Viewer(f"ws://{gw.config['live']['endpoint']}")
    try:
        viewer.until(lambda v: TOPIC in v.topics(), 5, "the channel advertised")
        viewer.subscribe(viewer.topics()[TOPIC])
        viewer.until(lambda v: v.messages, 5, "a record in the live view")
        assert viewer.messages[0].payload["seq"] < 200  # (it watched the huge one come)
        # (not the last: the gateway exits with it, and its viewers' connections end)
        viewer.until(lambda v: any(m.payload["seq"] == 250 for m in v.messages), 10,
                     "records after the huge one in the live view")
    finally:
        viewer.close()
    shown = {m.payload["seq"]: m for m in viewer.messages}
    first = viewer.messages[0].payload["seq"]
    assert sorted(shown)[:251 - first] == list(range(first, 251))  # (200 too)
    assert shown[200].payload["time"] == HUGE
    assert shown[200].log_time == round((1.7e9 + 2.0) * 1e9)  # (its host_time)
    wait_for(lambda: (sub.drain(0.05), gw.proc.poll())[1] is not None, 10,
             "the replay to end (exit=true)")
    sub.drain_until_quiet()
    assert gw.proc.returncode == 0, gw.log()
    assert [p["seq"] for p in sub.records(76)] == [s for s in range(300) if s != 200]
    log = gw.log()
    assert "output live failed" not in log and "Traceback" not in log, log
    assert log.count("msgpack cannot pack") == 1, log  # (ZeroMQ was given it too)


def test_a_matrix_no_float_holds_is_replayed_as_read_and_the_replay_ends(
        gateway, tmp_path):
    """A foreign file's orientation record whose matrix holds 10**400 (no float holds
    it: deriving its angles raised OverflowError outside any guard, and the replay
    stopped there for good): every record is published, that one as it was read
    without derived fields, the others with them, and the replay exits 0."""
    topic = "gx2/77/orientation"
    path = tmp_path / "bigint.mcap"
    with path.open("wb") as output:
        writer = RecordingWriter(output)
        for seq in range(1, 301):
            at = 1.7e9 + seq / 100
            matrix = [list(row) for row in matrix_from_euler(0.2, -0.1, seq / 100)]
            if seq == 100:
                matrix = [[HUGE, 0, 0], [0, 1, 0], [0, 0, 1]]
            writer.message(topic, {"orientation": matrix, "node": 77,
                                   "record": "orientation", "seq": seq,
                                   "host_time": at, "time": at})
        writer.finish()
    recordings = tmp_path / "recordings"
    gw = gateway(f"replay://{path}?speed=0&delay=0.5&exit=true", [{"address": 77}],
                 record={"directory": str(recordings)})
    wait_for(lambda: gw.proc.poll() is not None, 20, "the replay to end (exit=true)")
    assert gw.proc.returncode == 0, gw.log()
    assert "Traceback" not in gw.log() and "OverflowError" not in gw.log(), gw.log()
    (kept,) = recordings.glob("*.mcap")
    with kept.open("rb") as stream:
        got = {json.loads(message.data)["seq"]: json.loads(message.data)
               for _, channel, message in make_reader(stream).iter_messages()
               if channel.topic == topic}
    assert sorted(got) == list(range(1, 301))
    assert got[100]["orientation"][0][0] == HUGE and "roll" not in got[100], got[100]
    assert all("roll" in got[seq] for seq in got if seq != 100)
