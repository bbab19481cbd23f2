"""The benchmark metrics (paper Sec. 3, Appendix A): V, CVG, SR, TPS and Joint, as pure accounting.

This module imports numpy only. The pixel counts that feed V (N^occ and N^noOcc, from segmentation
renders with and without the occluder) come from `lerobot_bavo.envs.visibility`.

- ``normalized_visibility``  Eq. 1: V_e(C, x) = N^occ_e(C, x) / N^noOcc_e(C, x), 0 when N^noOcc = 0
- ``event_cvg``              Eq. 2: CVG_e = 1/H sum_{h=0}^{H-1} [V_e(C_{t+h}, x_{t+h}) - V_e(C_t, x_{t+h})]
- ``episode_cvg`` / ``aggregate_cvg``  Appendix A: truncated events are excluded (not padded); events
  are averaged within an episode, then episodes are averaged, so each episode weighs the same.
- ``success_rate``, ``task_progress_score`` (percent), ``joint_score`` = SR x CVG / 100 (Table 4).
- ``CVGEventRecord`` / ``CVGAccumulator``: per-step bookkeeping the environment drives.

Units: V and CVG_e are fractions in [0, 1] / [-1, 1]; SR and TPS are percent; the paper reports
CVG as 100 x CVG in percentage points (pp), which is what ``joint_score`` expects.
"""

from __future__ import annotations

import math
import operator
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "CVG_HORIZON",
    "NUM_MILESTONES",
    "normalized_visibility",
    "event_cvg",
    "episode_cvg",
    "aggregate_cvg",
    "success_rate",
    "task_progress_score",
    "milestone_depth_counts",
    "wilson_interval",
    "joint_score",
    "CVGEventRecord",
    "CVGAccumulator",
    "CELL_METRICS",
    "cell_metrics",
]

CVG_HORIZON = 60  # H, control steps (2.4 s at 25 Hz), Appendix A
NUM_MILESTONES = 5  # M1..M5 per task; M5 is success (reward = depth / NUM_MILESTONES)

# The metrics of a (task, condition) cell, in the order tables show them: key in results.json -> column label.
# A new metric is one entry here and one line in `cell_metrics`; `bavo-eval`, the grid and the scripts read
# both.
CELL_METRICS = {"sr": "SR (%)", "tps": "TPS (%)", "cvg": "CVG (pp)", "joint": "Joint"}


# --------------------------------------------------------------------------------------------
# Visibility
# --------------------------------------------------------------------------------------------
def normalized_visibility(n_occ: int, n_no_occ: int) -> float:
    """Eq. 1: fraction of the target's otherwise-visible pixels that the occluder leaves visible.

    Args:
        n_occ: visible target pixels rendered with the benchmark occluder.
        n_no_occ: visible target pixels from the same camera and state without the occluder.

    Returns:
        n_occ / n_no_occ in [0, 1]; 0.0 when n_no_occ == 0 (target not visible anyway, Appendix A).

    Raises:
        TypeError: for non-integer counts.
        ValueError: for negative counts, or n_occ > n_no_occ (an occluder can only hide pixels).
    """
    n_occ, n_no_occ = operator.index(n_occ), operator.index(n_no_occ)
    if n_occ < 0 or n_no_occ < 0:
        raise ValueError(f"pixel counts must be >= 0, got n_occ={n_occ}, n_no_occ={n_no_occ}")
    if n_occ > n_no_occ:
        raise ValueError(
            f"n_occ={n_occ} > n_no_occ={n_no_occ}: adding the occluder cannot reveal target pixels"
        )
    if n_no_occ == 0:
        return 0.0
    return n_occ / n_no_occ


# --------------------------------------------------------------------------------------------
# CVG
# --------------------------------------------------------------------------------------------
def event_cvg(
    v_realized: Sequence[float], v_frozen: Sequence[float], horizon: int = CVG_HORIZON
) -> float | None:
    """Eq. 2: mean over h = 0..H-1 of V_e(C_{tau+h}, x_{tau+h}) - V_e(C_tau, x_{tau+h}).

    Args:
        v_realized: V_e from the policy's camera at steps tau, tau+1, ... (index h).
        v_frozen: V_e from the event-start camera pose C_tau at the same steps and states.
        horizon: H.

    Returns:
        The event CVG, or None when fewer than H samples exist (the episode ended inside the
        window: the event is excluded, not padded). Samples beyond H are ignored.
    """
    if horizon < 1:
        raise ValueError(f"horizon must be >= 1, got {horizon}")
    if len(v_realized) != len(v_frozen):
        raise ValueError(
            f"v_realized and v_frozen must be step-aligned, got {len(v_realized)} and {len(v_frozen)} samples"
        )
    if len(v_realized) < horizon:
        return None
    diffs = [float(r) - float(f) for r, f in zip(v_realized[:horizon], v_frozen[:horizon], strict=True)]
    if not all(math.isfinite(d) for d in diffs):
        raise ValueError("visibility values must be finite")
    return math.fsum(diffs) / horizon


def _mean_of_present(values: Sequence[float | None]) -> float | None:
    kept = [float(v) for v in values if v is not None]
    return math.fsum(kept) / len(kept) if kept else None


def episode_cvg(event_values: Sequence[float | None]) -> float | None:
    """Mean CVG over an episode's retained events (None entries are truncated events).

    Returns None when the episode has no retained event.
    """
    return _mean_of_present(event_values)


def aggregate_cvg(episode_values: Sequence[float | None]) -> float | None:
    """Dataset CVG: mean over episodes that have a value; episodes without retained events (None)
    do not count. Each episode weighs the same regardless of its number of events.

    Returns None when no episode has a value.
    """
    return _mean_of_present(episode_values)


# --------------------------------------------------------------------------------------------
# Task metrics
# --------------------------------------------------------------------------------------------
def success_rate(successes: Sequence[bool]) -> float:
    """SR in percent: 100 x fraction of episodes that reached M5."""
    s = np.asarray(successes)
    if s.size == 0:
        raise ValueError("success_rate needs at least one episode")
    if s.dtype != bool and not np.isin(s, (0, 1)).all():
        raise ValueError(f"successes must be booleans (or 0/1), got {list(successes)}")
    return 100.0 * float(s.astype(bool).mean())


def task_progress_score(depths: Sequence[int]) -> float:
    """TPS in percent: 100 x mean_i d_i / 5, with d_i in {0..5} the deepest milestone of episode i."""
    if len(depths) == 0:
        raise ValueError("task_progress_score needs at least one episode")
    ds = [_checked_depth(d) for d in depths]
    return 100.0 * sum(ds) / (NUM_MILESTONES * len(ds))


def milestone_depth_counts(depths: Sequence[int]) -> list[int]:
    """Episodes per deepest milestone reached, index 0..NUM_MILESTONES (the last is success): where a
    policy's episodes stop, which SR and TPS summarise away."""
    counts = [0] * (NUM_MILESTONES + 1)
    for d in depths:
        counts[_checked_depth(d)] += 1
    return counts


def _checked_depth(d: int) -> int:
    """A milestone depth as an int in {0..NUM_MILESTONES}; bools and floats are errors, not depths."""
    if isinstance(d, bool | np.bool_):
        raise TypeError(f"milestone depths must be integers, got {d!r}")
    d = operator.index(d)  # rejects floats
    if not 0 <= d <= NUM_MILESTONES:
        raise ValueError(f"milestone depth must be in [0, {NUM_MILESTONES}], got {d}")
    return d


def wilson_interval(successes: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """95 % (z = 1.96) Wilson score interval of a success rate, in percent: (low, high).

    Why Wilson: SR over 20-80 episodes is often near 0 or 100 %, where the normal approximation's interval
    leaves [0, 100]; Wilson's stays inside and keeps close to its nominal coverage at these counts."""
    if n < 1 or not 0 <= successes <= n:
        raise ValueError(f"need 0 <= successes <= n and n >= 1, got {successes} of {n}")
    p = successes / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return 100.0 * float(max(0.0, centre - half)), 100.0 * float(min(1.0, centre + half))


def mcnemar_exact_p(only_a: int, only_b: int) -> float:
    """Two-sided exact McNemar p-value for two policies run on the same episode seeds.

    Why: comparing two checkpoints on the same seeds, the episodes both win or both lose say nothing about
    which is better; the discordant ones (`only_a` won by A alone, `only_b` by B alone) are, under no
    difference, Binomial(only_a + only_b, 1/2). p = min(1, 2 P(X <= min(only_a, only_b)))."""
    if only_a < 0 or only_b < 0:
        raise ValueError(f"need discordant counts >= 0, got {only_a} and {only_b}")
    n = only_a + only_b
    tail = sum(math.comb(n, i) for i in range(min(only_a, only_b) + 1))
    return min(1.0, 2.0 * tail / 2**n)


def joint_score(sr_percent: float, cvg_pp: float | None) -> float | None:
    """Joint = SR x CVG / 100 (Table 4), with SR in percent and CVG in pp; None if CVG is None."""
    if cvg_pp is None:
        return None
    return sr_percent * cvg_pp / 100.0


# --------------------------------------------------------------------------------------------
# Per-step bookkeeping
# --------------------------------------------------------------------------------------------
def cell_metrics(successes: Sequence[bool], depths: Sequence[int],
                 episode_cvgs: Sequence[float | None]) -> dict[str, float | None]:
    """The `CELL_METRICS` of one cell from its episodes: SR and TPS in percent, CVG in pp (None where no
    episode retained an event), Joint."""
    sr = success_rate(successes)
    cvg = aggregate_cvg(episode_cvgs)
    cvg_pp = None if cvg is None else 100.0 * cvg
    values = {"sr": sr, "tps": task_progress_score(depths), "cvg": cvg_pp, "joint": joint_score(sr, cvg_pp)}
    assert tuple(values) == tuple(CELL_METRICS)
    return values


@dataclass
class CVGEventRecord:
    """One occlusion event: its V samples at steps start_step, start_step + 1, ... (index h)."""

    index: int
    start_step: int
    target_name: str
    v_realized: list[float] = field(default_factory=list)
    v_frozen: list[float] = field(default_factory=list)
    ended_at: int | None = None  # step at which a later event replaced this event's occluder

    def covers(self, step: int, horizon: int) -> bool:
        """Whether step lies in this event's window [start_step, start_step + horizon - 1]."""
        if self.ended_at is not None and step >= self.ended_at:
            return False
        return self.start_step <= step < self.start_step + horizon

    def cvg(self, horizon: int = CVG_HORIZON) -> float | None:
        return event_cvg(self.v_realized, self.v_frozen, horizon)

    def to_dict(self, horizon: int = CVG_HORIZON) -> dict:
        return {
            "index": self.index,
            "start_step": self.start_step,
            "target": self.target_name,
            "num_samples": len(self.v_realized),
            "cvg": self.cvg(horizon),
        }


class CVGAccumulator:
    """Collects V samples for the occlusion events of one episode and reduces them to CVG.

    The environment drives it:
        acc.start_event(step, target_name)          # at each intervention (tau_e = step)
        acc.record(step, v_realized, v_frozen)      # every step, including the event's start step
        info = acc.close_episode()                  # at episode end; the accumulator is then empty

    Each event keeps its own H-step window [tau_e, tau_e + H - 1], so windows may overlap (Stage
    transitions can be closer than H; Random-time triggers are > 60 steps apart and do not overlap).
    ``record`` appends to every event whose window covers ``step``. Because V_e depends on the
    event's own target, occluder and start pose C_tau_e, a value passed as a float is used for every
    open event (the normal case: one open event); with overlapping windows pass a mapping
    {event index: value} covering each index in ``open_events(step)``.

    Steps must be recorded contiguously: an event's h-th sample must come from step tau_e + h,
    otherwise ``record`` raises (a skipped step would silently shift Eq. 2's index).
    """

    def __init__(self, horizon: int = CVG_HORIZON):
        if horizon < 1:
            raise ValueError(f"horizon must be >= 1, got {horizon}")
        self.horizon = horizon
        self.events: list[CVGEventRecord] = []

    def start_event(self, step: int, target_name: str) -> int:
        """Open a new event at tau_e = step; returns its index within the episode."""
        step = operator.index(step)
        if step < 0:
            raise ValueError(f"step must be >= 0, got {step}")
        if self.events and step < self.events[-1].start_step:
            raise ValueError(f"events must start in time order: {step} < {self.events[-1].start_step}")
        event = CVGEventRecord(index=len(self.events), start_step=step, target_name=target_name)
        self.events.append(event)
        return event.index

    def end_open_events(self, step: int) -> None:
        """A new occluder replaces the current one at `step`: windows still open stop there.

        Their V_e can no longer be measured (their occluder is gone), so they keep fewer than H
        samples and count as truncated. Random-time triggers are > H apart, so this only happens
        under Stage Occlusion (for which the paper reports no CVG).
        """
        for event in self.events:
            if event.covers(step, self.horizon):
                event.ended_at = step

    def open_events(self, step: int) -> list[int]:
        """Indices of events whose recovery window covers step."""
        return [e.index for e in self.events if e.covers(step, self.horizon)]

    def record(
        self,
        step: int,
        v_realized: float | Mapping[int, float],
        v_frozen: float | Mapping[int, float],
    ) -> None:
        """Append one step's V samples to every event whose window still covers step."""
        step = operator.index(step)
        for event in self.events:
            if not event.covers(step, self.horizon):
                continue
            h = step - event.start_step
            if len(event.v_realized) != h:
                raise ValueError(
                    f"event {event.index} (start {event.start_step}) expected step "
                    f"{event.start_step + len(event.v_realized)}, got {step}"
                )
            event.v_realized.append(_value_for(v_realized, event.index, "v_realized"))
            event.v_frozen.append(_value_for(v_frozen, event.index, "v_frozen"))

    def close_episode(self) -> dict:
        """Reduce the episode and reset. Truncated events get cvg None and do not enter the mean.

        Returns:
            {"horizon", "events": [{"index", "start_step", "target", "num_samples", "cvg"}, ...],
             "num_events", "num_retained", "episode_cvg" (None if no event was retained)}.
        """
        events = [e.to_dict(self.horizon) for e in self.events]
        values = [e["cvg"] for e in events]
        self.events = []
        return {
            "horizon": self.horizon,
            "events": events,
            "num_events": len(events),
            "num_retained": sum(v is not None for v in values),
            "episode_cvg": episode_cvg(values),
        }


def _value_for(v: float | Mapping[int, float], index: int, name: str) -> float:
    if isinstance(v, Mapping):
        if index not in v:
            raise KeyError(f"{name} has no value for open event {index} (keys {sorted(v)})")
        return float(v[index])
    return float(v)
