"""The control ops: one table, from which the gateway's request models and dispatch and
gx2ctl's command-line parser all derive.

Adding an op is a row here and its function in :mod:`gateway.daemon.operations`
(registered under the row's name; a test checks that every row has one), plus, for
readable output, a printer in :mod:`gateway.ctl.output` (without one gx2ctl prints the
result as JSON).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from .protocol import MAX_PING_NODES
from .values import NODE, POLLABLE_RECORD, RATE_HZ, STREAMABLE_RECORD, WORD, Kind

REQUIRED: Any = object()


@dataclass(frozen=True)
class Param:
    """One field of a request, and one argument of its gx2ctl command.

    ``many``: a list of 1..many values (one or more arguments on the command line).
    A param with a ``default`` is optional: ``--name`` on the command line (or
    ``option``), left out of the request when not given.
    """

    name: str
    kind: Kind
    help: str = ""
    many: int = 0
    default: Any = REQUIRED
    option: str | None = None

    @property
    def required(self) -> bool:
        return self.default is REQUIRED

    @property
    def flag(self) -> str:
        return self.option or "--" + self.name.replace("_", "-")


@dataclass(frozen=True)
class Op:
    """One control op: its name on the wire, its words on gx2ctl's command line (``("eeprom",
    "read")``), what it does, its fields."""

    name: str
    command: tuple[str, ...]
    help: str
    params: tuple[Param, ...] = ()
    talks_to_node: bool = True
    """Sends something to a node (refused during a replay, where nothing is sent)."""
    description: str = ""
    fields: tuple[str, ...] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "fields", tuple(p.name for p in self.params))


_NODE = Param("node", NODE, "the node's address")

OPS: tuple[Op, ...] = (
    Op("ping", ("ping",), "wireless ping; exit 0 if every node answered",
       (Param("nodes", NODE, "node addresses", many=MAX_PING_NODES),)),
    Op("status", ("status",), "the gateway, the link and every node", talks_to_node=False),
    Op("start", ("start",), "continuous mode with RECORD (a name or 0xNN); the node keeps "
       "it through reboots until the next start or stop",
       (_NODE, Param("record", STREAMABLE_RECORD, "the record to stream"))),
    Op("stop", ("stop",), "stop continuous mode, until the stream is silent; the node "
       "stays stopped through reboots until the next start", (_NODE,)),
    Op("poll", ("poll",), "one polled record, printed as one JSON line",
       (_NODE, Param("record", POLLABLE_RECORD, "the record to ask for"))),
    Op("eeprom_read", ("eeprom", "read"), "read the word at ADDRESS",
       (_NODE, Param("address", WORD, "EEPROM address (decimal or 0x hex)"))),
    Op("eeprom_write", ("eeprom", "write"), "write VALUE at ADDRESS, read back to verify",
       (_NODE, Param("address", WORD, "EEPROM address (decimal or 0x hex)"),
        Param("value", WORD, "the word to write (decimal or 0x hex)"))),
    Op("rate", ("rate",), "data rate via the divider at EEPROM 0xFCA2 (51200/HZ)",
       (_NODE, Param("hz", RATE_HZ, "records per second, about 1..301"))),
    Op("info", ("info",), "firmware version and identifier strings", (_NODE,)),
)

BY_NAME: dict[str, Op] = {op.name: op for op in OPS}
