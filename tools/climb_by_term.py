"""Which randomisation term costs a teacher its climb? The climb probe's figures with Table III's
terms switched on one at a time.

A lab tool, not a ``tron1`` command: on stairs up at one level (128 envs x 500 steps, training
commands, full window, seed 0) the teacher of a checkpoint is scored as the climb probe scores it
(success, traverse, command progress along the path, risers climbed per env) on the nominal robot,
under every Table III term at once, with the paper's moderate pushes, and under each physical term
alone (the camera terms do not reach a teacher). Run it on a teacher trained on the nominal robot
to see which term it cannot meet:

    python tools/climb_by_term.py runs/climb/v1_nominal/checkpoints/latest.pt --level 6
"""

from __future__ import annotations

import argparse
from dataclasses import replace

from tron1cli.env.randomization import PushConfig, RandomizationConfig
from tron1cli.evaluation.climb import CLIMB_ENVS, CLIMB_TERRAIN, ClimbRow, climb_row
from tron1cli.evaluation.protocol import EvalSpec
from tron1cli.policy.runtime import load_policy


def term_sets(skip: tuple[str, ...] = ()) -> list[tuple[str, tuple[str, ...], bool]]:
    """(label, Table III terms on, pushes on) of each row, in print order; ``skip``: terms left out
    of every row ("all" is then Table III without them)."""
    every = RandomizationConfig.table_iii(skip).terms
    rows = [("none", (), False), ("all", every, False), ("all + pushes", every, True), ("pushes", (), True)]
    return rows + [(t, (t,), False) for t in every if not t.startswith("camera")]


def climb_by_term(
    path: str, level: int, skip: tuple[str, ...] = (), envs: int = CLIMB_ENVS, steps: int = 500
) -> list[tuple[str, ClimbRow]]:
    """The probe's row of the teacher of checkpoint ``path`` on stairs up at ``level`` under each
    of :func:`term_sets` (Table III's default ranges, moderate pushes)."""
    policy = load_policy(path, actor="teacher")
    run_cfg = policy.run_cfg
    rows = []
    for label, terms, pushes in term_sets(skip):
        env = replace(run_cfg.env, randomization=RandomizationConfig(terms=terms))
        policy.run_cfg = replace(run_cfg, env=env)
        push = PushConfig.moderate() if pushes else None
        spec = EvalSpec(CLIMB_TERRAIN, level, envs, steps, True, seed=0, pushes=push)
        rows.append((label, climb_row("teacher", policy, spec)))
    policy.run_cfg = run_cfg
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint")
    ap.add_argument("--level", type=int, default=6, help="stairs-up level (6: 14 cm risers)")
    ap.add_argument("--skip", default="", help="Table III terms to leave out of every row, comma-separated")
    args = ap.parse_args()
    skip = tuple(t for t in args.skip.split(",") if t)
    print(f"stairs up level {args.level}, teacher: success %, traverse %, progress, risers per env")
    for label, row in climb_by_term(args.checkpoint, args.level, skip):
        success, traverse = 100 * row.success, 100 * row.traverse
        print(f"{label:15s} {success:5.1f} {traverse:5.1f} {row.progress:.2f} {row.risers:.2f}")


if __name__ == "__main__":
    main()
