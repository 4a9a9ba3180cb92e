"""Where does a teacher fall? Falls per minute of exposure, by the forward command.

A lab tool, not a ``tron1`` command: it runs the climb probe's protocol (training commands,
randomisation on, full window, 128 envs x 500 steps, seed 0) on one level of one terrain type
(stairs up unless ``--terrain`` names another, e.g. ``slope_down``) and splits every env's
walking time by the forward velocity command in force at each step (m/s: above 0.65, 0.3-0.65,
0-0.3, zero or backwards), counting the falls that happen under each.

    python tools/falls_by_command.py policies/runs/climb/checkpoints/latest.pt --level 9
    python tools/falls_by_command.py CKPT --terrain slope_down
"""

from __future__ import annotations

import argparse

import numpy as np

from tron1cli.env.terrain import TERRAIN_TYPES
from tron1cli.evaluation.climb import CLIMB_ENVS, CLIMB_TERRAIN
from tron1cli.evaluation.protocol import EvalSpec, run_batch
from tron1cli.policy.runtime import load_policy

#: (label, lower bound of the forward command in m/s); a step belongs to the first band it exceeds
BANDS = (("vx > 0.65", 0.65), ("vx 0.3-0.65", 0.3), ("vx 0-0.3", 0.0), ("vx <= 0", -np.inf))


def falls_by_command(
    path: str, level: int, terrain: str = CLIMB_TERRAIN, envs: int = CLIMB_ENVS, steps: int = 500
) -> list[tuple]:
    """Rows (band, exposure s, falls, falls per minute) of the teacher of checkpoint ``path`` on
    terrain type ``terrain``."""
    policy = load_policy(path, actor="teacher")
    exposure, falls = np.zeros(len(BANDS)), np.zeros(len(BANDS))
    band = np.zeros(envs, dtype=int)

    def note_band(env, t) -> None:  # the command in force during the step
        vx = env.commands.value[:, 0]
        band[:] = np.select([vx > lo for _, lo in BANDS], range(len(BANDS)))

    def count(env, res, walking) -> None:
        exposure[:] += np.bincount(band[walking], minlength=len(BANDS)) * env.policy_dt
        falls[:] += np.bincount(band[walking & res.failed], minlength=len(BANDS))

    spec = EvalSpec(terrain, level, envs, steps, True, seed=0)
    run_batch(policy, spec, before_step=note_band, after_step=count)
    return [
        (label, e, int(f), 60.0 * f / e if e > 0 else float("nan"))
        for (label, _), e, f in zip(BANDS, exposure, falls, strict=True)
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint")
    ap.add_argument("--level", type=int, default=9)
    ap.add_argument("--terrain", default=CLIMB_TERRAIN, choices=TERRAIN_TYPES)
    args = ap.parse_args()
    print(f"{args.terrain}, level {args.level}: band, exposure (s), falls, falls per minute")
    for label, e, f, rate in falls_by_command(args.checkpoint, args.level, args.terrain):
        print(f"{label:12s} {e:7.0f} {f:5d} {rate:7.2f}")


if __name__ == "__main__":
    main()
