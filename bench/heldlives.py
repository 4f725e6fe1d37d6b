"""Random lives of one node's clock, checked against the truth while held.

A life is a seeded list of stretches: free (each packet's delay above the floor
exponential, mean 0.3 ms), behind another node (every packet waited 1 to 3.4 ms),
held over capacity (the queue 0.3 s and growing nothing the clock may learn from),
released or left held into the next stretch, a reboot, an outage longer than the
clock's window. For every packet while held (not HELD_FRESH, which gives no bound), how
far ``time`` moved away from the truth since the hold is compared with
``NodeClock.held_error()``: a life whose movement passed it by more than a fifth of
FLOOR_NOISE is printed, worst first, with the stretch and the fit's base.

    .venv/bin/python bench/heldlives.py --lives 600
    .venv/bin/python bench/heldlives.py --show 135     # one life's stretches

Pure code, no I/O: the clock of aspp/clock.py as it is in this checkout.
"""

from __future__ import annotations

import argparse
import random
from dataclasses import dataclass

from aspp.clock import FLOOR_NOISE, NodeClock
from aspp.clockstate import HELD

PERIOD = 0.01
"""Seconds between packets (100 Hz)."""
SPANS = (0.5, 1.5, 3, 8, 12, 20, 40, 70)
KINDS = ("free", "free", "free", "behind", "hold", "reset", "outage")
OUTAGE_S = 61.0
"""Device seconds skipped by an outage: more than the clock's window."""
SLACK = FLOOR_NOISE / 5
"""How far past held_error a movement must go to count (the floor's own jitter)."""


@dataclass(frozen=True)
class Stretch:
    kind: str
    seconds: float
    release: bool = True
    """For a hold: whether the line is released at its end (else held into the next)."""


@dataclass(frozen=True)
class Miss:
    """The worst packet of a life whose held time moved past held_error."""

    excess: float
    stretch: int
    kind: str
    fitted: float
    moved: float
    allowed: float


def life(seed: int) -> tuple[float, list[Stretch]]:
    """The crystal's true drift and the stretches of life ``seed``."""
    rand = random.Random(seed)
    drift = rand.uniform(-100e-6, 100e-6)
    return drift, [Stretch(rand.choice(KINDS), rand.choice(SPANS), rand.random() < 0.5)
                   for _ in range(rand.randint(5, 25))]


def live(seed: int, drift: float, stretches: list[Stretch]) -> Miss | None:
    """Run one life through a NodeClock; its worst miss, or None."""
    rand = random.Random(seed)
    clock, offset, device = NodeClock(), 1000.0, 0.0
    worst: Miss | None = None
    reference: float | None = None
    for number, stretch in enumerate(stretches):
        if stretch.kind == "reset":
            clock.reset()
            offset += device + rand.uniform(1, 5)
            device = 0.0
            continue
        if stretch.kind == "outage":
            device += OUTAGE_S
            continue
        if stretch.kind == "hold":
            if clock.held:
                clock.release()
                continue
            if clock.state.name == "FRESH":
                continue
            clock.hold()
            reference = None
        for i in range(round(stretch.seconds / PERIOD)):
            at = device + i * PERIOD
            truth = offset + (1 + drift) * at + 0.003
            if clock.held:
                delay, waited = 0.3 + rand.uniform(0, 0.01), True
            elif stretch.kind == "behind":
                delay, waited = rand.uniform(0.001, 0.0034), True
            else:
                delay, waited = rand.expovariate(1 / 0.0003), False
            given = clock.update(at, truth + delay, waited)
            if clock.state is not HELD:
                continue
            if reference is None:
                reference = given - truth
                continue
            allowed = clock.held_error() or 0.0
            # (away from the truth: a line released shortly before the hold may still
            # be slewing towards it, SLEW, and that movement is no error)
            moved = abs(given - truth) - abs(reference)
            if moved > allowed + SLACK and (worst is None or moved - allowed > worst.excess):
                worst = Miss(moved - allowed, number, stretch.kind,
                             clock._fitted, moved, allowed)  # (the bench looks inside)
        device += round(stretch.seconds / PERIOD) * PERIOD
        if stretch.kind == "hold" and clock.held and stretch.release:
            clock.release()
    return worst


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lives", type=int, default=300)
    parser.add_argument("--first", type=int, default=0, help="the first life's seed")
    parser.add_argument("--show", type=int, help="print one life's stretches and its miss")
    args = parser.parse_args()
    if args.show is not None:
        drift, stretches = life(args.show)
        print(f"drift {drift * 1e6:+.1f} ppm")
        for number, stretch in enumerate(stretches):
            print(number, stretch)
        print(live(args.show, drift, stretches))
        return
    misses = []
    for seed in range(args.first, args.first + args.lives):
        miss = live(seed, *life(seed))
        if miss is not None:
            misses.append((miss.excess, seed, miss))
    misses.sort(key=lambda found: -found[0])
    print(f"{len(misses)} of {args.lives} lives moved past held_error "
          f"(by more than {SLACK * 1e3:.1f} ms)")
    for excess, seed, miss in misses[:8]:
        print(f"seed {seed}: {excess * 1e3:.3f} ms past, in stretch {miss.stretch} "
              f"({miss.kind}), drift fitted over {miss.fitted:.1f} s, moved "
              f"{miss.moved * 1e3:.3f} ms, allowed {miss.allowed * 1e3:.3f} ms")


if __name__ == "__main__":
    main()
