"""A running gateway as users meet it: the installed gx2-gateway console script as a
subprocess, a control client and subscribers on real ZeroMQ sockets on the loopback.
"""

from __future__ import annotations

import math
import signal
import subprocess
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgpack
import yaml
import zmq

from gateway.common import curve
from gateway.common.curve import ClientKeys

from .ports import endpoint, free_port
from .processes import EXIT, script
from .waiting import wait_for

SEND_TIMEOUT_MS = 2000


class Control:
    """A control client speaking the protocol directly (gx2ctl has its own tests)."""

    def __init__(self, context: zmq.Context, endpoint: str,
                 keys: ClientKeys | None = None) -> None:
        self.socket = context.socket(zmq.DEALER)
        self.socket.setsockopt(zmq.LINGER, 0)
        # a DEALER whose only peer refused it (a CURVE handshake that failed) has no
        # pipe left to queue on, and a plain send would wait for one forever
        self.socket.setsockopt(zmq.SNDTIMEO, SEND_TIMEOUT_MS)
        if keys is not None:
            curve.connect_as(self.socket, keys)
        self.socket.connect(endpoint)

    def send_raw(self, *frames: bytes) -> None:
        self.socket.send_multipart(list(frames))

    def receive(self, timeout: float = 5.0) -> dict[str, Any] | None:
        if not self.socket.poll(int(timeout * 1000)):
            return None
        return msgpack.unpackb(self.socket.recv_multipart()[-1])

    def call(self, op: str, timeout: float = 10.0, **fields: Any) -> dict[str, Any]:
        """One request; the whole reply ({"id", "ok", "result" | "error"})."""
        request_id = uuid.uuid4().hex
        try:
            self.send_raw(b"", msgpack.packb({"id": request_id, "op": op, **fields}))
        except zmq.Again:
            raise AssertionError(f"could not send {op}: no peer took it") from None
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            reply = self.receive(left)
            if reply is not None and reply.get("id") == request_id:
                return reply
        raise AssertionError(f"no reply to {op} within {timeout} s")

    def try_call(self, op: str, timeout: float, **fields: Any) -> dict[str, Any] | None:
        """Like :meth:`call`, but None if nothing answers in time (a gateway starting)."""
        try:
            return self.call(op, timeout, **fields)
        except AssertionError:
            return None

    def result(self, op: str, timeout: float = 10.0, **fields: Any) -> dict[str, Any]:
        reply = self.call(op, timeout, **fields)
        assert reply["ok"], reply
        return reply["result"]


class Subscriber:
    """A SUB socket that collects [topic, payload] messages."""

    def __init__(self, context: zmq.Context, endpoint: str, *prefixes: str,
                 keys: ClientKeys | None = None) -> None:
        self.socket = context.socket(zmq.SUB)
        self.socket.setsockopt(zmq.LINGER, 0)
        self.socket.setsockopt(zmq.RCVHWM, 0)
        if keys is not None:
            curve.connect_as(self.socket, keys)
        for prefix in prefixes or ("",):
            self.socket.setsockopt(zmq.SUBSCRIBE, prefix.encode())
        self.socket.connect(endpoint)
        self.messages: list[tuple[str, dict[str, Any]]] = []

    def drain(self, seconds: float) -> list[tuple[str, dict[str, Any]]]:
        """Collect for ``seconds``; return what arrived in that time."""
        start = len(self.messages)
        deadline = time.monotonic() + seconds
        while (left := deadline - time.monotonic()) > 0:
            if self.socket.poll(int(left * 1000) + 1):
                topic, payload = self.socket.recv_multipart()
                self.messages.append((topic.decode(), msgpack.unpackb(payload)))
        return self.messages[start:]

    def drain_until_quiet(self, quiet: float = 0.5, timeout: float = 30.0
                          ) -> list[tuple[str, dict[str, Any]]]:
        """Collect until nothing arrived for ``quiet`` seconds (``timeout`` at most):
        what a gateway that has exited had published may still be queued in the
        socket, more than a fixed drain reads on a busy host (CI: a replay's last
        1,030 records after a drain of 0.3 s)."""
        start = len(self.messages)
        deadline = time.monotonic() + timeout
        while self.drain(quiet):
            if time.monotonic() > deadline:
                raise AssertionError(f"still publishing after {timeout} s: "
                                     f"{len(self.messages) - start} messages")
        return self.messages[start:]

    def until(self, condition: Callable[[list[tuple[str, dict[str, Any]]]], bool],
              timeout: float, what: str) -> list[tuple[str, dict[str, Any]]]:
        deadline = time.monotonic() + timeout
        while not condition(self.messages):
            left = deadline - time.monotonic()
            if left <= 0:
                raise AssertionError(f"timed out after {timeout} s waiting for {what}; "
                                     f"{len(self.messages)} messages")
            self.drain(min(left, 0.05))
        return self.messages

    def records(self, node: int) -> list[dict[str, Any]]:
        return [p for t, p in self.messages if t.startswith(f"gx2/{node}/")]


class RunningGateway:
    def __init__(self, config: dict[str, Any], directory: Path, context: zmq.Context,
                 env: dict[str, str] | None = None,
                 preexec: Callable[[], None] | None = None) -> None:
        self.config = config
        self.path = directory / "nodes.yaml"
        self.path.write_text(yaml.safe_dump(config))
        self.log_path = directory / "gateway.log"
        self._log = self.log_path.open("w")
        self.proc = subprocess.Popen([script("gx2-gateway"), "--config", str(self.path),
                                      "--log-level", "DEBUG"],
                                     stdout=self._log, stderr=subprocess.STDOUT,
                                     stdin=subprocess.DEVNULL, env=env, preexec_fn=preexec)
        self.context = context
        self.control_endpoint = config["control"]["endpoint"]
        self.publish_endpoint = config["publish"]["endpoint"]
        self.control = Control(context, self.control_endpoint)

    def subscribe(self, *prefixes: str) -> Subscriber:
        return Subscriber(self.context, self.publish_endpoint, *prefixes)

    def status(self) -> dict[str, Any]:
        return self.control.result("status")

    def node_status(self, node: int) -> dict[str, Any]:
        return next(n for n in self.status()["nodes"] if n["node"] == node)

    def wait_streaming(self, *nodes: int, timeout: float = 10.0) -> None:
        def ready() -> bool:
            states = {n["node"]: n["state"] for n in self.status()["nodes"]}
            return all(states[n] == "streaming" for n in nodes)
        wait_for(ready, timeout, f"nodes {nodes} streaming")

    def log(self) -> str:
        self._log.flush()
        return self.log_path.read_text()

    def terminate(self, signum: int = signal.SIGTERM) -> tuple[int, float]:
        """Signal it; return (exit status, seconds it took)."""
        start = time.monotonic()
        self.proc.send_signal(signum)
        try:
            status = self.proc.wait(EXIT + 3)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
            raise AssertionError(f"gateway ignored signal {signum}:\n{self.log()}") from None
        return status, time.monotonic() - start

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        self._log.close()


def gateway_config(port: str | None, nodes: list[dict[str, Any]],
                   **sections: Any) -> dict[str, Any]:
    """One base station on ``port`` with ``nodes``; or, with ``port`` None and
    ``base_stations=[...]``, those."""
    config: dict[str, Any] = {
        "publish": {"endpoint": endpoint()},
        "control": {"endpoint": endpoint()},
    }
    if port is None:
        config["base_stations"] = sections.pop("base_stations")
    else:
        config.update(base_station={"port": port}, nodes=nodes)
    for key, value in sections.items():
        config.setdefault(key, {}).update(value)
    # a metrics section without its endpoint would take the default, 127.0.0.1:9105:
    # the demo's, which a user may be running beside the suite (issue 24)
    for section in ("metrics", "live"):  # (the live view's default: the demo's 8765)
        given = config.get(section)
        if isinstance(given, dict) and "endpoint" not in given:
            given["endpoint"] = f"127.0.0.1:{free_port()}"
    return config


def is_nan(value: Any) -> bool:
    return isinstance(value, float) and math.isnan(value)
