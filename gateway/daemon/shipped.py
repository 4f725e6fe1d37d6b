"""``gx2-gateway --files``: where the files shipped with the gateway are.

The wheel carries what the deployment steps (docs/operating.md) install besides the
code: ``deploy/`` (the systemd unit, the udev rule, the alerting rules), ``config/`` (the
example configurations), ``README.md`` (the unit's ``Documentation=``) and ``docs/`` (the
documentation, readable offline), in one directory laid
out as the repository is. In the repository that directory, ``gateway/share/``, holds
symbolic links to them, so each file exists once; the build follows the links.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from importlib.resources import files
from pathlib import Path
from typing import Any

SHIPPED = ("README.md", "config", "deploy", "docs")
"""What the directory holds (for the build: the package data in pyproject.toml)."""


def shipped_directory() -> Path:
    """The directory in this installation (the repository's gateway/share/ in an
    editable one)."""
    return Path(str(files("gateway"))) / "share"


class PrintFiles(argparse.Action):
    """Print the directory and exit, as ``--version`` prints the version: the program's
    required options (``--config``) are not asked for."""

    def __init__(self, option_strings: Sequence[str], dest: str, **kwargs: Any) -> None:
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, **kwargs)

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        directory = shipped_directory()
        missing = [name for name in SHIPPED if not (directory / name).exists()]
        if missing:
            parser.exit(1, f"{parser.prog}: {directory} lacks {', '.join(missing)}: this "
                           "installation is incomplete (install the wheel again)\n")
        print(directory)
        parser.exit()
