"""The MuJoCo twin of the UR-10e work cell (`--robot.backend=sim`): `sim_backend`, its `scene` and `sim_camera`.

MuJoCo is imported when the backend is built, never when the plugin registers the robot.
"""
