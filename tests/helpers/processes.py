"""The installed console scripts, run as a user runs them."""

from __future__ import annotations

import errno
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

STARTUP = 20.0
"""Seconds allowed for the daemon to import, bind and open the port (slow CI)."""
EXIT = 2.0
"""The promise: SIGTERM or SIGINT to exit 0 within 2 s."""
STARVED = 3.0
"""Seconds more allowed to a process starved of CPU on a loaded CI VM (exits seen at
4.6 s with 80% of the CPU stolen): the tests then tell a hang from the promise kept."""


def script(name: str) -> str:
    """The path of an installed console script (gx2-gateway, gx2ctl, gx2-sim)."""
    found = shutil.which(name, path=str(Path(sys.executable).parent))
    assert found, f"{name} is not installed beside {sys.executable}"
    return found


def spawn_run(command: list[str], **options: Any) -> subprocess.CompletedProcess:
    """subprocess.run, retried when the spawn itself fails with EFAULT: seen on this
    sandbox when several threads start processes at once; the program never ran, so a
    retry cannot hide a bug in it."""
    for attempt in range(3):
        try:
            return subprocess.run(command, **options)
        except OSError as error:
            if error.errno != errno.EFAULT or attempt == 2:
                raise
    raise AssertionError("unreachable")
