"""What a camera input costs a CPU training step of `focal`, and which cheaper step keeps the loss curve.

    lerobot-focal-bench camera-step [--clouds DATASET_ROOT] [--image-size 84 --crop 76] [--batch 64]
                                    [--repeats 10] [--loss-steps 30] [--out docs/benchmarks]

One process, every variant from the same weights, timed round-robin (``policy_speed.time_ms``) so a shared
machine's load hits all alike: the ratios to the low-dimensional step (the grid's 9-d state + 39-d object
poses) are the result, not the milliseconds. The variants:

- ``low-dim``: the reference;
- ``cloud 512``: 512-point clouds + state, the encoder's winners-only max-pool backward (the default);
- ``cloud 512, bf16 autocast``: the forward under ``torch.autocast("cpu", torch.bfloat16)`` (what LeRobot's
  ``--policy.use_amp=true`` does on a CPU), for CPUs with AVX-512 BF16;
- ``cloud 256``: half the points, a farthest-point sample of each 512-point cloud (training on fewer points);
- ``cloud 256, bf16 autocast``: both;
- ``image``: one RGB camera (``--image-size``, random crop ``--crop``) + state through LeRobot's ResNet-18
  encoder with group norm and spatial softmax (focal's ``use_images``);
- ``image, channels-last``: the same network and batch in NHWC memory layout (oneDNN's preferred one);
- ``image, bf16 autocast`` and ``image, channels-last + bf16``.

Each cheaper variant is also trained side by side with its base, from the same weights on the same batch with
the same noise at every step (``--loss-steps`` steps for the clouds, ``--image-loss-steps`` for the images,
whose steps cost ~25 low-dim ones), and both loss curves are plotted: a variant is worth keeping only if its
curve stays on its base's.

Writes ``camera_step_cpu.json``, ``.md`` and ``.png`` (the loss curves).
"""

from __future__ import annotations

import copy
import json
import platform
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from lerobot_focal.benchmarks import train_step
from lerobot_focal.benchmarks.policy_speed import ACTION_DIM, ENV_DIM, STATE_DIM, benchmark_features, time_ms
from lerobot_focal.console import doc_parser
from lerobot_focal.constants import OBS_POINTCLOUD

IMAGE_KEY = "observation.images.front"
#: (cheaper variant, the variant it must train like)
PAIRS = (("cloud 512, bf16 autocast", "cloud 512"), ("cloud 256", "cloud 512"),
         ("cloud 256, bf16 autocast", "cloud 512"),
         ("image, channels-last", "image"), ("image, bf16 autocast", "image"),
         ("image, channels-last + bf16", "image"))


def _policy(inputs: dict, down_dims: tuple[int, ...], **config):
    from lerobot_focal.policy import FocalConfig, FocalPolicy

    torch.manual_seed(0)
    cfg = FocalConfig(device="cpu", down_dims=down_dims, input_features=inputs,
                      output_features=benchmark_features()[1], pointcloud_feature_dim=64, state_feature_dim=64,
                      use_env_state="observation.environment_state" in inputs, **config)
    return FocalPolicy(cfg).train()


def _fewer_points(clouds: torch.Tensor, points: int) -> torch.Tensor:
    from lerobot_focal.geometry.pointcloud import farthest_point_sample

    flat = clouds.flatten(0, 1).numpy()
    return torch.from_numpy(np.stack([farthest_point_sample(c, points) for c in flat])).view(
        *clouds.shape[:2], points, clouds.shape[-1])


def build_variants(batch: int, down_dims: tuple[int, ...], clouds: torch.Tensor, image_size: int,
                   crop: int) -> dict[str, tuple]:
    """name -> (policy, batch, autocast, channels_last), every family's variants from one set of weights."""
    from lerobot.configs.types import FeatureType, PolicyFeature

    g = torch.Generator().manual_seed(1)
    state = {"observation.state": PolicyFeature(type=FeatureType.STATE, shape=(STATE_DIM,))}
    common = {"observation.state": torch.randn(batch, 2, STATE_DIM, generator=g),
              "action": torch.randn(batch, 12, ACTION_DIM, generator=g),
              "action_is_pad": torch.zeros(batch, 12, dtype=torch.bool)}

    low = _policy(benchmark_features()[0], down_dims, use_images=False)
    low_data = {**common, "observation.environment_state": torch.randn(batch, 2, ENV_DIM, generator=g)}

    def cloud_family(points: torch.Tensor):
        feats = {**state, OBS_POINTCLOUD: PolicyFeature(type=FeatureType.STATE, shape=tuple(points.shape[2:]))}
        return _policy(feats, down_dims, use_images=False), {**common, OBS_POINTCLOUD: points}

    cloud, cloud_data = cloud_family(clouds)
    cloud_half, half_data = cloud_family(_fewer_points(clouds, 256))
    cloud_half.load_state_dict(cloud.state_dict())  # the encoder is blind to the number of points

    image_feats = {**state, IMAGE_KEY: PolicyFeature(type=FeatureType.VISUAL, shape=(3, image_size, image_size))}
    image = _policy(image_feats, down_dims, crop_shape=(crop, crop))
    image_data = {**common, IMAGE_KEY: torch.rand(batch, 2, 3, image_size, image_size, generator=g)}

    def clone(policy, channels_last: bool = False):
        policy = copy.deepcopy(policy)
        return policy.to(memory_format=torch.channels_last) if channels_last else policy

    return {
        "low-dim": (low, low_data, False, False),
        "cloud 512": (cloud, cloud_data, False, False),
        "cloud 512, bf16 autocast": (clone(cloud), cloud_data, True, False),
        "cloud 256": (cloud_half, half_data, False, False),
        "cloud 256, bf16 autocast": (clone(cloud_half), half_data, True, False),
        "image": (image, image_data, False, False),
        "image, channels-last": (clone(image, True), image_data, False, True),
        "image, bf16 autocast": (clone(image), image_data, True, False),
        "image, channels-last + bf16": (clone(image, True), image_data, True, True),
    }


def training_step(policy, data: dict[str, torch.Tensor], autocast: bool, channels_last: bool
                  ) -> Callable[[], float]:
    """`train_step.training_step` with the policy's own optimizer; with `channels_last` the images arrive in NHWC
    memory layout (the encoder folds the observation steps into the batch of 4-d frames)."""
    optimizer = policy.config.get_optimizer_preset().build(policy.get_optim_params())
    if channels_last:
        data = {k: _nhwc(v) if k.startswith("observation.images.") else v for k, v in data.items()}
    return train_step.training_step(policy, optimizer, data, threads=1, autocast=autocast)


def _nhwc(frames: torch.Tensor) -> torch.Tensor:
    b, t = frames.shape[:2]
    return frames.flatten(0, 1).contiguous(memory_format=torch.channels_last).unflatten(0, (b, t))


def loss_curves(variants: dict[str, tuple], steps: int, image_steps: int) -> dict[str, list[float]]:
    """Each variant trained from its weights (`image_steps` for the image family, `steps` for the clouds), the
    noise and flow times seeded per step alike."""
    curves = {}
    for name, (policy, data, autocast, channels_last) in variants.items():
        if name == "low-dim":
            continue
        step = training_step(copy.deepcopy(policy), data, autocast, channels_last)
        curve = []
        for i in range(image_steps if name.startswith("image") else steps):
            torch.manual_seed(1000 + i)
            curve.append(step())
        curves[name] = curve
    return curves


def run(out: Path, batch: int = 64, repeats: int = 10, loss_steps: int = 200, clouds_root: Path | None = None,
        image_size: int = 84, crop: int = 76, down_dims: tuple[int, ...] = (32, 64, 128),
        image_loss_steps: int = 40) -> dict:
    torch.set_num_threads(1)
    g = torch.Generator().manual_seed(2)
    clouds = (train_step.dataset_clouds(clouds_root, batch) if clouds_root
              else torch.randn(batch, 2, 512, 3, generator=g))
    if clouds.shape[2] != 512:
        raise SystemExit(f"camera-step compares 512- and 256-point clouds; {clouds_root} holds {clouds.shape[2]}-point "
                         "clouds (collect with --num_points 512)")
    variants = build_variants(batch, down_dims, clouds, image_size, crop)
    steps = {name: training_step(copy.deepcopy(p), d, a, c) for name, (p, d, a, c) in variants.items()}
    medians = time_ms(steps, "cpu", repeats, warmup=2)
    curves = loss_curves(variants, loss_steps, image_loss_steps)
    pairs = list(PAIRS)
    agreement = {}
    for a, b in pairs:
        tail = max(1, len(curves[a]) // 5)
        agreement[a] = {"base": b, "steps": len(curves[a]), "final_loss": float(np.mean(curves[a][-tail:])),
                        "base_final_loss": float(np.mean(curves[b][-tail:]))}
    for entry in agreement.values():
        entry["relative_difference"] = entry["final_loss"] / entry["base_final_loss"] - 1
    ref = medians["low-dim"]
    rows = [{"variant": n, "ms_per_step": round(ms, 1), "vs_low_dim": round(ms / ref, 2)} for n, ms in medians.items()]
    result = {"batch": batch, "repeats": repeats, "loss_steps": loss_steps, "image_loss_steps": image_loss_steps,
              "down_dims": list(down_dims),
              "clouds": str(clouds_root) if clouds_root else None, "image_size": image_size, "crop": crop,
              "threads": 1, "machine": platform.processor() or platform.machine(), "rows": rows,
              "loss_agreement": agreement, "loss_curves": curves}
    out.mkdir(parents=True, exist_ok=True)
    (out / "camera_step_cpu.json").write_text(json.dumps(result, indent=1))
    _plot(out / "camera_step_cpu.png", curves, pairs)
    (out / "camera_step_cpu.md").write_text(render(result))
    print(render(result))
    return result


def render(result: dict) -> str:
    source = f"the clouds of `{result['clouds']}`" if result["clouds"] else "Gaussian noise as clouds"
    md = [f"# What a camera input costs a CPU training step of focal (batch {result['batch']}, one thread)", "",
          f"`lerobot-focal-bench camera-step{' --clouds ' + result['clouds'] if result['clouds'] else ''}`: median "
          f"of {result['repeats']} round-robin repeats in one process, every variant from the same weights; "
          f"U-Net {'/'.join(map(str, result['down_dims']))}, encoders 64 wide; clouds: {source}; images "
          f"{result['image_size']}×{result['image_size']} cropped to {result['crop']}×{result['crop']}. "
          "The ratio to the low-dimensional step is the number to read (the machine may be shared).", "",
          "| variant | ms / step | × the low-dim step |", "|---|---|---|"]
    md += [f"| {r['variant']} | {r['ms_per_step']:.1f} | {r['vs_low_dim']:.2f}× |" for r in result["rows"]]
    md += ["", "Each cheaper variant trained side by side with its base (same weights, batch and noise at every step): "
               "the loss, mean of the last fifth of the steps ([curves](camera_step_cpu.png)):", "",
           "| variant | its base | steps | loss | base's loss | difference |", "|---|---|---|---|---|---|"]
    md += [f"| {a} | {e['base']} | {e['steps']} | {e['final_loss']:.4f} | {e['base_final_loss']:.4f} | "
           f"{e['relative_difference'] * 100:+.2f} % |" for a, e in result["loss_agreement"].items()]
    return "\n".join(md) + "\n"


def _plot(path: Path, curves: dict[str, list[float]], pairs: list[tuple[str, str]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from lerobot_focal.figures import save_png

    fig, axes = plt.subplots(1, len(pairs), figsize=(3.4 * len(pairs), 3.0), squeeze=False)
    for ax, (a, b) in zip(axes.flat, pairs, strict=True):
        window = max(1, len(curves[a]) // 10)  # the per-step noise draw dominates a single step's loss
        for name, color, style in ((b, "C0", "-"), (a, "C1", "--")):
            smooth = np.convolve(curves[name][: len(curves[a])], np.ones(window) / window, mode="valid")
            ax.plot(np.arange(len(smooth)) + window, smooth, color=color, ls=style, label=name)
        ax.set_xlabel("training step")
        ax.set_ylabel(f"loss, running mean of {window}")
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
    fig.suptitle("cheaper camera-input steps against their base: same weights, batch and noise", fontsize=9)
    save_png(fig, path, dpi=100)


def main(argv: list[str] | None = None) -> int:
    p = doc_parser(__doc__, "lerobot-focal-bench camera-step")
    p.add_argument("--batch", type=int, default=64)
    p.add_argument("--repeats", type=int, default=10)
    p.add_argument("--loss-steps", type=int, default=200, help="steps each cloud variant trains beside its base")
    p.add_argument("--image-loss-steps", type=int, default=40, help="steps each image variant trains beside its base")
    p.add_argument("--clouds", type=Path, default=None, metavar="DATASET_ROOT",
                   help="take the clouds from this LeRobotDataset (e.g. a grid's point-cloud demos); Gaussian noise "
                        "otherwise, whose clouds have more max-pool winners than a scene's")
    p.add_argument("--image-size", type=int, default=84)
    p.add_argument("--crop", type=int, default=76)
    p.add_argument("--out", type=Path, default=Path("docs/benchmarks"))
    args = p.parse_args(argv)
    run(args.out, args.batch, args.repeats, args.loss_steps, args.clouds, args.image_size, args.crop,
        image_loss_steps=args.image_loss_steps)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
