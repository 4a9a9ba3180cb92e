"""The climb probe (``tron1 eval CKPT --climb``): does a checkpoint's teacher, and its student, climb?

Both actors of one checkpoint walk the full-window protocol (:mod:`tron1cli.evaluation.protocol`,
training commands and randomisation, 10 s) on pyramid stairs up at levels 3, 6 and 9 (8, 14 and
20 cm risers). Per batch: success (survival, the paper's), traverse (success that walked half its
commanded distance), command progress, and risers climbed per env: the highest the ground under
the base got above the spawn point's, over the riser height, averaged over every env of the batch
(fallers keep what they climbed before the fall), and what the fallers fell by: tilt, the base or
a thigh touching the ground. A policy that stands before the first riser
succeeds but climbs 0 risers. One fixed probe, so that experiments compare on the same figures.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from tron1cli.env.terminations import FALL_CAUSES
from tron1cli.env.terrain import riser_m
from tron1cli.evaluation.protocol import EvalResult, EvalSpec, run_batch

CLIMB_TERRAIN = "stairs_up"
CLIMB_LEVELS = (3, 6, 9)
CLIMB_ENVS = 128  #: envs per batch: six batches of 500 steps in about 4 minutes on two cores


@dataclass(frozen=True)
class ClimbRow:
    """One batch of the probe: ``actor`` on stairs up at ``level`` (``riser_m`` m risers).

    success, traverse: shares of the envs (0-1); progress: command progress (0-1); risers: mean
    risers climbed per env; pitch_deg: mean base pitch (degrees, + nose down); fell_tilt,
    fell_base, fell_thigh: shares of the envs (0-1) whose fall came with the base tilted past the
    termination limit, the base touching the ground, a thigh touching it (one fall may have
    several)."""

    actor: str
    level: int
    riser_m: float
    success: float
    traverse: float
    progress: float | None
    risers: float
    pitch_deg: float | None
    fell_tilt: float
    fell_base: float
    fell_thigh: float

    @classmethod
    def of(cls, actor: str, level: int, riser: float, r: EvalResult) -> ClimbRow:
        m = r.metrics
        return cls(
            actor,
            level,
            riser,
            float(m["success_rate"]),
            float(m["traverse_rate"]),
            m["command_progress"],
            risers_climbed(r.rise_m, riser),
            m["pitch_deg"],
            *fall_shares(r.fall_causes),
        )


def fall_shares(causes: np.ndarray) -> tuple[float, float, float]:
    """Shares of the envs (0-1) whose fall had each cause, from per-env fall causes (N,
    len(FALL_CAUSES)) bool: tilt, base contact, thigh contact (either thigh)."""
    col = {name: causes[:, k] for k, name in enumerate(FALL_CAUSES)}
    thigh = np.any([c for name, c in col.items() if name.startswith("thigh")], axis=0)
    return float(col["tilt"].mean()), float(col["base"].mean()), float(thigh.mean())


def risers_climbed(rise_m: np.ndarray, riser: float) -> float:
    """Mean risers climbed per env: rise (m) per env over the riser height (m), each env's count
    rounded to whole risers (the ground under the base mid-edge reads half a riser)."""
    return float(np.floor(np.asarray(rise_m) / riser + 0.5).mean())


def climb_probe(
    policies: dict[str, object],
    envs: int = CLIMB_ENVS,
    steps: int = 500,
    seed: int = 0,
    levels: Iterable[int] = CLIMB_LEVELS,
    randomize: bool = True,
    on_batch: Callable[[str, int], Callable[[int], None] | None] | None = None,
) -> list[ClimbRow]:
    """Rows of the probe for each actor -> :class:`tron1cli.policy.runtime.Policy` in ``policies``
    and each level; ``on_batch(actor, level)`` may return a per-step callback (progress)."""
    rows = []
    for actor, policy in policies.items():
        for level in levels:
            spec = EvalSpec(CLIMB_TERRAIN, level, envs, steps, randomize, seed=seed)
            on_step = on_batch(actor, level) if on_batch is not None else None
            rows.append(climb_row(actor, policy, spec, on_step))
    return rows


def climb_row(actor: str, policy, spec: EvalSpec, on_step: Callable[[int], None] | None = None) -> ClimbRow:
    """The probe's row of ``policy`` (acting as ``actor``) for one batch ``spec`` on
    :data:`CLIMB_TERRAIN` (the probe's own, or one a lab tool varies: a fixed speed, pushes)."""
    riser = riser_m(policy.run_cfg.env.terrain_cfg, spec.level)
    return ClimbRow.of(actor, spec.level, riser, run_batch(policy, spec, on_step))
