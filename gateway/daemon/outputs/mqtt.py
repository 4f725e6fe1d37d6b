"""The MQTT output (``mqtt:``): records as JSON into a broker the site already runs,
with the gateway's status and every node's availability retained, and the gateway's
own availability as its last will (docs/site.md).

Built on paho-mqtt 2, its network loop in a thread of its own, fed by a second thread
of ours from a bounded queue: ``take`` on the loop only decides whether the record is
due (``rate_hz``) and appends it, 0.2 us of the loop's time a record against 11 us for
paho's ``publish`` called on the loop and 126 us for aiomqtt, whose publishing and
socket writes all run on the loop (bench/mqttclient.py, docs/performance-history.md). A
broker that is slow, down or unreachable costs the queue (``mqtt.queue`` messages, and
at most as many more inside paho: a batch is handed over once paho has written the
last): what does not fit, or comes while the broker is away, is dropped and counted,
never waited for; paho reconnects with a backoff (RECONNECT_S) and the retained
messages are sent again on each connection. What raises in paho's thread (our
callbacks, or paho's own connecting: a host name the resolver refuses) is contained
by the outputs' guard (:mod:`.guard`): counted, said once, the reason in ``error``,
and the thread goes on retrying; it never dies unseen.

Imported only when ``mqtt:`` is configured, as live.py is.
"""

from __future__ import annotations

import collections
import contextlib
import functools
import logging
import ssl
import sys
import threading
from collections.abc import Callable, Mapping
from typing import Any, TypeVar
from urllib.parse import urlsplit

from paho.mqtt.client import CallbackAPIVersion, Client, MQTTErrorCode

from gateway.common.reading import as_map
from gateway.common.topics import MARK_TOPIC, STATUS_TOPIC, parse

from ..config import MQTT_SCHEMES, MqttConfig
from ..station.nodes import State
from . import Message, Needs, Output
from .guard import Guard, Guarded
from .homeassistant import discovery
from .sampler import Sampler

log = logging.getLogger("gx2.mqtt")

RECONNECT_S = (1, 30)
"""paho's reconnect backoff: from 1 s, doubling, to 30 s at most."""
BATCH_S = 0.05
"""Seconds the records of a stream gather in the queue before the output's thread hands
them to paho at once: a wake of each thread a record cost 0.3 ms of CPU each, three
times the gateway's own work a record (bench/ab.py --mqtt, docs/performance-history.md). A
record waits this long at most on top of the network."""
KEEPALIVE_S = 30
"""The broker notices a gateway gone silent (and sends its will) in 1.5 times this; paho
gives up on a broker that has not answered the CONNECT (no CONNACK) after as long."""
HANDSHAKE_CLOSED = ("the connection closed during the MQTT handshake: is the url's scheme "
                    "right (mqtts:// for TLS)?")
"""Why a connection the broker accepted and closed before its CONNACK failed: most
often plain MQTT sent to a TLS port (mosquitto logs "wrong version number")."""
OFFLINE_STATES = frozenset({State.UNKNOWN, State.UNREACHABLE, State.SILENT,
                            State.LINK_DOWN})
"""A node in these states is ``offline``; in any other it answers: ``online``."""
WILL_QOS = 1
"""The last will and the availability messages: delivered at least once (the records
and status are QoS 0)."""


F = TypeVar("F", bound=Callable[..., Any])


def guarded(method: F) -> F:
    """A callback of paho's thread, contained by the guard: what it raises is counted
    and said once (paho would let it end its thread, and with it every reconnection)."""
    @functools.wraps(method)
    def call(self: MqttOutput, *args: Any) -> Any:
        try:
            return method(self, *args)
        except Exception as error:  # (a bug, contained)
            self._guard.failed(f"failed in paho's thread ({method.__name__})", error)
            return None
    return call  # type: ignore[return-value]


class GuardedClient(Client):
    """paho's client whose network thread does not die of what it raises: paho 2's
    ``loop_start`` runs ``_thread_main`` in it (``loop_forever`` until ``loop_stop``),
    and a connection that fails with anything but an OSError (the resolver's
    UnicodeError for a host it refuses) ended the thread there, with a traceback,
    leaving the output "away" for good and unsaid. Here it is handed to ``failed`` and
    the loop goes on, reconnecting with paho's own backoff. (``_thread_main`` and
    ``_thread_terminate`` are paho's own names: tests/daemon/outputs/test_mqtt.py
    fails if the thread stops being this one.)"""

    def __init__(self, *args: Any, failed: Callable[[Exception], None],
                 stopping: threading.Event, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._failed_in_thread = failed
        self._stopping = stopping

    def _thread_main(self) -> None:
        try:
            while not self._thread_terminate and not self._stopping.is_set():
                try:
                    self.loop_forever(retry_first_connection=True)
                    return
                except Exception as error:  # (contained: said, and tried again)
                    self._failed_in_thread(error)
                    self._stopping.wait(RECONNECT_S[0])
        finally:
            self._thread = None


class MqttOutput(Output):
    def __init__(self, config: MqttConfig, guard: Guarded | None = None) -> None:
        self.config = config
        self._guard = guard or Guard().of("mqtt")
        """Where what raises in its threads is counted and said (:mod:`.guard`)."""
        self.base = f"{config.prefix}/{config.name}"
        self.url = config.url
        parts = urlsplit(config.url)
        self._host = parts.hostname or ""
        self._port = parts.port or MQTT_SCHEMES[parts.scheme]
        self._queue: collections.deque[tuple[str, Message | bytes, bool]] = \
            collections.deque()
        self._wake = threading.Event()
        self._closing = threading.Event()
        self._sampler = Sampler()
        self._every: dict[bytes, tuple[str, float | None]] = {}
        """Gateway topic -> (MQTT topic, least seconds between two sent, or None)."""
        self._availability: dict[int, str] = {}
        """Node -> what was last said of it (``online``/``offline``)."""
        self._names: dict[int, str | None] = {}
        """Node -> its name, for each node in the status reports."""
        self._discovery = config.homeassistant_prefix if config.homeassistant else None
        """Home Assistant's discovery prefix, None without discovery."""
        self.connected = False
        self.connects = 0
        self.sent = 0
        """Messages handed to paho while connected."""
        self.dropped = {"queue": 0, "offline": 0}
        """Messages never sent: the queue was full, or the broker was away."""
        self.thinned = 0
        """Records not sent by ``rate_hz`` (by design: no loss)."""
        self.error: str | None = None
        """Why it is not connected (the last refusal or failure), None once it is."""
        self._answered = False
        """Whether the broker answered this attempt's CONNECT (a CONNACK, even a
        refusal): a connection closed before that is a handshake that failed."""
        self.client = self._client()
        cleartext = config.cleartext()
        if cleartext:
            log.warning("%s", cleartext)
        self._drainer = threading.Thread(target=self._drain, name="gx2-mqtt", daemon=True)

    def _client(self) -> Client:
        config = self.config
        client = GuardedClient(CallbackAPIVersion.VERSION2,
                               client_id=config.client_id or f"gx2-gateway-{config.name}",
                               failed=self._connecting_failed, stopping=self._closing)
        if config.username is not None:
            client.username_pw_set(config.username, config.password)
        if urlsplit(config.url).scheme == "mqtts":
            client.tls_set(ca_certs=config.tls_ca, certfile=config.tls_cert,
                           keyfile=config.tls_key, cert_reqs=ssl.CERT_REQUIRED)
        client.will_set(f"{self.base}/availability", "offline", qos=WILL_QOS, retain=True)
        client.reconnect_delay_set(*RECONNECT_S)
        client.on_pre_connect = self._on_pre_connect
        client.on_connect = self._on_connect
        client.on_connect_fail = self._on_connect_fail
        client.on_disconnect = self._on_disconnect
        client.on_message = self._on_message
        return client

    # -- the loop's side ----------------------------------------------------------------

    def take(self, message: Message) -> None:
        """A published message: queued if due, dropped and counted if the queue is full."""
        target = self._every.get(message.topic)
        if target is None:
            target = self._every[message.topic] = self._target(message.topic)
        name, every_s = target
        if not name:
            return
        if every_s is not None and not self._sampler.due(message.topic, every_s,
                                                         message.payload):
            self.thinned += 1
            return
        self._put(name, message, message.topic == STATUS_TOPIC)

    def _put(self, topic: str, message: Message | bytes, retain: bool) -> None:
        if len(self._queue) >= self.config.queue:
            self.dropped["queue"] += 1
            return
        self._queue.append((topic, message, retain))
        if not self._wake.is_set():
            self._wake.set()

    def _target(self, topic: bytes) -> tuple[str, float | None]:
        """The MQTT topic of a gateway topic and its least interval ("" for none)."""
        if topic == STATUS_TOPIC:
            return f"{self.base}/status", None
        if topic == MARK_TOPIC:
            return f"{self.base}/mark", None
        found = parse(topic.decode())
        if found is None:
            return "", None
        node, record = found
        return f"{self.base}/{node}/{record}", self.config.every_s(record)

    def report(self, status: Mapping[str, Any]) -> None:
        """Each node's availability, said (retained) when it changes; a node a reload
        removed is said ``offline`` once, and forgotten; a node's sensors announced to
        Home Assistant when it first appears and whenever its name changes."""
        reported: set[int] = set()
        for node in status.get("nodes") or ():
            address, state = as_map(node).get("node"), as_map(node).get("state")
            if not isinstance(address, int):
                continue
            reported.add(address)
            name = as_map(node).get("name")
            name = name if isinstance(name, str) else None
            if address not in self._names or self._names[address] != name:
                # (a node first seen, or named or renamed by a reload: announced again;
                # while not connected, by the connection, which announces every node:
                # queued here too, the announcements were sent twice when it came
                # within a batch)
                self._names[address] = name
                if self.connected:
                    self._announce(address)
            self._say(address, "offline" if state in OFFLINE_STATES else "online")
        for address in set(self._availability) - reported:
            self._say(address, "offline")
            del self._availability[address]
            self._announce(address, removed=True)
            self._names.pop(address, None)

    def _announce(self, address: int, removed: bool = False) -> None:
        """A node's sensors to Home Assistant's discovery (an empty config: removed)."""
        if self._discovery is not None:
            for topic, config in discovery(self._discovery, self.base, self.config.name,
                                           address, self._names.get(address)):
                self._put(topic, b"" if removed else config, True)

    def _say(self, address: int, said: str) -> None:
        if self._availability.get(address) != said:
            self._availability[address] = said
            self._put(f"{self.base}/{address}/availability", said.encode(), True)

    def status(self) -> dict[str, Any]:
        return {"url": self.url, "topic": self.base, "connected": self.connected,
                "connects": self.connects, "error": self.error, "sent": self.sent,
                "dropped": dict(self.dropped), "thinned": self.thinned,
                "queued": len(self._queue)}

    # -- its threads ----------------------------------------------------------------------

    def start(self) -> None:
        self.client.connect_async(self._host, self._port, keepalive=KEEPALIVE_S)
        self.client.loop_start()
        self._drainer.start()

    def _drain(self) -> None:
        """:meth:`_drain_batches` until closed; what raises in it is contained by the
        guard, and it goes on (a message dropped, never the thread)."""
        while not self._closing.is_set():
            try:
                self._drain_batches()
            except Exception as error:  # (a bug, contained)
                self.dropped["offline"] += 1
                self._guard.failed("failed to hand a message to paho", error)

    def _drain_batches(self) -> None:
        """Hand the queue to paho while connected, drop it (counted) while not: woken
        by the first message after a pause, it lets BATCH_S of them gather, so that it
        and paho's thread wake some 20 times a second under a stream, not once a
        record. While paho has not written the last batch (a slow broker), it waits."""
        queue, client = self._queue, self.client
        while not self._closing.is_set():
            self._wake.wait(0.5)
            self._closing.wait(BATCH_S)
            self._wake.clear()
            if self.connected and client.want_write():
                continue  # (the last batch is still being written: the queue fills)
            for _ in range(len(queue)):
                topic, message, retain = queue.popleft()
                if not self.connected:
                    self.dropped["offline"] += 1
                    continue
                payload = message.json() if isinstance(message, Message) else message
                qos = WILL_QOS if retain and not topic.endswith("/status") else 0
                if client.publish(topic, payload, qos=qos, retain=retain).rc \
                        == MQTTErrorCode.MQTT_ERR_SUCCESS:
                    self.sent += 1
                else:
                    self.dropped["offline"] += 1

    def _connecting_failed(self, error: Exception) -> None:
        """paho's connecting raised what it does not handle itself (not an OSError):
        the reason in ``error``, counted and said once by the guard (not again by
        :meth:`_failed`: one line)."""
        self.connected = False
        self.error = f"cannot connect to {self._host}:{self._port}: " \
                     f"{type(error).__name__}: {error}"
        self._guard.failed(f"failed in paho's thread connecting to {self._host}:"
                           f"{self._port} (retried with paho's backoff)", error)

    @guarded
    def _on_pre_connect(self, client: Client, userdata: Any) -> None:
        self._answered = False

    @guarded
    def _on_connect(self, client: Client, userdata: Any, flags: Any, reason: Any,
                    properties: Any) -> None:
        self._answered = True
        if reason.is_failure:
            self._failed(f"the broker refused the connection: {reason}")
            return
        log.info("MQTT: connected to %s, publishing under %s/", self.url, self.base)
        self.connected, self.error = True, None
        self.connects += 1
        client.publish(f"{self.base}/availability", "online", qos=WILL_QOS, retain=True)
        for node, said in list(self._availability.items()):
            client.publish(f"{self.base}/{node}/availability", said, qos=WILL_QOS,
                           retain=True)
        if self._discovery is not None:
            client.subscribe(f"{self._discovery}/status")
            for node in list(self._names):
                self._announce(node)
        self._wake.set()

    @guarded
    def _on_message(self, client: Client, userdata: Any, message: Any) -> None:
        """Home Assistant's status: ``online`` when it (re)starts: announce again."""
        if message.payload == b"online":
            for node in list(self._names):
                self._announce(node)

    @guarded
    def _on_connect_fail(self, client: Client, userdata: Any) -> None:
        # paho calls this inside its ``except OSError``: the error is the one handled
        error = sys.exc_info()[1]
        why = (getattr(error, "reason", None) or getattr(error, "strerror", None)
               or str(error)) if error is not None else "no reason given"
        self._failed(f"cannot connect to {self._host}:{self._port}: {why}")

    @guarded
    def _on_disconnect(self, client: Client, userdata: Any, flags: Any, reason: Any,
                       properties: Any) -> None:
        was = self.connected
        self.connected = False
        if self._closing.is_set() or (self._answered and not was):
            return  # (a refusal: said by _on_connect)
        if was:
            self._failed(f"disconnected: {reason}")
        elif getattr(reason, "getName", lambda: "")() == "Keep alive timeout":
            self._failed(f"no CONNACK within {self.client.keepalive} s: is it an MQTT "
                         "broker?")
        else:  # (accepted, then closed before the broker's answer)
            self._failed(HANDSHAKE_CLOSED)

    def _failed(self, why: str) -> None:
        """Said once a WARN, each time the reason changes; retried by paho's backoff."""
        self.connected = False
        if why != self.error:
            log.warning("MQTT %s: %s (retrying from %d s to %d s apart; records meanwhile "
                        "are dropped and counted)", self.url, why, *RECONNECT_S)
        self.error = why

    def close(self, seconds: float) -> None:
        """Say the gateway and its nodes are offline (a clean exit sends no will), then
        disconnect, within ``seconds``."""
        self._closing.set()
        self._wake.set()
        if self.connected:
            for node in list(self._availability):  # (the loop may still report)
                self.client.publish(f"{self.base}/{node}/availability", "offline",
                                    qos=WILL_QOS, retain=True)
            said = self.client.publish(f"{self.base}/availability", "offline",
                                       qos=WILL_QOS, retain=True)
            with contextlib.suppress(RuntimeError, ValueError):  # (the connection went)
                said.wait_for_publish(max(0.0, seconds / 2))
        self.client.disconnect()
        stopping = threading.Thread(target=self.client.loop_stop, daemon=True,
                                    name="gx2-mqtt-stop")
        stopping.start()
        stopping.join(max(0.0, seconds / 2))


def make(needs: Needs) -> MqttOutput:
    assert needs.config.mqtt is not None
    return MqttOutput(needs.config.mqtt, needs.guard.of("mqtt"))

