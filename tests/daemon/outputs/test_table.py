"""An output is its module and its row of the table: built from its row, and in the
status report under its row's name, with no other file edited (issue 33)."""

from __future__ import annotations

import sys
import types
from typing import Any

import pytest
import zmq

from gateway.daemon import outputs as outputs_module
from gateway.daemon.config import GatewayConfig
from gateway.daemon.outputs import Needs, Output, Outputs, Row, build
from gateway.daemon.status import outputs_status
from tests.helpers.gateway import gateway_config


class Counted(Output):
    """A new output: it says how many messages it took."""

    def __init__(self) -> None:
        self.taken = 0

    def take(self, message: Any) -> None:
        self.taken += 1

    def status(self) -> dict[str, Any]:
        return {"taken": self.taken}


def test_a_new_output_in_the_table_is_in_the_status_report_under_its_name(
        monkeypatch: pytest.MonkeyPatch) -> None:
    module = types.ModuleType("gateway.daemon.outputs.counted")
    module.make = lambda needs: Counted()  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, module.__name__, module)
    monkeypatch.setitem(outputs_module.OUTPUTS, "counted",
                        Row("publish", "counted", in_status=True))
    config = GatewayConfig.model_validate(gateway_config("sim://", [{"address": 76}]))
    context = zmq.Context()
    try:
        fan = Outputs(build(Needs(config, context, None, dict)))
        try:
            fan.publish(76, "accel", {"seq": 1})
            # the outputs not configured say null, as they did before the table
            assert outputs_status(fan) == {"counted": {"taken": 1}, "recording": None,
                                           "live": None, "lsl": None,
                                           "mqtt": None}
        finally:
            for output in fan.by_name.values():
                output.close(0.0)
    finally:
        context.destroy(linger=0)
