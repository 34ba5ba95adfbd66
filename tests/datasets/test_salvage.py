"""`lerobot-focal-salvage-dataset` on the folder LeRobot's writer leaves when its process dies: the state is
captured by copying the folder while the writer is still open (data file without footer, no episode index,
info.json counting the saved episodes), then compared with the same dataset finalized normally."""

from __future__ import annotations

import shutil
import subprocess
import sys

import numpy as np
import pytest
from lerobot.datasets import LeRobotDataset

from lerobot_focal.datasets.making.synthetic import SyntheticSpec, episode_arrays, features

pytestmark = pytest.mark.subprocess  # the salvage command


def test_salvage_recovers_every_saved_episode_of_an_unclosed_dataset(tmp_path):
    spec = SyntheticSpec(num_episodes=3, episode_length=12, num_points=8, with_image=True, image_size=16)
    live = tmp_path / "live"
    ds = LeRobotDataset.create(repo_id="local/live", fps=spec.fps, features=features(spec), root=live, use_videos=False)
    for ep in range(spec.num_episodes):
        arrays = episode_arrays(spec, ep)
        for i in range(spec.episode_length):
            ds.add_frame({**{k: v[i] for k, v in arrays.items()}, "task": f"reach goal {ep}"})
        ds.save_episode()
    for i in range(5):  # the episode in flight: frames in memory only
        ds.add_frame({**{k: v[i] for k, v in episode_arrays(spec, 9).items()}, "task": "in flight"})
    killed = tmp_path / "killed"
    shutil.copytree(live, killed)  # what a SIGKILL leaves on disk right now
    ds.clear_episode_buffer()
    ds.finalize()

    assert not (killed / "meta" / "episodes").exists()
    with pytest.raises(Exception):  # noqa: B017 - whatever LeRobot raises, it cannot open the folder
        LeRobotDataset("local/live", root=killed)

    out = tmp_path / "salvaged"
    proc = subprocess.run(
        [sys.executable, "-m", "lerobot_focal.datasets.repair.salvage", str(killed), "--out", str(out)],
        capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "recovered 3 episode(s), 36 frames (info.json claimed 3)" in proc.stdout

    got, want = LeRobotDataset("local/salvaged", root=out), LeRobotDataset("local/live", root=live)
    assert got.num_episodes == want.num_episodes == 3 and len(got) == len(want)
    for i in range(len(want)):
        a, b = got[i], want[i]
        for key in ("action", "observation.state", "observation.pointcloud", "observation.images.front",
                    "episode_index", "frame_index"):
            np.testing.assert_array_equal(a[key].numpy(), b[key].numpy(), err_msg=f"{key} of frame {i}")
        assert a["task"] == b["task"]
    for key in ("action", "observation.state"):
        np.testing.assert_allclose(got.meta.stats[key]["mean"], want.meta.stats[key]["mean"], rtol=1e-6)


def test_salvage_refuses_a_folder_that_is_not_a_dataset(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "lerobot_focal.datasets.repair.salvage", str(tmp_path)], capture_output=True, text=True,
        timeout=120,
    )
    assert proc.returncode == 1
    assert f"error: {tmp_path} has no meta/info.json: it is not a LeRobotDataset folder." in proc.stderr
