"""Command-line helpers every console script shares: one-line usage errors (exit 2),
argparse types for the values of :mod:`gateway.common.values`, and ``fail``; every
program's ``--version``, ``--print-completion`` and ``--print-man``."""

from __future__ import annotations

import argparse
import difflib
import re
import sys
from collections.abc import Callable
from typing import Any, NoReturn

from .completion import add_options as add_completion_options
from .endpoints import check_endpoint
from .protocol import Exit
from .values import NODE, POLLABLE_RECORD, STREAMABLE_RECORD, Kind
from .version import installed


class VersionAction(argparse.Action):
    """``--version``: argparse's, with the version looked up only when asked for."""

    def __init__(self, option_strings: list[str], dest: str = argparse.SUPPRESS,
                 default: str = argparse.SUPPRESS) -> None:
        super().__init__(option_strings, dest, nargs=0, default=default,
                         help="show the program's version and exit")

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> NoReturn:
        print(f"{parser.prog} {installed()}")  # (on stdout, as argparse's own)
        parser.exit()


class ArgumentParser(argparse.ArgumentParser):
    """argparse, but a usage error is one line (and exit status 2), a mistyped choice
    gets a suggestion, and every program has ``--version`` and prints its shell
    completion and man page (:mod:`gateway.common.completion`)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if self.prog.count(" ") == 0:  # the program itself, not a subcommand's parser
            self.add_argument("--version", action=VersionAction)
            add_completion_options(self)

    def error(self, message: str) -> NoReturn:
        self.exit(Exit.USAGE, f"{self.prog}: {message}{suggestion(message)} "
                              f"(see {self.prog} --help)\n")


def suggestion(message: str) -> str:
    """``; did you mean 'status'?`` for argparse's "invalid choice" message."""
    found = re.search(r"invalid choice: '([^']*)' \(choose from (.*)\)", message)
    if found is None:
        return ""
    close = difflib.get_close_matches(found.group(1), re.findall(r"'([^']*)'",
                                                                  found.group(2)), n=1)
    return f"; did you mean {close[0]!r}?" if close else ""


def argtype(kind: Kind) -> Callable[[str], Any]:
    """An argparse type reading ``kind`` from its text."""
    def parse(text: str) -> Any:
        try:
            return kind.from_text(text)
        except ValueError as error:
            raise argparse.ArgumentTypeError(str(error)) from None
    parse.__name__ = kind.name  # what argparse calls it in its own messages
    parse.kind = kind  # type: ignore[attr-defined]  # what its shell completion offers
    return parse


node_address = argtype(NODE)
streamable_record = argtype(STREAMABLE_RECORD)
pollable_record = argtype(POLLABLE_RECORD)


def node_list(text: str) -> list[int]:
    """``76,77,95`` -> [76, 77, 95], each checked, no repeats."""
    nodes = [node_address(part.strip()) for part in text.split(",") if part.strip()]
    if not nodes:
        raise argparse.ArgumentTypeError("no node addresses given")
    if len(set(nodes)) != len(nodes):
        raise argparse.ArgumentTypeError(f"a node appears twice in {text!r}")
    return nodes


def probability(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"{value} is not a probability (0..1)")
    return value


def endpoint(text: str) -> str:
    try:
        return check_endpoint(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def bounded(kind: type[int] | type[float], low: float, high: float) -> Callable[[str], Any]:
    """An argparse type: a number of ``kind`` within low..high."""
    def parse(text: str) -> int | float:
        try:
            value = kind(text)
        except ValueError:
            what = "an integer" if kind is int else "a number"
            raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"{value} is out of range {low}..{high}")
        return value
    return parse


def fail(prog: str, message: str, status: int) -> NoReturn:
    print(f"{prog}: {message}", file=sys.stderr)
    raise SystemExit(status)
