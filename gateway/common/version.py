"""The installed version, as ``--version`` and the status report give it: looked up when
first asked (importing importlib.metadata is 20 to 50 ms of every program's start, and
most runs of gx2ctl never ask)."""

from __future__ import annotations

from functools import cache


@cache
def installed() -> str:
    """The installed distribution's version ("unknown" from a source tree)."""
    from importlib.metadata import PackageNotFoundError, version
    try:
        return version("gx2-gateway")
    except PackageNotFoundError:  # pragma: no cover - running from a source tree
        return "unknown"
