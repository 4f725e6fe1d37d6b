"""One view of several gateways (issue 37), through the installed gx2ctl against two
real gateways, each on its own gx2-sim pty: ``status`` (text and ``--json``) shows both
in one table, grouped by gateway; a gateway that does not answer is a line saying so
while the other is still shown; ``tail``, ``record`` and ``top`` (in a real terminal)
take both; an op that acts on one node refuses two gateways in one line."""

from __future__ import annotations

import json
import shlex
import shutil
import signal
from pathlib import Path

import pytest
import yaml

from gateway.common import curve
from gateway.common.curve import ClientKeys
from gateway.recording.reader import read
from gateway.recording.reports import Reading
from gateway.sim.node import NodeSettings
from tests.e2e.test_recording import messages, node_records
from tests.e2e.test_top import Terminal, row
from tests.helpers.gateway import Control
from tests.helpers.processes import STARTUP, Running, gx2ctl, script
from tests.helpers.waiting import wait_for

DIVIDER = 512
"""100 Hz."""


@pytest.fixture
def site(simulator, gateway, tmp_path: Path):
    """Two gateways (hall-a with node 76, hall-b with node 90, both streaming) and a
    gateways file naming them."""
    running = {}
    for name, node in (("hall-a", 76), ("hall-b", 90)):
        sim = simulator(NodeSettings(node, divider=DIVIDER, stream="accel_angrate"),
                        name=f"sim-{name}")
        running[name] = gateway(sim.path, [{"address": node}], directory=tmp_path / name)
        running[name].wait_streaming(node)
    listed = tmp_path / "site.yaml"
    listed.write_text(yaml.safe_dump({"gateways": [
        {"name": "hall-a", "config": "hall-a/nodes.yaml"},
        {"name": "hall-b", "control": running["hall-b"].control_endpoint}]}))
    return running, listed


def test_status_shows_both_gateways_in_one_table(site) -> None:
    running, listed = site
    run = gx2ctl("--config", str(listed), "status")
    assert run.status == 0 and run.stderr == "", run
    lines = run.stdout.splitlines()
    table = lines[lines.index("") + 1:]
    assert table[0].split()[:3] == ["node", "name", "state"]
    a, b = table.index("== hall-a"), table.index("== hall-b")
    assert [line.split()[0] for line in table[a + 1:b]] == ["76"]
    assert table[b + 1].split()[:3] == ["90", "-", "streaming"]
    assert lines[0] == "== hall-a" and lines[1].startswith("gateway  version ")

    shown = gx2ctl("--control", running["hall-a"].control_endpoint,
                   "--control", running["hall-b"].control_endpoint, "--json", "status")
    assert shown.status == 0, shown
    answer = json.loads(shown.stdout)
    assert list(answer) == ["gateways"]
    assert [g["error"] for g in answer["gateways"]] == [None, None]
    assert [[n["node"] for n in g["nodes"]] for g in answer["gateways"]] == [[76], [90]]
    assert [g["name"] for g in answer["gateways"]] == [running[n].control_endpoint
                                                       for n in ("hall-a", "hall-b")]
    # one gateway: the status as it always was, no wrapper
    one = gx2ctl("--config", str(running["hall-a"].path), "--json", "status")
    assert one.status == 0 and "gateways" not in json.loads(one.stdout), one
    # --check of both once each says all well on its own (a node streaming for under a
    # second is WARN, "clock not locked": one full run met it there)
    for each in running.values():
        wait_for(lambda each=each: all(n["health"] == "OK" for n in each.status()["nodes"]),
                 10, "each gateway's nodes OK")
    check = gx2ctl("--config", str(listed), "status", "--check")
    assert check.status == 0, check


def test_a_gateway_that_does_not_answer_is_a_line_saying_so(site) -> None:
    running, listed = site
    running["hall-b"].terminate()
    run = gx2ctl("--config", str(listed), "--timeout", "1", "status")
    assert run.status == 3, run
    assert "== hall-b: no answer from the gateway at " in run.stdout
    lines = run.stdout.splitlines()
    table = lines[lines.index("") + 1:]
    a = table.index("== hall-a")
    assert table[a + 1].split()[:3] == ["76", "-", "streaming"]
    # where hall-b's nodes would be (above why each node not OK is not: hall-a's may be
    # "clock not locked" so soon after its start)
    assert table[a + 2].startswith("== hall-b: no answer")
    assert all(line.startswith("hall-a/") for line in table[a + 3:]), table
    assert run.stderr.count("\n") == 1 and "1 of 2 gateways did not answer: hall-b" in \
        run.stderr, run.stderr

    shown = gx2ctl("--config", str(listed), "--timeout", "1", "--json", "status")
    assert shown.status == 3
    a, b = json.loads(shown.stdout)["gateways"]
    assert (a["name"], a["error"], a["nodes"][0]["node"]) == ("hall-a", None, 76)
    assert b["name"] == "hall-b" and "no answer" in b["error"] and "nodes" not in b


def test_tail_prints_both_gateways_records_and_goes_on_when_one_stops(site) -> None:
    running, _ = site
    tail = Running("gx2ctl", "--config", str(running["hall-a"].path), "--timeout", "1",
                   "--config", str(running["hall-b"].path), "tail")
    try:
        seen: set[tuple[str, int]] = set()

        def both() -> bool:
            line = tail.wait_for_line(lambda text: text.startswith("{"), STARTUP)
            record = json.loads(line)
            seen.add((record["gateway"], record["node"]))
            return len(seen) == 2
        wait_for(both, STARTUP, "records of both gateways")
        # (two configurations both named nodes.yaml: each gateway is named by its path)
        assert seen == {(str(running["hall-a"].path), 76), (str(running["hall-b"].path), 90)}

        running["hall-b"].terminate()
        wait_for(lambda: any("published nothing for" in line for line in tail.stderr), 15,
                 "tail to say hall-b fell silent")
        assert [line for line in tail.stderr if line.startswith("gx2ctl: ")] == [
            f"gx2ctl: {running['hall-b'].path} at {running['hall-b'].publish_endpoint} "
            "published nothing for 3 s (not even its heartbeat)\n"]
        after = len(tail.stdout)
        wait_for(lambda: len(tail.stdout) > after + 50, 10, "hall-a's records to go on")
        assert json.loads(tail.stdout[-1])["node"] == 76 and tail.proc.poll() is None
    finally:
        tail.proc.send_signal(signal.SIGINT)
    assert tail.finish(10) == 0, tail.stderr


def test_record_from_both_gateways_into_one_file(site, tmp_path: Path) -> None:
    running, listed = site
    target = tmp_path / "both.mcap"
    record = Running("gx2ctl", "--config", str(listed), "--timeout", "1", "record",
                     str(target))
    try:
        wait_for(target.exists, STARTUP, "record to hear the gateways")

        def holds_hall_b() -> bool:  # (the file as flushed so far, read past its end)
            return any(entry.topic == "gx2/90/accel_angrate"
                       for entry in read(target, Reading()))
        wait_for(holds_hall_b, STARTUP, "hall-b's records in the file")
        running["hall-b"].terminate()
        wait_for(lambda: any("hall-b at " in line and "published nothing" in line
                             for line in record.stderr), 15, "record to say hall-b is silent")
        assert record.proc.poll() is None, "hall-a is still recorded"
    finally:
        record.proc.send_signal(signal.SIGINT)
    assert record.finish(10) == 0, record.stderr
    records = node_records(messages(target))
    assert {topic for topic, _, _ in records} == {"gx2/76/accel_angrate",
                                                  "gx2/90/accel_angrate"}
    for node, least in ((76, 300), (90, 1)):  # each node's stream whole: seq +1 each
        seqs = [p["seq"] for _, p, _ in records if p["node"] == node]
        assert len(seqs) >= least and seqs == list(range(seqs[0], seqs[0] + len(seqs)))


def test_an_op_on_one_node_refuses_several_gateways(site) -> None:
    _, listed = site
    run = gx2ctl("--config", str(listed), "ping", "76")
    assert run.status == 2 and run.stdout == "", run
    assert run.stderr.startswith("gx2ctl: ping acts on one gateway, and 2 are given "
                                 "(hall-a, hall-b)") and run.stderr.count("\n") == 1


@pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed")
def test_top_shows_both_gateways(site, tmp_path: Path) -> None:
    running, listed = site
    terminal = Terminal(f"{shlex.quote(script('gx2ctl'))} --config "
                        f"{shlex.quote(str(listed))} top", tmp_path)
    try:
        watch_both(running, terminal)
    finally:
        terminal.close()


def watch_both(running, terminal: Terminal) -> None:
    def shown() -> list[str] | None:
        screen = terminal.screen()
        ok = (row(screen, 76) or "").endswith("OK") and (row(screen, 90) or "").endswith("OK")
        return screen if ok else None
    screen = wait_for(shown, STARTUP, "both gateways' nodes in top")
    a = next(i for i, line in enumerate(screen) if line.startswith("== hall-a "))
    b = next(i for i, line in enumerate(screen) if line.startswith("== hall-b "))
    assert a < screen.index(row(screen, 76)) < b < screen.index(row(screen, 90))
    assert all(len(line) <= 80 for line in screen)

    running["hall-b"].terminate()
    wait_for(lambda: any("no heartbeat" in line for line in terminal.screen()), 15,
             "top to say hall-b is silent")
    assert (row(terminal.screen(), 76) or "").endswith("OK")  # the other goes on
    terminal.keys("q")
    wait_for(lambda: terminal.exit_status() is not None, 10, "top to quit")
    assert terminal.exit_status() == 0


def with_a_dead_one(running, tmp_path: Path) -> Path:
    """A gateways file naming both gateways and a third, hall-c, that nothing serves."""
    listed = tmp_path / "three.yaml"
    listed.write_text(yaml.safe_dump({"gateways": [
        {"name": "hall-a", "config": "hall-a/nodes.yaml"},
        {"name": "hall-b", "control": running["hall-b"].control_endpoint},
        {"name": "hall-c", "control": f"ipc://{tmp_path}/hall-c-control"}]}))
    return listed


def test_tail_prints_the_live_gateways_while_a_dead_one_is_asked(site,
                                                                  tmp_path: Path) -> None:
    """A gateway that does not answer holds no line of the others back: tail prints
    them from the first found, and says the dead one once it gives it up (issue 43:
    nothing for --timeout)."""
    running, _ = site
    tail = Running("gx2ctl", "--config", str(with_a_dead_one(running, tmp_path)),
                   "--timeout", "60", "tail")
    try:
        seen: set[str] = set()

        def both() -> bool:
            line = tail.wait_for_line(lambda text: text.startswith("{"), STARTUP)
            seen.add(json.loads(line)["gateway"])
            return seen == {"hall-a", "hall-b"}
        wait_for(both, STARTUP, "records of both live gateways, well before --timeout")
        assert not [line for line in tail.stderr if "hall-c" in line], tail.stderr
    finally:
        tail.proc.send_signal(signal.SIGINT)
    assert tail.finish(10) == 0, tail.stderr


@pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed")
def test_top_shows_a_gateway_that_does_not_answer_on_its_screen(site,
                                                                tmp_path: Path) -> None:
    """A dead gateway is a line of top's screen saying so, and counted (issue 43: its
    line went to stderr behind the full-screen view, the header said 2 gateways)."""
    running, _ = site
    terminal = Terminal(f"{shlex.quote(script('gx2ctl'))} --config "
                        f"{shlex.quote(str(with_a_dead_one(running, tmp_path)))} "
                        "--timeout 2 top", tmp_path)
    try:
        def said() -> list[str] | None:
            screen = terminal.screen()
            dead = [line for line in screen if line.startswith("== hall-c  left out: ")]
            ok = (row(screen, 76) or "").endswith("OK") and \
                (row(screen, 90) or "").endswith("OK")
            return screen if dead and ok else None
        screen = wait_for(said, STARTUP, "top to show hall-c left out and the others")
        assert screen[0].startswith("gx2ctl top: 3 gateways "), screen
        assert any("no answer from the gateway at ipc://" in line for line in screen), \
            screen
        terminal.keys("q")
        wait_for(lambda: terminal.exit_status() is not None, 10, "top to quit")
        assert terminal.exit_status() == 0
    finally:
        terminal.close()


def test_top_json_prints_each_gateways_heartbeat_with_its_name(site) -> None:
    _, listed = site
    top = Running("gx2ctl", "--config", str(listed), "--json", "top", "90")
    try:
        heard: dict[str, list[int]] = {}

        def both() -> bool:
            beat = json.loads(top.wait_for_line(lambda text: text.startswith("{"), STARTUP))
            heard[beat["name"]] = [n["node"] for n in beat["nodes"]]
            return len(heard) == 2
        wait_for(both, STARTUP, "a heartbeat of each gateway")
        assert heard == {"hall-a": [], "hall-b": [90]}  # (only the node asked for)
    finally:
        top.proc.send_signal(signal.SIGINT)
    assert top.finish(10) == 0, top.stderr


def test_record_takes_each_gateways_own_curve_key_and_a_plain_one_alongside(
        simulator, gateway, zmq_context, tmp_path: Path) -> None:
    """hall-a and hall-b encrypt with server keys of their own (hall-b's given by its
    gateways file entry), hall-c not at all: one record takes all three."""
    for name in ("srv-a", "srv-b", "ops"):
        curve.generate(tmp_path / name)
    ops = curve.load_key_pair(tmp_path / "ops.key_secret")
    running = {}
    for name, node, secured in (("hall-a", 76, "srv-a"), ("hall-b", 90, "srv-b"),
                                ("hall-c", 91, None)):
        sim = simulator(NodeSettings(node, divider=DIVIDER, stream="accel_angrate"),
                        name=f"sim-{name}")
        extra = {"curve": {"server_key": str(tmp_path / f"{secured}.key_secret"),
                           "clients": [str(tmp_path / "ops.key")]}} if secured else {}
        gw = running[name] = gateway(sim.path, [{"address": node}], wait=False,
                                     directory=tmp_path / name, **extra)
        if secured:
            server = curve.load_key_pair(tmp_path / f"{secured}.key_secret").public
            gw.control = Control(zmq_context, gw.control_endpoint, ClientKeys(ops, server))
        wait_for(lambda gw=gw: gw.control.try_call("status", timeout=0.5), STARTUP,
                 f"{name} answering")
        gw.wait_streaming(node)
    listed = tmp_path / "site.yaml"
    listed.write_text(yaml.safe_dump({"gateways": [
        {"name": "hall-a", "config": "hall-a/nodes.yaml"},
        {"name": "hall-b", "control": running["hall-b"].control_endpoint,
         "server_key": "srv-b.key"},
        {"name": "hall-c", "config": "hall-c/nodes.yaml"}]}))
    configs = [f"--config={tmp_path / name / 'nodes.yaml'}" for name in running]
    client = ("--client-key", str(tmp_path / "ops.key_secret"))
    for number, named in enumerate(([f"--config={listed}"], configs)):
        target = tmp_path / f"three{number}.mcap"
        done = gx2ctl(*named, *client, "record", "--seconds", "2", str(target))
        assert done.status == 0, done.stderr
        assert {topic for topic, _, _ in node_records(messages(target))} == {
            "gx2/76/accel_angrate", "gx2/90/accel_angrate", "gx2/91/accel_angrate"}

    refused = gx2ctl(*configs[1:], "status")  # (no client key: the error names hall-b)
    assert refused.status == 2 and refused.stderr.count("\n") == 1, refused.stderr
    assert refused.stderr.startswith(f"gx2ctl: {configs[1].removeprefix('--config=')}: "), \
        refused.stderr
