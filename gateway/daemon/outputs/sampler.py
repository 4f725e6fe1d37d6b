"""Which records an output that thins them sends (``mqtt.rate_hz``): at most so many a
second of each topic, on the samples' own clock."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any


class Sampler:
    """Which samples of a topic go out under ``rate_hz``: never more often than it, on
    the samples' own clock (``time``), whatever the link's jitter did to arrival.

    Each topic has a deadline, which advances by whole periods: the sample nearest it
    goes out (one at or past it, or one before it by less than half the gap from the
    sample before: a 100 Hz stream at 10 Hz sends every 10th sample, evenly), and the
    next deadline is one period on from this one, not from the sample, so a sample
    taken a little early never brings the next one forward. A sample more than half a
    gap past its deadline (samples lost, a stream slower than the rate) starts the
    deadlines again from itself; so does one whose time goes back (a node rebooted)."""

    __slots__ = ("_due",)

    def __init__(self) -> None:
        self._due: dict[bytes, list[float]] = {}
        """Topic -> [its deadline, the time of its last sample]."""

    def due(self, topic: bytes, every_s: float, payload: Mapping[str, Any]) -> bool:
        when = payload.get("time") or payload.get("host_time") or 0.0
        state = self._due.get(topic)
        if state is None:
            self._due[topic] = [when + every_s, when]
            return True
        deadline, last = state
        state[1] = when
        if when < last:  # (its time went back: a new start)
            state[0] = when + every_s
            return True
        half_gap = (when - last) / 2
        if when < deadline - half_gap:
            return False
        state[0] = deadline + every_s if when <= deadline + half_gap else when + every_s
        return True
