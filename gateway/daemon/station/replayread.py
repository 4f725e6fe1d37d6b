"""One reading of a recording, shared by every base station that plays it.

A recording of several base stations holds each one's reads on its own channel
(``serial/<name>``); each station replaying it plays its own channel, paced at the
recorded times. Read once per station, the file was decompressed as many times as
there are stations. Here it is read (and decompressed) once: a task walks the files
and hands each entry to every station that plays that file, through a bounded queue
per station. A station that falls behind holds the reading up (the queue is full),
never loses an entry; one that stops playing leaves, and the reading goes on without
it. The stations keep all their own rules (which channel, which marks, the pace).
Only stations that play at one pace share a reading (the same files, speed and delay):
a station of another pace would hold the others to its own.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gateway.recording.reader import Entry, read
from gateway.recording.reports import FileReport, Reading

if TYPE_CHECKING:
    from .replayurl import Replay

QUEUED = 256
"""Entries read ahead for one station, at most."""
YIELD_EVERY = 200
"""Entries read between two turns given to the loop, at most (a file read as fast as
the stations take it)."""
_END = object()
"""The end of one file, in a station's queue."""


class ReplayReader:
    """The files of one recording, read once for the stations that play them."""

    def __init__(self, files: tuple[Path, ...], span: tuple[int, int] | None = None) -> None:
        self.files = files
        self.span = span
        """The window played (:attr:`.replayurl.Replay.span`): only its chunks are read."""
        self._players: dict[object, tuple[asyncio.Queue[Any], Callable[[Path], bool],
                                          Callable[[FileReport], None]]] = {}
        self._task: asyncio.Task[None] | None = None
        self.reads = 0
        """Times a file was opened and walked (once each, whatever the stations)."""

    def join(self, player: object, plays: Callable[[Path], bool],
             on_file: Callable[[FileReport], None]) -> None:
        """``player`` takes the entries of every file ``plays`` says it plays, and each
        such file's report once read. Joined before the reading starts."""
        self._players[player] = (asyncio.Queue(QUEUED), plays, on_file)

    def leave(self, player: object) -> None:
        """``player`` plays no more: the reading goes on without it (what it left in
        its queue is dropped, so a reading waiting on it waits no more)."""
        joined = self._players.pop(player, None)
        if joined is not None:
            queue = joined[0]
            while not queue.empty():
                queue.get_nowait()
        if not self._players and self._task is not None:
            self._task.cancel()

    async def entries(self, player: object, path: Path) -> AsyncIterator[Entry]:
        """The entries of ``path``, in the order written, for ``player`` (which plays
        it, as its ``plays`` said)."""
        if self._task is None:
            self._task = asyncio.get_running_loop().create_task(self._read())
        queue = self._players[player][0]
        while True:
            entry = await queue.get()
            if entry is _END:
                return
            if isinstance(entry, BaseException):
                raise entry
            yield entry

    async def _read(self) -> None:
        try:
            for path in self.files:
                players = [player for player, (_, plays, _) in list(self._players.items())
                           if plays(path)]
                if not players:
                    continue
                reading = Reading(lambda report, players=players: self._done(players, report))
                self.reads += 1
                for seen, entry in enumerate(read(path, reading, span=self.span), 1):
                    await self._give(players, entry)
                    if seen % YIELD_EVERY == 0:
                        await asyncio.sleep(0)
                await self._give(players, _END)
        except Exception as error:  # (a bug: every station hears it, none waits)
            for queue, _, _ in list(self._players.values()):
                while not queue.empty():
                    queue.get_nowait()
                queue.put_nowait(error)
            raise

    async def _give(self, players: list[object], item: object) -> None:
        for player in players:
            joined = self._players.get(player)
            if joined is not None:  # (not one that has left)
                await joined[0].put(item)

    def _done(self, players: list[object], report: FileReport) -> None:
        for player in players:
            joined = self._players.get(player)
            if joined is not None:
                joined[2](report)


class ReplayReaders:
    """The gateway's readers, one per recording played at one pace (the files a
    replay:// URL names, its speed and its delay: ``exit`` is no matter of pace)."""

    def __init__(self) -> None:
        self._readers: dict[tuple[Any, ...], ReplayReader] = {}

    def of(self, replay: Replay) -> ReplayReader:
        key = (replay.files, replay.speed, replay.delay, replay.span)
        reader = self._readers.get(key)
        if reader is None:
            reader = self._readers[key] = ReplayReader(replay.files, replay.span)
        return reader
