"""A policy card's tables in Markdown, read from the JSON that ``tron1 eval``, ``tron1 push-test``
and ``tron1 deploy-sim --json`` write: Table I beside the paper's row, the climb probe, Fig. 5
(success by commanded speed) and Fig. 6 (pushes). Nothing here runs a policy.

``ship_tables(DIR)`` reads the layout ``tools/ship_perceptive.sh`` writes and marks a part
that is not there yet as such, so a half-done shipping run still gives its tables.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from tron1cli.deploy.runs import summary_rows, summary_title
from tron1cli.evaluation.metric_names import EVAL_LAYOUTS, PERCENT_METRICS
from tron1cli.evaluation.paper import PAPER_TABLE_I
from tron1cli.viz.cells import figure, speed_cell

#: Table I's columns after method: (header, eval metric, scale, decimals)
_TABLE_I_COLUMNS = (
    ("success %", "success_rate", 100.0, 1),
    ("progress", "command_progress", 1.0, 2),
    ("traverse %", "traverse_rate", 100.0, 1),
    ("orientation err.", "orientation_error", 1.0, 3),
    ("ang. vel. err. (rad/s)", "angular_velocity_error", 1.0, 2),
    ("vel. err. (m/s)", "velocity_tracking_error", 1.0, 2),
    ("rec. err. (cm)", "reconstruction_error_cm", 1.0, 2),
)
#: what a standard error in Table I stands for, printed under it
SE_NOTE = (
    "SE: the binomial standard error over the envs, taken as independent. An eval batch spreads "
    f"its envs over {EVAL_LAYOUTS} random terrain layouts of the level (`--layouts`); with the "
    "training bank's 2, one student checkpoint succeeded 58.9 % on discrete with seed 0 and 52.9 % "
    "with seed 1, while on 16 layouts another gave 64.9 and 64.3 % (1024 envs each, 2026-12-07)."
)
#: the paper's terrain order; other terrains an eval holds follow it
_TERRAINS = tuple(PAPER_TABLE_I)


def _row(cells) -> str:
    return "| " + " | ".join(str(c) for c in cells) + " |"


def _header(cells) -> str:
    return _row(cells) + "\n" + _row("---" for _ in cells)


def _cell(m: dict | None, metric: str, scale: float, decimals: int, envs: int) -> str:
    """One measured figure: the mean, then the std over a method's policies where it has several,
    or, for one policy's success or traverse rate, the binomial standard error over its envs."""
    if m is None or m["mean"] is None:
        return "-"
    text = f"{scale * m['mean']:.{decimals}f}"
    if m["n"] > 1:
        return f"{text} ± {scale * m['std']:.{decimals}f}"
    if metric in PERCENT_METRICS:
        p = m["mean"]
        return f"{text} (SE {100.0 * math.sqrt(p * (1.0 - p) / envs):.1f})"
    return text


def table1_markdown(reports: list[dict], paper: bool = True) -> str:
    """Table I: one row per terrain and method of each ``tron1 eval`` report (its results.json),
    then the paper's row ("Ours", mean ± std over its 3 seeds) under each of the paper's terrains."""
    terrains: list[str] = []
    for rep in reports:
        terrains += [t for t in rep["protocol"]["terrains"] if t not in terrains]
    terrains.sort(key=lambda t: _TERRAINS.index(t) if t in _TERRAINS else len(_TERRAINS))
    lines = [_header(["terrain", "method", *(c[0] for c in _TABLE_I_COLUMNS)])]
    for t in terrains:
        for rep in reports:
            proto = rep["protocol"]
            for label, per in rep["results"].items():
                if t not in per:
                    continue
                cells = (_cell(per[t].get(m), m, k, d, proto["envs"]) for _, m, k, d in _TABLE_I_COLUMNS)
                lines.append(_row([t, f"{label} ({proto['actor']})", *cells]))
        if paper and t in PAPER_TABLE_I:
            ref = PAPER_TABLE_I[t]
            cells = (
                f"{k * ref[m][0]:.{d}f} ± {k * ref[m][1]:.{d}f}" if m in ref else "-"
                for _, m, k, d in _TABLE_I_COLUMNS
            )
            lines.append(_row([t, "paper (Ours, 3 seeds)", *cells]))
    return "\n".join(lines) + "\n\n" + SE_NOTE


def climb_markdown(report: dict) -> str:
    """The climb probe (``tron1 eval --climb``, climb.json): one row per actor and level."""
    lines = [
        _header(
            [
                "actor",
                "level",
                "riser (cm)",
                "success %",
                "traverse %",
                "progress",
                "risers",
                "fell: tilt / base / thigh %",
            ]
        )
    ]
    for r in report["rows"]:
        falls = " / ".join(f"{100.0 * r[k]:.1f}" for k in ("fell_tilt", "fell_base", "fell_thigh"))
        lines.append(
            _row(
                [
                    r["actor"],
                    r["level"],
                    f"{100.0 * r['riser_m']:.0f}",
                    f"{100.0 * r['success']:.1f}",
                    f"{100.0 * r['traverse']:.1f}",
                    f"{r['progress']:.2f}",
                    f"{r['risers']:.1f}",
                    falls,
                ]
            )
        )
    return "\n".join(lines)


def speeds_markdown(reports: list[dict]) -> str:
    """Fig. 5: success % / command progress by commanded speed, one table per velocity dimension,
    one row per terrain and method, from eval reports run with ``--speeds``."""
    by_dim: dict[str, list[str]] = {}
    speeds: dict[str, list[str]] = {}
    units: dict[str, str] = {}
    for rep in reports:
        for dim, sweep in rep.get("success_by_speed", {}).items():
            units[dim] = sweep["unit"]
            progress = rep["progress_by_speed"][dim]["results"]
            for label, per in sweep["results"].items():
                for t, by_v in per.items():
                    vs = speeds.setdefault(dim, list(by_v))
                    cells = [speed_cell(by_v.get(v), progress[label][t].get(v)) for v in vs]
                    by_dim.setdefault(dim, []).append(_row([t, label, *cells]))
    parts = []
    for dim, rows in by_dim.items():
        head = _header(["terrain", "method", *(f"{dim} {v} {units[dim]}" for v in speeds[dim])])
        parts.append(f"success % / command progress by commanded {dim}:\n\n" + head + "\n" + "\n".join(rows))
    return "\n\n".join(parts)


def pushes_markdown(reports: list[dict]) -> str:
    """Fig. 6: survival under pushes (``tron1 push-test`` results.json), one row per protocol,
    terrain and method: overall, then per push type."""
    if not reports:
        return ""
    types = list(next(iter(reports[0]["methods"].values()))["per_push"])
    lines = [_header(["pushes", "terrain", "method", "survival %", *types])]
    for rep in reports:
        proto = rep["protocol"]
        for label, m in rep["methods"].items():
            per = (f"{100.0 * m['per_push'][k]:.0f}" for k in types)
            lines.append(
                _row([proto["name"], proto["terrain"], label, f"{100.0 * m['survival_rate']:.1f}", *per])
            )
    return "\n".join(lines)


def deploy_markdown(rep: dict) -> str:
    """deploy-sim's figures (``tron1 deploy-sim --json``, one run or ``--runs N``) as a two-column
    table."""
    if "summary" in rep:
        sm = rep["summary"]
        rows = [("runs", summary_title(sm)), *summary_rows(sm)]
        return _header(["figure", "value"]) + "\n" + "\n".join(_row(r) for r in rows)

    rows = [
        ("run", f"{Path(rep['policy']).name} on {rep['terrain_type']} level {rep['level']}"),
        ("survived", f"{'yes' if rep['survived'] else 'no'} ({rep['ended']})"),
        ("simulated time (s)", f"{rep['duration_s']:.2f} of {rep['requested_duration_s']:g}"),
        ("velocity tracking error (m/s)", figure(rep["vel_tracking_error"])),
        ("heightmap reconstruction error (cm)", figure(rep.get("reconstruction_error_cm"), ".2f")),
        ("real-time factor", figure(rep["realtime_factor"], ".2f")),
        ("depth rate (Hz)", figure(rep.get("depth_rate_hz"), ".1f")),
        ("depth frames (dropped)", f"{rep.get('depth_frames')} ({rep.get('depth_dropped')})"),
        (
            "policy inference p50 / p99 (ms)",
            f"{figure(rep['policy_ms_p50'])} / {figure(rep['policy_ms_p99'])}",
        ),
    ]
    return _header(["figure", "value"]) + "\n" + "\n".join(_row(r) for r in rows)


def _render(render, paths: list[Path]) -> str:
    """``render`` of the JSON in ``paths``; ValueError naming the files when one is not the
    output it should be."""
    try:
        return render([json.loads(p.read_text()) for p in paths])
    except (ValueError, KeyError, TypeError, IndexError) as e:
        names = ", ".join(str(p) for p in paths)
        raise ValueError(f"{names}: not the output of the command that should write it ({e!r})") from None


def ship_tables(out: Path) -> str:
    """All the card's tables from a ``tools/ship_perceptive.sh`` output directory, in Markdown;
    a file that is not there yet is named under its table as not yet run."""
    fig5 = sorted(out.glob("fig5_*/results.json")) or [out / "fig5_TERRAIN" / "results.json"]
    pushes = sorted(out.glob("push_moderate_*/results.json")) + sorted(
        out.glob("push_extreme_*/results.json")
    )
    sections = (
        (
            "Table I, hardest level",
            [out / f"table1_{k}" / "results.json" for k in ("student", "teacher", "blind")],
            table1_markdown,
        ),
        ("Climb probe (stairs up)", [out / "climb" / "climb.json"], lambda reps: climb_markdown(reps[0])),
        ("Fig. 5, success by commanded speed", fig5, speeds_markdown),
        ("Fig. 6, pushes", pushes or [out / "push_moderate_TERRAIN" / "results.json"], pushes_markdown),
        (
            "deploy-sim, hardest stairs up with depth",
            [out / "deploy_sim_stairs.json"],
            lambda reps: deploy_markdown(reps[0]),
        ),
    )
    parts = []
    for title, paths, render in sections:
        present = [p for p in paths if p.is_file()]
        missing = [str(p) for p in paths if not p.is_file()]
        text = [_render(render, present)] if present else []
        if missing:
            text.append("(not yet run: " + ", ".join(missing) + ")")
        parts.append(f"### {title}\n\n" + "\n\n".join(text))
    return "\n\n".join(parts) + "\n"
