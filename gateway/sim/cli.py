"""``gx2-sim``: a virtual base station with nodes behind a pseudo-terminal."""

from __future__ import annotations

import logging
import signal
import sys
import threading
from typing import Any

from pydantic import ValidationError

from aspp.timing import DEFAULT_DIVIDER, MAX_DIVIDER, MIN_DIVIDER
from gateway.common.args import (
    ArgumentParser,
    bounded,
    fail,
    node_list,
    probability,
    streamable_record,
)
from gateway.common.strict import describe, load_model
from gateway.common.yamlfile import ConfigError

from .config import SimConfig
from .node import GX2, INERTIA_LINK
from .server import LinkInUse, Simulator

PROG = "gx2-sim"
UNPLUG_SECONDS = 2.0


def build_parser() -> ArgumentParser:
    parser = ArgumentParser(
        prog=PROG, description="A virtual 3DM-GX2 wireless base station with nodes, behind "
        "a pseudo-terminal. Prints the port to open and serves until interrupted. "
        f"While it runs, SIGUSR1 reboots every node and SIGUSR2 unplugs the base station "
        f"for {UNPLUG_SECONDS:g} s.")
    parser.add_argument("--nodes", type=node_list, default=[], metavar="76,77,95",
                        help="node addresses to simulate (added to those in --config)")
    parser.add_argument("--link", metavar="PATH",
                        help="make PATH a symlink to the pty (stable across unplugs)")
    parser.add_argument("--config", metavar="FILE", help="YAML file of nodes and faults")
    parser.add_argument("--check", action="store_true",
                        help="validate --config and the options and exit (0: valid, 2: not)")
    nodes = parser.add_argument_group("settings of the --nodes nodes")
    nodes.add_argument("--model", choices=(INERTIA_LINK, GX2), default=INERTIA_LINK)
    nodes.add_argument("--stream", type=streamable_record, metavar="RECORD",
                       help="record streamed from power-up (auto-start), e.g. accel_angrate")
    nodes.add_argument("--divider", type=bounded(int, MIN_DIVIDER, MAX_DIVIDER),
                       default=DEFAULT_DIVIDER,
                       help="data rate divider: 51200/x Hz (default 512, 100 Hz)")
    nodes.add_argument("--timer-start", type=bounded(float, 0.0, 1e9), default=0.0,
                       metavar="SECONDS",
                       help="timer value at power-up (215 starts 3.45 s before the wrap)")
    faults = parser.add_argument_group("faults (applied to every node)")
    for name, what in (("command-loss", "commands lost over the radio"),
                       ("data-loss", "packets from nodes lost over the radio"),
                       ("stop-loss", "0xFA stops lost (on top of command loss)")):
        faults.add_argument(f"--{name}", type=probability, metavar="P", help=what)
    faults.add_argument("--out-of-range", type=node_list, default=[], metavar="95,...",
                        help="nodes that do not answer (ping 0x21, no replies)")
    for name, what in (("garbage", "packets followed by random bytes"),
                       ("bad-checksum", "packets with a corrupted checksum"),
                       ("false-header", "packets preceded by a false header")):
        faults.add_argument(f"--{name}", type=probability, metavar="P", help=what)
    faults.add_argument("--nack", type=probability, metavar="P",
                        help="well-formed commands NACKed anyway (the host must resend)")
    faults.add_argument("--glue-ack", action="store_true",
                        help="send each ACK in one write with the next packet")
    faults.add_argument("--first-write-failure", type=probability, metavar="P",
                        help="chance that the first EEPROM write after power-up fails")
    parser.add_argument("--baudrate", type=bounded(int, 1200, 4_000_000), default=None)
    parser.add_argument("--seed", type=int, default=None)
    parser.add_argument("-v", "--verbose", action="store_true")
    return parser


def merged_config(args: Any) -> SimConfig:
    """The config file with the command line's nodes and overrides applied."""
    base = load_model(args.config, SimConfig) if args.config else SimConfig()
    data = base.model_dump()
    known = {n["address"] for n in data["nodes"]}
    for address in args.nodes:
        if address in known:
            raise ConfigError(f"node {address} is both in --config and in --nodes")
        data["nodes"].append({"address": address, "model": args.model, "stream": args.stream,
                              "divider": args.divider, "timer_start": args.timer_start})
    for node in data["nodes"]:
        radio = node.setdefault("radio", {})
        for key in ("command_loss", "data_loss", "stop_loss"):
            if getattr(args, key) is not None:
                radio[key] = getattr(args, key)
        if node["address"] in args.out_of_range:
            radio["in_range"] = False
    for key in ("garbage", "bad_checksum", "false_header", "nack"):
        if getattr(args, key) is not None:
            data["line"][key] = getattr(args, key)
    if args.glue_ack:
        data["line"]["glue_ack"] = True
    for key in ("baudrate", "seed", "first_write_failure"):
        if getattr(args, key) is not None:
            data[key] = getattr(args, key)
    try:
        config = SimConfig.model_validate(data)
    except ValidationError as error:
        raise ConfigError(describe(error, args.config or "command line")) from None
    if not config.nodes:
        raise ConfigError("no nodes: give --nodes 76,77 or a --config with nodes")
    missing = set(args.out_of_range) - {n.address for n in config.nodes}
    if missing:
        raise ConfigError(f"--out-of-range names node {min(missing)}, which is not simulated")
    return config


def simulator_from(config: SimConfig, link: str | None = None) -> Simulator:
    return Simulator([n.build() for n in config.nodes], link=link,
                     radio={n.address: n.radio.build() for n in config.nodes},
                     line=config.line.build(), baudrate=config.baudrate, seed=config.seed,
                     first_write_failure_rate=config.first_write_failure)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    try:
        config = merged_config(args)
    except ConfigError as error:
        fail(PROG, str(error), 2)
    if args.check:
        count = len(config.nodes)
        print(f"{args.config or 'command line'}: valid ({count} node{'s' if count != 1 else ''})")
        return 0
    done = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: done.set())
    try:
        sim = simulator_from(config, args.link).start()
    except LinkInUse as error:
        fail(PROG, f"--link {error}", 2)
    except OSError as error:
        fail(PROG, f"cannot create the port: {error}", 1)
    signal.signal(signal.SIGUSR1, lambda *_: [sim.reboot(n.address) for n in config.nodes])
    signal.signal(signal.SIGUSR2, lambda *_: sim.unplug(duration=UNPLUG_SECONDS))
    nodes = ", ".join(f"{n.address}" + (f" ({n.stream})" if n.stream else "")
                      for n in config.nodes)
    print(f"{PROG}: base station on {sim.port.path}"
          + (f" (link {args.link})" if args.link else "") + f"; nodes {nodes}", flush=True)
    print(sim.path, flush=True)
    while not done.wait(0.5):
        if sim.error is not None:
            break
    sim.stop()
    return 1 if sim.error is not None else 0


if __name__ == "__main__":
    sys.exit(main())
