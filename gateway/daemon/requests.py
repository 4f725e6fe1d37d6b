"""Control requests as the gateway validates them: one strict pydantic model per row of
the op table (:mod:`gateway.common.ops`), generated from it, and the parser that turns
a msgpack message into one of them or a :class:`RequestError` naming the bad field.

The wire format itself (shapes, limits, error kinds) is :mod:`gateway.common.protocol`.
"""

from __future__ import annotations

import operator
from functools import reduce
from typing import Annotated, Any, Literal

import msgpack
from pydantic import AfterValidator, Field, TypeAdapter, ValidationError, create_model

from gateway.common.ops import OPS, Op, Param
from gateway.common.protocol import CANCEL, MAX_REQUEST_BYTES
from gateway.common.strict import Strict, describe

RequestId = Annotated[str, Field(min_length=1, max_length=64)] | int
MAX_TIMEOUT = 90_000.0
"""A day, and a bias capture's longest sampling time on top (gx2ctl allows a day)."""
REPLY_MARGIN = (0.1, 0.1, 1.0)
"""A request with a timeout is answered this much before it runs out, to cross the
network in time: a tenth of it, at least 0.1 s and at most 1 s."""


def answer_within(timeout: float) -> float:
    """Seconds from a request's arrival within which it must be answered."""
    share, least, most = REPLY_MARGIN
    return max(timeout / 2, timeout - min(most, max(least, share * timeout)))


class RequestBase(Strict):
    id: RequestId
    timeout: Annotated[float, Field(gt=0, le=MAX_TIMEOUT)] | None = None
    """Seconds the client waits for the answer; the gateway answers before then."""


def _annotation(param: Param) -> Any:
    value = Annotated[param.kind.type, AfterValidator(param.kind.check)]
    if param.many:
        return Annotated[list[value], Field(min_length=1, max_length=param.many)]  # type: ignore[valid-type]
    if param.default is None:
        return value | None
    return value


def _model(op: Op) -> type[RequestBase]:
    fields: dict[str, Any] = {"op": (Literal[op.name], ...)}
    for param in op.params:
        fields[param.name] = (_annotation(param), ... if param.required else param.default)
    name = "".join(part.title() for part in op.name.split("_")) + "Request"
    return create_model(name, __base__=RequestBase, **fields)  # type: ignore[call-overload,no-any-return]


class CancelRequest(RequestBase):
    """Cancel the request ``request`` (an id) that the same client sent earlier."""

    op: Literal["cancel"]
    request: RequestId


MODELS: dict[str, type[RequestBase]] = {op.name: _model(op) for op in OPS}
"""One per row of the op table: what :class:`~.operations.Operations` runs."""
ACCEPTED: dict[str, type[RequestBase]] = {**MODELS, CANCEL: CancelRequest}
"""Every request the control endpoint takes: the ops, and ``cancel``, which it answers
itself (it concerns a client's own earlier request)."""
_REQUEST: TypeAdapter[RequestBase] = TypeAdapter(
    Annotated[reduce(operator.or_, ACCEPTED.values()), Field(discriminator="op")])


class RequestError(Exception):
    """A request that cannot be run; ``request_id`` is echoed if it could be read."""

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


def parse_request(payload: bytes) -> RequestBase:
    """Validate one control message; raises RequestError naming the bad field."""
    data = unpack(payload)
    request_id = data.get("id") if isinstance(data.get("id"), (str, int)) else None
    if data.get("op") not in ACCEPTED:
        raise RequestError(f"op: must be one of {', '.join(ACCEPTED)}", request_id)
    try:
        return _REQUEST.validate_python(data)
    except ValidationError as error:
        raise RequestError(describe(error, skip=1, noun="field"), request_id) from None
