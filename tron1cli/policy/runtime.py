"""Load a student policy from a training checkpoint (torch) or an exported ONNX file (onnxruntime).

Both give the same object: :class:`Policy`, a batched, deterministic step
``(history, depth, hidden) -> (action, hidden_next, h_hat, e_hat)`` in numpy, with the contract
(:mod:`tron1cli.policy.contract`) that says which env it expects. Evaluation, push tests and
deploy-sim drive either kind through this one interface. A checkpoint can also be loaded as its
teacher (``actor="teacher"``: privileged e_t and the true heightmap instead of the estimators), so
that the evaluation protocol measures the teacher-student gap.
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


def _load_model(path: Path) -> tuple[torch.nn.Module, Any, dict]:
    """(VisionCTS in eval mode, no gradients, RunConfig, the raw checkpoint) of a training checkpoint."""
    from tron1cli.learn import LearnerConfig, ObsDims, VisionCTS
    from tron1cli.train.checkpoint import load_training_checkpoint
    from tron1cli.train.runner import RunConfig

    state = load_training_checkpoint(path)
    try:
        run_cfg = RunConfig.from_dict(json.loads(state["config"]))
        sd = state["learner"]
        model = VisionCTS(
            ObsDims.from_dict(sd["dims"]), tuple(sd["groups"]), LearnerConfig.from_dict(sd["config"])
        )
        model.load_state_dict(sd["model"])
    except (KeyError, TypeError, ValueError, RuntimeError, AttributeError) as e:
        raise Tron1Error(f"{path}: checkpoint does not hold a usable policy ({_short(e)})") from e
    bad = [k for k, v in model.state_dict().items() if v.is_floating_point() and not torch.isfinite(v).all()]
    if bad:
        raise Tron1Error(f"{path}: the policy's weights are not finite (NaN or inf in {bad[0]})")
    model.eval()
    for p in model.parameters():
        p.requires_grad_(False)
    return model, run_cfg, state


def _refuse_teacher_stage(path: Path, run_cfg) -> None:
    """Tron1Error for a checkpoint of the teacher stage: every env a teacher, no student trained."""
    if run_cfg.n_teacher >= run_cfg.env.num_envs:
        raise Tron1Error(
            f"{path} is a teacher-stage checkpoint (no student was trained): evaluate it with "
            "--actor teacher, or finish it with tron1 train --preset perceptive --init"
        )


def load_student(path: Path) -> tuple[torch.nn.Module, Any, dict]:
    """(StudentPolicy in eval mode, RunConfig, the raw checkpoint) of a training checkpoint."""
    from tron1cli.learn import StudentPolicy

    model, run_cfg, state = _load_model(path)
    _refuse_teacher_stage(path, run_cfg)
    return StudentPolicy(model).eval(), run_cfg, state


@dataclass
class Policy:
    """A deterministic policy, batched over B rows: a student (checkpoint or ONNX) or the teacher
    of a checkpoint.

    path: where it came from; kind: "checkpoint" or "onnx"; contract: its deployment contract;
    run_cfg: the RunConfig it was trained with (rebuilt from the contract for ONNX files).
    """

    path: Path
    kind: str
    contract: dict
    run_cfg: Any
    _torch: torch.nn.Module | None = None
    _ort: Any = None
    _teacher: torch.nn.Module | None = None  # the whole VisionCTS when the teacher acts

    @property
    def actor(self) -> str:
        return "teacher" if self._teacher is not None else "student"

    @property
    def gru_hidden(self) -> int:
        return int(self.contract["gru_hidden"])

    @property
    def depth_hw(self) -> tuple[int, int] | None:
        hw = self.contract["obs_layout"].get("depth_hw")
        return None if hw is None else (int(hw[0]), int(hw[1]))

    def initial_hidden(self, batch: int) -> np.ndarray:
        return np.zeros((batch, self.gru_hidden), dtype=np.float32)

    def depth_input(self, obs: dict[str, np.ndarray], batch: int) -> np.ndarray:
        """The depth input: the env's frames, or a (B, 1, 1) placeholder for a blind policy."""
        if self.depth_hw is None:
            return np.zeros((batch, 1, 1), dtype=np.float32)
        return np.asarray(obs["depth"], dtype=np.float32)

    def act(
        self, obs: dict[str, np.ndarray], hidden: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One step from the env's observation groups: (action, hidden_next, h_hat (m; no columns
        for the teacher, which reads the true heightmap))."""
        if self._teacher is None:
            action, hidden, h_hat, _ = self.step(obs["history"], self.depth_input(obs, len(hidden)), hidden)
            return action, hidden, h_hat
        m = self._teacher
        keys = ("proprio", "history", "privileged") + (("heightmap",) if m.latent_h_dim else ())
        with torch.no_grad():
            ob = m.normalize({k: torch.from_numpy(np.asarray(obs[k], dtype=np.float32)) for k in keys})
            le, lh = m.teacher_latents(ob["privileged"], ob.get("heightmap"))
            action = m.action_mean(ob["proprio"], le, lh).numpy()
        return action, hidden, np.zeros((len(action), 0), dtype=np.float32)

    def step(self, history: np.ndarray, depth: np.ndarray, hidden: np.ndarray) -> Arrays:
        """One student step for B rows: returns (action, hidden_next, h_hat (m), e_hat), numpy float32."""
        if self._teacher is not None:
            raise Tron1Error(f"{self.path}: loaded as its teacher, which acts on privileged observations")
        history = np.ascontiguousarray(history, dtype=np.float32)
        depth = np.ascontiguousarray(depth, dtype=np.float32)
        hidden = np.ascontiguousarray(hidden, dtype=np.float32)
        if self._ort is not None:
            outs = self._ort.run(None, {"history": history, "depth": depth, "hidden": hidden})
            return tuple(np.asarray(o) for o in outs)  # type: ignore[return-value]
        with torch.no_grad():
            outs = self._torch(torch.from_numpy(history), torch.from_numpy(depth), torch.from_numpy(hidden))
        return tuple(o.numpy() for o in outs)  # type: ignore[return-value]


def _short(e: BaseException) -> str:
    """One line for a loading error; torch's shape mismatches list every tensor on lines of their own."""
    lines = [x.strip() for x in str(e).splitlines() if x.strip()]
    if len(lines) > 1 and lines[0].startswith("Error(s) in loading state_dict"):
        more = f" and {len(lines) - 2} more" if len(lines) > 2 else ""
        return f"weights of another shape: {lines[1].rstrip('.')}{more}"
    return f"{type(e).__name__}: {lines[0]}" if lines else type(e).__name__


def _static_dims(value_info) -> list[int | None]:
    """The dims of a graph input or output: ints, None where symbolic (the batch)."""
    dims = value_info.type.tensor_type.shape.dim
    return [d.dim_value if d.HasField("dim_value") else None for d in dims]


def check_graph(model, contract: dict, where: str) -> None:
    """Refuse an ONNX graph whose inputs and outputs disagree with its own contract (names,
    ranks, widths), and one whose weights are not finite."""
    from onnx import numpy_helper

    names_in = [i.name for i in model.graph.input]
    names_out = [o.name for o in model.graph.output]
    if names_in != list(pc.INPUTS) or names_out != list(pc.OUTPUTS):
        raise Tron1Error(
            f"{where}: graph inputs {names_in} / outputs {names_out} do not match the contract "
            f"{list(pc.INPUTS)} / {list(pc.OUTPUTS)}"
        )
    layout = contract["obs_layout"]
    gru = int(contract["gru_hidden"])
    hw = layout.get("depth_hw") or [1, 1]
    want = {
        "history": [None, int(layout["sizes"]["history"])],
        "depth": [None, int(hw[0]), int(hw[1])],
        "hidden": [None, gru],
        "action": [None, len(contract["joint_names"])],
        "hidden_next": [None, gru],
    }
    for vi in (*model.graph.input, *model.graph.output):
        if vi.name not in want:
            continue
        have, need = _static_dims(vi), want[vi.name]
        if len(have) != len(need) or any(h is not None and h != n for h, n in zip(have, need, strict=False)):
            show = ["batch" if d is None else d for d in have]
            raise Tron1Error(
                f"{where}: graph {vi.name} has shape {show}, its contract says "
                f"{['batch', *need[1:]]} (obs_layout, gru_hidden)"
            )
    for init in model.graph.initializer:
        if init.data_type in (1, 10, 11, 16):  # float, float16, double, bfloat16
            arr = numpy_helper.to_array(init)
            if not np.isfinite(arr.astype(np.float64, copy=False)).all():
                raise Tron1Error(f"{where}: the policy's weights are not finite (NaN or inf in {init.name})")


def onnx_policy(model, path: Path) -> Policy:
    """A :class:`Policy` of an in-memory ONNX model (its contract and graph checked)."""
    import onnxruntime as ort

    from tron1cli.train.runner import RunConfig

    contract = pc.from_metadata({p.key: p.value for p in model.metadata_props}, str(path))
    check_graph(model, contract, str(path))
    try:
        run_cfg = RunConfig.from_dict(contract["run_config"])
    except (KeyError, TypeError, ValueError) as e:
        raise Tron1Error(f"{path}: the contract's run configuration is unreadable ({e})") from e
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    opts.inter_op_num_threads = 1
    try:
        sess = ort.InferenceSession(model.SerializeToString(), opts, providers=["CPUExecutionProvider"])
    except Exception as e:  # onnxruntime's own error types
        raise Tron1Error(f"{path}: onnxruntime cannot load the graph ({_short(e)})") from e
    return Policy(path, "onnx", contract, run_cfg, _ort=sess)


def load_policy(path: Path | str, actor: str = "student") -> Policy:
    """Load ``path`` (a ``.pt`` checkpoint or an ``.onnx`` export) as its student, or a checkpoint as
    its teacher (``actor="teacher"``); bad files raise Tron1Error."""
    path = Path(path)
    if actor not in pc.ACTORS:
        raise ValueError(f"unknown actor '{actor}'; choose from {', '.join(pc.ACTORS)}")
    if not path.is_file():
        raise Tron1Error(f"policy not found: {path}")
    from tron1cli.train.checkpoint import onnx_source

    # by its content: an ONNX export named .pt is loaded as what it is
    if path.suffix == ".onnx" or onnx_source(path) is not None:
        if actor == "teacher":
            raise Tron1Error(
                f"{path}: an ONNX export holds the student only; the teacher needs the checkpoint"
            )
        import onnx

        try:
            model = onnx.load(str(path))
        except Exception as e:  # protobuf raises its own DecodeError types
            raise Tron1Error(f"cannot read ONNX file {path}: {type(e).__name__}") from e
        return onnx_policy(model, path)
    from tron1cli.learn import StudentPolicy

    model, run_cfg, state = _load_model(path)
    contract = pc.build_contract(run_cfg, int(state["learner"]["config"]["gru_hidden"]), str(path))
    if actor == "teacher":
        return Policy(path, "checkpoint", contract, run_cfg, _teacher=model)
    _refuse_teacher_stage(path, run_cfg)
    return Policy(path, "checkpoint", contract, run_cfg, _torch=StudentPolicy(model).eval())
