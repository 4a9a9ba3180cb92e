"""Branch a training run at its latest checkpoint with another teacher share or another number of
terrain layouts a level, keeping everything else: weights, optimiser state, terrain levels,
iteration count, seed and the metrics so far.

A lab tool for one-change experiments (same start, seed and optimiser state), not a ``tron1``
command: ``tron1 train --resume`` refuses a changed configuration, and ``--init`` starts a fresh
optimiser. This writes DST as a copy of SRC whose run configuration (config.json and the
checkpoint's own copy) has ``learner.teacher_ratio`` set and ``env.depth_from`` moved to the first
student (``--teacher-ratio``), or ``env.terrain_cfg.variants_per_level`` set and every env put on
a random layout of its own level (``--layouts``); then ``tron1 train --resume --run-dir DST`` goes
on from there.

    python tools/branch_run.py policies/runs/cts_phase2 /tmp/arm --teacher-ratio 0.125
    python tools/branch_run.py policies/runs/cts_phase2 /tmp/arm --layouts 16
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import numpy as np
import torch

from tron1cli.errors import Tron1Error
from tron1cli.fileio import write_file
from tron1cli.learn.config import teacher_count
from tron1cli.train.checkpoint import load_training_checkpoint, save_checkpoint
from tron1cli.train.layout import CONFIG, METRICS, checkpoint_dir, latest_checkpoint


def branched(config: dict, teacher_ratio: float | None = None, layouts: int | None = None) -> dict:
    """A copy of a run configuration (config.json's dict) with the teacher share changed and the
    students' depth starting at the first student, and/or ``layouts`` terrain tiles a level."""
    out = json.loads(json.dumps(config))
    if teacher_ratio is not None:
        out["learner"]["teacher_ratio"] = teacher_ratio
        out["env"]["depth_from"] = teacher_count(out["env"]["num_envs"], teacher_ratio)
    if layouts is not None:
        out["env"]["terrain_cfg"]["variants_per_level"] = layouts
    return out


def relaid_tiles(tile: np.ndarray, old: int, new: int, seed: int) -> np.ndarray:
    """Bank indices (N,) of a curriculum's tiles in a bank of ``new`` variants a (type, level)
    instead of ``old``: the same type and level, a variant drawn at random (seeded)."""
    group = np.asarray(tile) // old  # type_index * num_levels + level
    return group * new + np.random.default_rng([seed, new]).integers(0, new, len(group))


def branch(src: Path, dst: Path, teacher_ratio: float | None = None, layouts: int | None = None) -> int:
    """Write the branch; returns the iteration it starts from."""
    if dst.exists():
        raise Tron1Error(f"{dst} exists; branch into a new folder")
    if teacher_ratio is None and layouts is None:
        raise Tron1Error("nothing to change: give --teacher-ratio and/or --layouts")
    if layouts is not None and layouts < 1:
        raise Tron1Error(f"--layouts must be >= 1, got {layouts}")
    state = load_training_checkpoint(latest_checkpoint(src))
    before = json.loads(state["config"])
    config = branched(before, teacher_ratio, layouts)
    if teacher_ratio is not None and not 0 < config["env"]["depth_from"] < config["env"]["num_envs"]:
        raise Tron1Error(f"--teacher-ratio {teacher_ratio:g} leaves no teacher or no student")
    if layouts is not None:
        old = before["env"]["terrain_cfg"]["variants_per_level"]
        tiles = relaid_tiles(state["curriculum"]["tile"], old, layouts, before["env"]["seed"])
        state["curriculum"] = {**state["curriculum"], "tile": torch.as_tensor(tiles, dtype=torch.int64)}
    checkpoint_dir(dst).mkdir(parents=True)
    state["config"] = json.dumps(config)
    save_checkpoint(
        latest_checkpoint(dst), {k: v for k, v in state.items() if k not in ("format", "version")}
    )
    config_json = branched(json.loads((src / CONFIG).read_text()), teacher_ratio, layouts)
    write_file(dst / CONFIG, json.dumps(config_json, indent=2))
    shutil.copyfile(src / METRICS, dst / METRICS)
    return int(state["iteration"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("src", type=Path, help="the run directory to branch from")
    ap.add_argument("dst", type=Path, help="the new run directory")
    ap.add_argument("--teacher-ratio", type=float, help="the branch's share of teacher envs")
    ap.add_argument("--layouts", type=int, help="the branch's random terrain tiles per type and level")
    args = ap.parse_args()
    try:
        it = branch(args.src, args.dst, args.teacher_ratio, args.layouts)
    except (Tron1Error, OSError, KeyError, ValueError) as e:
        sys.exit(f"error: {e}")
    given = (("teacher_ratio", args.teacher_ratio), ("layouts", args.layouts))
    changes = [f"{k} {v:g}" for k, v in given if v is not None]
    print(f"{args.dst}: branched from {args.src} at iteration {it} with {', '.join(changes)}")


if __name__ == "__main__":
    main()
