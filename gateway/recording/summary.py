"""Totals of the samples lost (:mod:`.losses`), and the line that says them: what
``gx2ctl record`` shows on stderr, the plot's title and export's line for a table."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from .losses import Counted


@dataclass
class Summary:
    """Totals of rows counted: received, lost by the radio and by the gateway, missed
    while a base station was down, and recorded but unread (a damaged stretch of a
    recording)."""

    received: int = 0
    radio: int = 0
    gateway: int = 0
    down: int = 0
    unread: int = 0
    unread_seconds: float = 0.0

    def add(self, counted: Counted[Any], gateway: int | None = None,
            period: float | None = None) -> None:
        """Count a row; ``gateway``: the messages the gateway lost just before it, if
        known otherwise than by its stream (a subscriber's count of every record);
        ``period``: the stream's (s), to say how long the unread stretches are."""
        self.received += 1
        self.radio += counted.radio
        self.gateway += counted.gateway if gateway is None else gateway
        self.down += counted.down
        self.unread += counted.unread
        self.unread_seconds += counted.unread * (period or 0.0)

    def line(self, separator: str = ", ") -> str:
        """``radio: 2,600 lost (26.00%), gateway: 0 lost (0.00%)``: each a share of what
        should have arrived (received and lost); then, if any, what was missed while a
        station was down (``station down: 200 lost (9.09%)``) and the file's damage."""
        total = self.received + self.radio + self.gateway + self.down + self.unread
        said = [f"radio: {self.radio:,} lost ({_share(self.radio, total)})",
                f"gateway: {self.gateway:,} lost ({_share(self.gateway, total)})"]
        if self.down:
            said.append(f"{self.outage()} ({_share(self.down, total)})")
        if self.unread:
            said.append(self.damage())
        return separator.join(said)

    def apart(self) -> str:
        """What is neither the radio's nor the gateway's loss, if any: ``station down:
        200 lost, file damaged: 98 messages, 1.0 s unread``."""
        return ", ".join(said for said in (self.outage(), self.damage()) if said)

    def outage(self) -> str:
        """``station down: 200 lost``; empty if none was."""
        return f"station down: {self.down:,} lost" if self.down else ""

    def damage(self) -> str:
        """``file damaged: 98 messages, 1.0 s unread``; empty if none was."""
        if not self.unread:
            return ""
        seconds = f", {self.unread_seconds:.1f} s" if self.unread_seconds else ""
        return (f"file damaged: {self.unread:,} message{'s' * (self.unread != 1)}"
                f"{seconds} unread")


def _share(part: int, total: int) -> str:
    return f"{100 * part / total:.2f}%" if total else "0.00%"


__all__ = ["Summary"]
