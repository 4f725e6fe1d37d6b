"""The ops that measure, correct and check what a node senses: bias capture (0xCD),
bias corrections (0xC9, 0xCA), keeping them (0xD0), temperatures (0xD1) and the
built-in test (0xFB). Each is a function registered under its row of the op table.

A bias capture and a self-test need the node quiet: its stream is stopped first and
started again afterwards (:meth:`Supervisor.quiet`). Writing a bias correction or
storing it changes what the node measures and keeps, so both are refused unless
``control.allow_eeprom_write`` is true, like EEPROM writes.
"""

from __future__ import annotations

import asyncio
import itertools
import logging
from collections.abc import Callable
from typing import Any

from aspp import commands
from aspp.selftest import BIT_OFF, NEGATIVE_RATE_BIT, POSITIVE_BIT, Sample, judge
from aspp.temperature import accel_celsius, gyro_celsius

from .errors import GoesOn, NodeError, OpError
from .opcontext import Operations, Result, handles
from .station.nodes import Node
from .station.scheduler import Priority

log = logging.getLogger("gx2.calibration")
SAMPLES = 10
"""Readings of the outputs in each phase of a self-test (after one discarded)."""
BIT_OFF_BACKOFF = (0.5, 1.0, 2.0, 5.0, 10.0, 30.0)
"""Between attempts to switch BIT off on a node that stopped answering in a self-test."""
QUANTITY = {"accel": 1, "gyro": 2}
"""0xD0's Transfer Quantity for each bias."""


# A capture cancelled (by its client, or its deadline) before 0xCD is written has sent
# the node nothing: it is dropped, and the node keeps its bias. Once 0xCD is written the
# node samples and then takes the new bias whatever the gateway does: the reference has
# no command that stops a capture or reads a bias back (to write the old one again). So
# from then on the capture runs to its end in the background, the node's stream is
# started again after it, and the result is logged; the request is answered at once
# with GoesOn, saying so. (Unless the gateway is shutting down: then it is cancelled.)
@handles("bias_capture")
async def bias_capture(gw: Operations, request: Any) -> Result:
    node = gw.node(request.node)
    loop = asyncio.get_running_loop()
    sent_at: list[float] = []
    capture = loop.create_task(_capture(gw, node, request.ms,
                                        lambda: sent_at.append(loop.time())))
    try:
        return await asyncio.shield(capture)
    except asyncio.CancelledError:
        if capture.done():  # it ended as it was cancelled: its result stands
            return capture.result()
        if not sent_at or gw.supervisor(node).closed:  # (at shutdown nothing outlives)
            capture.cancel()
            await asyncio.wait([capture])  # (the stream is given back)
            raise
        gw.spawn(_log_failure(capture, node))
        left = max(0.0, request.ms / 1000 - (loop.time() - sent_at[0]))
        raise GoesOn(f"bias capture on {node.address} goes on: the node is already "
                     f"sampling (a capture cannot be stopped) and takes its new gyro bias "
                     f"in {left:.1f} s; the gateway logs it") from None


async def _capture(gw: Operations, node: Node, ms: int,
                   on_sent: Callable[[], None]) -> Result:
    seconds = ms / 1000
    async with gw.supervisor(node).quiet(node) as held:
        # the reply comes only after the sampling time, and a capture is never sent
        # twice: the node would start sampling again
        answer = await gw.scheduler(node).send(node, commands.capture_gyro_bias(ms),
                                               takes=seconds, resend_unanswered=False,
                                               what=f"capture gyro bias ({seconds:g} s)",
                                               on_sent=on_sent)
    bias = answer.reply.record["gyro_bias"]
    log.info("node %s: gyro bias captured over %g s: %s rad/s%s", node.label, seconds,
             " ".join(f"{axis} {value:+.6f}" for axis, value in zip("xyz", bias, strict=True)),
             f"; {held.restored} started again" if held.restored else "")
    return {"node": node.address, "ms": ms, "gyro_bias": list(bias),
            "stream": held.streamed, "restored": held.restored}


async def _log_failure(capture: asyncio.Task[Result], node: Node) -> None:
    """A capture left to finish on its own: its success is logged by itself, a failure
    here (nobody else is waiting for it)."""
    try:
        await capture
    except OpError as error:
        log.warning("bias capture on %s, cancelled by its client while the node sampled, "
                    "failed: %s", node.label, error)


@handles("bias_set")
async def bias_set(gw: Operations, request: Any) -> Result:
    node = gw.node(request.node)
    gw.check_writes_allowed(f"writing the {request.sensor} bias correction")
    vector = (request.x, request.y, request.z)
    command = (commands.write_accel_bias(vector) if request.sensor == "accel"
               else commands.write_gyro_bias(vector))
    field = command.spec.arguments[0].name
    echoed = tuple((await gw.scheduler(node).ask(node, command)).record[field])  # type: ignore[arg-type]
    sent = tuple(command.arguments[field])  # type: ignore[arg-type]
    if echoed != sent:  # (as float32, the precision the node keeps)
        raise NodeError(f"node {node.address}: sent {request.sensor} bias {list(sent)}, "
                        f"it echoed {list(echoed)}")
    return {"node": node.address, "sensor": request.sensor, "bias": list(echoed)}


@handles("store")
async def store(gw: Operations, request: Any) -> Result:
    node = gw.node(request.node)
    gw.check_writes_allowed(f"storing the {request.sensor} bias in non-volatile memory")
    quantity = QUANTITY[request.sensor]
    stored = (await gw.scheduler(node).ask(node, commands.store_nonvolatile(quantity))
              ).record["quantity"]
    if stored != quantity:
        what = "nothing (it answered 0xFFFF)" if stored == 0xFFFF else f"quantity {stored}"
        raise NodeError(f"node {node.address}: asked to store the {request.sensor} bias "
                        f"(quantity {quantity}), it stored {what}")
    return {"node": node.address, "sensor": request.sensor, "quantity": quantity}


async def read_temperatures(gw: Operations, node: Node) -> Result:
    codes = (await gw.scheduler(node).ask(node, commands.poll(0xD1))).record["temperature"]
    gyro = node.config.gyro
    return {"node": node.address, "codes": list(codes),  # type: ignore[arg-type]
            "accel_c": round(accel_celsius(codes[0]), 2),  # type: ignore[index]
            "gyro_c": [round(gyro_celsius(code, gyro), 2) for code in codes[1:]],  # type: ignore[index]
            "gyro_model": gyro}


@handles("temperature")
async def temperature(gw: Operations, request: Any) -> Result:
    return await read_temperatures(gw, gw.node(request.node))


# -- the built-in test ----------------------------------------------------------------------

async def _samples(gw: Operations, node: Node) -> list[Sample]:
    """SAMPLES readings of accel and angular rate (the first, which may predate the
    last change of BIT, discarded)."""
    readings = []
    for _ in range(SAMPLES + 1):
        record = (await gw.scheduler(node).ask(node, commands.poll(0xC2))).record
        readings.append(Sample(record["accel"], record["ang_rate"]))  # type: ignore[arg-type]
    return readings[1:]


async def _set_bit(gw: Operations, node: Node, config: int,
                   priority: Priority = Priority.OPERATOR) -> int:
    """0xFB with ``config``; the TestConfig echoed (NodeError unless it is ``config``)."""
    echoed = (await gw.scheduler(node).ask(node, commands.built_in_test(config), priority=priority,
                                     what=f"built-in test 0x{config:02X}")
              ).record["test_config"]
    if echoed != config:
        raise NodeError(f"node {node.address}: set BIT to 0x{config:02X}, it echoed "
                        f"0x{echoed:02X}")
    return echoed  # type: ignore[no-any-return]


async def _switch_bit_off(gw: Operations, node: Node) -> int | None:
    """BIT off, whatever happened before: a background task switches it off now and
    keeps trying until the node confirms it, and the request's cancellation cannot stop
    it. The TestConfig echoed at the first attempt, or None if it was not confirmed."""
    first: asyncio.Future[int | None] = asyncio.get_running_loop().create_future()
    gw.spawn(_bit_off_until_confirmed(gw, node, first))
    return await asyncio.shield(first)


async def _bit_off_until_confirmed(gw: Operations, node: Node,
                                   first: asyncio.Future[int | None]) -> None:
    for delay in itertools.chain([0.0], BIT_OFF_BACKOFF, itertools.repeat(BIT_OFF_BACKOFF[-1])):
        await asyncio.sleep(delay)
        try:
            echo = await _set_bit(gw, node, BIT_OFF,
                                  Priority.BACKGROUND if first.done() else Priority.OPERATOR)
        except OpError as error:  # no answer, or no base station: BIT may still be on
            if not first.done():
                first.set_result(None)
            log.warning("%s; switching BIT off again in a while", error)
            continue
        if not first.done():
            first.set_result(echo)
        else:
            log.info("node %s: BIT is off", node.label)
        return


@handles("selftest")
async def selftest(gw: Operations, request: Any) -> Result:
    node = gw.node(request.node)
    async with gw.supervisor(node).quiet(node) as held:
        off = await _samples(gw, node)
        temperatures = await read_temperatures(gw, node)
        try:
            await _set_bit(gw, node, POSITIVE_BIT)
            positive = await _samples(gw, node)
            await _set_bit(gw, node, NEGATIVE_RATE_BIT)
            negative = await _samples(gw, node)
        finally:
            echo = await _switch_bit_off(gw, node)
        if echo is None:
            raise NodeError(f"node {node.address}: BIT was not confirmed off (the gateway "
                            "keeps switching it off)")
        after = await _samples(gw, node)
    checks = judge(off, positive, negative, after,
                   [temperatures["accel_c"], *temperatures["gyro_c"]], echo)
    return {"node": node.address, "passed": all(c.passed for c in checks),
            "checks": [c.as_dict() for c in checks], "stream": held.streamed,
            "restored": held.restored}
