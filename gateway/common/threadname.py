"""A thread's name where ``top -H`` and ``/proc/PID/task/TID/comm`` show it: Python's
own thread names stay inside the interpreter (3.11 sets no native name), so every
thread of the gateway shows as ``gx2-gateway`` and the simulator's share of the demo's
CPU cannot be told from the gateway's (bench/democpu.py)."""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

PR_SET_NAME = 15
"""prctl(2): the calling thread's name, 15 bytes at most."""


def name_this_thread(name: str) -> None:
    """Give the calling thread ``name`` (cut to 15 bytes) in the kernel's view; nothing
    where the kernel has no such call."""
    if not sys.platform.startswith("linux"):
        return
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True)
        libc.prctl(PR_SET_NAME, name.encode()[:15], 0, 0, 0)
    except (OSError, AttributeError):  # (no libc to load: the name is a nicety)
        pass
