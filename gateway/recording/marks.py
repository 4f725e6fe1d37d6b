"""A mark (``gx2ctl mark``) as recorded: what happened, when, to which nodes, and the
fields its maker gave it (``--field KEY=VALUE``), read from its message whatever an
older or foreign file holds (a missing time: the message's own)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from gateway.common.reading import number

if TYPE_CHECKING:
    from .reader import Entry


@dataclass(frozen=True)
class Mark:
    """A mark (``gx2ctl mark``): what happened, when (UNIX s), to which nodes."""

    time: float
    host_time: float
    nodes: tuple[int, ...]
    text: str
    fields: tuple[tuple[str, str], ...] = ()
    """(key, value), in the order given; a tuple, so that a mark is hashable."""

    @classmethod
    def of(cls, entry: Entry) -> Mark:
        """The mark an entry on MARK holds, its recorded times standing in for a
        missing or non-numeric ``time`` or ``host_time``."""
        payload = entry.payload()
        host_time = _seconds(payload.get("host_time"), entry.log_time / 1e9)
        nodes = payload.get("nodes")
        fields = payload.get("fields")
        return cls(_seconds(payload.get("time"), entry.publish_time / 1e9), host_time,
                   tuple(n for n in nodes if isinstance(n, int) and not isinstance(n, bool))
                   if isinstance(nodes, list) else (), str(payload.get("text") or ""),
                   tuple((str(k), str(v)) for k, v in fields.items()
                         if isinstance(v, (str, int, float)) and not isinstance(v, bool))
                   if isinstance(fields, dict) else ())

    def concerns(self, node: int) -> bool:
        """A mark of the whole experiment, or one naming ``node``."""
        return not self.nodes or node in self.nodes


def _seconds(value: Any, default: float) -> float:
    real = number(value)
    return default if real is None else real
