"""Shared console handles and the one-line error convention of every subcommand."""

from __future__ import annotations

import json
import os
import sys

from rich.console import Console

#: results go to stdout, progress and errors to stderr
out = Console()
err = Console(stderr=True)


def terrain_help(extra: tuple[str, ...] = ()) -> str:
    """Help text listing the CLI terrain names of the terrain registry (plus ``extra``)."""
    from tron1cli.env.terrain import terrain_choices

    return terrain_choices(extra) + "."


def fail(message: str, code: int = 1) -> None:
    """Print one line on stderr and exit with ``code`` (1 runtime, 2 usage)."""
    err.print(f"[bold red]error:[/] {message}", highlight=False, soft_wrap=True)
    sys.exit(code)


def print_json(obj: dict) -> None:
    """One JSON object on stdout, nothing else."""
    sys.stdout.write(json.dumps(obj, indent=2, sort_keys=False) + "\n")
    sys.stdout.flush()


def available_cores() -> int:
    """CPU cores this process may run on (its affinity mask; all cores where that is unknown)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def resolve_device(name: str) -> str:
    """``cpu`` or ``cuda`` (the learner's device); exits 2 naming the problem otherwise."""
    if name not in ("cpu", "cuda"):
        fail(f"--device must be cpu or cuda, got '{name}'", 2)
    if name == "cuda":
        import torch

        if not torch.cuda.is_available():
            fail(
                "--device cuda: torch sees no CUDA GPU on this machine (this torch build: "
                f"{torch.__version__}); use --device cpu",
                2,
            )
    return name
