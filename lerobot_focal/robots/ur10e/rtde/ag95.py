"""DH-Robotics AG-95 adaptive gripper over Modbus RTU.

The AG-95 is driven by a handful of 16-bit holding registers. Every command is a single-register write
(function 0x06) and every status read is a holding-register read (function 0x03); the gripper answers as a
Modbus RTU slave, factory default slave id 1, 115200 baud, 8 data bits, no parity, 1 stop bit.

Register map (DH-Robotics AG/PGE-series "Modbus-RTU control" manual; the AG-95 shares it):

======  =====================  ====  =========================================================================
Addr    Name                   R/W   Values
======  =====================  ====  =========================================================================
0x0100  initialise             W     1 = initialise (find the stroke ends); 0xA5 = full re-calibration
0x0101  force                  R/W   20..100 (% of maximum grip force)
0x0103  position               R/W   0..1000 (per-mille of the stroke; 0 = fully closed, 1000 = fully open)
0x0104  speed                  R/W   1..100 (% of maximum speed)
0x0200  initialisation state   R     0 = not initialised, 1 = initialised, 2 = initialising
0x0201  grip state             R     0 = moving, 1 = reached target (no object), 2 = object caught,
                                     3 = object dropped
0x0202  position feedback      R     0..1000, same scale as 0x0103
======  =====================  ====  =========================================================================

0x0300.. (save to flash, slave id, baud rate, parity) are configuration registers this driver never writes:
changing them by accident would make the gripper stop answering on the settings the robot config names.

The gripper ignores motion commands until it has been initialised, which is why :meth:`AG95Gripper.connect`
initialises by default and waits for state 1.

Transport: on the real robot the RS-485 line is a serial port (a USB adaptor, ``/dev/ttyUSB0``; or the UR
e-series tool connector through the tool-communication serial device). UR's "RS485" URCap also forwards the
tool connector's RS-485 to a TCP socket on the controller (port 54321) as raw bytes, i.e. RTU frames over TCP;
``port="tcp://<host>:<port>"`` selects that transport, which is also what the loopback tests use.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass
from enum import IntEnum

from pymodbus import FramerType
from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException

logger = logging.getLogger(__name__)

AG95_STROKE_M = 0.095
"""Full opening of the AG-95 between the fingertips, in metres (the "95" in the name)."""


class Register(IntEnum):
    INIT = 0x0100
    FORCE = 0x0101
    POSITION = 0x0103
    SPEED = 0x0104
    INIT_STATE = 0x0200
    GRIP_STATE = 0x0201
    POSITION_FEEDBACK = 0x0202


INIT_COMMAND = 0x01
FULL_INIT_COMMAND = 0xA5
POSITION_RANGE = (0, 1000)
FORCE_RANGE = (20, 100)
SPEED_RANGE = (1, 100)


class InitState(IntEnum):
    NOT_INITIALIZED = 0
    INITIALIZED = 1
    INITIALIZING = 2


class GripState(IntEnum):
    MOVING = 0
    REACHED = 1
    CAUGHT = 2
    DROPPED = 3


class GripperError(RuntimeError):
    """The gripper answered wrongly, refused a command, or a value was out of its range."""


class GripperConnectionError(GripperError):
    """The port could not be opened (wrong device path / host, adaptor unplugged, permissions)."""


class GripperTimeoutError(GripperError, TimeoutError):
    """The gripper did not answer in time, or did not reach the awaited state in time."""


@dataclass
class AG95Config:
    """Where the gripper is and how patient to be with it.

    ``port`` is a serial device (``/dev/ttyUSB0``, ``/dev/ttyTool``) or ``tcp://host:port`` for RTU frames over
    TCP (UR RS485 URCap, or a test server). The serial settings must match what is stored in the gripper
    (factory: 115200 8N1, slave 1).
    """

    port: str = "/dev/ttyUSB0"
    slave_id: int = 1
    baudrate: int = 115200
    parity: str = "N"
    stopbits: int = 1
    # One Modbus transaction. At 115200 baud a round trip is a few ms; 0.3 s absorbs USB-adaptor latency.
    timeout_s: float = 0.3
    # Retries per transaction before declaring the gripper silent: one retry rides over a single CRC error.
    retries: int = 1
    # The AG-95's initialisation sweeps the whole stroke twice; a few seconds on the real device.
    init_timeout_s: float = 10.0
    # Initialise on connect (the gripper ignores motion commands until it is initialised).
    initialize_on_connect: bool = True
    force_percent: int = 50
    speed_percent: int | None = None


@dataclass(frozen=True)
class AG95Status:
    init_state: InitState
    grip_state: GripState
    position: int  # per-mille of the stroke, 0 = closed

    @property
    def initialized(self) -> bool:
        return self.init_state == InitState.INITIALIZED

    @property
    def opening_m(self) -> float:
        return self.position / POSITION_RANGE[1] * AG95_STROKE_M

    @property
    def settled(self) -> bool:
        return self.grip_state != GripState.MOVING


def _parse_tcp(port: str) -> tuple[str, int]:
    rest = port.removeprefix("tcp://")
    host, sep, tcp_port = rest.rpartition(":")
    if not sep or not host or not tcp_port.isdigit():
        raise ValueError(f"AG-95 port {port!r}: expected 'tcp://<host>:<port>' or a serial device path")
    return host, int(tcp_port)


def make_modbus_client(config: AG95Config) -> ModbusTcpClient | ModbusSerialClient:
    """A synchronous pymodbus client with RTU framing on the transport that ``config.port`` names."""
    if config.port.startswith("tcp://"):
        host, tcp_port = _parse_tcp(config.port)
        return ModbusTcpClient(
            host, port=tcp_port, framer=FramerType.RTU, timeout=config.timeout_s, retries=config.retries
        )
    return ModbusSerialClient(
        port=config.port,
        framer=FramerType.RTU,
        baudrate=config.baudrate,
        bytesize=8,
        parity=config.parity,
        stopbits=config.stopbits,
        timeout=config.timeout_s,
        retries=config.retries,
    )


def _check_int(name: str, value: float, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise GripperError(f"AG-95 {name} must be a finite number in [{lo}, {hi}], got {value!r}")
    if not lo <= value <= hi:
        raise GripperError(f"AG-95 {name} {value} is outside [{lo}, {hi}]")
    return int(round(value))


class AG95Gripper:
    """Blocking driver; safe to share between threads (one Modbus transaction at a time)."""

    def __init__(self, config: AG95Config):
        self.config = config
        self._client: ModbusTcpClient | ModbusSerialClient | None = None
        self._lock = threading.Lock()

    # ---------------------------------------------------------------- connection
    @property
    def where(self) -> str:
        return f"AG-95 on {self.config.port} (slave {self.config.slave_id})"

    def _hint(self) -> str:
        if self.config.port.startswith("tcp://"):
            return (
                "check that the RS-485 bridge / UR RS485 URCap is running on that host and port, that the "
                "gripper is powered, and that slave_id matches the gripper"
            )
        return (
            f"check power to the gripper, the RS-485 A/B wiring, that the gripper is set to "
            f"{self.config.baudrate} baud 8{self.config.parity}{self.config.stopbits} and slave_id "
            f"{self.config.slave_id}, and that no other program holds the port"
        )

    @property
    def is_connected(self) -> bool:
        return self._client is not None and self._client.connected

    def connect(self) -> None:
        """Open the port and prove the gripper answers; initialise it and apply force/speed if configured."""
        if self._client is not None:
            raise GripperError(f"{self.where} is already connected")
        client = make_modbus_client(self.config)
        if not client.connect():
            client.close()
            raise GripperConnectionError(f"{self.where}: could not open the port; {self._hint()}")
        self._client = client
        try:
            status = self.read_status()  # fails fast with GripperTimeoutError if nobody answers
            if self.config.initialize_on_connect and not status.initialized:
                self.initialize()
            self.set_force(self.config.force_percent)
            if self.config.speed_percent is not None:
                self.set_speed(self.config.speed_percent)
        except BaseException:
            self.disconnect()
            raise

    def disconnect(self) -> None:
        client, self._client = self._client, None
        if client is not None:
            client.close()

    def __enter__(self) -> AG95Gripper:
        self.connect()
        return self

    def __exit__(self, *exc) -> None:
        self.disconnect()

    # ---------------------------------------------------------------- transactions
    def _require_client(self) -> ModbusTcpClient | ModbusSerialClient:
        if self._client is None:
            raise GripperError(f"{self.where} is not connected; call connect() first")
        return self._client

    def _transact(self, what: str, call):
        client = self._require_client()
        with self._lock:
            try:
                response = call(client)
            except ConnectionException as e:
                raise GripperConnectionError(
                    f"{self.where}: connection lost while trying to {what}; {self._hint()}"
                ) from e
            except ModbusIOException as e:
                raise GripperTimeoutError(
                    f"{self.where} did not answer ({what}) within {self.config.timeout_s}s "
                    f"x {self.config.retries + 1} tries; {self._hint()}"
                ) from e
            except ModbusException as e:
                raise GripperError(f"{self.where}: Modbus error while trying to {what}: {e}") from e
        if response.isError():
            code = getattr(response, "exception_code", None)
            raise GripperError(
                f"{self.where} refused to {what} (Modbus exception code {code}); "
                f"the slave answered but rejected the request: is this device an AG-95 and slave_id right?"
            )
        return response

    def _write(self, register: Register, value: int) -> None:
        self._transact(
            f"write {value} to {register.name} (0x{register.value:04X})",
            lambda c: c.write_register(register.value, value, device_id=self.config.slave_id),
        )

    def _read(self, register: Register, count: int) -> list[int]:
        response = self._transact(
            f"read {count} register(s) from {register.name} (0x{register.value:04X})",
            lambda c: c.read_holding_registers(register.value, count=count, device_id=self.config.slave_id),
        )
        if len(response.registers) < count:
            raise GripperError(f"{self.where}: short read from 0x{register.value:04X}: {response.registers}")
        return list(response.registers[:count])

    # ---------------------------------------------------------------- commands
    def initialize(self, full: bool = False, wait: bool = True, timeout_s: float | None = None) -> None:
        """Start initialisation (``full`` re-calibrates the stroke) and, by default, wait until it is done."""
        self._write(Register.INIT, FULL_INIT_COMMAND if full else INIT_COMMAND)
        if not wait:
            return
        timeout_s = self.config.init_timeout_s if timeout_s is None else timeout_s
        # The state register may still read "initialised" from before for a moment, so require that the gripper
        # either was seen initialising or has been given a short grace period.
        deadline = time.monotonic() + timeout_s
        seen_initializing = False
        grace_until = time.monotonic() + min(0.2, timeout_s / 2)
        while True:
            state = self.read_init_state()
            if state == InitState.INITIALIZING:
                seen_initializing = True
            elif state == InitState.INITIALIZED and (seen_initializing or time.monotonic() >= grace_until):
                return
            if time.monotonic() >= deadline:
                raise GripperTimeoutError(
                    f"{self.where} did not finish initialising within {timeout_s}s (last state {state.name}); "
                    "check that nothing blocks the fingers and that the gripper is not in a fault state "
                    "(power-cycle it)"
                )
            time.sleep(0.02)

    def set_force(self, percent: float) -> None:
        self._write(Register.FORCE, _check_int("force (%)", percent, *FORCE_RANGE))

    def set_speed(self, percent: float) -> None:
        self._write(Register.SPEED, _check_int("speed (%)", percent, *SPEED_RANGE))

    def set_position(self, permille: float, wait: bool = False, timeout_s: float = 5.0) -> AG95Status | None:
        """Command an opening in per-mille of the stroke (0 closed .. 1000 open); ``wait`` blocks until settled."""
        self._write(Register.POSITION, _check_int("position (per-mille)", permille, *POSITION_RANGE))
        return self.wait_until_settled(timeout_s) if wait else None

    def set_opening(self, fraction: float, wait: bool = False, timeout_s: float = 5.0) -> AG95Status | None:
        """Same as :meth:`set_position` with the opening as a fraction in [0, 1] (what policies output)."""
        if not isinstance(fraction, (int, float)) or not math.isfinite(fraction):
            raise GripperError(f"AG-95 opening must be a finite fraction in [0, 1], got {fraction!r}")
        return self.set_position(min(max(fraction, 0.0), 1.0) * POSITION_RANGE[1], wait=wait, timeout_s=timeout_s)

    # ---------------------------------------------------------------- status
    def read_init_state(self) -> InitState:
        return self._decode(InitState, self._read(Register.INIT_STATE, 1)[0], "initialisation state")

    def read_status(self) -> AG95Status:
        """Initialisation state, grip state and position feedback in one Modbus transaction."""
        init, grip, position = self._read(Register.INIT_STATE, 3)
        return AG95Status(
            init_state=self._decode(InitState, init, "initialisation state"),
            grip_state=self._decode(GripState, grip, "grip state"),
            position=position,
        )

    def wait_until_settled(self, timeout_s: float = 5.0, poll_s: float = 0.02) -> AG95Status:
        """Poll until the fingers stop (target reached, object caught, or object dropped)."""
        deadline = time.monotonic() + timeout_s
        # A fresh position command may not have flipped the grip state to "moving" yet on the first poll.
        time.sleep(poll_s)
        while True:
            status = self.read_status()
            if status.settled:
                return status
            if time.monotonic() >= deadline:
                raise GripperTimeoutError(
                    f"{self.where} still moving after {timeout_s}s (position {status.position}/1000)"
                )
            time.sleep(poll_s)

    def _decode(self, enum: type[IntEnum], value: int, what: str):
        try:
            return enum(value)
        except ValueError:
            raise GripperError(
                f"{self.where} reported an unknown {what} {value}; is this device an AG-95 (or a PGE/AG series "
                "gripper with the same register map)?"
            ) from None
