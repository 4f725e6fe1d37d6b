"""A real MQTT broker for the tests and benches: mosquitto (Debian's package) on a free
loopback port with a configuration file of its own, and a subscriber that collects
what it is sent (paho-mqtt, the client the gateway does not share with it: each test
makes its own)."""

from __future__ import annotations

import getpass
import json
import shutil
import socket
import subprocess
import threading
from pathlib import Path
from typing import Any

from .ports import free_port
from .waiting import wait_for

MOSQUITTO = shutil.which("mosquitto") or (
    "/usr/sbin/mosquitto" if Path("/usr/sbin/mosquitto").exists() else None)
"""The broker's program (Debian installs it in /usr/sbin), None where it is missing."""
MOSQUITTO_PASSWD = shutil.which("mosquitto_passwd")


class Broker:
    """mosquitto on 127.0.0.1:``port``; ``stop()`` and ``start()`` again on the same
    port (a broker restarted mid-stream)."""

    def __init__(self, directory: Path, users: dict[str, str] | None = None,
                 port: int | None = None, tls: tuple[Path, Path] | None = None) -> None:
        """``tls``: a PEM certificate and its key, served on the port (mqtts://)."""
        assert MOSQUITTO is not None, "mosquitto is not installed"
        self.port = port or free_port()
        self.url = f"{'mqtts' if tls else 'mqtt'}://127.0.0.1:{self.port}"
        self.directory = directory
        lines = [f"listener {self.port} 127.0.0.1", "persistence false",
                 "log_dest stderr", "log_type error", "log_type warning",
                 # started as root it would become the user mosquitto, who cannot read
                 # the test's files (its password file); as anyone else this is ignored
                 f"user {getpass.getuser()}"]
        if tls:
            lines += [f"certfile {tls[0]}", f"keyfile {tls[1]}"]
        if users:
            assert MOSQUITTO_PASSWD is not None, "mosquitto_passwd is not installed"
            passwords = directory / "mosquitto.passwd"
            passwords.touch(mode=0o600)
            for user, password in users.items():
                subprocess.run([MOSQUITTO_PASSWD, "-b", str(passwords), user, password],
                               check=True, capture_output=True)
            lines += ["allow_anonymous false", f"password_file {passwords}"]
        else:
            lines.append("allow_anonymous true")
        self.config = directory / "mosquitto.conf"
        self.config.write_text("\n".join(lines) + "\n")
        self.log_path = directory / "mosquitto.log"
        self.proc: subprocess.Popen[bytes] | None = None
        self.start()

    def start(self) -> None:
        with self.log_path.open("ab") as log:
            self.proc = subprocess.Popen([str(MOSQUITTO), "-c", str(self.config)],
                                         stdout=log, stderr=subprocess.STDOUT,
                                         stdin=subprocess.DEVNULL)
        wait_for(self._listening, 10, f"mosquitto listening on {self.port}")

    def _listening(self) -> bool:
        assert self.proc is not None
        if self.proc.poll() is not None:
            raise AssertionError(f"mosquitto exited: {self.log_path.read_text()}")
        try:
            socket.create_connection(("127.0.0.1", self.port), timeout=1).close()
        except OSError:
            return False
        return True

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.proc = None


class Listener:
    """A subscriber of its own (paho-mqtt, MQTT 3.1.1) collecting every message of
    ``topics`` as (topic, payload bytes, retained), in arrival order."""

    def __init__(self, broker: Broker, *topics: str, username: str | None = None,
                 password: str | None = None) -> None:
        from paho.mqtt.client import CallbackAPIVersion, Client

        self.messages: list[tuple[str, bytes, bool]] = []
        self._lock = threading.Lock()
        self._subscribed = threading.Event()
        self.client = Client(CallbackAPIVersion.VERSION2)
        if username is not None:
            self.client.username_pw_set(username, password)
        self.client.on_message = self._on_message
        self.client.on_connect = lambda client, *_: client.subscribe([(t, 0) for t in topics])
        self.client.on_subscribe = lambda *_: self._subscribed.set()
        self.client.connect("127.0.0.1", broker.port)
        self.client.loop_start()
        wait_for(self._subscribed.is_set, 10, f"subscribed to {topics}")

    def _on_message(self, client: Any, userdata: Any, message: Any) -> None:
        with self._lock:
            self.messages.append((message.topic, bytes(message.payload),
                                  bool(message.retain)))

    def taken(self) -> list[tuple[str, bytes, bool]]:
        with self._lock:
            return list(self.messages)

    def json(self, topic: str) -> list[dict[str, Any]]:
        """The JSON payloads received on ``topic``, in order."""
        return [json.loads(payload) for name, payload, _ in self.taken() if name == topic]

    def latest(self, topic: str) -> bytes | None:
        found = [payload for name, payload, _ in self.taken() if name == topic]
        return found[-1] if found else None

    def close(self) -> None:
        self.client.loop_stop()
        self.client.disconnect()


def retained(broker: Broker, topic: str, timeout: float = 5.0) -> bytes:
    """The message the broker retains on ``topic``, as a new subscriber receives it."""
    listener = Listener(broker, topic)
    try:
        return wait_for(lambda: next((p for t, p, r in listener.taken() if r and t == topic),
                                     None), timeout, f"a retained message on {topic}")
    finally:
        listener.close()
