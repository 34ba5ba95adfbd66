"""The loop through LeRobot's real console scripts with ``--robot.backend=rtde`` against the emulated controller.

Same commands as ``test_ur10e_loop.py`` (sim backend) — ``lerobot-teleoperate``, ``lerobot-record``,
``lerobot-rollout --policy.path=<focal checkpoint>`` — but the robot drives ur_rtde 1.6.5's real client over
loopback sockets into the emulated UR controller (its own process, the MuJoCo twin behind it). Nothing between
the driver and the socket is faked; the only stand-in is the gamepad (an SDL virtual F710, as there).
The emulator's command log is the ground truth of what reached the arm.
"""

from __future__ import annotations

import re
import signal
import subprocess
import time

import numpy as np
import pytest

pytest.importorskip("rtde_control")
pytest.importorskip("mujoco")
pytest.importorskip("pygame")

from lerobot_focal.testing.ur10e_emulator.rtde_emulator import RtdeEmulatorProcess  # noqa: E402

from .test_ur10e_loop import (  # noqa: E402
    BIN,
    EPISODE_S,
    FPS,
    _env,
    _load,
    _record_args,
    _rollout,
    _run,
    _tail,
    _train,
    assert_frames_match_their_timestamps,
    wait_for_episode,
)
from .ur_emulator_support import free_loopback_host  # noqa: E402

pytestmark = pytest.mark.subprocess  # LeRobot commands against the emulated controller


def _robot(host: str) -> list[str]:
    return [
        "--robot.type=ur10e",
        "--robot.backend=rtde",
        f"--robot.robot_ip={host}",
        "--robot.gripper=none",
        "--robot.rtde_frequency=125",
        f"--robot.control_hz={FPS}",
    ]


def _servo_count(emu: RtdeEmulatorProcess, since: int = 0) -> int:
    return sum(c["name"] == "servoL" for c in emu.commands(since))


@pytest.fixture(scope="module")
def emulator():
    with RtdeEmulatorProcess(free_loopback_host()) as emu:
        yield emu


@pytest.fixture(scope="module")
def recorded_rtde(emulator, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("rtde_loop")
    root = tmp / "dataset"
    x0 = emulator.arm_state()[1][0]
    since = emulator.status()["commands_total"]
    _run(_record_args(root, episodes=2, robot=_robot(emulator.host)), _env(tmp, pad=True), tmp / "record.log", 300)
    return tmp, root, emulator.commands(since), emulator.arm_state()[1][0] - x0


def test_record_over_rtde_saves_episodes_and_the_emulated_arm_moved_as_commanded(recorded_rtde):
    tmp, root, commands, twin_dx = recorded_rtde
    ds = _load(root)
    assert ds.num_episodes == 2 and ds.meta.robot_type == "ur10e"
    frames = [ds[i] for i in range(len(ds))]
    assert_frames_match_their_timestamps(ds, frames)
    actions = np.stack([f["action"].numpy() for f in frames])
    states = np.stack([f["observation.state"].numpy() for f in frames])
    assert "observation.images.front" not in ds.meta.features  # no cameras configured on this arm
    # Every recorded action went through ur_rtde into the controller: one servoL per frame (the reset phase is
    # 0 s), no more, no fewer.
    servo = [c for c in commands if c["name"] == "servoL"]
    assert len(servo) == len(ds), (len(servo), len(ds))
    ep = np.array([int(f["episode_index"]) for f in frames])
    for e in (0, 1):
        cmd = actions[ep == e, :3].sum(axis=0) / FPS
        moved = states[ep == e][-1, 6:9] - states[ep == e][0, 6:9]
        assert cmd[0] > 0.05 and moved[0] > 0.5 * cmd[0], (cmd, moved)
        assert np.dot(cmd, moved) > 0, (cmd, moved)
    # The recorded state is the twin's, read back through the real receive interface.
    assert twin_dx > 0.1
    # Pose order and units on the wire: the last servoL target is the last recorded TCP position (m), give or
    # take the one control period of motion between observation and command.
    last = servo[-1]["doubles"]
    np.testing.assert_allclose([last[0], last[1], last[2]], states[-1, 6:9], atol=0.15 / FPS + 1e-3)


def test_teleoperate_over_rtde_moves_the_emulated_arm(emulator, tmp_path):
    since = emulator.status()["commands_total"]
    x0 = emulator.arm_state()[1][0]
    log = tmp_path / "teleop.log"
    args = [str(BIN / "lerobot-teleoperate"), *_robot(emulator.host)[:-1], "--teleop.type=focal_gamepad",
            "--fps=30", "--robot.control_hz=30", "--teleop_time_s=3"]  # fmt: skip
    _run(args, _env(tmp_path, pad=True), log, timeout=180)
    m = re.search(r"UR10e disconnected after (\d+) commands \(commanded TCP path ([\d.]+) m\)", log.read_text())
    assert m, _tail(log)
    assert int(m.group(1)) > 20 and float(m.group(2)) > 0.02, m.group(0)
    assert _servo_count(emulator, since) == int(m.group(1))  # each command the robot counted reached the script
    assert emulator.arm_state()[1][0] - x0 > 0.02  # the virtual pad pushes +x
    assert emulator.status()["runtime_state"] == 1  # disconnect stopped the control script


def test_controller_killed_mid_recording_keeps_every_finished_episode(tmp_path):
    root = tmp_path / "dataset"
    log = tmp_path / "record.log"
    with RtdeEmulatorProcess(free_loopback_host()) as emu:
        with log.open("w") as fh:
            proc = subprocess.Popen(
                _record_args(root, episodes=5, robot=_robot(emu.host)),
                env=_env(tmp_path, pad=True),
                stdout=fh,
                stderr=subprocess.STDOUT,
            )
        try:
            wait_for_episode(log, proc, 2, timeout_s=240)
            time.sleep(EPISODE_S / 2)
            emu.kill()  # the controller dies mid-episode
            proc.wait(timeout=120)
        finally:
            if proc.poll() is None:
                proc.send_signal(signal.SIGKILL)
    text = log.read_text(errors="replace")
    assert proc.returncode != 0
    assert "lost the controller" in text, _tail(log)
    ds = _load(root)
    assert ds.num_episodes == 2  # episodes 0 and 1 were finished: both kept, intact
    assert len(ds) == sum(int(e["length"]) for e in ds.meta.episodes)
    for i in range(len(ds)):
        assert np.isfinite(ds[i]["action"].numpy()).all()


@pytest.mark.slow
def test_rollout_focal_checkpoint_over_rtde(recorded_rtde, emulator, tmp_path):
    import json

    _, root, _, _ = recorded_rtde
    out = tmp_path / "train"
    features = {"observation.state": {"type": "STATE", "shape": [13]}}
    model = _train(root, out, tmp_path, "--policy.down_dims=[32,64,128]",
                   f"--policy.input_features={json.dumps(features)}", steps=10, log_freq=5)
    since = emulator.status()["commands_total"]
    log = tmp_path / "rollout.log"
    text = _rollout(model, _robot(emulator.host), tmp_path, log)
    assert "Policy loaded: type=focal" in text
    m = re.search(r"UR10e disconnected after (\d+) commands", text)
    assert m and int(m.group(1)) > 10, _tail(log)
    assert _servo_count(emulator, since) == int(m.group(1))
