"""The control ops: one table, from which the gateway's request models and dispatch and
gx2ctl's command-line parser all derive.

Adding an op is a row here and its function in :mod:`gateway.daemon.operations`
(registered under the row's name; a test checks that every row has one), plus, for
readable output, a printer in :mod:`gateway.ctl.output` (without one gx2ctl prints the
result as JSON).
"""

from __future__ import annotations

import re
import unicodedata
from dataclasses import dataclass, field
from typing import Any

from .protocol import MAX_PING_NODES, MAX_REQUEST_BYTES
from .values import (
    ADDRESS_RANGES,
    FLOAT,
    NODE,
    POLLABLE_RECORD,
    RATE_HZ,
    SAMPLING_MS,
    SENSOR,
    STATION,
    STREAMABLE_RECORD,
    WORD,
    Kind,
)

REQUIRED: Any = object()
MARK_CHARACTERS = 1000
"""The longest text a mark keeps, in characters; in UTF-8 bytes, MARK_BYTES (so that
a mark naming the most nodes still fits in one request of MAX_REQUEST_BYTES)."""
MARK_BYTES = 3 * MAX_REQUEST_BYTES // 4
LINE_BREAKING = ("Cc", "Zl", "Zp")
"""Unicode categories a mark's text may not hold (but a tab): control characters and
line or paragraph separators."""


def _mark_text(value: str) -> str:
    """One line of text, not blank, not too long: a label on a plot, a cell in a table."""
    text = value.strip()
    if not text:
        raise ValueError("a mark's text is empty")
    size = len(text.encode("utf-8", "replace"))
    if len(text) > MARK_CHARACTERS or size > MARK_BYTES:
        raise ValueError(f"a mark's text is at most {MARK_CHARACTERS} characters and "
                         f"{MARK_BYTES} bytes of UTF-8, not {len(text)} characters "
                         f"({size} bytes)")
    if any(c != "\t" and unicodedata.category(c) in LINE_BREAKING for c in text):
        raise ValueError("a mark's text is one line: no line breaks or control characters")
    return text


MARK_TEXT = Kind("mark text", str, str, _mark_text)
MARK_FIELDS = 20
"""The most fields a mark carries (``--field KEY=VALUE``)."""
_FIELD_KEY = re.compile(r"[A-Za-z0-9_.-]{1,64}")


def _mark_field(value: str) -> str:
    """``KEY=VALUE``: a key of letters, digits and ``_.-`` (a column's name in the
    dataset), a value of one line, as a mark's text is."""
    key, equals, field_value = value.partition("=")
    if not equals or not _FIELD_KEY.fullmatch(key.strip()):
        raise ValueError(f"a mark's field is KEY=VALUE, KEY of letters, digits and _.- "
                         f"(at most 64), not {value!r}")
    text = field_value.strip()
    if text:
        _mark_text(text)
    return f"{key.strip()}={text}"


MARK_FIELD = Kind("mark field", str, str, _mark_field)


@dataclass(frozen=True)
class Param:
    """One field of a request, and one argument of its gx2ctl command.

    ``many``: a list of 1..many values (one or more arguments on the command line).
    A param with a ``default`` is optional: ``--name`` on the command line (or
    ``option``), or an argument that may be left out if ``positional``; a list with one
    is zero or more arguments, left out of the request when none is given. A default of
    None is left out of the request too (the gateway reads it as None).
    """

    name: str
    kind: Kind
    help: str = ""
    many: int = 0
    default: Any = REQUIRED
    option: str | None = None
    positional: bool = False
    metavar: str | None = None
    """What gx2ctl's help calls its value (default: the name in capitals)."""

    @property
    def required(self) -> bool:
        return self.default is REQUIRED

    @property
    def flag(self) -> str:
        return self.option or "--" + self.name.replace("_", "-")


@dataclass(frozen=True)
class Switch:
    """An option of the gx2ctl command alone, never sent to the gateway: it changes what
    gx2ctl makes of the result (``status --check``)."""

    name: str
    help: str

    @property
    def flag(self) -> str:
        return "--" + self.name.replace("_", "-")


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
    extra_ms: str | None = None
    """A param in milliseconds that the op takes on top of a usual request (a bias
    capture's sampling time): gx2ctl waits that much longer."""
    extra_seconds: float = 0.0
    """Seconds the op takes on top of a usual request, whatever its params."""
    notice: str = ""
    """What gx2ctl says (on stderr) before it sends the request; ``{field}`` is
    replaced by the request's field."""
    switches: tuple[Switch, ...] = ()
    on_cancel: str = ""
    """What stays, or goes on, when its client cancels it (Ctrl-C in gx2ctl) before it
    ends: said to that client and logged by the gateway."""
    fields: tuple[str, ...] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "fields", tuple(p.name for p in self.params))

    def label(self, fields: Any) -> str:
        """The request in words, for a log line or a message: ``bias capture on 76``,
        ``ping of 76, 77``. ``fields``: the request (its attributes) or a map."""
        def get(name: str) -> Any:
            return fields.get(name) if isinstance(fields, dict) else getattr(fields, name,
                                                                               None)
        words = " ".join(self.command)
        if get("node") is not None:
            return f"{words} on {get('node')}"
        if get("nodes"):
            return f"{words} of {', '.join(map(str, get('nodes')))}"
        return words

    def extra_time(self, fields: dict[str, Any]) -> float:
        """Seconds this request takes beyond a usual one."""
        ms = fields.get(self.extra_ms, 0) if self.extra_ms else 0
        return self.extra_seconds + (ms or 0) / 1000


_NODE = Param("node", NODE, "the node's address")
_PURSUED = ("the gateway goes on {doing} it in the background, as when it does not answer "
            "(gx2ctl status shows it)")
_SENT = "{what} already sent may have reached the node: check {check}"

SCAN_DEFAULT = "1-100"
"""The addresses a scan pings unless told: where the reference says node addresses
typically are (the factory sets a node's to its serial number's last two digits)."""

OPS: tuple[Op, ...] = (
    Op("ping", ("ping",), "wireless ping; exit 0 if every node answered",
       (Param("nodes", NODE, "node addresses", many=MAX_PING_NODES),)),
    Op("status", ("status",), "the gateway, the link and every node, with its health",
       talks_to_node=False,
       switches=(Switch("check", "exit 1 unless every base station's link is up and every "
                        "node is OK (for cron, a load balancer or a monitoring check)"),
                 Switch("wide", "every column whole, however wide the terminal (without "
                        "it the table fits the terminal's width, dropping columns)"))),
    Op("start", ("start",), "continuous mode with RECORD (a name or 0xNN); the node keeps "
       "it through reboots until the next start or stop",
       (_NODE, Param("record", STREAMABLE_RECORD, "the record to stream")),
       on_cancel=_PURSUED.format(doing="starting")),
    Op("stop", ("stop",), "stop continuous mode, until the stream is silent; the node "
       "stays stopped through reboots until the next start", (_NODE,),
       on_cancel=_PURSUED.format(doing="stopping")),
    Op("poll", ("poll",), "one polled record, printed as one JSON line",
       (_NODE, Param("record", POLLABLE_RECORD, "the record to ask for"))),
    Op("eeprom_read", ("eeprom", "read"), "read the word at ADDRESS",
       (_NODE, Param("address", WORD, "EEPROM address (decimal or 0x hex)"))),
    Op("eeprom_write", ("eeprom", "write"), "write VALUE at ADDRESS, read back to verify",
       (_NODE, Param("address", WORD, "EEPROM address (decimal or 0x hex)"),
        Param("value", WORD, "the word to write (decimal or 0x hex)")),
       on_cancel=_SENT.format(what="a write", check="with gx2ctl eeprom read")),
    Op("rate", ("rate",), "data rate via the divider at EEPROM 0xFCA2 (51200/HZ)",
       (_NODE, Param("hz", RATE_HZ, "records per second, about 1..301")),
       on_cancel=_SENT.format(what="a write", check="with gx2ctl eeprom read NODE 0xFCA2")),
    Op("info", ("info",), "firmware version and identifier strings", (_NODE,)),
    Op("bias_capture", ("bias", "capture"), "capture the gyro bias (0xCD): the node must "
       "stand still while it samples its sensors",
       (_NODE, Param("ms", SAMPLING_MS, "sampling time in ms (10000..30000 advised)",
                     default=10000)), extra_ms="ms",
       notice="node {node} samples its sensors for {ms} ms: keep it still until then",
       on_cancel="bias unchanged",
       description="Capture gyro bias (0xCD): the node samples its sensors for --ms "
       "milliseconds and takes their mean as its gyro bias. It must stand still. A "
       "stream it is running is stopped first and started again afterwards. gx2ctl "
       "waits the sampling time on top of --timeout."),
    Op("bias_set", ("bias", "set"), "write the accel (0xC9) or gyro (0xCA) bias "
       "correction (needs allow_eeprom_write)",
       (_NODE, Param("sensor", SENSOR, "accel (g) or gyro (rad/s)"),
        Param("x", FLOAT, "x"), Param("y", FLOAT, "y"), Param("z", FLOAT, "z")),
       on_cancel=_SENT.format(what="a correction", check="by setting it again")),
    Op("store", ("store",), "keep the accel or gyro bias through power cycles (0xD0; "
       "needs allow_eeprom_write)", (_NODE, Param("sensor", SENSOR, "accel or gyro")),
       on_cancel=_SENT.format(what="a store", check="by storing again")),
    Op("temperature", ("temperature",), "the four temperatures (0xD1) in degrees Celsius, "
       "with their codes", (_NODE,)),
    Op("selftest", ("selftest",), "built-in test (0xFB): each output checked against BIT "
       "on and off; exit 0 only if every check passed", (_NODE,), extra_seconds=10.0,
       notice="node {node}: built-in test; keep it still until it ends",
       on_cancel="BIT switched off (the gateway keeps at it until the node confirms) and "
       "any stream it ran started again",
       description="Built-in test: with the node standing still, its outputs are read "
       "with BIT off, with the positive accelerometer and rate sensor BIT (bit 4) and "
       "with the negative rate sensor BIT (bit 5); each output must step the way the "
       "reference says, by a margin well above its noise; |accel| must be 1 g and the "
       "temperatures plausible. BIT is always switched off again. One line per check; "
       "exit 0 only if all pass. A stream the node is running is stopped for the test "
       "and started again afterwards. gx2ctl waits 10 s on top of --timeout."),
    Op("reload", ("reload",), "re-read the configuration file, as SIGHUP: nodes added, "
       "removed or changed; nothing else touched", talks_to_node=False,
       on_cancel="the reload goes on (the gateway logs what it changed)",
       description="Re-read the gateway's configuration file, as systemctl reload "
       "(SIGHUP) does: nodes added are armed, nodes removed stopped and forgotten, "
       "changed nodes armed again; every other node streams on untouched. Prints what "
       "changed. A file that does not check is refused (exit 2), one that changes "
       "what needs a restart (an endpoint, a station's port, the recording) is refused "
       "(exit 1) naming the key; either way the running configuration is kept whole."),
    Op("mark", ("mark",), "mark a moment (a trial's start, a knock, a note) in what is "
       "recorded", (Param("nodes", NODE, "the nodes it concerns (default: the whole "
                          "experiment)", many=MAX_PING_NODES, default=()),
                    Param("text", MARK_TEXT, "what happened (one line, quoted)"),
                    Param("fields", MARK_FIELD, "a field the mark carries (a trial's "
                          "subject, condition ...): KEY=VALUE, repeatable",
                          many=MARK_FIELDS, default=(), option="--field",
                          metavar="KEY=VALUE")),
       talks_to_node=False,
       description="Publish a mark on gx2/gateway/mark: TEXT, the time the gateway took "
       "it, the NODEs it concerns (none: the whole experiment) and its --field KEY=VALUE "
       "(fields: a map of strings). The gateway's own recording and gx2ctl record keep "
       "it; gx2ctl export writes marks.csv, gx2ctl trials lists the trials with their "
       "start mark's fields, gx2ctl plot draws it. Refused (exit 1) while the gateway "
       "replays a recording."),
    Op("scan", ("scan",), "ping each address (1-100 by default) and say what answers: "
       "LQI/RSSI, firmware, serial number, rate, stream",
       (Param("station", STATION, "the base station whose channel to scan (default: every "
              "one, at once)", default=None, positional=True),
        Param("addresses", ADDRESS_RANGES, "the addresses to ping, such as "
              "1-100,200,300-310", default=SCAN_DEFAULT, metavar="RANGES")),
       on_cancel="it only reads: no node was changed",
       description="Find the nodes on a base station's channel: ping each address "
       "(--addresses, 1-100 by default) through the base station, as gx2ctl ping does, "
       "and read each node that answers without changing it: its LQI and RSSI, firmware "
       "version, model and serial number, divider (its rate), the record it streams "
       "from power-up (EEPROM 0xFCA6) and the one it streams now. The configured nodes' "
       "streams go on meanwhile. Each node found is printed as it is found; on a "
       "terminal the progress (addresses done, found, time left) is shown on stderr; "
       "Ctrl-C stops the scan and prints what it found (exit 130). Without STATION, "
       "every base station is scanned at once. Exit 0 when the scan completed (nodes "
       "found or not), 1 when a base station it scans is down, 2 for malformed ranges "
       "or an address outside 1..65534. An absent address takes about 40 ms (the base "
       "station's own wait), a node found about 0.1 s more at 100 Hz: 1-100 takes "
       "4 to 5 s."),
)

BY_NAME: dict[str, Op] = {op.name: op for op in OPS}
