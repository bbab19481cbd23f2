"""Pre/post-processors of the A-FAR policy: the ManiFlow pipeline (see `processor_maniflow`).

Pre: rename -> add batch dim -> device -> feature layout -> normalise (MIN_MAX for STATE, including the point
cloud with per-channel stats, and ACTION). Post: unnormalise -> cpu. The training-only teacher keys
(`observation.teacher.*`) are dropped from the config's input features by `validate_features()`, so the
normaliser leaves them untouched and evaluation never needs them.
"""

from typing import Any

import torch
from lerobot.processor import PolicyAction, PolicyProcessorPipeline

from ..maniflow.processor_maniflow import make_maniflow_pre_post_processors
from .configuration_afar import AfarConfig


def make_afar_pre_post_processors(
    config: AfarConfig,
    dataset_stats: dict[str, dict[str, torch.Tensor]] | None = None,
) -> tuple[
    PolicyProcessorPipeline[dict[str, Any], dict[str, Any]],
    PolicyProcessorPipeline[PolicyAction, PolicyAction],
]:
    """Creates the pre- and post-processing pipelines for A-FAR.

    Args:
        config: The A-FAR policy configuration (after `validate_features()`, which the policy's constructor
            calls).
        dataset_stats: Dataset statistics (min/max per feature, per last-axis element). Defaults to None.

    Returns:
        The pre-processor and post-processor pipelines.
    """
    return make_maniflow_pre_post_processors(config, dataset_stats)
