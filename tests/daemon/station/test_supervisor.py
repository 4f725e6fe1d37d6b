"""The supervisor over gx2-sim's base station in memory: what a node keeps doing
(configured stream, operator intent), streams found on their own, and background work
that gives way to an operator."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Callable
from typing import Any

import pytest

from gateway.daemon.errors import LinkDown, NodeError
from gateway.daemon.station import scheduler as scheduling
from gateway.daemon.station import supervisor as supervising
from gateway.daemon.station.nodes import OFF, State
from gateway.sim.base_station import RadioLink
from gateway.sim.node import NodeSettings
from tests.helpers.waiting import wait_for_async
from tests.helpers.wired import Wired


@pytest.fixture(autouse=True)
def quick(monkeypatch):
    monkeypatch.setattr(scheduling, "REPLY_TIMEOUT", 0.1)
    monkeypatch.setattr(supervising, "BACKOFF", (0.05,))


def run(scenario: Callable[[], Awaitable[Any]]) -> Any:
    return asyncio.run(asyncio.wait_for(scenario(), 30))


def test_the_configured_stream_is_armed_at_its_rate() -> None:
    async def scenario() -> None:
        async with Wired([NodeSettings(76, divider=1024)],
                         [{"address": 76, "stream": "euler"}]) as gw:
            node = gw.nodes[76]
            await wait_for_async(lambda: node.state is State.STREAMING, 5, "streaming")
            assert (node.record, node.divider) == ("euler", 1024)
            assert gw.node(76).continuous == 0xCE
    run(scenario)


def test_a_stream_found_on_its_own_is_taken_with_the_rate_of_its_timer() -> None:
    async def scenario() -> None:
        async with Wired([NodeSettings(76, stream="mag", divider=2048)],
                         [{"address": 76}]) as gw:
            node = gw.nodes[76]
            await wait_for_async(lambda: node.state is State.STREAMING, 5, "streaming")
            assert (node.record, node.divider, node.desired) == ("mag", 2048, None)
            assert [c.code for c in gw.node(76).log.commands] == []  # left as it is
    run(scenario)


def test_a_polled_reply_is_not_taken_for_a_stream() -> None:
    async def scenario() -> None:
        async with Wired([NodeSettings(76)], [{"address": 76}]) as gw:
            for _ in range(3):
                await gw.run("poll", node=76, record="euler")
            assert gw.nodes[76].state is State.POLLED
    run(scenario)


def test_the_operators_start_is_kept_through_a_reboot() -> None:
    async def scenario() -> None:
        async with Wired([NodeSettings(77)], [{"address": 77, "stream": "euler"}]) as gw:
            node = gw.nodes[77]
            await wait_for_async(lambda: node.record == "euler", 5, "euler")
            await gw.run("start", node=77, record="accel_angrate")
            gw.station.reboot(77, asyncio.get_running_loop().time())
            await wait_for_async(lambda: node.reboots == 1, 5, "the reboot")
            await wait_for_async(lambda: node.state is State.STREAMING, 5, "re-armed")
            assert (node.record, gw.node(77).continuous) == ("accel_angrate", 0xC2)
    run(scenario)


def test_a_start_that_failed_is_pursued_until_the_node_answers() -> None:
    async def scenario() -> None:
        radio = {95: RadioLink(in_range=False)}
        async with Wired([NodeSettings(95)], [{"address": 95}], radio=radio) as gw:
            with pytest.raises(NodeError):
                await gw.run("start", node=95, record="euler")
            assert gw.nodes[95].desired == "euler"
            radio[95].in_range = True  # it comes into range
            await wait_for_async(lambda: gw.node(95).continuous == 0xCE, 5, "started")
            await wait_for_async(lambda: gw.nodes[95].state is State.STREAMING, 5,
                                 "streaming")
    run(scenario)


def test_a_stop_cut_short_by_its_deadline_is_finished_in_the_background() -> None:
    async def scenario() -> None:
        radio = {76: RadioLink()}
        async with Wired([NodeSettings(76)], [{"address": 76, "stream": "euler"}],
                         radio=radio) as gw:
            node = gw.nodes[76]
            await wait_for_async(lambda: node.record == "euler", 5, "euler")
            radio[76].command_loss = 1.0
            with pytest.raises(TimeoutError):
                async with asyncio.timeout(0.3):
                    await gw.run("stop", node=76)
            assert node.desired == OFF and node.state is State.STREAMING
            radio[76].command_loss = 0.0
            await wait_for_async(lambda: gw.node(76).continuous == 0, 10, "stopped")
            await wait_for_async(lambda: node.state is State.POLLED, 5, "polled")
    run(scenario)


def test_an_operators_request_waits_one_background_attempt_at_most() -> None:
    """Node 95 is out of range and being armed: an operator's poll of it goes out after
    at most the attempt already on its way, not behind the background's retries."""
    async def scenario() -> None:
        async with Wired([NodeSettings(95)], [{"address": 95, "stream": "euler"}],
                         radio={95: RadioLink(in_range=False)}) as gw:
            def sent_to_95() -> list[int]:
                return [e.command[0] for _, e in gw.station.from_host_log
                        if getattr(e, "node", None) == 95 and hasattr(e, "command")]
            await wait_for_async(lambda: len(sent_to_95()) >= 2, 5, "background retries")
            before = len(sent_to_95())
            with pytest.raises(NodeError):
                await gw.run("poll", node=95, record="mag")
            after = sent_to_95()[before:]
            first_poll = after.index(0xC7)
            assert first_poll <= 1, f"the poll waited behind {after[:first_poll]}"
            assert after.count(0xC7) == scheduling.MAX_ATTEMPTS
            assert all(code == 0xC7 for code in after[first_poll:first_poll + 4]), after
    run(scenario)


def captures(gw: Wired, address: int) -> int:
    return sum(1 for c in gw.node(address).log.commands if c.code == 0xCD)


async def capture_under_way(gw: Wired, address: int) -> asyncio.Task[Any]:
    """A bias capture of ``address`` that the node has begun."""
    task = asyncio.get_running_loop().create_task(gw.run("bias_capture", node=address,
                                                         ms=1000))
    await wait_for_async(lambda: captures(gw, address), 5, "the capture to begin")
    return task


def test_a_capture_cut_by_the_link_leaves_the_node_link_down_until_it_is_back() -> None:
    async def scenario() -> None:
        async with Wired([NodeSettings(76)], [{"address": 76, "stream": "euler"}]) as gw:
            node = gw.nodes[76]
            await wait_for_async(lambda: node.state is State.STREAMING, 5, "streaming")
            capture = await capture_under_way(gw, 76)
            gw.link(False)
            with pytest.raises(LinkDown):
                await capture
            assert node.state is State.LINK_DOWN  # not "polled", as if nothing happened
            gw.link(True)
            await wait_for_async(lambda: node.state is State.STREAMING, 5, "re-armed")
            assert gw.node(76).continuous == 0xCE
    run(scenario)


def test_a_reboot_during_a_capture_is_left_to_the_pursuit_it_started() -> None:
    """The reboot's pursuit arms the node; the failed capture neither marks it polled
    nor starts a second arming beside it."""
    async def scenario() -> None:
        async with Wired([NodeSettings(76)], [{"address": 76, "stream": "euler"}]) as gw:
            node = gw.nodes[76]
            await wait_for_async(lambda: node.state is State.STREAMING, 5, "streaming")
            capture = await capture_under_way(gw, 76)
            gw.station.reboot(76, time.monotonic())
            await wait_for_async(lambda: node.reboots == 1, 5, "the reboot")
            with pytest.raises(NodeError):
                await capture
            assert node.state in (State.ARMING, State.STREAMING), node.state
            await wait_for_async(lambda: node.state is State.STREAMING, 5, "re-armed")
            starts = [c for c in gw.node(76).log.commands if c.code == 0xC4]
            assert len(starts) == 2, starts  # the configured stream's, and the reboot's
    run(scenario)


def test_a_capture_cancelled_at_shutdown_starts_nothing_afterwards() -> None:
    async def scenario() -> None:
        async with Wired([NodeSettings(76)], [{"address": 76, "stream": "euler"}]) as gw:
            await wait_for_async(lambda: gw.nodes[76].state is State.STREAMING, 5,
                                 "streaming")
            before = asyncio.all_tasks()
            capture = await capture_under_way(gw, 76)
            gw.supervisor.close()
            capture.cancel()
            await asyncio.wait([capture])
            started = {t for t in asyncio.all_tasks() if not t.done()} - before
            assert started == set(), started  # (it was: the stream, started again)
    run(scenario)


def sent_to(gw: Wired, address: int) -> list[int]:
    """The first byte of every command packet the base station took for ``address``."""
    return [e.command[0] for _, e in gw.station.from_host_log
            if getattr(e, "node", None) == address and hasattr(e, "command")]


def test_a_stop_of_a_node_out_of_range_is_not_confirmed_and_kept() -> None:
    """Issue 21: node 95 (auto-started, out of range, being armed) is stopped: no answer,
    so not confirmed; no 0xFA goes out; it stays unreachable, and when it comes within
    reach streaming, the gateway stops it."""
    async def scenario() -> None:
        radio = {95: RadioLink(in_range=False)}
        async with Wired([NodeSettings(95, stream="euler")],
                         [{"address": 95, "stream": "euler"}], radio=radio) as gw:
            node = gw.nodes[95]
            await wait_for_async(lambda: node.state is State.UNREACHABLE, 5, "unreachable")
            with pytest.raises(NodeError, match="node 95: stop not confirmed: no answer"):
                await gw.run("stop", node=95)
            assert (node.state, node.desired) == (State.UNREACHABLE, OFF)
            await asyncio.sleep(0.3)  # (background retries at BACKOFF: pings alone)
            assert 0xFA not in sent_to(gw, 95) and node.state is State.UNREACHABLE
            radio[95].in_range = True
            await wait_for_async(lambda: gw.node(95).continuous == 0, 5, "stopped")
            await wait_for_async(lambda: node.state is State.POLLED, 5, "polled")
            assert node.desired == OFF
    run(scenario)


def test_a_stream_that_goes_silent_as_it_is_stopped_is_not_confirmed(monkeypatch) -> None:
    """Out of range a moment before the stop, still shown streaming: the 0xFA goes out,
    the stream is silent, but no ping is answered; back within reach, still streaming,
    it is stopped at once, not at the next retry (60 s away here)."""
    monkeypatch.setattr(supervising, "BACKOFF", (60.0,))

    async def scenario() -> None:
        radio = {76: RadioLink()}
        async with Wired([NodeSettings(76)], [{"address": 76, "stream": "euler"}],
                         radio=radio) as gw:
            node = gw.nodes[76]
            await wait_for_async(lambda: node.state is State.STREAMING, 5, "streaming")
            radio[76].in_range = False
            with pytest.raises(NodeError, match="stop not confirmed: no answer"):
                await gw.run("stop", node=76)
            assert (node.state, node.desired) == (State.UNREACHABLE, OFF)
            assert sent_to(gw, 76).count(0xFA) == 1
            pings = 2 * supervising.PROBE_PINGS  # the operator's, then the retry's
            await wait_for_async(lambda: gw.station.stats.pings == pings
                                 and 76 not in gw.supervisor._stops, 5, "a retry, ended")
            radio[76].in_range = True
            await wait_for_async(lambda: gw.node(76).continuous == 0, 5, "stopped")
            await wait_for_async(lambda: node.state is State.POLLED, 5, "polled")
    run(scenario)


def test_a_stop_of_a_polled_node_in_range_pings_then_stops() -> None:
    async def scenario() -> None:
        async with Wired([NodeSettings(76)], [{"address": 76}]) as gw:
            await wait_for_async(lambda: gw.nodes[76].state is State.POLLED, 5, "polled")
            result = await gw.run("stop", node=76)
            assert result["attempts"] == 1 and gw.nodes[76].state is State.POLLED
            assert gw.station.stats.pings >= 1
    run(scenario)
