"""MJCF builder for the simulated UR-10e work cell (arm + stand-in gripper + table + objects + camera).

The model is generated from the DH table in :mod:`lerobot_focal.robots.ur10e.kinematics` instead of shipping
UR's meshes: nothing is downloaded, the kinematics match the real controller exactly (checked against
:func:`dh_forward` in the tests), and the geometry is made of primitives, which is all a ray-cast depth camera
needs.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..kinematics import (
    AG95_MAX_OPENING_M,
    DH_A,
    DH_ALPHA,
    DH_D,
    JOINT_LIMITS,
    JOINT_NAMES,
    LINK_MASS,
)

#: The twin's workspace box for point clouds (base frame, metres; lower corner, upper corner): the table top in
#: front of the arm and what stands on it, from 3 mm above the table surface (so the table itself is cropped
#: away, as DP3 crops it) to 0.8 m. A focal trained on the twin's depth takes it as
#: --policy.depth_cloud.crop_min / --policy.depth_cloud.crop_max (the policy's checkpoint then holds it).
TABLE_TOP_BOX: tuple[tuple[float, float, float], tuple[float, float, float]] = ((-1.1, -0.7, 0.003), (-0.2, 0.4, 0.8))


def crop_flags(box: tuple[tuple[float, ...], tuple[float, ...]] = TABLE_TOP_BOX) -> tuple[str, str]:
    """`lerobot-train` flags that give a focal trained on depth this crop box."""
    lo, hi = (",".join(f"{v:g}" for v in corner) for corner in box)
    return f"--policy.depth_cloud.crop_min=[{lo}]", f"--policy.depth_cloud.crop_max=[{hi}]"


# Position-servo stiffness per joint (N m / rad); gravity is compensated so these only shape tracking.
_KP = (4000.0, 4000.0, 2500.0, 600.0, 600.0, 400.0)
_TORQUE = (330.0, 330.0, 150.0, 56.0, 56.0, 56.0)


@dataclass
class SceneObject:
    """A free object on the table; `kind` is "box" (size = half extents) or "cylinder" (radius, half height)."""

    name: str
    kind: str
    size: tuple[float, ...]
    pos: tuple[float, float]
    rgba: tuple[float, float, float, float]
    mass: float = 0.1


@dataclass
class SceneSpec:
    tcp_offset: float = 0.16
    camera_pos: tuple[float, float, float] = (-1.45, -0.15, 0.75)
    camera_lookat: tuple[float, float, float] = (-0.6, -0.15, 0.0)
    camera_fovy_deg: float = 58.0
    table_height: float = 0.0
    objects: list[SceneObject] = field(
        default_factory=lambda: [
            SceneObject("red_cube", "box", (0.02, 0.02, 0.02), (-0.65, -0.05), (0.85, 0.15, 0.15, 1.0)),
            SceneObject("green_cylinder", "cylinder", (0.025, 0.04), (-0.55, -0.32), (0.2, 0.75, 0.25, 1.0)),
        ]
    )


def _fmt(v) -> str:
    return " ".join(f"{float(x):.6g}" for x in np.atleast_1d(v))


def _camera_xyaxes(pos: np.ndarray, lookat: np.ndarray) -> np.ndarray:
    """MuJoCo cameras look along their -z with +y up; build those axes from a look-at point."""
    fwd = lookat - pos
    fwd /= np.linalg.norm(fwd)
    x = np.cross(fwd, np.array([0.0, 0.0, 1.0]))
    x /= np.linalg.norm(x)
    y = np.cross(x, fwd)
    return np.concatenate([x, y])


def _link_xml(i: int) -> tuple[str, str]:
    """Opening and closing tags for link i (its joint, inertia and visual capsule toward the next frame)."""
    name = JOINT_NAMES[i]
    lo, hi = JOINT_LIMITS[i]
    child_pos = np.array([DH_A[i], 0.0, DH_D[i]])
    length = float(np.linalg.norm(child_pos))
    radius = 0.075 if i < 3 else 0.05
    mass = LINK_MASS[i]
    com = child_pos / 2
    inertia = max(mass * (length**2 + 3 * radius**2) / 12, 1e-3)
    geoms = f'<geom type="cylinder" size="{radius} {radius}" rgba="0.25 0.3 0.38 1" class="arm"/>'
    if length > 1e-9:
        geoms += (
            f'<geom type="capsule" fromto="0 0 0 {_fmt(child_pos)}" size="{radius * 0.8:.4g}"'
            ' rgba="0.7 0.72 0.75 1" class="arm"/>'
        )
    opening = (
        f'<body name="{name}_link" gravcomp="1">'
        f'<joint name="{name}" axis="0 0 1" range="{lo:.6g} {hi:.6g}" armature="0.2" damping="2"/>'
        f'<inertial pos="{_fmt(com)}" mass="{mass}" diaginertia="{_fmt([inertia] * 3)}"/>'
        f"{geoms}"
    )
    return opening, "</body>"


def _child_frame_attrs(i: int) -> str:
    """Placement of frame i+1 inside link i: Tz(d) Tx(a) Rx(alpha) of the DH convention."""
    a = DH_ALPHA[i]
    return f'pos="{_fmt([DH_A[i], 0.0, DH_D[i]])}" quat="{_fmt([np.cos(a / 2), np.sin(a / 2), 0.0, 0.0])}"'


def _gripper_xml(tcp_offset: float) -> str:
    """A two-finger parallel gripper sized like the AG-95 (0..95 mm stroke) on the flange.

    Finger inner faces sit at +-q along the flange x axis, so the opening is the sum of the two slide
    positions; the TCP site is at the fingertip centre, as on the real tool's TCP setting.
    """
    half_stroke = AG95_MAX_OPENING_M / 2
    palm_len = tcp_offset - 0.05
    fz = tcp_offset - 0.0225
    finger = (
        '<geom type="box" size="0.008 0.012 0.0275" pos="{x} 0 0" rgba="0.15 0.15 0.15 1" '
        'class="finger"/>'
    )
    return (
        f'<body name="gripper" gravcomp="1">'
        f'<inertial pos="0 0 {palm_len / 2:.4g}" mass="1.0" diaginertia="0.003 0.003 0.002"/>'
        f'<geom type="cylinder" size="0.045 {palm_len / 2:.4g}" pos="0 0 {palm_len / 2:.4g}" '
        'rgba="0.2 0.2 0.22 1" class="arm"/>'
        f'<site name="tcp" pos="0 0 {tcp_offset}" size="0.005"/>'
        f'<body name="left_finger" pos="0 0 {fz:.4g}" gravcomp="1">'
        f'<joint name="left_finger" type="slide" axis="1 0 0" range="0 {half_stroke}" damping="5"/>'
        '<inertial pos="0 0 0" mass="0.1" diaginertia="1e-4 1e-4 1e-4"/>'
        + finger.format(x=0.008)
        + "</body>"
        f'<body name="right_finger" pos="0 0 {fz:.4g}" gravcomp="1">'
        f'<joint name="right_finger" type="slide" axis="-1 0 0" range="0 {half_stroke}" damping="5"/>'
        '<inertial pos="0 0 0" mass="0.1" diaginertia="1e-4 1e-4 1e-4"/>'
        + finger.format(x=-0.008)
        + "</body></body>"
    )


def _object_xml(obj: SceneObject, table_z: float) -> str:
    if obj.kind == "box":
        half_h = obj.size[2]
        geom = f'type="box" size="{_fmt(obj.size)}"'
    elif obj.kind == "cylinder":
        half_h = obj.size[1]
        geom = f'type="cylinder" size="{_fmt(obj.size)}"'
    else:
        raise ValueError(f"Unknown scene object kind {obj.kind!r}; use 'box' or 'cylinder'.")
    return (
        f'<body name="{obj.name}" pos="{obj.pos[0]} {obj.pos[1]} {table_z + half_h + 1e-3:.4g}">'
        f'<freejoint name="{obj.name}"/>'
        f'<geom {geom} mass="{obj.mass}" rgba="{_fmt(obj.rgba)}" class="object"/>'
        "</body>"
    )


def build_scene_xml(spec: SceneSpec | None = None) -> str:
    """Return the complete MJCF of the work cell as a string (loaded with MjModel.from_xml_string)."""
    spec = spec or SceneSpec()
    cam_pos = np.asarray(spec.camera_pos, dtype=float)
    xyaxes = _camera_xyaxes(cam_pos, np.asarray(spec.camera_lookat, dtype=float))
    tz = spec.table_height

    chain_open, chain_close = [], []
    for i in range(6):
        o, c = _link_xml(i)
        chain_open.append(o)
        chain_open.append(f'<body name="frame{i + 1}" {_child_frame_attrs(i)}>')
        chain_close.append("</body>" + c)
    arm = "".join(chain_open) + '<body name="flange">' + _gripper_xml(spec.tcp_offset) + "</body>"
    arm += "".join(reversed(chain_close))

    actuators = "".join(
        f'<position name="{n}" joint="{n}" kp="{_KP[i]}" dampratio="1" '
        f'ctrlrange="{JOINT_LIMITS[i][0]:.6g} {JOINT_LIMITS[i][1]:.6g}" '
        f'forcerange="{-_TORQUE[i]} {_TORQUE[i]}"/>'
        for i, n in enumerate(JOINT_NAMES)
    )
    half_stroke = AG95_MAX_OPENING_M / 2
    actuators += "".join(
        f'<position name="{f}" joint="{f}" kp="300" dampratio="1" ctrlrange="0 {half_stroke}" '
        'forcerange="-45 45"/>'
        for f in ("left_finger", "right_finger")
    )
    objects = "".join(_object_xml(o, tz) for o in spec.objects)

    return f"""<mujoco model="ur10e_workcell">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="0.002" integrator="implicitfast" cone="elliptic" impratio="10"/>
  <default>
    <default class="arm"><geom contype="0" conaffinity="0" group="1"/></default>
    <default class="finger"><geom contype="1" conaffinity="1" condim="4" friction="1.5 0.02 0.001"
      solref="0.004 1" group="1"/></default>
    <default class="object"><geom contype="1" conaffinity="1" condim="4" friction="1.0 0.02 0.001"
      group="2"/></default>
  </default>
  <worldbody>
    <geom name="floor" type="plane" size="3 3 0.1" pos="0 0 {tz - 0.75:.4g}" rgba="0.45 0.45 0.42 1"/>
    <!-- The table top is a bounded plane: mj_multiRay's culling misses parts of large boxes seen up close
         (measured: a quarter of the rays on a 1.5 m box), while planes are always tested. -->
    <geom name="table" type="plane" size="0.75 0.75 0.1" pos="-0.45 -0.15 {tz:.4g}"
      rgba="0.62 0.5 0.36 1" friction="1.0 0.02 0.001"/>
    <geom name="table_body" type="box" size="0.75 0.75 0.025" pos="-0.45 -0.15 {tz - 0.026:.4g}"
      rgba="0.5 0.4 0.29 1" contype="0" conaffinity="0"/>
    <camera name="front" pos="{_fmt(cam_pos)}" xyaxes="{_fmt(xyaxes)}" fovy="{spec.camera_fovy_deg}"/>
    <body name="base" pos="0 0 {tz:.4g}">
      <geom type="cylinder" size="0.09 0.04" pos="0 0 0.04" rgba="0.25 0.3 0.38 1" class="arm"/>
      {arm}
    </body>
    {objects}
  </worldbody>
  <actuator>{actuators}</actuator>
</mujoco>
"""
