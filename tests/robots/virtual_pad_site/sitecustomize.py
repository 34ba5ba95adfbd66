"""Plug an SDL virtual F710 into a real ``lerobot-record`` subprocess (test support, not product code).

SDL virtual joysticks exist only inside the process that attaches them, so a test that runs the real
``lerobot-record`` console script puts this directory on ``PYTHONPATH``: Python imports ``sitecustomize`` at
start-up, which (only when ``FOCAL_VIRTUAL_PAD`` is set) attaches the virtual pad before LeRobot starts, holds the
deadman button and plays a fixed stick pattern on a background thread. Everything after that — pygame, SDL's
joystick layer, the focal_gamepad teleoperator, lerobot-record, the UR10e sim — is the real code path.

``FOCAL_VIRTUAL_PAD`` = ``"<period_s>"``: LB (deadman) is held and the left stick stays pushed forward (+x) at
70 %, while every half period the left stick's sideways deflection (y) and the right stick (z) flip sign, so
each recorded episode has net motion along +x with some y/z variation.
"""

import os

if os.environ.get("FOCAL_VIRTUAL_PAD"):
    import sys
    import threading
    import time
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "teleoperators"))
    from virtual_joystick import F710, F710Button, VirtualJoystick  # noqa: E402

    _period = float(os.environ["FOCAL_VIRTUAL_PAD"])
    _pad = VirtualJoystick().attach()
    _pad.set_button(F710Button.LB, True)
    def _play() -> None:
        sign = 1.0
        while True:
            _pad.set_axis(F710.LEFT_Y, -0.7)  # stick forward = +x
            _pad.set_axis(F710.LEFT_X, 0.5 * sign)
            _pad.set_axis(F710.RIGHT_Y, 0.5 * sign)
            sign = -sign
            time.sleep(_period / 2)

    threading.Thread(target=_play, name="virtual-f710", daemon=True).start()
