"""Subscribing to gx2-gateway from Python: the records of chosen nodes, from one gateway
or several, with their losses counted; and the same records read back from its
recordings, so an analysis script is the same live and offline.

    from gateway.client import Recording, Subscriber

    with Subscriber("tcp://127.0.0.1:5555", nodes=[76], records=["accel_angrate"]) as sub:
        for message in sub:
            print(message.node, message.time, message["accel"], message.gap)

    with Recording("recordings/", nodes=[76], records=["accel_angrate"],
                   between_marks=("start", "stop"), trial=1) as sub:
        ...  # the same loop

Modules: :mod:`.messages` (what both yield), :mod:`.subscriber` (live, ZeroMQ),
:mod:`.recorded` (the recordings), :mod:`.frames` (``to_pandas``), :mod:`.arrows`
(``Recording.to_arrow``). The recordings' reader is imported when first asked for:
``gx2ctl tail`` and ``top`` do not pay for it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from .messages import BOOKKEEPING, Event, Malformed, Message, Status
from .subscriber import GatewayError, Subscriber

if TYPE_CHECKING:
    from gateway.recording.files import RecordingError
    from gateway.recording.parquetfile import MissingExtra
    from gateway.recording.refined import Unrefinable
    from gateway.recording.window import WindowError

    from .frames import to_pandas
    from .recorded import Recording

__all__ = ["BOOKKEEPING", "Event", "GatewayError", "Malformed", "Message", "MissingExtra",
           "Recording", "RecordingError", "Status", "Subscriber", "Unrefinable", "WindowError",
           "to_pandas"]

_LATER = {"Recording": ("gateway.client.recorded", "Recording"),
          "to_pandas": ("gateway.client.frames", "to_pandas"),
          "RecordingError": ("gateway.recording.files", "RecordingError"),
          "WindowError": ("gateway.recording.window", "WindowError"),
          "Unrefinable": ("gateway.recording.refined", "Unrefinable"),
          "MissingExtra": ("gateway.recording.parquetfile", "MissingExtra")}
"""Names imported when first used (the recordings' reader costs some 100 ms to load)."""


def __getattr__(name: str) -> Any:
    if name not in _LATER:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib
    module, attribute = _LATER[name]
    value = getattr(importlib.import_module(module), attribute)
    globals()[name] = value
    return value
