"""Load a student policy from a training checkpoint (torch) or an exported ONNX file (onnxruntime).

Both give the same object: :class:`Policy`, a batched, deterministic step
``(history, depth, hidden) -> (action, hidden_next, h_hat, e_hat)`` in numpy, with the contract
(:mod:`tron1cli.policy.contract`) that says which env it expects. Evaluation, push tests and
deploy-sim drive either kind through this one interface.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from tron1cli.errors import Tron1Error
from tron1cli.policy import contract as pc

Arrays = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def load_student(path: Path) -> tuple[torch.nn.Module, Any, dict]:
    """(StudentPolicy in eval mode, RunConfig, the raw checkpoint) of a training checkpoint."""
    from tron1cli.learn import LearnerConfig, ObsDims, StudentPolicy, VisionCTS
    from tron1cli.train.checkpoint import load_checkpoint
    from tron1cli.train.runner import RunConfig

    state = load_checkpoint(path)
    try:
        run_cfg = RunConfig.from_dict(json.loads(state["config"]))
        sd = state["learner"]
        model = VisionCTS(
            ObsDims.from_dict(sd["dims"]), tuple(sd["groups"]), LearnerConfig.from_dict(sd["config"])
        )
        model.load_state_dict(sd["model"])
    except (KeyError, TypeError, ValueError, RuntimeError) as e:
        raise Tron1Error(f"{path}: checkpoint does not hold a usable policy ({type(e).__name__}: {e})") from e
    student = StudentPolicy(model).eval()
    for p in student.parameters():
        p.requires_grad_(False)
    return student, run_cfg, state


@dataclass
class Policy:
    """A deterministic student policy, batched over B rows.

    path: where it came from; kind: "checkpoint" or "onnx"; contract: its deployment contract;
    run_cfg: the RunConfig it was trained with (rebuilt from the contract for ONNX files).
    """

    path: Path
    kind: str
    contract: dict
    run_cfg: Any
    _torch: torch.nn.Module | None = None
    _ort: Any = None

    @property
    def gru_hidden(self) -> int:
        return int(self.contract["gru_hidden"])

    @property
    def depth_hw(self) -> tuple[int, int] | None:
        hw = self.contract["obs_layout"]["depth_hw"]
        return None if hw is None else (int(hw[0]), int(hw[1]))

    @property
    def label(self) -> str:
        return self.path.stem if self.path.stem != "latest" else self.path.parent.parent.name

    def initial_hidden(self, batch: int) -> np.ndarray:
        return np.zeros((batch, self.gru_hidden), dtype=np.float32)

    def depth_input(self, obs: dict[str, np.ndarray], batch: int) -> np.ndarray:
        """The depth input: the env's frames, or a (B, 1, 1) placeholder for a blind policy."""
        if self.depth_hw is None:
            return np.zeros((batch, 1, 1), dtype=np.float32)
        return np.asarray(obs["depth"], dtype=np.float32)

    def step(self, history: np.ndarray, depth: np.ndarray, hidden: np.ndarray) -> Arrays:
        """One policy step for B rows: returns (action, hidden_next, h_hat (m), e_hat), numpy float32."""
        history = np.ascontiguousarray(history, dtype=np.float32)
        depth = np.ascontiguousarray(depth, dtype=np.float32)
        hidden = np.ascontiguousarray(hidden, dtype=np.float32)
        if self._ort is not None:
            outs = self._ort.run(None, {"history": history, "depth": depth, "hidden": hidden})
            return tuple(np.asarray(o) for o in outs)  # type: ignore[return-value]
        with torch.no_grad():
            outs = self._torch(torch.from_numpy(history), torch.from_numpy(depth), torch.from_numpy(hidden))
        return tuple(o.numpy() for o in outs)  # type: ignore[return-value]


def load_policy(path: Path | str) -> Policy:
    """Load ``path`` (a ``.pt`` checkpoint or an ``.onnx`` export); bad files raise Tron1Error."""
    from tron1cli.train.runner import RunConfig

    path = Path(path)
    if not path.is_file():
        raise Tron1Error(f"policy not found: {path}")
    if path.suffix == ".onnx":
        import onnx
        import onnxruntime as ort

        try:
            model = onnx.load(str(path))
        except Exception as e:  # protobuf raises its own DecodeError types
            raise Tron1Error(f"cannot read ONNX file {path}: {type(e).__name__}") from e
        contract = pc.from_metadata({p.key: p.value for p in model.metadata_props}, str(path))
        names_in = [i.name for i in model.graph.input]
        names_out = [o.name for o in model.graph.output]
        if names_in != list(pc.INPUTS) or names_out != list(pc.OUTPUTS):
            raise Tron1Error(
                f"{path}: graph inputs {names_in} / outputs {names_out} do not match the contract "
                f"{list(pc.INPUTS)} / {list(pc.OUTPUTS)}"
            )
        try:
            run_cfg = RunConfig.from_dict(contract["run_config"])
        except (KeyError, TypeError, ValueError) as e:
            raise Tron1Error(f"{path}: the contract's run configuration is unreadable ({e})") from e
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = 1
        opts.inter_op_num_threads = 1
        sess = ort.InferenceSession(model.SerializeToString(), opts, providers=["CPUExecutionProvider"])
        return Policy(path, "onnx", contract, run_cfg, _ort=sess)
    student, run_cfg, state = load_student(path)
    contract = pc.build_contract(run_cfg, int(state["learner"]["config"]["gru_hidden"]), str(path))
    return Policy(path, "checkpoint", contract, run_cfg, _torch=student)
