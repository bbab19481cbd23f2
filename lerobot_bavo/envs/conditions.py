"""Visibility conditions (paper Sec. 3.1, App. A): one class per condition, registered by name.

A condition decides whether the benchmark occluder exists, when occlusion events start in an episode
(its schedule) and whether the env reports CVG under it by default. Where the occluder goes is not
the condition's business (`envs/occlusion.py` places it for the task's current Stage target).

- `Clean`: no occluder, no event.
- `Stage`: an event at reset and one when each of the task's two Stage transition milestones is
  first reached (the paper's training condition).
- `RandomTime`: an event at reset and one at each trigger sampled at reset, one per window
  (`sample_random_triggers`); the condition the paper reports CVG for.

Adding a condition is adding a class here or anywhere else:

    @register_condition
    class EveryFifty(Condition):
        name = "every50"
        def due(self, schedule, step, depth):
            return step % 50 == 0

`BavoEnv`, `BavoEnvConfig`, `bavo-eval`, `bavo-collect` and `bavo-demo` look conditions up by name
in `CONDITIONS`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from lerobot_bavo.envs.occlusion import sample_random_triggers, stage_index
from lerobot_bavo.registry import Registry

CONDITIONS = Registry("condition")
register_condition = CONDITIONS.register


class Condition:
    """One visibility condition. Subclasses set `name` and override `due` (and `sample_triggers` when
    their events are drawn at reset).

    Class attributes:
        name: the condition's name (`--condition`, `BavoEnv(condition=...)`).
        description: one Markdown sentence for dataset cards.
        occluded: whether the env builds the occluder and runs the schedule at all.
        reports_cvg: whether the env renders the frozen-camera counterfactual and reports CVG by
            default (`BavoEnv(compute_cvg=None)`).
    """

    name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    occluded: ClassVar[bool] = True
    reports_cvg: ClassVar[bool] = False

    def sample_triggers(self, rng: np.random.Generator) -> list[int]:
        """Steps drawn at reset, from the episode's generator (after the task's layout). Default: none,
        and nothing is drawn."""
        return []

    def due(self, schedule: OcclusionSchedule, step: int, depth: int) -> bool:
        """Whether an event starts at control step `step`, given the milestone depth reached."""
        return False

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"


@register_condition
class Clean(Condition):
    name = "clean"
    description = "**Clean**: no artificial occlusion."
    occluded = False


@register_condition
class Stage(Condition):
    name = "stage"
    description = (
        "**Stage Occlusion** (the paper's training condition): an occluder panel is placed on the line of "
        "sight "
        "from the active camera to a task-relevant target at reset, and re-placed for a new target at the "
        "task's two "
        "stage transitions (three occlusion phases per episode). The scripted demonstrator pauses "
        "manipulation after "
        "each event, moves the camera arm to a view that sees the target past the occluder, then resumes "
        "(paper Sec. 3.2)."
    )

    def due(self, schedule, step, depth):
        """At reset, then once per transition milestone, when it is first reached."""
        if step == 0:
            return True
        stage = stage_index(depth, schedule.transitions)
        if stage > schedule.stage_fired:
            schedule.stage_fired = stage
            return True
        return False


@register_condition
class RandomTime(Condition):
    name = "random"
    description = "**Random-time Occlusion**: occlusion events at reset and at six randomly timed triggers."
    reports_cvg = True

    def sample_triggers(self, rng):
        return sample_random_triggers(rng)

    def due(self, schedule, step, depth):
        """At reset and at the sampled triggers; the milestone depth plays no part."""
        return step == 0 or step in schedule.triggers


def get_condition(condition: str | Condition) -> Condition:
    """A condition instance from its registered name (or the instance itself); unknown names raise a
    ValueError listing the registered conditions."""
    if isinstance(condition, Condition):
        return condition
    return CONDITIONS.lookup(condition)()


@dataclass
class OcclusionSchedule:
    """When occlusion events happen in one episode: the condition's rule plus the episode's state.

    Args:
        condition: a `Condition` or its registered name.
        transitions: the task's two Stage transition milestones.
        triggers: steps sampled at reset (Random-time); empty otherwise.
        stage_fired: the last Stage index an event was started for (Stage's state).
    """

    condition: Condition | str
    transitions: tuple[int, int]
    triggers: list[int] = field(default_factory=list)
    stage_fired: int = 0

    def __post_init__(self):
        self.condition = get_condition(self.condition)
        self.transitions = tuple(self.transitions)

    @classmethod
    def sample(cls, condition: str | Condition, transitions: tuple[int, int],
               rng: np.random.Generator) -> OcclusionSchedule:
        condition = get_condition(condition)
        return cls(condition, tuple(transitions), condition.sample_triggers(rng))

    def due(self, step: int, depth: int) -> bool:
        """Whether an event starts at control step `step` given the milestone depth reached."""
        return self.condition.due(self, step, depth)


__all__ = ["CONDITIONS", "Clean", "Condition", "OcclusionSchedule", "RandomTime", "Stage", "get_condition",
           "register_condition"]
