"""``gx2ctl top``: every node of a running gateway at a glance, refreshed in place until
``q`` or Ctrl-C.

It draws the gateway's heartbeat (``gx2/gateway/status``, once a second by default),
received through :mod:`gateway.client` with ``status="only"``: the gateway does no work
for it, and no record crosses the network to it. When the gateway goes away the last
table stays, marked stale; when it comes back the subscription reconnects by itself.

A frame is a pure function of the status and the terminal's width, so the layout is
tested without a terminal: columns are dropped or abbreviated to fit, never wrapped.
Not a terminal (a pipe, a file): one plain frame per heartbeat, as ``top -b`` does.
"""

from __future__ import annotations

import contextlib
import os
import select
import sys
import termios
import time
import tty
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from rich.console import Console, Group
from rich.live import Live
from rich.text import Text

from gateway.client import Status
from gateway.common.jsontext import json_line
from gateway.common.protocol import Exit, HealthLevel
from gateway.common.reading import as_map, number
from gateway.common.timetext import TIME, seconds_at

from .cells import MISSING, cell, duration, node_maps, reasons
from .statusview import station_maps
from .subscribing import Stop, subscribe
from .toptable import HEALTH_STYLE, cut, table

if TYPE_CHECKING:
    from .where import Endpoints

TICK = 0.2
"""Seconds between looks at the keyboard (and at the clock, for the ages shown)."""
REDRAW = 1.0
"""A frame is drawn on each heartbeat, and at least this often (ages move on)."""
QUIT = "q quits"
"""The last line on a terminal."""
BUSY_LINE, FULL_LINE = 90, 99
"""Shares of the serial line (%) from which it is shown busy (packets begin to queue
behind each other) and full (the base station's buffer fills and drops them)."""
MISSED = 1.25
"""Heartbeat intervals of silence after which one heartbeat is taken as missed (a
quarter of one allowed for its jitter on a busy host): from then on what is shown is
stale, and said to be."""
DEFAULT_HEARTBEAT = 1.0
"""The interval taken when a status does not say its own (``gateway.heartbeat_s``)."""


# --- the frame -----------------------------------------------------------------------

@dataclass
class Watch:
    """What top knows of the gateway it watches."""

    endpoint: str
    nodes: tuple[int, ...] = ()
    """Only these nodes (all if empty)."""
    silence: float = 3.0
    """Seconds without a heartbeat after which the gateway is shown as gone."""
    status: Mapping[str, Any] | None = None
    restarted_at: float | None = None
    """When (on :meth:`now`'s clock) the gateway was last seen to restart."""
    _clock: tuple[float, float] | None = None
    """The gateway's UNIX time in its last status, and time.monotonic() here then."""

    def take(self, status: Status) -> None:
        self.status = status.payload
        made = number(as_map(status.payload.get("gateway")).get("time"))
        self._clock = None if made is None else (made, time.monotonic())
        if status.restarted:
            self.restarted_at = self.now()

    def now(self) -> float:
        """UNIX time on the gateway's clock (its last status, and the time since): the
        ages shown are right even when this host's clock is not."""
        if self._clock is None:
            return time.time()
        made, received = self._clock
        return made + time.monotonic() - received

    def heartbeat(self) -> float:
        """Seconds between the gateway's heartbeats, as its last status says."""
        every = number(as_map((self.status or {}).get("gateway")).get("heartbeat_s"))
        return every if every is not None and every > 0 else DEFAULT_HEARTBEAT

    def stale_for(self, silent_for: float) -> float | None:
        """``silent_for`` once a heartbeat was missed (what is shown is that old), else
        None: nothing shown yet, or the last status still the latest."""
        if self.status is None or silent_for <= MISSED * self.heartbeat():
            return None
        return silent_for

    def freshness(self, silent_for: float) -> str:
        """What the header says of the heartbeat: a change is worth a frame at once."""
        if self.status is None:
            return "waiting"
        if silent_for > self.silence:
            return "gone"
        return "fresh" if self.stale_for(silent_for) is None else "stale"

    def shown(self) -> list[Mapping[str, Any]]:
        """The nodes of the last status that are shown."""
        return [n for n in node_maps(self.status or {})
                if not self.nodes or n.get("node") in self.nodes]


def _bytes(value: float) -> str:
    return f"{value:,.0f} B/s"


def clock_text(now: float) -> str:
    """The time of day at ``now`` to the second, as every time is shown
    (:mod:`gateway.common.timetext`; a gateway's clock may say anything)."""
    return seconds_at(now, TIME, digits=0) or "--:--:--"


def link_text(label: str, link: Mapping[str, Any], now: float, stale: bool = False) -> Text:
    """A base station's line: its state and for how long, what its serial line carries
    (the share of the baud rate: yellow when busy, red when full), reconnects, port;
    ``stale``: all grey, as what no heartbeat vouches for any more."""
    state = cell(link.get("state"))
    text = Text(f"{label} ")
    text.append(state, "green" if state == "up" else "bold red")
    since = number(link.get("since"))
    if since is not None:
        text.append(f" {duration(now - since)}")
    rate, line = number(link.get("bytes_per_s")), number(link.get("line_bytes_per_s"))
    if rate is not None:
        text.append(f"  {_bytes(rate)}")
        if line:
            share = 100 * rate / line
            text.append(f" = {share:.0f}% of {_bytes(line)}",
                        "bold red" if share >= FULL_LINE else
                        "yellow" if share >= BUSY_LINE else "")
    text.append(f"  reconnects {cell(link.get('reconnects'))}  {cell(link.get('port'))}")
    error = link.get("error")
    if state != "up" and isinstance(error, str) and error:
        text.append(f" ({error})", "red")
    if stale:
        text.spans.clear()
        text.stylize("dim")
    return text


def header(watch: Watch, now: float, silent_for: float) -> list[Text]:
    status = watch.status or {}
    gateway, link = as_map(status.get("gateway")), as_map(status.get("link"))
    nodes = watch.shown()
    counts = {level: sum(1 for n in nodes if n.get("health") == level)
              for level in HEALTH_STYLE}
    stale = watch.stale_for(silent_for) is not None
    first = Text(f"gx2-gateway {cell(gateway.get('version'))} up "
                 f"{duration(gateway.get('uptime'))}  nodes ")
    for level, style in HEALTH_STYLE.items():
        first.append(f"{counts[level]} {level}",
                     "dim" if stale else style if counts[level] else "")
        first.append(" ")
    first.append(f" {clock_text(now)}", "dim")

    stations = station_maps(status)
    if len(stations) == 1:
        second = link_text("link", link, now, stale)
    else:
        up = sum(1 for s in stations if s.get("state") == "up")
        second = Text(f"base stations {len(stations)}: ")
        second.append(f"{up} up", "dim" if stale else "green" if up == len(stations)
                      else "")
        if up < len(stations):
            second.append(f", {len(stations) - up} not up", "dim" if stale else "bold red")
    discarded: dict[str, float] = {}
    for station in stations:
        for kind, value in as_map(station.get("discarded")).items():
            if (amount := number(value)):
                discarded[str(kind)] = discarded.get(str(kind), 0) + amount
    counted = [n for s in stations if (n := number(s.get("discarded_bytes"))) is not None]
    third = Text(f"discarded {sum(counted):.0f} B" if counted else f"discarded {MISSING} B")
    third.append(
        ": " + ", ".join(f"{k} {v:.0f}" for k, v in discarded.items()) if discarded
        else "")
    lines = [first, second, third]
    if watch.status is None:
        lines.append(Text(f"waiting for the gateway's heartbeat on {watch.endpoint} "
                          f"({silent_for:.0f} s)", "yellow"))
    elif silent_for > watch.silence:
        lines.append(Text(f"no heartbeat for {silent_for:.0f} s from {watch.endpoint}: is "
                          "gx2-gateway running? (its last status is shown, greyed)",
                          "bold red"))
    elif stale:
        lines.append(Text(f"no heartbeat for {silent_for:.1f} s (one is due every "
                          f"{watch.heartbeat():g} s) from {watch.endpoint}: what is shown "
                          f"is {silent_for:.1f} s old", "bold yellow"))
    elif watch.restarted_at is not None and now - watch.restarted_at < 60:
        lines.append(Text(f"the gateway restarted {duration(now - watch.restarted_at)} "
                          "ago", "yellow"))
    else:
        lines.append(Text(""))
    return lines


def frame(watch: Watch, now: float, silent_for: float, width: int,
          ellipsis: str = "…", height: int | None = None) -> list[Text]:
    """Every line of one frame, none wider than ``width`` cells and, given a ``height``,
    no more lines than it less one (the footer's): nodes that do not fit are counted in
    a last ``+N more`` row, before any reason is dropped; everything it shows greyed
    once a heartbeat is missed (it is the gateway's last word, of unknown worth now)."""
    nodes = watch.shown()
    stale_for = watch.stale_for(silent_for)
    rows = table(nodes, now, width, ellipsis, stale_for)
    head, body = [*header(watch, now, silent_for), *rows[:1]], grouped(
        watch.status or {}, nodes, rows[1:], now, stale_for is not None)
    notes: list[Text] = []
    gateway = as_map((watch.status or {}).get("gateway"))
    health = gateway.get("health")

    def style(level: object) -> str:
        return "dim" if stale_for is not None else HEALTH_STYLE.get(str(level), "")
    if health is not None and health != HealthLevel.OK and (why := reasons(gateway)):
        notes.append(Text("gateway ").append(f"{cell(health)}: {why}", style(health)))
    for node in nodes:
        if node.get("health") != HealthLevel.OK and (why := reasons(node)):
            notes.append(Text(f"{cell(node.get('node'))} ").append(
                f"{cell(node.get('health'))}: {why}", style(node.get("health"))))
    if height is not None:
        body, notes = within(height - 1 - len(head), body, notes)
    return [cut(line, width, ellipsis) for line in (*head, *body, *notes)]


def grouped(status: Mapping[str, Any], nodes: Sequence[Mapping[str, Any]],
            rows: list[Text], now: float, stale: bool = False) -> list[Text]:
    """The node rows; with several base stations, under a line for each station (its
    link and its serial line's share), in the status's order of stations."""
    stations = station_maps(status)
    if len(stations) == 1:
        return rows
    body: list[Text] = []
    names = [cell(s.get("name")) for s in stations]
    for name, station in zip(names, stations, strict=True):
        heading = link_text(f"{name}:", station, now, stale)
        heading.stylize("bold", 0, len(name) + 1)
        body.append(heading)
        body += [row for node, row in zip(nodes, rows, strict=True)
                 if cell(node.get("station")) == name]
    return body + [row for node, row in zip(nodes, rows, strict=True)
                   if cell(node.get("station")) not in names]


def within(room: int, body: list[Text], notes: list[Text]) -> tuple[list[Text], list[Text]]:
    """The node rows and reasons that fit in ``room`` lines: every node (or all but the
    last that fit, and a ``+N more`` row counting the rest), then the reasons that fit.
    At least the count is shown, however little room there is."""
    if len(body) > max(room, 1):
        kept = max(room - 1, 0)
        return [*body[:kept], Text(f"+{len(body) - kept} more", "bold")], []
    return body, notes[:max(room - len(body), 0)]


# --- running -------------------------------------------------------------------------

@contextlib.contextmanager
def keyboard() -> Iterator[Callable[[], bool]]:
    """A check for ``q`` typed at the terminal (keys arrive at once, unechoed; Ctrl-C
    still interrupts); without a terminal on stdin, a check that is never true."""
    try:
        fd = sys.stdin.fileno()
    except (AttributeError, ValueError, OSError):  # none, closed, or not a file
        fd = -1
    if fd < 0 or not os.isatty(fd):
        yield lambda: False
        return
    saved = termios.tcgetattr(fd)
    tty.setcbreak(fd)

    def pressed() -> bool:
        while select.select([fd], [], [], 0)[0]:
            typed = os.read(fd, 64)
            if not typed or b"q" in typed.lower():
                return True
        return False
    try:
        yield pressed
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)


def terminal() -> tuple[Console, str]:
    """The console to draw on, and the ellipsis it can show: a terminal that cannot
    show a character gets a "?" for it, never a crash."""
    utf = "utf" in (getattr(sys.stdout, "encoding", "") or "").lower()
    with contextlib.suppress(AttributeError, ValueError):
        sys.stdout.reconfigure(errors="replace")  # type: ignore[union-attr]
    return Console(highlight=False), "…" if utf else "~"


def run_top(nodes: list[int], where: Endpoints, timeout: float, as_json: bool) -> int:
    """Draw the gateway's status until ``q``, Ctrl-C or SIGTERM."""
    stop = Stop()
    console, ellipsis = terminal()
    with subscribe(nodes, where, timeout, status="only") as (sub, silence):
        watch = Watch(sub.endpoints[0], tuple(nodes), silence)
        if as_json or not console.is_terminal:
            return _print_frames(sub, watch, console.width, stop, as_json, ellipsis)
        with keyboard() as pressed, Live(console=console, screen=True,
                                         auto_refresh=False) as live:
            drawn, was = 0.0, watch.freshness(sub.silent_for())
            while not stop.requested and not pressed():
                event = sub.receive(TICK)
                if isinstance(event, Status):
                    watch.take(event)
                # a heartbeat missed (or the gateway gone) is drawn at once, not at the
                # next redraw: that is when the rows stop being news
                now_is = watch.freshness(sub.silent_for())
                if event is not None or now_is != was or time.monotonic() - drawn >= REDRAW:
                    was = now_is
                    width = console.width
                    lines = frame(watch, watch.now(), sub.silent_for(), width, ellipsis,
                                  console.height)
                    live.update(Group(*lines, cut(Text(QUIT, "dim"), width, ellipsis)),
                                refresh=True)
                    drawn = time.monotonic()
    return Exit.OK



def _print_frames(sub: Any, watch: Watch, width: int, stop: Stop, as_json: bool,
                  ellipsis: str) -> int:
    """One plain frame per heartbeat, one after the other, and one when a heartbeat is
    missed or the gateway is taken for gone (or each heartbeat as one JSON line, of the
    nodes asked for: data, nothing else)."""
    was = watch.freshness(sub.silent_for())
    while not stop.requested:
        event = sub.receive(TICK)
        if isinstance(event, Status):
            watch.take(event)
        now_is = watch.freshness(sub.silent_for())
        changed, was = now_is != was, now_is
        if as_json:
            if isinstance(event, Status):
                print(json_line({**event.payload, "nodes": watch.shown()}), flush=True)
            continue
        if isinstance(event, Status) or changed:
            lines = frame(watch, watch.now(), sub.silent_for(), width, ellipsis)
            print("\n".join(line.plain for line in lines), end="\n\n", flush=True)
    return Exit.OK
