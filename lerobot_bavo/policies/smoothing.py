"""A first-order low-pass on chosen action dimensions at inference (`smoothed_action_dims`,
`action_smoothing_alpha`).

Why: a flow policy's command for a joint it is unsure of jitters from one control step to the next, inside
an executed chunk as well as between chunks. When that joint's position is part of the state the next chunk
is conditioned on (the camera arm's, on BAVO-Bench), the jitter the arm follows walks the state, and with it
the camera's view, away. Filtering the sent command, a_t = a_{t-1} + alpha (u_t - a_{t-1}) with u_t the
policy's command, keeps slow motion and removes most of the step-to-step jitter: white jitter keeps
sqrt(alpha / (2 - alpha)) of its standard deviation, and the filter's time constant is about
(1 - alpha) / alpha control steps. It reads only the policy's own commands (nothing privileged) and is applied
to the normalised actions, which equals filtering the joint commands because MIN_MAX normalisation is affine
per dimension. The filter restarts with each episode; its first command passes through. It also slows the
motions a policy needs to be quick (a view recovery): what it did on Cube Handoff is in
docs/results/learning_rate.md.
"""

from __future__ import annotations

import math

from torch import Tensor


def check_smoothing(dims: tuple[int, ...], alpha: float, binary_dims: tuple[int, ...] = ()) -> None:
    """Raise ValueError unless `alpha` is in (0, 1] and `dims` are distinct indices >= 0 that are not
    executed as binary commands (a filtered gripper command would no longer be one of its levels)."""
    if not (math.isfinite(alpha) and 0.0 < alpha <= 1.0):
        raise ValueError(f"`action_smoothing_alpha` must be in (0, 1] (1 = no smoothing). Got {alpha}.")
    if len(set(dims)) != len(dims) or any(d < 0 for d in dims):
        raise ValueError(f"`smoothed_action_dims` must be distinct indices >= 0. Got {list(dims)}.")
    if both := sorted(set(dims) & set(binary_dims)):
        raise ValueError(f"`smoothed_action_dims` {both} are also `binary_action_dims`: a low-passed binary "
                         "command is no longer binary. Leave the grippers out of the smoothed dimensions.")


def low_pass_step(previous: Tensor, command: Tensor, alpha: float) -> Tensor:
    """previous + alpha * (command - previous): one step of the first-order low-pass (any matching shapes)."""
    return previous + alpha * (command - previous)


class ActionLowPass:
    """The filter's state for one episode: the last action sent, on `dims` of a (B, A) action."""

    def __init__(self, dims: tuple[int, ...], alpha: float):
        check_smoothing(tuple(dims), alpha)
        self.dims, self.alpha = list(dims), float(alpha)
        self.reset()

    def reset(self) -> None:
        self._sent: Tensor | None = None

    def __call__(self, action: Tensor) -> Tensor:
        """The action (B, A) to send: `action` with its `dims` low-passed; the input is not modified."""
        if not self.dims or self.alpha == 1.0:  # off: the commands as they are, bit for bit
            return action
        out = action.clone()
        if self._sent is not None:
            out[..., self.dims] = low_pass_step(self._sent, action[..., self.dims], self.alpha)
        self._sent = out[..., self.dims].clone()
        return out
