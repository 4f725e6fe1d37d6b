"""GX2 commands: typed builders with validated arguments, and the parser the device side
uses, both driven by the table in :mod:`aspp.records`.

A :class:`Command` is the GX2 command bytes plus what answers them; wrap it for a node
with :meth:`Command.packet`. Every builder validates before producing a byte: a bad
argument raises :class:`aspp.errors.CommandError` naming it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType

from .errors import CommandError, RecordError
from .fields import Const, Field
from .frame import encode_command_packet
from .records import STREAMABLE, CommandSpec, checked, lookup
from .timing import MAX_DIVIDER, MIN_DIVIDER, valid_divider

EEPROM_DIVIDER = 0xFCA2
"""EEPROM word holding the calculation-cycle divider x: data rate = 51200 / x Hz."""
EEPROM_AUTO_START = 0xFCA6
"""EEPROM word whose LSB is the record to stream from power-up (0 for none)."""
AUTO_START_WIRELESS = 0x8000
"""MSB of the auto-start word that a wireless node needs."""
DOCUMENTED_EEPROM = {EEPROM_DIVIDER: "data rate divider", EEPROM_AUTO_START: "auto-start record"}


@dataclass(frozen=True)
class Command:
    """One GX2 command, validated: its spec, its arguments by name, its bytes."""

    spec: CommandSpec
    arguments: Mapping[str, object]
    data: bytes

    @property
    def code(self) -> int:
        return self.spec.code

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def expects_reply(self) -> bool:
        """False only for 0xFA, which the node never answers."""
        return self.spec.reply is not None

    def packet(self, node: int) -> bytes:
        """The ASPP command packet that delivers this command to ``node``."""
        return encode_command_packet(node, self.data)

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.arguments.items())
        return f"Command(0x{self.code:02X} {self.name}{': ' + args if args else ''})"


def build(record: str | int, **arguments: object) -> Command:
    """Build any command from the table by record name or byte, arguments by name."""
    spec = _spec(record)
    expected = {f.name for f in spec.arguments}
    unknown = set(arguments) - expected
    if unknown:
        raise CommandError(f"{spec.name} takes no argument {sorted(unknown)[0]!r}")
    items: list[object] = [spec.code]
    for item in spec.request:
        if isinstance(item, Const):
            items.append(item.value)
            continue
        if item.name not in arguments:
            raise CommandError(f"{spec.name} needs {item.name!r}")
        items.extend(_validated(spec, item, arguments[item.name]))
    data = spec.request_struct.pack(*items)
    return Command(spec, _read_arguments(spec, data), data)


def _validated(spec: CommandSpec, item: Field, value: object) -> tuple[object, ...]:
    flat = item.type.flatten(item.name, value)
    shaped = flat[0] if len(flat) == 1 else flat
    if item.check is not None:
        item.check(item.name, shaped)
    if spec.code == 0xC4 and item.name == "continuous_command":
        _check_streamable(shaped)
    return flat


def _check_streamable(code: object) -> None:
    if code != 0 and code not in STREAMABLE:
        raise CommandError(f"continuous_command 0x{code:02X} is not a record that can "
                           f"stream; use 0 to stop or one of "
                           f"{', '.join(f'0x{c:02X}' for c in sorted(STREAMABLE))}")


def parse(data: bytes, check_arguments: bool = True) -> Command:
    """Parse GX2 command bytes; raise CommandError if they are not exactly one valid
    command (unknown byte, wrong length, wrong confirmation bytes, and with
    ``check_arguments`` an argument out of its range). A device parses with
    ``check_arguments=False``: the reference defines what it does with some values a
    host should never send (0xD0 answers any quantity but 1 and 2 with 0xFFFF)."""
    if not data:
        raise CommandError("no command byte")
    try:
        spec = lookup(data[0])
    except RecordError:
        raise CommandError(f"0x{data[0]:02X} is not a GX2 command") from None
    if len(data) != spec.request_size:
        raise CommandError(f"0x{spec.code:02X} {spec.name} takes {spec.request_size} "
                           f"bytes, not {len(data)}")
    arguments = _read_arguments(spec, data)
    if check_arguments:
        for item in spec.arguments:
            if item.check is not None:
                item.check(item.name, arguments[item.name])
        if spec.code == 0xC4:
            _check_streamable(arguments["continuous_command"])
    return Command(spec, arguments, bytes(data))


def _read_arguments(spec: CommandSpec, data: bytes) -> Mapping[str, object]:
    """The arguments as the bytes carry them (floats as the float32 the device gets);
    raises CommandError if the confirmation bytes are wrong."""
    items = spec.request_struct.unpack(data)
    arguments: dict[str, object] = {}
    at = 1
    for item in spec.request:
        if isinstance(item, Const):
            if items[at] != item.value:
                raise CommandError(f"0x{spec.code:02X} {spec.name}: confirmation bytes "
                                   f"{items[at].hex(' ')} are not {item.value.hex(' ')}")
            at += 1
            continue
        arguments[item.name] = item.type.shape_items(items[at:at + item.type.items])
        at += item.type.items
    return MappingProxyType(arguments)


def _spec(record: str | int, *, streamable: bool = False,
          pollable: bool = False) -> CommandSpec:
    """:func:`aspp.records.checked`, its error raised as a CommandError."""
    try:
        return checked(record, streamable=streamable, pollable=pollable)
    except RecordError as error:
        raise CommandError(str(error)) from None


def poll(record: str | int) -> Command:
    """Ask once for a record that needs no arguments (0xC1..0xD3 data records, 0xE9)."""
    return build(_spec(record, pollable=True).code)


def set_continuous(record: str | int) -> Command:
    """C4 C1 29 <cmd>: stream ``record`` every calculation cycle."""
    return build(0xC4, continuous_command=_spec(record, streamable=True).code)


def stop_continuous() -> Command:
    """0xFA: the short stop, which the node never answers."""
    return build(0xFA)


def stop_continuous_long() -> Command:
    """C4 C1 29 00: the long stop, answered with a 0xC4 record."""
    return build(0xC4, continuous_command=0)


def write_accel_bias(bias: tuple[float, float, float]) -> Command:
    return build(0xC9, accel_bias=bias)


def write_gyro_bias(bias: tuple[float, float, float]) -> Command:
    return build(0xCA, gyro_bias=bias)


def capture_gyro_bias(sampling_time_ms: int) -> Command:
    return build(0xCD, sampling_time=sampling_time_ms)


def store_nonvolatile(quantity: int) -> Command:
    """Store the accel bias (1) or the gyro bias (2) across power cycles."""
    return build(0xD0, quantity=quantity)


def write_eeprom(address: int, value: int) -> Command:
    return build(0xE4, address=address, value=value)


def read_eeprom(address: int) -> Command:
    return build(0xE5, address=address)


def firmware_version() -> Command:
    return build(0xE9)


def firmware_text(version: int) -> str:
    """0xE9's number as the reference writes versions: 2113 is 2.1.13, 2103 is 2.1.03."""
    return f"{version // 1000}.{version // 100 % 10}.{version % 100:02d}"


def device_id(selector: int) -> Command:
    """One of the four identifier strings: 0 model number, 1 serial number, 2 model
    name, 3 device options."""
    return build(0xEA, selector=selector)


def built_in_test(test_config: int) -> Command:
    return build(0xFB, test_config=test_config)


def set_divider(divider: int) -> Command:
    """Write the data rate divider (EEPROM 0xFCA2); rate = 51200 / divider Hz."""
    if isinstance(divider, bool) or not isinstance(divider, int):
        raise CommandError(f"divider must be an integer, not {divider!r}")
    if not valid_divider(divider):
        raise CommandError(f"divider {divider} is out of range {MIN_DIVIDER}..{MAX_DIVIDER}")
    return write_eeprom(EEPROM_DIVIDER, divider)


def auto_start_record(word: int) -> str | None:
    """The record an auto-start word (EEPROM 0xFCA6, as read) streams from power-up, or
    None: polled mode (0), or a byte that is not a record the node can stream."""
    code = word & 0xFF
    return lookup(code).name if code in STREAMABLE else None


def set_auto_start(record: str | int | None) -> Command:
    """Stream ``record`` from every power-up (None: start in polled mode)."""
    if record is None:
        return write_eeprom(EEPROM_AUTO_START, 0)
    return write_eeprom(EEPROM_AUTO_START,
                        AUTO_START_WIRELESS | _spec(record, streamable=True).code)
