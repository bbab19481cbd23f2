"""Pre/post-processors of the ManiFlow policy (also used by A-FAR).

Pre: rename -> add batch dim -> device -> feature layout (`maniflow_feature_layout`) -> normalise (MIN_MAX for
STATE and ACTION). Post: unnormalise -> cpu. This is LeRobot's default pipeline plus one reshaping step.

Point-cloud normalisation: `observation.point_cloud` is a STATE-typed feature. With the (N, 6) layout
LeRobot's stats are per last-axis channel, shape (6,), and the normaliser's `2 * (x - min) / (max - min) - 1`
broadcasts over (B, To, N, 6): exactly ManiFlow's per-channel `limits` normaliser. BAVO datasets store the
cloud flat, (N * 6,), with the per-channel stats tiled to (N * 6,) (LeRobot's dataset tools fail on 2-D
features), which normalises the same way. The env, however, returns (N, 6) clouds at evaluation, which do not
broadcast against (N * 6,) stats: the layout step reshapes every observation feature to the layout the policy
was trained with (the normaliser's), so both layouts work on both sides. Teacher keys
(`observation.teacher.*`) are not in the config's input features after `validate_features()`, so they pass
through unnormalised and unreshaped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import torch
from lerobot.configs import FeatureType, PipelineFeatureType, PolicyFeature
from lerobot.processor import (
    ObservationProcessorStep,
    PolicyAction,
    PolicyProcessorPipeline,
    ProcessorStepRegistry,
    make_default_policy_processor_steps,
    make_policy_processor_pipelines,
)

from lerobot_bavo.features import OBS_POINT_CLOUD, unflatten_points

from .configuration_maniflow import ManiFlowConfig


def per_channel_point_stats(stats: dict[str, Any], n_points: int, channels: int) -> dict[str, torch.Tensor]:
    """Point-cloud stats made independent of point order: reduce per-slot stats to per-channel, tile back.

    Why: a flat (N * C,) cloud's stats may be element-wise, one min/max per point *slot*. `bavo-collect`
    writes them tiled per channel, but LeRobot's dataset tools (delete / split / merge episodes, stats
    recomputation) rebuild the global stats from element-wise per-episode stats, so after an edit every slot
    gets its own range and the same frame normalises differently depending on point order. Reducing over the
    slots gives exactly the per-channel min and max (the min of per-slot minima is the minimum over all
    points), so the MIN_MAX normaliser that ManiFlow uses is the same however the dataset was produced. `mean`
    and `std` are combined assuming equal counts per slot (true: every frame has N points); quantiles, which
    cannot be combined exactly and are not used by MIN_MAX, become the mean over slots. `count` is kept.

    Args:
        stats: LeRobot stats of `observation.point_cloud` (arrays or tensors of shape (N * C,) or (N, C), or
            already per-channel (C,)).
        n_points, channels: N and C.

    Returns:
        Stats of shape (N * C,) (or (N, C) when given so) in which every slot holds its channel's value.
    """
    out: dict[str, torch.Tensor] = {}
    for name, value in stats.items():
        v = torch.as_tensor(value)
        if name == "count" or v.numel() not in (n_points * channels,):
            out[name] = v
            continue
        shape = v.shape
        per_slot = unflatten_points(v, n_points, channels).to(torch.float64)
        if name == "min":
            red = per_slot.min(0).values
        elif name == "max":
            red = per_slot.max(0).values
        elif name == "std" and "mean" in stats:
            means = unflatten_points(torch.as_tensor(stats["mean"]), n_points, channels).to(torch.float64)
            red = ((per_slot**2 + means**2).mean(0) - means.mean(0) ** 2).clamp_min(0).sqrt()
        else:
            red = per_slot.mean(0)
        out[name] = red.repeat(n_points).reshape(shape).to(v.dtype)
    return out


@ProcessorStepRegistry.register(name="maniflow_feature_layout")
@dataclass
class FeatureLayoutProcessorStep(ObservationProcessorStep):
    """Reshape observation features to their configured layout: (..., N, C) <-> flat (..., N * C).

    For every key in `shapes`, the trailing dimensions of the tensor whose product equals the configured
    size are reshaped to the configured shape; tensors already in that layout, and keys absent from the
    observation, are left alone.

    Attributes:
        shapes: feature key -> configured shape (e.g. {"observation.point_cloud": [1536]}).
    """

    shapes: dict[str, list[int]] = field(default_factory=dict)

    @classmethod
    def from_features(cls, features: dict[str, PolicyFeature]) -> FeatureLayoutProcessorStep:
        return cls(
            shapes={
                k: list(ft.shape)
                for k, ft in features.items()
                if ft.type in (FeatureType.STATE, FeatureType.ENV) and math.prod(ft.shape) > 1
            }
        )

    def observation(self, observation: dict[str, Any]) -> dict[str, Any]:
        for key, shape in self.shapes.items():
            value = observation.get(key)
            if not isinstance(value, torch.Tensor):
                continue
            shape = tuple(shape)
            if value.ndim >= len(shape) and tuple(value.shape[value.ndim - len(shape) :]) == shape:
                continue
            size, m = math.prod(shape), 0
            trailing = 1
            while trailing < size and m < value.ndim:
                m += 1
                trailing *= value.shape[-m]
            if not (m and trailing == size):
                raise ValueError(
                    f"'{key}' has shape {tuple(value.shape)}, but the policy was trained on {list(shape)} "
                    "per step "
                    f"({size} values): the observation does not match the checkpoint (e.g. another point "
                    "count or "
                    "image size); build the env with the checkpoint's settings"
                )
            observation[key] = value.reshape(*value.shape[: value.ndim - m], *shape)
        return observation

    def get_config(self) -> dict[str, Any]:
        return {"shapes": {k: list(v) for k, v in self.shapes.items()}}

    def transform_features(
        self, features: dict[PipelineFeatureType, dict[str, PolicyFeature]]
    ) -> dict[PipelineFeatureType, dict[str, PolicyFeature]]:
        return features


def make_maniflow_pre_post_processors(
    config: ManiFlowConfig,
    dataset_stats: dict[str, dict[str, torch.Tensor]] | None = None,
) -> tuple[
    PolicyProcessorPipeline[dict[str, Any], dict[str, Any]],
    PolicyProcessorPipeline[PolicyAction, PolicyAction],
]:
    """Creates the pre- and post-processing pipelines for ManiFlow (and A-FAR).

    Args:
        config: The policy configuration; call `validate_features()` first (the policy's constructor does) so
            that training-only teacher keys are neither reshaped nor normalised.
        dataset_stats: Dataset statistics (min/max per feature, per last-axis element). Defaults to None. The
            point cloud's are reduced to per-channel values first (`per_channel_point_stats`).

    Returns:
        The pre-processor and post-processor pipelines.
    """
    if dataset_stats is not None:
        bad = sorted(f"{key}.{name}" for key, st in dataset_stats.items() if key in config.input_features
                     or key in config.output_features for name, v in st.items()
                     if name in ("min", "max", "mean", "std") and bool(torch.isnan(torch.as_tensor(v)).any()))
        if bad:
            raise ValueError(f"dataset statistics hold NaN in {bad}: every normalised input would be NaN; "
                             "recompute the dataset's stats (meta/stats.json)")
    if dataset_stats is not None and config.uses_point_cloud and OBS_POINT_CLOUD in dataset_stats:
        dataset_stats = dict(dataset_stats)
        dataset_stats[OBS_POINT_CLOUD] = per_channel_point_stats(
            dataset_stats[OBS_POINT_CLOUD], config.num_points, config.point_channels
        )
    steps = make_default_policy_processor_steps(config, dataset_stats, normalizer_device=config.device)
    layout = FeatureLayoutProcessorStep.from_features(config.input_features)
    return make_policy_processor_pipelines(
        input_steps=[
            steps.rename_observations,
            steps.add_batch_dim,
            steps.to_device,
            layout,
            steps.normalize,
        ],
        output_steps=[steps.unnormalize, steps.to_cpu],
    )
