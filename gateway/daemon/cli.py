"""``gx2-gateway --config nodes.yaml``: the daemon's command line, thin.

SIGINT and SIGTERM mean "stop, quietly, exit 0" from the first instant: a quiet
handler is installed before anything heavy is imported, and the daemon's own handlers
(which close everything cleanly) replace it once the loop runs.
"""

from __future__ import annotations

import signal
import sys
from types import FrameType
from typing import NoReturn


def _exit_quietly(signum: int, frame: FrameType | None) -> NoReturn:
    raise SystemExit(0)


SWITCH_INTERVAL = 0.0005
"""Seconds a thread holds the GIL while another waits for it (Python's default is 5 ms):
the loop, woken by a read, waits at most this long for the recorder's thread. Four
saturated stations, recording and metrics on, latency p99 from the simulator's write to
a subscriber: 2.39, 2.12 and 2.65 ms at the default, 1.58, 1.53 and 1.72 ms at this
(0.66x), the gateway's CPU 18.4, 17.7, 20.5% against 16.8, 15.5, 18.1% of a core (not
more); rounds interleaved, bench/stations.py --stations 4 --rounds 1 --seconds 15 run
from each tree in turn."""


def main(argv: list[str] | None = None) -> int:
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, _exit_quietly)
    # a reload before the loop runs has nothing to reload: the file is being read now
    signal.signal(signal.SIGHUP, signal.SIG_IGN)

    import logging
    import os

    from gateway.common.args import ArgumentParser, fail

    from .config import ConfigError, load_config
    from .shipped import PrintFiles

    parser = ArgumentParser(prog="gx2-gateway", description="Gateway for MicroStrain "
                            "3DM-GX2 / Inertia-Link wireless sensors: owns the base "
                            "station's serial port and publishes every node's records "
                            "over ZeroMQ.")
    parser.add_argument("--config", required=True, metavar="FILE",
                        help="the gateway's YAML configuration (see config/nodes.yaml, "
                        "also in the --files directory)")
    parser.add_argument("--files", action=PrintFiles,
                        help="print the directory of the files shipped with gx2-gateway "
                        "(deploy/: systemd unit, udev rule, alerting rules; config/: "
                        "example configurations; README.md; docs/) and exit")
    parser.add_argument("--check", action="store_true",
                        help="validate the configuration and exit (0: valid, 2: not); "
                        "what a start would meet on this host but not fail on (a device "
                        "not plugged in, an endpoint held) is a warning on stderr")
    parser.add_argument("--log-level", default="INFO",
                        choices=("DEBUG", "INFO", "WARNING", "ERROR"))
    args = parser.parse_args(argv)
    try:
        config = load_config(args.config)
    except ConfigError as error:
        fail(parser.prog, str(error), 2)
    # a recording with nothing the gateway can play is refused as the configuration is:
    # at --check, and at start rather than as a replay that ends at once having done nothing
    from .station.ports import never_serial, nothing_to_play
    for where, station in config.placed_stations():
        problem = nothing_to_play(station.port,
                                  None if config.base_stations is None else station.name)
        if args.check:
            problem = problem or never_serial(station.port)
        if problem:
            fail(parser.prog, f"{args.config}: {where}.port: {problem}", 2)
    if args.check:
        # the unit runs --check as its user, in its sandbox, before the gateway: a
        # directory it cannot write fails there, not as a recorder that keeps nothing
        from .checks import live_refusal, lsl_refusal, unwritable, warnings
        record = config.record
        problem = unwritable(record.directory) if record is not None else None
        if problem:
            fail(parser.prog, f"{args.config}: record.directory: {record.directory}: "
                 f"{problem}", 2)
        problem = live_refusal(config) or lsl_refusal(config)
        if problem:
            fail(parser.prog, f"{args.config}: {problem}", 2)
        for warning in warnings(config):
            print(f"{parser.prog}: warning: {args.config}: {warning}", file=sys.stderr)
        count, stations = len(config.all_nodes), len(config.stations)
        print(f"{args.config}: valid ({count} node{'s' if count != 1 else ''}"
              + (f" on {stations} base stations)" if stations > 1 else ")"))
        return 0
    under_systemd = "INVOCATION_ID" in os.environ or "JOURNAL_STREAM" in os.environ
    logging.basicConfig(
        level=args.log_level, stream=sys.stderr,
        format="%(levelname)s %(name)s: %(message)s" if under_systemd
        else "%(asctime)s %(levelname)s %(name)s: %(message)s")

    import asyncio  # (not before: a configuration refused, or --check, never needs it)

    from .app import Gateway, StartupError

    async def serve() -> int:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for signum in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(signum, stop.set)
        gateway = Gateway(config, args.config)
        assert gateway.reloader is not None
        # systemctl reload: the file read again, its nodes applied (or refused, logged)
        loop.add_signal_handler(signal.SIGHUP, gateway.reloader.soon)
        await gateway.run(stop)
        return gateway.exit_status

    sys.setswitchinterval(SWITCH_INTERVAL)
    try:
        return asyncio.run(serve())
    except StartupError as error:
        fail(parser.prog, str(error), 1)


if __name__ == "__main__":
    sys.exit(main())
