"""Where does an actor fall on discrete obstacles? Falls per minute by the relief around the base.

A lab tool, not a ``tron1`` command: it runs ``tron1 eval``'s protocol (training commands,
randomisation on, full window, seed 0) on discrete obstacles at one level and splits every env's
walking time by the local relief at each step: the highest minus the lowest ground on a 5 x 5 grid
of points within +/- ``REACH_M`` of the base (m; blocks stand 2-36 cm on the hardest level), counting
the falls under each band and what ended them (tilt, base or thigh contact). Where the relief
passes 20 cm it splits the time and falls again by the forward command in force (forward, backward,
neither), since the knee points backwards and walking back meets a block with it.

    python tools/falls_on_discrete.py policies/runs/cts_phase2/checkpoints/latest.pt --actor student
"""

from __future__ import annotations

import argparse

import numpy as np

from tron1cli.env.terminations import FALL_CAUSES
from tron1cli.evaluation.protocol import EvalSpec, run_batch
from tron1cli.policy.runtime import load_policy

#: half side (m) of the square around the base whose relief is measured
REACH_M = 0.4
#: (label, lower bound of the relief in m); a step belongs to the first band it reaches
BANDS = (("relief >= 30 cm", 0.30), ("20-30 cm", 0.20), ("10-20 cm", 0.10), ("< 10 cm", -np.inf))
#: the relief (m) from which steps are also split by the forward command
TALL_M = 0.20
#: (label, lower bound of the forward command in m/s), first band exceeded; used where relief >= TALL_M
DIRECTIONS = (("vx > 0.2 m/s", 0.2), ("vx -0.2-0.2", -0.2), ("vx < -0.2 m/s", -np.inf))


def relief(env) -> np.ndarray:
    """(N,) highest minus lowest ground (m) on a 5 x 5 grid within +/- REACH_M of each base."""
    xy = env.state.base_pos[:, :2]
    grid = np.linspace(-REACH_M, REACH_M, 5)
    h = np.stack([env.ground_height(xy + np.array([dx, dy])) for dx in grid for dy in grid], axis=1)
    return h.max(axis=1) - h.min(axis=1)


def falls_on_discrete(
    path: str, actor: str, level: int, envs: int, seed: int, steps: int = 500
) -> tuple[list[tuple], list[tuple], np.ndarray, float, int]:
    """Rows (band, exposure s, falls, falls per minute) by relief, the same by forward command
    where the relief passes ``TALL_M``, the fall causes summed ((len(FALL_CAUSES),)), the success
    rate (0-1) and how many envs left the tile."""
    policy = load_policy(path, actor=actor)
    exposure, falls = np.zeros(len(BANDS)), np.zeros(len(BANDS))
    exposure_dir, falls_dir = np.zeros(len(DIRECTIONS)), np.zeros(len(DIRECTIONS))
    causes = np.zeros(len(FALL_CAUSES))
    band = np.zeros(envs, dtype=int)
    direction = np.zeros(envs, dtype=int)
    tall = np.zeros(envs, dtype=bool)

    def note_band(env, t) -> None:  # the relief and the command where the step starts
        r = relief(env)
        band[:] = np.select([r >= lo for _, lo in BANDS], range(len(BANDS)))
        tall[:] = r >= TALL_M
        vx = env.commands.value[:, 0]
        direction[:] = np.select([vx > lo for _, lo in DIRECTIONS], range(len(DIRECTIONS)))

    def count(env, res, walking) -> None:
        fell = walking & res.failed
        exposure[:] += np.bincount(band[walking], minlength=len(BANDS)) * env.policy_dt
        falls[:] += np.bincount(band[fell], minlength=len(BANDS))
        exposure_dir[:] += np.bincount(direction[walking & tall], minlength=len(DIRECTIONS)) * env.policy_dt
        falls_dir[:] += np.bincount(direction[fell & tall], minlength=len(DIRECTIONS))
        causes[:] += res.fall_causes[fell].sum(axis=0)

    result = run_batch(
        policy,
        EvalSpec("discrete", level, envs, steps, True, seed=seed),
        before_step=note_band,
        after_step=count,
    )

    def rows(bands, exp, fal) -> list[tuple]:
        return [
            (label, e, int(f), 60.0 * f / e if e > 0 else float("nan"))
            for (label, _), e, f in zip(bands, exp, fal, strict=True)
        ]

    return (
        rows(BANDS, exposure, falls),
        rows(DIRECTIONS, exposure_dir, falls_dir),
        causes,
        float(result.metrics["success_rate"]),
        int(result.left.sum()),
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint")
    ap.add_argument("--actor", default="student", choices=("student", "teacher"))
    ap.add_argument("--level", type=int, default=9)
    ap.add_argument("--envs", type=int, default=128)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--steps", type=int, default=500)
    args = ap.parse_args()
    rows, by_command, causes, success, left = falls_on_discrete(
        args.checkpoint, args.actor, args.level, args.envs, args.seed, args.steps
    )
    print(
        f"discrete, level {args.level}, {args.actor}, {args.envs} envs x {args.steps} steps: "
        f"success {100 * success:.1f} %, {left} left the tile"
    )
    print("band, exposure (s), falls, falls per minute")
    for label, e, f, rate in rows:
        print(f"{label:16s} {e:7.0f} {f:5d} {rate:7.2f}")
    print(f"where the relief passes {100 * TALL_M:.0f} cm, by the forward command:")
    for label, e, f, rate in by_command:
        print(f"{label:16s} {e:7.0f} {f:5d} {rate:7.2f}")
    print("causes: " + ", ".join(f"{n} {int(c)}" for n, c in zip(FALL_CAUSES, causes, strict=True)))


if __name__ == "__main__":
    main()
