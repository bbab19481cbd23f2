"""Execution noise for demonstrations (DART: Laskey et al., "DART: Noise Injection for Robust Imitation
Learning", CoRL 2017).

Why: the scripted experts never make a mistake, so their demonstrations only show states on the
expert's own path. A cloned policy that drifts a centimetre off that path sees states no
demonstration contains, and its errors compound (measured on Cube Handoff, privileged-state MLP,
20 Clean episodes: 4/20 successes from 40 clean demonstrations, 5/20 and 9/20 from 40
demonstrations recorded with this noise at 0.01 rad, two noise draws;
`docs/results/ladder_cube_handoff.md`). With execution
noise, the env executes the expert's joint targets plus a slowly varying random offset, while the
dataset records the expert's clean targets; because the experts plan in their own commanded
joint space (not from the perturbed measured state) and re-plan each phase from the objects'
actual poses, every recorded action points back towards the plan from wherever the noise took
the arm, which is the correction a policy needs to learn.

The offset is an AR(1) (discretised Ornstein-Uhlenbeck) process per manipulator arm joint, with
stationary standard deviation `std` (radians) and per-step correlation `correlation` (at 25 Hz,
0.9 gives a time constant of ~0.4 s): white noise of the same size would be filtered out by the
position controllers before it moved the arm. Grippers and the camera arm are never perturbed.

Contact phases can be kept clean (`clean_contacts`, off by default): while the expert is in one of
its `contact_phases` (the final approach, grasp and release of an object, where a centimetre off
makes the expert itself fail), no noise is executed and the offset restarts from zero afterwards.
Why it exists: privileged-state ManiFlow trained on noise-everywhere demonstrations completed every
Cube Handoff episode in which it lifted the cube, but stopped at the first touch of the cube in 15
of 20. It is not the default because it has not been shown to help: the state-MLP probe scores 5/20
on Clean either way (`docs/results/ladder_cube_handoff.md`), and the reported runs used noise in
every phase.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from lerobot_bavo.experts.base import in_contact_phase
from lerobot_bavo.sim import constants as C

# Entries of the 21-d action that get noise: both manipulators' six arm joints (not the grippers,
# not the camera arm).
PERTURBED_JOINTS = np.r_[np.arange(21)[C.LEFT_ARM], np.arange(21)[C.RIGHT_ARM]]


def ar1_step(offset: np.ndarray, correlation: float, std: float, eps: np.ndarray) -> np.ndarray:
    """One step of an AR(1) process whose stationary standard deviation is `std`:
    x' = rho x + sqrt(1 - rho^2) std eps, with eps ~ N(0, 1)."""
    return correlation * offset + np.sqrt(1.0 - correlation * correlation) * std * eps


@dataclass(frozen=True)
class ExecutionNoise:
    """DART-style noise on the executed arm joint targets (see the module docstring).

    Args:
        std: stationary standard deviation of each joint's offset, radians (0: no noise). The recipe
            uses 0.01 rad (~5 mm at the gripper). Larger offsets make the experts fail unless the
            contact phases are kept clean, and even then on tasks where one arm holds an object while
            the other works (Dustpan Sweeping); docs/results/dart_noise.md has the measured rates.
        correlation: per-control-step AR(1) coefficient in [0, 1).
        clean_contacts: no noise during the expert's `contact_phases`.
    """

    std: float = 0.0
    correlation: float = 0.9
    clean_contacts: bool = False

    def __post_init__(self):
        if not np.isfinite(self.std) or self.std < 0:
            raise ValueError(f"execution noise std must be a finite number >= 0 (radians), got {self.std}")
        if not 0.0 <= self.correlation < 1.0:
            raise ValueError(f"execution noise correlation must be in [0, 1), got {self.correlation}")

    @property
    def enabled(self) -> bool:
        return self.std > 0

    def to_dict(self) -> dict:
        return asdict(self)

    def quiet_for(self, agent) -> bool:
        """Whether `agent`'s current step is executed clean: `clean_contacts` and the agent (an expert, after
        its `act`) is in one of its `contact_phases`. Agents without phases are never quiet."""
        return self.clean_contacts and in_contact_phase(agent)

    def process(self, seed: int) -> JointNoise:
        """The noise of one episode, drawn from its own generator seeded by the episode seed (never a
        global one), so the same seed gives the same perturbed episode."""
        return JointNoise(self, seed)


class JointNoise:
    """The per-episode noise process: `perturb(action)` returns the action to execute."""

    def __init__(self, noise: ExecutionNoise, seed: int):
        self.noise = noise
        self.rng = np.random.default_rng([int(seed), 0xDA27])
        self.offset = np.zeros(len(PERTURBED_JOINTS))

    def perturb(self, action: np.ndarray, quiet: bool = False) -> np.ndarray:
        """`action` (21,) with the next offset added to the arm joints; a new array, dtype of `action`.
        `quiet` (a contact phase): no noise, and the offset restarts from zero."""
        out = np.array(action, copy=True)
        if quiet:
            self.offset = np.zeros_like(self.offset)
        if not self.noise.enabled or quiet:
            return out
        eps = self.rng.standard_normal(len(PERTURBED_JOINTS))
        self.offset = ar1_step(self.offset, self.noise.correlation, self.noise.std, eps)
        out[PERTURBED_JOINTS] = out[PERTURBED_JOINTS] + self.offset
        return out
