"""Each control op against gx2-sim's base station in memory (tests/helpers/wired.py):
what goes to the node, what comes back, and every refusal, in milliseconds."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from typing import Any

import pytest

from aspp.commands import EEPROM_AUTO_START, EEPROM_DIVIDER
from gateway.common import ops
from gateway.daemon.errors import Invalid, NodeError, Refused
from gateway.daemon.operations import HANDLERS
from gateway.daemon.requests import MODELS
from gateway.daemon.station import scheduler as scheduling
from gateway.sim.base_station import RadioLink
from gateway.sim.node import FIRMWARE_VERSION, NodeSettings
from tests.helpers.wired import Wired


def run(scenario: Callable[[], Awaitable[Any]]) -> Any:
    return asyncio.run(asyncio.wait_for(scenario(), 30))


def sent(gw: Wired, node: int, code: int) -> list:
    """The commands with ``code`` the simulated node received."""
    return [c for c in gw.node(node).log.commands if c.code == code]


def test_every_op_in_the_table_has_a_handler_and_a_request_model() -> None:
    assert set(HANDLERS) == set(MODELS) == set(ops.BY_NAME)


def test_poll_returns_the_published_payload() -> None:
    async def scenario() -> None:
        async with Wired([NodeSettings(76)], [{"address": 76}]) as gw:
            payload = await gw.run("poll", node=76, record="euler")
            assert payload["record"] == "euler" and payload["node"] == 76
            assert payload == gw.publisher.records(76, "euler")[-1]
            assert len(sent(gw, 76, 0xCE)) == 1
    run(scenario)


def test_info_reads_the_firmware_and_the_four_strings() -> None:
    async def scenario() -> None:
        async with Wired([NodeSettings(76, serial="0042")], [{"address": 76}]) as gw:
            info = await gw.run("info", node=76)
            assert info == {"node": 76, "firmware": FIRMWARE_VERSION,
                            "firmware_version": "2.1.13", "model_number": "6226-0001",
                            "serial_number": "0042",
                            "model_name": "Inertia-Link", "options": "Wireless"}
    run(scenario)


def test_eeprom_write_retries_a_failed_first_write_and_reads_back() -> None:
    async def scenario() -> None:
        async with Wired([NodeSettings(76)], [{"address": 76}],
                         allow_eeprom_write=True) as gw:
            gw.node(76).first_write_failure_rate = 1.0
            result = await gw.run("eeprom_write", node=76, address=EEPROM_AUTO_START,
                                  value=0x80CE)
            assert result == {"node": 76, "address": EEPROM_AUTO_START, "value": 0x80CE,
                              "attempts": 2}
            assert len(sent(gw, 76, 0xE4)) == 2 and len(sent(gw, 76, 0xE5)) == 1
            assert gw.node(76).eeprom[EEPROM_AUTO_START] == 0x80CE
    run(scenario)


@pytest.mark.parametrize(("allowed", "address", "needs"), [
    (False, EEPROM_DIVIDER, "allow_eeprom_write"),
    (True, 0x0100, "allow_any_eeprom_address"),
])
def test_eeprom_writes_are_refused_by_policy(allowed: bool, address: int, needs: str) -> None:
    async def scenario() -> None:
        async with Wired([NodeSettings(76)], [{"address": 76}],
                         allow_eeprom_write=allowed) as gw:
            with pytest.raises(Refused, match=needs):
                await gw.run("eeprom_write", node=76, address=address, value=7)
            assert sent(gw, 76, 0xE4) == []
    run(scenario)


def test_rate_writes_the_divider_and_the_node_takes_it() -> None:
    async def scenario() -> None:
        async with Wired([NodeSettings(76)], [{"address": 76}],
                         allow_eeprom_write=True) as gw:
            assert await gw.run("rate", node=76, hz=50) == {"node": 76, "hz": 50.0,
                                                            "divider": 1024}
            assert gw.nodes[76].divider == 1024 and gw.node(76).divider == 1024
    run(scenario)


def test_a_node_that_is_not_configured_is_invalid() -> None:
    async def scenario() -> None:
        async with Wired([NodeSettings(76)], [{"address": 76}]) as gw:
            with pytest.raises(Invalid, match="node 77 is not configured"):
                await gw.run("poll", node=77, record="euler")
    run(scenario)


def test_ping_reports_each_node() -> None:
    async def scenario() -> None:
        async with Wired([NodeSettings(76), NodeSettings(95)],
                         [{"address": 76}, {"address": 95}],
                         radio={95: RadioLink(in_range=False)}) as gw:
            result = await gw.run("ping", nodes=[76, 95, 300])
            assert result["nodes"] == [{"node": 76, "answered": True},
                                       {"node": 95, "answered": False},
                                       {"node": 300, "answered": False}]
    run(scenario)


def test_a_ping_with_the_base_station_down_says_so_for_each_node() -> None:
    async def scenario() -> None:
        async with Wired([NodeSettings(76)], [{"address": 76}]) as gw:
            gw.link(False)
            result = await gw.run("ping", nodes=[76, 300])
            down = "the base station is down (not connected)"
            assert result["nodes"] == [{"node": 76, "answered": False, "error": down},
                                       {"node": 300, "answered": False, "error": down}]
    run(scenario)


def test_a_node_out_of_range_fails_with_the_reason(monkeypatch) -> None:
    monkeypatch.setattr(scheduling, "REPLY_TIMEOUT", 0.1)

    async def scenario() -> None:
        async with Wired([NodeSettings(95)], [{"address": 95}],
                         radio={95: RadioLink(in_range=False)}) as gw:
            with pytest.raises(NodeError, match=r"node 95: .*no reply from the node"):
                await gw.run("eeprom_read", node=95, address=EEPROM_DIVIDER)
    run(scenario)
