"""gx2-sim's loop outlives an unplug that lands between its registering the port and
its select, the port's descriptor closed under it. (It died with EBADF, and a replug
then found nothing serving the port: tests/e2e/test_calibration.py's unplug failed a CI
run so.) The window is made to happen every time: the loop's selector unplugs the port
itself just before it selects."""

from __future__ import annotations

import os
import select
import selectors
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from gateway.sim import server
from gateway.sim.node import NodeSettings
from gateway.sim.server import Simulator
from tests.helpers.waiting import wait_for


class RacingSelector(selectors.SelectSelector):
    """A select-based selector that runs ``before_next`` (once) just before a select."""

    before_next: Callable[[], None] | None = None

    def select(self, timeout: float | None = None) -> list:  # type: ignore[override]
        action, RacingSelector.before_next = RacingSelector.before_next, None
        if action is not None:
            action()
        return super().select(timeout)


def test_the_loop_survives_an_unplug_between_its_registering_and_its_select(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(server.selectors, "SelectSelector", RacingSelector)
    sim = Simulator([NodeSettings(76, stream="accel_angrate")], link=tmp_path / "gx2").start()
    try:
        RacingSelector.before_next = sim.unplug
        wait_for(lambda: RacingSelector.before_next is None and not sim.port.is_open, 5,
                 "the unplug inside the loop's select")
        sim.replug()
        # it still serves the port: the stream's bytes arrive
        fd = os.open(sim.path, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
        try:
            deadline = time.monotonic() + 5.0
            data = b""
            while not data and time.monotonic() < deadline:
                readable, _, _ = select.select([fd], [], [], deadline - time.monotonic())
                data = os.read(fd, 4096) if readable else b""
            assert data, f"nothing served after the replug: {sim.error!r}"
        finally:
            os.close(fd)
    finally:
        sim.stop()
    assert sim.error is None, sim.error
