"""Export a checkpoint's student policy to ONNX and prove the export right.

The graph is :class:`tron1cli.learn.StudentPolicy`: normalisation baked in, deterministic (mean
action), inputs history (B, H*P), depth (B, rows, cols) and hidden (B, gru), outputs action,
hidden_next, h_hat and e_hat. The contract goes into the metadata. After writing, the file is
checked by the ONNX checker and onnxruntime is compared with torch over a recurrent rollout in
the policy's own env (the torch policy drives; both see the same inputs, the GRU state of each
is carried by itself).
"""

from __future__ import annotations

import io
import os
import tempfile
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from tron1cli.errors import Tron1Error
from tron1cli.policy import contract as pc
from tron1cli.policy.runtime import load_policy, load_student

OPSET = 17


@dataclass(frozen=True)
class ExportReport:
    path: Path
    parity_steps: int
    max_abs_diff: float
    per_output: dict[str, float]
    size_bytes: int


def default_output(checkpoint: Path) -> Path:
    """Beside the checkpoint: ``runs/x/checkpoints/latest.pt`` -> ``runs/x/checkpoints/latest.onnx``."""
    return checkpoint.with_suffix(".onnx")


def _onnx_bytes(student: torch.nn.Module, batch: int, hist_w: int, depth_hw, gru: int) -> bytes:
    args = (
        torch.zeros(batch, hist_w),
        torch.full((batch, *(depth_hw or (1, 1))), 1.0),
        torch.zeros(batch, gru),
    )
    buf = io.BytesIO()
    dyn = {n: {0: "batch"} for n in (*pc.INPUTS, *pc.OUTPUTS)}
    with warnings.catch_warnings():  # the TorchScript exporter (needs no onnxscript) warns it is deprecated
        warnings.simplefilter("ignore")
        torch.onnx.export(
            student,
            args,
            buf,
            input_names=list(pc.INPUTS),
            output_names=list(pc.OUTPUTS),
            dynamic_axes=dyn,
            opset_version=OPSET,
            dynamo=False,
        )
    return buf.getvalue()


def export_onnx(
    checkpoint: Path, out: Path | None = None, parity_steps: int = 200, tol: float = 1e-4
) -> ExportReport:
    """Write the ONNX file (atomically), check it, and compare it with torch; see the module doc."""
    import onnx

    checkpoint = Path(checkpoint)
    out = Path(out) if out is not None else default_output(checkpoint)
    student, run_cfg, state = load_student(checkpoint)
    gru = int(state["learner"]["config"]["gru_hidden"])
    contract = pc.build_contract(run_cfg, gru, str(checkpoint))
    layout = pc.layout_of(run_cfg)
    model = onnx.load_from_string(_onnx_bytes(student, 2, layout.history_dim, layout.depth_hw, gru))
    for k, v in pc.to_metadata(contract).items():
        entry = model.metadata_props.add()
        entry.key, entry.value = k, v
    model.producer_name = "tron1cli"
    try:
        onnx.checker.check_model(model, full_check=True)
    except onnx.checker.ValidationError as e:
        raise Tron1Error(f"the exported graph fails the ONNX checker: {str(e).splitlines()[0]}") from e
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=out.parent, prefix=f".{out.name}.", suffix=".tmp")
    with os.fdopen(fd, "wb") as f:
        f.write(model.SerializeToString())
    os.replace(tmp, out)
    diffs = parity(checkpoint, out, parity_steps)
    worst = max(diffs.values())
    if not worst <= tol:
        raise Tron1Error(
            f"onnxruntime differs from torch by {worst:.2e} (> {tol:.0e}) over {parity_steps} steps"
        )
    return ExportReport(out, parity_steps, worst, diffs, out.stat().st_size)


def parity(checkpoint: Path, onnx_path: Path, steps: int, num_envs: int = 2) -> dict[str, float]:
    """Largest |onnx - torch| per output over a ``steps``-long recurrent rollout in the policy's env."""
    from tron1cli.env.core import Tron1Env

    ref, ort = load_policy(checkpoint), load_policy(onnx_path)
    cfg = ref.run_cfg
    env = Tron1Env(replace(cfg.env, num_envs=num_envs, nthread=1, depth_from=0), cfg.reward)
    try:
        obs = env.reset()
        h_ref = ref.initial_hidden(num_envs)
        h_ort = ort.initial_hidden(num_envs)
        worst = dict.fromkeys(pc.OUTPUTS, 0.0)
        for _ in range(steps):
            depth = ref.depth_input(obs, num_envs)
            a = ref.step(obs["history"], depth, h_ref)
            b = ort.step(obs["history"], depth, h_ort)
            for name, x, y in zip(pc.OUTPUTS, a, b, strict=True):
                if x.size:
                    worst[name] = max(worst[name], float(np.max(np.abs(x - y))))
            h_ref, h_ort = a[1], b[1]
            res = env.step(a[0])
            for i in np.flatnonzero(res.done):
                h_ref[i] = 0.0
                h_ort[i] = 0.0
            obs = res.obs
    finally:
        env.close()
    return worst
