"""Checkpoints: a versioned plain dict of tensors and the resolved config, written atomically.

Loading uses ``torch.load(weights_only=True)``: a checkpoint can hold tensors, numbers, strings,
lists and dicts, never arbitrary pickled objects. :func:`load_training_checkpoint` also checks
the form of a training run's checkpoint (what every reader of one relies on) once, where it is
read.
"""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import torch

from tron1cli.errors import Tron1Error, describe
from tron1cli.fileio import atomic_write

FORMAT = "tron1cli-checkpoint"
VERSION = 1

#: what a policy (an ONNX export) is, and what to do with one where a checkpoint is read
ONNX_HINT = (
    "eval, push-test and deploy-sim take it as it is; export-onnx and train --init need the "
    "training checkpoint (.pt) it was exported from"
)


def save_checkpoint(path: Path, payload: dict) -> None:
    """Write ``payload`` (plus format and version) to ``path`` atomically (temp file + rename).

    The checkpoint is serialised in memory first, so a disk that fills while it is written raises
    ``OSError`` (ENOSPC, naming the file) rather than torch's RuntimeError, and the file it would
    replace is kept."""
    data = {"format": FORMAT, "version": VERSION, **payload}
    buf = io.BytesIO()
    torch.save(data, buf)
    blob = buf.getbuffer()
    atomic_write(Path(path), lambda f: f.write(blob))


def onnx_source(path: Path) -> str | None:
    """When ``path`` holds an ONNX model (by its content, whatever its name): the checkpoint it
    says it was exported from ('' when it says none); None for any other file."""
    path = Path(path)
    try:
        if zipfile.is_zipfile(path):  # a torch checkpoint is a zip archive
            return None
        import onnx

        model = onnx.load(str(path), load_external_data=False)
    except Exception:  # noqa: BLE001 - anything onnx cannot read is not an ONNX file
        return None
    if model.ir_version <= 0 or not model.graph.node:
        return None
    props = {p.key: p.value for p in model.metadata_props}
    try:
        source = json.loads(props.get("source_checkpoint", '""'))
    except ValueError:
        source = ""
    return source if isinstance(source, str) else ""


def refuse_onnx(path: Path) -> None:
    """Raise :class:`Tron1Error` saying what to do when ``path``, read where a training checkpoint
    is expected, holds an ONNX export (:func:`onnx_source`)."""
    source = onnx_source(path)
    if source is not None:
        came = f" (exported from {source})" if source else ""
        raise Tron1Error(f"{path} is an exported ONNX policy{came}, not a training checkpoint: {ONNX_HINT}")


def load_checkpoint(path: Path) -> dict:
    """Load a checkpoint safely; a missing, corrupt or foreign file raises :class:`Tron1Error`."""
    path = Path(path)
    if not path.is_file():
        raise Tron1Error(f"checkpoint not found: {path}")
    if path.stat().st_size == 0:
        raise Tron1Error(f"cannot read checkpoint {path}: the file is empty")
    refuse_onnx(path)
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


def _is_count(x, least: int = 0) -> bool:
    return isinstance(x, int) and not isinstance(x, bool) and x >= least


def _tensors(d) -> bool:
    return isinstance(d, dict) and all(isinstance(k, str) and torch.is_tensor(v) for k, v in d.items())


def check_training_checkpoint(data: dict, where: str) -> None:
    """Refuse (:class:`Tron1Error`, one line naming ``where``) a checkpoint without the form of a
    training run's: its run configuration (JSON text of an object), the learner's state (weights
    as tensors, observation dims, reward groups, learner settings), the iteration and env-step
    counts, and, where present, the curriculum and episode statistics as tensors."""

    def bad(what: str) -> Tron1Error:
        return Tron1Error(f"{where}: not a usable training checkpoint ({what})")

    if not isinstance(data.get("config"), str):
        raise bad("no run configuration" if "config" not in data else "its run configuration is not text")
    try:
        config = json.loads(data["config"])
    except ValueError as e:
        raise bad(f"its run configuration is not JSON: {e}") from None
    if not isinstance(config, dict):
        raise bad("its run configuration is not a JSON object")
    learner = data.get("learner")
    if not isinstance(learner, dict):
        raise bad("no learner state" if learner is None else "its learner state is not a dict")
    if not _tensors(learner.get("model")) or not learner["model"]:
        raise bad("its learner state holds no weights")
    if not isinstance(learner.get("dims"), dict):
        raise bad("its learner state lacks the observation dims")
    groups = learner.get("groups")
    if not isinstance(groups, list | tuple) or not groups or not all(isinstance(g, str) for g in groups):
        raise bad("its learner state lacks the reward groups")
    lcfg = learner.get("config")
    if not isinstance(lcfg, dict) or not _is_count(lcfg.get("gru_hidden"), 1):
        raise bad("its learner state lacks the learner settings")
    for key in ("iteration", "env_steps"):
        if not _is_count(data.get(key)):
            raise bad(f"{key} = {data.get(key)!r} is not a count")
    wall = data.get("wall_s", 0.0)
    if isinstance(wall, bool) or not isinstance(wall, int | float):
        raise bad(f"wall_s = {wall!r} is not a number")
    for key in ("curriculum", "episode_stats"):
        if key in data and not _tensors(data[key]):
            raise bad(f"its {key} is not a dict of tensors")


def load_training_checkpoint(path: Path) -> dict:
    """:func:`load_checkpoint` of a training run's checkpoint, its form checked
    (:func:`check_training_checkpoint`)."""
    data = load_checkpoint(path)
    check_training_checkpoint(data, str(path))
    return data


def nonfinite_weights(model_state: dict) -> list[str]:
    """Names of the floating-point tensors of a state dict that hold NaN or inf."""
    return [k for k, v in model_state.items() if v.is_floating_point() and not bool(torch.isfinite(v).all())]
