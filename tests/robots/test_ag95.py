"""AG-95 driver against a real pymodbus server (RTU frames over loopback TCP) serving a simulated gripper.

Nothing is mocked: every command goes through pymodbus' client, the RTU framer, a socket, pymodbus' server and
its SimDevice datastore, into :class:`AG95Model`.
"""

from __future__ import annotations

import math
import socket
import threading
import time

import pytest

pytest.importorskip("pymodbus")

from lerobot_focal.robots.ur10e.rtde.ag95 import (  # noqa: E402
    AG95Config,
    AG95Gripper,
    GripperConnectionError,
    GripperError,
    GripperTimeoutError,
    GripState,
    InitState,
    Register,
)
from lerobot_focal.testing.ur10e_emulator.ag95_sim import AG95ModbusServer, AG95Model  # noqa: E402


@pytest.fixture
def server():
    with AG95ModbusServer(AG95Model()) as srv:
        yield srv


def _config(srv: AG95ModbusServer, **kw) -> AG95Config:
    kw.setdefault("timeout_s", 0.3)
    kw.setdefault("init_timeout_s", 3.0)
    return AG95Config(port=srv.url, **kw)


def test_connect_initialises_and_applies_force(server):
    assert server.model.init_state == InitState.NOT_INITIALIZED
    with AG95Gripper(_config(server, force_percent=35)) as gripper:
        status = gripper.read_status()
        assert status.init_state == InitState.INITIALIZED
        assert status.position == 1000  # initialisation ends fully open
        assert (Register.INIT, 1) in server.model.writes
        assert server.model.force == 35
        assert server.model.writes.index((Register.INIT, 1)) < server.model.writes.index((Register.FORCE, 35))
    assert not gripper.is_connected


def test_without_initialisation_motion_is_ignored(server):
    with AG95Gripper(_config(server, initialize_on_connect=False)) as gripper:
        assert gripper.read_status().init_state == InitState.NOT_INITIALIZED
        gripper.set_position(600)
        time.sleep(0.1)
        assert gripper.read_status().position == 0
        gripper.initialize(full=True)
        assert (Register.INIT, 0xA5) in server.model.writes
        assert gripper.read_status().initialized


def test_position_moves_then_reaches(server):
    with AG95Gripper(_config(server, speed_percent=2)) as gripper:  # 2 % of 5000 = 100 per-mille/s
        assert server.model.speed == 2
        gripper.set_position(900)
        time.sleep(0.2)
        moving = gripper.read_status()
        assert moving.grip_state == GripState.MOVING
        assert 900 < moving.position < 1000
        gripper.set_speed(100)
        reached = gripper.wait_until_settled(timeout_s=2.0)
        assert reached.grip_state == GripState.REACHED
        assert reached.position == 900
        assert reached.opening_m == pytest.approx(0.9 * 0.095)


def test_opening_fraction_is_clipped_to_the_stroke(server):
    with AG95Gripper(_config(server)) as gripper:
        assert gripper.set_opening(0.25, wait=True).position == 250
        assert gripper.set_opening(1.7, wait=True).position == 1000
        with pytest.raises(GripperError, match="finite"):
            gripper.set_opening(math.nan)


def test_object_caught_then_dropped(server):
    with AG95Gripper(_config(server)) as gripper:
        server.model.place_object(400)
        status = gripper.set_position(0, wait=True)
        assert status.grip_state == GripState.CAUGHT
        assert status.position == 400
        server.model.place_object(None)
        assert gripper.read_status().grip_state == GripState.DROPPED
        time.sleep(0.2)
        assert gripper.read_status().position == 0


@pytest.mark.parametrize(
    ("method", "value"),
    [("set_force", 10), ("set_force", 101), ("set_force", math.nan), ("set_speed", 0), ("set_position", 1001),
     ("set_position", -1), ("set_position", math.inf), ("set_position", True)],
)
def test_out_of_range_values_are_refused_before_sending(server, method, value):
    with AG95Gripper(_config(server)) as gripper:
        sent = list(server.model.writes)
        with pytest.raises(GripperError, match="AG-95"):
            getattr(gripper, method)(value)
        assert server.model.writes == sent


def test_rejection_by_the_device_is_a_clear_error(server):
    with AG95Gripper(_config(server)) as gripper:
        with pytest.raises(GripperError, match=r"refused .*exception code 3"):
            gripper._write(Register.POSITION, 5000)  # bypasses the driver's own range check


def test_wrong_slave_id_fails_at_connect_naming_the_slave(server):
    gripper = AG95Gripper(_config(server, slave_id=7))
    with pytest.raises(GripperError, match=r"slave 7"):
        gripper.connect()
    assert not gripper.is_connected


def _silent_listener() -> tuple[socket.socket, threading.Event]:
    """A TCP peer that accepts and reads but never answers, like a gripper on the wrong baud rate."""
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    sock.listen()
    done = threading.Event()

    def swallow() -> None:
        conn, _ = sock.accept()
        conn.settimeout(0.05)
        while not done.is_set():
            try:
                if conn.recv(256) == b"":
                    break
            except TimeoutError:
                continue
            except OSError:
                break
        conn.close()

    threading.Thread(target=swallow, daemon=True).start()
    return sock, done


def test_gripper_that_never_answers_times_out_with_a_clear_error():
    sock, done = _silent_listener()
    port = sock.getsockname()[1]
    gripper = AG95Gripper(AG95Config(port=f"tcp://127.0.0.1:{port}", timeout_s=0.2, retries=1))
    t0 = time.monotonic()
    try:
        with pytest.raises(GripperTimeoutError) as err:
            gripper.connect()
    finally:
        done.set()
        sock.close()
    assert time.monotonic() - t0 < 3.0
    message = str(err.value)
    assert f"127.0.0.1:{port}" in message and "slave 1" in message and "did not answer" in message
    assert isinstance(err.value, TimeoutError)
    assert not gripper.is_connected


def test_server_stopped_mid_session_raises(server):
    gripper = AG95Gripper(_config(server, retries=0))
    gripper.connect()
    server.stop()
    with pytest.raises(GripperError, match=server.url.removeprefix("tcp://")):
        gripper.read_status()
    gripper.disconnect()


def test_nothing_listening_is_a_connection_error():
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    port = sock.getsockname()[1]
    sock.close()
    with pytest.raises(GripperConnectionError, match="could not open the port"):
        AG95Gripper(AG95Config(port=f"tcp://127.0.0.1:{port}", timeout_s=0.2)).connect()


def test_missing_serial_port_is_a_connection_error():
    with pytest.raises(GripperConnectionError, match=r"/dev/ttyDOESNOTEXIST.*baud"):
        AG95Gripper(AG95Config(port="/dev/ttyDOESNOTEXIST", timeout_s=0.2)).connect()


def test_initialisation_that_never_finishes_times_out():
    with AG95ModbusServer(AG95Model(init_duration_s=30.0)) as srv:
        gripper = AG95Gripper(_config(srv, init_timeout_s=0.3))
        with pytest.raises(GripperTimeoutError, match="did not finish initialising"):
            gripper.connect()
        assert not gripper.is_connected


def test_commands_before_connect_say_so():
    with pytest.raises(GripperError, match="not connected"):
        AG95Gripper(AG95Config(port="tcp://127.0.0.1:1")).read_status()


def test_malformed_tcp_port_is_rejected():
    with pytest.raises(ValueError, match="tcp://<host>:<port>"):
        AG95Gripper(AG95Config(port="tcp://localhost")).connect()
