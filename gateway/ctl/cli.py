"""``gx2ctl``: the ops tool that talks to a running gx2-gateway.

Every control op of the table in :mod:`gateway.common.ops` is a command here, its
arguments read by the same checks the gateway applies; ``tail`` and ``keygen`` run
locally. Exit status: 0 success, 1 a node failed, 2 bad usage or input, 3 the gateway
did not answer in time. Every error is one line on stderr; nothing here may hang on a
dead gateway.
"""

from __future__ import annotations

import argparse
import os
import sys
from typing import Any

from gateway.common import curve
from gateway.common.args import ArgumentParser, argtype, bounded, endpoint, fail, node_address
from gateway.common.endpoints import DEFAULT_CONTROL
from gateway.common.ops import OPS, Op
from gateway.common.protocol import Exit

from . import PROG
from .client import Client, CtlError
from .offline import add_commands as add_offline_commands
from .output import json_line, show
from .recordings import add_commands as add_recording_commands
from .site import CLIENT_KEY_ENV, SERVER_KEY_ENV, gateways
from .where import Endpoints, Gateway

DEFAULT_TIMEOUT = 5.0


def add_gateway_options(parser: argparse.ArgumentParser, suppress: bool = False) -> None:
    """Where the gateway is and how to talk to it. Given before the command (their
    defaults there) or after it (``suppress``: left out unless given, so that what came
    before the command stands): ``gx2ctl status --json`` is what people type."""
    def default(value: object) -> object:
        return argparse.SUPPRESS if suppress else value

    # after the command, gateways go to their own lists (AFTER), joined to those given
    # before it: --config a.yaml status --config b.yaml is both gateways, not b alone
    after = "_after" if suppress else ""
    parser.add_argument("--config", metavar="FILE", action="append", default=default(None),
                        dest=f"config{after}",
                        help="the gateway's nodes.yaml: use its control and publish "
                        "endpoints; or a file listing gateways (gateways:). Given more "
                        "than once, or with --control: several gateways (status, top, "
                        "tail, record)")
    parser.add_argument("--control", type=endpoint, metavar="ENDPOINT", action="append",
                        default=default(None), dest=f"control{after}",
                        help=f"the gateway's control endpoint (default {DEFAULT_CONTROL}); "
                        "more than once, or with --config: several gateways")
    parser.add_argument("--timeout", type=bounded(float, 0.01, 86400),
                        default=default(DEFAULT_TIMEOUT), metavar="SECONDS",
                        help=f"give up (exit 3) after this long (default {DEFAULT_TIMEOUT:g})")
    parser.add_argument("--client-key", metavar="FILE", default=default(None),
                        help="CURVE: this client's .key_secret file (default: "
                        f"${CLIENT_KEY_ENV})")
    parser.add_argument("--server-key", metavar="KEY", default=default(None),
                        help="CURVE: the gateway's public key, as Z85 text or a .key file "
                        f"(default: ${SERVER_KEY_ENV}, or beside the server key --config "
                        "names)")
    parser.add_argument("--json", action="store_true", default=default(False),
                        help="print each reply as one strict JSON object on one line "
                        "(NaN as null); poll and tail always print JSON")


def build_parser() -> ArgumentParser:
    parser = ArgumentParser(
        prog=PROG, description="Control a running gx2-gateway. Exit status: 0 success, "
        "1 a node failed, 2 bad usage or input, 3 the gateway did not answer in time.")
    add_gateway_options(parser)
    anywhere = argparse.ArgumentParser(add_help=False)
    add_gateway_options(anywhere, suppress=True)
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    groups: dict[str, Any] = {}
    for op in OPS:
        add_op(commands, groups, op, anywhere)
    commands.add_parser(
        "tail", parents=[anywhere], help="print published records as JSON lines until interrupted",
        description="Print each published record as one JSON line until SIGINT/SIGTERM. "
        "With NODEs, only their records; without, every node's records (the gateway's own "
        "gx2/gateway/... messages are not printed). The publish endpoint comes from "
        "--config, or else from the gateway's status reply.").add_argument(
        "nodes", nargs="*", type=node_address, metavar="NODE")
    commands.add_parser(
        "top", parents=[anywhere],
        help="a live table of every node, refreshed in place until q or Ctrl-C",
        description="A live table of the gateway's link and every node (state, record, "
        "rate against the expected rate, radio loss over the health window, losses in the "
        "gateway, reboots, LQI/RSSI, clock drift, last seen, health), drawn from the "
        "gateway's heartbeat and refreshed in place until q, Ctrl-C or SIGTERM. Columns "
        "are dropped or cut to fit the terminal. Not a terminal: one plain frame per "
        "heartbeat; with --json, each heartbeat as a JSON line. NO_COLOR turns colour "
        "off.").add_argument("nodes", nargs="*", type=node_address, metavar="NODE",
                             help="only these nodes (default: all)")
    recorder = commands.add_parser(
        "record", parents=[anywhere], help="record the published stream to an MCAP file",
        description="Record every published record (of the NODEs given, or of all), the "
        "gateway's status and every mark to FILE, an MCAP file with one JSON channel per "
        "topic, until SIGINT/SIGTERM or --seconds (counted from the first message). Shows "
        "records, rate and gaps on stderr. Exit 0 when the file was written; 1 if nothing "
        "came within --timeout and three heartbeats (no file is left) or the disk failed "
        "(the file keeps what was written up to the last second, or is removed if that is "
        "nothing); 2 if FILE exists, cannot be made or is not named .mcap; 3 if the "
        "gateway falls silent (the file keeps what came).")
    recorder.add_argument("file", metavar="FILE.mcap", help="a new file")
    recorder.add_argument("nodes", nargs="*", type=node_address, metavar="NODE")
    recorder.add_argument("--seconds", type=bounded(float, 0.1, 1e7), metavar="S",
                          help="stop after S seconds (default: until interrupted)")
    add_offline_commands(commands)
    add_recording_commands(commands)
    commands.add_parser(
        "keygen", help="write a new CURVE key pair: PREFIX.key (public, 0644) and "
        "PREFIX.key_secret (0600); never overwrites").add_argument("prefix", metavar="PREFIX")
    return parser


def add_op(commands: Any, groups: dict[str, Any], op: Op,
           anywhere: argparse.ArgumentParser) -> None:
    """The op's command (``eeprom read``: a group ``eeprom`` with an action ``read``),
    taking the gateway's options after it too (``anywhere``)."""
    *group, word = op.command
    parent = commands
    if group:
        if group[0] not in groups:
            holder = commands.add_parser(group[0], help=f"{group[0]} commands")
            groups[group[0]] = holder.add_subparsers(dest="action", required=True,
                                                     metavar="ACTION")
        parent = groups[group[0]]
    sub = parent.add_parser(word, parents=[anywhere], help=op.help,
                            description=op.description or op.help)
    sub.set_defaults(op=op)
    for param in op.params:
        metavar = param.metavar or param.name.upper()
        listed = param.help
        if param.kind.choices:
            listed += f"; one of: {', '.join(param.kind.choices)}"
        if param.many and param.option:  # (--field K=V --field K=V)
            sub.add_argument(param.flag, dest=param.name, action="append", default=[],
                             type=argtype(param.kind), metavar=metavar, help=listed)
        elif param.many:
            sub.add_argument(param.name, nargs="+" if param.required else "*",
                             type=argtype(param.kind), metavar=metavar, help=listed)
        elif param.required:
            sub.add_argument(param.name, type=argtype(param.kind), metavar=metavar,
                             help=listed)
        elif param.positional:
            sub.add_argument(param.name, nargs="?", type=argtype(param.kind),
                             default=param.default, metavar=metavar, help=listed)
        else:
            sub.add_argument(param.flag, dest=param.name, type=argtype(param.kind),
                             default=param.default, metavar=metavar.split("_")[-1],
                             help=f"{listed} (default {param.default})")
    for switch in op.switches:
        sub.add_argument(switch.flag, dest=switch.name, action="store_true", help=switch.help)


# --- commands ---------------------------------------------------------------------------

def fields_of(op: Op, args: argparse.Namespace) -> dict[str, Any]:
    """The request's fields from a parsed command line (lists without repeats, and no
    longer than the gateway takes; an optional list left out when empty)."""
    fields = {}
    for param in op.params:
        value = getattr(args, param.name)
        if param.many:
            value = list(dict.fromkeys(value))
            if not value and not param.required:
                continue
            if len(value) > param.many:
                raise CtlError(f"{' '.join(op.command)} takes at most {param.many} "
                               f"{param.name}, not {len(value)}", Exit.USAGE)
        fields[param.name] = value
    return fields


def run_op(op: Op, args: argparse.Namespace, where: Endpoints) -> int:
    fields = fields_of(op, args)
    if op.notice:
        print(f"{PROG}: {op.notice.format(**fields)}", file=sys.stderr, flush=True)
    with Client(where.control, args.timeout, where.keys) as client:
        result = client.call(op.name, extra_time=op.extra_time(fields), cancel=True,
                             **fields)
    switches = {switch.name: getattr(args, switch.name) for switch in op.switches}
    shown = show(op.name, {**fields, **switches}, result, args.json)
    emit(shown.lines)
    if shown.failure:
        raise CtlError(shown.failure, shown.status)
    return Exit.OK


def emit(lines: list[str]) -> None:
    for line in lines:
        print(line)
    sys.stdout.flush()


def run_keygen(prefix: str) -> int:
    try:
        public, secret = curve.generate(prefix)
    except curve.CurveError as error:
        raise CtlError(str(error), Exit.NODE_FAILED) from None
    emit([f"public key  {public}  {curve.public_key(str(public)).decode()}",
          f"key pair    {secret}  (mode 0600: keep it private)"])
    return Exit.OK


SEVERAL = ("status", "tail", "top", "record")
"""The commands that take several gateways; the others act on one node of one."""


def run_several(args: argparse.Namespace, named: list[Gateway]) -> int:
    """A command given several gateways."""
    if args.command not in SEVERAL:
        raise CtlError(f"{args.command} acts on one gateway, and {len(named)} are given "
                       f"({', '.join(g.name for g in named)}): give one --config or "
                       f"--control (several: {', '.join(SEVERAL)})", Exit.USAGE)
    if args.command == "tail":
        from .tail import run_tail_several
        return run_tail_several(args.nodes, named, args.timeout)
    if args.command == "top":
        from .topsite import run_top_several
        return run_top_several(args.nodes, named, args.timeout, args.json)
    if args.command == "record":
        from .record import run_record
        return run_record(args.file, args.nodes, args.seconds, named, args.timeout)
    from .sitestatus import run_status
    return run_status(named, args.timeout, args.json, bool(args.check), bool(args.wide))


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    for name in ("config", "control"):
        joined = [*(getattr(args, name, None) or ()), *vars(args).pop(f"{name}_after", ())]
        setattr(args, name, joined or None)
    try:
        if args.command == "keygen":
            return run_keygen(args.prefix)
        if args.command == "recordings":
            from .recordings import run_recordings
            return run_recordings(args)
        if args.command == "trials":
            from .recordings import run_trials
            return run_trials(args)
        if args.command == "dataset":
            from .recordings import run_dataset
            return run_dataset(args)
        if args.command in ("export", "plot"):
            from .offline import run_export, run_plot
            return (run_export if args.command == "export" else run_plot)(args)
        named = gateways(args)
        if len(named) > 1:
            return run_several(args, named)
        where = named[0].where
        if args.command == "tail":
            from .tail import run_tail
            return run_tail(args.nodes, where, args.timeout)
        if args.command == "top":
            from .top import run_top
            return run_top(args.nodes, where, args.timeout, args.json)
        if args.command == "record":
            from .record import run_record
            return run_record(args.file, args.nodes, args.seconds, named, args.timeout)
        if args.command == "scan":
            from .scan import run_scan
            return run_scan(args.station, args.addresses, where, args.timeout, args.json)
        return run_op(args.op, args, where)
    except CtlError as error:
        if getattr(args, "json", False):  # a script reading stdout learns of it too
            emit([json_line({"ok": False, "error": str(error), "exit": int(error.status)})])
        fail(PROG, str(error), error.status)
    except KeyboardInterrupt:
        return Exit.OK if args.command in ("tail", "record", "top") else 130
    except BrokenPipeError:  # a reader such as `head` has gone: not an error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return Exit.OK
    except Exception as error:  # a bug: still one line, never a traceback
        fail(PROG, f"internal error: {type(error).__name__}: {error}", Exit.NODE_FAILED)
