"""``gx2ctl scan``: the nodes on a base station's channel, found by pinging a range of
addresses, and what each one is.

The control protocol answers each request once, so progress cannot come from one long
request: gx2ctl asks for a batch of addresses at a time (:data:`BATCH`), prints each
node found as its batch comes back, and shows on a terminal how far it is; the gateway
scans what fits in a request's time and says how many of the batch that was, and the
rest goes in the next request. Ctrl-C cancels the request under way (a scan only reads,
so nothing is left half done), prints what was found, and exits 130.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Mapping, Sequence
from typing import Any

from gateway.common.jsontext import json_line
from gateway.common.protocol import Exit
from gateway.common.reading import number
from gateway.common.values import ranges_text

from . import PROG
from .cells import cell
from .client import INTERRUPTED, Client, CtlError
from .where import Endpoints

BATCH = 8
"""Addresses asked for in one request: about 0.3 s of absent addresses on gx2-sim
(40 ms each), so the progress moves several times a second and a Ctrl-C is answered
promptly, while a request costs the scan little (about 2 ms each)."""


class Progress:
    """One line on stderr, rewritten in place, on a terminal only: addresses done,
    nodes found, and the time left at the pace so far."""

    def __init__(self, total: int, terminal: bool) -> None:
        self.total = total
        self.terminal = terminal
        self.start = time.monotonic()
        self.shown = False

    def show(self, done: int, found: int) -> None:
        if not self.terminal:
            return
        elapsed = time.monotonic() - self.start
        left = (f", about {elapsed / done * (self.total - done):.0f} s left" if done
                else "")
        sys.stderr.write(f"\r\x1b[K{PROG}: scan: {done} of {self.total} addresses, "
                         f"{found} found{left}")
        sys.stderr.flush()
        self.shown = True

    def clear(self) -> None:
        if self.shown:
            sys.stderr.write("\r\x1b[K")
            sys.stderr.flush()
            self.shown = False


def run_scan(station: str | None, addresses: Sequence[int], where: Endpoints,
             timeout: float, as_json: bool) -> int:
    fields: dict[str, Any] = {} if station is None else {"station": station}
    found: list[Mapping[str, Any]] = []
    stations: list[str] = [] if station is None else [station]
    done = 0
    progress = Progress(len(addresses), sys.stderr.isatty())
    interrupted: str | None = None
    failed: CtlError | None = None
    try:
        with Client(where.control, timeout, where.keys) as client:
            progress.show(done, len(found))
            while done < len(addresses):
                batch = addresses[done:done + BATCH]
                result = client.call("scan", cancel=True, addresses=ranges_text(batch),
                                     **fields)
                scanned = result.get("scanned")
                # (0: the gateway read part of the batch's first node, and goes on)
                if not isinstance(scanned, int) or not 0 <= scanned <= len(batch):
                    raise CtlError(f"the gateway sent a malformed scan reply (scanned "
                                   f"{scanned!r} of {len(batch)})", Exit.NODE_FAILED)
                done += scanned
                new = [entry for entry in (result.get("found") or [])
                       if isinstance(entry, Mapping)]
                found += new
                if isinstance(result.get("stations"), list):
                    stations = [cell(name) for name in result["stations"]]
                if new and not as_json:
                    progress.clear()
                    for entry in new:
                        print(found_line(entry), flush=True)
                progress.show(done, len(found))
    except CtlError as error:
        progress.clear()
        if error.status != INTERRUPTED and not done:
            raise  # (nothing scanned: the error is all there is to say)
        if error.status == INTERRUPTED:
            interrupted = str(error)
        else:  # (the base station dropped mid-scan, say): what was scanned stands
            failed = error
    except KeyboardInterrupt:  # (between two requests: none to cancel)
        progress.clear()
        interrupted = "interrupted"
    progress.clear()
    seconds = time.monotonic() - progress.start
    if as_json:
        print(json_line({"found": list(found), "scanned": done, "of": len(addresses),
                         "stations": stations, "seconds": round(seconds, 3),
                         "interrupted": interrupted is not None,
                         **({} if failed is None else {"error": str(failed),
                                                      "exit": int(failed.status)})}),
              flush=True)
    else:
        print(summary(done, addresses, stations, found, seconds,
                      "interrupted" if interrupted is not None
                      else "stopped" if failed is not None else None), flush=True)
    if failed is not None:
        print(f"{PROG}: {failed}", file=sys.stderr, flush=True)
        return failed.status
    if interrupted is not None:
        print(f"{PROG}: {interrupted}", file=sys.stderr, flush=True)
        return INTERRUPTED
    return Exit.OK


def summary(done: int, addresses: Sequence[int], stations: Sequence[str],
            found: Sequence[Mapping[str, Any]], seconds: float, cut: str | None) -> str:
    """``scanned 100 addresses (1-100) on station1 in 4.6 s: 3 nodes found``; ``cut``:
    how it ended early (``interrupted``, ``stopped``), if it did."""
    covered = f"{done} addresses ({ranges_text(addresses[:done])})" if done else "no address"
    where = f" on {', '.join(stations)}" if stations else ""
    what = (f"{len(found)} node{'' if len(found) == 1 else 's'} found" if found
            else "no node answered")
    if cut:
        return f"{cut} after {covered} of {len(addresses)}{where}, {seconds:.1f} s: {what}"
    return f"scanned {covered}{where} in {seconds:.1f} s: {what}"


def found_line(entry: Mapping[str, Any]) -> str:
    """One node found, what it is as far as it answered: ``81  station1  LQI 201  RSSI
    -45 dBm  Inertia-Link  serial 4200-0081  firmware 2.1.13  50 Hz (divider 1024)
    streaming euler (from power-up: euler)  not configured``."""
    rate = number(entry.get("rate_hz"))
    parts = [cell(entry.get("address")), cell(entry.get("station")),
             f"LQI {cell(entry.get('lqi'))}", f"RSSI {cell(entry.get('rssi'))} dBm",
             cell(entry.get("model_name")), f"serial {cell(entry.get('serial_number'))}",
             f"firmware {cell(entry.get('firmware_version'))}",
             f"{rate:g} Hz (divider {cell(entry.get('divider'))})" if rate is not None
             else f"divider {cell(entry.get('divider'))}",
             _stream(entry)]
    if entry.get("configured") is True:
        name = entry.get("name")
        parts.append(f"configured ({cell(name)})" if name else "configured")
    else:
        parts.append("not configured")
    unanswered = entry.get("unanswered")
    if isinstance(unanswered, str) and unanswered.strip():
        parts.append(f"answers pings, not every read: {cell(unanswered)}")
    return "  ".join(parts)


def _stream(entry: Mapping[str, Any]) -> str:
    streaming, auto_start = entry.get("streaming"), entry.get("auto_start")
    now = f"streaming {cell(streaming)}" if isinstance(streaming, str) else "not streaming"
    if entry.get("divider") is None:  # (not read: nothing is known of its power-up)
        return now
    if auto_start is None and entry.get("unanswered"):  # (the last read: not answered)
        return f"{now} (from power-up: unknown)"
    return f"{now} (from power-up: {cell(auto_start) if auto_start else 'none'})"

