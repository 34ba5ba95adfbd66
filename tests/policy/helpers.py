"""Small FocalConfig/FocalPolicy builders shared by the policy tests."""

from lerobot.configs.types import FeatureType, PolicyFeature

from lerobot_focal.policy import FocalConfig, FocalPolicy

SMALL_UNET = (16, 32, 64)


def small_config(*, state=9, pointcloud=(64, 3), image=None, action=3, **overrides) -> FocalConfig:
    inputs = {}
    if state:
        inputs["observation.state"] = PolicyFeature(FeatureType.STATE, (state,))
    if pointcloud:
        inputs["observation.pointcloud"] = PolicyFeature(FeatureType.STATE, tuple(pointcloud))
    if image:
        inputs["observation.images.front"] = PolicyFeature(FeatureType.VISUAL, tuple(image))
    kwargs = dict(
        device="cpu",
        down_dims=SMALL_UNET,
        input_features=inputs,
        output_features={"action": PolicyFeature(FeatureType.ACTION, (action,))},
    )
    kwargs.update(overrides)
    return FocalConfig(**kwargs)


def small_policy(**kw) -> FocalPolicy:
    return FocalPolicy(small_config(**kw))
