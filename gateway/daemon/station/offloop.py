"""Blocking calls made beside the event loop, each in a daemon thread of its own.

Opening a base station can block for seconds (pyserial's ``socket://`` and
``rfc2217://`` connect with a 5 s timeout; a USB adapter's driver may hang in
``open(2)``), and so can closing one (a tty drains its output first; rfc2217 joins its
reader thread). On the loop that stalled every other station (issue 31). The loop's own
executor is no place for them: its worker threads are joined when the interpreter
exits, so a connect stuck there would hold up the promised 2 s shutdown. A daemon
thread is abandoned at exit instead; the caller keeps at most one such call in flight
per port, so a call that hangs costs one thread, never more.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")


def in_thread(call: Callable[[], T], name: str) -> asyncio.Future[T]:
    """Run ``call`` in a new daemon thread; its result (or exception) on the running
    loop's future. A future already cancelled, or a loop already closed (a shutdown),
    just drops what the call returns."""
    loop = asyncio.get_running_loop()
    future: asyncio.Future[T] = loop.create_future()

    def settle(result: T | None, error: BaseException | None) -> None:
        if future.done():
            return
        if error is not None:
            future.set_exception(error)
        else:
            future.set_result(result)  # type: ignore[arg-type]

    def run() -> None:
        try:
            result, error = call(), None
        except BaseException as failure:  # handed to the loop, raised where awaited
            result, error = None, failure
        with contextlib.suppress(RuntimeError):  # the loop is closed: nobody waits
            loop.call_soon_threadsafe(settle, result, error)

    threading.Thread(target=run, name=name, daemon=True).start()
    return future
