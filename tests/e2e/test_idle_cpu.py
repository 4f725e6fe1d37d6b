"""What the gateway costs while it waits: the installed gx2-gateway over gx2-sim on a
pty, its CPU time read from the kernel (/proc/PID/stat) while nothing but waiting is
to be done."""

from __future__ import annotations

import os
import time
from pathlib import Path

from gateway.sim.node import NodeSettings
from gateway.sim.physics import Motion
from tests.helpers.processes import Running
from tests.helpers.simulated import received
from tests.helpers.waiting import wait_for

TICKS = os.sysconf("SC_CLK_TCK")
BASELINE = 1.0
"""Seconds of the capture alone, measured as the idle level the queued poll is held to."""
MARGIN = 0.25
"""Share of one core allowed over that idle level: the waiting spun at 90-100% (issue 19),
a waiting gateway takes 1-3%, and a loaded CI machine can slow a spin but not start one."""


def cpu_seconds(pid: int) -> float:
    """User and system CPU time of every thread of ``pid`` (fields 14 and 15)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS


class Meter:
    """The share of one core a process used since the meter started."""

    def __init__(self, pid: int) -> None:
        self.pid = pid
        self.cpu, self.wall = cpu_seconds(pid), time.monotonic()

    def share(self) -> float:
        return (cpu_seconds(self.pid) - self.cpu) / (time.monotonic() - self.wall)


def test_a_poll_queued_behind_a_bias_capture_leaves_the_gateway_idle(simulator, gateway):
    """Issue 19: a poll of a node whose bias capture awaits its reply made the
    scheduler's timer fire back to back until that reply came, about 90% of a core for
    the whole capture; waiting behind it must cost what waiting alone costs."""
    sim = simulator(NodeSettings(76, motion=Motion(yaw_rate=0.0)))
    gw = gateway(sim.path, [{"address": 76, "stream": "accel_angrate"}])
    gw.wait_streaming(76)
    config = ("--config", str(gw.path))
    capture = Running("gx2ctl", *config, "bias", "capture", "76", "--ms", "3500")
    poll = None
    try:
        wait_for(lambda: received(sim, 76, 0xCD), 5, "the capture to reach node 76")
        alone = Meter(gw.proc.pid)
        # the interval measured, not a synchronisation: the node only samples in it
        time.sleep(BASELINE)
        idle = alone.share()
        queued = Meter(gw.proc.pid)
        poll = Running("gx2ctl", *config, "--timeout", "10", "poll", "76", "accel_angrate")
        assert capture.finish(10) == 0, capture.stderr
        busy = queued.share()
        assert poll.finish(10) == 0, poll.stderr
    finally:
        capture.kill()
        if poll is not None:
            poll.kill()
    assert '"accel"' in "".join(poll.stdout), poll.stdout
    assert received(sim, 76, 0xC2), "the poll never reached the node"
    assert busy < idle + MARGIN, (f"the gateway used {busy:.0%} of a core with a poll "
                                  f"queued behind the capture, {idle:.0%} without")
