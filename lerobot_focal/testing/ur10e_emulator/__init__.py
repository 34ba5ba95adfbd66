"""An emulated UR-10e controller and a simulated AG-95 gripper: a test harness that also runs from the CLI.

The tests drive the robot's real `rtde` backend (ur_rtde's own client) against this emulator, with the MuJoCo
twin as the arm behind it, and the AG-95 driver against :mod:`.ag95_sim` over Modbus. It is not part of the
robot: `--robot.type=ur10e` never imports it. Standalone::

    python -m lerobot_focal.testing.ur10e_emulator.rtde_emulator --host 127.0.0.1 --version 5.15.0.0

then point the robot at it with ``--robot.backend=rtde --robot.robot_ip=127.0.0.1`` (docs/robot.md).

Modules: :mod:`.rtde_emulator` (the whole controller, in a child process, with fault hooks and the CLI),
:mod:`.controller_servers` (RTDE, dashboard and script-port servers), :mod:`.emulated_controller` (robot / safety /
runtime state, dashboard answers), :mod:`.control_script` (ur_rtde's control script as a register state machine),
:mod:`.rtde_protocol` (the wire format), :mod:`.ag95_sim` (the gripper behind a pymodbus server).
"""
