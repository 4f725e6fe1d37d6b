"""Argument helpers every console script shares: one-line usage errors, and parsers for
the values the tools take (node lists, probabilities, record names)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from typing import NoReturn

from aspp.errors import AsppError
from aspp.frame import MAX_NODE, MIN_NODE
from aspp.records import checked

USAGE_ERROR = 2


class ArgumentParser(argparse.ArgumentParser):
    """argparse, but a usage error is one line (and exit status 2)."""

    def error(self, message: str) -> NoReturn:
        self.exit(USAGE_ERROR, f"{self.prog}: {message} (see {self.prog} --help)\n")


def node_address(text: str) -> int:
    try:
        value = int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"node address {text!r} is not a number") from None
    if not MIN_NODE <= value <= MAX_NODE:
        raise argparse.ArgumentTypeError(
            f"node address {value} is out of range {MIN_NODE}..{MAX_NODE}")
    return value


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


def record_arg(streamable: bool = False, pollable: bool = False) -> Callable[[str], str]:
    """An argparse type: a record by name or ``0xNN`` (that can stream, or be polled),
    returned as its name."""
    def parse(text: str) -> str:
        try:
            return checked(text, streamable=streamable, pollable=pollable).name
        except AsppError as error:
            raise argparse.ArgumentTypeError(str(error)) from None
    return parse


streamable_record = record_arg(streamable=True)
pollable_record = record_arg(pollable=True)


def check_endpoint(value: str) -> str:
    """A ZeroMQ endpoint the gateway can bind or a client connect; ValueError if not."""
    scheme, sep, rest = value.partition("://")
    host, colon, port = rest.rpartition(":")
    if (not sep or scheme not in ("tcp", "ipc", "inproc") or not rest
            or (scheme == "tcp" and not (colon and host and (port.isdigit() or port == "*")))):
        raise ValueError(f"must be a ZeroMQ endpoint such as tcp://127.0.0.1:5556 or "
                         f"ipc:///run/gx2-gateway/control, not {value!r}")
    return value


def endpoint(text: str) -> str:
    try:
        return check_endpoint(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def bounded(kind: type[int] | type[float], low: float, high: float):
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
