"""Publish topics: ``gx2/<address>/<record>`` for a node's records (decimal address,
no padding, so a subscriber to ``gx2/76/`` gets node 76 and never node 760) and
``gx2/gateway/status`` for the gateway's own heartbeat and ``gx2/gateway/mark`` for the
marks made with ``gx2ctl mark``, which no node topic can equal. ``gx2/<address>/frame``
is a node's orientation as Foxglove draws it (the live view and recordings only).
"""

from __future__ import annotations

import functools
import re

PREFIX = "gx2/"
STATUS_TOPIC = b"gx2/gateway/status"
MARK_TOPIC = b"gx2/gateway/mark"
"""A mark (``gx2ctl mark``): ``text``, ``time`` and ``host_time`` (UNIX s, when the
gateway took it), ``nodes`` (the nodes it concerns; empty: the whole experiment)."""
NODE_TOPIC = re.compile(rb"gx2/[0-9]+/")
"""Matches the start of a node's topic (not the gateway's own gx2/gateway/...)."""


def topic(node: int, record: str) -> bytes:
    return f"gx2/{node}/{record}".encode("ascii")


def node_prefix(node: int) -> str:
    """What to subscribe to for every record of ``node``."""
    return f"gx2/{node}/"


FRAME = "frame"
"""The last part of a node's frame topic, ``gx2/<address>/frame``: its orientation as
Foxglove's FrameTransform, in the live view and recordings only (never on ZeroMQ), and
no record (no ``seq``, none of a record's fields)."""


def frame_topic(node: int) -> bytes:
    return f"gx2/{node}/{FRAME}".encode("ascii")


def is_frame(name: str) -> bool:
    """Whether ``name`` is a node's frame topic."""
    return name.endswith("/" + FRAME) and parse_node(name) is not None


# Cached: readers of recordings ask once a message, of the same few topics. Reading
# 200,000 rows 1.2x and 1.3x faster, CSV 1.1x and 1.2x, Parquet, .mat and a ROS 2 bag
# within the runs' noise (0.9x to 1.1x): bench/exportformats.py --before, 2 runs of 2
# and 3 rounds. Bounded, for a foreign file of many topics.
@functools.lru_cache(maxsize=4096)
def parse_node(name: str) -> tuple[int, str] | None:
    """``(address, last part)`` of any topic under a node's ``gx2/<address>/``."""
    parts = name.split("/")
    if len(parts) == 3 and parts[0] == "gx2" and parts[1].isdecimal() and parts[2]:
        return int(parts[1]), parts[2]
    return None


@functools.lru_cache(maxsize=4096)
def parse(name: str) -> tuple[int, str] | None:
    """``(address, record)`` of a node's record topic, None for any other (a node's
    frame topic included: it carries no record)."""
    found = parse_node(name)
    return None if found is None or found[1] == FRAME else found


STATION_NAME = r"^[A-Za-z0-9][A-Za-z0-9_-]{0,31}$"
"""A base station's name: in recording channels (``serial/<name>``), status and metric
labels as it is, so it is kept to what each of them takes."""


def default_station_name(index: int) -> str:
    """The name of the station at ``index`` (from 0) that was given none."""
    return f"station{index + 1}"
