"""Waiting for a condition with a deadline: the tests' only way of waiting for
something to happen (never a bare sleep standing in for an event)."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from typing import Any, TypeVar

T = TypeVar("T")
POLL = 0.005
"""The first polling interval of a deadline-bounded wait (not a synchronisation point);
each next one twice as long, up to POLL_MAX."""
POLL_MAX = 0.05
"""The longest polling interval. A condition is most often a status request to the
gateway: asked every 5 ms it took the gateway 16.5% of a core more than not asking and
the test 8.2%, every 50 ms 2.4% and 1.1% (a gateway streaming two nodes, 8 s each), and
the suite runs several tests at once on two cores."""


def wait_for(condition: Callable[[], T], timeout: float, what: str) -> T:
    """Poll ``condition`` until it returns something truthy, and return that; fail
    (AssertionError naming ``what``) at the deadline."""
    deadline = time.monotonic() + timeout
    poll = POLL
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() >= deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(poll)
        poll = min(2 * poll, POLL_MAX)


async def wait_for_async(condition: Callable[[], Any], timeout: float, what: str) -> Any:
    """:func:`wait_for` inside an event loop, which keeps running while it waits."""
    deadline = time.monotonic() + timeout
    poll = POLL
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() >= deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        await asyncio.sleep(poll)
        poll = min(2 * poll, POLL_MAX)
