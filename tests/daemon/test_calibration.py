"""The built-in test and the bias capture over gx2-sim's base station in memory: what
happens when the node stops answering in the middle."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from typing import Any

import pytest

from gateway.daemon import calibration
from gateway.daemon.errors import NodeError
from gateway.daemon.station import scheduler as scheduling
from gateway.sim.base_station import RadioLink
from gateway.sim.node import NodeSettings
from gateway.sim.physics import Motion
from tests.helpers.waiting import wait_for_async
from tests.helpers.wired import Wired


@pytest.fixture(autouse=True)
def quick(monkeypatch):
    monkeypatch.setattr(scheduling, "REPLY_TIMEOUT", 0.1)
    monkeypatch.setattr(calibration, "BIT_OFF_BACKOFF", (0.1,))


def run(scenario: Callable[[], Awaitable[Any]]) -> Any:
    return asyncio.run(asyncio.wait_for(scenario(), 30))


def test_bit_is_switched_off_once_a_node_that_went_away_answers_again() -> None:
    async def scenario() -> None:
        radio = {76: RadioLink()}
        async with Wired([NodeSettings(76, motion=Motion(yaw_rate=0.0))],
                         [{"address": 76}], radio=radio) as gw:
            node = gw.node(76)
            execute = node.execute

            def then_gone(command, t):  # out of range as soon as BIT is on
                reply = execute(command, t)
                if command.code == 0xFB and command.arguments["test_config"]:
                    radio[76].in_range = False
                return reply
            node.execute = then_gone
            with pytest.raises(NodeError, match="node 76"):
                await gw.run("selftest", node=76)
            assert node.test_config == 0x10
            radio[76].in_range = True
            await wait_for_async(lambda: node.test_config == 0, 10, "BIT to be switched off")
    run(scenario)


def test_a_capture_without_a_reply_is_not_sent_again() -> None:
    async def scenario() -> None:
        radio = {95: RadioLink(data_loss=1.0)}  # it hears, but nothing comes back
        async with Wired([NodeSettings(95)], [{"address": 95}], radio=radio) as gw:
            with pytest.raises(NodeError, match="no reply"):
                await gw.run("bias_capture", node=95, ms=100)
            assert [c.code for c in gw.node(95).log.commands].count(0xCD) == 1
    run(scenario)
