"""What gx2ctl prints: strict JSON lines, and readable text for each reply.

The gateway's results are data from another process (another version, perhaps): every
formatter here tolerates missing keys, extra keys and unexpected types, printing ``-``
rather than failing, so a newer or older gateway never makes gx2ctl crash.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from gateway.common.jsontext import json_line
from gateway.common.ops import BY_NAME
from gateway.common.protocol import HealthLevel
from gateway.common.reading import as_map, number

MISSING = "-"


@dataclass(frozen=True)
class Shown:
    """What gx2ctl prints for a result, and why the run failed although the gateway
    answered (a ping some node did not answer), if it did."""

    lines: list[str]
    failure: str | None = None


Printer = Callable[[Mapping[str, Any], Mapping[str, Any]], Shown]
PRINTERS: dict[str, Printer] = {}


def prints(op: str) -> Callable[[Printer], Printer]:
    """Register the readable printer of op ``op``: it gets the request's fields and the
    result. An op without one is printed as one JSON line."""
    if op not in BY_NAME:
        raise ValueError(f"{op!r} is not in the op table")

    def register(printer: Printer) -> Printer:
        PRINTERS[op] = printer
        return printer
    return register


def show(op: str, fields: Mapping[str, Any], result: Mapping[str, Any],
         as_json: bool) -> Shown:
    printer = PRINTERS.get(op)
    shown = printer(fields, result) if printer is not None else None
    if as_json or shown is None:
        return Shown([json_line(result)], shown.failure if shown else None)
    return shown


def cell(value: Any) -> str:
    """One table cell or inline value, readable whatever its type."""
    if value is None:
        return MISSING
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:g}" if math.isfinite(value) else MISSING
    text = str(value)
    return " ".join(text.split()) or MISSING


def duration(seconds: Any) -> str:
    """``12.3 s``, ``4 min 05 s``, ``2 h 03 min``, ``3 d 04 h``."""
    value = number(seconds)
    if value is None:
        return MISSING
    if value < 60:
        return f"{max(value, 0.0):.1f} s"
    whole = int(value)
    days, rest = divmod(whole, 86400)
    hours, rest = divmod(rest, 3600)
    minutes, secs = divmod(rest, 60)
    if days:
        return f"{days} d {hours:02d} h"
    if hours:
        return f"{hours} h {minutes:02d} min"
    return f"{minutes} min {secs:02d} s"


def ago(timestamp: Any, now: float) -> str:
    """How long before ``now`` a UNIX time was; ``never`` for None."""
    if timestamp is None:
        return "never"
    value = number(timestamp)
    return MISSING if value is None else f"{duration(now - value)} ago"


def table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    widths = [max(len(row[i]) for row in (header, *rows)) for i in range(len(header))]
    return ["  ".join(text.ljust(width) for text, width in zip(row, widths, strict=True))
            .rstrip() for row in (header, *rows)]


def _count(value: Any, unit: str) -> str:
    text = cell(value)
    return f"{text} {unit}" if text != MISSING else MISSING


NODE_COLUMNS = ("node", "name", "state", "record", "configured", "desired", "rate Hz",
                "packets", "published", "lost radio", "lost gateway", "reboots",
                "silences", "LQI", "RSSI", "last seen", "clock", "health")


def clock_cell(clock: Any) -> str:
    """A node's clock estimate in a few characters: its drift and whether it is locked
    ("+40.1 ppm" locked, "~+40.1 ppm" still settling, "-" before a timed record)."""
    if not isinstance(clock, Mapping):
        return "-"
    drift = number(clock.get("drift_ppm"))
    shown = "?" if drift is None else f"{drift:+.1f} ppm"
    return shown if clock.get("locked") is True else f"~{shown}"


def status_lines(result: Mapping[str, Any], now: float) -> list[str]:
    """The gateway line, the link line and a table of nodes."""
    gateway = as_map(result.get("gateway"))
    link = as_map(result.get("link"))
    health = gateway.get("health")
    why = reasons(gateway)
    lines = [f"gateway  version {cell(gateway.get('version'))}, "
             f"up {duration(gateway.get('uptime'))}, "
             f"publish {cell(gateway.get('publish_endpoint'))}, "
             f"control {cell(gateway.get('control_endpoint'))}"
             + (f", health {cell(health)}" if health is not None else "")
             + (f" ({why})" if why else "")]
    since = number(link.get("since"))
    for_how_long = f" for {duration(now - since)}" if since is not None else ""
    error = link.get("error")
    why = (f" ({cell(error)})" if link.get("state") != "up" and isinstance(error, str)
           and error else "")
    lines.append(f"link     {cell(link.get('port'))} {cell(link.get('state'))}{for_how_long}"
                 f"{why}, reconnects {cell(link.get('reconnects'))}, "
                 f"read {_count(link.get('bytes_read'), 'bytes')}, "
                 f"discarded {_count(link.get('discarded_bytes'), 'bytes')}")
    recording = result.get("recording")
    if isinstance(recording, Mapping):
        error = recording.get("error")
        lines.append(f"record   {cell(recording.get('file') or recording.get('directory'))}, "
                     f"written {cell(recording.get('written'))}, "
                     f"dropped {cell(recording.get('dropped'))}"
                     + (f" (last error: {cell(error)})" if isinstance(error, str) and error
                        else "") + _kept(recording))
    replay = result.get("replay")
    if isinstance(replay, Mapping):
        lines.append(f"replay   {cell(replay.get('reads'))} reads played"
                     f"{', finished' if replay.get('finished') is True else ''}")
    rows = [[cell(node.get("node")), cell(node.get("name")), cell(node.get("state")),
             cell(node.get("record")), cell(node.get("configured")),
             cell(node.get("desired")), cell(node.get("rate_hz")), cell(node.get("packets")),
             cell(node.get("published")), cell(node.get("lost_radio")),
             cell(node.get("lost_gateway")), cell(node.get("reboots")),
             cell(node.get("silences")), cell(node.get("lqi")), cell(node.get("rssi")),
             ago(node.get("last_seen"), now), clock_cell(node.get("clock")),
             cell(node.get("health"))] for node in node_maps(result)]
    if rows:
        lines.append("")
        lines.extend(table(NODE_COLUMNS, rows))
        lines.extend(f"{cell(node.get('node'))} {cell(node.get('health'))}: {why}"
                     for node in node_maps(result) if (why := reasons(node)))
    else:
        lines.append("no nodes")
    return lines


def _kept(recording: Mapping[str, Any]) -> str:
    """What the recordings of the directory take, and the oldest kept ("" from a
    gateway that does not say)."""
    size, oldest = number(recording.get("bytes")), recording.get("oldest")
    if size is None:
        return ""
    name = oldest.rsplit("/", 1)[-1] if isinstance(oldest, str) and oldest else ""
    return f", {size / 1e6:.1f} MB kept" + (f" since {name}" if name else "")


def node_maps(result: Mapping[str, Any]) -> list[Mapping[str, Any]]:
    nodes = result.get("nodes")
    return [node for node in (nodes if isinstance(nodes, list) else [])
            if isinstance(node, Mapping)]


def reasons(node: Mapping[str, Any]) -> str:
    """Why a node (or the gateway itself) is not OK, in one line ("" if it is, or if
    the gateway gave none)."""
    given = node.get("reasons")
    return "; ".join(cell(r) for r in given) if isinstance(given, list) else ""


def unhealthy(result: Mapping[str, Any]) -> str | None:
    """Why a status is not all well (the link down, the gateway itself not OK, a node
    not OK), or None. A gateway that reports no health of its own (an older one) is
    judged by its link and nodes."""
    problems = []
    link = as_map(result.get("link"))
    if link.get("state") != "up":
        problems.append(f"the link is {cell(link.get('state'))}")
    gateway = as_map(result.get("gateway"))
    health = gateway.get("health")
    if health is not None and health != HealthLevel.OK:
        why = reasons(gateway)
        problems.append(f"the gateway is {cell(health)}" + (f": {why}" if why else ""))
    if link.get("state") == "up":
        nodes = node_maps(result)
        bad = [f"{cell(n.get('node'))} {cell(n.get('health'))}" for n in nodes
               if n.get("health") != HealthLevel.OK]
        if not nodes:
            problems.append("the gateway reported no nodes")
        elif bad:
            problems.append(f"{len(bad)} of {len(nodes)} nodes not OK: {', '.join(bad)}")
    return "; ".join(problems) or None


def answered(result: Mapping[str, Any]) -> dict[Any, bool]:
    """node -> whether it answered, from a ping result."""
    nodes = result.get("nodes")
    return {entry.get("node"): entry.get("answered") is True
            for entry in (nodes if isinstance(nodes, list) else [])
            if isinstance(entry, Mapping)}


@prints("status")
def _status(fields: Mapping[str, Any], result: Mapping[str, Any]) -> Shown:
    return Shown(status_lines(result, time.time()),
                 unhealthy(result) if fields.get("check") else None)


@prints("ping")
def _ping(fields: Mapping[str, Any], result: Mapping[str, Any]) -> Shown:
    """One line per node asked about, in the order asked (missing: no answer)."""
    requested = fields["nodes"]
    replies = answered(result)
    silent = [str(node) for node in requested if not replies.get(node)]
    failure = (f"{len(silent)} of {len(requested)} nodes did not answer: "
               f"{', '.join(silent)}") if silent else None
    return Shown([f"{node} {'answered' if replies.get(node) else 'no answer'}"
                  for node in requested], failure)


def _word(value: Any) -> str:
    if isinstance(value, int) and not isinstance(value, bool) and 0 <= value <= 0xFFFF:
        return f"{value} (0x{value:04X})"
    return cell(value)


def _address(value: Any) -> str:
    if isinstance(value, int) and not isinstance(value, bool) and 0 <= value <= 0xFFFF:
        return f"0x{value:04X}"
    return cell(value)


def _attempts(value: Any) -> str:
    return f"{cell(value)} attempt{'' if value == 1 else 's'}"


INFO_KEYS = (("node", "node"), ("firmware", "firmware"), ("model_number", "model number"),
             ("serial_number", "serial number"), ("model_name", "model name"),
             ("options", "options"))


@prints("start")
def _start(fields: Mapping[str, Any], result: Mapping[str, Any]) -> Shown:
    return Shown([f"{cell(result.get('node'))} streaming {cell(result.get('record'))} "
                  f"({_attempts(result.get('attempts'))})"])


@prints("stop")
def _stop(fields: Mapping[str, Any], result: Mapping[str, Any]) -> Shown:
    elapsed = number(result.get("elapsed"))
    took = f", {elapsed:.2f} s" if elapsed is not None else ""
    return Shown([f"{cell(result.get('node'))} stopped "
                  f"({_attempts(result.get('attempts'))}{took})"])


@prints("poll")
def _poll(fields: Mapping[str, Any], result: Mapping[str, Any]) -> Shown:
    return Shown([json_line(result)])  # a record is data: always one JSON line


@prints("eeprom_read")
def _eeprom_read(fields: Mapping[str, Any], result: Mapping[str, Any]) -> Shown:
    return Shown([f"{cell(result.get('node'))} eeprom[{_address(result.get('address'))}]"
                  f" = {_word(result.get('value'))}"])


@prints("eeprom_write")
def _eeprom_write(fields: Mapping[str, Any], result: Mapping[str, Any]) -> Shown:
    return Shown([f"{cell(result.get('node'))} eeprom[{_address(result.get('address'))}]"
                  f" = {_word(result.get('value'))}, written and read back "
                  f"({_attempts(result.get('attempts'))})"])


@prints("rate")
def _rate(fields: Mapping[str, Any], result: Mapping[str, Any]) -> Shown:
    return Shown([f"{cell(result.get('node'))} rate {cell(result.get('hz'))} Hz "
                  f"(divider {cell(result.get('divider'))})"])


@prints("info")
def _info(fields: Mapping[str, Any], result: Mapping[str, Any]) -> Shown:
    width = max(len(label) for _, label in INFO_KEYS)
    values = dict(result)
    if isinstance(result.get("firmware_version"), str):
        values["firmware"] = f"{cell(result.get('firmware'))} ({result['firmware_version']})"
    return Shown([f"{label.ljust(width)}  {cell(values.get(key))}"
                  for key, label in INFO_KEYS])


def _vector(value: Any, unit: str) -> str:
    if not isinstance(value, list) or len(value) != 3:
        return MISSING
    return "  ".join(f"{axis} {number(v):+.6f}" if number(v) is not None else f"{axis} -"
                     for axis, v in zip("xyz", value, strict=True)) + f" {unit}"


def _stream_line(node: str, result: Mapping[str, Any], what: str) -> list[str]:
    """What happened to the stream a quiet command stopped."""
    streamed = result.get("stream")
    if not isinstance(streamed, str):
        return []
    restored = result.get("restored")
    then = (f"{cell(restored)} started again" if isinstance(restored, str)
            else "not started again yet (the gateway keeps trying)")
    return [f"{node} streamed {streamed}: stopped for the {what}, {then}"]


@prints("bias_capture")
def _bias_capture(fields: Mapping[str, Any], result: Mapping[str, Any]) -> Shown:
    node = cell(result.get("node"))
    ms = number(result.get("ms"))
    over = f" over {ms / 1000:g} s" if ms is not None else ""
    return Shown([f"{node} gyro bias captured{over}: "
                  f"{_vector(result.get('gyro_bias'), 'rad/s')}",
                  *_stream_line(node, result, "capture")])


UNITS = {"accel": "g", "gyro": "rad/s"}


@prints("bias_set")
def _bias_set(fields: Mapping[str, Any], result: Mapping[str, Any]) -> Shown:
    sensor = cell(result.get("sensor"))
    return Shown([f"{cell(result.get('node'))} {sensor} bias correction set (echoed): "
                  f"{_vector(result.get('bias'), UNITS.get(sensor, ''))}"])


@prints("store")
def _store(fields: Mapping[str, Any], result: Mapping[str, Any]) -> Shown:
    return Shown([f"{cell(result.get('node'))} {cell(result.get('sensor'))} bias stored in "
                  f"non-volatile memory (quantity {cell(result.get('quantity'))})"])


@prints("temperature")
def _temperature(fields: Mapping[str, Any], result: Mapping[str, Any]) -> Shown:
    codes = result.get("codes")
    codes = codes if isinstance(codes, list) and len(codes) == 4 else [None] * 4
    gyros = result.get("gyro_c")
    gyros = gyros if isinstance(gyros, list) and len(gyros) == 3 else [None] * 3
    rows = [["accel", result.get("accel_c"), codes[0]],
            *[[f"gyro {axis}", value, code]
              for axis, value, code in zip("xyz", gyros, codes[1:], strict=True)]]
    lines = [f"node {cell(result.get('node'))} temperatures (gyro model "
             f"{cell(result.get('gyro_model'))})"]
    lines += table(("sensor", "deg C", "code"),
                   [[name, f"{v:.2f}" if (v := number(value)) is not None else MISSING,
                     cell(code)] for name, value, code in rows])
    return Shown(lines)


@prints("selftest")
def _selftest(fields: Mapping[str, Any], result: Mapping[str, Any]) -> Shown:
    node = cell(result.get("node"))
    checks = [c for c in (result.get("checks") or []) if isinstance(c, Mapping)]
    rows = [[cell(c.get("name")),
             f"{v:+.4f}" if (v := number(c.get("value"))) is not None else MISSING,
             f"{cell(c.get('limit'))} {cell(c.get('unit'))}".rstrip(" -"),
             "pass" if c.get("passed") is True else "FAIL"] for c in checks]
    failed = [row[0] for row in rows if row[3] == "FAIL"]
    verdict = (f"{node} self-test passed ({len(rows)} checks)" if rows and not failed
               else f"{node} self-test FAILED: {len(failed)} of {len(rows)} checks")
    return Shown([*table(("check", "value", "limit", "result"), rows), verdict,
                  *_stream_line(node, result, "test")],
                 f"node {node} failed its self-test: {', '.join(failed)}"
                 if failed or not rows else None)


def time_of_day(stamp: Any) -> str:
    """``12:03:04.123``, local time, of a UNIX time (``-`` for anything else)."""
    value = number(stamp)
    if value is None:
        return MISSING
    try:
        whole = time.strftime("%H:%M:%S", time.localtime(value))
    except (OverflowError, OSError, ValueError):
        return MISSING
    return f"{whole}.{int(value % 1 * 1000):03d}"


@prints("mark")
def _mark(fields: Mapping[str, Any], result: Mapping[str, Any]) -> Shown:
    nodes = result.get("nodes")
    named = (f" ({', '.join(cell(n) for n in nodes)})" if isinstance(nodes, list) and nodes
             else "")
    return Shown([f"mark at {time_of_day(result.get('time'))}: {cell(result.get('text'))}"
                  f"{named}"])
