"""The fault soak's run as data: the nodes it drives, the faults as they ran, the status
polls and every timed sample with its truth. bench/faultsoak.py makes a Result,
bench/soakreport.py judges it, and ``--save`` pickles it for ``--load``."""

from __future__ import annotations

from array import array
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from gateway.sim.node import NodeSettings

NODES = (NodeSettings(76, divider=740, ppm=25.0), NodeSettings(77, divider=760, ppm=-30.0),
         NodeSettings(78, divider=780, ppm=10.0))
"""69.2, 67.4 and 65.6 Hz of 40-byte packets: 70% of the line, rates apart so that no
node's packets wait behind another's for long."""
ADDRESSES = tuple(n.address for n in NODES)
RECOVERY_SLACK = 5.0
"""Seconds past the health window a recovery may take: the health's 1 s sampling, the
2 Hz poll, a clock locking after a second of packets, a stream re-armed."""

# -- the run's records ---------------------------------------------------------------


@dataclass
class Fault:
    """One fault as it ran; times are ``time.monotonic()``."""

    kind: str
    detail: str
    start: float
    due: float
    end: float | None = None
    undo: Callable[[], None] | None = None
    recovered: float | None = None
    """Seconds from its end to the first healthy status asked after it."""


@dataclass
class NodePoll:
    health: str
    reasons: tuple[str, ...]
    locked: bool
    floor_age_s: float | None
    floor_seen: bool | None
    late_ms: float | None

    @property
    def clock_warn(self) -> bool:
        """A WARN that names the clock or the line: what tells a user ``time`` is off."""
        return self.health == "WARN" and any("clock" in r or "line" in r
                                             for r in self.reasons)

    @property
    def clock_trouble(self) -> bool:
        """Status says the estimate is held, unlocked or its floor unseen."""
        return not self.locked or self.clock_warn


@dataclass
class Poll:
    asked: float
    at: float
    healthy: bool
    nodes: dict[int, NodePoll]
    gateway_reasons: tuple[str, ...]


@dataclass
class Samples:
    """Every timed record with its truth, per node, as columns (an hour is a million)."""

    truth: dict[int, array] = field(default_factory=lambda: {a: array("d") for a in ADDRESSES})
    arrival: dict[int, array] = field(default_factory=lambda: {a: array("d")
                                                                for a in ADDRESSES})
    error: dict[int, array] = field(default_factory=lambda: {a: array("d") for a in ADDRESSES})
    untrue: int = 0
    """Records for which the tap saw no true instant."""

    def add(self, node: int, truth: float, arrival: float, error: float) -> None:
        self.truth[node].append(truth)
        self.arrival[node].append(arrival)
        self.error[node].append(error)

    def sort(self) -> None:
        """In order of arrival (records matched late were added late), for bisect."""
        for node, arrival in self.arrival.items():
            order = sorted(range(len(arrival)), key=arrival.__getitem__)
            for column in (self.truth, self.arrival, self.error):
                column[node] = array("d", (column[node][i] for i in order))


@dataclass
class Result:
    seconds: float
    window_s: float
    started: float
    warmed: float
    faults: list[Fault]
    polls: list[Poll]
    samples: Samples
    losses: dict[str, int]
    resources: list[tuple[int, int]]
    """(RSS KiB, open fds) after the warm-up and at the end."""
    ops_failed: list[str]
    work: Path
    model: str = "gx2sim"
    """The base station's output (faultsoak.MODELS)."""
    recording: tuple[int, int, int] | None = None
    """(records checked, missing from the recording, not checked: within a full disk's
    window); None without a recording."""
    recording_cut: list[str] = field(default_factory=list)
    """The recording's files read only up to where they stop (a file cut short by a
    full disk), each with what the reader said."""
    rss: list[tuple[float, int]] = field(default_factory=list)
    """(seconds after the warm-up, the gateway's RSS in KiB), each RSS_PERIOD."""

    @property
    def bound(self) -> float:
        return self.window_s + RECOVERY_SLACK
