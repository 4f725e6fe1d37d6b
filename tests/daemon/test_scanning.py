"""The scan op against gx2-sim's base station in memory (tests/helpers/wired.py): a node
the gateway does not know is read through its replies (never written), the scan takes
turns with other commands, a request scans what fits its time, and the address ranges
read as documented."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Callable
from typing import Any

import pytest

from gateway.common.values import ADDRESS_RANGES, ranges_text
from gateway.daemon.errors import Invalid, LinkDown
from gateway.sim.base_station import RadioLink
from gateway.sim.node import NodeSettings
from tests.helpers.wired import Wired


def run(scenario: Callable[[], Awaitable[Any]]) -> Any:
    return asyncio.run(asyncio.wait_for(scenario(), 60))


def test_a_node_not_configured_is_read_through_its_replies_and_never_written() -> None:
    async def scenario() -> None:
        async with Wired([NodeSettings(81, stream="euler", divider=1024)], []) as gw:
            result = await gw.run("scan", addresses="80-82", timeout=5.0)
            assert result["scanned"] == 3 and result["stations"] == ["station1"]
            [entry] = result["found"]
            assert entry["address"] == 81 and entry["configured"] is False
            assert (entry["divider"], entry["rate_hz"], entry["auto_start"],
                    entry["streaming"]) == (1024, 50.0, "euler", "euler")
            assert entry["serial_number"] == "4200-0081"
            assert entry["unanswered"] is None
            assert entry["lqi"] is not None and entry["rssi"] is not None
            codes = {c.code for c in gw.node(81).log.commands}
            assert codes == {0xE5, 0xE9, 0xEA}  # reads only
            assert gw.node(81).continuous == 0xCE  # still streaming as it was
            assert gw.reader.listeners == {}  # nothing left listening
    run(scenario)


def test_a_node_that_answers_pings_but_not_commands_is_reported_with_what_failed() -> None:
    async def scenario() -> None:
        async with Wired([NodeSettings(81)], [],
                         radio={81: RadioLink(command_loss=1.0)}) as gw:
            result = await gw.run("scan", addresses="81", timeout=30.0)
            [entry] = result["found"]
            assert entry["firmware"] is None and entry["lqi"] is None
            assert "no reply from the node" in entry["unanswered"]
    run(scenario)


def test_the_scan_takes_turns_with_other_commands() -> None:
    """A poll sent while a long scan runs is answered within a few pings, not after
    the scan."""
    async def scenario() -> None:
        async with Wired([NodeSettings(76)], [{"address": 76}]) as gw:
            scan = asyncio.ensure_future(gw.run("scan", addresses="100-300", timeout=60.0))
            while gw.station.stats.pings < 10:
                await asyncio.sleep(0.01)
            start = time.monotonic()
            polled = await gw.run("poll", node=76, record="euler")
            took = time.monotonic() - start
            assert polled["record"] == "euler"
            assert not scan.done()
            assert took < 0.5, took  # a ping of an absent address is 30 ms on gx2-sim
            scan.cancel()
            await asyncio.wait([scan])
    run(scenario)


def test_a_configured_node_that_reboots_during_a_scan_is_armed_again_meanwhile() -> None:
    """The supervisor's own commands (background work) take turns with the scan's
    pings: a node that lost its stream gets it back while the scan goes on."""
    async def scenario() -> None:
        async with Wired([NodeSettings(76)], [{"address": 76, "stream": "euler"}]) as gw:
            while gw.nodes[76].state.value != "streaming":
                await asyncio.sleep(0.01)
            scan = asyncio.ensure_future(gw.run("scan", addresses="100-400", timeout=60.0))
            while gw.station.stats.pings < 10:
                await asyncio.sleep(0.01)
            gw.station.reboot(76, time.monotonic())  # its stream is gone
            while gw.node(76).continuous:
                await asyncio.sleep(0.01)
            start = time.monotonic()
            while gw.node(76).continuous != 0xCE:
                assert time.monotonic() - start < 2.0, "76 not armed again during the scan"
                await asyncio.sleep(0.01)
            assert not scan.done()
            scan.cancel()
            await asyncio.wait([scan])
    run(scenario)


def test_a_request_scans_what_fits_in_its_time_and_says_how_many() -> None:
    async def scenario() -> None:
        async with Wired([NodeSettings(1)], []) as gw:
            start = time.monotonic()
            result = await gw.run("scan", addresses="1-100", timeout=1.5)
            assert time.monotonic() - start < 1.35  # answered within its time
            assert 1 <= result["scanned"] < 100
            assert [e["address"] for e in result["found"]] == [1]
            rest = await gw.run("scan", addresses=ranges_text(range(result["scanned"] + 1,
                                                                     101)), timeout=30.0)
            assert result["scanned"] + rest["scanned"] == 100
    run(scenario)


def test_a_station_down_or_unknown_is_refused() -> None:
    async def scenario() -> None:
        async with Wired([NodeSettings(3)], []) as gw:
            with pytest.raises(Invalid, match="no base station is named 'north'"):
                await gw.run("scan", station="north", addresses="1-3")
            gw.link(False)
            with pytest.raises(LinkDown, match="station1 is down"):
                await gw.run("scan", addresses="1-3")
    run(scenario)


@pytest.mark.parametrize(("text", "addresses"), [
    ("1-5", (1, 2, 3, 4, 5)), ("7", (7,)), (" 3 , 1-2 ", (1, 2, 3)),
    ("1-3,2-4", (1, 2, 3, 4)), ("0x10-0x11,65534", (16, 17, 65534))])
def test_ranges_read_into_every_address_once_ascending(text: str,
                                                       addresses: tuple[int, ...]) -> None:
    assert ADDRESS_RANGES.from_text(text) == addresses
    assert ADDRESS_RANGES.from_text(ranges_text(addresses)) == addresses


def test_ranges_text_joins_runs() -> None:
    assert ranges_text([5, 1, 2, 3, 7, 8, 10]) == "1-3,5,7-8,10"
    assert ranges_text([]) == ""
