"""The control protocol as both ends see it: message shapes, size limits, error kinds
and the exit status each gives gx2ctl.

A request is one msgpack map ``{"id", "op", ...fields}`` (the op table in
:mod:`gateway.common.ops` names the fields), sent by a DEALER as ``[b"", payload]``
like REQ, at most :data:`MAX_REQUEST_BYTES`. An optional ``timeout`` (seconds) is how
long the client will wait: the gateway answers before it runs out. Every request gets
exactly one reply:

    {"id": ..., "ok": true,  "result": {...}}
    {"id": ..., "ok": false, "error": {"kind": "node", "message": "..."}}

A client that times out may send the same request again with the same id: the gateway
runs each (client, id) once and answers a repeat with the first run's reply.

A client that gives up on a request it sent (gx2ctl on Ctrl-C) says so with
``{"id": ..., "op": "cancel", "request": <that request's id>}``: the gateway stops the
request where it safely can, answers it with an error of kind ``cancelled``, and
answers the cancel with ``{"request", "cancelled", "message"}``: whether it stopped,
and what stays or goes on (a bias capture the node has begun cannot be stopped).
"""

from __future__ import annotations

from enum import IntEnum, StrEnum
from typing import Any

import msgpack

MAX_REQUEST_BYTES = 4096
"""Largest request the gateway accepts (ZMQ_MAXMSGSIZE on its socket as well)."""
MAX_REPLY_BYTES = 1 << 20
"""Largest reply (or published message) a client accepts."""
MAX_PING_NODES = 64
"""The most nodes one ping may name."""


class HealthLevel(StrEnum):
    """A node's ``health`` in status (and the heartbeat): how it is doing."""

    OK = "OK"
    WARN = "WARN"
    """It delivers, worse than it should."""
    ERROR = "ERROR"
    """It delivers nothing."""


class ErrorKind(StrEnum):
    INVALID = "invalid"
    """The request is malformed or names something that does not exist."""
    REFUSED = "refused"
    """The gateway's policy forbids it (an EEPROM write not allowed, a replay)."""
    NODE = "node"
    """The node did not answer, NACKed, or did not confirm."""
    LINK = "link"
    """The base station is not connected."""
    INTERNAL = "internal"
    """A bug, logged by the gateway."""
    CANCELLED = "cancelled"
    """Its client cancelled it (op ``cancel``); the message says what stays."""


class Exit(IntEnum):
    """gx2ctl's exit status."""

    OK = 0
    NODE_FAILED = 1
    USAGE = 2
    NO_ANSWER = 3


EXIT_FOR_KIND = {ErrorKind.INVALID: Exit.USAGE, ErrorKind.REFUSED: Exit.NODE_FAILED,
                 ErrorKind.NODE: Exit.NODE_FAILED, ErrorKind.LINK: Exit.NODE_FAILED,
                 ErrorKind.INTERNAL: Exit.NODE_FAILED, ErrorKind.CANCELLED: Exit.NODE_FAILED}
CANCEL = "cancel"
"""The op that cancels an earlier request of the same client (not in the op table: it
is about a request, not a node, and no gx2ctl command of its own)."""


def exit_for(kind: object) -> Exit:
    """The exit status for an error kind; 1 for a kind this version does not know."""
    try:
        return EXIT_FOR_KIND[ErrorKind(kind)]
    except ValueError:
        return Exit.NODE_FAILED


def request(request_id: object, op: str, fields: dict[str, Any]) -> bytes:
    return msgpack.packb({"id": request_id, "op": op, **fields})


def ok(request_id: object, result: dict[str, Any]) -> bytes:
    return msgpack.packb({"id": request_id, "ok": True, "result": result})


def error(request_id: object, kind: ErrorKind, message: str) -> bytes:
    return msgpack.packb({"id": request_id, "ok": False,
                          "error": {"kind": str(kind), "message": message}})
