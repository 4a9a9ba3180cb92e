"""Does a teacher climb when every env is asked to walk straight ahead? The climb probe's figures
at one fixed command.

A lab tool, not a ``tron1`` command: on stairs up at the given levels, every env is commanded
``--speed`` m/s forward with no sideways speed and no yaw rate for the whole window (128 envs x
500 steps, randomisation on, full window, seed 0), and the teacher of each checkpoint is scored as
the climb probe scores it: success, traverse, command progress (along the commanded path) and
risers climbed per env. A teacher that walks but turns off its path reads low progress and few
risers here, whatever the training commands let it do.

    python tools/climb_at_speed.py policies/runs/climb_phase8/checkpoints/latest.pt --speed 0.5
"""

from __future__ import annotations

import argparse

from tron1cli.evaluation.climb import CLIMB_ENVS, CLIMB_TERRAIN, ClimbRow, climb_row
from tron1cli.evaluation.protocol import EvalSpec
from tron1cli.policy.runtime import load_policy


def climb_at_speed(path: str, speed: float, level: int, envs: int = CLIMB_ENVS, steps: int = 500) -> ClimbRow:
    """The probe's row (:class:`tron1cli.evaluation.climb.ClimbRow`) of the teacher of checkpoint
    ``path`` on stairs up at ``level``, every env commanded ``speed`` m/s straight ahead."""
    spec = EvalSpec(CLIMB_TERRAIN, level, envs, steps, True, speed=speed, seed=0)
    return climb_row("teacher", load_policy(path, actor="teacher"), spec)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoints", nargs="+")
    ap.add_argument("--speed", type=float, default=0.5, help="forward command (m/s)")
    ap.add_argument("--levels", default="6,9", help="stairs-up levels, comma-separated")
    args = ap.parse_args()
    print(f"stairs up at {args.speed:g} m/s straight ahead: success %, traverse %, progress, risers per env")
    for path in args.checkpoints:
        for level in (int(v) for v in args.levels.split(",")):
            row = climb_at_speed(path, args.speed, level)
            print(
                f"{path} level {level}: {100 * row.success:.1f} {100 * row.traverse:.1f} "
                f"{row.progress:.2f} {row.risers:.2f}",
                flush=True,
            )


if __name__ == "__main__":
    main()
