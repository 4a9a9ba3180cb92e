"""PNG plots: training curves against wall-clock minutes."""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def read_metrics(run_dir: Path) -> list[dict]:
    """The per-iteration metrics of a run directory (``metrics.jsonl``)."""
    path = Path(run_dir) / "metrics.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def first_reached(
    rows: list[dict], survival: float = 0.9, error: float = 0.3, group: str = "student"
) -> dict:
    """Wall-clock minutes at which the survival and tracking-error thresholds were first met."""
    out: dict[str, float | None] = {"survival_min": None, "tracking_min": None, "both_min": None}
    for m in rows:
        s, e, t = m.get(f"{group}/survival"), m.get(f"{group}/vel_tracking_error"), m["wall_s"] / 60.0
        ok_s = s is not None and s >= survival
        ok_e = e is not None and e <= error
        if ok_s and out["survival_min"] is None:
            out["survival_min"] = t
        if ok_e and out["tracking_min"] is None:
            out["tracking_min"] = t
        if ok_s and ok_e and out["both_min"] is None:
            out["both_min"] = t
    return out


def training_curves(runs: dict[str, Path], out_png: Path, group: str = "student") -> Path:
    """Survival and velocity tracking error of ``group`` against wall-clock minutes, one line per run."""
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4))
    for label, run_dir in runs.items():
        rows = read_metrics(run_dir)
        t = [m["wall_s"] / 60.0 for m in rows]
        ax1.plot(t, [m.get(f"{group}/survival") for m in rows], label=label)
        ax2.plot(t, [m.get(f"{group}/vel_tracking_error") for m in rows], label=label)
    ax1.axhline(0.9, color="grey", ls="--", lw=0.8)
    ax2.axhline(0.3, color="grey", ls="--", lw=0.8)
    ax1.set(xlabel="wall-clock minutes", ylabel=f"{group} survival (share of episodes)", ylim=(0, 1.02))
    ax2.set(xlabel="wall-clock minutes", ylabel=f"{group} velocity tracking error (m/s)", ylim=(0, None))
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3)
        ax.legend()
    fig.tight_layout()
    out_png = Path(out_png)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=110)
    plt.close(fig)
    return out_png
