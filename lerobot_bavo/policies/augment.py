"""Training-time batch augmentations shared by ManiFlow and A-FAR.

Occluder dropout: the Stage occluder is placed on the line of sight to the current target and stays
in the scene, so in Stage demonstrations its points tell a policy where the target is; a policy that
learns that cue fails when the panel is absent (Clean) or moves at unexpected times (Random-time)
(docs/results/occluder_shortcut.md). With probability `p` per training sample, the points labelled
as the occluder's (`observation.teacher.occluder`, made with the training view) are moved to the
end of the cloud in both observation steps. Clouds are stored in farthest-point-sampling order and
the policy reads the first `points_per_step` of them, so the sample then shows the remaining scene
points in their FPS order: the cloud of the same scene with the panel left out, as in Clean. The
labels are training-only: at deployment the policy sees whatever blocks the view.
"""

from __future__ import annotations

import torch
from torch import Tensor


def points_last_order(labels: Tensor, chosen: Tensor) -> Tensor:
    """Per-cloud point order (..., N) that keeps unlabelled points first, in their stored order, where
    `chosen`.

    Args:
        labels: (B, ..., N) bool, True for the points to move back.
        chosen: (B,) bool, the samples to reorder; the others keep the identity order.
    """
    key = (labels & chosen.reshape(-1, *([1] * (labels.ndim - 1)))).to(torch.uint8)
    return torch.sort(key, dim=-1, stable=True).indices


def reorder_points(x: Tensor, order: Tensor) -> Tensor:
    """Gather the points of `x` by `order` along the point axis.

    Args:
        x: (B, [To,] N * c) flat per-point features (the dataset layout) or (B, [To,] N).
        order: (B, To, N) from `points_last_order`; a feature without the time axis uses the last step's
        order.
    """
    n = order.shape[-1]
    if x.ndim == order.ndim - 1:  # no time axis
        order = order[:, -1]
    if x.shape[:-1] != order.shape[:-1] or x.shape[-1] % n:
        raise ValueError(f"cannot reorder a feature of shape {tuple(x.shape)} by a point order of shape "
                         f"{tuple(order.shape)}")
    c = x.shape[-1] // n
    pts = x.reshape(*x.shape[:-1], n, c)
    out = torch.gather(pts, -2, order[..., None].expand(*order.shape, c))
    return out.reshape(x.shape)


def occluder_dropout(batch: dict, labels: Tensor, point_keys: list[str], p: float,
                     generator: torch.Generator | None = None, keep: Tensor | None = None) -> dict:
    """A copy of `batch` in which, for each sample with probability `p`, the labelled points of every key in
    `point_keys` go behind the others (see the module docstring).

    Args:
        labels: (B, To, N) or (B, N): True on the occluder's points.
        point_keys: the per-point features to reorder together (the cloud and point-aligned teacher targets).
        keep: (B,) bool, samples whose occluder points always stay (e.g. the frames the demonstrator spends
            recovering the view, whose camera motion the panel explains); None: every sample may be chosen.
    """
    if labels.ndim == 2:
        labels = labels[:, None]
    b = labels.shape[0]
    chosen = torch.rand(b, generator=generator, device=labels.device) < p
    if keep is not None:
        chosen = chosen & ~keep.reshape(b).bool()
    order = points_last_order(labels.bool(), chosen)
    out = dict(batch)
    for key in point_keys:
        out[key] = reorder_points(batch[key], order)
    return out
