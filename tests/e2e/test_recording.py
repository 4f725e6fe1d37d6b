"""Recording and replay through the real gateway, the simulator behind a pty, and the
files read back by the ``mcap`` package's own reader (never our writer's code)."""

from __future__ import annotations

import json
import math
import re
import resource
import subprocess
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml
from mcap.reader import NonSeekingReader, make_reader

from gateway.common.jsontext import strict
from gateway.common.topics import parse
from gateway.recording.reader import read
from gateway.recording.reports import Reading
from gateway.sim.node import NodeSettings
from tests.helpers.gateway import gateway_config
from tests.helpers.ports import free_port
from tests.helpers.processes import Running, gx2ctl, script, spawn_run
from tests.helpers.waiting import wait_for

NODES = [{"address": 76, "stream": "accel_angrate"}, {"address": 77, "stream": "euler"}]


def tap(sim) -> tuple[bytearray, bytearray]:
    """Every byte the simulated base station writes to the host, and reads from it."""
    sent, received = bytearray(), bytearray()
    write, read = sim.port.write, sim.port.read

    def tapped_write(data: bytes) -> int:
        written = write(data)
        sent.extend(data[:written])
        return written

    def tapped_read() -> tuple[bytes, bool]:
        data, alive = read()
        received.extend(data)
        return data, alive
    sim.port.write, sim.port.read = tapped_write, tapped_read
    return sent, received


def messages(path: Path) -> list[tuple[str, Any, Any]]:
    """(topic, message, channel) of a finished file, in log time order."""
    with path.open("rb") as stream:
        reader = make_reader(stream)
        assert reader.get_summary() is not None, f"{path} was not finished"
        return [(channel.topic, message, channel)
                for _, channel, message in reader.iter_messages()]


def recorded(directory: Path) -> list[tuple[str, Any, Any]]:
    found = []
    for path in sorted(directory.glob("*.mcap")):
        found.extend(messages(path))
    return found


def payloads(entries: list[tuple[str, Any, Any]]) -> dict[tuple[int, int], tuple[str, dict]]:
    """(node, seq) -> (topic, payload) of every node record."""
    return {(p["node"], p["seq"]): (topic, p) for topic, p, _ in node_records(entries)}


def node_records(entries: list[tuple[str, Any, Any]]) -> list[tuple[str, dict, Any]]:
    """(topic, payload, message) of every node record (a node's frame is none)."""
    return [(topic, json.loads(message.data), message) for topic, message, _ in entries
            if parse(topic) is not None]


def record_simulator(simulator, gateway, directory: Path, seconds: float, **record: Any):
    sim = simulator(NodeSettings(76), NodeSettings(77))
    sent, received = tap(sim)
    gw = gateway(sim.path, NODES, record={"directory": str(directory), **record})
    sub = gw.subscribe("gx2/")
    gw.wait_streaming(76, 77)
    assert gw.control.result("poll", node=76, record="euler")["record"] == "euler"
    sub.drain(seconds)
    status, _ = gw.terminate()
    assert status == 0, gw.log()
    # what the base station sent while the gateway ran: the simulator goes on writing
    # into the pty's buffer after it (for as long as the test takes to read the files)
    sent_while_running = bytes(sent)
    sub.drain(0.2)
    return sim, sent_while_running, received, gw, sub


def test_a_recording_holds_the_lines_bytes_both_ways_and_every_published_record(
        simulator, gateway, tmp_path):
    directory = tmp_path / "recordings"
    _, sent, received, gw, sub = record_simulator(simulator, gateway, directory, 3.0)
    entries = recorded(directory)
    serial = b"".join(m.data for t, m, _ in entries if t == "serial")
    written = b"".join(m.data for t, m, _ in entries if t == "serial/written")
    # the reads are exactly the bytes the base station sent, in order, until the
    # gateway stopped reading
    assert len(serial) > 20_000 and bytes(sent).startswith(serial)
    assert len(sent) - len(serial) < 2_000
    assert written == bytes(received), "the writes are not what reached the base station"
    times = [m.log_time for t, m, _ in entries if t == "serial"]
    assert times == sorted(times) and abs(times[-1] / 1e9 - time.time()) < 30
    channels = {t: c for t, _, c in entries}
    assert channels["serial"].message_encoding != "json"
    assert channels["gx2/76/accel_angrate"].message_encoding == "json"
    assert "gx2/gateway/status" in channels and "gx2/76/euler" in channels  # the poll
    # every record the live subscriber got is in the file, identical (NaN as null),
    # log_time its host_time and publish_time its time
    in_file = payloads(entries)
    live = [(t, p) for t, p in sub.messages if t.split("/")[1].isdecimal()]
    assert len(live) > 400
    for topic, payload in live:
        assert in_file[payload["node"], payload["seq"]] == (topic, strict(payload))
    for _, payload, message in node_records(entries):
        assert message.log_time == round(payload["host_time"] * 1e9)
        if "time" in payload:
            assert message.publish_time == round(payload["time"] * 1e9)
    assert gw.log().count("recording to") == 1


def test_replay_publishes_what_was_published_live_and_sends_nothing(
        simulator, gateway, tmp_path):
    directory = tmp_path / "recordings"
    record_simulator(simulator, gateway, directory, 3.0)
    live = {key: payload for key, (_, payload) in payloads(recorded(directory)).items()}
    replay = gateway(f"replay://{directory}?speed=0&exit=true&delay=3", NODES)
    sub = replay.subscribe("gx2/")
    # before it plays: a control op that would talk to a node is refused (exit 1)
    pinged = gx2ctl("--control", replay.control_endpoint, "ping", "76")
    assert pinged.status == 1 and "replaying a recording" in pinged.stderr, pinged
    assert replay.status()["replay"]["reads"] == 0
    wait_for(lambda: replay.proc.poll() is not None, 30, "the replay to end (exit=true)")
    assert replay.proc.returncode == 0, replay.log()
    sub.drain_until_quiet()
    played = {(p["node"], p["seq"]): strict(p) for t, p in sub.messages
              if t.split("/")[1].isdecimal()}
    assert played.keys() == live.keys()
    for key, payload in live.items():
        again = played[key]
        assert again.keys() == payload.keys()
        for name, value in payload.items():
            if name in ("host_time", "time"):
                assert math.isclose(again[name], value, abs_tol=1e-6), (key, name)
            else:
                assert again[name] == value, (key, name)


def test_a_gateway_killed_while_recording_leaves_a_file_readable_to_its_last_second(
        simulator, gateway, tmp_path):
    directory = tmp_path / "recordings"
    sim = simulator(NodeSettings(76))
    gw = gateway(sim.path, NODES[:1], record={"directory": str(directory)})
    gw.wait_streaming(76)
    time.sleep(3.0)  # (the run to be cut short: not a synchronisation)
    killed_at = time.time()
    gw.proc.kill()
    gw.proc.wait()
    [path] = directory.glob("*.mcap")
    last = 0
    count = 0
    with path.open("rb") as stream:
        try:
            for _, channel, message in NonSeekingReader(stream).iter_messages(
                    log_time_order=False):
                if channel.topic == "serial":
                    last = max(last, message.log_time)
                    count += 1
        except Exception:  # the unfinished tail: what comes before it is what counts
            pass
    assert count > 100
    # a chunk a second, written by a thread that wakes every 0.1 s: 1.1 s at most, and
    # some room for a loaded CI machine's scheduler
    assert killed_at - last / 1e9 < 2.0, f"lost {killed_at - last / 1e9:.2f} s"


def test_files_rotate_by_size_each_finished_and_in_time_order(simulator, gateway, tmp_path):
    directory = tmp_path / "recordings"
    _, sent, *_ = record_simulator(simulator, gateway, directory, 4.0, rotate_mb=0.01)
    paths = sorted(directory.glob("*.mcap"))
    assert len(paths) >= 3, paths
    firsts, serial = [], b""
    for path in paths:
        entries = messages(path)  # finished: it has a summary
        firsts.append(entries[0][1].log_time)
        serial += b"".join(m.data for t, m, _ in entries if t == "serial")
    assert firsts == sorted(firsts), "file names do not sort in time order"
    assert bytes(sent).startswith(serial), "bytes lost or repeated between files"
    assert len(sent) - len(serial) < 2_000


def test_a_disk_that_refuses_writes_is_counted_and_publishing_goes_on(
        simulator, gateway, tmp_path):
    # files may not grow past 64 kB (RLIMIT_FSIZE: writes past it fail with EFBIG, as
    # on a full disk; Python ignores the SIGXFSZ that comes with them)
    def limit_files() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (64_000, 64_000))
    sim = simulator(NodeSettings(76, divider=256), NodeSettings(77, divider=256))
    directory = tmp_path / "recordings"
    gw = gateway(sim.path, NODES, record={"directory": str(directory)}, preexec=limit_files)
    gw.wait_streaming(76, 77)
    wait_for(lambda: gw.status()["recording"]["errors"] > 0, 30, "the disk to refuse")
    dropped = gw.status()["recording"]["dropped"]
    sub = gw.subscribe("gx2/76/")
    sub.until(lambda m: len(m) > 100, 10, "records published after the disk failed")
    recording = gw.status()["recording"]
    assert recording["dropped"] > dropped > 0 and recording["error"]
    assert "recording to" in gw.log() and "failed" in gw.log()
    status, _ = gw.terminate()
    assert status == 0


def test_gx2ctl_record_writes_the_published_stream_of_the_nodes_asked(
        simulator, gateway, tmp_path):
    sim = simulator(NodeSettings(76), NodeSettings(77))
    gw = gateway(sim.path, NODES)
    gw.wait_streaming(76, 77)
    target = tmp_path / "capture.mcap"
    run = Running("gx2ctl", "--control", gw.control_endpoint, "record", str(target), "76",
                  "--seconds", "2")
    assert run.finish(15) == 0, run.stderr
    assert "records" in run.stderr[-1] and "radio: " in run.stderr[-1]
    topics = {t for t, _, _ in messages(target)}
    assert topics == {"gx2/76/accel_angrate", "gx2/gateway/status"}
    count = sum(t == "gx2/76/accel_angrate" for t, _, _ in messages(target))
    assert 100 < count < 260  # 2 s at 100 Hz, less the subscription's first moments
    again = gx2ctl("--control", gw.control_endpoint, "record", str(target), "--seconds", "1")
    assert again.status == 2 and "exists" in again.stderr


def test_replay_urls_that_cannot_play_are_refused_in_one_line(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    (tmp_path / "notes.mcap").write_text("not a recording")
    good = tmp_path / "x.mcap"
    good.write_bytes(b"\x89MCAP0\r\n")
    for url, words in ((f"replay://{tmp_path}/missing.mcap", "no such file"),
                       (f"replay://{empty}", "no .mcap files"),
                       (f"replay://{tmp_path}/notes.mcap", "not an MCAP file"),
                       (f"replay://{good}?speed=fast", "speed"),
                       (f"replay://{good}?pace=2", "unknown option")):
        config = tmp_path / "nodes.yaml"
        config.write_text(f"base_station: {{port: '{url}'}}\nnodes: [{{address: 76}}]\n")
        ran = subprocess.run([script("gx2-gateway"), "--config", str(config), "--check"],
                             capture_output=True, text=True, timeout=30)
        assert ran.returncode == 2, (url, ran)
        assert words in ran.stderr and len(ran.stderr.strip().splitlines()) == 1, ran.stderr


def test_gx2ctl_record_with_no_gateway_exits_1_and_leaves_no_file(tmp_path):
    config = tmp_path / "nodes.yaml"
    config.write_text(yaml.safe_dump(gateway_config("sim://", NODES,
                                                    publish={"heartbeat_s": 0.1})))
    target = tmp_path / "capture.mcap"
    ran = gx2ctl("--config", str(config), "--timeout", "0.5", "record", str(target),
                 "--seconds", "2")
    assert ran.status == 1, ran
    [line] = ran.stderr.splitlines()
    assert "not even its heartbeat" in line and "nothing recorded" in line, line
    assert not target.exists()


def test_gx2ctl_record_refuses_a_file_not_named_mcap_in_one_line(tmp_path):
    """Asked before any gateway is: nothing listens on the endpoint."""
    for name, suggested in (("x.csv", "x.mcap"), ("run", "run.mcap")):
        target = tmp_path / name
        ran = gx2ctl("--control", f"tcp://127.0.0.1:{free_port()}", "record", str(target))
        assert ran.status == 2, ran
        assert ran.stderr.splitlines() == [
            f"gx2ctl: {target}: gx2ctl record writes MCAP: name the file {suggested}"]
        assert not target.exists()


def limited_to(size: int) -> Callable[[], None]:
    """A preexec: files may not grow past ``size`` bytes (RLIMIT_FSIZE: a write past it
    fails with EFBIG, as one on a full disk; Python ignores the SIGXFSZ)."""
    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (size, size))
    return limit


def record_limited(gw, target: Path, size: int) -> subprocess.CompletedProcess:
    return spawn_run([script("gx2ctl"), "--control", gw.control_endpoint, "record",
                      str(target), "--seconds", "30"], capture_output=True, text=True,
                     timeout=40, stdin=subprocess.DEVNULL, preexec_fn=limited_to(size))


def test_gx2ctl_record_on_a_failing_disk_says_so_in_one_line(simulator, gateway, tmp_path):
    sim = simulator(NodeSettings(76), NodeSettings(77))
    gw = gateway(sim.path, NODES)
    gw.wait_streaming(76, 77)
    # not even the first second fits: no file is left (a retry is not told "exists")
    nothing = tmp_path / "nothing.mcap"
    ran = record_limited(gw, nothing, 16)
    assert ran.returncode == 1, ran
    assert ran.stderr.splitlines() == [
        f"gx2ctl: {nothing}: File too large; nothing was recorded, the file is removed"]
    assert not nothing.exists()
    # a file that fills up keeps what was written, ended so that readers read it whole
    size = 20_000
    some = tmp_path / "some.mcap"
    ran = record_limited(gw, some, size)
    assert ran.returncode == 1, ran
    [line] = ran.stderr.splitlines()
    kept = re.fullmatch(rf"gx2ctl: {re.escape(str(some))}: File too large; it keeps the "
                        r"([\d,]+) messages written before", line)
    assert kept, line
    with some.open("rb") as stream:
        count = sum(1 for _ in NonSeekingReader(stream).iter_messages())
    assert count == int(kept.group(1).replace(",", "")) > 100
    reading = Reading()
    assert sum(1 for _ in read(some, reading)) == count
    [report] = reading.files
    assert not report.partial
    # ended (unless the end itself would not fit: then it is read up to its last chunk)
    assert report.whole or some.stat().st_size + 64 > size
    # a file that cannot be made at all: bad input, one line, before any gateway is asked
    under_a_file = tmp_path / "nothing.txt"
    under_a_file.write_text("")
    ran = record_limited(gw, under_a_file / "capture.mcap", size)
    assert ran.returncode == 2, ran
    assert ran.stderr.splitlines() == [f"gx2ctl: {under_a_file}/capture.mcap: Not a directory"]
