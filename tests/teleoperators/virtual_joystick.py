"""An SDL virtual joystick laid out like a Logitech F710 (XInput, Linux), for tests without a gamepad.

pygame's wheel bundles its own libSDL2 in ``site-packages/pygame.libs``; SDL >= 2.0.14 can attach a virtual
joystick that pygame then enumerates and reads like a USB pad, so the code under test runs its real device path
(``pygame.joystick.Joystick``, the event queue, hot-unplug) and only the physical pad is replaced.

SDL virtual joysticks live inside one process: the code reading the pad must run in the process that attached
it (call ``lerobot_record.record(cfg)`` in-process for an end-to-end test, not a subprocess).

Usage::

    with VirtualJoystick() as pad:          # attached and visible as pygame joystick `pad.index`
        pad.set_button(F710.LB, True)
        pad.set_axis(F710.LEFT_Y, -1.0)     # stick fully forward
        ...                                  # the code under test pumps pygame events itself
"""

from __future__ import annotations

import ctypes
import glob
import os
from enum import IntEnum
from pathlib import Path

# Must be set before SDL initialises: no display here, and no "Hello from pygame" banner in test output.
os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")
os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")

import pygame  # noqa: E402

_SDL_JOYSTICK_TYPE_GAMECONTROLLER = 1
_HAT_BITS = {(0, 0): 0, (0, 1): 1, (1, 0): 2, (0, -1): 4, (-1, 0): 8, (1, 1): 3, (1, -1): 6, (-1, -1): 12, (-1, 1): 9}


class F710(IntEnum):
    """SDL indices of the F710 in XInput mode on Linux (xpad), matching ``GamepadMapping``'s defaults."""

    LEFT_X = 0
    LEFT_Y = 1
    LT = 2
    RIGHT_X = 3
    RIGHT_Y = 4
    RT = 5


class F710Button(IntEnum):
    A = 0
    B = 1
    X = 2
    Y = 3
    LB = 4
    RB = 5
    BACK = 6
    START = 7
    GUIDE = 8
    LEFT_STICK = 9
    RIGHT_STICK = 10


def _load_sdl() -> ctypes.CDLL:
    libs_dir = Path(pygame.__file__).parent.parent / "pygame.libs"
    candidates = sorted(glob.glob(str(libs_dir / "libSDL2-2*.so*")))
    if not candidates:
        raise RuntimeError(
            f"no bundled libSDL2 in {libs_dir}: the virtual joystick needs pygame's manylinux wheel (pygame>=2.1)"
        )
    sdl = ctypes.CDLL(candidates[0])
    sdl.SDL_JoystickAttachVirtual.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int, ctypes.c_int]
    sdl.SDL_JoystickAttachVirtual.restype = ctypes.c_int
    sdl.SDL_JoystickDetachVirtual.argtypes = [ctypes.c_int]
    sdl.SDL_JoystickDetachVirtual.restype = ctypes.c_int
    sdl.SDL_JoystickOpen.argtypes = [ctypes.c_int]
    sdl.SDL_JoystickOpen.restype = ctypes.c_void_p
    sdl.SDL_JoystickClose.argtypes = [ctypes.c_void_p]
    sdl.SDL_JoystickSetVirtualAxis.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_int16]
    sdl.SDL_JoystickSetVirtualAxis.restype = ctypes.c_int
    sdl.SDL_JoystickSetVirtualButton.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_uint8]
    sdl.SDL_JoystickSetVirtualButton.restype = ctypes.c_int
    sdl.SDL_JoystickSetVirtualHat.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_uint8]
    sdl.SDL_JoystickSetVirtualHat.restype = ctypes.c_int
    sdl.SDL_GetError.restype = ctypes.c_char_p
    return sdl


class VirtualJoystick:
    """A virtual pad with the F710's 6 axes, 11 buttons and 1 hat, at rest (sticks centred, triggers released)."""

    def __init__(self, naxes: int = 6, nbuttons: int = 11, nhats: int = 1):
        self.naxes, self.nbuttons, self.nhats = naxes, nbuttons, nhats
        self._sdl: ctypes.CDLL | None = None
        self._handle: int | None = None
        self.index: int | None = None  # SDL device index, what pygame.joystick.Joystick() takes

    def attach(self) -> VirtualJoystick:
        pygame.init()  # re-initialising the joystick subsystem later would detach us, so only ever init
        if not pygame.joystick.get_init():
            pygame.joystick.init()
        self._sdl = _load_sdl()
        index = self._sdl.SDL_JoystickAttachVirtual(
            _SDL_JOYSTICK_TYPE_GAMECONTROLLER, self.naxes, self.nbuttons, self.nhats
        )
        if index < 0:
            raise RuntimeError(f"SDL_JoystickAttachVirtual failed: {self._sdl.SDL_GetError().decode()}")
        self.index = index
        self._handle = self._sdl.SDL_JoystickOpen(index)
        if not self._handle:
            raise RuntimeError(f"SDL_JoystickOpen failed: {self._sdl.SDL_GetError().decode()}")
        # SDL's virtual game controller rests axes 4/5 at -1 (its trigger slots); the F710 has triggers on 2/5.
        for axis in range(self.naxes):
            self.set_axis(axis, -1.0 if axis in (F710.LT, F710.RT) else 0.0)
        self.pump()
        return self

    def detach(self) -> None:
        """Unplug the pad (pygame then sees JOYDEVICEREMOVED, as with a real USB unplug)."""
        if self._handle is not None:
            self._sdl.SDL_JoystickClose(self._handle)
            self._handle = None
        if self.index is not None:
            self._sdl.SDL_JoystickDetachVirtual(self.index)
            self.index = None

    def __enter__(self) -> VirtualJoystick:
        return self.attach()

    def __exit__(self, *exc) -> None:
        self.detach()

    def _check(self, rc: int, what: str) -> None:
        if rc < 0:
            raise RuntimeError(f"{what} failed: {self._sdl.SDL_GetError().decode()}")

    def _require(self) -> None:
        if self._handle is None:
            raise RuntimeError("virtual joystick is not attached")

    def set_axis(self, axis: int, value: float) -> None:
        """``value`` in [-1, 1] (SDL convention: stick right / down and trigger pressed are +)."""
        self._require()
        raw = -32768 if value <= -1.0 else min(32767, int(round(value * 32767)))
        self._check(self._sdl.SDL_JoystickSetVirtualAxis(self._handle, int(axis), raw), f"set axis {axis}")

    def set_button(self, button: int, pressed: bool) -> None:
        self._require()
        self._check(self._sdl.SDL_JoystickSetVirtualButton(self._handle, int(button), int(pressed)), "set button")

    def set_hat(self, hat: int, value: tuple[int, int]) -> None:
        """``value`` as pygame reports hats: (x, y) with up = (0, 1)."""
        self._require()
        self._check(self._sdl.SDL_JoystickSetVirtualHat(self._handle, int(hat), _HAT_BITS[value]), "set hat")

    def press(self, button: int) -> None:
        """A press and release within one control step; only an event-latching reader will see it."""
        self.set_button(button, True)
        self.pump()
        self.set_button(button, False)

    @staticmethod
    def pump() -> None:
        """Let SDL turn the new virtual state into joystick state/events, without consuming the events.

        SDL applies virtual joystick changes on its next joystick update, which happens when events are pumped.
        """
        pygame.event.pump()
