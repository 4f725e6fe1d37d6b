"""The MQTT output's own choices, without a broker: what rate_hz lets through, a
queue that stays bounded (dropped and counted) when nothing drains it, Home
Assistant's names, paho's thread kept alive, a password in the clear said."""

from __future__ import annotations

import itertools
import json
import logging
import math
import random
import socket
import threading
from types import SimpleNamespace
from typing import Any

import pytest

from gateway.common.topics import STATUS_TOPIC, topic
from gateway.daemon.config import MqttConfig
from gateway.daemon.outputs import Message, mqtt
from gateway.daemon.outputs.guard import Guard
from gateway.daemon.outputs.homeassistant import discovery
from gateway.daemon.outputs.mqtt import MqttOutput
from gateway.daemon.outputs.sampler import Sampler
from tests.helpers.waiting import wait_for


def test_rate_hz_takes_every_nth_sample_by_sample_time_whatever_the_arrival() -> None:
    sampler = Sampler()
    start = 1_700_000_000.0
    taken = [seq for seq in range(1000)
             if sampler.due(b"t", 0.1, {"time": start + seq * 0.01,
                                        # arrivals in bursts, as a busy line delivers
                                        "host_time": start + (seq // 7) * 0.07 + 0.05})]
    assert taken == list(range(0, 1000, 10))


def test_a_node_whose_time_goes_back_is_sent_at_once() -> None:
    sampler = Sampler()
    assert sampler.due(b"t", 1.0, {"time": 100.0})
    assert not sampler.due(b"t", 1.0, {"time": 100.5})
    assert sampler.due(b"t", 1.0, {"time": 3.0})  # (a reboot: a new estimate)


def test_the_queue_is_bounded_and_what_does_not_fit_is_counted() -> None:
    output = MqttOutput(MqttConfig(url="mqtt://127.0.0.1:1", name="t", queue=100))
    for seq in range(150):  # never started: nothing drains it
        output.take(Message(topic(76, "accel_angrate"), {"seq": seq, "time": float(seq)}))
    output.take(Message(STATUS_TOPIC, {"gateway": {}}))
    said = output.status()
    assert said["queued"] == 100 and said["dropped"] == {"queue": 51, "offline": 0}, said
    assert said["connected"] is False and said["sent"] == 0


def test_topics_are_under_the_prefix_and_name() -> None:
    output = MqttOutput(MqttConfig(url="mqtts://broker.example", prefix="site/a", name="gw1",
                                   rate_hz={"euler": 5}))
    assert output._target(topic(76, "accel_angrate")) == ("site/a/gw1/76/accel_angrate",
                                                          None)
    assert output._target(topic(77, "euler")) == ("site/a/gw1/77/euler", 0.2)
    assert output._target(STATUS_TOPIC) == ("site/a/gw1/status", None)
    assert output._port == 8883


def test_availability_is_said_on_change_and_offline_for_a_node_removed() -> None:
    output = MqttOutput(MqttConfig(url="mqtt://127.0.0.1:1", name="gw"))
    output.report({"nodes": [{"node": 76, "state": "streaming"},
                             {"node": 77, "state": "unreachable"}]})
    output.report({"nodes": [{"node": 76, "state": "streaming"},
                             {"node": 77, "state": "unreachable"}]})  # (no change)
    output.report({"nodes": [{"node": 77, "state": "polled"}]})  # 76 removed by a reload
    said = [(topic, payload) for topic, payload, retain in output._queue if retain]
    assert said == [("gx2/gw/76/availability", b"online"),
                    ("gx2/gw/77/availability", b"offline"),
                    ("gx2/gw/77/availability", b"online"),
                    ("gx2/gw/76/availability", b"offline")]


class Broker:
    """What paho's client is to the output's _on_connect: what it publishes, kept."""

    def __init__(self) -> None:
        self.published: list[tuple[str, bytes, bool]] = []

    def publish(self, topic: str, payload: Any, qos: int = 0, retain: bool = False) -> None:
        self.published.append((topic, payload.encode() if isinstance(payload, str)
                                else payload, retain))

    def subscribe(self, *args: Any, **kwargs: Any) -> None:
        pass


def connected(output: MqttOutput) -> list[tuple[str, bytes, bool]]:
    """What a connection of ``output`` sends: published at once, and queued (the
    discovery announcements) for the drainer."""
    output._queue.clear()
    broker = Broker()
    output._on_connect(broker, None, None, SimpleNamespace(is_failure=False), None)
    return [*broker.published, *output._queue]


def test_a_node_removed_while_the_broker_is_away_is_removed_on_connect() -> None:
    """A reload removes node 77 while the broker is away: its removal (``offline``, an
    empty discovery config for each sensor), queued and dropped as offline, is sent by
    the next connection, once; Home Assistant kept a ghost of the node (issue 43
    review). A node removed and added again before the connection is not removed."""
    output = MqttOutput(MqttConfig(url="mqtt://127.0.0.1:1", name="gw", homeassistant=True))
    output.connected = True
    output.report({"nodes": [{"node": 76, "state": "streaming"},
                             {"node": 77, "state": "streaming"},
                             {"node": 78, "state": "streaming"}]})
    output.connected = False  # the broker goes away
    output.report({"nodes": [{"node": 76, "state": "streaming"}]})  # a reload: 77, 78 go
    output.report({"nodes": [{"node": 76, "state": "streaming"},
                             {"node": 78, "state": "streaming"}]})  # 78 back
    configs = [t for t, _ in discovery("homeassistant", "gx2/gw", "gw", 77, None)]
    sent = connected(output)  # (what was queued meanwhile: dropped, offline)
    about = [(t, payload) for t, payload, retain in sent if "77" in t and retain]
    assert about == [("gx2/gw/77/availability", b"offline"),
                     *((topic, b"") for topic in configs)], about
    assert {t for t, payload, _ in sent if payload and t.endswith("/config")} == {
        t for node in (76, 78) for t, _ in discovery("homeassistant", "gx2/gw", "gw", node,
                                                     None)}
    assert ("gx2/gw/78/availability", b"online", True) in sent
    assert not [t for t, _, _ in connected(output) if "77" in t]  # (said once)


def test_a_listener_that_never_answers_the_connect_is_said_once(monkeypatch, caplog) -> None:
    """A port that accepts TCP and never sends CONNACK: paho gives up after the
    keepalive (1 s here), and the output says so."""
    monkeypatch.setattr(mqtt, "KEEPALIVE_S", 1)
    monkeypatch.setattr(mqtt, "RECONNECT_S", (1, 1))
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen(8)
        output = MqttOutput(MqttConfig(url=f"mqtt://127.0.0.1:{server.getsockname()[1]}",
                                       name="gw"))
        with caplog.at_level(logging.WARNING, "gx2.mqtt"):
            output.start()
            try:
                error = wait_for(lambda: output.status()["error"], 10, "the reason")
                wait_for(lambda: output.connects == 0 and len(caplog.records) >= 1, 5,
                         "the warning")
            finally:
                output.close(2)
    assert error.startswith("no CONNACK within 1 s"), error
    assert [r.getMessage() for r in caplog.records if "CONNACK" in r.getMessage()] \
        and len(caplog.records) == 1


def test_the_urls_scheme_is_case_insensitive() -> None:
    config = MqttConfig(url="MQTTS://Broker.example:8884", name="gw")
    assert config.url == "mqtts://Broker.example:8884"
    assert MqttOutput(config).client._ssl  # (TLS, as for mqtts://)


@pytest.mark.parametrize("rate_hz", [1, 2, 5, 10, 3, 7])
def test_rate_hz_is_never_exceeded_and_spaces_the_samples_evenly(rate_hz: float) -> None:
    """A synthetic 100 Hz stream, its sample instants jittered by up to 0.2 ms, for a
    minute: at most ``rate_hz`` records a second go out, over the minute and over any
    second of it; each is the sample nearest its deadline, the deadlines a whole
    period apart (1, 2, 5 and 10 Hz: every 100th, 50th, 20th, 10th sample exactly; 3
    and 7 Hz: 33 or 34, 14 or 15 samples apart)."""
    jitter = random.Random(rate_hz)
    start, seconds = 1_700_000_000.0, 60
    sampler = Sampler()
    sent = [seq for seq in range(100 * seconds) if sampler.due(
        b"t", 1.0 / rate_hz, {"time": start + seq / 100 + jitter.uniform(-2e-4, 2e-4)})]
    assert rate_hz * seconds <= len(sent) <= rate_hz * seconds + 1
    for first in range(0, 100 * seconds - 100, 7):  # every second's window (of samples)
        assert sum(first <= seq < first + 100 for seq in sent) <= rate_hz + 1
    assert (len(sent) - 1) / ((sent[-1] - sent[0]) / 100) <= rate_hz
    steps = {b - a for a, b in itertools.pairwise(sent)}
    period = 100 / rate_hz
    assert steps <= {math.floor(period), math.ceil(period)}, steps


def test_home_assistant_hears_a_name_a_reload_gives_and_changes() -> None:
    """Discovery announces a node's device name when it first appears and again
    whenever a report says another (a reload named or renamed it), never otherwise."""
    output = MqttOutput(MqttConfig(url="mqtt://127.0.0.1:1", name="gw", homeassistant=True))
    output.connected = True  # (while not, the connection announces every node)

    def announced() -> list[str]:
        names = [json.loads(payload)["device"]["name"] for topic, payload, _ in output._queue
                 if topic.endswith("/config") and payload]
        output._queue.clear()
        return sorted(set(names))
    output.report({"nodes": [{"node": 76, "state": "streaming", "name": None}]})
    assert announced() == ["GX2 node 76"]
    output.report({"nodes": [{"node": 76, "state": "streaming", "name": None}]})
    assert announced() == []
    output.report({"nodes": [{"node": 76, "state": "streaming", "name": "left-wing"},
                             {"node": 77, "state": "streaming", "name": "tail"}]})
    assert announced() == ["GX2 node 76 (left-wing)", "GX2 node 77 (tail)"]
    output.report({"nodes": [{"node": 76, "state": "streaming", "name": "right-wing"},
                             {"node": 77, "state": "streaming", "name": "tail"}]})
    assert announced() == ["GX2 node 76 (right-wing)"]


def test_what_raises_in_paho_s_thread_is_said_once_and_it_goes_on_retrying(
        monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture) -> None:
    """A host the resolver refuses raises UnicodeError (a ValueError) where paho
    connects, which paho does not catch: its network thread died of it, unseen (mqtt.error
    null, every record "broker away"). Contained: the reason in status, counted by the
    outputs' guard, said once, and paho's thread still there, trying again."""
    monkeypatch.setattr(mqtt, "RECONNECT_S", (1, 1))
    tries = []

    def refused(address: Any, *args: Any, **kwargs: Any) -> Any:
        tries.append(address)
        raise UnicodeError("encoding with 'idna' codec failed (UnicodeError: label empty "
                           "or too long)")
    monkeypatch.setattr(socket, "create_connection", refused)
    guard = Guard()
    output = MqttOutput(MqttConfig(url="mqtt://127.0.0.1:1", name="gw"), guard.of("mqtt"))
    with caplog.at_level(logging.WARNING):
        output.start()
        try:
            error = wait_for(lambda: output.status()["error"], 10, "the reason")
            wait_for(lambda: len(tries) >= 3, 10, "paho trying again")
            alive = [t.name for t in threading.enumerate() if t.name.startswith("paho")]
        finally:
            output.close(2)
    assert "UnicodeError" in error and "label empty" in error, error
    assert alive, "paho's thread died"
    assert guard.failures["mqtt"] >= 3
    said = [r.getMessage() for r in caplog.records if "UnicodeError" in r.getMessage()]
    assert len(said) == 1 and said[0].startswith("output mqtt failed in paho's thread"), said


def test_a_password_sent_in_the_clear_to_another_host_is_said_at_start(
        caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING, "gx2.mqtt"):
        MqttOutput(MqttConfig(url="mqtt://broker.example:1883", name="gw", username="lab",
                              password="S3cretPassw0rd"))
        MqttOutput(MqttConfig(url="mqtts://broker.example", name="gw", username="lab",
                              password="S3cretPassw0rd"))
        MqttOutput(MqttConfig(url="mqtt://127.0.0.1", name="gw", username="lab",
                              password="S3cretPassw0rd"))
    said = [r.getMessage() for r in caplog.records]
    assert len(said) == 1 and "unencrypted" in said[0] and "broker.example" in said[0]
    assert "S3cretPassw0rd" not in caplog.text
