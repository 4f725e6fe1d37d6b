"""SIGTERM while a request is still running, through the installed gx2-gateway over
gx2-sim: the request is answered (gx2ctl exits 1 with one line saying why) before the
gateway goes, and the gateway still exits 0 within the promised 2 s, starting nothing
on its way out."""

from __future__ import annotations

import pytest
import zmq

from gateway.sim.node import NodeSettings
from tests.helpers.processes import EXIT, STARVED, Running
from tests.helpers.simulated import received
from tests.helpers.waiting import wait_for


def after_the_capture(sim, node: int) -> list[int]:
    """The codes of the commands ``node`` received after its bias capture."""
    def codes(station, now) -> list[int]:
        log = [c.code for c in station.nodes[node].log.commands]
        return log[log.index(0xCD) + 1:]
    return sim.call(codes)


@pytest.mark.parametrize("busy", [False, True], ids=["plain", "stopping-and-recording"])
def test_sigterm_during_a_capture_answers_it_and_exits_within_the_promise(
        simulator, gateway, tmp_path, busy):
    """``busy``: the shutdown also stops streams and finishes a recording, so the loop
    runs on for a while after the request was cut short."""
    sim = simulator(NodeSettings(76))
    sections = ({"shutdown": {"stop_streams": True},
                 "record": {"directory": str(tmp_path / "recordings")}} if busy else {})
    gw = gateway(sim.path, [{"address": 76, "stream": "accel_angrate"}], **sections)
    gw.wait_streaming(76)
    capture = Running("gx2ctl", "--config", str(gw.path), "bias", "capture", "76",
                      "--ms", "5000")
    try:
        # (gx2ctl's start, then the stream's stop confirmed, then the capture: 5 s was
        # outlived once, beside the suite and a 60-seed sweep on this machine's 2 cores)
        wait_for(lambda: received(sim, 76, 0xCD), 15, "the capture to reach node 76")
        status, took = gw.terminate()
        assert status == 0, gw.log()
        assert took < EXIT + STARVED, f"exited after {took:.2f} s"
        # answered before the gateway went: gx2ctl does not wait for its own timeout
        assert capture.finish(STARVED) == 1, capture.stderr
    finally:
        capture.kill()
    notice, *errors = capture.stderr
    assert "keep it still" in notice
    assert len(errors) == 1 and "shutting down" in errors[0], capture.stderr
    assert 0xC4 not in after_the_capture(sim, 76), "its stream was started again"
    log = gw.log()
    assert "write failed" not in log, log
    assert "Traceback" not in log, log


def test_a_subscriber_that_stopped_reading_never_holds_the_exit_past_the_promise(
        simulator, gateway, zmq_context):
    # what the publisher still holds for its subscribers has the shutdown's time left
    # to reach them, and no more: this one reads nothing, its buffers full
    sim = simulator(NodeSettings(76, divider=256), NodeSettings(77, divider=256))
    gw = gateway(sim.path, [{"address": 76, "stream": "accel_angrate"},
                            {"address": 77, "stream": "accel_angrate"}])
    stalled = zmq_context.socket(zmq.SUB)
    stalled.setsockopt(zmq.RCVHWM, 1)
    stalled.setsockopt(zmq.RCVBUF, 1024)
    stalled.setsockopt(zmq.LINGER, 0)
    stalled.setsockopt(zmq.SUBSCRIBE, b"")
    stalled.connect(gw.publish_endpoint)
    try:
        wait_for(lambda: stalled.poll(0), 10, "the subscription to reach the gateway")
        sub = gw.subscribe("gx2/76/")
        sub.until(lambda m: len(m) >= 400, 10, "two seconds more of node 76")
        status, took = gw.terminate()
        assert status == 0, gw.log()
        assert took < EXIT + STARVED, f"exited after {took:.2f} s"
    finally:
        stalled.close()
