"""The installed console scripts, run as a user runs them.

``GX2_BIN`` names another directory to take them from: the end-to-end tests that use
only the console scripts can then be run against another installation (an older
commit's, to show that a test fails there).
"""

from __future__ import annotations

import contextlib
import errno
import io
import os
import queue
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

STARTUP = 20.0
"""Seconds allowed for the daemon to import, bind and open the port (slow CI)."""
EXIT = 2.0
"""The promise: SIGTERM or SIGINT to exit 0 within 2 s."""
STARVED = 3.0
"""Seconds more allowed to a process starved of CPU on a loaded CI VM (exits seen at
4.6 s with 80% of the CPU stolen): the tests then tell a hang from the promise kept."""


FAVOURED = -10
"""The niceness a test of how well ``time`` is placed runs its simulator and gateway at
(:func:`favoured`)."""
PROGRAMS = -5
"""The niceness every other test that waits on time runs at, its programs with it
(tests/conftest.py, programs_favoured): above the suite's computing tests (properties,
recordings decoded), which wait on nothing, and below FAVOURED. At 8 processes on 2
cores, without it, a simulated node once streamed 89.8 of its 100 Hz and a station's
records once came 0.29 s apart."""


@contextlib.contextmanager
def favoured(niceness: int = FAVOURED) -> Iterator[None]:
    """Run the body with this process's threads (gx2-sim's among them) at ``niceness``
    (FAVOURED unless said), and the programs it starts with them: a test of how well ``time`` is
    placed measures the gateway as a host with a core to spare runs it, not the suite's
    other processes beside it (refined against live in the full suite, 3 processes on 2
    cores: in one run of two the reads came in batches that hid every sighting of node
    77, so nothing was placed between them). Linux keeps a niceness per thread, and a
    thread or child takes its parent thread's. Without the right to raise priority
    (not root), nothing changes. Afterwards every thread of the process is back at its
    niceness, one started meanwhile at the main thread's."""
    before: dict[int, int] = {}
    for tid in _threads():
        try:
            was = os.getpriority(os.PRIO_PROCESS, tid)
            os.setpriority(os.PRIO_PROCESS, tid, niceness)
        except OSError:  # (not permitted, or the thread ended)
            continue
        before[tid] = was
    try:
        yield
    finally:
        if before:
            usual = before.get(threading.get_native_id(), 0)
            for tid in _threads():  # (this process's only, as they are now)
                with contextlib.suppress(OSError):
                    os.setpriority(os.PRIO_PROCESS, tid, before.get(tid, usual))


def can_favour() -> bool:
    """Whether this process may raise its threads' priority to FAVOURED (root may)."""
    tid = threading.get_native_id()
    was = os.getpriority(os.PRIO_PROCESS, tid)
    try:
        os.setpriority(os.PRIO_PROCESS, tid, FAVOURED)
    except OSError:
        return False
    os.setpriority(os.PRIO_PROCESS, tid, was)
    return True


def _threads() -> list[int]:
    return [int(tid) for tid in os.listdir("/proc/self/task")]


def restore_sigint() -> None:
    """Let Ctrl-C reach the programs the tests start, however the suite was started.

    A suite started in the background by a shell without job control (``pytest &`` in
    a script) inherits SIGINT ignored, and so does every program it starts: one that
    leaves SIGINT to Python (gx2ctl export) never sees the Ctrl-C a test sends it
    (found running the suite beside the demo). A handler is reset to the default at
    each child's exec, as a terminal leaves it."""
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def script(name: str) -> str:
    """The path of an installed console script (gx2-gateway, gx2ctl, gx2-sim)."""
    where = os.environ.get("GX2_BIN") or str(Path(sys.executable).parent)
    found = shutil.which(name, path=where)
    assert found, f"{name} is not installed in {where}"
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


@dataclass(frozen=True)
class Ran:
    """A finished run of a console script."""

    status: int
    stdout: str
    stderr: str
    seconds: float


def interrupted(command: list[str], begun: Callable[[], bool], what: str,
                timeout: float = 30.0) -> tuple[int, str, str]:
    """``command`` run until ``begun()`` (or its end), then Ctrl-C'd (SIGINT); its exit
    status, stdout and stderr. Killed if it outlives ``timeout`` after that."""
    from tests.helpers.waiting import wait_for
    run = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        wait_for(lambda: run.poll() is not None or begun(), timeout, what)
        run.send_signal(signal.SIGINT)
        stdout, stderr = run.communicate(timeout=timeout)
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
    return run.returncode, stdout, stderr


def gx2ctl(*args: str, timeout: float = 60.0) -> Ran:
    """``gx2ctl ARGS``, timed from just before it starts until it exits."""
    start = time.monotonic()
    run = spawn_run([script("gx2ctl"), *args], capture_output=True, text=True,
                    timeout=timeout, stdin=subprocess.DEVNULL)
    return Ran(run.returncode, run.stdout, run.stderr, time.monotonic() - start)


def gx2ctl_here(*args: str) -> Ran:
    """``gx2ctl ARGS`` run by the function the installed program calls
    (``gateway.ctl.cli:main``, pyproject.toml's entry point) in this process: its exit
    status and what it printed, as :func:`gx2ctl` gives them. For the offline commands'
    many runs whose subject is what they read and write: a run of the program costs a
    second of CPU importing pyarrow and, through pyarrow's first conversion of a value,
    pandas (tests/recording ran about 120 of them). Each module still runs the
    installed program where the program itself is the subject (its start, a kill, its
    memory)."""
    from gateway.ctl.cli import main
    out, err = io.StringIO(), io.StringIO()
    start = time.monotonic()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            status = main(list(args))
        except SystemExit as exit:
            status = exit.code if isinstance(exit.code, int) else int(exit.code is not None)
    if status == 128 + signal.SIGINT:  # (a Ctrl-C meant for the suite: it stops)
        raise KeyboardInterrupt(err.getvalue())
    return Ran(int(status or 0), out.getvalue(), err.getvalue(), time.monotonic() - start)


class Running:
    """A console script running in the background, its stdout and stderr lines
    collected by threads."""

    def __init__(self, name: str, *args: str, env: dict[str, str] | None = None) -> None:
        self.proc = subprocess.Popen([script(name), *args], stdin=subprocess.DEVNULL,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True, env=env)
        self.lines: queue.Queue[str] = queue.Queue()
        self.stdout: list[str] = []
        self.stderr: list[str] = []
        self._threads = [threading.Thread(target=self._pump, args=(self.proc.stdout, True),
                                          daemon=True),
                         threading.Thread(target=self._pump, args=(self.proc.stderr, False),
                                          daemon=True)]
        for thread in self._threads:
            thread.start()

    def _pump(self, stream: object, is_stdout: bool) -> None:
        for line in stream:  # type: ignore[attr-defined]
            (self.stdout if is_stdout else self.stderr).append(line)
            if is_stdout:
                self.lines.put(line.rstrip("\n"))

    def wait_for_line(self, predicate: Callable[[str], bool], timeout: float) -> str:
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            if left <= 0 or (self.proc.poll() is not None and self.lines.empty()):
                raise AssertionError(f"no such line on stdout within {timeout} s; exit "
                                     f"{self.proc.poll()}, stdout {self.stdout!r}, "
                                     f"stderr {self.stderr!r}")
            try:
                line = self.lines.get(timeout=min(left, 0.1))
            except queue.Empty:
                continue
            if predicate(line):
                return line

    def finish(self, timeout: float) -> int:
        """The exit status, within ``timeout`` s; then the output is all collected."""
        try:
            status = self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            raise AssertionError(f"still running {timeout} s later; stderr "
                                 f"{self.stderr!r}") from None
        for thread in self._threads:
            thread.join(10)
        return status

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(5)
        for thread in self._threads:
            thread.join(2)
