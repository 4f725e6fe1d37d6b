"""The simulator's thread is named where ``top -H`` shows it, so the demo's CPU splits
into the simulator's and the gateway's own (bench/democpu.py)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from gateway.sim.node import NodeSettings
from gateway.sim.server import Simulator


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc is Linux's")
def test_the_simulators_thread_is_named_gx2_sim_for_the_kernel() -> None:
    with Simulator([NodeSettings(76)]) as sim:
        names = {(task / "comm").read_text().strip()
                 for task in Path("/proc/self/task").iterdir()}
        assert sim.error is None
    assert "gx2-sim" in names
