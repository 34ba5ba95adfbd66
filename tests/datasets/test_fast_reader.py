"""The fast reader returns what LeRobot's stock reader returns, bit for bit, and changes nothing unless enabled."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from lerobot.datasets.dataset_reader import DatasetReader
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from lerobot_focal.datasets.fast_loading import fast_reader as fr
from lerobot_focal.datasets.making.synthetic import SyntheticSpec, write_synthetic_dataset

REPO_ID = "local/fast_reader_test"
FPS = 10
EP_LEN = 12
# past frames reach before the episode start, the action chunk (16) is longer than an episode (12):
# every item near a boundary is padded, and the clamped indices and masks must match the stock reader.
DELTAS = {
    "observation.state": [-0.3, -0.1, 0.0],
    "observation.pointcloud": [-0.1, 0.0],
    "action": [i / FPS for i in range(-1, 15)],
    "timestamp": [-0.2, 0.5],  # a scalar column with a window
}


@pytest.fixture(autouse=True)
def _restore_reader():
    was = fr.is_installed()
    yield
    if not was:
        fr.uninstall()


@pytest.fixture(scope="module")
def pc_root(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("fast_reader") / "pc"
    write_synthetic_dataset(root, SyntheticSpec(num_episodes=4, episode_length=EP_LEN, num_points=64), repo_id=REPO_ID)
    return root


@pytest.fixture(scope="module")
def img_root(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("fast_reader") / "img"
    spec = SyntheticSpec(num_episodes=3, episode_length=8, num_points=32, with_image=True, image_size=16)
    write_synthetic_dataset(root, spec, repo_id=REPO_ID)
    return root


@pytest.fixture(scope="module")
def dtypes_root(tmp_path_factory) -> Path:
    """float64 / int16 / uint8 / bool columns: the stock reader's dtype rules (floats -> default dtype, ints ->
    int64) are not the Arrow dtypes, and the cache must reproduce them."""
    root = tmp_path_factory.mktemp("fast_reader") / "dtypes"
    feats = {
        "observation.state": {"dtype": "float64", "shape": (3,), "names": None},
        "observation.counter": {"dtype": "int16", "shape": (1,), "names": None},
        "observation.grid": {"dtype": "uint8", "shape": (2, 2), "names": None},
        "observation.flag": {"dtype": "bool", "shape": (1,), "names": None},
        "action": {"dtype": "float32", "shape": (2,), "names": None},
    }
    ds = LeRobotDataset.create(repo_id=REPO_ID, fps=FPS, features=feats, root=root, use_videos=False)
    rng = np.random.default_rng(0)
    for ep, length in enumerate((5, 9, 3)):  # unequal episodes
        for i in range(length):
            ds.add_frame({
                "observation.state": rng.standard_normal(3) * 1e3 + 1e-9,  # not representable in float32
                "observation.counter": np.array([ep * 100 - i], dtype=np.int16),
                "observation.grid": rng.integers(0, 255, (2, 2), dtype=np.uint8),
                "observation.flag": np.array([i % 2 == 0]),
                "action": rng.standard_normal(2).astype(np.float32),
                "task": f"t{ep % 2}",
            })
        ds.save_episode()
    ds.finalize()
    return root


def _open(root: Path, **kwargs) -> LeRobotDataset:
    return LeRobotDataset(REPO_ID, root=root, **kwargs)


def _bytes(t: torch.Tensor) -> torch.Tensor:
    flat = t.reshape(-1)
    return flat if t.dtype == torch.bool else flat.contiguous().view(torch.uint8)


def assert_same_item(stock: dict, fast: dict) -> None:
    assert list(stock) == list(fast)  # same keys in the same order
    for key, ref in stock.items():
        got = fast[key]
        if isinstance(ref, torch.Tensor):
            assert isinstance(got, torch.Tensor), key
            assert got.dtype == ref.dtype and got.shape == ref.shape, (key, got.dtype, ref.dtype, got.shape, ref.shape)
            # bit for bit, NaN-safe: compare the raw bytes
            assert torch.equal(_bytes(got), _bytes(ref)), key
        else:
            assert got == ref, key


def _compare(root: Path, **kwargs) -> tuple[list[dict], LeRobotDataset]:
    assert not fr.is_installed()
    stock = _open(root, **kwargs)
    ref = [stock[i] for i in range(len(stock))]
    assert fr.install()
    fast = _open(root, **kwargs)
    assert fast.reader._focal_cache is not None, "the fast path was not taken"
    assert len(fast) == len(stock)
    for i in range(len(fast)):
        assert_same_item(ref[i], fast[i])
    return ref, fast


def test_bit_exact_with_boundary_padding(pc_root):
    ref, _ = _compare(pc_root, delta_timestamps=DELTAS)
    # the comparison covered padding at both ends of episodes, and interior frames without any
    first, last, mid = ref[0], ref[EP_LEN - 1], ref[EP_LEN + 5]
    assert first["observation.state_is_pad"].tolist() == [True, True, False]
    assert first["action_is_pad"].tolist() == [True] + [False] * EP_LEN + [True] * (16 - 1 - EP_LEN)
    assert last["action_is_pad"][2:].all() and not last["action_is_pad"][:2].any()
    assert not mid["observation.state_is_pad"].any()
    assert torch.equal(first["observation.pointcloud"][0], first["observation.pointcloud"][1])  # clamped copy


def test_bit_exact_episode_subset(pc_root):
    """Episode-filtered datasets map absolute frame indices to rows (LeRobot's absolute_to_relative_idx)."""
    _compare(pc_root, delta_timestamps=DELTAS, episodes=[1, 3])


def test_bit_exact_without_delta_timestamps(pc_root):
    _compare(pc_root)


def test_bit_exact_dtypes_and_unequal_episodes(dtypes_root):
    deltas = {"observation.state": [-0.2, 0.0], "observation.counter": [-0.1, 0.0, 0.3],
              "observation.grid": [0.0, 0.1], "observation.flag": [-0.1, 0.0], "action": [0.0, 0.1, 0.2, 0.3]}
    ref, fast = _compare(dtypes_root, delta_timestamps=deltas)
    assert ref[0]["observation.state"].dtype == torch.float32  # stock reader's rule, reproduced
    assert ref[0]["observation.counter"].dtype == torch.int64
    assert set(fast.reader._focal_cache.columns) >= {"observation.state", "observation.grid", "observation.flag"}


def test_images_keep_the_stock_path_and_match(img_root):
    """PNG image columns are not cached; they go through LeRobot's formatting, with windows, and still match."""
    deltas = {"observation.images.front": [-0.1, 0.0], "observation.pointcloud": [-0.1, 0.0],
              "action": [i / FPS for i in range(10)]}
    _, fast = _compare(img_root, delta_timestamps=deltas)
    assert "observation.images.front" not in fast.reader._focal_cache.columns


def test_dataloader_batches_match(pc_root):
    stock = _open(pc_root, delta_timestamps=DELTAS)
    order = list(np.random.default_rng(1).permutation(len(stock)))
    ref = next(iter(torch.utils.data.DataLoader(stock, batch_size=16, sampler=order)))
    with fr.enabled():
        fast = _open(pc_root, delta_timestamps=DELTAS)
        got = next(iter(torch.utils.data.DataLoader(fast, batch_size=16, sampler=order)))
    assert list(ref) == list(got)
    for key in ref:
        if isinstance(ref[key], torch.Tensor):
            assert torch.equal(ref[key], got[key]) and ref[key].dtype == got[key].dtype, key
        else:
            assert ref[key] == got[key]


def test_items_are_not_views_of_the_cache(pc_root):
    with fr.enabled():
        fast = _open(pc_root, delta_timestamps=DELTAS)
        before = fast[3]
        item = fast[3]
        for value in item.values():
            if isinstance(value, torch.Tensor) and value.is_floating_point():
                value.add_(1.0)  # in-place edits by a caller must not leak into the cache
        assert_same_item(before, fast[3])


def test_off_by_default_and_env_opt_in(monkeypatch, pc_root):
    stock_get_item = DatasetReader.get_item
    monkeypatch.delenv(fr.ENV_VAR, raising=False)
    assert not fr.install_from_env()
    assert DatasetReader.get_item is stock_get_item
    monkeypatch.setenv(fr.ENV_VAR, "0")
    assert not fr.install_from_env()
    monkeypatch.setenv(fr.ENV_VAR, "1")
    assert fr.install_from_env() and DatasetReader.get_item is not stock_get_item
    fr.uninstall()
    assert DatasetReader.get_item is stock_get_item


def test_refuses_an_unverified_lerobot_reader(monkeypatch):
    monkeypatch.setitem(fr.EXPECTED_SOURCES, "DatasetReader.get_item", "0" * 16)
    stock_get_item = DatasetReader.get_item
    assert not fr.install()
    assert DatasetReader.get_item is stock_get_item
    assert fr.install(force=True)  # LEROBOT_FOCAL_FAST_READER=force


def test_large_datasets_stay_on_the_stock_path(monkeypatch, pc_root):
    monkeypatch.setenv(fr.ENV_VAR + "_MAX_MB", "0.001")
    stock = _open(pc_root, delta_timestamps=DELTAS)
    with fr.enabled():
        fast = _open(pc_root, delta_timestamps=DELTAS)
        assert fast.reader._focal_cache is None
        assert_same_item(stock[5], fast[5])


def test_changed_hf_dataset_falls_back(pc_root):
    with fr.enabled():
        fast = _open(pc_root, delta_timestamps=DELTAS)
        stock = _open(pc_root, delta_timestamps=DELTAS)
        fr.uninstall()
        ref = stock[4]
        fr.install()
        fast.reader.hf_dataset = stock.hf_dataset  # someone swapped the dataset under the reader
        assert_same_item(ref, fast[4])


@pytest.mark.slow
def test_lerobot_train_runs_with_the_fast_reader(pc_root, tmp_path):
    """LeRobot's own training entry point, two steps, with the reader installed by the launcher."""
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1", "WANDB_MODE": "disabled"}
    repo = Path(__file__).resolve().parents[2]
    cmd = [sys.executable, "-m", "lerobot_focal.datasets.fast_loading.fast_reader",
           f"--config_path={repo / 'configs/focal_cpu.json'}",
           f"--dataset.repo_id={REPO_ID}", f"--dataset.root={pc_root}", "--batch_size=8", "--steps=2", "--log_freq=1",
           "--save_checkpoint=false", f"--output_dir={tmp_path / 'out'}", "--policy.down_dims=[16,32,64]"]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)
    log = proc.stdout + proc.stderr
    assert proc.returncode == 0, log[-3000:]
    assert "fast reader: " in log and "columns cached in memory" in log
    assert "data_s:" in log
