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
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from tron1cli.errors import Tron1Error, UsageError
from tron1cli.fileio import atomic_write, clean_stale_temps, same_path, temp_prefix
from tron1cli.policy import contract as pc
from tron1cli.policy.runtime import Policy, load_policy, load_student, onnx_policy

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
    checkpoint: Path,
    out: Path | None = None,
    parity_steps: int = 200,
    tol: float = 1e-4,
    on_loaded=None,
) -> ExportReport:
    """Check, compare with torch, then write the ONNX file (atomically); see the module doc.

    Nothing is written unless the graph passes the checker and the parity check, so a failed
    export leaves an earlier file in place. on_loaded(): called once the checkpoint has loaded.
    """
    import onnx

    checkpoint = Path(checkpoint)
    out = Path(out) if out is not None else default_output(checkpoint)
    if same_path(out, checkpoint):
        raise UsageError(f"-o {out} is the checkpoint being exported; writing there would destroy it")
    student, run_cfg, state = load_student(checkpoint)  # refuses non-finite weights
    if on_loaded is not None:
        on_loaded()
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
    diffs = parity(load_policy(checkpoint), onnx_policy(model, out), parity_steps)
    worst = max(diffs.values())
    if not worst <= tol:
        raise Tron1Error(
            f"onnxruntime differs from torch by {worst:.2e} (> {tol:.0e}) over {parity_steps} steps"
        )
    clean_stale_temps(out.parent, temp_prefix(out))  # an earlier export killed midway
    data = model.SerializeToString()
    atomic_write(out, lambda f: f.write(data), fsync=False)
    return ExportReport(out, parity_steps, worst, diffs, out.stat().st_size)


def parity(ref: Policy | Path, ort: Policy | Path, steps: int, num_envs: int = 2) -> dict[str, float]:
    """Largest |onnx - torch| per output over a ``steps``-long recurrent rollout in the policy's env.

    ref, ort: the torch and the onnxruntime policy (or their files). A non-finite output of
    either raises :class:`Tron1Error` (NaN would otherwise compare as no difference at all).
    """
    from tron1cli.env.core import Tron1Env

    ref = ref if isinstance(ref, Policy) else load_policy(ref)
    ort = ort if isinstance(ort, Policy) else load_policy(ort)
    cfg = ref.run_cfg
    env = Tron1Env(replace(cfg.env, num_envs=num_envs, nthread=1, depth_from=0), cfg.reward)
    try:
        obs = env.reset()
        h_ref = ref.initial_hidden(num_envs)
        h_ort = ort.initial_hidden(num_envs)
        worst = dict.fromkeys(pc.OUTPUTS, 0.0)
        for t in range(steps):
            depth = ref.depth_input(obs, num_envs)
            a = ref.step(obs["history"], depth, h_ref)
            b = ort.step(obs["history"], depth, h_ort)
            for name, x, y in zip(pc.OUTPUTS, a, b, strict=True):
                if not (np.isfinite(x).all() and np.isfinite(y).all()):
                    raise Tron1Error(
                        f"the policy's output {name} is not finite at step {t} of the parity rollout "
                        "(NaN or inf); not exported"
                    )
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
