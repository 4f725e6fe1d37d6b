"""The ops of a step or two, one async function each, registered with
:func:`~.opcontext.handles`: status, ping, start and stop, poll, EEPROM, rate, info,
reload and mark.

Single steps (a poll) and multi-step ones (write then verify) read top to bottom here;
the scheduler decides when each packet goes out, and the supervisor owns everything
about a node's stream (``start`` and ``stop`` change what it pursues).
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Callable
from typing import Any

from aspp import commands
from aspp.commands import DOCUMENTED_EEPROM, EEPROM_DIVIDER
from aspp.frame import encode_ping
from aspp.records import Record
from aspp.timing import data_rate, divider_for_rate

from .errors import NodeError, OpError, Refused
from .opcontext import Operations, Result, handles
from .requests import answer_within
from .station.nodes import Node

RELOAD_SHARE = 0.8
"""Of the time a reload request is answered within: how long it waits for operations
on the nodes it changes before answering that it waits (it goes on, and is logged)."""


@handles("status")
async def status(gw: Operations, request: Any) -> Result:
    return gw.status()


@handles("ping")
async def ping(gw: Operations, request: Any) -> Result:
    """Each node its own answer: a node whose base station is down is reported as such
    (``error``) beside the others' answers, never the whole request failed for it."""
    addresses = request.nodes
    # a configured node is pinged through its own base station, any other address
    # through the first (one wireless ping reaches only its station's channel)
    stations = [gw.station_of.get(a, gw.stations[0]) for a in addresses]
    results = await asyncio.gather(*(station.scheduler.ping(a, encode_ping(a))
                                     for station, a in zip(stations, addresses, strict=True)),
                                   return_exceptions=True)
    nodes = []
    for address, result in zip(addresses, results, strict=True):
        entry: Result = {"node": address, "answered": result is True}
        if isinstance(result, BaseException):
            if not isinstance(result, OpError):
                raise result  # a bug: the control server answers and logs it
            if not isinstance(result, NodeError):  # (no answer byte at all: not answered)
                entry["error"] = str(result)  # its base station is down
        nodes.append(entry)
    return {"nodes": nodes}


@handles("start")
async def start(gw: Operations, request: Any) -> Result:
    node = gw.node(request.node)
    return await gw.supervisor(node).start(node, request.record)


@handles("stop")
async def stop(gw: Operations, request: Any) -> Result:
    node = gw.node(request.node)
    return await gw.supervisor(node).stop(node)


@handles("poll")
async def poll(gw: Operations, request: Any) -> Result:
    node = gw.node(request.node)
    return (await gw.scheduler(node).ask(node, commands.poll(request.record))).payload


@handles("eeprom_read")
async def eeprom_read(gw: Operations, request: Any) -> Result:
    node = gw.node(request.node)
    value = (await gw.scheduler(node).ask(node, commands.read_eeprom(request.address))
             ).record["value"]
    return {"node": node.address, "address": request.address, "value": value}


@handles("eeprom_write")
async def eeprom_write(gw: Operations, request: Any) -> Result:
    return await write_word(gw, gw.node(request.node), request.address, request.value)


async def write_word(gw: Operations, node: Node, word: int, value: int) -> Result:
    """Write, retry once if the reply shows the old word (the reference: the first
    write after power-up may fail), then read it back."""
    gw.check_writes_allowed("writing EEPROM")
    if word not in DOCUMENTED_EEPROM and not gw.allow_any_eeprom_address:
        known = ", ".join(f"0x{a:04X} ({what})" for a, what in DOCUMENTED_EEPROM.items())
        raise Refused(f"EEPROM 0x{word:04X} is not a word the reference documents "
                      f"({known}); to write it anyway set "
                      "control.allow_any_eeprom_address: true and restart the gateway")
    attempts = 0
    while True:
        attempts += 1
        stored = (await gw.scheduler(node).ask(node, commands.write_eeprom(word, value))
                  ).record["value"]
        if stored == value:
            break
        if attempts == 2:
            raise NodeError(f"node {node.address}: EEPROM 0x{word:04X} still holds "
                            f"{stored} after 2 writes of {value}")
    readback = (await gw.scheduler(node).ask(node, commands.read_eeprom(word))).record["value"]
    if readback != value:
        raise NodeError(f"node {node.address}: EEPROM 0x{word:04X} reads back "
                        f"{readback}, not {value}")
    if word == EEPROM_DIVIDER:
        node.divider_read(value)
    return {"node": node.address, "address": word, "value": value, "attempts": attempts}


@handles("rate")
async def rate(gw: Operations, request: Any) -> Result:
    node = gw.node(request.node)
    divider = divider_for_rate(request.hz)  # (the request model checked it)
    await write_word(gw, node, EEPROM_DIVIDER, divider)
    return {"node": node.address, "hz": round(data_rate(divider), 3), "divider": divider}


@handles("info")
async def info(gw: Operations, request: Any) -> Result:
    node = gw.node(request.node)

    async def ask(command: commands.Command) -> Record:
        return (await gw.scheduler(node).ask(node, command)).record
    return {"node": node.address, **await identify(node.address, ask)}


IDENTITY = ("model_number", "serial_number", "model_name", "options")
"""The four identifier strings (0xEA), by selector."""


async def identify(address: int, ask: Callable[[commands.Command], Awaitable[Record]]
                   ) -> Result:
    """What a node is: its firmware version and four identifier strings, each read with
    ``ask`` (a command to the node, its reply's record)."""
    result: Result = {}
    for _, command, fields in identity_reads(address):
        result.update(fields(await ask(command)))
    return result


def identity_reads(address: int) -> list[tuple[str, commands.Command,
                                               Callable[[Record], Result]]]:
    """The reads :func:`identify` makes, one at a time: the field each fills, its
    command, and the fields its reply's record gives (a scan cut short goes on from
    the first read it lacks)."""
    def version(record: Record) -> Result:
        return {"firmware": record["version"],
                "firmware_version": commands.firmware_text(record["version"])}

    def text(selector: int) -> Callable[[Record], Result]:
        def field(record: Record) -> Result:
            if record["selector"] != selector:  # a late answer to an earlier request
                raise NodeError(f"node {address}: asked for identifier {selector}, "
                                f"got {record['selector']}")
            return {IDENTITY[selector]: record["text"]}
        return field
    return [("firmware", commands.firmware_version(), version),
            *((key, commands.device_id(selector), text(selector))
              for selector, key in enumerate(IDENTITY))]


@handles("reload")
async def reload(gw: Operations, request: Any) -> Result:
    """As SIGHUP: the nodes of the configuration file applied, or the reload refused
    whole (Invalid: the file does not check; Refused: it needs a restart)."""
    if gw.reload is None:
        raise Refused("reload: this gateway was not started from a configuration file")
    return await gw.reload(None if request.timeout is None
                           else RELOAD_SHARE * answer_within(request.timeout))


@handles("mark")
async def mark(gw: Operations, request: Any) -> Result:
    """The moment the gateway took it, on its clock: the one every record's ``time`` and
    ``host_time`` are on, so a mark lines up with the samples around it."""
    if gw.replaying:
        raise Refused("mark: this gateway is replaying a recording; a mark belongs to "
                      "what is happening now, on a live gateway")
    nodes = [gw.node(address).address for address in request.nodes]
    now = time.time()
    pairs = [field.partition("=")[::2] for field in request.fields or ()]
    fields = dict(pairs)
    if len(fields) < len(pairs):  # (the last would win unseen: say which)
        twice = sorted({key for key, _ in pairs if [k for k, _ in pairs].count(key) > 1})
        raise Refused(f"mark: field {', '.join(twice)} given more than once")
    payload = {"text": request.text, "time": now, "host_time": now, "nodes": nodes,
               "fields": fields}
    if gw.publish_mark is None or not await gw.publish_mark(payload):
        raise OpError("the mark could not be published (the gateway's log says why)")
    return dict(payload)
