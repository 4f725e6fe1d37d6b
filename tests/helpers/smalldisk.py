"""A small disk of its own: a real tmpfs in a mount namespace of its own (unshare(1),
as root), held by a process that lives as long as its holder object. A program joins
that namespace (setns(2), before it starts: :meth:`SmallDisk.enter` as its preexec),
and its starter reaches the same tmpfs through the holder's ``/proc/PID/root``. It
fills with a file written until the kernel says ENOSPC, and frees when that file is
deleted: the program meets the very error a full disk gives (the suite's recording
failures, the fault soak's full disk)."""

from __future__ import annotations

import ctypes
import errno
import os
import shutil
import subprocess
from pathlib import Path

CLONE_NEWNS = 0x00020000
"""setns(2)'s flag for a mount namespace (<sched.h>)."""
HOLD = 'mount -t tmpfs -o "$2" gx2-test "$1" && echo mounted && exec cat >/dev/null'
"""The holder: mounts the tmpfs in its own namespace, says so, and keeps it until its
standard input closes (its owner ends, or dies)."""


PAGE = 4096
"""tmpfs gives and takes space in pages."""


class Unavailable(RuntimeError):
    """No tmpfs of its own here (not root, or no unshare(1))."""


class SmallDisk:
    """A tmpfs at ``inside`` that only the programs that enter it (and its owner,
    through ``outside``) see."""

    def __init__(self, directory: Path, options: str) -> None:
        unshare = shutil.which("unshare")
        if os.geteuid() != 0 or unshare is None:
            raise Unavailable("a tmpfs of its own needs root and unshare(1)")
        self.inside = directory / "disk"
        self.inside.mkdir()
        self._holder = subprocess.Popen(
            [unshare, "--mount", "--propagation", "private", "sh", "-c", HOLD, "sh",
             str(self.inside), options], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
            stderr=subprocess.PIPE, text=True)
        if self._holder.stdout.readline().strip() != "mounted":  # type: ignore[union-attr]
            why = self._holder.communicate(timeout=10)[1].strip()
            raise Unavailable(f"no tmpfs of its own here: {why}")
        self.outside = Path(f"/proc/{self._holder.pid}/root{self.inside}")
        self.namespace = f"/proc/{self._holder.pid}/ns/mnt"
        """The mount namespace, for ``nsenter --mount=`` (a program started from a
        process with threads running, where a preexec function is not safe)."""
        self._namespace = os.open(f"/proc/{self._holder.pid}/ns/mnt", os.O_RDONLY)
        self._setns = ctypes.CDLL(None, use_errno=True).setns

    def enter(self) -> None:
        """In the gateway's process, before it starts: the holder's mount namespace."""
        if self._setns(self._namespace, CLONE_NEWNS) != 0:
            os._exit(126)

    def fill(self) -> int:
        """Fill what is left of the disk (the filler grows); the bytes added."""
        added = 0
        with (self.outside / "filler").open("ab", buffering=0) as filler:
            for block in (65536, 4096, 512, 1):
                try:
                    while True:
                        added += filler.write(bytes(block))
                except OSError as error:
                    if error.errno != errno.ENOSPC:
                        raise
        return added

    def free(self, size: int | None = None) -> None:
        """Free the disk, or only ``size`` bytes of it."""
        filler = self.outside / "filler"
        if size is None:
            filler.unlink()
        else:
            os.truncate(filler, filler.stat().st_size - size)

    def close(self) -> None:
        os.close(self._namespace)
        self._holder.communicate(timeout=10)  # (stdin closed: the tmpfs goes with it)
