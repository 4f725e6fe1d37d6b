"""Sample time placed after the fact (aspp.refine), on synthetic streams whose truth is
known: a stretch in which every packet waited behind another node's is placed from the
sightings of the floor on both sides of it, where the live estimate (aspp.clock) rests
on the waiting packets and is late by their wait."""

from __future__ import annotations

import random

from aspp.clock import FLOOR_NOISE, NodeClock
from aspp.refine import Placement, refine

PERIOD = 0.01
FLOOR = 0.003
DRIFT = 30e-6
OFFSET = 500.0
PACKET = 0.0034
"""The time on the line of the packet queued ahead (39 bytes at 115200 baud)."""
HIDDEN = (100.0, 250.0)
"""Device seconds in which each packet waits behind another node's: longer than the
live estimate's window (a minute), so that its line comes to rest on them."""


def floor_at(device: float) -> float:
    """When a packet sampled at ``device`` arrives with the least delay there is."""
    return OFFSET + (1 + DRIFT) * device + FLOOR


def stream(seconds: float, hidden: tuple[float, float], seed: int
           ) -> list[tuple[float, float, bool]]:
    """(device, arrival, waited) every PERIOD: a free line's delays (most within a
    fraction of a millisecond of the floor) but inside ``hidden``, where each packet
    waited on the line behind another's for the rest of that one's time there."""
    rng = random.Random(seed)
    points = []
    for i in range(round(seconds / PERIOD)):
        device = i * PERIOD
        behind = hidden[0] <= device < hidden[1]
        delay = rng.uniform(2 * FLOOR_NOISE, PACKET) if behind else rng.expovariate(1 / 3e-4)
        points.append((device, floor_at(device) + delay, behind))
    return points


def live_times(points: list[tuple[float, float, bool]]) -> list[float]:
    clock = NodeClock()
    return [clock.update(device, arrival, waited) for device, arrival, waited in points]


def test_a_hidden_stretch_is_placed_from_the_sightings_on_both_sides_of_it() -> None:
    points = stream(350.0, HIDDEN, seed=3)
    live = live_times(points)
    placed = refine(points, live)
    inside = [i for i, (device, _, _) in enumerate(points)
              if HIDDEN[0] <= device < HIDDEN[1]]
    assert len(inside) == 15000

    def error(times: list[float], i: int) -> float:
        return times[i] - floor_at(points[i][0])

    # live: the line rests on the waiting packets, late by their least wait (1 ms here)
    assert max(error(live, i) for i in inside) > 0.8e-3
    # refined: bridged between the sightings on either side, within 0.2 ms throughout,
    # and each row's bound holds its error
    assert {placed.placement[i] for i in inside} == {Placement.BETWEEN}
    assert max(abs(error(placed.line, i)) for i in inside) <= 0.2e-3
    for i in inside:
        assert abs(error(placed.line, i)) <= placed.bound[i]  # type: ignore[operator]
    # and on the free line around it, no worse than live
    settled = [i for i, (device, _, _) in enumerate(points)
               if 20.0 <= device < HIDDEN[0] or HIDDEN[1] <= device < 330.0]
    assert max(abs(error(placed.line, i)) for i in settled) <= 0.2e-3


def test_a_stretch_hidden_to_the_end_keeps_the_live_time() -> None:
    # no sighting after it: nothing bridges it, so the live time stands, said as such
    points = stream(200.0, (150.0, 200.0), seed=4)
    live = live_times(points)
    placed = refine(points, live)
    last = len(points) - 1
    assert placed.placement[last] is Placement.LIVE
    assert placed.line[last] == live[last] and placed.bound[last] is None


def test_a_power_up_that_never_shows_its_floor_is_unplaceable_in_every_row() -> None:
    points = stream(60.0, (0.0, 60.0), seed=5)
    placed = refine(points, live_times(points))
    assert set(placed.placement) == {Placement.UNPLACEABLE}
    assert set(placed.bound) == {None}
