"""The scheduler on its own: what it writes, in what order, and how each ACK, NACK and
reply is attributed. The reader's role is played by calling on_ack/on_nack/on_reply."""

from __future__ import annotations

import asyncio

import pytest

from gateway.daemon.station import scheduler as scheduling
from gateway.daemon.station.scheduler import LinkDown, NodeError, Scheduler


@pytest.fixture(autouse=True)
def quick(monkeypatch):
    monkeypatch.setattr(scheduling, "ACK_TIMEOUT", 0.05)
    monkeypatch.setattr(scheduling, "BACKOFF_FIRST", 0.01)


class Line:
    """What the scheduler wrote, with a way to wait for the next write."""

    def __init__(self) -> None:
        self.written: list[bytes] = []
        self.scheduler = Scheduler(self.written.append)
        self.scheduler.link_up = True

    async def writes(self, count: int) -> list[bytes]:
        for _ in range(200):
            if len(self.written) >= count:
                return self.written
            await asyncio.sleep(0.005)
        raise AssertionError(f"{count} writes expected, got {self.written}")

    def command(self, node: int, tag: bytes, expect: int | None = 0xC2,
                reply_timeout: float = 0.2) -> asyncio.Task:
        return asyncio.ensure_future(self.scheduler.command(
            node, tag, expect, tag.decode(), reply_timeout=reply_timeout))


def run(coroutine):
    asyncio.run(asyncio.wait_for(coroutine, 10))


def test_one_packet_in_flight_then_replies_by_node_and_echo():
    async def scenario():
        line = Line()
        a, b = line.command(1, b"A"), line.command(2, b"B")
        assert await line.writes(1) == [b"A"]          # B waits for A's ACK
        line.scheduler.on_ack()
        assert await line.writes(2) == [b"A", b"B"]     # A awaits its reply; B goes out
        line.scheduler.on_ack()
        line.scheduler.on_reply(2, 0xC2, "reply to B")
        line.scheduler.on_reply(1, 0xC2, "reply to A")
        assert (await a).reply == "reply to A" and (await b).reply == "reply to B"
        assert (await a).attempts == 1
    run(scenario())


def test_a_reply_before_its_ack_does_not_pass_the_ack_to_the_next_packet():
    """Found in review: the early reply completed A and B went out at once, so A's late
    ACK was credited to B and B's own NACK was lost."""
    async def scenario():
        line = Line()
        a, b = line.command(1, b"A"), line.command(2, b"B")
        await line.writes(1)
        line.scheduler.on_reply(1, 0xC2, "A's reply")   # before A's ACK
        assert (await a).reply == "A's reply"
        await asyncio.sleep(0.01)
        assert line.written == [b"A"]                  # A's ACK is still to come
        line.scheduler.on_ack()                        # ... and it closes A
        await line.writes(2)
        line.scheduler.on_nack()                       # B's NACK is B's: B is resent
        assert await line.writes(3) == [b"A", b"B", b"B"]
        line.scheduler.on_ack()
        line.scheduler.on_reply(2, 0xC2, "B's reply")
        assert (await b).attempts == 2
        assert line.scheduler.stats.unexpected == 0
    run(scenario())


def test_nack_and_silence_are_retried_then_fail_with_the_reason():
    async def scenario():
        line = Line()
        nacked = line.command(1, b"N")
        for count in range(1, 5):
            await line.writes(count)
            line.scheduler.on_nack()
        with pytest.raises(NodeError, match=r"node 1: N: NACK from the base station \(4 att"):
            await nacked
        silent = line.command(2, b"S", reply_timeout=0.02)
        for count in range(5, 9):
            await line.writes(count)
            line.scheduler.on_ack()
        with pytest.raises(NodeError, match="no reply from the node"):
            await silent
        lost_ack = line.command(3, b"L")
        with pytest.raises(NodeError, match="no ACK"):
            await lost_ack
        assert line.written.count(b"L") == 4
    run(scenario())


def test_nodes_are_served_round_robin():
    async def scenario():
        line = Line()
        busy = [line.command(1, f"1-{i}".encode(), expect=None) for i in range(4)]
        other = line.command(2, b"2-0", expect=None)
        for count in range(1, 6):
            await line.writes(count)
            line.scheduler.on_ack()
        await asyncio.gather(*busy, other)
        assert line.written[:2] == [b"1-0", b"2-0"]
    run(scenario())


def test_an_abandoned_request_frees_its_node():
    async def scenario():
        line = Line()
        first = line.command(1, b"X", reply_timeout=5.0)
        await line.writes(1)
        line.scheduler.on_ack()                        # X now awaits a reply for 5 s
        second = line.command(1, b"Y", expect=None)
        first.cancel()
        await line.writes(2)                           # Y goes out without waiting
        line.scheduler.on_ack()
        assert (await second).reply is None
    run(scenario())


def test_pings_and_link_loss():
    async def scenario():
        line = Line()
        up = asyncio.ensure_future(line.scheduler.ping(1, b"P1"))
        down = asyncio.ensure_future(line.scheduler.ping(2, b"P2"))
        await line.writes(1)
        line.scheduler.on_ping_ok()
        await line.writes(2)
        line.scheduler.on_nack()
        assert await up is True and await down is False
        pending = line.command(3, b"Z")
        await line.writes(3)
        line.scheduler.on_link_down()
        with pytest.raises(LinkDown):
            await pending
        with pytest.raises(LinkDown):
            await line.scheduler.ping(1, b"P")
        assert line.scheduler.link_losses == 1
    run(scenario())


def test_a_command_behind_an_awaited_reply_does_not_wake_the_scheduler():
    """Issue 19: the head held back behind its node's awaited reply was still taken as a
    wake-up time (0.0), so service() ran back to back until the reply came (48,616 calls
    in 0.2 s here); now the reply's arrival wakes it, and the queued command goes out."""
    async def scenario():
        line = Line()
        first = line.command(1, b"A", reply_timeout=5.0)
        await line.writes(1)
        line.scheduler.on_ack()                        # A awaits its reply for 5 s
        second = line.command(1, b"B", expect=None)    # ... and B queues behind it
        calls = 0
        service = line.scheduler.service

        def counted() -> None:
            nonlocal calls
            calls += 1
            service()
        line.scheduler.service = counted  # type: ignore[method-assign]
        # the interval measured, not a synchronisation: nothing is to happen in it
        await asyncio.sleep(0.2)
        assert calls <= 2, f"{calls} wake-ups while B waited for A's reply"
        assert line.written == [b"A"]
        line.scheduler.on_reply(1, 0xC2, "A's reply")
        await line.writes(2)
        line.scheduler.on_ack()
        assert (await first).reply == "A's reply" and (await second).reply is None
    run(scenario())


def test_a_command_queued_behind_an_abandoned_one_goes_out_at_once():
    """Its caller giving up frees the node now, not at its reply deadline: with nothing
    waking the scheduler for a held-back head, nothing else would send B for 5 s."""
    async def scenario():
        line = Line()
        first = line.command(1, b"X", reply_timeout=5.0)
        await line.writes(1)
        line.scheduler.on_ack()                        # X now awaits a reply for 5 s
        second = line.command(1, b"Y", expect=None)
        await asyncio.sleep(0)                         # Y's task queues it behind X
        assert line.written == [b"X"]
        first.cancel()
        await line.writes(2)
        line.scheduler.on_ack()
        assert (await second).reply is None
    run(scenario())
