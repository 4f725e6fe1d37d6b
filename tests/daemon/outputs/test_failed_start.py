"""A start that fails leaves nothing serving: the outputs built before what could not
bind are closed, with real sockets on the loopback (issue 33: the metrics and live view
servers were left listening after the StartupError)."""

from __future__ import annotations

import socket
from collections.abc import Iterator
from typing import Any

import pytest
import zmq

from gateway.daemon.app import Gateway
from gateway.daemon.config import GatewayConfig
from gateway.daemon.errors import StartupError
from tests.helpers.gateway import gateway_config
from tests.helpers.ports import free_port


@pytest.fixture
def taken() -> Iterator[int]:
    """A loopback TCP port something else listens on."""
    with socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen()
        yield listener.getsockname()[1]


def serving(port: int) -> bool:
    with socket.socket() as probe:
        return probe.connect_ex(("127.0.0.1", port)) == 0


def start(config: dict[str, Any]) -> None:
    with pytest.raises(StartupError, match="cannot bind"):
        Gateway(GatewayConfig.model_validate(config))


def test_a_control_port_in_use_leaves_no_output_serving(taken: int, tmp_path) -> None:
    metrics, live = free_port(), free_port()
    start(gateway_config("sim://", [{"address": 76}],
                         control={"endpoint": f"tcp://127.0.0.1:{taken}"},
                         metrics={"endpoint": f"127.0.0.1:{metrics}"},
                         live={"endpoint": f"127.0.0.1:{live}"},
                         record={"directory": str(tmp_path / "rec")}))
    assert {"metrics": serving(metrics), "live": serving(live)} == \
        {"metrics": False, "live": False}
    assert not (tmp_path / "rec").exists() or not any((tmp_path / "rec").iterdir())


def test_an_output_that_cannot_bind_closes_those_built_before_it(taken: int) -> None:
    metrics, publish = free_port(), f"tcp://127.0.0.1:{free_port()}"
    start(gateway_config("sim://", [{"address": 76}], publish={"endpoint": publish},
                         metrics={"endpoint": f"127.0.0.1:{metrics}"},
                         live={"endpoint": f"127.0.0.1:{taken}"}))
    assert not serving(metrics)
    # and ZeroMQ's publication (built first) let its endpoint go
    context = zmq.Context()
    try:
        context.socket(zmq.PUB).bind(publish)
    finally:
        context.destroy(linger=0)
