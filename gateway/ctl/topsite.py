"""``gx2ctl top`` of several gateways: one table, each gateway's nodes under a line
naming it (its version, uptime and health counts, and what is wrong with its
heartbeat: waiting, stale or gone), then by base station as for one gateway. Each
gateway is watched as :mod:`gateway.ctl.top` watches one, on its own clock; one that
falls silent is greyed and said to be, and the others go on."""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from rich.console import Group
from rich.live import Live
from rich.text import Text

from gateway.client import Status
from gateway.common.jsontext import json_line
from gateway.common.protocol import Exit, HealthLevel
from gateway.common.reading import as_map

from .cells import cell, reasons
from .sitestream import Lookups, add, left_out, subscribe_all
from .subscribing import Source, Stop
from .top import QUIT, REDRAW, TICK, Watch, clock_text, grouped, header, keyboard, terminal, within
from .toptable import HEALTH_STYLE, cut, table
from .where import Gateway


@dataclass
class Watched:
    """One of the gateways top watches, by its name."""

    name: str
    watch: Watch
    silent_for: float = 0.0


def frame(watched: Sequence[Watched], width: int, ellipsis: str = "…",
          height: int | None = None, absent: Mapping[str, str] | None = None
          ) -> list[Text]:
    """Every line of one frame of several gateways, as :func:`gateway.ctl.top.frame`
    draws one: the columns' header, each gateway's line and its nodes (by station),
    each gateway not found yet or left out (``absent``: name -> why) as a line saying
    so, then why each node that is not OK is not (``NAME/NODE``)."""
    absent = absent or {}
    nodes, each = [], []
    for one in watched:
        shown = one.watch.shown()
        nodes += shown
        each += [(one.watch.now(), one.watch.stale_for(one.silent_for))] * len(shown)
    rows = table(nodes, time.time(), width, ellipsis, each=each)
    first = Text(f"gx2ctl top: {len(watched) + len(absent)} gateways ")
    first.append(clock_text(time.time()), "dim")
    head, rest = [first, rows[0]], rows[1:]
    body: list[Text] = []
    notes: list[Text] = []
    for one in watched:
        watch, shown = one.watch, one.watch.shown()
        mine, rest = rest[:len(shown)], rest[len(shown):]
        stale = watch.stale_for(one.silent_for) is not None
        said = header(watch, watch.now(), one.silent_for)
        body.append(Text(f"== {one.name}  ", "bold").append_text(said[0]))
        if said[3].plain:  # waiting for it, stale, gone, or restarted
            body.append(said[3])
        body += grouped(watch.status or {}, shown, mine, watch.now(), stale)
        notes += _notes(one.name, watch.status or {}, shown, stale)
    for name, why in absent.items():  # (issue 43: a dead one was off the screen)
        body.append(Text(f"== {name}  ", "bold").append(
            why, "yellow" if why.startswith(LOOKING) else "bold red"))
    if height is not None:
        body, notes = within(height - 1 - len(head), body, notes)
    return [cut(line, width, ellipsis) for line in (*head, *body, *notes)]


def _notes(name: str, status: Mapping[str, Any], nodes: Sequence[Mapping[str, Any]],
           stale: bool) -> list[Text]:
    def style(level: object) -> str:
        return "dim" if stale else HEALTH_STYLE.get(str(level), "")
    gateway = as_map(status.get("gateway"))
    health = gateway.get("health")
    notes = []
    if health is not None and health != HealthLevel.OK and (why := reasons(gateway)):
        notes.append(Text(f"{name} ").append(f"{cell(health)}: {why}", style(health)))
    for node in nodes:
        if node.get("health") != HealthLevel.OK and (why := reasons(node)):
            notes.append(Text(f"{name}/{cell(node.get('node'))} ").append(
                f"{cell(node.get('health'))}: {why}", style(node.get("health"))))
    return notes


LOOKING = "looking for it"
"""What a gateway not found yet is said to be (then found, or left out, and why)."""


def run_top_several(nodes: list[int], named: Sequence[Gateway], timeout: float,
                    as_json: bool) -> int:
    """Draw the gateways' statuses until ``q``, Ctrl-C or SIGTERM, each from when it is
    found; one that cannot be found is a line of the screen saying why (issue 43: it
    went to stderr, behind the full-screen view)."""
    stop = Stop()
    console, ellipsis = terminal()
    lookups = Lookups(nodes, named, timeout)
    first = lookups.first(lambda: stop.requested)
    if not first:
        return Exit.OK
    said: set[str] = set()
    with subscribe_all(nodes, first, status="only") as sub:
        watched: dict[str, Watched] = {}

        def adopt(found: Sequence[tuple[Gateway, Source]]) -> None:
            for gateway, source in found:
                watched[source.address] = Watched(
                    gateway.name, Watch(source.address, tuple(nodes), source.silence))

        def absent() -> dict[str, str]:
            return {**{name: f"{LOOKING} (asking it where it publishes)"
                       for name in lookups.pending},
                    **{name: f"left out: {why}" for name, why in lookups.missing.items()}}

        def look(event: object) -> str:
            """Take a heartbeat, and the gateways found since; the freshness of every
            gateway, to see a change."""
            for gateway, source in lookups.take() if lookups.pending else ():
                add(sub, source)
                adopt([(gateway, source)])
            if isinstance(event, Status):
                watched[event.gateway].watch.take(event)
            for address, one in watched.items():
                one.silent_for = sub.silent_for(address)
            return " ".join([*(one.watch.freshness(one.silent_for)
                               for one in watched.values()), *absent().values()])

        adopt(first)
        was = look(None)
        if as_json or not console.is_terminal:
            while not stop.requested:
                event = sub.receive(TICK)
                now_is = look(event)
                changed, was = now_is != was, now_is
                if as_json:
                    left_out(lookups, said)  # (stderr: stdout is one heartbeat a line)
                    if isinstance(event, Status):
                        one = watched[event.gateway]
                        print(json_line({**event.payload, "name": one.name,
                                         "nodes": one.watch.shown()}), flush=True)
                elif isinstance(event, Status) or changed:
                    lines = frame(list(watched.values()), console.width, ellipsis,
                                  absent=absent())
                    print("\n".join(line.plain for line in lines), end="\n\n", flush=True)
            return Exit.OK
        with keyboard() as pressed, Live(console=console, screen=True,
                                         auto_refresh=False) as live:
            drawn = 0.0
            while not stop.requested and not pressed():
                event = sub.receive(TICK)
                now_is = look(event)
                if event is not None or now_is != was or time.monotonic() - drawn >= REDRAW:
                    was = now_is
                    width = console.width
                    lines = frame(list(watched.values()), width, ellipsis, console.height,
                                  absent())
                    live.update(Group(*lines, cut(Text(QUIT, "dim"), width, ellipsis)),
                                refresh=True)
                    drawn = time.monotonic()
    return Exit.OK
