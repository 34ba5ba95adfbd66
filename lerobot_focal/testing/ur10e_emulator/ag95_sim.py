"""A simulated AG-95 behind a real pymodbus server, so the driver is exercised over the wire without hardware.

:class:`AG95Model` is the device: the registers of :mod:`lerobot_focal.robots.ur10e.rtde.ag95`, initialisation that
takes a while, fingers that move toward the commanded position at the commanded speed and stop on an object.
It has no Modbus in it, so the simulated robot can also use it directly.

:class:`AG95ModbusServer` puts the model behind pymodbus' TCP server with RTU framing (the same bytes as on the
RS-485 line, carried over TCP like UR's RS485 URCap does) on its own thread and event loop. It uses pymodbus'
``SimDevice`` datastore (pymodbus >= 3.12) and its ``action`` hook, which runs on every request: writes become
device commands, and the feedback registers are refreshed from the model before each read.
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable

from pymodbus import FramerType
from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from lerobot_focal.robots.ur10e.rtde.ag95 import (
    FORCE_RANGE,
    FULL_INIT_COMMAND,
    INIT_COMMAND,
    POSITION_RANGE,
    SPEED_RANGE,
    GripState,
    InitState,
    Register,
)

_WRITE_FUNCTION_CODES = {5, 6, 15, 16, 22, 23}


class AG95Model:
    """Kinematics-only AG-95. Time comes from ``clock`` so callers may drive it with simulated time."""

    def __init__(
        self,
        full_speed_permille_per_s: float = 5000.0,
        init_duration_s: float = 0.15,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.full_speed = full_speed_permille_per_s
        self.init_duration_s = init_duration_s
        self.clock = clock
        self._lock = threading.Lock()
        self.init_state = InitState.NOT_INITIALIZED
        self.grip_state = GripState.REACHED
        self.position = 0.0
        self.target = 0
        self.force = 20
        self.speed = 50
        self.object_position: int | None = None  # an object between the fingers stops them at this opening
        self._init_done_at: float | None = None
        self._last_t = clock()
        self.writes: list[tuple[int, int]] = []  # (register, value) as received, for tests to inspect

    def place_object(self, opening_permille: int | None) -> None:
        """Put an object of this width between the fingers (``None`` takes it away: a caught object drops)."""
        with self._lock:
            self._advance()
            self.object_position = opening_permille
            if opening_permille is None and self.grip_state == GripState.CAUGHT:
                self.grip_state = GripState.DROPPED

    def write(self, register: int, value: int) -> bool:
        """Apply a register write; False where the real gripper would reject it (unknown register or value)."""
        with self._lock:
            self._advance()
            self.writes.append((register, value))
            if register == Register.INIT:
                if value not in (INIT_COMMAND, FULL_INIT_COMMAND):
                    return False
                self.init_state = InitState.INITIALIZING
                self.grip_state = GripState.MOVING
                self._init_done_at = self.clock() + self.init_duration_s
            elif register == Register.FORCE:
                if not FORCE_RANGE[0] <= value <= FORCE_RANGE[1]:
                    return False
                self.force = value
            elif register == Register.SPEED:
                if not SPEED_RANGE[0] <= value <= SPEED_RANGE[1]:
                    return False
                self.speed = value
            elif register == Register.POSITION:
                if not POSITION_RANGE[0] <= value <= POSITION_RANGE[1]:
                    return False
                self.target = value
                if self.init_state == InitState.INITIALIZED:  # not initialised: the gripper ignores motion
                    self.grip_state = GripState.MOVING
            else:
                return False
            return True

    def read(self, register: int) -> int:
        with self._lock:
            self._advance()
            return {
                Register.INIT: 0,
                Register.FORCE: self.force,
                Register.POSITION: self.target,
                Register.SPEED: self.speed,
                Register.INIT_STATE: int(self.init_state),
                Register.GRIP_STATE: int(self.grip_state),
                Register.POSITION_FEEDBACK: int(round(self.position)),
            }.get(register, 0)

    def _advance(self) -> None:
        now = self.clock()
        dt, self._last_t = max(0.0, now - self._last_t), now
        if self.init_state == InitState.INITIALIZING:
            if now >= self._init_done_at:
                self.init_state = InitState.INITIALIZED
                self.position = self.target = POSITION_RANGE[1]  # initialisation ends fully open
                self.grip_state = GripState.REACHED
            return
        if self.init_state != InitState.INITIALIZED or self.grip_state not in (GripState.MOVING, GripState.DROPPED):
            return
        step = self.full_speed * self.speed / 100.0 * dt
        closing = self.target < self.position
        stop_at = self.target
        blocked = (
            closing
            and self.grip_state == GripState.MOVING
            and self.object_position is not None
            and self.target < self.object_position <= self.position
        )
        if blocked:
            stop_at = self.object_position
        if abs(stop_at - self.position) <= step:
            self.position = float(stop_at)
            if blocked:
                self.grip_state = GripState.CAUGHT
            elif self.grip_state == GripState.MOVING:
                self.grip_state = GripState.REACHED
        else:
            self.position += step if stop_at > self.position else -step


class AG95ModbusServer:
    """Serve an :class:`AG95Model` as Modbus RTU-over-TCP slave ``slave_id`` on ``host`` (port 0: any free one)."""

    def __init__(self, model: AG95Model | None = None, slave_id: int = 1, host: str = "127.0.0.1", port: int = 0):
        self.model = model if model is not None else AG95Model()
        self.slave_id = slave_id
        self.host = host
        self.port = port
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: ModbusTcpServer | None = None
        self._thread: threading.Thread | None = None

    @property
    def url(self) -> str:
        """The value to put in ``AG95Config.port``."""
        return f"tcp://{self.host}:{self.port}"

    def _device(self) -> SimDevice:
        block = [
            SimData(Register.INIT, count=5, values=0, datatype=DataType.REGISTERS),
            SimData(Register.INIT_STATE, count=3, values=0, datatype=DataType.REGISTERS),
        ]
        return SimDevice(id=self.slave_id, simdata=block, action=self._action)

    async def _action(self, function_code, start_address, address, count, registers, values):
        if values is not None and function_code in _WRITE_FUNCTION_CODES:
            for offset, value in enumerate(values):
                if not self.model.write(address + offset, int(value)):
                    return ExcCodes.ILLEGAL_VALUE
        for offset in range(count):
            registers[address - start_address + offset] = self.model.read(address + offset)
        return None

    def start(self) -> AG95ModbusServer:
        started = threading.Event()
        failure: list[BaseException] = []

        async def serve() -> None:
            try:
                self._server = ModbusTcpServer(
                    self._device(), address=(self.host, self.port), framer=FramerType.RTU
                )
                await self._server.serve_forever(background=True)
                self.port = self._server.transport.sockets[0].getsockname()[1]
            except BaseException as e:  # noqa: BLE001 - reported to the starting thread
                failure.append(e)
                started.set()
                return
            started.set()
            await self._server.serving

        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(
            target=self._loop.run_until_complete, args=(serve(),), name="ag95-sim-server", daemon=True
        )
        self._thread.start()
        if not started.wait(5.0):
            raise RuntimeError("simulated AG-95 Modbus server did not start within 5 s")
        if failure:
            raise RuntimeError(
                f"simulated AG-95 Modbus server failed to start on {self.host}:{self.port}"
            ) from failure[0]
        return self

    def stop(self) -> None:
        if self._loop is None or self._server is None:
            return
        asyncio.run_coroutine_threadsafe(self._server.shutdown(), self._loop).result(5.0)
        self._thread.join(5.0)
        self._loop.close()
        self._loop = self._server = self._thread = None

    def __enter__(self) -> AG95ModbusServer:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
