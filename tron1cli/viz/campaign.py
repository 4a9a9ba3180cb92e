"""A training campaign's record: the metrics of its phases as one series, and the card's table.

A campaign is one or more run directories in order, each phase started with ``tron1 train
--init`` from the previous phase's weights (and each possibly resumed across runs).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

from tron1cli.train.layout import METRICS

#: the curves' x axes (``tron1 report --x``): name -> (label, metrics key, divisor)
X_AXES = {
    "minutes": ("wall-clock minutes", "wall_s", 60.0),
    "env_steps": ("env steps (millions)", "env_steps", 1e6),
}

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


def read_metrics(run_dir: Path, on_skip: Callable[[str], None] | None = None) -> list[dict]:
    """The per-iteration metrics of a run directory (``metrics.jsonl``). A cut-off last line (a
    run killed while writing it) is left out, and ``on_skip`` told so in one line; ValueError for
    a missing file or a corrupt line elsewhere."""
    path = Path(run_dir) / METRICS
    if not path.is_file():
        raise ValueError(f"{run_dir}: no metrics.jsonl (not a training run directory)")
    lines = path.read_bytes().decode(errors="replace").splitlines()
    rows = []
    for k, line in enumerate(lines):
        if not line.strip():
            continue
        try:
            row = json.loads(line)
        except json.JSONDecodeError:
            if k == len(lines) - 1:
                if on_skip is not None:
                    on_skip(f"{path} line {k + 1} is cut off (a run stopped while writing it); left out")
                break
            raise ValueError(f"{path} line {k + 1} is not JSON") from None
        if not isinstance(row, dict) or not {"wall_s", "env_steps"} <= row.keys():
            raise ValueError(f"{path} line {k + 1} is not a training iteration's metrics")
        rows.append(row)
    return rows


def campaign_phases(run_dirs: list[Path], on_skip: Callable[[str], None] | None = None) -> list[dict]:
    """The metrics of a campaign's phases in order as one series: ``wall_s`` and ``env_steps``
    made cumulative and each row tagged with its ``phase`` index (``on_skip``: told of a line
    left out, :func:`read_metrics`)."""
    out: list[dict] = []
    wall0 = steps0 = 0.0
    for i, run_dir in enumerate(run_dirs):
        rows = read_metrics(run_dir, on_skip)
        for m in rows:
            out.append(m | {"wall_s": m["wall_s"] + wall0, "env_steps": m["env_steps"] + steps0, "phase": i})
        if rows:
            wall0, steps0 = out[-1]["wall_s"], out[-1]["env_steps"]
    return out


def _mean(rows: list[dict], key: str) -> float | None:
    vals = [r[key] for r in rows if r.get(key) is not None]
    return sum(vals) / len(vals) if vals else None


#: ``tron1 report``'s two tables (each fits 80 columns): training figures (episode, tracking and
#: heightmap error are the students'), terrain level per type
REPORT_COLUMNS: dict[str, dict[str, tuple[tuple[str, ...], int]]] = {
    "training (episode, tracking and hmap: the students')": {
        short: TABLE_COLUMNS[long]
        for short, long in (
            ("teacher\nsurvival", "teacher survival"),
            ("student\nsurvival", "student survival"),
            ("episode\n(s)", "student episode (s)"),
            ("tracking\n(m/s)", "student tracking (m/s)"),
            ("mean\nlevel", "mean level"),
            ("hmap\n(cm)", "heightmap error (cm)"),
        )
    },
    "terrain level per type (0 easiest, 9 hardest)": {
        name.replace("_", "\n"): ((f"terrain/level/{name}",), 1)
        for name in ("stairs_up", "stairs_down", "slope_up", "slope_down", "rough", "discrete", "flat")
    },
}
LEAD_HEAD = ("wall-clock minutes", "phase", "iteration", "env steps (M)")


def campaign_cells(
    rows: list[dict], every_min: float = 15.0, smooth: int = 20, columns: dict = TABLE_COLUMNS
) -> list[list[str]]:
    """A campaign table's cells (rows of :func:`campaign_phases`; :data:`LEAD_HEAD`, then one
    cell per entry of ``columns``): one line every ``every_min`` wall-clock minutes and the last
    one, each figure a mean over the ``smooth`` iterations up to it within its phase."""
    out: list[list[str]] = []
    picks, next_t = [], every_min
    for i, r in enumerate(rows):
        if r["wall_s"] / 60.0 >= next_t or i == len(rows) - 1:
            picks.append(i)
            next_t = (r["wall_s"] / 60.0 // every_min + 1) * every_min
    for i in picks:
        r = rows[i]
        win = [x for x in rows[max(0, i - smooth + 1) : i + 1] if x["phase"] == r["phase"]]
        cells = [f"{r['wall_s'] / 60:.0f}", str(r["phase"] + 1), str(r.get("iteration", "-"))]
        cells.append(f"{r['env_steps'] / 1e6:.1f}")
        for keys, digits in columns.values():
            vals = [_mean(win, k) for k in keys]
            cells.append(" / ".join("-" if v is None else f"{v:.{digits}f}" for v in vals))
        out.append(cells)
    return out


def campaign_table(rows: list[dict], every_min: float = 15.0, smooth: int = 20) -> str:
    """:func:`campaign_cells` as a Markdown table (the card's)."""
    head = [*LEAD_HEAD, *TABLE_COLUMNS]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(c) + " |" for c in campaign_cells(rows, every_min, smooth)]
    return "\n".join(lines)
