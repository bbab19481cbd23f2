"""Short planned switches of a snapped (binary) command held back at inference (`binary_min_run`).

Why: the experts close a gripper with a ramp (1 -> 0 over ten steps) and then hold each level for at least
121 steps (Cube Handoff's demonstrations). A policy holding the cube can still sample, at the first action
of a new chunk, the start of that ramp from part-open; snapped, its first steps execute as fully open, and
the grip is lost for a few steps, chunk after chunk (docs/results/learning_rate.md, "gripper switches
shorter than one executed chunk"). Holding back a switch whose new level the chunk plans for fewer than
`min_run` steps before coming back removes those openings; a grasp or a release, planned to the end of the
horizon, passes. It reads only the policy's own plan and the level it executed last, nothing privileged,
and acts on the snapped (normalised) commands, so it composes with `binary_action_levels`.
"""

from __future__ import annotations

from torch import Tensor


def check_min_run(min_run: int | None, binary_dims: tuple[int, ...] | None,
                  temporal_ensemble_coeff: float | None) -> None:
    """Raise ValueError unless `min_run` is None (off) or an int >= 2 usable with the other settings."""
    if min_run is None:
        return
    if isinstance(min_run, bool) or not isinstance(min_run, int) or min_run < 2:
        raise ValueError(f"`binary_min_run` must be an integer >= 2 (steps), or None to turn it off. "
                         f"Got {min_run!r}.")
    if binary_dims is not None and len(binary_dims) == 0:
        raise ValueError("`binary_min_run` holds back switches of the snapped `binary_action_dims`, and "
                         "there are none (`binary_action_dims=[]`). Leave `binary_min_run` unset.")
    if temporal_ensemble_coeff is not None:
        raise ValueError("`binary_min_run` filters each executed chunk's plan, and `temporal_ensemble_coeff` "
                         "executes a blend of chunks instead. Set one of them.")


def hold_run_levels(plan: list[float], executed: float | None, min_run: int) -> list[float]:
    """One dimension's planned levels from the current step on, with short switches held back.

    Walking the plan from its first step with the level executed last (`executed`; None: the plan's first
    level): a run of another level that lasts fewer than `min_run` steps and is followed by the current level
    again is replaced by the current level; any other run (long enough, or reaching the end of the plan, or
    followed by a third level) is a switch and becomes the current level.
    """
    out = list(plan)
    current = out[0] if executed is None else executed
    i = 0
    while i < len(out):
        if out[i] == current:
            i += 1
            continue
        j = i
        while j < len(out) and out[j] == out[i]:
            j += 1
        if j < len(out) and j - i < min_run and out[j] == current:
            out[i:j] = [current] * (j - i)
        else:
            current = out[i]
        i = j
    return out


def hold_short_switches(plan: Tensor, dims: tuple[int, ...], min_run: int,
                        executed: Tensor | None = None) -> Tensor:
    """`plan` (B, T, A), already snapped on `dims`, from the current step on, with each of `dims` passed
    through `hold_run_levels` against `executed` (B, A), the last action executed (None at an episode's
    start). The input is not modified."""
    if not dims:
        return plan
    out = plan.clone()
    for b in range(plan.shape[0]):
        for d in dims:
            last = None if executed is None else float(executed[b, d])
            held = hold_run_levels([float(v) for v in plan[b, :, d]], last, min_run)
            out[b, :, d] = out.new_tensor(held)
    return out
