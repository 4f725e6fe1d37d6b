"""The fan-out: each message made once into what every output shares (its JSON made
once, by the first that asks), outputs that read only status reports never on the
per-record path, and every output closed at once against one deadline."""

from __future__ import annotations

import asyncio
import json
import math
import threading
import time
from typing import Any

import pytest
from jsonschema import Draft202012Validator

from gateway.common import jsontext
from gateway.common.jsontext import compact, compact_bytes
from gateway.common.protocol import HealthLevel
from gateway.common.schemas import status_schema
from gateway.daemon import outputs as outputs_module
from gateway.daemon.config import HealthConfig
from gateway.daemon.health import Health
from gateway.daemon.outputs import Message, Output, Outputs
from gateway.daemon.outputs import message as message_module
from gateway.daemon.outputs.metrics import StatusCollector


class Publication(Output):
    def __init__(self) -> None:
        self.sent: list[tuple[bytes, dict[str, Any]]] = []

    def send(self, topic: bytes, payload: dict[str, Any]) -> bool:
        self.sent.append((topic, payload))
        return True


class Writes(Output):
    def __init__(self) -> None:
        self.data: list[bytes] = []
        self.messages: list[Message] = []

    def take(self, message: Message) -> None:
        self.messages.append(message)
        self.data.append(message.json())


class Reports(Output):
    takes_messages = False

    def __init__(self) -> None:
        self.reports: list[Any] = []

    def take(self, message: Message) -> None:
        raise AssertionError("a status reader given a record")

    def report(self, status: Any) -> None:
        self.reports.append(status)


def test_each_message_is_one_for_every_output_and_its_json_made_once(
        monkeypatch: pytest.MonkeyPatch) -> None:
    made = []
    monkeypatch.setattr(message_module, "compact_bytes",
                        lambda payload: made.append(payload) or compact_bytes(payload))
    first, second, reports = Writes(), Writes(), Reports()
    fan = Outputs({"zeromq": Publication(), "a": first, "b": second, "metrics": reports})
    payload = {"node": 76, "seq": 1, "roll": 0.5, "mag": [math.nan, 1e-05, 1e16]}
    assert fan.publish(76, "euler", payload)
    fan.report({"gateway": {}})
    assert first.messages[0] is second.messages[0]
    assert made == [payload]  # (once, for both)
    assert first.data == second.data
    assert json.loads(first.data[0]) == json.loads(compact(payload))
    assert reports.reports == [{"gateway": {}}] and fan.published() == {76: {"euler": 1}}


def test_a_gateway_with_only_zeromq_makes_no_message(monkeypatch) -> None:
    monkeypatch.setattr(outputs_module, "Message", None)  # (called: a TypeError)
    publication = Publication()
    assert Outputs({"zeromq": publication}).publish(76, "euler", {"seq": 1})
    assert publication.sent == [(b"gx2/76/euler", {"seq": 1})]


@pytest.mark.parametrize("value", [
    {"roll": math.nan, "pitch": math.inf, "yaw": -math.inf},
    {"data": b"\x01\xff", 7: "an int key"},
    {"big": 2 ** 70, "small": 5e-324, "third": 0.1 + 0.2},
    {"z": 1, "a": [1.5, {"y": None, "b": True}], "text": "é\n\""},
])
def test_the_fast_json_reads_back_as_the_strict_json_does(value: dict[str, Any]) -> None:
    fast, strict = json.loads(compact_bytes(value)), json.loads(jsontext.compact(value))
    assert fast == strict and json.dumps(fast) == json.dumps(strict)  # (and key order)


class Closes(Output):
    def __init__(self, barrier: threading.Barrier) -> None:
        self.barrier = barrier
        self.given: float | None = None

    def close(self, seconds: float) -> None:
        self.given = seconds
        self.barrier.wait()  # (passes only once every output is closing at once)


def test_every_output_is_closed_at_once_within_one_deadline() -> None:
    barrier = threading.Barrier(3, timeout=5)
    closing = [Closes(barrier) for _ in range(3)]
    fan = Outputs({"zeromq": Publication(), **{str(i): c for i, c in enumerate(closing)}})
    asyncio.run(fan.close(time.monotonic() + 1.5))
    assert all(c.given is not None and 1.0 < c.given <= 1.5 for c in closing)


class Raises(Output):
    def take(self, message: Message) -> None:
        raise ValueError("a bug in one output")


def test_an_output_that_raises_is_counted_and_logged_once_and_the_others_get_the_message(
        caplog: pytest.LogCaptureFixture) -> None:
    publication, after = Publication(), Writes()
    raises = Raises()
    raises.name = "live"
    fan = Outputs({"zeromq": publication, "live": raises, "recording": after})
    for seq in range(3):
        assert fan.publish(76, "euler", {"seq": seq})
    assert fan.mark({"text": "a knock"})
    assert [payload for _, payload in publication.sent] == [
        {"seq": 0}, {"seq": 1}, {"seq": 2}, {"text": "a knock"}]
    assert len(after.messages) == 4
    assert fan.take_failures == {"live": 4}
    said = [r.message for r in caplog.records if "failed to take" in r.message]
    assert said == ["output live failed to take a message on gx2/76/euler: ValueError: "
                    "a bug in one output (counted; not logged again for this output "
                    "and error)"]


def test_take_failures_are_in_status_and_metrics_and_make_the_gateway_warn_for_a_window(
        ) -> None:
    """What an operator sees of an output that raised: status's ``outputs`` (valid by
    the status schema), ``gx2_output_take_failures_total`` and a WARN of the gateway's
    own while failures happened within the health window, OK again after it."""
    raises = Raises()
    raises.name = "live"
    fan = Outputs({"zeromq": Publication(), "live": raises, "recording": Writes(),
                   "metrics": Reports()})
    health = Health([], HealthConfig(window_s=10.0), take_failures=fan.take_failures)
    health.sample(100.0)
    assert health.gateway(100.0) == (HealthLevel.OK, ())
    for seq in range(3):
        fan.publish(76, "euler", {"seq": seq})
    health.sample(101.0)
    level, reasons = health.gateway(101.0)
    assert level is HealthLevel.WARN
    assert reasons == ("output live failed to take 3 messages in 1 s: a bug, contained "
                       "(the other outputs got them; the log says what)",)

    said = fan.guard_status()
    assert said == {"live": {"take_failures": 3}, "recording": {"take_failures": 0}}
    status = {"gateway": {"time": 1.7e9, "version": "0", **health.gateway_status(101.0)},
              "link": {}, "nodes": [], "recording": None, "replay": None, "outputs": said}
    Draft202012Validator(status_schema()).validate(json.loads(compact(status)))
    collector = StatusCollector()
    collector.report = status
    metrics = {(sample.name, tuple(sample.labels.items())): sample.value
               for family in collector.collect() for sample in family.samples}
    assert metrics[("gx2_output_take_failures_total", (("output", "live"),))] == 3
    assert metrics[("gx2_output_take_failures_total", (("output", "recording"),))] == 0
    assert metrics[("gx2_gateway_health", ())] == 1

    for second in range(102, 113):  # a window with no more failures
        health.sample(float(second))
    assert health.gateway(112.0) == (HealthLevel.OK, ())
