"""A published message as every output sees it (:class:`Message`): in a module of its
own, so that what makes messages (:mod:`.frames`) needs nothing else of the package."""

from __future__ import annotations

from typing import Any

from gateway.common.jsontext import compact_bytes


class Message:
    """A published message as every output sees it: its topic, its payload (shared by
    every output, never changed once published), and its JSON, made once, by the first
    output that asks for it (the live view on the loop, when a viewer watches its
    topic, or the recorder in its thread: the two may race for one message, and then
    both make the same bytes)."""

    __slots__ = ("_json", "payload", "times", "topic")

    def __init__(self, topic: bytes, payload: dict[str, Any],
                 times: tuple[float, float] | None = None) -> None:
        self.topic = topic
        self.payload = payload
        self.times = times
        """(logged, sampled) UNIX times where the payload does not say them as a
        record's do (a node's frame); None: ``message_times(payload)``."""
        self._json: bytes | None = None

    def json(self) -> bytes:
        """Its payload as strict, compact JSON (gateway.common.jsontext.compact_bytes)."""
        data = self._json
        if data is None:
            data = self._json = compact_bytes(self.payload)
        return data
