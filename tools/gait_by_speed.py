"""How does a teacher walk at a fixed forward speed on stairs up? Posture and feet, by speed.

A lab tool, not a ``tron1`` command: for each commanded forward speed (m/s; no lateral or yaw
command) it runs the climb probe's set-up (stairs up at one level, the policy's own training
randomisation, seed 0, 128 envs) for 300 policy steps (6 s) and prints, over the envs still
walking at each step: survival at the end, the forward speed walked (m/s), the risers climbed
per env (the highest the ground under the base got above its spawn, in risers, rounded), the
base's height above the ground under it (m; 0.81 with straight legs), the swinging feet's
clearance (m, foot-sphere centre above the ground under it, averaged over every step a foot is
in the air) and the mean of each swing's highest clearance (m; lift-off to touchdown).

    python tools/gait_by_speed.py policies/runs/climb/checkpoints/latest.pt --level 9
"""

from __future__ import annotations

import argparse

import numpy as np

from tron1cli.env.terrain import riser_m
from tron1cli.evaluation.climb import CLIMB_ENVS, CLIMB_TERRAIN, risers_climbed
from tron1cli.evaluation.protocol import EvalSpec, run_batch
from tron1cli.policy.runtime import load_policy

SPEEDS = (0.3, 0.5, 0.8)  #: default forward speeds (m/s)
COLUMNS = ("survival", "vx_mps", "risers", "base_height_m", "swing_clearance_m", "swing_peak_m")


def gait_at_speed(policy, level: int, speed: float, envs: int = CLIMB_ENVS, steps: int = 300) -> dict:
    """The figures of :data:`COLUMNS` for ``policy``'s teacher commanded ``speed`` m/s forward."""
    vx, height, clearance, peaks = [], [], [], []
    top = np.full((envs, 2), -np.inf)  # the highest clearance of each foot's swing so far (m)

    def take(env, res, walking) -> None:
        s, ok = env.state, walking & ~res.done  # a done env's state is already its reset
        top[~ok] = -np.inf  # a swing cut by a fall or a reset is not counted
        if not ok.any():
            return
        vx.append(s.base_lin_vel_b[ok, 0].mean())
        height.append((s.base_pos[:, 2] - env.ground_height(s.base_pos[:, :2]))[ok].mean())
        feet = np.stack([env.ground_height(s.foot_pos[:, k, :2]) for k in range(2)], axis=1)
        swing = ~s.foot_in_contact & ok[:, None]
        above = s.foot_pos[:, :, 2] - feet
        if swing.any():
            clearance.append(above[swing].mean())
        top[swing] = np.maximum(top[swing], above[swing])
        landed = s.foot_in_contact & np.isfinite(top)
        peaks.extend(top[landed])
        top[landed] = -np.inf

    spec = EvalSpec(CLIMB_TERRAIN, level, envs, steps, True, speed=speed, seed=0)
    result = run_batch(policy, spec, after_step=take)
    return dict(
        survival=result.metrics["success_rate"],
        vx_mps=float(np.mean(vx)) if vx else float("nan"),
        risers=risers_climbed(result.rise_m, riser_m(policy.run_cfg.env.terrain_cfg, level)),
        base_height_m=float(np.mean(height)) if height else float("nan"),
        swing_clearance_m=float(np.mean(clearance)) if clearance else float("nan"),
        swing_peak_m=float(np.mean(peaks)) if peaks else float("nan"),
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint")
    ap.add_argument("--level", type=int, default=9)
    ap.add_argument("--speeds", type=float, nargs="+", default=list(SPEEDS))
    args = ap.parse_args()
    policy = load_policy(args.checkpoint, actor="teacher")
    print(f"stairs up, level {args.level}, teacher: speed (m/s), " + ", ".join(COLUMNS))
    for v in args.speeds:
        row = gait_at_speed(policy, args.level, v)
        print(f"{v:5.2f} " + " ".join(f"{row[c]:8.3f}" for c in COLUMNS))


if __name__ == "__main__":
    main()
