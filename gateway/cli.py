"""``gx2-gateway --config nodes.yaml``: the daemon's command line, thin."""

from __future__ import annotations

import asyncio
import logging
import os
import signal
import sys

from .cli_args import ArgumentParser, fail
from .config import ConfigError, load_config
from .daemon import Gateway, StartupError

PROG = "gx2-gateway"


def build_parser() -> ArgumentParser:
    parser = ArgumentParser(prog=PROG, description="Gateway for MicroStrain 3DM-GX2 / "
                            "Inertia-Link wireless sensors: owns the base station's serial "
                            "port and publishes every node's records over ZeroMQ.")
    parser.add_argument("--config", required=True, metavar="FILE",
                        help="the gateway's YAML configuration (see config/nodes.yaml)")
    parser.add_argument("--check", action="store_true",
                        help="validate the configuration and exit (0: valid, 2: not)")
    parser.add_argument("--log-level", default="INFO",
                        choices=("DEBUG", "INFO", "WARNING", "ERROR"))
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        config = load_config(args.config)
    except ConfigError as error:
        fail(PROG, str(error), 2)
    if args.check:
        count = len(config.nodes)
        print(f"{args.config}: valid ({count} node{'s' if count != 1 else ''})")
        return 0
    under_systemd = "INVOCATION_ID" in os.environ or "JOURNAL_STREAM" in os.environ
    logging.basicConfig(
        level=args.log_level, stream=sys.stderr,
        format="%(levelname)s %(name)s: %(message)s" if under_systemd
        else "%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        return asyncio.run(_serve(config))
    except StartupError as error:
        fail(PROG, str(error), 1)


async def _serve(config: object) -> int:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for signum in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(signum, stop.set)
    gateway = Gateway(config)  # type: ignore[arg-type]
    await gateway.run(stop)
    return 0


if __name__ == "__main__":
    sys.exit(main())
