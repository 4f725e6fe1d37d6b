"""The outputs' one guard: code of an output's that raised where it must not (a
``take``, the frame made for a record, an output's thread building a sample or serving
its client) is contained there, counted for that output, and said once a kind of error.

Its counts are status's ``outputs.<name>.take_failures``, the metric
``gx2_output_take_failures_total``, and a WARN of the gateway's while they grow
(:class:`~gateway.daemon.health.Health`): the same whichever part of the output failed,
on the loop or in the output's own thread.
"""

from __future__ import annotations

import logging
import threading

log = logging.getLogger("gx2.outputs")


class Guard:
    """Failures contained, by output name (the fan-out's ``take_failures``)."""

    def __init__(self) -> None:
        self.failures: dict[str, int] = {}
        """Output name -> messages (or calls) that raised, contained."""
        self._said: set[tuple[str, type[BaseException]]] = set()
        self._lock = threading.Lock()

    def of(self, name: str) -> Guarded:
        """What an output's own thread reports its failures to; its count is there (0)
        from now on, so a thread's first failure never adds a key to ``failures``
        while the loop reads it."""
        with self._lock:
            self.failures.setdefault(name, 0)
        return Guarded(self, name)

    def failed(self, name: str, what: str, error: BaseException) -> None:
        """``name``'s code raised ``error`` doing ``what`` ("failed to take a message on
        gx2/76/euler"): counted, and logged the first time for that output and kind of
        error. From any thread."""
        with self._lock:
            self.failures[name] = self.failures.get(name, 0) + 1
            kind = (name, type(error))
            first = kind not in self._said
            self._said.add(kind)
        if first:
            log.error("output %s %s: %s: %s (counted; not logged again for this output "
                      "and error)", name, what, type(error).__name__, error)


class Guarded:
    """One output's way to the guard."""

    __slots__ = ("_guard", "name")

    def __init__(self, guard: Guard, name: str) -> None:
        self._guard = guard
        self.name = name

    def failed(self, what: str, error: BaseException) -> None:
        self._guard.failed(self.name, what, error)
