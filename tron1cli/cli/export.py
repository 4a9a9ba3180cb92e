"""``tron1 export-onnx``: the student policy of a checkpoint as a self-describing ONNX file."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from tron1cli.cli.common import (
    check_inputs,
    check_outputs,
    err,
    fail,
    finite,
    note,
    out,
    path_option,
    print_json,
)


def export_onnx(
    checkpoint: Path = typer.Argument(..., help="Training checkpoint (.pt).", show_default=False),
    output: Path | None = typer.Option(
        None,
        "--output",
        "-o",
        parser=path_option,
        metavar="FILE.onnx",
        help="ONNX file (.onnx) [default: beside the checkpoint].",
    ),
    parity_steps: int = typer.Option(200, "--parity-steps", min=1, help="Recurrent rollout steps compared."),
    tol: float = typer.Option(
        1e-4, "--tol", callback=finite, min=0.0, help="Largest |onnxruntime - torch| allowed."
    ),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object on stdout."),
) -> None:
    """Export the student (both estimators, normalisation baked in, mean action) and verify it.

    Inputs history, depth, hidden; outputs action, hidden_next, h_hat, e_hat; the metadata holds
    the whole deployment contract. Fails (exit 1) if onnxruntime and torch differ by more than --tol
    over a recurrent rollout in the policy's own env.
    """
    check_inputs([checkpoint], "checkpoint")
    from tron1cli.policy.export import default_output
    from tron1cli.train.checkpoint import refuse_onnx

    refuse_onnx(checkpoint)  # before the output check: an ONNX's default output is itself
    from tron1cli.policy.export import export_onnx as run_export

    target = output if output is not None else default_output(checkpoint)
    replaced = check_outputs(files=[("-o", target)], inputs=[checkpoint])
    if target.suffix.lower() != ".onnx":  # a .pt name would pass it off as a checkpoint
        fail(f"-o {target}: an ONNX export's name ends in .onnx, e.g. -o {target.with_suffix('.onnx')}", 2)
    what = f"exporting {checkpoint} and comparing onnxruntime with torch over {parity_steps} steps ..."
    with err.status(what):  # transient: an error is the only line
        rep = run_export(checkpoint, target, parity_steps, tol)
    if replaced:
        note(f"replaced the earlier {rep.path}")
    if as_json:
        print_json(
            {
                "onnx": str(rep.path),
                "size_bytes": rep.size_bytes,
                "parity_steps": rep.parity_steps,
                "max_abs_diff": rep.max_abs_diff,
                "per_output": rep.per_output,
            }
        )
        return
    t = Table(title=f"{rep.path} ({rep.size_bytes / 1024:.0f} KiB), checker passed")
    t.add_column("output")
    t.add_column(f"max |onnx - torch| over {rep.parity_steps} steps", justify="right")
    for k, v in rep.per_output.items():
        t.add_row(k, f"{v:.2e}")
    out.print(t)
