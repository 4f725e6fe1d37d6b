"""``gx2ctl``: the ops tool that talks to a running gx2-gateway (CONTRACT section 5).

Requests go to the gateway's control ROUTER over a DEALER (protocol in
:mod:`gateway.protocol`); ``tail`` subscribes to the publish endpoint. Exit status:
0 success, 1 a node failed, 2 bad usage or input, 3 the gateway did not answer in time.
Every error is one line on stderr; nothing here may hang on a dead gateway.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import time
from dataclasses import dataclass
from types import FrameType
from typing import Any

import zmq

from aspp.commands import divider_for_rate
from aspp.errors import AsppError

from . import curve
from .cli_args import (
    ArgumentParser,
    bounded,
    endpoint,
    fail,
    node_address,
    pollable_record,
    streamable_record,
)
from .ctl_client import (
    MAX_REPLY_BYTES,
    NO_ANSWER,
    NODE_FAILED,
    OK,
    USAGE,
    Client,
    ClientKeys,
    CtlError,
    connectable,
)
from .ctl_output import (
    Malformed,
    answered,
    json_line,
    ping_lines,
    result_lines,
    status_lines,
    tail_line,
)

PROG = "gx2ctl"
DEFAULT_CONTROL = "tcp://127.0.0.1:5556"
"""The config's control.endpoint default (not imported: gateway.config loads pydantic,
which would slow every run; a test checks that the two agree)."""
DEFAULT_TIMEOUT = 5.0
CLIENT_KEY_ENV, SERVER_KEY_ENV = "GX2_CLIENT_KEY", "GX2_SERVER_KEY"
MAX_PING_NODES = 64
"""The most nodes one ping request may name (gateway.protocol.PingRequest)."""

# --- argument types -------------------------------------------------------------------

def word(text: str) -> int:
    """An EEPROM address or value: decimal or 0x hex, 0..65535."""
    body = text.strip()
    try:
        if not body.isascii():
            raise ValueError
        if body[:2].lower() == "0x" and body[2:].isalnum():
            value = int(body[2:], 16)
        elif body.isdecimal():
            value = int(body, 10)
        else:
            raise ValueError
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a decimal or 0x hexadecimal number") from None
    if not 0 <= value <= 0xFFFF:
        raise argparse.ArgumentTypeError(f"{text} is out of range 0..65535 (0xFFFF)")
    return value


def rate_hz(text: str) -> float:
    """A data rate whose divider 51200/HZ is within 170..51200."""
    try:
        hz = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of Hz") from None
    try:
        divider_for_rate(hz)
    except AsppError as error:
        raise argparse.ArgumentTypeError(str(error)) from None
    return hz


def build_parser() -> ArgumentParser:
    parser = ArgumentParser(
        prog=PROG, description="Control a running gx2-gateway. Exit status: 0 success, "
        "1 a node failed, 2 bad usage or input, 3 the gateway did not answer in time.")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--config", metavar="FILE",
                       help="the gateway's nodes.yaml: use its control and publish endpoints")
    where.add_argument("--control", type=endpoint, metavar="ENDPOINT",
                       help=f"the gateway's control endpoint (default {DEFAULT_CONTROL})")
    parser.add_argument("--timeout", type=bounded(float, 0.01, 86400), default=DEFAULT_TIMEOUT,
                        metavar="SECONDS",
                        help=f"give up (exit 3) after this long (default {DEFAULT_TIMEOUT:g})")
    parser.add_argument("--client-key", metavar="FILE",
                        help="CURVE: this client's .key_secret file (default: "
                        f"${CLIENT_KEY_ENV})")
    parser.add_argument("--server-key", metavar="KEY",
                        help="CURVE: the gateway's public key, as Z85 text or a .key file "
                        f"(default: ${SERVER_KEY_ENV}, or beside the server key --config "
                        "names)")
    parser.add_argument("--json", action="store_true",
                        help="print each reply as one strict JSON object on one line "
                        "(NaN as null); poll and tail always print JSON")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    add = commands.add_parser
    add("ping", help="wireless ping; exit 0 if every node answered").add_argument(
        "nodes", nargs="+", type=node_address, metavar="NODE")
    add("status", help="the gateway, the link and every node")
    start = add("start", help="continuous mode with RECORD (a name or 0xNN)")
    start.add_argument("node", type=node_address, metavar="NODE")
    start.add_argument("record", type=streamable_record, metavar="RECORD")
    add("stop", help="stop continuous mode, until the stream is silent").add_argument(
        "node", type=node_address, metavar="NODE")
    poll = add("poll", help="one polled record, printed as one JSON line")
    poll.add_argument("node", type=node_address, metavar="NODE")
    poll.add_argument("record", type=pollable_record, metavar="RECORD")
    eeprom = add("eeprom", help="read or write an EEPROM word (decimal or 0x hex)")
    actions = eeprom.add_subparsers(dest="action", required=True, metavar="ACTION")
    read = actions.add_parser("read", help="read the word at ADDR")
    write = actions.add_parser("write", help="write VALUE at ADDR, read back to verify")
    for sub in (read, write):
        sub.add_argument("node", type=node_address, metavar="NODE")
        sub.add_argument("address", type=word, metavar="ADDR")
    write.add_argument("value", type=word, metavar="VALUE")
    rate = add("rate", help="data rate via the divider at EEPROM 0xFCA2 (51200/HZ)")
    rate.add_argument("node", type=node_address, metavar="NODE")
    rate.add_argument("hz", type=rate_hz, metavar="HZ")
    add("info", help="firmware version and identifier strings").add_argument(
        "node", type=node_address, metavar="NODE")
    add("tail", help="print published records as JSON lines until interrupted",
        description="Print each published record as one JSON line until SIGINT/SIGTERM. "
        "With NODEs, only their records; without, every node's records (the gateway's own "
        "gx2/gateway/... messages are not printed). The publish endpoint comes from "
        "--config, or else from the gateway's status reply.").add_argument(
        "nodes", nargs="*", type=node_address, metavar="NODE")
    add("keygen", help="write a new CURVE key pair: PREFIX.key (public, 0644) and "
        "PREFIX.key_secret (0600); never overwrites").add_argument("prefix", metavar="PREFIX")
    return parser


# --- endpoints ------------------------------------------------------------------------

@dataclass(frozen=True)
class Endpoints:
    control: str
    publish: str | None
    """Known only from --config; otherwise asked of the gateway when needed."""
    keys: ClientKeys | None = None
    publish_secured: bool | None = None
    """Whether the publish socket uses CURVE too (None: ask the gateway's status)."""


def endpoints(args: argparse.Namespace) -> Endpoints:
    """From --config (loaded here: its errors exit 2), --control, or the default; CURVE
    keys from the options, the environment, or the config."""
    client_key = args.client_key or os.environ.get(CLIENT_KEY_ENV)
    server_key = args.server_key or os.environ.get(SERVER_KEY_ENV)
    if args.config is None:
        keys = client_keys(client_key, server_key, None)
        return Endpoints(args.control or DEFAULT_CONTROL, None, keys)
    from .config import ConfigError, load_config  # pydantic: only when a config is used
    try:
        config = load_config(args.config)
    except ConfigError as error:
        raise CtlError(str(error), USAGE) from None
    secured = config.curve is not None
    if secured and server_key is None:
        sibling = curve.public_sibling(config.curve.server_key)
        server_key = str(sibling) if sibling.exists() else config.curve.server_key
    keys = client_keys(client_key, server_key, args.config if secured else None)
    return Endpoints(config.control.endpoint, config.publish.endpoint, keys,
                     secured and config.curve.publish)


def client_keys(client_key: str | None, server_key: str | None,
                secured_by: str | None) -> ClientKeys | None:
    """The CURVE keys to connect with, or None for a plain connection."""
    if client_key is None and server_key is None and secured_by is None:
        return None
    if client_key is None:
        why = f"{secured_by} configures curve" if secured_by else "--server-key is given"
        raise CtlError(f"{why}: give this client's key pair with --client-key FILE or "
                       f"${CLIENT_KEY_ENV} (make one with gx2ctl keygen)", USAGE)
    if server_key is None:
        raise CtlError(f"--client-key is given: give the gateway's public key with "
                       f"--server-key KEY or ${SERVER_KEY_ENV}", USAGE)
    try:
        pair = curve.load_key_pair(client_key)
        server = (curve.load_key_pair(server_key).public
                  if server_key.endswith(curve.SECRET_SUFFIX) else curve.public_key(server_key))
    except curve.CurveError as error:
        raise CtlError(str(error), USAGE) from None
    return ClientKeys(pair, server)


# --- commands -------------------------------------------------------------------------

def request_of(args: argparse.Namespace) -> tuple[str, dict[str, Any]]:
    """The op and fields of the request a (parsed) command line makes."""
    command = args.command
    if command == "ping":
        nodes = list(dict.fromkeys(args.nodes))
        if len(nodes) > MAX_PING_NODES:
            raise CtlError(f"ping takes at most {MAX_PING_NODES} nodes, not {len(nodes)}",
                           USAGE)
        return "ping", {"nodes": nodes}
    if command == "status":
        return "status", {}
    if command in ("start", "poll"):
        return command, {"node": args.node, "record": args.record}
    if command in ("stop", "info"):
        return command, {"node": args.node}
    if command == "rate":
        return "rate", {"node": args.node, "hz": float(args.hz)}
    if args.action == "read":
        return "eeprom_read", {"node": args.node, "address": args.address}
    return "eeprom_write", {"node": args.node, "address": args.address, "value": args.value}


def run_request(args: argparse.Namespace, where: Endpoints) -> int:
    op, fields = request_of(args)
    with Client(where.control, args.timeout, where.keys) as client:
        result = client.call(op, **fields)
    if op == "poll" or args.json:
        emit([json_line(result)])
    elif op == "status":
        emit(status_lines(result, time.time()))
    elif op == "ping":
        emit(ping_lines(fields["nodes"], result))
    else:
        emit(result_lines(op, result))
    if op == "ping":
        replies = answered(result)
        silent = [str(node) for node in fields["nodes"] if not replies.get(node)]
        if silent:
            raise CtlError(f"{len(silent)} of {len(fields['nodes'])} nodes did not answer: "
                           f"{', '.join(silent)}", NODE_FAILED)
    return OK


def publish_endpoint(status: dict[str, Any]) -> str:
    """The publish endpoint a status reply names."""
    gateway = status.get("gateway")
    found = gateway.get("publish_endpoint") if isinstance(gateway, dict) else None
    if not isinstance(found, str) or "://" not in found:
        raise CtlError("the gateway's status reply names no gateway.publish_endpoint",
                       NODE_FAILED)
    return found


class Stop:
    """Set by SIGINT/SIGTERM: tail finishes its batch and exits 0, quietly."""

    requested = False

    def __init__(self) -> None:
        for signum in (signal.SIGINT, signal.SIGTERM):
            signal.signal(signum, self._request)

    def _request(self, signum: int, frame: FrameType | None) -> None:
        self.requested = True


def run_tail(nodes: list[int], where: Endpoints, timeout: float) -> int:
    """Print published records until a signal; malformed messages are warned about.
    The gateway's heartbeat (gx2/gateway/status, not printed) proves it is alive even
    when no node streams: nothing at all for ``timeout`` seconds exits 3."""
    found, secured = where.publish, where.publish_secured
    if found is None:
        with Client(where.control, timeout, where.keys) as client:
            status = client.call("status")
        found = publish_endpoint(status)
        secured = bool(status.get("gateway", {}).get("publish_curve"))
    address = connectable(found, where.control)
    stop = Stop()
    context = zmq.Context()
    sub = context.socket(zmq.SUB)
    try:
        sub.setsockopt(zmq.LINGER, 0)
        sub.setsockopt(zmq.MAXMSGSIZE, MAX_REPLY_BYTES)  # records are far smaller
        if secured and where.keys is not None:
            curve.connect_as(sub, where.keys.client, where.keys.server_public)
        try:
            sub.connect(address)
        except zmq.ZMQError as error:
            raise CtlError(f"cannot use publish endpoint {address}: {error}", USAGE) from None
        unique = list(dict.fromkeys(nodes))
        prefixes = [f"gx2/{node}/" for node in unique] or ["gx2/"]
        for prefix in [*prefixes, "gx2/gateway/status"]:
            sub.setsockopt(zmq.SUBSCRIBE, prefix.encode())
        heard = time.monotonic()
        while not stop.requested:
            if sub.poll(100, zmq.POLLIN):
                _print_batch(sub, stop)
                heard = time.monotonic()
            elif time.monotonic() - heard > timeout:
                raise CtlError(f"the gateway at {address} published nothing for "
                               f"{timeout:g} s (not even its heartbeat)", NO_ANSWER)
    finally:
        sub.close(linger=0)
        context.term()
    return OK


def _print_batch(sub: zmq.Socket, stop: Stop) -> None:
    """Every message already queued, printed, then one flush."""
    while not stop.requested:
        try:
            frames = sub.recv_multipart(zmq.NOBLOCK)
        except zmq.Again:
            break
        try:
            line = tail_line(frames, nodes_only=True)
        except Malformed as problem:
            sys.stdout.flush()
            print(f"{PROG}: skipped a message {problem}", file=sys.stderr, flush=True)
            continue
        if line is not None:
            print(line)
    sys.stdout.flush()


def emit(lines: list[str]) -> None:
    for line in lines:
        print(line)
    sys.stdout.flush()


def run_keygen(prefix: str) -> int:
    try:
        public, secret = curve.generate(prefix)
    except curve.CurveError as error:
        raise CtlError(str(error), NODE_FAILED) from None
    emit([f"public key  {public}  {curve.public_key(str(public)).decode()}",
          f"key pair    {secret}  (mode 0600: keep it private)"])
    return OK


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        if args.command == "keygen":
            return run_keygen(args.prefix)
        where = endpoints(args)
        if args.command == "tail":
            return run_tail(args.nodes, where, args.timeout)
        return run_request(args, where)
    except CtlError as error:
        fail(PROG, str(error), error.status)
    except KeyboardInterrupt:
        return OK if args.command == "tail" else 130
    except BrokenPipeError:  # a reader such as `head` has gone: not an error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return OK
    except Exception as error:  # a bug: still one line, never a traceback
        fail(PROG, f"internal error: {type(error).__name__}: {error}", NODE_FAILED)

