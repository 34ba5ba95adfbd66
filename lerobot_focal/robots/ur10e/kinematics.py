"""UR-10e kinematic constants and pose conventions shared by both backends.

Everything here is pure numpy/scipy so the real-arm path never needs MuJoCo. The numbers are UR's published
values for the e-Series UR10e (DH table and joint limits from UR's "DH parameters" support article and the
`ur_description` joint_limits.yaml); keeping them in one place means the simulated twin and the safety limits
cannot drift apart.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

# Standard DH parameters of the UR10e (metres, radians): T_i = Rz(q_i) Tz(d_i) Tx(a_i) Rx(alpha_i).
DH_D = (0.1807, 0.0, 0.0, 0.17415, 0.11985, 0.11655)
DH_A = (0.0, -0.6127, -0.57155, 0.0, 0.0, 0.0)
DH_ALPHA = (np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0)

JOINT_NAMES = ("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3")
# Position limits: every joint is +-360 deg except the elbow (+-180 deg, self-collision).
JOINT_LIMITS = tuple((-np.pi, np.pi) if n == "elbow" else (-2 * np.pi, 2 * np.pi) for n in JOINT_NAMES)
# Maximum joint speeds (rad/s): 120 deg/s for the two big joints, 180 deg/s for the others.
JOINT_MAX_SPEED = (2.0944, 2.0944, 3.1416, 3.1416, 3.1416, 3.1416)
# Link masses (kg) from UR's published dynamics parameters, used only to make the simulation plausible.
LINK_MASS = (7.369, 13.051, 3.989, 2.1, 1.98, 0.615)

# A "ready" configuration: tool pointing down, TCP ~0.4 m above the table at x = -0.6 m, yaw 0.
HOME_Q = (0.0, -1.7, 1.9, -np.pi / 2 + 1.7 - 1.9, -np.pi / 2, np.pi / 2)

AG95_MAX_OPENING_M = 0.095

# Orientation convention for observations and absolute actions: angles are measured relative to the
# tool-pointing-down orientation (flange z along base -z). Raw UR rotation vectors / RPY of a tool pointing
# down sit at +-pi, where they wrap; relative to TOOL_DOWN they sit near zero, which keeps recorded
# trajectories continuous for learning.
TOOL_DOWN = Rotation.from_euler("x", np.pi)


def dh_forward(q: np.ndarray, tcp_offset: float = 0.0) -> np.ndarray:
    """4x4 base->TCP transform from the DH table (used to cross-check the MJCF model)."""
    t = np.eye(4)
    for i in range(6):
        ct, st = np.cos(q[i]), np.sin(q[i])
        ca, sa = np.cos(DH_ALPHA[i]), np.sin(DH_ALPHA[i])
        ti = np.array(
            [
                [ct, -st * ca, st * sa, DH_A[i] * ct],
                [st, ct * ca, -ct * sa, DH_A[i] * st],
                [0.0, sa, ca, DH_D[i]],
                [0.0, 0.0, 0.0, 1.0],
            ]
        )
        t = t @ ti
    tool = np.eye(4)
    tool[2, 3] = tcp_offset
    return t @ tool


def pose6_from_matrix(pos: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """(x, y, z, roll, pitch, yaw) with angles relative to TOOL_DOWN (extrinsic xyz = fixed-axis RPY)."""
    rel = Rotation.from_matrix(rot) * TOOL_DOWN.inv()
    return np.concatenate([np.asarray(pos, dtype=float), rel.as_euler("xyz")])


def matrix_from_pose6(pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`pose6_from_matrix`: returns (position, 3x3 rotation)."""
    rot = Rotation.from_euler("xyz", pose[3:6]) * TOOL_DOWN
    return np.asarray(pose[:3], dtype=float), rot.as_matrix()


def rotvec_pose_from_pose6(pose: np.ndarray) -> list[float]:
    """Pose in UR's native [x, y, z, rx, ry, rz] (rotation vector) for servoL."""
    pos, rot = matrix_from_pose6(pose)
    return [*pos.tolist(), *Rotation.from_matrix(rot).as_rotvec().tolist()]


def pose6_from_rotvec_pose(ur_pose: list[float] | np.ndarray) -> np.ndarray:
    """Convert UR's getActualTCPPose() [x, y, z, rx, ry, rz] into our pose6 convention."""
    ur_pose = np.asarray(ur_pose, dtype=float)
    return pose6_from_matrix(ur_pose[:3], Rotation.from_rotvec(ur_pose[3:6]).as_matrix())


def apply_delta(pose: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """Compose a gamepad-style delta with a pose.

    Translation is added in the base frame; the rotation delta (droll, dpitch, dyaw) is a rotation about the
    base axes through the TCP, applied on the left. Base-frame deltas keep "stick right = tool moves right"
    regardless of the wrist orientation, which is what an operator expects from a gamepad.
    """
    pos, rot = matrix_from_pose6(pose)
    new_rot = Rotation.from_euler("xyz", delta[3:6]) * Rotation.from_matrix(rot)
    return pose6_from_matrix(pos + delta[:3], new_rot.as_matrix())


def pose_difference(target: np.ndarray, current: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(translation delta, rotation-vector delta) such that apply_delta-like composition maps current->target."""
    p_t, r_t = matrix_from_pose6(target)
    p_c, r_c = matrix_from_pose6(current)
    drot = Rotation.from_matrix(r_t) * Rotation.from_matrix(r_c).inv()
    return p_t - p_c, drot.as_rotvec()
