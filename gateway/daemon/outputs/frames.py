"""A node's orientation as Foxglove draws it: for each record with an orientation (a
matrix's quaternion, or the euler angles), a ``foxglove.FrameTransform`` on
``gx2/<address>/frame``, given to the live view and the recorder (never to ZeroMQ: its
subscribers' topics are the records').

The frame is the node's sensor frame in the earth frame (north, east, down), named
PARENT_FRAME: the child frame is the node's name (``gx2-<address>`` for a node without
one) as the node's state says it now, so a reload that names, renames or adds a node
is seen from its next record; its rotation the record's orientation
(:mod:`aspp.orientation`), its translation none, its timestamp the sample's ``time``.
Which records give one is decided once a node and record (:meth:`Frames.maker`); a
record without one pays nothing more. A record with no orientation to give (a NaN
matrix, a replayed record without its fields or with a matrix no float holds) gives no
frame, and is published all the same.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

from aspp.orientation import Quaternion, quaternion_from_euler, quaternion_from_matrix
from aspp.records import ORIENTED
from gateway.common.topics import frame_topic
from gateway.recording.files import OutOfRange, message_times, ns

from .message import Message

PARENT_FRAME = "world"
"""The frame every node's frame hangs from: the GX2's earth frame (x north, y east, z
down). Foxglove's 3D panel draws its z axis up: the nodes are seen from below."""
EULER = frozenset(("euler", "euler_angrate"))
"""The records with the euler angles and no matrix."""
_ORIGIN = {"x": 0.0, "y": 0.0, "z": 0.0}

MakeFrame = Callable[[Mapping[str, Any]], "Message | None"]


def child_frame(address: int, name: str | None) -> str:
    """A node's frame's name: its configured name, else ``gx2-<address>``."""
    return name or f"gx2-{address}"


def _of_matrix(payload: Mapping[str, Any]) -> Quaternion:
    """The record's quaternion (Node.tally's), or its matrix's where it has none (a file
    of messages recorded before records carried one, replayed)."""
    quaternion = payload.get("quaternion")
    if quaternion is None:
        return quaternion_from_matrix(payload["orientation"])
    return quaternion  # type: ignore[no-any-return]


def _of_euler(payload: Mapping[str, Any]) -> Quaternion:
    return quaternion_from_euler(payload["roll"], payload["pitch"], payload["yaw"])


class Frames:
    """Each node's frame: its name, and which of its records give it."""

    def __init__(self, name_of: Callable[[int], str | None]) -> None:
        self._name_of = name_of
        """A node's configured name now (None: unnamed, or no such node), read for
        each frame from the one place a reload changes (the nodes' states)."""

    def maker(self, node: int, record: str) -> MakeFrame | None:
        """What makes the frame of ``node``'s ``record``: None for a record with no
        orientation."""
        if record in ORIENTED:
            rotation = _of_matrix
        elif record in EULER:
            rotation = _of_euler
        else:
            return None
        topic = frame_topic(node)
        name_of = self._name_of

        def make(payload: Mapping[str, Any]) -> Message | None:
            """The frame of one record; None when it has none to give (a NaN angle, a
            time no timestamp holds: a foreign recording replayed)."""
            try:
                w, x, y, z = rotation(payload)
                if not math.isfinite(w + x + y + z):
                    return None
                times = message_times(payload)
                stamp = ns(times[1])
            except (KeyError, TypeError, ValueError, OverflowError, OutOfRange):
                return None  # (a replayed record without its fields, or with text or an
                #              int no float holds in them)
            frame = {"timestamp": {"sec": stamp // 1_000_000_000,
                                   "nsec": stamp % 1_000_000_000},
                     "parent_frame_id": PARENT_FRAME,
                     "child_frame_id": child_frame(node, name_of(node)),
                     "translation": _ORIGIN, "rotation": {"x": x, "y": y, "z": z, "w": w}}
            return Message(topic, frame, times)
        return make
