"""Retention of a recording directory (``record.keep_gb``, ``record.keep_days``): the
recorder's thread deletes finished files oldest first, each deletion logged, never the
file being written, and says what the directory's recordings take.

The directory is listed when the recorder starts and whenever it opens a new file
(another process may have added or deleted files); in between, the files the recorder
finishes are added to what is known, so the once-a-second check lists nothing.
"""

from __future__ import annotations

import contextlib
import logging
import re
import time
from pathlib import Path
from typing import NamedTuple

from gateway.recording.files import SUFFIX

log = logging.getLogger("gx2.record")
GB = 1e9
DAY_S = 86400.0
OWN_FILE = re.compile(r"gx2-\d{8}T\d{6}\.\d{3}Z" + re.escape(SUFFIX))
"""The names :func:`~gateway.recording.files.file_name` gives: the only files retention
ever deletes."""


def size_text(count: float) -> str:
    """``812 B``, ``30.0 kB``, ``117.2 MB``, ``84.0 GB`` (powers of 10, as keep_gb)."""
    for unit, scale in (("GB", GB), ("MB", 1e6), ("kB", 1e3)):
        if count >= scale:
            return f"{count / scale:.1f} {unit}"
    return f"{count:.0f} B"


class Kept(NamedTuple):
    """A finished file of the directory, as retention knows it."""

    path: Path
    size: int
    modified: float
    """UNIX time of its last write: its age is that of the last data it holds."""


class Retention:
    """The finished files of one directory, and the limits they are kept within (None:
    no limit). Used by one thread only."""

    def __init__(self, directory: Path, keep_gb: float | None,
                 keep_days: float | None) -> None:
        self.directory = directory
        self.keep_bytes = None if keep_gb is None else keep_gb * GB
        self.keep_s = None if keep_days is None else keep_days * DAY_S
        self._kept: list[Kept] = []
        """The finished files of the directory, oldest first."""
        self.bytes = 0
        """What the directory's recordings take, the file being written included."""
        self.oldest = ""
        """The oldest file kept."""

    def list(self, writing: Path | None) -> None:
        """What the directory holds, but for ``writing`` (the file being written)."""
        try:
            paths = sorted(p for p in self.directory.iterdir() if OWN_FILE.fullmatch(p.name))
        except OSError:
            return
        kept = []
        for path in paths:
            if path == writing:
                continue
            with contextlib.suppress(OSError):
                found = path.stat()
                kept.append(Kept(path, found.st_size, found.st_mtime))
        self._kept = kept

    def add(self, path: Path) -> None:
        """A file just finished (or cut short): retention's from now on."""
        with contextlib.suppress(OSError):
            self._kept.append(Kept(path, path.stat().st_size, time.time()))

    def apply(self, writing: Path | None, size: int) -> None:
        """Delete finished files, oldest first, until the directory (``writing`` taking
        ``size`` bytes so far) is within ``keep_gb`` and ``keep_days``; update what
        status says it holds."""
        total = size + sum(kept.size for kept in self._kept)
        now = time.time()
        while self._kept:
            oldest = self._kept[0]
            if self.keep_s is not None and now - oldest.modified > self.keep_s:
                why = f"older than keep_days {self.keep_s / DAY_S:g}"
            elif self.keep_bytes is not None and total > self.keep_bytes:
                why = (f"the recordings took {size_text(total)}, over keep_gb "
                       f"{self.keep_bytes / GB:g}")
            else:
                break
            del self._kept[0]
            total -= oldest.size
            try:
                oldest.path.unlink()
            except FileNotFoundError:
                continue  # (someone else deleted it)
            except OSError as error:
                total += oldest.size  # (still there)
                log.warning("recording: cannot delete %s (%s): %s", oldest.path,
                            error.strerror or error, why)
                continue
            log.info("recording: deleted %s (%s, last written %s): %s",
                     oldest.path.name, size_text(oldest.size),
                     time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(oldest.modified)), why)
        self.bytes = total
        first = self._kept[0].path if self._kept else writing
        self.oldest = str(first or "")
