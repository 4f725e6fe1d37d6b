"""What the hand-run scripts in bench/ share: the test suite's helpers (a free port),
a process's RSS and open descriptors, the installed gateway's command, a tap on what
the simulator really writes into its pty, and a subscriber with a control client
(bench/soak.py and bench/faultsoak.py count losses through them the same way)."""

from __future__ import annotations

import os
import shutil
import statistics
import sys
import time
import uuid
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgpack
import zmq

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:  # (run as bench/NAME.py: the suite's helpers live there)
    sys.path.insert(0, str(REPO))

from aspp import Decoder, Reply  # noqa: E402
from gateway.sim.server import Simulator  # noqa: E402
from tests.helpers.ports import free_port  # noqa: E402

__all__ = ["REPO", "Tap", "Watcher", "cpu_ns", "free_port", "gateway_command",
           "gateway_losses", "open_fds", "rss_kib", "tap_writes", "unix_minus_monotonic"]


def cpu_ns(pid: int) -> int:
    """CPU time of every thread of ``pid`` (ZeroMQ's I/O thread included), in ns."""
    return sum(int((task / "schedstat").read_text().split()[0])
               for task in Path(f"/proc/{pid}/task").iterdir())


def rss_kib(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise RuntimeError(f"no VmRSS for process {pid}")


def open_fds(pid: int) -> int:
    """How many descriptors ``pid`` holds open (a leak grows it)."""
    return len(os.listdir(f"/proc/{pid}/fd"))


def gateway_command() -> str:
    """The gx2-gateway installed beside this Python (the venv's), else the one on PATH:
    the code measured is the tree this interpreter installed."""
    return shutil.which("gx2-gateway", path=str(Path(sys.executable).parent)) or "gx2-gateway"


def unix_minus_monotonic() -> float:
    """The UNIX clock less the monotonic one (a median of a few readings: a reading
    interrupted between the two calls is off)."""
    return statistics.median(time.time() - time.monotonic() for _ in range(9))


def tap_writes(sim: Simulator, on_reply: Callable[[Reply, float], None]) -> None:
    """Call ``on_reply(reply, time.monotonic())`` for every reply packet the simulator
    writes into the pty, as it writes it (in the simulator's thread, holding its lock:
    the simulator's state may be read there)."""
    decoder = Decoder()
    write = sim.port.write

    def tapped(data: bytes) -> int:
        written = write(data)
        now = time.monotonic()
        for event in decoder.feed(data[:written]):
            if type(event) is Reply:
                on_reply(event, now)
        return written
    sim.port.write = tapped  # type: ignore[method-assign]


class Tap:
    """Counts the reply packets the simulator really wrote into the pty, per node;
    ``also(reply, now)``, if given, sees each too."""

    def __init__(self, sim: Simulator,
                 also: Callable[[Reply, float], None] | None = None) -> None:
        self.replies: Counter[int] = Counter()

        def count(reply: Reply, now: float) -> None:
            self.replies[reply.node] += 1
            if also is not None:
                also(reply, now)
        tap_writes(sim, count)


class Watcher:
    """The subscriber and the control client, read from the caller's loop: ``drain``
    takes every record waiting (``on_record(topic, message)`` sees each) and every
    answer to a request sent with ``ask``, so a slow answer never blocks the loop."""

    def __init__(self, context: zmq.Context, publish: str, control: str,
                 on_record: Callable[[bytes, dict[str, Any]], None] | None = None) -> None:
        self.sub = context.socket(zmq.SUB)
        self.sub.setsockopt(zmq.RCVHWM, 0)  # this subscriber must not be the one losing
        self.sub.setsockopt(zmq.LINGER, 0)
        self.sub.setsockopt(zmq.SUBSCRIBE, b"gx2/")
        self.sub.connect(publish)
        self.control = context.socket(zmq.DEALER)
        self.control.setsockopt(zmq.LINGER, 0)
        self.control.connect(control)
        self.on_record = on_record
        self.received: Counter[int] = Counter()
        self.last_seq: dict[int, int] = {}
        self.first_seq: dict[int, int] = {}
        """Published before this subscriber joined: seq 1 .. first_seq - 1."""
        self.seq_gaps = 0
        self.last_record: dict[int, float] = {}
        self.answers: dict[str, dict[str, Any]] = {}
        """Replies to ``ask`` by request id, until taken."""
        self.poller = zmq.Poller()
        self.poller.register(self.sub, zmq.POLLIN)
        self.poller.register(self.control, zmq.POLLIN)

    def drain(self, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while True:
            left = deadline - time.monotonic()
            if not dict(self.poller.poll(max(0, int(left * 1000)))) and left <= 0:
                return
            self._take_records()
            self._take_answers()
            if time.monotonic() >= deadline:
                return

    def _take_records(self) -> None:
        while True:
            try:
                topic, payload = self.sub.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return
            if topic.startswith(b"gx2/gateway/"):
                continue
            message = msgpack.unpackb(payload)
            node, seq = message["node"], message["seq"]
            self.received[node] += 1
            last = self.last_seq.get(node)
            self.first_seq.setdefault(node, seq)
            if last is not None and seq != last + 1:
                self.seq_gaps += seq - last - 1
            self.last_seq[node] = seq
            self.last_record[node] = time.monotonic()
            if self.on_record is not None:
                self.on_record(topic, message)

    def _take_answers(self) -> None:
        while True:
            try:
                frames = self.control.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return
            reply = msgpack.unpackb(frames[-1])
            self.answers[str(reply.get("id"))] = reply

    def ask(self, op: str, **fields: Any) -> str:
        """Send a request; its reply lands in ``answers`` under the id returned."""
        request_id = uuid.uuid4().hex
        self.control.send_multipart([b"", msgpack.packb({"id": request_id, "op": op,
                                                          **fields})])
        return request_id

    def status(self, timeout: float = 2.0) -> dict[str, Any] | None:
        return self.request("status", timeout)

    def request(self, op: str, timeout: float = 10.0, **fields: Any) -> dict[str, Any] | None:
        """The result, or None for an error or no answer in time."""
        request_id = self.ask(op, **fields)
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            self.drain(min(0.05, left))  # keep up with the stream meanwhile
            reply = self.answers.pop(request_id, None)
            if reply is not None:
                return reply["result"] if reply.get("ok") else None
        return None


def gateway_losses(status: dict[str, Any], tap: Tap, watch: Watcher,
                   nodes: tuple[int, ...]) -> dict[str, int]:
    """What the simulator delivered into the pty, what the gateway received and
    published, and what a subscriber got, summed over ``nodes`` (from a final status,
    once the streams are stopped and the counts settled); ``in_gateway`` must be 0:
    received but not published, or published but missing at the subscriber (seq)."""
    by_node = {n["node"]: n for n in status["nodes"]}
    received = sum(by_node[a]["packets"] for a in nodes)
    published = sum(by_node[a]["published"] for a in nodes)
    lost_gateway = sum(by_node[a]["lost_gateway"] for a in nodes)
    got = sum(watch.received[a] for a in nodes)
    before_joining = sum(watch.first_seq.get(a, 1) - 1 for a in nodes)
    return {"delivered": sum(tap.replies[a] for a in nodes), "received": received,
            "published": published, "got": got, "before_joining": before_joining,
            "seq_gaps": watch.seq_gaps,
            "in_gateway": lost_gateway + (received - published)
            + (published - before_joining - got)}
