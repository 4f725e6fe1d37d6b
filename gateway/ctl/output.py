"""What gx2ctl prints: strict JSON lines, and readable text for each reply.

The gateway's results are data from another process (another version, perhaps): every
formatter here tolerates missing keys, extra keys and unexpected types, printing ``-``
rather than failing, so a newer or older gateway never makes gx2ctl crash.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from gateway.common.jsontext import json_line
from gateway.common.ops import BY_NAME
from gateway.common.protocol import Exit
from gateway.common.reading import number
from gateway.common.timetext import TIME, seconds_at

from .cells import MISSING, cell
from .statusview import status_lines, terminal_width, unhealthy


@dataclass(frozen=True)
class Shown:
    """What gx2ctl prints for a result, and why the run failed although the gateway
    answered (a ping some node did not answer), if it did."""

    lines: list[str]
    failure: str | None = None
    status: Exit = Exit.NODE_FAILED
    """The exit status a failure gives."""


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
        return (Shown([json_line(result)]) if shown is None
                else Shown([json_line(result)], shown.failure, shown.status))
    return shown


def table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    widths = [max(len(row[i]) for row in (header, *rows)) for i in range(len(header))]
    return ["  ".join(text.ljust(width) for text, width in zip(row, widths, strict=True))
            .rstrip() for row in (header, *rows)]


def answered(result: Mapping[str, Any]) -> dict[Any, bool]:
    """node -> whether it answered, from a ping result."""
    nodes = result.get("nodes")
    return {entry.get("node"): entry.get("answered") is True
            for entry in (nodes if isinstance(nodes, list) else [])
            if isinstance(entry, Mapping)}


@prints("status")
def _status(fields: Mapping[str, Any], result: Mapping[str, Any]) -> Shown:
    return Shown(status_lines(result, time.time(), terminal_width(bool(fields.get("wide")))),
                 unhealthy(result) if fields.get("check") else None)


@prints("ping")
def _ping(fields: Mapping[str, Any], result: Mapping[str, Any]) -> Shown:
    """One line per node asked about, in the order asked (missing: no answer; a node
    whose base station is down: why it was not pinged)."""
    requested = fields["nodes"]
    replies = answered(result)
    errors = ping_errors(result)
    silent = [str(node) for node in requested if not replies.get(node)]
    failure = (f"{len(silent)} of {len(requested)} nodes did not answer: "
               f"{', '.join(silent)}") if silent else None
    return Shown([f"{node} not pinged: {errors[node]}" if node in errors
                  else f"{node} {'answered' if replies.get(node) else 'no answer'}"
                  for node in requested], failure)


def ping_errors(result: Mapping[str, Any]) -> dict[Any, str]:
    """node -> why it could not be pinged (its base station down), from a ping result."""
    nodes = result.get("nodes")
    return {entry.get("node"): " ".join(entry["error"].split())
            for entry in (nodes if isinstance(nodes, list) else [])
            if isinstance(entry, Mapping) and isinstance(entry.get("error"), str)
            and entry["error"].strip()}


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
    """``12:03:04.123 UTC`` of a UNIX time, as every time is shown
    (:mod:`gateway.common.timetext`; ``-`` for anything else)."""
    return seconds_at(stamp, TIME) or MISSING


@prints("mark")
def _mark(fields: Mapping[str, Any], result: Mapping[str, Any]) -> Shown:
    nodes = result.get("nodes")
    named = (f" ({', '.join(cell(n) for n in nodes)})" if isinstance(nodes, list) and nodes
             else "")
    fields = result.get("fields")
    given = "".join(f"  {cell(k)}={cell(v)}" for k, v in fields.items()) if isinstance(
        fields, Mapping) else ""
    return Shown([f"mark at {time_of_day(result.get('time'))}: {cell(result.get('text'))}"
                  f"{named}{given}"])


@prints("reload")
def _reload(fields: Mapping[str, Any], result: Mapping[str, Any]) -> Shown:
    waiting = result.get("waiting_for")
    if isinstance(waiting, list) and waiting:
        return Shown([], f"the reload waits for the operation on node "
                     f"{', '.join(cell(n) for n in waiting)} and is applied when it ends "
                     "(the gateway's log says when)", Exit.NO_ANSWER)
    lines = [f"{what}: {', '.join(cell(n) for n in nodes)}"
             for what in ("added", "removed", "changed")
             if isinstance(nodes := result.get(what), list) and nodes]
    unconfirmed = [entry for entry in result.get("not_stopped") or ()
                   if isinstance(entry, Mapping)]
    lines += [f"removed {cell(e.get('node'))} not confirmed stopped: {cell(e.get('error'))}"
              for e in unconfirmed]
    return Shown(lines or ["reloaded: no node changed"],
                 failure="a removed node was not confirmed stopped" if unconfirmed else None)
