"""Waiting for a condition with a deadline: the tests' only way of waiting for
something to happen (never a bare sleep standing in for an event)."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from typing import Any, TypeVar

T = TypeVar("T")
POLL = 0.005
"""The polling interval of a deadline-bounded wait (not a synchronisation point)."""


def wait_for(condition: Callable[[], T], timeout: float, what: str) -> T:
    """Poll ``condition`` until it returns something truthy, and return that; fail
    (AssertionError naming ``what``) at the deadline."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() >= deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(POLL)


async def wait_for_async(condition: Callable[[], Any], timeout: float, what: str) -> Any:
    """:func:`wait_for` inside an event loop, which keeps running while it waits."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() >= deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        await asyncio.sleep(POLL)
