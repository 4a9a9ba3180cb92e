"""Checkpoints: a versioned plain dict of tensors and the resolved config, written atomically.

Loading uses ``torch.load(weights_only=True)``: a checkpoint can hold tensors, numbers, strings,
lists and dicts, never arbitrary pickled objects.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import torch

from tron1cli.errors import Tron1Error

FORMAT = "tron1cli-checkpoint"
VERSION = 1


def save_checkpoint(path: Path, payload: dict) -> None:
    """Write ``payload`` (plus format and version) to ``path`` atomically (temp file + rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = {"format": FORMAT, "version": VERSION, **payload}
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            torch.save(data, f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def load_checkpoint(path: Path) -> dict:
    """Load a checkpoint safely; a missing, corrupt or foreign file raises :class:`Tron1Error`."""
    path = Path(path)
    if not path.is_file():
        raise Tron1Error(f"checkpoint not found: {path}")
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises many types for truncated or foreign files
        raise Tron1Error(
            f"cannot read checkpoint {path}: {type(e).__name__}: {str(e).splitlines()[0]}"
        ) from e
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise Tron1Error(f"{path} is not a tron1cli checkpoint")
    if data.get("version") != VERSION:
        raise Tron1Error(
            f"{path}: checkpoint format version {data.get('version')}, this tron1 reads {VERSION}"
        )
    return data
