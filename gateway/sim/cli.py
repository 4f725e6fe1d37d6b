"""``gx2-sim``: a virtual base station with nodes behind a pseudo-terminal."""

from __future__ import annotations

import logging
import signal
import sys
import threading
from typing import Any, NamedTuple, TypeVar

from pydantic import ValidationError

from aspp.timing import DEFAULT_DIVIDER, MAX_DIVIDER, MIN_DIVIDER
from gateway.common.args import (
    ArgumentParser,
    bounded,
    fail,
    node_address,
    node_list,
    probability,
    streamable_record,
)
from gateway.common.strict import describe
from gateway.common.yamlfile import ConfigError

from .config import SimConfig, SimNodeEntry, SimStationsConfig, load_sim_config
from .control import ControlError, ControlServer, Handler, power, send
from .node import GX2, INERTIA_LINK
from .physics import MOTIONS
from .server import LinkInUse, Simulator

PROG = "gx2-sim"
UNPLUG_SECONDS = 2.0
MAX_UNPLUG_SECONDS = 86400.0
"""The longest unplug asked for by a duration (0: until replugged)."""


def build_parser() -> ArgumentParser:
    parser = ArgumentParser(
        prog=PROG, description="A virtual 3DM-GX2 wireless base station with nodes, behind "
        "a pseudo-terminal (or several, each behind its own: base_stations: in --config). "
        "Prints the port to open (several: NAME: PORT a line) and serves until "
        "interrupted. While it runs, SIGUSR1 reboots every node and SIGUSR2 unplugs every "
        f"base station for {UNPLUG_SECONDS:g} s; 'gx2-sim unplug NAME' unplugs one "
        "(gx2-sim unplug --help), 'gx2-sim power NODE on|off' switches a node on or off.")
    parser.add_argument("--nodes", type=node_list, default=[], metavar="76,77,95",
                        help="node addresses to simulate (added to those in --config; "
                        "not with base_stations:)")
    parser.add_argument("--link", metavar="PATH",
                        help="make PATH a symlink to the pty (stable across unplugs; "
                        "with base_stations:, each station's link: instead)")
    parser.add_argument("--config", metavar="FILE",
                        help="YAML file of nodes and faults, or of base_stations:")
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
    nodes.add_argument("--motion", choices=tuple(MOTIONS), default="turn",
                       help="turn about the vertical (default), or swing as well")
    faults = parser.add_argument_group("faults (applied to every node of every station)")
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


CONTROL_COMMANDS = ("unplug", "replug", "power")
SWITCH = ("on", "off")


def build_control_parser(action: str) -> ArgumentParser:
    """``gx2-sim unplug|replug [NAME]``: to one station of the running simulator;
    ``gx2-sim power NODE on|off``: to one node."""
    if action == "power":
        parser = ArgumentParser(
            prog=f"{PROG} power",
            description="Switch a node of the running gx2-sim on (it powers up: a "
            "discovery packet, then what it auto-starts, as a node added mid-study) or "
            "off (it answers nothing and sends nothing). Its config's powered: false "
            "starts it off.")
        parser.add_argument("node", type=node_address, metavar="NODE",
                            help="the node's address")
        parser.add_argument("state", choices=SWITCH, help="on or off")
        parser.add_argument("--pid", type=bounded(int, 1, 1 << 22), metavar="PID",
                            help="the gx2-sim to talk to, where several have that node")
        return parser
    parser = ArgumentParser(
        prog=f"{PROG} {action}",
        description=("Unplug one base station of the running gx2-sim (its pty goes away "
                     "and comes back behind the same link)." if action == "unplug" else
                     "Plug an unplugged base station of the running gx2-sim back in."))
    parser.add_argument("name", nargs="?", metavar="NAME",
                        help="the station's name (base_stations:); omit it for a "
                        "gx2-sim of one station")
    if action == "unplug":
        parser.add_argument("--seconds", type=bounded(float, 0.0, MAX_UNPLUG_SECONDS),
                            default=UNPLUG_SECONDS,
                            help=f"plug it back in after this long (default "
                            f"{UNPLUG_SECONDS:g}; 0: until 'gx2-sim replug NAME')")
    parser.add_argument("--pid", type=bounded(int, 1, 1 << 22), metavar="PID",
                        help="the gx2-sim to talk to, where several have that station")
    return parser


def control_main(action: str, argv: list[str]) -> int:
    args = build_control_parser(action).parse_args(argv)
    try:
        if action == "power":
            print(power(args.node, args.state == "on", args.pid), flush=True)
        else:
            print(send(action, args.name, getattr(args, "seconds", None), args.pid),
                  flush=True)
    except ControlError as error:
        fail(PROG, str(error), 1)
    return 0


def control_handler(stations: list[Station], sims: list[Simulator]) -> Handler:
    """What the running simulator does for ``gx2-sim unplug|replug|power`` (gateway.sim.
    control): its stations by name (the one-station form's is ``-``), its nodes by
    address."""
    by_name = {station.name or "-": sim for station, sim in zip(stations, sims, strict=True)}
    by_node = {node.address: (station.name, sim)
               for station, sim in zip(stations, sims, strict=True)
               for node in station.config.nodes}

    def handle(words: list[str]) -> str:
        if words == ["stations"]:
            return "ok " + " ".join(by_name)
        if words == ["nodes"]:
            return "ok " + " ".join(map(str, by_node))
        if words[:1] == ["power"]:
            return switch(words[1:])
        if len(words) not in (2, 3) or words[0] not in CONTROL_COMMANDS:
            raise ControlError(f"not a command: {' '.join(words)!r}")
        sim = by_name.get(words[1])
        if sim is None:
            raise ControlError(f"no station {words[1]} (stations: {', '.join(by_name)})")
        label = "the base station" if words[1] == "-" else words[1]
        if words[0] == "replug":
            sim.replug()
            return f"ok {label} plugged in"
        try:
            seconds = float(words[2]) if len(words) == 3 else UNPLUG_SECONDS
        except ValueError:
            raise ControlError(f"not a number of seconds: {words[2]!r}") from None
        if not 0 <= seconds <= MAX_UNPLUG_SECONDS:  # (nan too)
            raise ControlError(f"seconds: {words[2]} is not from 0 to "
                               f"{MAX_UNPLUG_SECONDS:g}")
        sim.unplug(duration=seconds or None)
        return f"ok {label} unplugged" + (f" for {seconds:g} s" if seconds
                                          else " until replugged")

    def switch(words: list[str]) -> str:
        """``NODE on|off``."""
        if len(words) != 2 or words[1] not in SWITCH or not words[0].isdecimal():
            raise ControlError(f"not a command: power {' '.join(words)!r}")
        address, on = int(words[0]), words[1] == "on"
        if address not in by_node:
            raise ControlError(f"no node {address} (nodes: {', '.join(map(str, by_node))})")
        name, sim = by_node[address]
        where = f" (base station {name})" if name else ""
        if not sim.power(address, on):
            return f"ok node {address} was {words[1]} already{where}"
        return (f"ok node {address} switched on: it powers up{where}" if on
                else f"ok node {address} switched off{where}")
    return handle


def merged_config(args: Any, base: SimConfig) -> SimConfig:
    """The one-station file (or none) with the command line's nodes and overrides."""
    data = base.model_dump()
    known = {n["address"] for n in data["nodes"]}
    for address in args.nodes:
        if address in known:
            raise ConfigError(f"node {address} is both in --config and in --nodes")
        data["nodes"].append({"address": address, "model": args.model, "stream": args.stream,
                              "divider": args.divider, "timer_start": args.timer_start,
                              "motion": args.motion})
    _override(data, args)
    config = _validated(SimConfig, data, args.config or "command line")
    if not config.nodes:
        raise ConfigError("no nodes: give --nodes 76,77 or a --config with nodes")
    _check_out_of_range(args, config.nodes)
    return config


def merged_stations(args: Any, stations: SimStationsConfig) -> SimStationsConfig:
    """A ``base_stations:`` file with the command line's faults applied to every station.
    --nodes and --link are the one station's: which station they would be is a guess."""
    for option in ("nodes", "link"):
        if getattr(args, option):
            raise ConfigError(f"--{option}: {args.config} has base_stations: give each "
                              f"station its {option} there (--{option} is the one-station form's)")
    data = stations.model_dump()
    for station in data["base_stations"]:
        _override(station, args)
    merged = _validated(SimStationsConfig, data, args.config)
    _check_out_of_range(args, [n for s in merged.base_stations for n in s.nodes])
    return merged


def _override(data: dict[str, Any], args: Any) -> None:
    """The command line's faults and settings over one station's (dumped) config."""
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


M = TypeVar("M", SimConfig, SimStationsConfig)


def _validated(model: type[M], data: dict[str, Any], source: str) -> M:
    try:
        return model.model_validate(data)
    except ValidationError as error:
        raise ConfigError(describe(error, source, model=model)) from None


def _check_out_of_range(args: Any, nodes: list[SimNodeEntry]) -> None:
    missing = set(args.out_of_range) - {n.address for n in nodes}
    if missing:
        raise ConfigError(f"--out-of-range names node {min(missing)}, which is not simulated")


class Station(NamedTuple):
    """A base station to serve: ``name`` is None for the one-station form."""

    name: str | None
    config: SimConfig
    link: str | None


def configured_stations(args: Any) -> list[Station]:
    """Every base station the file and the command line ask for; ConfigError."""
    loaded = load_sim_config(args.config) if args.config else SimConfig()
    if isinstance(loaded, SimStationsConfig):
        return [Station(s.name, s, s.link)
                for s in merged_stations(args, loaded).base_stations]
    return [Station(None, merged_config(args, loaded), args.link)]


def simulator_from(config: SimConfig, link: str | None = None) -> Simulator:
    return Simulator([n.build() for n in config.nodes], link=link,
                     radio={n.address: n.radio.build() for n in config.nodes},
                     line=config.line.build(), baudrate=config.baudrate, seed=config.seed,
                     first_write_failure_rate=config.first_write_failure)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] in CONTROL_COMMANDS:
        return control_main(argv[0], argv[1:])
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    try:
        stations = configured_stations(args)
    except ConfigError as error:
        fail(PROG, str(error), 2)
    if args.check:
        print(f"{args.config or 'command line'}: valid ({_counted(stations)})")
        return 0
    done = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: done.set())
    sims = start_all(stations)
    signal.signal(signal.SIGUSR1, lambda *_: [sim.reboot(n.address) for sim, station
                                              in zip(sims, stations, strict=True)
                                              for n in station.config.nodes])
    signal.signal(signal.SIGUSR2, lambda *_: [sim.unplug(duration=UNPLUG_SECONDS)
                                              for sim in sims])
    try:
        control = ControlServer(control_handler(stations, sims)).start()
    except (ControlError, OSError) as error:
        for sim in sims:
            sim.stop()
        fail(PROG, f"cannot listen for 'gx2-sim unplug': {error}", 1)
    announce(stations, sims)
    while not done.wait(0.5):
        if any(sim.error is not None for sim in sims):
            break
    control.close()
    for sim in sims:
        sim.stop()
    return 1 if any(sim.error is not None for sim in sims) else 0


def _counted(stations: list[Station]) -> str:
    """What --check found, said as gx2-gateway --check says it."""
    def counted(count: int, noun: str) -> str:
        return f"{count} {noun}{'s' if count != 1 else ''}"

    nodes = counted(sum(len(station.config.nodes) for station in stations), "node")
    if stations[0].name is None:
        return nodes
    return f"{nodes} on {counted(len(stations), 'base station')}"


def start_all(stations: list[Station]) -> list[Simulator]:
    """Each station's simulator, started; on a failure, the ones started are stopped
    (their links removed) before the one-line error."""
    sims: list[Simulator] = []
    for station in stations:
        # the one-station form's link is --link; a station's is its link: key
        where = "--link" if station.name is None else f"{station.name}: link"
        try:
            sims.append(simulator_from(station.config, station.link).start())
        except (LinkInUse, OSError) as error:
            for sim in sims:
                sim.stop()
            if isinstance(error, LinkInUse):
                fail(PROG, f"{where} {error}", 2)
            fail(PROG, f"{station.name + ': ' if station.name else ''}cannot create the "
                 f"port: {error}", 1)
    return sims


def announce(stations: list[Station], sims: list[Simulator]) -> None:
    """Where to connect, once every station serves. The one-station form: a banner,
    then the path alone; several: a banner for each, then ``name: path`` for each (the
    last line: every station serves)."""
    def described(station: Station, sim: Simulator) -> str:
        nodes = ", ".join(f"{n.address}" + (f" ({n.stream})" if n.stream else "")
                          + ("" if n.powered else " (off)") for n in station.config.nodes)
        return (f"on {sim.port.path}" + (f" (link {station.link})" if station.link else "")
                + f"; nodes {nodes}")

    if stations[0].name is None:
        print(f"{PROG}: base station {described(stations[0], sims[0])}", flush=True)
        print(sims[0].path, flush=True)
        return
    for station, sim in zip(stations, sims, strict=True):
        print(f"{PROG}: base station {station.name} {described(station, sim)}", flush=True)
    for station, sim in zip(stations, sims, strict=True):
        print(f"{station.name}: {sim.path}", flush=True)


if __name__ == "__main__":
    sys.exit(main())
