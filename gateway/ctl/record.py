"""``gx2ctl record FILE.mcap [NODE...] [--seconds S]``: a running gateway's published
stream, recorded by a subscriber to an MCAP file with the channels the daemon's own
recordings have (no ``serial`` channel: a subscriber never sees the bytes).

A progress line on stderr (records, rate, gaps) while it runs, in place on a terminal
and every PROGRESS_PIPE_S otherwise; the file is finished on a signal, at the end of
``--seconds`` and when the gateway falls silent, and flushed every second meanwhile.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from gateway.client import Message
from gateway.common.protocol import Exit
from gateway.common.topics import STATUS_TOPIC, topic
from gateway.recording.files import RecordingWriter

from . import PROG
from .client import CtlError
from .tail import Stop, subscribe

if TYPE_CHECKING:
    from .cli import Endpoints

FLUSH_S = 1.0
PROGRESS_S = 0.5
PROGRESS_PIPE_S = 10.0
STATUS_CHANNEL = STATUS_TOPIC.decode()


def run_record(path: str, nodes: list[int], seconds: float | None, where: Endpoints,
               timeout: float) -> int:
    target = Path(path)
    if target.exists():
        raise CtlError(f"{target} exists: record to a new file", Exit.USAGE)
    stop = Stop()
    with subscribe(nodes, where, timeout, status=True) as (sub, silence):
        try:
            output = target.open("xb")
        except OSError as error:
            raise CtlError(f"{target}: {error.strerror or error}", Exit.USAGE) from None
        writer = RecordingWriter(output, {"recorded_by": "gx2ctl record",
                                          "source": sub.endpoints[0]})
        progress = Progress(target, sys.stderr.isatty())
        start = time.monotonic()
        flushed = start
        try:
            while not stop.requested:
                now = time.monotonic()
                if seconds is not None and now - start >= seconds:
                    break
                event = sub.receive(PROGRESS_S)
                if isinstance(event, Message):
                    writer.message(topic(event.node, event.record).decode(), event.payload)
                    progress.records += 1
                    progress.gaps += event.gap
                elif event is not None:
                    writer.message(STATUS_CHANNEL, event.payload)
                now = time.monotonic()
                if now - flushed >= FLUSH_S:
                    writer.flush()
                    flushed = now
                progress.show(now - start)
                if event is None and sub.silent_for() > silence:
                    raise CtlError(f"the gateway at {sub.endpoints[0]} published nothing "
                                   f"for {silence:g} s (not even its heartbeat); "
                                   f"{target} holds what came before", Exit.NO_ANSWER)
        finally:
            writer.finish()
            progress.done(time.monotonic() - start)
    return Exit.OK


class Progress:
    """Records, rate and gaps so far, on stderr."""

    def __init__(self, target: Path, terminal: bool) -> None:
        self.target = target
        self.terminal = terminal
        self.records = 0
        self.gaps = 0
        self._shown = 0.0

    def line(self, elapsed: float) -> str:
        rate = self.records / elapsed if elapsed > 0 else 0.0
        return (f"{PROG}: {self.target}: {self.records:,} records in {elapsed:.0f} s, "
                f"{rate:.1f}/s, {self.gaps:,} gaps")

    def show(self, elapsed: float) -> None:
        every = PROGRESS_S if self.terminal else PROGRESS_PIPE_S
        if elapsed - self._shown < every:
            return
        self._shown = elapsed
        if self.terminal:
            sys.stderr.write("\r\x1b[K" + self.line(elapsed))
            sys.stderr.flush()
        else:
            print(self.line(elapsed), file=sys.stderr, flush=True)

    def done(self, elapsed: float) -> None:
        if self.terminal:
            sys.stderr.write("\r\x1b[K")
        print(self.line(elapsed) + " (finished)", file=sys.stderr, flush=True)
