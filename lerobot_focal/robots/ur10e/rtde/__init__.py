"""The real UR-10e (`--robot.backend=rtde`): ur_rtde in a child process, the session that drives it, the AG-95.

`rtde_backend` is the backend the robot builds; `rtde_session` runs ur_rtde's client in `ur_rtde_child` (a
separate process) and `ag95` drives the gripper over Modbus RTU. Nothing here is imported when the plugin
registers the robot: ur_rtde and pymodbus load when the backend connects.
"""
