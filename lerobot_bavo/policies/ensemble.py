"""Temporal ensembling of overlapping action chunks (ACT's inference scheme, Zhao et al. 2023).

Why: a chunking policy that executes `k` actions of each chunk switches, every `k` steps, to a chunk sampled
afresh from a new observation; consecutive chunks of a flow policy can disagree (another noise draw, another
mode), and the switch shows as a jerk. With ensembling a chunk is still generated every `k` steps, but the
action executed at step t is the weighted mean of every stored chunk's prediction for step t, so chunks that
overlap are blended instead of cut over. Weights follow ACT (and LeRobot's `ACTTemporalEnsembler`):
w_i = exp(-coeff * i), i = 0 for the oldest prediction, so coeff > 0 favours older predictions (smoother),
coeff < 0 newer ones (more reactive), 0 is the plain mean.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor


def ensemble_weights(n: int, coeff: float, dtype=torch.float32, device=None) -> Tensor:
    """(n,) weights exp(-coeff * i) of n predictions ordered oldest first, normalised to sum to 1."""
    if n < 1:
        raise ValueError(f"need at least one prediction to ensemble. Got {n}.")
    w = torch.exp(-coeff * torch.arange(n, dtype=torch.float64))
    return (w / w.sum()).to(dtype=dtype, device=device)


def ensembled_action(predictions: list[Tensor], coeff: float) -> Tensor:
    """Weighted mean (B, A) of the predictions (each (B, A), oldest first) for one step."""
    stacked = torch.stack(predictions)  # (n, B, A)
    w = ensemble_weights(len(predictions), coeff, dtype=stacked.dtype, device=stacked.device)
    return torch.einsum("n,nba->ba", w, stacked)


class ChunkEnsemble:
    """The chunks generated so far in an episode and the step they start at; one per policy, reset with it.

    `interval` is the number of control steps between two chunks (the policy's `n_action_steps`); a chunk of
    length L covers the L steps from the one it was generated at, and is forgotten once they have passed.
    """

    def __init__(self, coeff: float, interval: int):
        if not math.isfinite(coeff):
            raise ValueError(f"`coeff` must be a finite number. Got {coeff}.")
        if interval < 1:
            raise ValueError(f"`interval` must be >= 1. Got {interval}.")
        self.coeff = coeff
        self.interval = interval
        self.reset()

    def reset(self) -> None:
        self.step = 0
        self._chunks: list[tuple[int, Tensor]] = []  # (first step it covers, (B, L, A)), oldest first

    def needs_chunk(self) -> bool:
        """Whether the current step is one at which a new chunk is generated."""
        return self.step % self.interval == 0

    def add(self, chunk: Tensor) -> None:
        """Store a chunk (B, L, A) whose first action is for the current step."""
        if chunk.ndim != 3 or chunk.shape[1] < self.interval:
            raise ValueError(f"a chunk must be (B, L, A) with L >= the interval {self.interval}. "
                             f"Got {tuple(chunk.shape)}.")
        self._chunks.append((self.step, chunk))

    def pop(self) -> Tensor:
        """The ensembled action (B, A) for the current step; advances to the next step."""
        self._chunks = [(s, c) for s, c in self._chunks if self.step - s < c.shape[1]]
        if not self._chunks:
            raise RuntimeError("no stored chunk covers this step: call `add` when `needs_chunk()` is true.")
        action = ensembled_action([c[:, self.step - s] for s, c in self._chunks], self.coeff)
        self.step += 1
        return action
