"""A node's stream watch, on its own (the daemon's end-to-end recovery tests drive it
through a real pty): when a stream would fall silent, and that it falls silent once."""

from __future__ import annotations

import time

from gateway.daemon.config import NodeEntry
from gateway.daemon.nodes import SILENCE_MIN, Node, State


def test_silent_at_is_the_watchers_deadline() -> None:
    node = Node(NodeEntry(address=76, stream="accel_angrate"))
    assert node.silent_at() is None  # nothing streams yet: nothing to watch
    node.streaming("accel_angrate")
    due = node.silent_at()
    assert due is not None and due - time.monotonic() <= node.silence_limit
    assert node.silence_limit >= SILENCE_MIN
    assert not node.fell_silent(due)  # at the deadline itself: not yet
    assert node.fell_silent(due + 0.001)
    assert (node.state, node.silences, node.silent_at()) == (State.SILENT, 1, None)
    assert not node.fell_silent(due + 10)  # counted once, not on every look


def test_polled_mode_is_not_watched() -> None:
    node = Node(NodeEntry(address=76))
    node.polled()
    assert node.state is State.POLLED and node.silent_at() is None
