"""Where a run directory keeps what (torch-free, so the CLI checks a run directory before torch loads).

- ``config.json``: the resolved run configuration (env, reward, learner, seed, ...);
- ``checkpoints/ckpt_<iteration>.pt`` and ``checkpoints/latest.pt``: versioned plain dicts of
  tensors plus the config, written atomically;
- ``metrics.jsonl``: one JSON object per iteration (throughput, per-group rewards, per-term
  episode sums, survival, episode length, tracking error, losses, learning rate, ...).
"""

from __future__ import annotations

from pathlib import Path

from tron1cli.errors import Tron1Error
from tron1cli.fileio import check_output_dir

CONFIG = "config.json"
CHECKPOINTS = "checkpoints"
LATEST = "latest.pt"
METRICS = "metrics.jsonl"


def checkpoint_dir(run_dir: Path | str) -> Path:
    """The run's checkpoint folder."""
    return Path(run_dir) / CHECKPOINTS


def latest_checkpoint(run_dir: Path | str) -> Path:
    """The run's latest checkpoint (what ``--resume`` continues from)."""
    return checkpoint_dir(run_dir) / LATEST


def check_run_dir(run_dir: Path | str, resume: bool) -> None:
    """Clear errors before anything is built: a resume without a run, a run directory that cannot
    be made or written."""
    check_output_dir(run_dir, "--run-dir")
    if resume and not latest_checkpoint(run_dir).exists():
        raise Tron1Error(f"nothing to resume in {run_dir}: no {CHECKPOINTS}/{LATEST}")


def policy_label(path: Path) -> str:
    """A policy's name in tables when none is given: its run's name for a run's latest checkpoint
    (``runs/x/checkpoints/latest.pt`` -> ``x``, also given as ``checkpoints/latest.pt`` from
    inside the run), else the file's stem."""
    p = path.resolve()
    if p.name == LATEST and p.parent.name == CHECKPOINTS and p.parent.parent.name:
        return p.parent.parent.name
    return path.stem
