"""Why a control request failed: each exception carries the protocol's error kind, so
the control server answers any of them the same way; and why the gateway cannot start."""

from __future__ import annotations

from gateway.common.protocol import ErrorKind


class OpError(Exception):
    kind = ErrorKind.INTERNAL


class Invalid(OpError):
    """The request cannot be run as asked (gx2ctl exit 2)."""

    kind = ErrorKind.INVALID


class Refused(OpError):
    """The gateway's policy forbids the request (gx2ctl exit 1)."""

    kind = ErrorKind.REFUSED


class NodeError(OpError):
    """A node did not answer, NACKed, or was not confirmed; the message says which."""

    kind = ErrorKind.NODE


class GoesOn(OpError):
    """The request was cancelled (by its client, or its deadline) past the point where
    what it started can be stopped: that goes on, and the gateway logs its result; the
    message says what goes on and where its result will be seen."""

    kind = ErrorKind.NODE


class LinkDown(OpError):
    """The base station is not connected."""

    kind = ErrorKind.LINK


class StartupError(Exception):
    """The gateway cannot start (an endpoint cannot be bound): one line, exit 1."""
