"""The control server on a real ROUTER (inproc), in front of the operations on gx2-sim's
base station in memory: one answer per request, malformed input answered, a repeated
id run once, and a request answered before its own timeout runs out."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Callable
from typing import Any

import msgpack
import pytest
import zmq
import zmq.asyncio

from gateway.daemon.control import ControlServer, answer_within
from gateway.daemon.station import scheduler as scheduling
from gateway.sim.base_station import RadioLink
from gateway.sim.node import NodeSettings
from tests.helpers.wired import Wired


async def serving(wired: Wired, body: Callable[[zmq.asyncio.Socket], Awaitable[Any]]) -> Any:
    context = zmq.asyncio.Context()
    endpoint = f"inproc://control-{id(wired)}"
    server = ControlServer(context, endpoint, wired.ops)
    task = asyncio.get_running_loop().create_task(server.serve())
    client = context.socket(zmq.DEALER)
    client.connect(endpoint)
    try:
        return await body(client)
    finally:
        task.cancel()
        server.close()
        client.close(0)
        context.term()


async def answer(client: zmq.asyncio.Socket, within: float = 5.0) -> dict[str, Any]:
    frames = await asyncio.wait_for(client.recv_multipart(), within)
    return msgpack.unpackb(frames[-1])


def run(scenario: Callable[[], Awaitable[Any]]) -> Any:
    return asyncio.run(asyncio.wait_for(scenario(), 30))


@pytest.mark.parametrize(("payload", "says"), [
    (b"\xc1", "not a msgpack message"),
    (msgpack.packb([1, 2]), "a request is a map"),
    (msgpack.packb({"id": 1, "op": "launch"}), "op: must be one of"),
    (msgpack.packb({"id": 1, "op": "poll", "node": 76}), "record: required field"),
    (msgpack.packb({"id": 1, "op": "poll", "node": 76, "record": "euler", "x": 1}),
     "x: unknown field"),
    (msgpack.packb({"id": 1, "op": "poll", "node": True, "record": "euler"}), "node:"),
    (msgpack.packb({"id": 1, "op": "ping", "nodes": [76], "timeout": -1}), "timeout:"),
])
def test_a_malformed_request_is_answered_invalid(payload: bytes, says: str) -> None:
    async def scenario() -> None:
        async with Wired([NodeSettings(76)], [{"address": 76}]) as wired:
            async def body(client: zmq.asyncio.Socket) -> None:
                await client.send_multipart([b"", payload])
                reply = await answer(client)
                assert reply["ok"] is False and reply["error"]["kind"] == "invalid"
                assert says in reply["error"]["message"], reply
            await serving(wired, body)
    run(scenario)


def test_a_repeated_id_is_run_once() -> None:
    async def scenario() -> None:
        async with Wired([NodeSettings(76)], [{"address": 76}]) as wired:
            async def body(client: zmq.asyncio.Socket) -> None:
                request = msgpack.packb({"id": "p", "op": "poll", "node": 76,
                                         "record": "euler"})
                await client.send_multipart([b"", request])
                await client.send_multipart([b"", request])
                first, second = await answer(client), await answer(client)
                assert first == second and first["ok"], first
                assert len([c for c in wired.node(76).log.commands if c.code == 0xCE]) == 1
            await serving(wired, body)
    run(scenario)


@pytest.mark.parametrize(("timeout", "within"), [(5.0, 4.5), (1.0, 0.9), (0.2, 0.1)])
def test_answer_within_leaves_room_to_cross_the_network(timeout: float,
                                                         within: float) -> None:
    assert answer_within(timeout) == pytest.approx(within)


def test_a_request_is_answered_before_its_timeout(monkeypatch) -> None:
    monkeypatch.setattr(scheduling, "REPLY_TIMEOUT", 2.0)  # one attempt outlasts it

    async def scenario() -> None:
        async with Wired([NodeSettings(95)], [{"address": 95}],
                         radio={95: RadioLink(in_range=False)}) as wired:
            async def body(client: zmq.asyncio.Socket) -> None:
                start = time.monotonic()
                await client.send_multipart([b"", msgpack.packb(
                    {"id": 7, "op": "eeprom_read", "node": 95, "address": 1,
                     "timeout": 1.0})])
                reply = await answer(client)
                took = time.monotonic() - start
                assert reply["ok"] is False and reply["error"]["kind"] == "node", reply
                assert "node 95" in reply["error"]["message"]
                assert answer_within(1.0) <= took < 1.0, took
            await serving(wired, body)
    run(scenario)


def test_a_client_cancels_its_own_request_and_no_other() -> None:
    """Issue 31, defect 11: the op ``cancel``; the request it cancels is answered
    ``cancelled``, the cancel with what stays."""
    async def scenario() -> None:
        async with Wired([NodeSettings(95)], [{"address": 95}],
                         radio={95: RadioLink(in_range=False)}) as wired:
            async def body(client: zmq.asyncio.Socket) -> None:
                other = client.context.socket(zmq.DEALER)  # another client
                other.connect(f"inproc://control-{id(wired)}")
                try:
                    await client.send_multipart([b"", msgpack.packb(
                        {"id": "r", "op": "eeprom_read", "node": 95, "address": 1})])
                    await other.send_multipart([b"", msgpack.packb(
                        {"id": "c", "op": "cancel", "request": "r"})])
                    refused = await answer(other)
                    assert refused["result"] == {
                        "request": "r", "cancelled": False,
                        "message": "no request 'r' of this client is running"}, refused
                finally:
                    other.close(0)
                await client.send_multipart([b"", msgpack.packb(
                    {"id": "c", "op": "cancel", "request": "r", "timeout": 2.0})])
                replies = {reply["id"]: reply for reply in
                           [await answer(client), await answer(client)]}
                assert replies["r"]["error"] == {
                    "kind": "cancelled", "message": "eeprom read on 95 cancelled by the "
                    "client"}, replies
                assert replies["c"]["result"] == {
                    "request": "r", "cancelled": True,
                    "message": "eeprom read on 95 cancelled by the client"}, replies
                await client.send_multipart([b"", msgpack.packb(
                    {"id": "c2", "op": "cancel", "request": "r"})])
                again = await answer(client)
                assert again["result"]["cancelled"] is True, again  # (what it did stands)
            await serving(wired, body)
    run(scenario)
