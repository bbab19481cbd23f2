"""Bounds on every size a policy config or a checkpoint may ask for, in one table (`BOUNDS`).

Why: a checkpoint's `config.json` is input we did not write, and its sizes turn into allocations before
anything else can fail. `"num_inference_steps": 1000000000` made `bavo-eval` precompute a billion-step sampler
schedule (past 6 GB, then it hung); an input shape of 3 M points or a 20 000 x 20 000 image made the env build
that cloud or render that image; a negative `dit_hidden_dim` failed deep inside torch with a bare traceback.
Every bound here is generous: widths up to 4096 and 64 layers (the `paper` preset is 768 wide, 12 layers), 64
x the benchmark's 256 points, 4096-pixel image sides. They refuse absurd values only, and every problem names
the field and its bound.

Pure and import-free (standard library only), so the env, which must not import torch, checks its observation
settings with the same table as the policy configs (`features.ObservationSettings`,
`checkpoints.env_settings`, `ManiFlowConfig` / `AfarConfig`).
"""

from __future__ import annotations

import math
import numbers
import reprlib
from collections.abc import Mapping

MAX_POINTS = 16_384  # points per cloud: 64 x the benchmark's 256
MAX_IMAGE_SIDE = 4096  # pixels per image side
MAX_WIDTH = 4096  # any layer width (paper preset: 768)
MAX_DEPTH = 64  # blocks / layers (paper preset: 12)
MAX_HEADS = 64
MAX_RATIO = 16.0  # MLP / FFN width relative to the model width (paper: 4)
MAX_LIST_LENGTH = 16  # entries of a list of widths (point_encoder_hidden_dims)
# Elements of one non-image feature (state, action, flat point cloud, object poses, training-only teacher
# features): the largest cloud with 64 channels a point, 1 Mi (a (N, 6) cloud at MAX_POINTS is 96 Ki).
MAX_FEATURE_SIZE = MAX_POINTS * 64
# layers x width^2 of a transformer stack: ~20 width^2 parameters per block, so 64 Mi is ~1.3 G parameters
# (5 GB in float32, twice that with the EMA copy); the paper preset is 12 x 768^2 = 7 Mi.
MAX_STACK_SIZE = 1 << 26

# field -> (lowest, highest), both allowed. A field a config or a checkpoint lacks, or leaves at None (a size
# preset fills it later), is not checked.
BOUNDS: dict[str, tuple[float, float]] = {
    # what the env observes (ObservationSettings, BavoEnvConfig, a checkpoint's input shapes)
    "n_points": (2, MAX_POINTS),
    "image_height": (16, MAX_IMAGE_SIDE),
    "image_width": (16, MAX_IMAGE_SIDE),
    # time: observation steps, the predicted chunk, the sampler's schedule (precomputed per step)
    "n_obs_steps": (1, 32),
    "horizon": (1, 1000),
    "n_action_steps": (1, 1000),
    "num_inference_steps": (1, 1000),
    # ManiFlow's sizes
    "dit_hidden_dim": (1, MAX_WIDTH),
    "dit_num_layers": (1, MAX_DEPTH),
    "dit_num_heads": (1, MAX_HEADS),
    "dit_mlp_ratio": (0.01, MAX_RATIO),
    "time_freq_dim": (2, MAX_WIDTH),
    "time_embed_hidden_dim": (1, MAX_WIDTH),
    "point_feature_dim": (1, MAX_WIDTH),
    "state_feature_dim": (1, MAX_WIDTH),
    "point_encoder_hidden_dims": (1, MAX_WIDTH),  # each entry
    "points_per_step": (0, MAX_POINTS),  # 0 = all
    # A-FAR's sizes
    "wqf_hidden_dim": (1, MAX_WIDTH),
    "wqf_num_blocks": (1, MAX_DEPTH),
    "wqf_num_heads": (1, MAX_HEADS),
    "wqf_ffn_ratio": (0.01, MAX_RATIO),
    "relation_num_points": (0, MAX_POINTS),  # 0 = all
}
# (depth field, width field) of each transformer stack, bounded together by MAX_STACK_SIZE.
STACKS = (("dit_num_layers", "dit_hidden_dim"), ("wqf_num_blocks", "wqf_hidden_dim"))
INTEGER_FIELDS = frozenset(BOUNDS) - {"dit_mlp_ratio", "wqf_ffn_ratio"}

_BOUNDED_REPR = reprlib.Repr(
    maxstring=60, maxother=60, maxlist=6, maxtuple=6, maxdict=6, maxset=6, maxlevel=3, maxlong=40
)


def short_repr(value) -> str:
    """`repr(value)` cut to a few dozen characters and items (reprlib), for error messages about input we did
    not write: a full repr of a large or aliased structure (a YAML alias bomb) costs seconds and gigabytes."""
    return _BOUNDED_REPR.repr(value)


def _number_problem(name: str, value, low: float, high: float) -> str | None:
    integer = name in INTEGER_FIELDS
    if isinstance(value, bool) or not isinstance(value, numbers.Integral if integer else numbers.Real):
        kind = "an integer" if integer else "a number"
        return f"`{name}` must be {kind} in [{low}, {high}], got {short_repr(value)}"
    if not (low <= value <= high):  # also refuses NaN
        return f"`{name}` must be in [{low}, {high}], got {short_repr(value)}"
    return None


def bound_problems(values: Mapping[str, object]) -> list[str]:
    """One message per value of `values` that `BOUNDS` names and that is out of its bounds (None: not
    checked), and per transformer stack larger than `MAX_STACK_SIZE`."""
    problems = []
    for name, value in values.items():
        if name not in BOUNDS or value is None:
            continue
        low, high = BOUNDS[name]
        if isinstance(value, (list, tuple)):
            if len(value) > MAX_LIST_LENGTH:
                problems.append(f"`{name}` may list at most {MAX_LIST_LENGTH} widths, got {len(value)}")
                continue
            problems += [p for v in value if (p := _number_problem(name, v, low, high))]
        elif (p := _number_problem(name, value, low, high)) is not None:
            problems.append(p)
    for depth, width in STACKS:
        d, w = values.get(depth), values.get(width)
        if all(isinstance(x, numbers.Integral) and not isinstance(x, bool) and x > 0 for x in (d, w)) \
                and int(d) * int(w) ** 2 > MAX_STACK_SIZE:
            problems.append(
                f"`{depth}` x `{width}`^2 = {d} x {w}^2 exceeds {MAX_STACK_SIZE} (about 1.3 G parameters; "
                f"the paper preset is 12 x 768^2)"
            )
    return problems


def feature_problems(features: Mapping[str, object] | None) -> list[str]:
    """One message per feature whose shape is not positive integers, or is larger than an image of
    `MAX_IMAGE_SIDE` pixels a side (3-D shapes) or `MAX_FEATURE_SIZE` elements (any other). A feature is a
    LeRobot `PolicyFeature` (`.shape`) or a JSON dict (`["shape"]`)."""
    problems = []
    for key, feature in (features or {}).items():
        shape = feature.get("shape") if isinstance(feature, Mapping) else getattr(feature, "shape", None)
        if not (
            isinstance(shape, (list, tuple))
            and shape
            and all(isinstance(n, numbers.Integral) and not isinstance(n, bool) and n > 0 for n in shape)
        ):
            problems.append(f"feature {short_repr(key)} must have a shape of positive integers, got "
                            f"{short_repr(shape)}")
        elif len(shape) == 3 and max(shape) > MAX_IMAGE_SIDE:
            problems.append(
                f"feature {short_repr(key)} has shape {short_repr(list(shape))}: an image side is at most "
                f"{MAX_IMAGE_SIDE}"
            )
        elif len(shape) != 3 and math.prod(int(n) for n in shape) > MAX_FEATURE_SIZE:
            problems.append(f"feature {short_repr(key)} has shape {short_repr(list(shape))}: at most "
                            f"{MAX_FEATURE_SIZE} elements")
    return problems


def check_config_bounds(config) -> None:
    """Raise ValueError listing every field of the policy `config` outside `BOUNDS` and every feature too
    large (`bound_problems`, `feature_problems`). Called from the configs' `__post_init__`, so a checkpoint's
    config.json is refused when it is read, before any module or schedule is built."""
    values = {name: getattr(config, name) for name in BOUNDS if hasattr(config, name)}
    problems = bound_problems(values)
    problems += feature_problems(getattr(config, "input_features", None))
    problems += feature_problems(getattr(config, "output_features", None))
    if problems:
        raise ValueError(f"{type(config).__name__}: " + "; ".join(problems))
