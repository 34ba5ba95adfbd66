"""RTDE wire format (protocol version 2, port 30004) as a UR controller speaks it: framing, types, recipes.

Only what a controller-side server needs: package types, the type of each variable name a client may ask
for, and packing/unpacking of one recipe's data package. Kept free of sockets and of the arm so the server,
the emulated controller and tests share one definition of the wire.
"""

from __future__ import annotations

import re
import socket
import struct
import threading
from dataclasses import dataclass, field

# Package types (ASCII codes).
REQUEST_PROTOCOL_VERSION = ord("V")
GET_URCONTROL_VERSION = ord("v")
TEXT_MESSAGE = ord("M")
DATA_PACKAGE = ord("U")
SETUP_OUTPUTS = ord("O")
SETUP_INPUTS = ord("I")
START = ord("S")
PAUSE = ord("P")

NOT_FOUND = "NOT_FOUND"
IN_USE = "IN_USE"

# RTDE type name -> (struct format, number of values).
TYPE_FORMATS: dict[str, tuple[str, int]] = {
    "BOOL": ("?", 1),
    "UINT8": ("B", 1),
    "UINT32": ("I", 1),
    "UINT64": ("Q", 1),
    "INT32": ("i", 1),
    "DOUBLE": ("d", 1),
    "VECTOR3D": ("3d", 3),
    "VECTOR6D": ("6d", 6),
    "VECTOR6INT32": ("6i", 6),
    "VECTOR6UINT32": ("6I", 6),
}

# Output variables of an e-Series controller (UR's RTDE guide), by type.
OUTPUT_TYPES: dict[str, str] = {
    **dict.fromkeys(
        [
            "timestamp", "actual_execution_time", "speed_scaling", "target_speed_fraction", "actual_momentum",
            "actual_main_voltage", "actual_robot_voltage", "actual_robot_current", "standard_analog_input0",
            "standard_analog_input1", "standard_analog_output0", "standard_analog_output1", "io_current",
            "tool_analog_input0", "tool_analog_input1", "tool_output_current", "tool_temperature",
            "tcp_force_scalar", "payload", "joint_position_deviation_ratio", "collision_detection_ratio",
            "actual_robot_energy_consumed", "actual_robot_braking_energy_dissipated",
        ],
        "DOUBLE",
    ),
    **dict.fromkeys(
        [
            "target_q", "target_qd", "target_qdd", "target_current", "target_moment", "actual_q", "actual_qd",
            "actual_current", "actual_current_window", "joint_control_output", "actual_TCP_pose",
            "actual_TCP_speed", "actual_TCP_force", "target_TCP_pose", "target_TCP_speed", "joint_temperatures",
            "actual_joint_voltage", "payload_inertia", "ft_raw_wrench", "actual_current_as_torque",
        ],
        "VECTOR6D",
    ),
    **dict.fromkeys(["actual_tool_accelerometer", "elbow_position", "elbow_velocity", "payload_cog"], "VECTOR3D"),
    **dict.fromkeys(["actual_digital_input_bits", "actual_digital_output_bits"], "UINT64"),
    **dict.fromkeys(
        [
            "runtime_state", "robot_status_bits", "safety_status_bits", "analog_io_types", "tool_mode",
            "tool_analog_input_types", "output_bit_registers0_to_31", "output_bit_registers32_to_63",
            "input_bit_registers0_to_31", "input_bit_registers32_to_63", "script_control_line",
        ],
        "UINT32",
    ),
    **dict.fromkeys(["robot_mode", "safety_mode", "safety_status", "tool_output_voltage"], "INT32"),
    "joint_mode": "VECTOR6INT32",
    **dict.fromkeys(["tool_output_mode", "tool_digital_output0_mode", "tool_digital_output1_mode"], "UINT8"),
}

# Input variables a client may write, by type.
INPUT_TYPES: dict[str, str] = {
    **dict.fromkeys(
        [
            "speed_slider_mask", "standard_digital_output_mask", "standard_digital_output",
            "configurable_digital_output_mask", "configurable_digital_output", "tool_digital_output_mask",
            "tool_digital_output", "standard_analog_output_mask", "standard_analog_output_type",
            "input_bit_registers0_to_31", "input_bit_registers32_to_63",
        ],
        "UINT32",
    ),
    **dict.fromkeys(["speed_slider_fraction", "standard_analog_output_0", "standard_analog_output_1"], "DOUBLE"),
}
_REGISTER = re.compile(r"^(input|output)_(int|double|bit)_register_(\d+)$")


def variable_type(name: str, inputs: bool) -> str:
    """RTDE type of variable `name` in an input (client writes) or output (controller sends) recipe."""
    m = _REGISTER.match(name)
    if m:
        direction, kind, index = m.group(1), m.group(2), int(m.group(3))
        if kind == "bit":
            return "BOOL" if 64 <= index <= 127 else NOT_FOUND
        if index > 47 or (inputs and direction != "input"):
            return NOT_FOUND
        return "INT32" if kind == "int" else "DOUBLE"
    return (INPUT_TYPES if inputs else OUTPUT_TYPES).get(name, NOT_FOUND)


@dataclass
class Recipe:
    """One output or input recipe: names, their types, and the struct format of its data package body."""

    recipe_id: int
    names: list[str]
    types: list[str]
    fmt: str = field(init=False)

    def __post_init__(self) -> None:
        self.fmt = ">" + "".join(TYPE_FORMATS[t][0] for t in self.types if t in TYPE_FORMATS)

    @property
    def valid(self) -> bool:
        return all(t in TYPE_FORMATS for t in self.types)

    def unpack(self, body: bytes) -> dict[str, object]:
        """{name: value or list of values} from a data package body (after the recipe id byte)."""
        flat = iter(struct.unpack(self.fmt, body))
        out: dict[str, object] = {}
        for name, rtype in zip(self.names, self.types, strict=True):
            n = TYPE_FORMATS[rtype][1]
            vals = [next(flat) for _ in range(n)]
            out[name] = vals if n > 1 else vals[0]
        return out

    def pack(self, values: dict[str, object]) -> bytes:
        """Data package body for this recipe; variables missing from `values` are sent as zeros."""
        flat: list = []
        for name, rtype in zip(self.names, self.types, strict=True):
            n = TYPE_FORMATS[rtype][1]
            v = values.get(name)
            if v is None:
                v = [0] * n if n > 1 else (False if rtype == "BOOL" else 0)
            flat.extend(list(v) if n > 1 else [v])
        return struct.pack(">B", self.recipe_id) + struct.pack(self.fmt, *flat)


def recv_exact(conn: socket.socket, n: int) -> bytes:
    buf = b""
    while len(buf) < n:
        chunk = conn.recv(n - len(buf))
        if not chunk:
            raise ConnectionError("peer closed the connection")
        buf += chunk
    return buf


def read_package(conn: socket.socket) -> tuple[int, bytes]:
    """(package type, payload) of the next package: uint16 size (header included) + uint8 type, big-endian."""
    size, ptype = struct.unpack(">HB", recv_exact(conn, 3))
    return ptype, recv_exact(conn, size - 3)


def send_package(conn: socket.socket, ptype: int, payload: bytes, lock: threading.Lock) -> None:
    with lock:
        conn.sendall(struct.pack(">HB", 3 + len(payload), ptype) + payload)
