"""A training campaign's record: the metrics of its phases as one series, and the card's table.

A campaign is one or more run directories in order, each phase started with ``tron1 train
--init`` from the previous phase's weights (and each possibly resumed across sessions).
"""

from __future__ import annotations

import json
from pathlib import Path

#: the card's columns: header -> (metrics keys, decimals)
TABLE_COLUMNS: dict[str, tuple[tuple[str, ...], int]] = {
    "teacher survival": (("teacher/survival",), 2),
    "student survival": (("student/survival",), 2),
    "student episode (s)": (("student/episode_length_s",), 1),
    "student tracking (m/s)": (("student/vel_tracking_error",), 2),
    "mean level": (("terrain/mean_level",), 2),
    "stairs up / down": (("terrain/level/stairs_up", "terrain/level/stairs_down"), 1),
    "slopes up / down": (("terrain/level/slope_up", "terrain/level/slope_down"), 1),
    "rough": (("terrain/level/rough",), 1),
    "discrete": (("terrain/level/discrete",), 1),
    "heightmap error (cm)": (("learn/heightmap_err_cm",), 1),
}


def read_metrics(run_dir: Path) -> list[dict]:
    """The per-iteration metrics of a run directory (``metrics.jsonl``)."""
    path = Path(run_dir) / "metrics.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def campaign_phases(run_dirs: list[Path]) -> list[dict]:
    """The metrics of a campaign's phases in order as one series: ``wall_s`` and ``env_steps``
    made cumulative and each row tagged with its ``phase`` index."""
    out: list[dict] = []
    wall0 = steps0 = 0.0
    for i, run_dir in enumerate(run_dirs):
        rows = read_metrics(run_dir)
        for m in rows:
            out.append(m | {"wall_s": m["wall_s"] + wall0, "env_steps": m["env_steps"] + steps0, "phase": i})
        if rows:
            wall0, steps0 = out[-1]["wall_s"], out[-1]["env_steps"]
    return out


def _mean(rows: list[dict], key: str) -> float | None:
    vals = [r[key] for r in rows if r.get(key) is not None]
    return sum(vals) / len(vals) if vals else None


def campaign_table(rows: list[dict], every_min: float = 15.0, smooth: int = 20) -> str:
    """Markdown table of a campaign (rows of :func:`campaign_phases`): one line every
    ``every_min`` wall-clock minutes and the last one, each figure a mean over the ``smooth``
    iterations up to it within its phase."""
    head = ["wall-clock minutes", "phase", "iteration", "env steps (M)", *TABLE_COLUMNS]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    picks, next_t = [], every_min
    for i, r in enumerate(rows):
        if r["wall_s"] / 60.0 >= next_t or i == len(rows) - 1:
            picks.append(i)
            next_t = (r["wall_s"] / 60.0 // every_min + 1) * every_min
    for i in picks:
        r = rows[i]
        win = [x for x in rows[max(0, i - smooth + 1) : i + 1] if x["phase"] == r["phase"]]
        cells = [f"{r['wall_s'] / 60:.0f}", str(r["phase"] + 1), str(r["iteration"])]
        cells.append(f"{r['env_steps'] / 1e6:.1f}")
        for keys, digits in TABLE_COLUMNS.values():
            vals = [_mean(win, k) for k in keys]
            cells.append(" / ".join("-" if v is None else f"{v:.{digits}f}" for v in vals))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
