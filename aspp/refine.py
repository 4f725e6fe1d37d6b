"""A node's clock placed after the fact, from a whole power-up's packets at once.

Live, :class:`aspp.clock.NodeClock` knows only the packets already read: while a node's
packets all wait behind another's, the line rests on them and ``time`` is late by the
wait (issue 32), and after it, the floor seen again moves the line but not the times
already given. A recording holds the future too. In the plane of x = device seconds and
y = arrival - device, every packet lies on or above the floor's line, and the packets
that did not wait (:func:`aspp.clock.waited` false) are the ones that may lie on it; a
stretch in which none did is placed by the sightings on both sides of it: the lower
hull's edge across the stretch, whose ends are packets on the floor.

The drift is not one number over hours: a crystal follows its temperature (about a ppm
per kelvin). So the hull is local: each SPAN of device time is placed by the lower hull
of the sightings within REACH either side of it, reached further out to the nearest
sighting where a side has none (a hidden stretch longer than REACH). Over the reach the
drift is taken as straight; a drift that bends at DRIFT_RATE over a gap of ``a + b``
seconds (a after the last sighting, b before the next) leaves the chord at most
``DRIFT_RATE * a * b / 2`` from the floor, which is the bound a bridged point carries
with the sightings' own noise.

Cost: the sightings are reduced to the lower hull of each BLOCK first (a hull of a
union is the hull of the parts' hulls), so a span's hull is built from a few hundred
vertices; a day of one node at 100 Hz (8.6 million packets) is about 8,600 such hulls.

Pure: fed (device, arrival, waited) triples in device order, it returns where each
falls; the caller converts to its own clock, as :class:`~aspp.clock.NodeClock`'s do.
"""

from __future__ import annotations

import bisect
import statistics
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum

from .clock import DRIFT_ERROR, DRIFT_RATE, FLOOR_NOISE, MAX_DRIFT, _push

SPAN = 10.0
"""Device seconds placed by one local hull."""
REACH = 120.0
"""Device seconds of sightings either side of a span that its hull is built from: long
enough that a hull's ends are far apart (the drift's error is the floor's noise over
the reach), short enough that a crystal's drift is straight across it."""
BLOCK = 2.0
"""Device seconds whose sightings are reduced to their own lower hull first."""
BEYOND = 2
"""Blocks of sightings a span's hull reaches past REACH on a side (where it has any):
the sightings nearest a hidden stretch longer than REACH, and more past them."""
LAG = 30.0
"""Device seconds between the two lowest points a drift's slope is taken across."""
TRUST = 0.3e-3
"""How far above the reach's floor, along its drift, a sighting may lie and still be
part of the hull: a crystal's drift bending by a ppm over the reach moves the floor by
0.12 ms, a packet that waited before the line by a millisecond or more."""
SIGHTING_NOISE = 0.1e-3
"""How far above the floor a packet that did not wait may lie: the host's read
latency on top of the line's (what bench/linemodels.py counts as a floor shown)."""


class Placement(Enum):
    """How a point was placed."""

    BETWEEN = "between"
    """By sightings on both sides of it (or on it)."""
    ONE_SIDE = "one_side"
    """By sightings on one side only (before the first, or after the last, sighting of
    its power-up): the line extrapolated at the drift measured."""
    LIVE = "live"
    """No two sightings bracket it inside the hull: its time as the live estimate gave
    it."""
    UNPLACEABLE = "unplaceable"
    """No packet of its power-up showed the floor: placed on the lowest of them, late
    by a wait no packet shows."""


@dataclass(frozen=True)
class Refined:
    """Per point: ``line`` (arrival of a packet sent at its device time with the
    floor's delay, on the caller's clock), how it was placed, and how far from the
    floor that may be (seconds; None when unplaceable: the wait is unknown)."""

    line: list[float]
    placement: list[Placement]
    bound: list[float | None]


def _block_hulls(xs: Sequence[float], ys: Sequence[float]) -> list[tuple[float, list]]:
    """The sightings' lower hull per BLOCK: (block start, vertices)."""
    blocks: list[tuple[float, list]] = []
    for x, y in zip(xs, ys, strict=True):
        if not blocks or x - blocks[-1][0] >= BLOCK:
            blocks.append((x, []))
        _push(blocks[-1][1], x, y)
    return blocks


def _lag_slopes(points: list[tuple[float, float]], lag: float) -> list[float]:
    """Slopes between points at least ``lag`` apart in x, each point paired with the
    first that far after it (Theil and Sen's estimator, thinned to O(n))."""
    slopes = []
    j = 0
    for x, y in points:
        while j < len(points) and points[j][0] - x < lag:
            j += 1
        if j == len(points):
            break
        slopes.append((points[j][1] - y) / (points[j][0] - x))
    return slopes


def _near_hull(lows: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """The blocks' lowest points within TRUST of their own lower hull. A block whose
    every sighting waited in the base station lies above it; in a short recording a
    hidden stretch is many of the blocks, and the slopes from them were the median
    (gx2-sim through the gateway, 52 s, a node hidden for 20: -65 ppm for -50, and the
    sightings after the stretch fell outside TRUST of that drift)."""
    base: list[tuple[float, float]] = []
    for x, y in lows:
        _push(base, x, y)
    near = []
    j = 0
    for x, y in lows:
        while j < len(base) - 2 and base[j + 1][0] <= x:
            j += 1
        (xa, ya), (xb, yb) = base[j], base[min(j + 1, len(base) - 1)]
        under = ya if xb == xa else ya + (yb - ya) * (x - xa) / (xb - xa)
        if y - under <= TRUST:
            near.append((x, y))
    return near


def _trusted_hull(blocks: list[tuple[float, list]], lo: int,
                  hi: int) -> tuple[list[tuple[float, float]], float]:
    """The lower hull of the sightings in ``blocks[lo:hi]`` that lie within TRUST of the
    floor. A packet that did not wait on the serial line may still have waited before
    it (in the base station, behind another node's packet: issue 32), and a run of
    them to one end of the reach tilts a hull's end edge by milliseconds (gx2-sim seed
    4: 57 ms). So the reach's drift is taken first from the blocks' lowest points, as
    the median of slopes across LAG (a run of late blocks is a minority of pairs), and
    only the points within TRUST of the lowest, along that drift, make the hull; the
    drift is returned with it (what carries the line beyond the hull's ends)."""
    lows = [min(vertices, key=lambda v: v[1]) for _, vertices in blocks[lo:hi]]
    near = _near_hull(lows)
    slopes = _lag_slopes(near, LAG) or _lag_slopes(near, BLOCK / 2)
    drift = statistics.median(slopes) if slopes else 0.0
    drift = max(-MAX_DRIFT, min(MAX_DRIFT, drift))
    floor = min(y - drift * x for x, y in lows)
    hull: list[tuple[float, float]] = []
    for _, vertices in blocks[lo:hi]:
        for x, y in vertices:
            if y - drift * x <= floor + TRUST:
                _push(hull, x, y)
    return hull, drift


def _at(hull: list[tuple[float, float]], drift: float,
        x: float) -> tuple[float, float | None, float | None]:
    """The hull's height at ``x`` and the device times of the sightings whose edge it
    lies on; beyond the hull's ends, from the end along ``drift`` (the reach's, never an
    end edge's steep slope: gx2-sim seed 2 was 10 ms early so), with None for the side
    that has none."""
    (x0, y0), (x1, y1) = hull[0], hull[-1]
    if x <= x0:
        return y0 + drift * (x - x0), None, x0
    if x >= x1:
        return y1 + drift * (x - x1), x1, None
    i = min(max(bisect.bisect_left(hull, (x,)), 1), len(hull) - 1)
    (xa, ya), (xb, yb) = hull[i - 1], hull[i]
    return ya + (yb - ya) * (x - xa) / (xb - xa), xa, xb


def refine(points: Sequence[tuple[float, float, bool]],
           live: Sequence[float] | None = None) -> Refined:
    """Place each (device, arrival, waited) point of one power-up (device seconds from
    its timer, arrival on the caller's clock, in device order) from all of them; where
    no two sightings inside the reach's hull bracket a point, ``live[i]`` (the time the
    live estimate gave it, on the same clock) is kept, if given (LIVE)."""
    seen_x = [d for d, _, waited in points if not waited]
    seen_y = [a - d for d, a, waited in points if not waited]
    if not seen_x:
        floor = min((a - d for d, a, _ in points), default=0.0)
        return Refined([d + floor for d, _, _ in points],
                       [Placement.UNPLACEABLE] * len(points), [None] * len(points))
    blocks = _block_hulls(seen_x, seen_y)
    starts = [start for start, _ in blocks]
    line: list[float] = []
    placement: list[Placement] = []
    bound: list[float | None] = []
    span_start, hull, drift = None, [], 0.0
    for i, (device, _, _) in enumerate(points):
        if span_start is None or device - span_start >= SPAN:
            span_start = device
            # the blocks within REACH either side, and BEYOND more past each edge of
            # the span that has any (a hidden stretch longer than REACH is bridged: with
            # one block only, the edge across the stretch could end at that block's
            # last sighting, the hull's end, and bridge nothing)
            lo = bisect.bisect_right(starts, device - REACH) - BEYOND
            hi = bisect.bisect_left(starts, device + SPAN + REACH) + BEYOND
            hull, drift = _trusted_hull(blocks, max(lo, 0), min(hi, len(blocks)))
        y, left, right = _at(hull, drift, device)
        inside = (left is not None and right is not None and left > hull[0][0]
                  and right < hull[-1][0])
        if live is not None and not inside:
            # (a hull's end is its first or last point whatever its height: an edge to
            # it bridges nothing, and a run of late packets there tilted it by 57 ms)
            line.append(live[i])
            placement.append(Placement.LIVE)
            bound.append(None)
            continue
        line.append(device + y)
        if left is not None and right is not None:
            # (on the edge between two sightings: a drift bending at DRIFT_RATE leaves
            # the chord at most DRIFT_RATE * a * b / 2 from the floor)
            placement.append(Placement.BETWEEN)
            bound.append(SIGHTING_NOISE + DRIFT_RATE * (device - left) * (right - device) / 2)
        else:
            placement.append(Placement.ONE_SIDE)
            away = abs(device - (left if left is not None else right))  # type: ignore[operator]
            bound.append(SIGHTING_NOISE + DRIFT_ERROR * away + DRIFT_RATE * away * away / 2)
    return Refined(line, placement, bound)


__all__ = ["FLOOR_NOISE", "REACH", "SPAN", "Placement", "Refined", "refine"]
