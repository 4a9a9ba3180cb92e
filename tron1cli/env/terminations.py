"""Episode ends: failures (falls, body contact), unstable simulations, and time-outs.

Time-outs are reported apart from failures so that the learner bootstraps them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tron1cli.config.env import TerminationConfig
from tron1cli.env.math3d import roll_pitch
from tron1cli.env.robot import TERMINATION_BODIES

#: what can make an episode end as a fall: the columns of :attr:`Terminations.causes`
FALL_CAUSES: tuple[str, ...] = ("tilt", *TERMINATION_BODIES)


@dataclass
class Terminations:
    """Boolean masks (N,) of one step's episode ends."""

    failed: np.ndarray  # fell: body contact or excessive tilt
    unstable: np.ndarray  # NaN, runaway velocity or a MuJoCo auto-reset inside the step
    time_out: np.ndarray  # episode length reached (not a failure)
    causes: np.ndarray  # (N, len(FALL_CAUSES)) bool: what made a failed env fail; False elsewhere

    @property
    def done(self) -> np.ndarray:
        return self.failed | self.unstable | self.time_out


def tilt_exceeded(projected_gravity: np.ndarray, max_roll: float, max_pitch: float) -> np.ndarray:
    """Whether roll or pitch exceeds its limit, from the gravity direction in the base frame (N, 3)."""
    roll, pitch = roll_pitch(projected_gravity)
    return (np.abs(roll) > max_roll) | (np.abs(pitch) > max_pitch)


def unstable_sim(
    state: np.ndarray, expected_time: np.ndarray, qvel: np.ndarray, max_qvel: float
) -> np.ndarray:
    """Envs whose simulation diverged during the last step.

    MuJoCo resets a diverging world by itself (its time restarts at 0), so a time that does not
    match ``expected_time`` is as telling as a NaN or a runaway velocity.
    """
    bad = ~np.isfinite(state).all(axis=1)
    bad |= np.abs(state[:, 0] - expected_time) > 1e-6
    bad |= (np.abs(qvel) > max_qvel).any(axis=1)
    return bad


def check(
    cfg: TerminationConfig,
    projected_gravity: np.ndarray,
    body_contact: np.ndarray,
    unstable: np.ndarray,
    episode_step: np.ndarray,
    max_episode_steps: int,
    left_tile: np.ndarray | None = None,
) -> Terminations:
    """Combine the termination conditions of one step (all inputs have N rows; ``body_contact``
    (N, len(TERMINATION_BODIES)) bool, each termination body touching the ground; only those in
    ``cfg.bodies`` end an episode).

    Reaching the edge of the terrain tile ends the episode as a time-out: the robot did nothing
    wrong, there is just no more ground.
    """
    tilted = tilt_exceeded(projected_gravity, cfg.max_roll, cfg.max_pitch)
    counted = np.array([cfg.contact_bodies and b in cfg.bodies for b in TERMINATION_BODIES])
    touching = body_contact & counted
    failed = (tilted | touching.any(axis=1)) & ~unstable
    time_out = episode_step >= max_episode_steps
    if left_tile is not None:
        time_out = time_out | left_tile
    time_out &= ~failed & ~unstable
    causes = np.column_stack([tilted, touching]) & failed[:, None]
    return Terminations(failed=failed, unstable=unstable, time_out=time_out, causes=causes)


def cause_words(causes: np.ndarray) -> str:
    """One env's fall causes ((len(FALL_CAUSES),) bool) in words: ``"tilt+base"``; ``""`` if none."""
    return "+".join(name for name, hit in zip(FALL_CAUSES, causes, strict=True) if hit)
