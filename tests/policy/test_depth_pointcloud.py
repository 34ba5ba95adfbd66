"""`focal_depth_to_pointcloud`: the preprocessor step that makes `observation.pointcloud` from a depth map.

A synthetic depth camera 1 m above a table (z = 0) with a 4 cm box on it. The same frame is fed in every
form it reaches the preprocessor in: the robot's raw uint16 mm frame (`lerobot-rollout`), and LeRobot's
decoded depth video (`lerobot-train`: float32 mm, batched (B, n_obs, 1, H, W)), exactly and through LeRobot's
own 12-bit depth quantiser.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.processor import PolicyProcessorPipeline, ProcessorStepRegistry
from lerobot.processor.converters import batch_to_transition, transition_to_batch

from lerobot_focal.policy import FocalConfig, FocalPolicy, make_focal_pre_post_processors
from lerobot_focal.policy.configuration_focal import FocalConfigError
from lerobot_focal.policy.depth_cloud_settings import DepthCloudConfig
from lerobot_focal.policy.processor_focal import DEPTH_TO_POINTCLOUD_STEP, DepthToPointCloudProcessorStep

from .helpers import SMALL_UNET

H, W = 48, 64
DEPTH_KEY = "observation.images.front_depth"
CROP_MIN, CROP_MAX = (-0.6, -0.5, -0.02), (0.6, 0.5, 0.5)
BOX = (0.1, 0.05, 0.04)  # centre x, y and height (m)


def _camera_info() -> dict:
    # OpenCV optical frame looking straight down from (0, 0, 1): x_cam = +x, y_cam = -y, z_cam = -z.
    pose = [[1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 1.0], [0.0, 0.0, 0.0, 1.0]]
    f = 0.5 * H / np.tan(np.deg2rad(58.0) / 2)
    return {"width": W, "height": H, "fx": f, "fy": f, "cx": (W - 1) / 2, "cy": (H - 1) / 2,
            "T_base_cam": pose, "depth_scale": 0.001}  # fmt: skip


def _depth_mm() -> np.ndarray:
    """uint16 (H, W) mm: the table at 1000 mm, the box top at 960 mm, a few dropouts (0)."""
    info = _camera_info()
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    # Table-plane hit of each pixel ray (z_cam = 1 m): world x = (u-cx)/fx, y = -(v-cy)/fy.
    x, y = (u - info["cx"]) / info["fx"], -(v - info["cy"]) / info["fy"]
    depth = np.full((H, W), 1000, dtype=np.uint16)
    on_box = (np.abs(x - BOX[0]) < 0.1) & (np.abs(y - BOX[1]) < 0.1)
    depth[on_box] = 1000 - int(BOX[2] * 1000)
    depth[::7, ::11] = 0
    return depth


def _step(**kw) -> DepthToPointCloudProcessorStep:
    args = dict(depth_key=DEPTH_KEY, camera_info=_camera_info(), crop_min=list(CROP_MIN), crop_max=list(CROP_MAX))
    args.update(kw)
    return DepthToPointCloudProcessorStep(**args)


def _chamfer(a: np.ndarray, b: np.ndarray) -> float:
    d = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=-1)
    return float(max(d.min(1).mean(), d.min(0).mean()))


def test_uint16_frame_and_decoded_dataset_form_give_the_same_cloud():
    step = _step()
    raw = _depth_mm()
    ref = step.depth_to_points(raw)
    assert ref.shape == (512, 3) and ref.dtype == np.float32
    # The scene comes back: table at z = 0, box top at 4 cm, everything inside the crop box.
    assert np.all(ref > np.array(CROP_MIN)) and np.all(ref < np.array(CROP_MAX))
    top = ref[ref[:, 2] > 0.02]
    assert len(top) > 10 and np.allclose(top[:, 2], BOX[2], atol=1e-6)
    assert np.abs(top[:, :2].mean(0) - BOX[:2]).max() < 0.01
    assert np.allclose(ref[ref[:, 2] < 0.02][:, 2], 0.0, atol=1e-6)

    # Live (lerobot-rollout): (H, W, 1) uint16 from the robot → (1, 1, H, W) uint16 tensor after
    # prepare_observation_for_inference; numpy and torch, batched or not — all identical.
    for form in (raw[..., None], torch.from_numpy(raw[None, None]), torch.from_numpy(raw[None])):
        out = step.depth_to_points(form)
        np.testing.assert_array_equal(out.reshape(512, 3), ref)
    assert step.depth_to_points(torch.from_numpy(raw[None, None])).shape == (1, 512, 3)

    # Dataset (lerobot-train): LeRobot's decoded depth video is float32 mm, batch (B, n_obs, 1, H, W).
    decoded = torch.from_numpy(raw.astype(np.float32))[None, None, None].repeat(2, 2, 1, 1, 1)
    batch = step.depth_to_points(decoded)
    assert batch.shape == (2, 2, 512, 3)
    for b in range(2):
        for t in range(2):
            np.testing.assert_array_equal(batch[b, t], ref)
    # --dataset.depth_output_unit=m decodes to metres; the step then reads floats as metres.
    metres = _step(float_depth_unit="m").depth_to_points(raw.astype(np.float32) / 1000.0)
    assert _chamfer(metres, ref) < 0.002  # float rounding can flip FPS ties on this regular grid

    # Through LeRobot's own 12-bit depth codec (what the depth video stores): the same cloud within the
    # quantisation step (~1-2 mm at 1 m with the default log mapping).
    from lerobot.datasets.depth_utils import dequantize_depth, quantize_depth

    codes = quantize_depth(raw, video_backend=None)
    lossy = dequantize_depth(torch.from_numpy(np.asarray(codes))[None], output_unit="mm")  # float32 (1, H, W)
    assert lossy.dtype == torch.float32 and tuple(lossy.shape) == (1, H, W)
    valid = raw > 0
    assert np.abs(lossy.numpy()[0] - raw)[valid].max() < 5.0
    # The codec turns "no return" (0) into its depth_min, 10 mm: the step's min_depth drops those again.
    np.testing.assert_allclose(lossy.numpy()[0][~valid], 10.0)
    assert _chamfer(step.depth_to_points(lossy), ref) < 0.005


def test_metres_given_as_millimetres_is_refused():
    with pytest.raises(ValueError, match="looks like metres.*depth_output_unit"):
        _step().depth_to_points(_depth_mm().astype(np.float32) / 1000.0)


def test_wrong_frame_size_names_the_camera_info():
    with pytest.raises(ValueError, match="48x64 depth frames"):
        _step().depth_to_points(np.zeros((1, 1, 32, 32), dtype=np.uint16))


def test_incomplete_camera_info_is_refused():
    with pytest.raises(ValueError, match=r"lacks \['fx'"):
        _step(camera_info={k: v for k, v in _camera_info().items() if k != "fx"})


def test_missing_depth_key_says_what_to_do():
    with pytest.raises(KeyError, match="use_depth: true"):
        _step()({"observation": {"observation.state": torch.zeros(1, 13)}})


def _config(tmp_path, depth_kw: dict | None = None, **kw) -> FocalConfig:
    path = tmp_path / "cameras.json"
    path.write_text(json.dumps({"front": _camera_info()}))
    args = dict(
        device="cpu",
        down_dims=SMALL_UNET,
        input_features={
            "observation.state": PolicyFeature(FeatureType.STATE, (13,)),
            DEPTH_KEY: PolicyFeature(FeatureType.VISUAL, (1, H, W)),
        },
        output_features={"action": PolicyFeature(FeatureType.ACTION, (7,))},
    )
    depth = dict(from_depth=DEPTH_KEY, camera_info=str(path), crop_min=CROP_MIN, crop_max=CROP_MAX)
    depth.update(depth_kw or {})
    args.update(kw)
    return FocalConfig(**args, depth_cloud=DepthCloudConfig(**depth))


def _stats() -> dict:
    return {
        "observation.state": {"min": torch.full((13,), -1.0), "max": torch.ones(13)},
        DEPTH_KEY: {"mean": torch.full((1, 1, 1), 1000.0), "std": torch.ones(1, 1, 1)},
        "action": {"min": -torch.ones(7), "max": torch.ones(7)},
    }


def test_config_declares_the_pointcloud_input_and_the_policy_reads_it(tmp_path):
    cfg = _config(tmp_path)
    assert cfg.input_features["observation.pointcloud"] == PolicyFeature(FeatureType.STATE, (512, 3))
    assert cfg.used_pointcloud_key == "observation.pointcloud"
    assert cfg.depth_cloud.camera_name == "front"
    # From the command line input_features start empty; LeRobot's make_policy fills them from the dataset and
    # calls this hook, which adds the cloud — or says which depth keys the dataset has.
    cfg2 = _config(tmp_path, input_features={})
    cfg2.input_features = {"observation.state": PolicyFeature(FeatureType.STATE, (13,))}
    cfg2.set_dataset_feature_metadata(
        {DEPTH_KEY: {"dtype": "video", "shape": [H, W, 1], "info": {"is_depth_map": True}}}
    )
    assert cfg2.input_features["observation.pointcloud"].shape == (512, 3)
    with pytest.raises(ValueError, match=r"not a feature of the dataset.*\['observation.images.wrist_depth'\]"):
        cfg2.set_dataset_feature_metadata({"observation.images.wrist_depth": {"info": {"is_depth_map": True}}})

    pre, _ = make_focal_pre_post_processors(cfg, dataset_stats=_stats())
    policy = FocalPolicy(cfg)
    depth = torch.from_numpy(_depth_mm().astype(np.float32))[None, None, None].repeat(2, 2, 1, 1, 1)
    batch = pre({"observation.state": torch.zeros(2, 2, 13), DEPTH_KEY: depth, "action": torch.zeros(2, 12, 7)})
    pc = batch["observation.pointcloud"]
    assert pc.shape == (2, 2, 512, 3)
    # Normalised with the crop box (MIN_MAX): inside [-1, 1]; the table (z = 0) at 2*(0.02/0.52)-1.
    assert pc.abs().max() <= 1.0
    assert torch.isclose(pc[..., 2].min(), torch.tensor(2 * 0.02 / 0.52 - 1), atol=1e-5)
    loss, _ = policy.forward(batch)
    assert torch.isfinite(loss)
    # Live frame: (1, 1, H, W) uint16, one obs step → an action.
    policy.eval()
    obs = pre({"observation.state": torch.zeros(1, 13), DEPTH_KEY: torch.from_numpy(_depth_mm()[None, None])})
    assert obs["observation.pointcloud"].shape == (1, 512, 3)
    assert policy.select_action(obs).shape == (1, 7)


def test_step_config_saves_and_reloads_with_the_pipeline(tmp_path):
    cfg = _config(tmp_path)
    pre, _ = make_focal_pre_post_processors(cfg, dataset_stats=_stats())
    pre.save_pretrained(tmp_path / "model")
    saved = json.loads((tmp_path / "model" / "policy_preprocessor.json").read_text())
    entry = next(s for s in saved["steps"] if s.get("registry_name") == DEPTH_TO_POINTCLOUD_STEP)
    assert entry["config"]["camera_info"]["fx"] == pytest.approx(_camera_info()["fx"])
    assert entry["config"]["crop_min"] == list(CROP_MIN) and entry["config"]["num_points"] == 512

    (tmp_path / "cameras.json").unlink()  # the reloaded step must not need the file any more
    assert ProcessorStepRegistry.get(DEPTH_TO_POINTCLOUD_STEP) is DepthToPointCloudProcessorStep
    loaded = PolicyProcessorPipeline.from_pretrained(
        tmp_path / "model",
        config_filename="policy_preprocessor.json",
        to_transition=batch_to_transition,
        to_output=transition_to_batch,
    )
    original = next(s for s in pre.steps if isinstance(s, DepthToPointCloudProcessorStep))
    reloaded = next(s for s in loaded.steps if isinstance(s, DepthToPointCloudProcessorStep))
    assert reloaded.get_config() == original.get_config()
    frame = {"observation.state": torch.zeros(1, 13), DEPTH_KEY: torch.from_numpy(_depth_mm()[None, None])}
    a, b = pre(dict(frame)), loaded(dict(frame))
    torch.testing.assert_close(a["observation.pointcloud"], b["observation.pointcloud"], rtol=0, atol=0)
    # ... including the normalisation stats of the cloud (the crop box).
    norm = next(s for s in loaded.steps if type(s).__name__ == "NormalizerProcessorStep")
    np.testing.assert_allclose(np.asarray(norm.stats["observation.pointcloud"]["min"]), CROP_MIN, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(norm.stats["observation.pointcloud"]["max"]), CROP_MAX, rtol=1e-6)


def test_missing_camera_info_and_crop_say_what_to_do(tmp_path):
    cfg = _config(tmp_path, depth_kw=dict(camera_info=None))
    with pytest.raises(FileNotFoundError, match=r"--policy.depth_cloud.camera_info=.*meta/cameras.json"):
        make_focal_pre_post_processors(cfg, dataset_stats=_stats())
    cfg = _config(tmp_path, depth_kw=dict(camera_info=str(tmp_path / "nope.json")))
    with pytest.raises(FileNotFoundError, match="_cameras.json"):
        make_focal_pre_post_processors(cfg, dataset_stats=_stats())
    cfg = _config(tmp_path, depth_kw=dict(camera="wrist"))
    with pytest.raises(KeyError, match=r"no camera 'wrist' \(it has \['front'\]\)"):
        make_focal_pre_post_processors(cfg, dataset_stats=_stats())
    with pytest.raises(FocalConfigError, match="depth_cloud.crop_min"):
        _config(tmp_path, depth_kw=dict(crop_min=None))


def test_dataset_meta_cameras_json_is_found(tmp_path):
    """Without --policy.depth_cloud.camera_info the step reads `<dataset root>/meta/cameras.json`, via the
    dataset metadata LeRobot's make_policy attaches to the config."""
    cfg = _config(tmp_path, depth_kw=dict(camera_info=None))
    (tmp_path / "ds" / "meta").mkdir(parents=True)
    (tmp_path / "cameras.json").rename(tmp_path / "ds" / "meta" / "cameras.json")
    cfg._runtime_dataset_meta = type("Meta", (), {"root": tmp_path / "ds"})()
    pre, _ = make_focal_pre_post_processors(cfg, dataset_stats=_stats())
    assert any(isinstance(s, DepthToPointCloudProcessorStep) for s in pre.steps)


def test_fine_tuning_a_depth_cloud_checkpoint_keeps_the_cloud_normalised(tmp_path):
    """`lerobot-train --policy.path=<checkpoint>` on a new dataset: LeRobot builds the policy with the new
    dataset's stats (`make_policy`), then reloads the saved preprocessor with those very stats as the
    normaliser's override. The new dataset has depth, not a cloud, so its stats have no cloud entry: the policy
    must leave the crop-box statistics there, or the cloud would pass un-normalised."""
    from lerobot.processor import PolicyProcessorPipeline

    cfg = _config(tmp_path)
    pre, _ = make_focal_pre_post_processors(cfg, dataset_stats=_stats())
    pre.save_pretrained(tmp_path / "ckpt")

    new_stats = _stats()  # LeRobotDataset.meta.stats of the new dataset: no "observation.pointcloud"
    FocalPolicy(cfg, dataset_stats=new_stats)  # what make_policy does with --policy.path
    reloaded = PolicyProcessorPipeline.from_pretrained(
        tmp_path / "ckpt", config_filename="policy_preprocessor.json",
        overrides={"normalizer_processor": {"stats": new_stats, "features": {**cfg.input_features,
                                                                               **cfg.output_features},
                                            "norm_map": cfg.normalization_mapping}},
    )
    normalizer = next(s for s in reloaded.steps if type(s).__name__ == "NormalizerProcessorStep")
    cloud = normalizer.stats["observation.pointcloud"]
    torch.testing.assert_close(torch.as_tensor(cloud["min"]), torch.tensor(CROP_MIN, dtype=torch.float32))
    torch.testing.assert_close(torch.as_tensor(cloud["max"]), torch.tensor(CROP_MAX, dtype=torch.float32))
    depth = torch.from_numpy(_depth_mm().astype(np.float32))[None, None, None].repeat(1, 2, 1, 1, 1)
    out = reloaded({"observation.state": torch.zeros(1, 2, 13), DEPTH_KEY: depth, "action": torch.zeros(1, 12, 7)})
    assert out["observation.pointcloud"].abs().max() <= 1.0  # normalised into [-1, 1], as at training


def _meta(root, robot_type="ur10e"):
    return type("Meta", (), {"root": root, "robot_type": robot_type})()


def test_the_recording_robots_camera_file_is_found_without_a_copy(tmp_path, monkeypatch):
    """A dataset without meta/cameras.json, trained where it was recorded: the step reads the file the dataset's
    robot type wrote on connect under $HF_LEROBOT_CALIBRATION, and the checkpoint keeps those intrinsics. Two
    robots of that type wrote files: refused, naming both and the flag that picks one."""
    import lerobot.utils.constants as constants

    calibration = tmp_path / "calibration"
    monkeypatch.setattr(constants, "HF_LEROBOT_CALIBRATION", calibration)
    written = calibration / "robots" / "ur10e" / "arm1_cameras.json"
    written.parent.mkdir(parents=True)
    info = {**_camera_info(), "fx": 123.0}
    written.write_text(json.dumps({"front": info}))
    cfg = _config(tmp_path, depth_kw=dict(camera_info=None))
    cfg._runtime_dataset_meta = _meta(tmp_path / "ds")
    pre, _ = make_focal_pre_post_processors(cfg, dataset_stats=_stats())
    step = next(s for s in pre.steps if isinstance(s, DepthToPointCloudProcessorStep))
    assert step.camera_info["fx"] == 123.0
    (written.parent / "arm2_cameras.json").write_text(json.dumps({"front": _camera_info()}))
    with pytest.raises(FileNotFoundError, match=r"arm1_cameras.json.*arm2_cameras.json.*depth_cloud.camera_info"):
        make_focal_pre_post_processors(cfg, dataset_stats=_stats())
    # Another robot type's files are not taken for this dataset's.
    cfg._runtime_dataset_meta = _meta(tmp_path / "ds", robot_type="so101_follower")
    with pytest.raises(FileNotFoundError, match="no so101_follower camera file"):
        make_focal_pre_post_processors(cfg, dataset_stats=_stats())


def test_a_config_saved_with_the_flat_depth_keys_still_loads(tmp_path):
    """Checkpoints saved before the depth settings became `depth_cloud` hold flat `pointcloud_*` keys: they load
    through LeRobot's own readers (`--policy.path` and a resumed run's train_config.json), into the group, and a
    value given the new way on the command line wins."""
    from draccus.parsers.decoding import decode
    from lerobot.configs import PreTrainedConfig
    from lerobot.configs.train import TrainPipelineConfig

    cfg = _config(tmp_path)
    (tmp_path / "new").mkdir()
    cfg._save_pretrained(tmp_path / "new")
    saved = json.loads((tmp_path / "new" / "config.json").read_text())
    flat = {k: v for k, v in saved.items() if k != "depth_cloud"}
    flat.update({f"pointcloud_{k}": v for k, v in saved["depth_cloud"].items()})
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "config.json").write_text(json.dumps(flat))

    loaded = PreTrainedConfig.from_pretrained(tmp_path / "old")
    assert loaded.depth_cloud == cfg.depth_cloud
    assert loaded.input_features == cfg.input_features
    overridden = PreTrainedConfig.from_pretrained(tmp_path / "old", cli_overrides=["--depth_cloud.num_points=256"])
    assert overridden.depth_cloud.num_points == 256 and overridden.depth_cloud.crop_min == cfg.depth_cloud.crop_min
    # A train_config.json decodes its policy through LeRobot's choice registry.
    pipeline = decode(TrainPipelineConfig, {"dataset": {"repo_id": "local/x"}, "policy": flat})
    assert pipeline.policy.depth_cloud == cfg.depth_cloud
    # Unknown keys are still refused, by draccus.
    with pytest.raises(Exception, match="pointcloud_typo"):
        decode(TrainPipelineConfig, {"dataset": {"repo_id": "local/x"}, "policy": {**flat, "pointcloud_typo": 1}})


def test_a_real_config_saved_before_the_group_loads(tmp_path):
    """A `config.json` written by `lerobot-train` before `depth_cloud` existed (a benchmark checkpoint's, kept as a
    fixture) loads through `--policy.path`'s reader with its flat keys in their groups."""
    import shutil

    from lerobot.configs import PreTrainedConfig

    fixture = Path(__file__).parent / "fixtures" / "focal_config_before_depth_cloud.json"
    assert "pointcloud_num_points" in json.loads(fixture.read_text())
    (tmp_path / "ckpt").mkdir()
    shutil.copy(fixture, tmp_path / "ckpt" / "config.json")
    loaded = PreTrainedConfig.from_pretrained(tmp_path / "ckpt")
    assert isinstance(loaded, FocalConfig)
    assert loaded.depth_cloud == DepthCloudConfig() and not loaded.depth_cloud.enabled
    assert loaded.down_dims == (32, 64, 128)
    # ... and the method's flat switches in theirs (the fixture is the paper's method).
    assert (loaded.loss.kind, loaded.anchor.kind, loaded.anchor.mu, loaded.loss.freq_weight) == (
        "fco", "logit_normal", 4.0, 1e-4)
