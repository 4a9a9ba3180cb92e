"""Branch a training run at its latest checkpoint with another teacher share, keeping everything
else: weights, optimiser state, terrain levels, iteration count, seed and the metrics so far.

A lab tool for one-change experiments (same start, seed and optimiser state), not a ``tron1``
command: ``tron1 train --resume`` refuses a changed ``--teacher-ratio``, and ``--init`` starts a
fresh optimiser. This writes DST as a copy of SRC whose run configuration (config.json and the
checkpoint's own copy) has ``learner.teacher_ratio`` set and ``env.depth_from`` moved to the first
student, then ``tron1 train --resume --run-dir DST`` goes on from there.

    python tools/branch_run.py policies/runs/cts_phase2 /tmp/arm --teacher-ratio 0.125
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

from tron1cli.errors import Tron1Error
from tron1cli.fileio import write_file
from tron1cli.learn.config import teacher_count
from tron1cli.train.checkpoint import load_training_checkpoint, save_checkpoint
from tron1cli.train.layout import CONFIG, METRICS, checkpoint_dir, latest_checkpoint


def branched(config: dict, teacher_ratio: float) -> dict:
    """A copy of a run configuration (config.json's dict) with the teacher share changed and the
    students' depth starting at the first student."""
    out = json.loads(json.dumps(config))
    out["learner"]["teacher_ratio"] = teacher_ratio
    out["env"]["depth_from"] = teacher_count(out["env"]["num_envs"], teacher_ratio)
    return out


def branch(src: Path, dst: Path, teacher_ratio: float) -> int:
    """Write the branch; returns the iteration it starts from."""
    if dst.exists():
        raise Tron1Error(f"{dst} exists; branch into a new folder")
    state = load_training_checkpoint(latest_checkpoint(src))
    config = branched(json.loads(state["config"]), teacher_ratio)
    if not 0 < config["env"]["depth_from"] < config["env"]["num_envs"]:
        raise Tron1Error(f"--teacher-ratio {teacher_ratio:g} leaves no teacher or no student")
    checkpoint_dir(dst).mkdir(parents=True)
    state["config"] = json.dumps(config)
    save_checkpoint(
        latest_checkpoint(dst), {k: v for k, v in state.items() if k not in ("format", "version")}
    )
    write_file(
        dst / CONFIG, json.dumps(branched(json.loads((src / CONFIG).read_text()), teacher_ratio), indent=2)
    )
    shutil.copyfile(src / METRICS, dst / METRICS)
    return int(state["iteration"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("src", type=Path, help="the run directory to branch from")
    ap.add_argument("dst", type=Path, help="the new run directory")
    ap.add_argument("--teacher-ratio", type=float, required=True, help="the branch's share of teacher envs")
    args = ap.parse_args()
    try:
        it = branch(args.src, args.dst, args.teacher_ratio)
    except (Tron1Error, OSError, KeyError, ValueError) as e:
        sys.exit(f"error: {e}")
    print(f"{args.dst}: branched from {args.src} at iteration {it} with teacher_ratio {args.teacher_ratio:g}")


if __name__ == "__main__":
    main()
