"""Checkpoints: a versioned plain dict of tensors and the resolved config, written atomically.

Loading uses ``torch.load(weights_only=True)``: a checkpoint can hold tensors, numbers, strings,
lists and dicts, never arbitrary pickled objects.
"""

from __future__ import annotations

from pathlib import Path

import torch

from tron1cli.errors import Tron1Error, describe
from tron1cli.fileio import atomic_write

FORMAT = "tron1cli-checkpoint"
VERSION = 1


def save_checkpoint(path: Path, payload: dict) -> None:
    """Write ``payload`` (plus format and version) to ``path`` atomically (temp file + rename)."""
    data = {"format": FORMAT, "version": VERSION, **payload}
    atomic_write(Path(path), lambda f: torch.save(data, f))


def load_checkpoint(path: Path) -> dict:
    """Load a checkpoint safely; a missing, corrupt or foreign file raises :class:`Tron1Error`."""
    path = Path(path)
    if not path.is_file():
        raise Tron1Error(f"checkpoint not found: {path}")
    if path.stat().st_size == 0:
        raise Tron1Error(f"cannot read checkpoint {path}: the file is empty")
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises many types for truncated or foreign files
        if "weights only load failed" in str(e).lower():  # never pass on torch's weights_only=False advice
            why = "it holds more than plain tensors and numbers (pickled objects are never loaded)"
        else:
            why = describe(e)
        raise Tron1Error(f"cannot read checkpoint {path}: {why}") from e
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise Tron1Error(f"{path} is not a tron1cli checkpoint")
    if data.get("version") != VERSION:
        raise Tron1Error(
            f"{path}: checkpoint format version {data.get('version')}, this tron1 reads {VERSION}"
        )
    return data
