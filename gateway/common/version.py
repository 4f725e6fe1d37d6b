"""The installed version, as ``--version`` and the status report give it."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

try:
    VERSION = version("gx2-gateway")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    VERSION = "unknown"
