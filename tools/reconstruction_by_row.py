"""Where does a student's heightmap reconstruction err? Mean |h_hat - h| per scan row, rear to front.

A lab tool, not a ``tron1`` command: the student of a checkpoint walks (training commands, its
training randomisation, seed 0) on one terrain type at one level; from step 25 on (the GRU has
seen a second of frames) every step of every env still up adds |h_hat - h| at each of the 441
scan points. Printed: the mean per scan row from the rear edge (x = -0.5 m, behind the base, out
of the camera's view) to the front edge (x = +0.5 m), in cm, and the overall mean. An error spread
over the whole scan says the image path is under-trained; one growing towards the rear says it is
short of memory (the camera sees the ground from about 0.3 m ahead of the base). Also printed: the
error split into a common offset (per frame, the mean of h_hat - h over the scan: the base height
misjudged) and what is left once it is removed (the terrain's shape misjudged):

    python tools/reconstruction_by_row.py policies/runs/cts_phase1/checkpoints/latest.pt --level 6
"""

from __future__ import annotations

import argparse

import numpy as np

from tron1cli.evaluation.protocol import EvalSpec, make_env
from tron1cli.policy.runtime import load_policy

WARMUP_STEPS = 25  #: policy steps (0.5 s) before the error counts


def error_by_row(
    path: str, terrain: str = "stairs_up", level: int = 6, envs: int = 32, steps: int = 150
) -> tuple[np.ndarray, float, float, int]:
    """(mean |h_hat - h| in m of each scan point, shaped (rows rear -> front, cols), mean |offset| m,
    mean |h_hat - h - offset| m, samples), offset being a frame's mean of h_hat - h over the scan."""
    policy = load_policy(path, actor="student")
    env = make_env(policy, EvalSpec(terrain=terrain, level=level, num_envs=envs, steps=steps))
    scan = env.height_scan
    try:
        obs = env.reset()
        hidden = policy.initial_hidden(envs)
        up = np.ones(envs, dtype=bool)
        total, count = np.zeros(scan.num_points), 0
        offset_sum, shape_sum = 0.0, 0.0
        for t in range(steps):
            action, hidden, h_hat = policy.act(obs, hidden)
            if not h_hat.shape[1]:
                raise SystemExit(f"{path}: the student reconstructs no heightmap (a run without one)")
            if t >= WARMUP_STEPS and up.any():
                diff = h_hat[up] - obs["heightmap"][up]  # (envs up, points)
                offset = diff.mean(axis=1, keepdims=True)
                total += np.abs(diff).sum(axis=0)
                offset_sum += float(np.abs(offset).sum())
                shape_sum += float(np.abs(diff - offset).mean(axis=1).sum())
                count += int(up.sum())
            res = env.step(action)
            obs = res.obs
            up &= ~res.done
    finally:
        env.close()
    n = max(count, 1)
    return (total / n).reshape(scan.num_x, scan.num_y), offset_sum / n, shape_sum / n, count


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint")
    ap.add_argument("--terrain", default="stairs_up")
    ap.add_argument("--level", type=int, default=6, help="terrain level (stairs up 6: 14 cm risers)")
    ap.add_argument("--envs", type=int, default=32)
    ap.add_argument("--steps", type=int, default=150, help="policy steps (50 Hz)")
    args = ap.parse_args()
    err, offset, shape, n = error_by_row(args.checkpoint, args.terrain, args.level, args.envs, args.steps)
    rows = " ".join(f"{100 * v:.1f}" for v in err.mean(axis=1))
    print(f"{args.terrain} level {args.level}, {n} env steps counted; mean |h_hat - h| (cm)")
    print(f"per scan row, rear -> front: {rows}")
    print(f"overall: {100 * err.mean():.2f}; common offset {100 * offset:.2f}, shape {100 * shape:.2f}")


if __name__ == "__main__":
    main()
