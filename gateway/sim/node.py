"""One simulated 3DM-GX2 / Inertia-Link node: its state, its calculation cycle, and the
reply every command of the reference defines.

A node works in calculation cycles of ``divider / 51200`` s. At the end of each cycle
it outputs its continuous-mode record if streaming, then the reply to at most one
buffered polled command: the reference's combined continuous and polled order.
Every reply is built with :func:`aspp.records.encode`, so the simulator and the
decoder share one definition of each record. Pure: time comes in as arguments.
"""

from __future__ import annotations

import math
import random
from collections import deque
from dataclasses import dataclass, field

from aspp import commands as gx2
from aspp.commands import EEPROM_AUTO_START, EEPROM_DIVIDER
from aspp.errors import CommandError
from aspp.fields import Vector
from aspp.orientation import euler_from_matrix
from aspp.records import STREAMABLE, encode, lookup
from aspp.temperature import DEFAULT_GYRO, accel_code, gyro_code
from aspp.timing import (
    DEFAULT_DIVIDER,
    TICKS_PER_SECOND,
    TIMER_MODULUS,
    sample_period,
    valid_divider,
)

from .physics import Motion

INERTIA_LINK = "inertia-link"
GX2 = "3dm-gx2"
FIRMWARE_VERSION = 2113  # 2.1.13: the first with every command of the reference (0xD3)
_NAN3 = (math.nan, math.nan, math.nan)
SAMPLED_MAX = 200_000
BIT_STEP = 0.1
"""What the built-in test adds to a stepped output: g for accelerometers, rad/s for
rate sensors (the reference gives no size)."""


@dataclass
class NodeSettings:
    """What a simulated node is and how it starts."""

    address: int
    model: str = INERTIA_LINK
    stream: str | None = None
    """Record streamed from power-up: the auto-start word at EEPROM 0xFCA6."""
    divider: int = DEFAULT_DIVIDER
    timer_start: float = 0.0
    """Seconds on the timer at power-up (215 starts it 3.45 s before the wrap)."""
    serial: str = ""
    motion: Motion = field(default_factory=Motion)
    ppm: float | None = None
    """Its crystal's error: the timer and the calculation cycles run this many parts per
    million fast (negative: slow). None: a few tens, different for each address."""
    phase: float = 0.0
    """Seconds after power-up at which its calculation cycles start: where its samples
    fall against another node's at the same rate (every node powers up together), so
    that one node's packets can be made to reach the serial line just after another's
    and queue behind them."""
    gyro: str = DEFAULT_GYRO
    """The rate sensor model, which sets how its temperature output reads."""
    gyro_bias_error: Vector = (0.0, 0.0, 0.0)
    """rad/s the rate sensors read beyond the true rate: what a bias capture estimates."""
    accel_noise: float = 0.0
    """Standard deviation of each accelerometer output, g."""
    rate_noise: float = 0.0
    """Standard deviation of each rate sensor output, rad/s."""
    bit_faults: frozenset[str] = frozenset()
    """Outputs that do not step under the built-in test ("accel_x" .. "rate_z"): a
    sensor that fails its self-test."""
    powered: bool = True
    """Switched on from the start; False: present but off (it answers nothing and sends
    nothing) until it is switched on (:meth:`~.base_station.BaseStation.power`)."""


@dataclass
class NodeLog:
    """What the node received and sent, for tests to check against."""

    commands: list[gx2.Command] = field(default_factory=list)
    ignored: list[tuple[bytes, str]] = field(default_factory=list)
    records_sent: int = 0
    continuous_sent: int = 0
    power_ups: int = 0


class SimNode:
    """The node's firmware, as far as the host can see it."""

    def __init__(self, settings: NodeSettings, now: float,
                 rng: random.Random | None = None) -> None:
        self.settings = settings
        self.address = settings.address
        self.rng = rng or random.Random(settings.address)
        self.first_write_failure_rate = 0.0
        self.log = NodeLog()
        self.eeprom: dict[int, int] = {EEPROM_DIVIDER: settings.divider, EEPROM_AUTO_START: 0}
        self.nonvolatile: dict[int, Vector] = {1: (0.0, 0.0, 0.0), 2: (0.0, 0.0, 0.0)}
        """What 0xD0 stored, loaded at power-up: 1 the accel bias, 2 the gyro bias."""
        self.bit_faults = set(settings.bit_faults)
        self.sampled: dict[int, float] = {}
        """Timer reading -> the host-clock instant (time.monotonic()) its record was
        taken, for the newest SAMPLED_MAX timed records."""
        if settings.stream:
            self.eeprom[EEPROM_AUTO_START] = gx2.AUTO_START_WIRELESS | lookup(settings.stream).code
        self.powered = settings.powered
        """Switched on: off, it hears no command and completes no cycle."""
        self.power_up(now)  # (off: its RAM as a power-up leaves it, set again at the next)

    # -- life cycle ------------------------------------------------------------------

    def power_up(self, now: float) -> None:
        """Power-on (or a reboot): timer restarts, RAM state is lost, EEPROM and the
        stored biases kept."""
        self.powered_at = now
        self._rebase(now + self.settings.phase)
        self.pending: deque[gx2.Command] = deque()
        self.accel_bias = self.nonvolatile[1]
        self.gyro_bias = self.nonvolatile[2]
        self.test_config = 0
        self.wrote_eeprom = False
        self.capture_due: tuple[float, float] | None = None
        """A bias capture under way: (when it ends, when it began)."""
        auto = self.eeprom.get(EEPROM_AUTO_START, 0) & 0xFF
        self.continuous = auto if auto in STREAMABLE else 0
        self.log.power_ups += 1

    @property
    def period(self) -> float:
        return sample_period(self.divider)

    @property
    def ppm(self) -> float:
        """The crystal's error; by default spread over -30..+30 ppm by address."""
        if self.settings.ppm is not None:
            return self.settings.ppm
        return float((self.address * 37) % 61 - 30)

    def _rebase(self, t: float) -> None:
        """Count cycles from ``t`` at the current period (after power-up, or when the
        divider changes: cycles already run keep the times they had). A fast crystal
        makes its cycles short in true time: the timer still counts divider * 384 ticks
        a cycle."""
        self._cycles_from = t
        self._cycle_period = self.period / (1 + self.ppm * 1e-6)
        self.cycle = 0

    @property
    def divider(self) -> int:
        value = self.eeprom.get(EEPROM_DIVIDER, DEFAULT_DIVIDER)
        return value if valid_divider(value) else DEFAULT_DIVIDER

    def next_cycle_time(self) -> float:
        return self._cycles_from + (self.cycle + 1) * self._cycle_period

    def timer_at(self, now: float) -> int:
        seconds = self.settings.timer_start + (now - self.powered_at) * (1 + self.ppm * 1e-6)
        return round(seconds * TICKS_PER_SECOND) % TIMER_MODULUS

    # -- the host's commands ------------------------------------------------------------

    def receive(self, data: bytes) -> None:
        """A command arrived over the radio; it is answered at the end of a cycle (a
        node switched off hears nothing)."""
        if not self.powered:
            return
        try:
            command = gx2.parse(data, check_arguments=False)
        except CommandError as error:
            self.log.ignored.append((data, str(error)))
            return
        self.log.commands.append(command)
        if command.code == 0xFA:
            self.continuous = 0  # no reply; takes effect from the next cycle
        else:
            self.pending.append(command)

    def _remember(self, t: float, reply: bytes) -> None:
        """When a timed record was really taken (the truth a test compares with)."""
        if lookup(reply[0]).timed:
            sampled = self.sampled
            sampled[int.from_bytes(reply[-4:], "big")] = t
            if len(sampled) > SAMPLED_MAX:
                del sampled[next(iter(sampled))]

    def run_until(self, now: float) -> list[tuple[float, bytes]]:
        """Complete every calculation cycle due by ``now``; return (time, reply) pairs."""
        out: list[tuple[float, bytes]] = []
        if not self.busy:
            self.cycle = max(self.cycle, int((now - self._cycles_from) / self._cycle_period))
            return out  # idle cycles produce nothing: skip them
        while self.next_cycle_time() <= now:
            self.cycle += 1
            t = self._cycles_from + self.cycle * self._cycle_period
            if self.continuous:
                out.append((t, self.record(self.continuous, t)))
                self.log.continuous_sent += 1
            if self.capture_due and self.capture_due[0] <= t:
                out.append((t, self._capture_reply(t)))
            elif self.pending:
                reply = self.execute(self.pending.popleft(), t)
                if reply is not None:
                    out.append((t, reply))
        self.log.records_sent += len(out)
        for t, reply in out:
            self._remember(t, reply)
        return out

    @property
    def busy(self) -> bool:
        """It has a cycle's work to do: switched on, and streaming, answering or
        capturing (idle cycles produce nothing, and are skipped)."""
        return self.powered and bool(self.continuous or self.pending or self.capture_due)

    def execute(self, command: gx2.Command, t: float) -> bytes | None:
        """Act on one command at the end of cycle time ``t``; return its reply record."""
        code, args = command.code, command.arguments
        timer = self.timer_at(t)
        if code == 0xC4:
            wanted = args["continuous_command"]
            if wanted != 0 and wanted not in STREAMABLE:
                return None  # not a record it can stream: the firmware ignores it
            self.continuous = wanted  # type: ignore[assignment]
            return encode(code, continuous_command=self.continuous, timer=timer)
        if code == 0xC9:
            self.accel_bias = args["accel_bias"]  # type: ignore[assignment]
            return encode(code, accel_bias=self.accel_bias, timer=timer)
        if code == 0xCA:
            self.gyro_bias = args["gyro_bias"]  # type: ignore[assignment]
            return encode(code, gyro_bias=self.gyro_bias, timer=timer)
        if code == 0xCD:
            self.capture_due = (t + args["sampling_time"] / 1000, t)  # type: ignore[operator]
            return None
        if code == 0xD0:
            quantity = args["quantity"]
            if quantity not in (1, 2):
                return encode(code, quantity=0xFFFF, timer=timer)
            self.nonvolatile[quantity] = self.accel_bias if quantity == 1 else self.gyro_bias  # type: ignore[index]
            return encode(code, quantity=quantity, timer=timer)
        if code == 0xE4:
            stored = self._write_eeprom(args["address"], args["value"])
            if args["address"] == EEPROM_DIVIDER:
                self._rebase(t)  # the new rate applies from this cycle on
            return encode(code, value=stored)
        if code == 0xE5:
            return encode(code, value=self.eeprom.get(args["address"], 0))  # type: ignore[arg-type]
        if code == 0xE9:
            return encode(code, version=FIRMWARE_VERSION)
        if code == 0xEA:
            if args["selector"] not in (0, 1, 2, 3):
                return None
            return encode(code, selector=args["selector"], text=self._identifier(args["selector"]))
        if code == 0xFB:
            self.test_config = args["test_config"]  # type: ignore[assignment]
            return encode(code, test_config=self.test_config)
        return self.record(code, t)

    def _write_eeprom(self, address: object, value: object) -> int:
        """The reference: the first write after power-up occasionally fails, and the
        reply then shows the word unchanged."""
        assert isinstance(address, int) and isinstance(value, int)
        first, self.wrote_eeprom = not self.wrote_eeprom, True
        if not (first and self.rng.random() < self.first_write_failure_rate):
            self.eeprom[address] = value
        return self.eeprom.get(address, 0)

    def _capture_reply(self, t: float) -> bytes:
        """The capture ends: the gyro bias is what the rate sensors read on average over
        the sampling time, the body's own turning included (it must stand still)."""
        assert self.capture_due is not None
        end, begin = self.capture_due
        self.capture_due = None
        points = [begin + (end - begin) * i / 10 for i in range(11)]
        sensed = [_plus3(self.settings.motion.ang_rate(p), self.settings.gyro_bias_error)
                  for p in points]
        self.gyro_bias = tuple(sum(v[axis] for v in sensed) / len(sensed)
                               for axis in range(3))  # type: ignore[assignment]
        return encode(0xCD, gyro_bias=self.gyro_bias, timer=self.timer_at(t))

    def _identifier(self, selector: object) -> str:
        serial = self.settings.serial or f"4200-{self.address:04d}"[:16]
        return {0: "6220-0001" if self.settings.model == GX2 else "6226-0001",
                1: serial,
                2: "3DM-GX2" if self.settings.model == GX2 else "Inertia-Link",
                3: "Wireless"}[selector]  # type: ignore[index]

    # -- measurements -------------------------------------------------------------------

    def _bit_steps(self) -> tuple[Vector, Vector]:
        """Built-in test steps (accel g, rate rad/s) of each axis: bit 4 steps the
        accelerometers and rate sensors positive, bit 5 the rate sensors negative; a
        faulty output does not step."""
        config = self.test_config
        accel = BIT_STEP if config & 0x10 else 0.0
        rate = BIT_STEP if config & 0x10 else (-BIT_STEP if config & 0x20 else 0.0)
        return (tuple(0.0 if f"accel_{a}" in self.bit_faults else accel for a in "xyz"),  # type: ignore[return-value]
                tuple(0.0 if f"rate_{a}" in self.bit_faults else rate for a in "xyz"))

    def _noise(self, sigma: float) -> Vector:
        if not sigma:
            return (0.0, 0.0, 0.0)
        gauss = self.rng.gauss
        return (gauss(0.0, sigma), gauss(0.0, sigma), gauss(0.0, sigma))

    def record(self, code: int, t: float) -> bytes:
        """The data record ``code`` as measured at the end of the cycle at ``t``."""
        motion, period, timer = self.settings.motion, self.period, self.timer_at(t)
        accel_step, rate_step = self._bit_steps()
        accel = _minus(_plus3(_plus3(motion.accel(t), accel_step),
                              self._noise(self.settings.accel_noise)), self.accel_bias)
        rate = _minus(_plus3(_plus3(_plus3(motion.ang_rate(t), rate_step),
                                    self.settings.gyro_bias_error),
                             self._noise(self.settings.rate_noise)), self.gyro_bias)
        orientation = motion.orientation(t)
        mag = _NAN3 if self.settings.model == INERTIA_LINK else motion.mag(t)
        if code == 0xC1:
            return encode(code, raw_accel=_raw(accel, 6553.6), raw_ang_rate=_raw(rate, 4000.0),
                          timer=timer)
        if code == 0xC2:
            return encode(code, accel=accel, ang_rate=rate, timer=timer)
        if code in (0xC3, 0xD3):
            # the motion's integrals over the cycle, plus what the sensors add (bias,
            # noise, a self-test's step) held over it
            fields = dict(
                delta_angle=_plus3(motion.delta_angle(t, period),
                                   _scale(_minus(rate, motion.ang_rate(t)), period)),
                delta_velocity=_plus3(motion.delta_velocity(t, period),
                                      _scale(_minus(accel, motion.accel(t)), period)))
            if code == 0xD3:
                fields["mag"] = mag
            return encode(code, **fields, timer=timer)
        if code == 0xC5:
            return encode(code, orientation=orientation, timer=timer)
        if code == 0xC6:
            return encode(code, orientation_update=motion.orientation_update(t, period),
                          timer=timer)
        if code == 0xC7:
            return encode(code, mag=mag, timer=timer)
        if code == 0xC8:
            return encode(code, accel=accel, ang_rate=rate, orientation=orientation, timer=timer)
        if code == 0xCB:
            return encode(code, accel=accel, ang_rate=rate, mag=mag, timer=timer)
        if code == 0xCC:
            return encode(code, accel=accel, ang_rate=rate, mag=mag, orientation=orientation,
                          timer=timer)
        if code in (0xCE, 0xCF):
            roll, pitch, yaw = euler_from_matrix(orientation)
            extra = {"ang_rate": rate} if code == 0xCF else {}
            return encode(code, roll=roll, pitch=pitch, yaw=yaw, **extra, timer=timer)
        if code == 0xD1:
            warm = 25.0 + 0.5 * math.sin(t / 60)
            board = accel_code(warm)
            gyro = gyro_code(warm + 3.0, self.settings.gyro)
            return encode(code, temperature=(board, gyro, gyro + 2, gyro - 1), timer=timer)
        if code == 0xD2:
            return encode(code, stab_accel=accel, ang_rate=rate, stab_mag=mag, timer=timer)
        raise ValueError(f"0x{code:02X} is not a data record")


def _minus(a: tuple[float, ...], b: tuple[float, ...]) -> tuple[float, float, float]:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _scale(v: tuple[float, ...], k: float) -> tuple[float, float, float]:
    return (v[0] * k, v[1] * k, v[2] * k)


def _raw(v: tuple[float, ...], codes_per_unit: float) -> tuple[float, float, float]:
    """A/D codes around mid-scale (32768) for a physical value."""
    return (32768 + v[0] * codes_per_unit, 32768 + v[1] * codes_per_unit,
            32768 + v[2] * codes_per_unit)


def _plus3(a: tuple[float, ...], b: tuple[float, ...]) -> tuple[float, float, float]:
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])
