"""The fault soak's judgement of a run (bench/faultsoak.py's docstring says what is
checked and why): recovery per fault, ``time`` against the truth inside and outside
the faults' windows, the honesty of status, losses and resources; a table per kind."""

from __future__ import annotations

import bisect
import re
import statistics
from collections.abc import Iterable
from dataclasses import dataclass, field
from itertools import pairwise

from soakrecords import ADDRESSES, Fault, Poll, Result

P99_TARGET, APART_TARGET = 0.2e-3, 0.15e-3
OFF, GOOD = 0.5e-3, 0.2e-3
"""A sample more than OFF from its node's median is off; WARN time whose samples are all
within GOOD, and with no off sample within WARN_NEAR of its poll, was needless."""
HONEST_SHARE, NEEDLESS_SHARE = 0.95, 0.05
UNWARNED_LISTED = 10
"""How many off samples with no WARN the report lists (--unwarned)."""
WARN_NEAR = 1.0
"""Seconds around a sample's arrival in which a poll's WARN covers it."""
LATE_NEAR = 0.5
LATE_TOLERANCE = 0.1e-3
"""What a sample's error may exceed ``late_ms`` by: the estimate's noise on a free line."""
RSS_FLAT_KIB = 1024
"""What the gateway's RSS may grow over the run's second half: flat is no growth that
goes on. The first minutes step up as each fault kind first runs (the allocator's
arenas, the C libraries' buffers; Python's own objects stay flat, measured with
tracemalloc: docs/performance-history.md), so the whole run's growth is shown, not
judged; a leak of 2 MiB an hour shows over an hour's second half."""

# -- the analysis ---------------------------------------------------------------------

Interval = tuple[float, float]


def merged(intervals: Iterable[Interval]) -> list[Interval]:
    out: list[Interval] = []
    for start, end in sorted(intervals):
        if out and start <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], end))
        else:
            out.append((start, end))
    return out


def covers(intervals: list[Interval], starts: list[float], first: float, last: float) -> bool:
    """Whether [first, last] meets one of the (merged, sorted) intervals."""
    i = bisect.bisect_right(starts, last) - 1
    return i >= 0 and intervals[i][1] >= first


def fault_span(fault: Fault, bound: float) -> Interval:
    end = fault.end if fault.end is not None else fault.due
    return fault.start, end + (fault.recovered if fault.recovered is not None else bound)


def trouble_spans(polls: list[Poll], node: int) -> list[Interval]:
    """The polls around each that says the node's clock is held, unlocked or unseen."""
    spans = []
    for i, poll in enumerate(polls):
        state = poll.nodes.get(node)
        if state is not None and state.clock_trouble:
            spans.append((polls[max(i - 1, 0)].asked, polls[min(i + 1, len(polls) - 1)].at))
    return spans


def windows(result: Result, node: int) -> list[Interval]:
    spans = [(result.started, result.warmed)]
    spans += [fault_span(f, result.bound) for f in result.faults]
    return merged(spans + trouble_spans(result.polls, node))


def p99(values: list[float]) -> float:
    if not values:
        return float("nan")
    d = sorted(abs(v) for v in values)
    return d[int(0.99 * (len(d) - 1))]


def split(result: Result, spans: dict[int, list[Interval]]) -> tuple[dict[int, list[int]],
                                                                      dict[int, list[int]]]:
    """Each node's sample indexes inside and outside its windows."""
    inside: dict[int, list[int]] = {}
    outside: dict[int, list[int]] = {}
    for node in ADDRESSES:
        starts = [s for s, _ in spans[node]]
        truth, arrival = result.samples.truth[node], result.samples.arrival[node]
        inside[node], outside[node] = [], []
        for i in range(len(truth)):
            target = inside if covers(spans[node], starts, truth[i], arrival[i]) else outside
            target[node].append(i)
    return inside, outside


@dataclass
class Figures:
    """p99 of |error - the node's median outside| (s), the nodes' medians' spread (s),
    and how many samples."""

    p99: float
    apart: float
    count: int
    worst: float


def figures(result: Result, medians: dict[int, float],
            chosen: dict[int, list[int]]) -> Figures:
    deviations: list[float] = []
    own: list[float] = []
    for node, indexes in chosen.items():
        errors = result.samples.error[node]
        values = [errors[i] for i in indexes]
        deviations += [v - medians[node] for v in values]
        if values:
            own.append(statistics.median(values))
    apart = max(own) - min(own) if len(own) > 1 else 0.0
    return Figures(p99(deviations), apart, len(deviations),
                   max(map(abs, deviations), default=float("nan")))


def polls_near(polls: list[Poll], at: list[float], t: float, near: float) -> list[Poll]:
    lo, hi = bisect.bisect_left(at, t - near), bisect.bisect_right(at, t + near)
    return polls[lo:hi]


@dataclass
class Honesty:
    off: int
    off_warned: int
    warn_seconds: float
    warn_good_seconds: float
    late_given: int
    late_violations: list[str]
    by_reason: dict[str, list[float]] = field(default_factory=dict)
    """WARN seconds and those on good samples, by the clock or line reason said."""
    warn_good_strict: float = 0.0
    """WARN seconds whose samples between the two polls were all good."""


def warned_off(result: Result, medians: dict[int, float],
               chosen: dict[int, list[int]]) -> tuple[int, int]:
    """How many of the chosen samples were off, and how many of those arrived within
    WARN_NEAR of a status naming their node's clock or line in a WARN."""
    polls = result.polls
    at = [p.at for p in polls]
    off = warned = 0
    for node, indexes in chosen.items():
        errors, arrival = result.samples.error[node], result.samples.arrival[node]
        for i in indexes:
            if abs(errors[i] - medians[node]) > OFF:
                off += 1
                warned += any(p.nodes[node].clock_warn for p in
                              polls_near(polls, at, arrival[i], WARN_NEAR) if node in p.nodes)
    return off, warned


def unwarned(result: Result, medians: dict[int, float]) -> list[str]:
    """The off samples no WARN named the clock or line for, each with the fault
    nearest before it: where to look."""
    polls, at = result.polls, [p.at for p in result.polls]
    said = []
    for node in ADDRESSES:
        errors, arrival = result.samples.error[node], result.samples.arrival[node]
        for i in range(len(errors)):
            if abs(errors[i] - medians[node]) <= OFF or any(
                    p.nodes[node].clock_warn for p in
                    polls_near(polls, at, arrival[i], WARN_NEAR) if node in p.nodes):
                continue
            before = [f for f in result.faults if f.start <= arrival[i]]
            near = (f"{before[-1].kind} {arrival[i] - before[-1].start:.1f} s after its "
                    "start" if before else "before any fault")
            said.append(f"node {node} at {arrival[i] - result.started:.1f} s "
                        f"{(errors[i] - medians[node]) * 1e3:+.2f} ms, {near}")
    return sorted(said, key=lambda line: float(line.split(" at ")[1].split(" s ")[0]))


def honesty(result: Result, medians: dict[int, float]) -> Honesty:
    polls = result.polls
    every = {n: list(range(len(result.samples.error[n]))) for n in ADDRESSES}
    off, off_warned = warned_off(result, medians, every)
    warn_s = good_s = strict_s = 0.0
    late_given, violations = 0, []
    by_reason: dict[str, list[float]] = {}
    for node in ADDRESSES:
        errors, arrival = result.samples.error[node], result.samples.arrival[node]
        for a, b in pairwise(polls):
            state = a.nodes.get(node)
            if state is None or not state.clock_warn:
                continue
            # (needed if a sample between the two polls was more than GOOD off, or one
            # the poll covers as warned_off does, within WARN_NEAR of it, more than OFF:
            # a power-up's bad samples come in its first 0.2 s, before a 2 Hz poll can
            # see its WARN; the strict share counts the samples between the polls only)
            lo, hi = bisect.bisect_left(arrival, a.at), bisect.bisect_right(arrival, b.at)
            between = all(abs(errors[i] - medians[node]) <= GOOD for i in range(lo, hi))
            near = all(abs(errors[i] - medians[node]) <= OFF for i in range(
                bisect.bisect_left(arrival, a.at - WARN_NEAR),
                bisect.bisect_right(arrival, a.at + WARN_NEAR)))
            good = between and near
            warn_s += b.at - a.at
            good_s += (b.at - a.at) * good
            strict_s += (b.at - a.at) * between
            for reason in {reason_kind(r) for r in state.reasons
                           if "clock" in r or "line" in r}:
                seconds = by_reason.setdefault(reason, [0.0, 0.0])
                seconds[0] += b.at - a.at
                seconds[1] += (b.at - a.at) * good
        for poll in polls:
            state = poll.nodes.get(node)
            if state is None or state.late_ms is None:
                continue
            late_given += 1
            lo = bisect.bisect_left(arrival, poll.asked - LATE_NEAR)
            hi = bisect.bisect_right(arrival, poll.at + LATE_NEAR)
            worst = max((errors[i] - medians[node] for i in range(lo, hi)), default=0.0)
            if worst > state.late_ms * 1e-3 + LATE_TOLERANCE:
                violations.append(f"node {node} at {poll.at - result.started:.1f} s: late_ms "
                                  f"{state.late_ms:.2f}, truly {worst * 1e3:.2f}")
    return Honesty(off, off_warned, warn_s, good_s, late_given, violations, by_reason,
                   strict_s)


def reason_kind(reason: str) -> str:
    """A reason without its figures: what the WARN time is counted by."""
    return re.sub(r"[-+]?\d[\d.,]*", "N", reason.split(":")[0])


@dataclass
class Report:
    lines: list[str]
    invariants: dict[str, tuple[bool, str]]

    @property
    def passed(self) -> bool:
        return all(ok for ok, _ in self.invariants.values())


def pct(values: list[float], q: float) -> float:
    d = sorted(values)
    return d[int(q * (len(d) - 1))] if d else float("nan")


def kind_rows(result: Result, medians: dict[int, float]) -> list[str]:
    rows = ["| fault | count | recovery p50 / max (s) | never | time in its windows: "
            "p99 / max / medians apart (ms) | samples | off / under a WARN |",
            "|---|---|---|---|---|---|---|"]
    for kind in dict.fromkeys(f.kind for f in result.faults):
        faults = [f for f in result.faults if f.kind == kind]
        times = [f.recovered for f in faults if f.recovered is not None]
        spans = merged(fault_span(f, result.bound) for f in faults)
        inside, _ = split(result, dict.fromkeys(ADDRESSES, spans))
        fig = figures(result, medians, inside)
        off, warned = warned_off(result, medians, inside)
        rows.append(f"| {kind} | {len(faults)} | {pct(times, 0.5):.1f} / "
                    f"{max(times, default=float('nan')):.1f} | {len(faults) - len(times)} | "
                    f"{fig.p99 * 1e3:.3f} / {fig.worst * 1e3:.1f} / {fig.apart * 1e3:.3f} | "
                    f"{fig.count:,} | {off:,} / {warned / off if off else 1:.0%} |")
    return rows


def analyse(result: Result, listed: int = UNWARNED_LISTED) -> Report:
    spans = {node: windows(result, node) for node in ADDRESSES}
    inside, outside = split(result, spans)
    medians = {node: statistics.median([result.samples.error[node][i] for i in outside[node]])
               if outside[node] else 0.0 for node in ADDRESSES}
    out, within = figures(result, medians, outside), figures(result, medians, inside)
    honest = honesty(result, medians)
    lines = kind_rows(result, medians)
    for name, fig, chosen in (("all windows", within, inside), ("outside windows", out, outside)):
        off, warned = warned_off(result, medians, chosen)
        lines.append(f"| {name} | | | | {fig.p99 * 1e3:.3f} / {fig.worst * 1e3:.1f} / "
                     f"{fig.apart * 1e3:.3f} | {fig.count:,} | {off:,} / "
                     f"{warned / off if off else 1:.0%} |")
    warned = honest.off_warned / honest.off if honest.off else 1.0
    needless = honest.warn_good_seconds / honest.warn_seconds if honest.warn_seconds else 0.0
    strict = honest.warn_good_strict / honest.warn_seconds if honest.warn_seconds else 0.0
    losses = result.losses
    (rss0, fds0), (rss1, fds1) = result.resources
    lines += [
        "",
        "nodes' median errors (ms): " + ", ".join(f"{a} {m * 1e3:+.3f}"
                                                  for a, m in medians.items()),
        f"off samples (> {OFF * 1e3:.1f} ms): {honest.off:,}, under a clock/line WARN "
        f"{warned:.1%}; WARN time {honest.warn_seconds:.0f} s, on good samples "
        f"{needless:.1%} (between its polls only: {strict:.1%}); late_ms given "
        f"{honest.late_given}, not a bound {len(honest.late_violations)}",
        f"replies delivered {losses['delivered']:,}, received {losses['received']:,}, "
        f"published {losses['published']:,}, got {losses['got']:,} (seq gaps "
        f"{losses['seq_gaps']}); lost in the gateway {losses['in_gateway']}; "
        f"records without truth {result.samples.untrue}",
        f"RSS {rss0 / 1024:.1f} -> {rss1 / 1024:.1f} MiB, open fds {fds0} -> {fds1}",
    ]
    series = getattr(result, "rss", [])
    if len(series) >= 4:
        quarter = len(series) // 4
        lines.append("RSS each quarter of the run (MiB): " + ", ".join(
            f"{series[i][0] / 60:.0f} min {series[i][1] / 1024:.1f}"
            for i in (0, quarter, 2 * quarter, 3 * quarter, len(series) - 1)))
    if result.recording is not None:
        checked, missing, skipped = result.recording
        lines.append(f"recording: {checked:,} records got checked against the files, "
                     f"{missing:,} missing; {skipped:,} got while the disk was full not "
                     "checked")
        lines += [f"  read up to where it stops: {cut}"
                  for cut in getattr(result, "recording_cut", [])]
    lines += [f"  WARN {warn:.0f} s, {good / warn if warn else 0:.0%} on good samples: {kind}"
              for kind, (warn, good) in sorted(honest.by_reason.items(),
                                                key=lambda item: -item[1][0])]
    lines += [f"  late_ms not a bound: {v}" for v in honest.late_violations[:10]]
    lines += [f"  off, no clock/line WARN: {v}"
              for v in unwarned(result, medians)[:listed]]
    lines += [f"  an operator's op failed: {op}" for op in result.ops_failed[:10]]
    slow = [f for f in result.faults if f.recovered is None or f.recovered > result.bound]
    lines += [f"  not recovered within {result.bound:.0f} s: {f.kind} {f.detail} at "
              f"{f.start - result.started:.0f} s; last reasons: {last_reasons(result, f)}"
              for f in slow[:10]]
    invariants = {
        "recovery": (not slow, f"{len(result.faults) - len(slow)} of {len(result.faults)} "
                               f"within {result.bound:.0f} s"),
        "time outside windows": (out.p99 <= P99_TARGET and out.apart <= APART_TARGET,
                                 f"p99 {out.p99 * 1e3:.3f} ms, apart {out.apart * 1e3:.3f} ms"),
        "off samples warned": (warned >= HONEST_SHARE, f"{warned:.1%}"),
        "needless WARN": (needless <= NEEDLESS_SHARE, f"{needless:.1%}"),
        "late_ms a bound": (not honest.late_violations,
                            f"{len(honest.late_violations)} of {honest.late_given}"),
        "nothing lost in the gateway": (losses["in_gateway"] == 0 and not losses["seq_gaps"],
                                        f"{losses['in_gateway']}"),
        "the recording holds what was published": (
            result.recording is None or (result.recording[1] == 0 and result.recording[0] > 0),
            "no recording" if result.recording is None else
            f"{result.recording[1]:,} of {result.recording[0]:,} missing"),
        "RSS and fds flat": (late_growth(result) <= RSS_FLAT_KIB and fds1 <= fds0,
                             f"RSS {late_growth(result) / 1024:+.1f} MiB over the second "
                             f"half ({(rss1 - rss0) / 1024:+.1f} in all), "
                             f"fds {fds1 - fds0:+d}"),
    }
    return Report(lines, invariants)


def late_growth(result: Result) -> int:
    """KiB the gateway's RSS grew from the run's middle to its end (0 with too few
    readings for a middle)."""
    series = getattr(result, "rss", [])
    if len(series) < 3:
        return 0  # (too short a run to tell a step from growth: shown, not judged)
    (_, _), (rss1, _) = result.resources
    middle = series[-1][0] / 2
    at_middle = min(series, key=lambda reading: abs(reading[0] - middle))[1]
    return rss1 - at_middle


def last_reasons(result: Result, fault: Fault) -> str:
    """What the last poll within the bound after the fault said, for the reader."""
    end = (fault.end or fault.due) + result.bound
    polls = [p for p in result.polls if p.at <= end]
    if not polls:
        return "no status"
    poll = polls[-1]
    said = [f"gateway: {'; '.join(poll.gateway_reasons)}"] if poll.gateway_reasons else []
    said += [f"{a} {s.health} {'; '.join(s.reasons)}{'' if s.locked else ' (unlocked)'}"
             for a, s in poll.nodes.items() if s.health != "OK" or not s.locked]
    return " | ".join(said) or "OK"


def print_report(result: Result, report: Report) -> None:
    print(f"\nfault soak ({result.model}): {result.seconds / 60:.1f} min of faults after "
          f"{result.warmed - result.started:.0f} s of warm-up, {len(result.faults)} faults, "
          f"{len(result.polls):,} polls; health window {result.window_s:.0f} s, recovery "
          f"bound {result.bound:.0f} s")
    for line in report.lines:
        print(line)
    print()
    for name, (ok, text) in report.invariants.items():
        print(f"{'PASS' if ok else 'FAIL'}  {name}: {text}")
