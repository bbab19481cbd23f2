"""Action chunks relative to the current state (`--policy.relative_action_dims`, ManiFlow and A-FAR).

Why: on the grasp-limited tasks the policies do not fit even their own demonstrations (a chunk errs by 20-24
mrad on training frames; docs/results/first_grasp.md). An absolute joint target is normalised over the
joint's whole range in the data; its step from where the arm is now is a small fraction of that range. A
network whose error is a fixed fraction of what it predicts then errs less in radians when it predicts the
step, re-scaled to about [-1, 1], than when it predicts the target (docs/results/relative_actions.md).

Everything here is in the MIN_MAX-normalised units the policy works in (`x_n = 2 (x - min) / (max - min) -
1`, per dimension, with the dataset's action and state statistics). For a dimension d in `dims`, with state
entry d being the same joint as action entry d (BAVO's 21-dim state and action share one layout):

    r_d = (a_n,d - s_n,d) / scale_d        (to_relative; s_n the current, last observation step)
    a_n,d = s_n,d + scale_d * r_d          (to_absolute; exactly its inverse)

`a_n - s_n` mixes the two features' normalisations (their min / max differ slightly), so r is the joint's
step only up to a fixed affine term; the map stays exactly invertible, which is what training and inference
need. `scale_d` makes r about unit-sized: a high quantile of |a_n - s_n| over every (frame, chunk offset) of
the training data (`lerobot_bavo.datasets.relative_actions`, whose command prints the flags for a dataset).
"""

from __future__ import annotations

import torch
from torch import Tensor


def current_state(state: Tensor) -> Tensor:
    """(B, S) state of the current step from (S,), (B, S) or (B, To, S) (the last observation step)."""
    if state.ndim == 1:
        return state[None]
    if state.ndim == 2:
        return state
    if state.ndim == 3:
        return state[:, -1]
    raise ValueError(f"Expected a state of shape (S,), (B, S) or (B, To, S). Got {tuple(state.shape)}.")


def _offsets(chunk: Tensor, state: Tensor, dims: Tensor, scales: Tensor) -> tuple[Tensor, Tensor]:
    if chunk.ndim != 3:
        raise ValueError(f"Expected an action chunk (B, H, A). Got {tuple(chunk.shape)}.")
    s = current_state(state).to(chunk.dtype)
    if s.shape[0] != chunk.shape[0]:
        raise ValueError(f"State batch {s.shape[0]} does not match the chunk's {chunk.shape[0]}.")
    return s[:, None, :].index_select(-1, dims), scales.to(chunk.dtype)


def to_relative(chunk: Tensor, state: Tensor, dims: Tensor, scales: Tensor) -> Tensor:
    """Normalised absolute chunk (B, H, A) -> the chunk the network predicts: dims `dims` (a long tensor)
    replaced by (a_n - s_n) / scale, the others unchanged. `state`: normalised, (B, S) or (B, To, S)."""
    if dims.numel() == 0:
        return chunk
    ref, sc = _offsets(chunk, state, dims, scales)
    return chunk.index_copy(-1, dims, (chunk.index_select(-1, dims) - ref) / sc)


def to_absolute(chunk: Tensor, state: Tensor, dims: Tensor, scales: Tensor) -> Tensor:
    """The inverse of `to_relative`: predicted chunk (B, H, A) -> normalised absolute chunk."""
    if dims.numel() == 0:
        return chunk
    ref, sc = _offsets(chunk, state, dims, scales)
    return chunk.index_copy(-1, dims, chunk.index_select(-1, dims) * sc + ref)


def as_index(dims: tuple[int, ...]) -> Tensor:
    """`dims` as the long tensor `to_relative` / `to_absolute` take."""
    return torch.tensor(dims, dtype=torch.long)
