"""``tron1 report``: a training run's (or a campaign's) progress as a table, and its curves."""

from __future__ import annotations

from pathlib import Path

import typer
from rich import box
from rich.table import Table

from tron1cli.cli.common import check_outputs, err, fail, finite, out, path_option, warn
from tron1cli.train.layout import METRICS


def report(
    run_dirs: list[Path] = typer.Argument(
        ...,
        help="Run directories (holding metrics.jsonl); several are a campaign's phases, in order.",
        show_default=False,
    ),
    every_min: float = typer.Option(
        20.0, "--every-min", callback=finite, min=0.1, help="One line every this many wall-clock minutes."
    ),
    smooth: int = typer.Option(
        20, "--smooth", min=1, help="Each figure: the mean over this many iterations."
    ),
    markdown: bool = typer.Option(False, "--markdown", help="Print a Markdown table (for a card) instead."),
    png: Path | None = typer.Option(
        None,
        "--png",
        parser=path_option,
        metavar="FILE.png",
        help="Also write the curves (survival, tracking, level per type, heightmap error).",
    ),
    x: str = typer.Option(
        "minutes",
        "--x",
        metavar="minutes|env_steps",
        help="The x axis of --png: wall-clock minutes or env steps.",
    ),
) -> None:
    """Where training stands, read from the run directories alone (no checkpoint is loaded): one
    line every --every-min wall-clock minutes and the last iteration, with survival, tracking
    error, terrain level per type and heightmap error, each a mean over --smooth iterations. A
    campaign's phases (runs started with --init from the one before) make one series; their
    minutes and env steps add up.
    """
    from tron1cli.viz.campaign import (
        REPORT_COLUMNS,
        X_AXES,
        campaign_cells,
        campaign_phases,
        campaign_table,
    )

    if x not in X_AXES:
        fail(f"--x {x}: must be one of {', '.join(X_AXES)}", 2)
    if png is not None and png.suffix.lower() != ".png":
        fail(f"--png {png}: the file must end in .png, e.g. --png curves.png", 2)
    check_outputs(files=[("--png", png)], inputs=[Path(d) / METRICS for d in run_dirs])
    try:
        rows = campaign_phases(run_dirs, on_skip=warn)
    except ValueError as e:
        fail(str(e), 1)
    if not rows:
        fail(f"{run_dirs[-1]}: metrics.jsonl holds no iteration yet", 1)
    if markdown:
        out.print(campaign_table(rows, every_min, smooth), markup=False, highlight=False, soft_wrap=True)
    else:
        last = rows[-1]
        for title, columns in REPORT_COLUMNS.items():
            table = Table(box=box.SIMPLE_HEAD, pad_edge=False, collapse_padding=True, title=title)
            for h in ("min", "phase", "iter", "steps\n(M)", *columns):
                table.add_column(h, justify="right")
            for cells in campaign_cells(rows, every_min, smooth, columns):
                table.add_row(*cells)
            out.print(table)
        out.print(
            f"{len(run_dirs)} run director{'ies' if len(run_dirs) > 1 else 'y'}, {len(rows):,} iterations, "
            f"{last['env_steps'] / 1e6:.1f} M env steps, {last['wall_s'] / 60:.0f} wall-clock minutes; "
            f"each figure a mean over the {smooth} iterations up to its line",
            highlight=False,
            soft_wrap=True,
        )
    if png is not None:
        from tron1cli.viz.plots import campaign_curves

        campaign_curves(list(run_dirs), png, smooth, x)
        err.print(f"curves written to {png}", highlight=False, soft_wrap=True)
