"""Offscreen rendering for the MuJoCo simulations: which OpenGL backend, and cheap frames on software GL.

The backend choice is made when a simulator is first built (never when the plugin is imported): importing
the plugin must leave the process's environment alone, and only code that renders needs ``MUJOCO_GL``.
"""

from __future__ import annotations


def ensure_offscreen_gl() -> str | None:
    """Pick an offscreen OpenGL backend for pixel observations when the user has not chosen one.

    gymnasium's MuJoCo renderer reads ``MUJOCO_GL`` when it creates its viewer; with no display its default
    (GLFW) fails. Prefer EGL (Mesa's surfaceless EGL works without a GPU), then OSMesa. Returns the backend
    in effect (None: no offscreen library found, rendering will fail with MuJoCo's own error).
    """
    import ctypes.util
    import os

    if os.environ.get("MUJOCO_GL"):
        return os.environ["MUJOCO_GL"]
    if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        return None
    for backend, lib in (("egl", "EGL"), ("osmesa", "OSMesa")):
        if ctypes.util.find_library(lib):
            os.environ["MUJOCO_GL"] = backend
            os.environ.setdefault("PYOPENGL_PLATFORM", backend)
            return backend
    return None


def make_rendering_cheap(mujoco_renderer) -> None:
    """Turn off shadows and reflections in a gymnasium ``MujocoRenderer``'s offscreen viewer.

    With software OpenGL (Mesa llvmpipe through EGL or OSMesa, the only kind on a GPU-less machine) they
    cost ~8x: a 128x128 MetaWorld frame took 152 ms with them and 18 ms without. Geometry, colours and
    textures are unchanged.
    """
    import mujoco

    # gymnasium's renderer has no public way to reach its offscreen viewer's scene flags; its private
    # `_get_viewer` (creates the viewer once, returns it after) is the one hook. tests/envs/test_registration.py
    # fails loudly if gymnasium renames it or changes its signature.
    viewer = mujoco_renderer._get_viewer(render_mode="rgb_array")
    viewer.scn.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = 0
    viewer.scn.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0
