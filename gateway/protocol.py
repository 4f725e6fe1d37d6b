"""The control protocol between gx2ctl (or any client) and the gateway.

Transport: ZeroMQ, the gateway's ROUTER socket; a client uses a DEALER and sends one
frame, or ``[b"", payload]`` as REQ does. The payload is a msgpack map with an ``op``
and an ``id`` chosen by the client; the gateway answers every request exactly once:

    {"id": ..., "ok": true,  "result": {...}}
    {"id": ..., "ok": false, "error": {"kind": "invalid", "message": "..."}}

A client that times out may send the same request again with the same ``id``: the
gateway runs each id once and answers a repeat with the first run's result, so a
retried EEPROM write is never applied twice.

Error kinds (and the gx2ctl exit status they give):
``invalid`` (2) the request is malformed; ``refused`` (1) the gateway's policy forbids
it; ``node`` (1) the node did not answer, NACKed or was not confirmed; ``link`` (1) the
base station is not connected; ``internal`` (1) a bug, logged by the gateway.
"""

from __future__ import annotations

from functools import partial
from typing import Annotated, Any, Literal

import msgpack
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, TypeAdapter, ValidationError

from aspp.frame import MAX_NODE, MIN_NODE
from aspp.records import checked

MAX_REQUEST_BYTES = 4096
"""Largest control request accepted (ZMQ_MAXMSGSIZE on the socket as well)."""
MAX_REPLY_BYTES = 1 << 20

Node = Annotated[int, Field(ge=MIN_NODE, le=MAX_NODE, strict=True)]
RequestId = Annotated[str, Field(min_length=1, max_length=64)] | Annotated[int, Field(strict=True)]


class _Request(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    id: RequestId


def _record(value: object, *, streamable: bool = False, pollable: bool = False) -> str:
    if isinstance(value, bool) or not isinstance(value, (str, int)):
        raise ValueError("must be a record name or command byte")
    return checked(value, streamable=streamable, pollable=pollable).name


StreamableRecord = Annotated[str, BeforeValidator(partial(_record, streamable=True))]
"""A record name or command byte that can stream; validated to its name."""
PollableRecord = Annotated[str, BeforeValidator(partial(_record, pollable=True))]
Word = Annotated[int, Field(ge=0, le=0xFFFF, strict=True)]
"""An EEPROM address or value: 16 bits."""


class PingRequest(_Request):
    op: Literal["ping"]
    nodes: Annotated[list[Node], Field(min_length=1, max_length=64)]


class StatusRequest(_Request):
    op: Literal["status"]


class StartRequest(_Request):
    op: Literal["start"]
    node: Node
    record: StreamableRecord


class StopRequest(_Request):
    op: Literal["stop"]
    node: Node


class PollRequest(_Request):
    op: Literal["poll"]
    node: Node
    record: PollableRecord


class EepromReadRequest(_Request):
    op: Literal["eeprom_read"]
    node: Node
    address: Word


class EepromWriteRequest(_Request):
    op: Literal["eeprom_write"]
    node: Node
    address: Word
    value: Word


class RateRequest(_Request):
    op: Literal["rate"]
    node: Node
    hz: Annotated[float, Field(gt=0, le=310)]


class InfoRequest(_Request):
    op: Literal["info"]
    node: Node


Request = Annotated[
    PingRequest | StatusRequest | StartRequest | StopRequest | PollRequest
    | EepromReadRequest | EepromWriteRequest | RateRequest | InfoRequest,
    Field(discriminator="op")]
_REQUEST = TypeAdapter(Request)
OPS = ("ping", "status", "start", "stop", "poll", "eeprom_read", "eeprom_write", "rate",
       "info")


class RequestError(Exception):
    """A request that cannot be run; ``id`` is echoed if it could be read."""

    def __init__(self, message: str, request_id: object = None) -> None:
        super().__init__(message)
        self.request_id = request_id


def unpack(payload: bytes) -> dict[str, Any]:
    """msgpack -> dict, with size limits; raises RequestError."""
    if len(payload) > MAX_REQUEST_BYTES:
        raise RequestError(f"request of {len(payload)} bytes exceeds {MAX_REQUEST_BYTES}")
    try:
        data = msgpack.unpackb(payload, raw=False, strict_map_key=True,
                               max_str_len=MAX_REQUEST_BYTES, max_bin_len=MAX_REQUEST_BYTES,
                               max_array_len=256, max_map_len=64, max_ext_len=0)
    except Exception as error:  # msgpack raises several unrelated types
        raise RequestError(f"not a msgpack message: {type(error).__name__}") from None
    if not isinstance(data, dict):
        raise RequestError(f"a request is a map, not {type(data).__name__}")
    return data


def parse_request(payload: bytes) -> Request:
    """Validate one control message; raises RequestError naming the bad field."""
    data = unpack(payload)
    request_id = data.get("id") if isinstance(data.get("id"), (str, int)) else None
    if data.get("op") not in OPS:
        raise RequestError(f"op: must be one of {', '.join(OPS)}", request_id)
    try:
        return _REQUEST.validate_python(data)
    except ValidationError as error:
        problem = error.errors(include_url=False)[0]
        where = ".".join(str(part) for part in problem["loc"][1:]) or "request"
        message = problem["msg"].removeprefix("Value error, ")
        if problem["type"] == "extra_forbidden":
            message = "unknown field"
        raise RequestError(f"{where}: {message}", request_id) from None


def ok(request_id: object, result: dict[str, Any]) -> bytes:
    return msgpack.packb({"id": request_id, "ok": True, "result": result})


def error(request_id: object, kind: str, message: str) -> bytes:
    return msgpack.packb({"id": request_id, "ok": False,
                          "error": {"kind": kind, "message": message}})
