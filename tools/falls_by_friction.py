"""Does the ground's grip bound success? Success by the friction coefficient an env drew.

A lab tool, not a ``tron1`` command: it runs eval's protocol (training commands, randomisation
on, full window, 500 steps, seed 0) on one level of one terrain type and splits the envs by the
sliding friction of their feet and ground (Table III: uniform in 0.4-1.2), reporting success per
band. On a slope of angle a a standing point foot slides once the friction coefficient is below
tan(a) (0.63 at the hardest slope, 32 degrees): the printout gives that bound beside the bands.

    python tools/falls_by_friction.py CKPT --terrain slope_up
    python tools/falls_by_friction.py CKPT --terrain slope_down --actor student --envs 512
"""

from __future__ import annotations

import argparse

import numpy as np

from tron1cli.env.terrain import TERRAIN_TYPES, TerrainConfig
from tron1cli.evaluation.protocol import EvalSpec, run_batch
from tron1cli.policy.runtime import load_policy

EDGES = (0.4, 0.5, 0.6, 0.7, 0.8, 1.0, 1.2)  #: friction bands (Table III's range cut into six)


def falls_by_friction(
    path: str, terrain: str, level: int = 9, envs: int = 256, actor: str = "teacher", steps: int = 500
) -> list[tuple]:
    """Rows (band label, envs, success %, its standard error) of ``actor`` of checkpoint ``path``."""
    policy = load_policy(path, actor=actor)
    mu = np.full(envs, np.nan)
    fell = np.zeros(envs, dtype=bool)

    def note_friction(env, t) -> None:
        if t == 0:  # drawn at the reset; only a fall ends an env's window, so it holds throughout
            g = env.randomizer.ground
            mu[:] = [m.geom_friction[g, 0] for m in env.physics.models]

    def count(env, res, walking) -> None:
        fell[walking & res.failed] = True

    run_batch(
        policy,
        EvalSpec(terrain, level, envs, steps, True, seed=0),
        before_step=note_friction,
        after_step=count,
    )
    band = np.digitize(mu, EDGES[1:-1])  # 0..5; the top edge falls in the last band
    labels = [f"{lo:.1f}-{hi:.1f}" for lo, hi in zip(EDGES[:-1], EDGES[1:], strict=True)]
    rows = [_row(label, fell[band == k]) for k, label in enumerate(labels)]
    return [*rows, _row("all", fell)]


def _row(label: str, fell: np.ndarray) -> tuple:
    """(label, envs, success %, its standard error) of the envs whose falls are ``fell``."""
    n = len(fell)
    p = 1.0 - fell.mean() if n else float("nan")
    return label, n, 100 * p, 100 * np.sqrt(p * (1 - p) / max(n, 1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint")
    ap.add_argument("--terrain", default="slope_up", choices=TERRAIN_TYPES)
    ap.add_argument("--level", type=int, default=9)
    ap.add_argument("--envs", type=int, default=256)
    ap.add_argument("--actor", default="teacher", choices=("teacher", "student"))
    args = ap.parse_args()
    tan = TerrainConfig().slope_tan[1]
    print(
        f"{args.actor} on {args.terrain}, level {args.level}, {args.envs} envs (a point foot standing on "
        f"the hardest slope slides below friction {tan:.2f}): band, envs, success %, s.e."
    )
    for label, n, p, se in falls_by_friction(
        args.checkpoint, args.terrain, args.level, args.envs, args.actor
    ):
        print(f"{label:8s} {n:5d} {p:6.1f} {se:5.1f}")


if __name__ == "__main__":
    main()
