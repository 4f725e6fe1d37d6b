"""``gx2ctl status`` for a person: the gateway, each base station's line, the recording,
then a table of the nodes (grouped by base station when there are several), fitted to
the terminal's width, and why each node that is not OK is not. Under each station's
line, the nodes it heard that are not configured (``heard``), one a line.

The width: ``--wide`` shows every column whole; otherwise the terminal's (``COLUMNS``
if set, as ``ls`` and ``ps`` read it); printed to a pipe or a file without ``COLUMNS``,
every column too, so what a script or a log keeps is never cut. The lines above the
table break between their items (never inside one) with a hanging indent.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from gateway.common.protocol import HealthLevel
from gateway.common.reading import as_map, number

from .cells import ago, cell, clock_cell, count, duration, node_maps, reasons
from .columns import Column, clipped, fit, plain_table

LABEL = 9
"""Cells before an item line's first item ("gateway  ", "link     "): where a broken
line goes on."""
HEARD_SHOWN = 8
"""Nodes heard shown under a station (those streaming first, by address, then the most
recently heard); ``--json`` lists them all."""


def _key(key: str) -> Any:
    return lambda node, now: cell(node.get(key))


NODE_COLUMNS = (
    Column("node", _key("node")),
    Column("name", _key("name")),
    Column("state", _key("state")),
    Column("record", _key("record")),
    Column("configured", _key("configured")),
    Column("desired", _key("desired")),
    Column("rate Hz", _key("rate_hz")),
    Column("packets", _key("packets")),
    Column("published", _key("published")),
    Column("lost radio", _key("lost_radio")),
    Column("lost gateway", _key("lost_gateway")),
    Column("reboots", _key("reboots")),
    Column("silences", _key("silences")),
    Column("LQI", _key("lqi")),
    Column("RSSI", _key("rssi")),
    Column("last seen", lambda node, now: ago(node.get("last_seen"), now)),
    Column("clock", lambda node, now: clock_cell(node.get("clock"))),
    Column("health", _key("health")),
)
GIVE_WAY = (
    ("configured", 0), ("desired", 0), ("silences", 0), ("packets", 0), ("published", 0),
    ("name", 12), ("record", 14), ("LQI", 0), ("reboots", 0), ("lost gateway", 0),
    ("last seen", 0), ("clock", 0), ("name", 0), ("RSSI", 0), ("record", 7),
    ("rate Hz", 0), ("lost radio", 0), ("record", 0), ("state", 0),
)
"""What gives way, in turn, while the table is wider than the terminal (columns.py):
first what a person checks least often (what was configured and asked for, the
counters whose change matters more than their value), then the radio's detail and the
clock; the node, its state and its health stay to the last, the health always.
In 80 columns (tests/ctl/test_status_view.py): node, name and record (cut), state,
rate, losses over the radio, LQI, RSSI, health; in 120 the gateway's losses, reboots,
last seen and the clock come back; ``--wide``: everything."""


def terminal_width(wide: bool) -> int | None:
    """The width to fit (None: every column, whole)."""
    if wide:
        return None
    columns = os.environ.get("COLUMNS", "")
    if columns.isdecimal() and int(columns) > 0:
        return int(columns)
    try:
        return os.get_terminal_size(sys.stdout.fileno()).columns if sys.stdout.isatty() \
            else None
    except (AttributeError, ValueError, OSError):
        return None


def items_line(label: str, items: Sequence[str], width: int | None,
               separator: str = ",") -> list[str]:
    """``label`` then ``items`` joined by ``separator`` and a space, broken between
    items to fit ``width`` (an item longer than a line is cut), the lines after the
    first indented."""
    lines: list[str] = []
    line, fresh = label.ljust(LABEL - 1), True
    for number_, item in enumerate(items):
        piece = item if number_ == len(items) - 1 else item + separator
        if not fresh and width is not None and len(line) + 1 + len(piece) > width:
            lines.append(line)
            line = " " * (LABEL - 1)
        line, fresh = f"{line} {piece}", False
    lines.append(line)
    return [clipped(text, width) for text in lines]


def station_maps(result: Mapping[str, Any]) -> list[Mapping[str, Any]]:
    """Each base station's map (name, nodes, the link's fields); an older gateway's
    status has only ``link``: that is its one station."""
    stations = result.get("stations")
    maps = [as_map(s) for s in stations] if isinstance(stations, list) else []
    return maps or [as_map(result.get("link"))]


def line_share(link: Mapping[str, Any]) -> str:
    """``line 87% of 11,520 B/s`` (``, over capacity`` when the gateway says so), or
    "" from a gateway that does not measure it."""
    rate, line = number(link.get("bytes_per_s")), number(link.get("line_bytes_per_s"))
    if rate is None or not line:
        return ""
    return (f"line {100 * rate / line:.0f}% of {line:,.0f} B/s"
            + (" OVER CAPACITY" if link.get("over_capacity") is True else ""))


def link_items(link: Mapping[str, Any], now: float) -> list[str]:
    since = number(link.get("since"))
    for_how_long = f" for {duration(now - since)}" if since is not None else ""
    error = link.get("error")
    why = (f" ({cell(error)})" if link.get("state") != "up" and isinstance(error, str)
           and error else "")
    share = line_share(link)
    # the port and the state apart: a long port name (/dev/serial/by-id/...) cut to the
    # width must not take the state and its reason with it
    return [cell(link.get("port")), f"{cell(link.get('state'))}{for_how_long}{why}",
            *([share] if share else []),
            f"reconnects {cell(link.get('reconnects'))}",
            f"read {count(link.get('bytes_read'), 'bytes')}",
            f"discarded {count(link.get('discarded_bytes'), 'bytes')}"]


def heard_item(heard: Mapping[str, Any], now: float) -> str:
    """One node heard: ``81 streaming accel_angrate at 100 Hz, RSSI -61, last 0.3 s
    ago``."""
    rate, record, rssi = number(heard.get("rate_hz")), heard.get("record"), heard.get("rssi")
    what = (f" streaming {cell(record)} at {rate:g} Hz" if rate is not None
            else f" sent {cell(record)}" if record is not None
            else " powered up (a discovery packet)" if heard.get("announced") is not None
            else "")
    return (f"{cell(heard.get('address'))}{what}"
            + (f", RSSI {number(rssi):.0f}" if number(rssi) is not None else "")
            + f", last {ago(heard.get('last_heard'), now)}")


def heard_lines(station: Mapping[str, Any], now: float, width: int | None) -> list[str]:
    """The nodes a station heard that are not configured, one a line under its own."""
    heard = [as_map(h) for h in station.get("heard") or () if isinstance(h, Mapping)]
    heard.sort(key=lambda h: (1, -(number(h.get("last_heard")) or 0.0))
               if number(h.get("rate_hz")) is None else (0, number(h.get("address")) or 0))
    lines = [clipped(f"{'':{LABEL - 1}} heard, not configured: {heard_item(h, now)}", width)
             for h in heard[:HEARD_SHOWN]]
    if len(heard) > HEARD_SHOWN:
        lines.append(clipped(f"{'':{LABEL - 1}} and {len(heard) - HEARD_SHOWN} more heard "
                             "(gx2ctl --json status lists them)", width))
    return lines


def status_lines(result: Mapping[str, Any], now: float, width: int | None = None) -> list[str]:
    """Every line of a readable status, none wider than ``width`` (None: no limit)."""
    lines = heading_lines(result, now, width)
    nodes = node_maps(result)
    if not nodes:
        return [*lines, "no nodes"]
    stations = station_maps(result)
    lines.append("")
    lines += node_table([Group(None, nodes, stations if len(stations) > 1 else [])],
                        now, width)
    return lines + reason_lines(nodes, width)


def heading_lines(result: Mapping[str, Any], now: float, width: int | None) -> list[str]:
    """The lines above the table: the gateway, each base station's line, the recording,
    the replay."""
    gateway = as_map(result.get("gateway"))
    health = gateway.get("health")
    why = reasons(gateway)
    lines = items_line("gateway", [
        f"version {cell(gateway.get('version'))}", f"up {duration(gateway.get('uptime'))}",
        f"publish {cell(gateway.get('publish_endpoint'))}",
        f"control {cell(gateway.get('control_endpoint'))}",
        *([f"health {cell(health)}" + (f" ({why})" if why else "")]
          if health is not None else [])], width)
    stations = station_maps(result)
    several = len(stations) > 1
    for station in stations:
        label = cell(station.get("name")) if several else "link"
        lines += items_line(label, link_items(station, now), width)
        lines += heard_lines(station, now, width)
    recording = result.get("recording")
    if isinstance(recording, Mapping):
        error = recording.get("error")
        lines += items_line("record", [
            cell(recording.get("file") or recording.get("directory")),
            f"written {cell(recording.get('written'))}",
            f"dropped {cell(recording.get('dropped'))}"
            + (f" (last error: {cell(error)})" if isinstance(error, str) and error else ""),
            *_kept(recording)], width)
    lsl = result.get("lsl")
    if isinstance(lsl, Mapping):
        streams = lsl.get("streams")
        count = len(streams) if isinstance(streams, list) else streams
        lines += items_line("lsl", [
            f"{cell(count)} stream{'' if count == 1 else 's'}",
            f"pushed {cell(lsl.get('pushed'))}", f"dropped {cell(lsl.get('dropped'))}"],
            width)
    mqtt = result.get("mqtt")
    if isinstance(mqtt, Mapping):
        error = mqtt.get("error")
        dropped = as_map(mqtt.get("dropped"))
        lines += items_line("mqtt", [
            f"{cell(mqtt.get('url'))} {cell(mqtt.get('topic'))}/",
            "connected" if mqtt.get("connected") is True else "not connected"
            + (f" ({cell(error)})" if isinstance(error, str) and error else ""),
            f"sent {cell(mqtt.get('sent'))}",
            f"dropped {cell(dropped.get('queue'))} (queue full), "
            f"{cell(dropped.get('offline'))} (broker away)"], width)
    replay = result.get("replay")
    if isinstance(replay, Mapping):
        lines += items_line("replay", [
            f"{cell(replay.get('reads'))} reads played"
            + (", finished" if replay.get("finished") is True else "")], width)
    return lines


def reason_lines(nodes: Sequence[Mapping[str, Any]], width: int | None,
                 prefix: str = "") -> list[str]:
    """Why each node that is not OK is not (``prefix``: the gateway's name and a /)."""
    lines = []
    for node in nodes:
        if why := reasons(node):
            lines += items_line(f"{prefix}{cell(node.get('node'))} {cell(node.get('health'))}:",
                                why.split("; "), width, ";")
    return lines


@dataclass(frozen=True)
class Group:
    """The nodes of one gateway in the table, under a line ``== title`` (none for the
    only gateway), by base station when ``stations`` are given."""

    title: str | None
    nodes: Sequence[Mapping[str, Any]]
    stations: Sequence[Mapping[str, Any]] = ()


def node_table(groups: Sequence[Group], now: float, width: int | None) -> list[str]:
    """The table of nodes: one set of columns, fitted to the width over every group's
    rows; each group under its title, and within it, given its stations, each
    station's nodes under a line naming the station and its line's share."""
    nodes = [node for group in groups for node in group.nodes]
    rows = [[column.cell(node, now) for column in NODE_COLUMNS] for node in nodes]
    shown = fit(NODE_COLUMNS, rows, width, GIVE_WAY)
    header, *body = plain_table(NODE_COLUMNS, rows, shown)
    lines = [header]
    for group in groups:
        mine, body = body[:len(group.nodes)], body[len(group.nodes):]
        if group.title is not None:
            lines.append(clipped(group.title, width))
        lines += by_station(group.nodes, mine, group.stations, width)
    return lines


def by_station(nodes: Sequence[Mapping[str, Any]], rows: list[str],
               stations: Sequence[Mapping[str, Any]], width: int | None) -> list[str]:
    """The rows under a line for each of ``stations`` (none: as they are)."""
    if not stations:
        return rows
    lines = []
    names = [cell(s.get("name")) for s in stations]
    for name, station in zip(names, stations, strict=True):
        group = [row for node, row in zip(nodes, rows, strict=True)
                 if cell(node.get("station")) == name]
        share = line_share(station)
        lines.append(clipped(f"-- {name} ({cell(station.get('state'))}"
                             + (f", {share}" if share else "") + ")", width))
        lines += group or ["(no nodes)"]
    others = [row for node, row in zip(nodes, rows, strict=True)
              if cell(node.get("station")) not in names]
    if others:
        lines += ["-- no station", *others]
    return lines


def _kept(recording: Mapping[str, Any]) -> list[str]:
    """What the recordings of the directory take, and the oldest kept (nothing from a
    gateway that does not say)."""
    size, oldest = number(recording.get("bytes")), recording.get("oldest")
    if size is None:
        return []
    name = oldest.rsplit("/", 1)[-1] if isinstance(oldest, str) and oldest else ""
    return [f"{size / 1e6:.1f} MB kept" + (f" since {name}" if name else "")]


def unhealthy(result: Mapping[str, Any]) -> str | None:
    """Why a status is not all well (a base station's link down, the gateway itself not
    OK, a node not OK), or None. A gateway that reports no health of its own (an older
    one) is judged by its links and nodes."""
    problems = []
    stations = station_maps(result)
    down = [s for s in stations if s.get("state") != "up"]
    if len(stations) == 1 and down:
        problems.append(f"the link is {cell(down[0].get('state'))}")
    elif down:
        problems.append(f"{len(down)} of {len(stations)} base stations not up: "
                        + ", ".join(f"{cell(s.get('name'))} {cell(s.get('state'))}"
                                    for s in down))
    gateway = as_map(result.get("gateway"))
    health = gateway.get("health")
    if health is not None and health != HealthLevel.OK:
        why = reasons(gateway)
        problems.append(f"the gateway is {cell(health)}" + (f": {why}" if why else ""))
    if not down:
        nodes = node_maps(result)
        bad = [f"{cell(n.get('node'))} {cell(n.get('health'))}" for n in nodes
               if n.get("health") != HealthLevel.OK]
        if not nodes:
            problems.append("the gateway reported no nodes")
        elif bad:
            problems.append(f"{len(bad)} of {len(nodes)} nodes not OK: {', '.join(bad)}")
    return "; ".join(problems) or None

