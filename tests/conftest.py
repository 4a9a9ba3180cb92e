"""Shared fixtures and helpers: tiny trained checkpoints (one PPO iteration), the CLI in a
subprocess, a foreign ONNX file, the lab tools of tools/."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest


def tron1(*args: str, env: dict[str, str] | None = None, timeout: float = 600) -> subprocess.CompletedProcess:
    """Run the ``tron1`` CLI in a subprocess (one torch thread), capturing its output; ``env``: more
    environment variables; ``timeout`` in s."""
    return subprocess.run(
        [sys.executable, "-m", "tron1cli", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env={"OMP_NUM_THREADS": "1", "PATH": "/usr/bin:/bin", **(env or {})},
    )


def write_foreign_onnx(path: Path) -> Path:
    """A valid ONNX model (one Identity node) that is not a tron1 policy."""
    import onnx
    from onnx import TensorProto, helper

    node = helper.make_node("Identity", ["x"], ["y"])
    g = helper.make_graph(
        [node],
        "g",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1])],
    )
    onnx.save(helper.make_model(g), str(path))
    return path


def make_tiny_checkpoint(run_dir: Path, perception: bool = False, gait: bool = True) -> Path:
    """Train one iteration with 8 envs and tiny networks; return the checkpoint path."""
    from tron1cli.config import EnvConfig, GaitConfig
    from tron1cli.learn import LearnerConfig
    from tron1cli.train.runner import RunConfig, Trainer

    env = EnvConfig(
        num_envs=8,
        nthread=1,
        terrain="stairs" if perception else "flat",
        perception=perception,
        depth_from=4,
        gait=GaitConfig(enabled=gait),
    )
    learner = replace(
        LearnerConfig(), num_steps_per_env=4, actor_hidden=(32,), critic_hidden=(32,), rec_batch_envs=4
    )
    trainer = Trainer(run_dir, RunConfig(env=env, learner=learner, gait_prior=gait, iterations=1))
    trainer.run()
    trainer.close()
    return run_dir / "checkpoints" / "latest.pt"


@pytest.fixture(scope="session")
def tiny_ckpt(tmp_path_factory) -> Path:
    """Blind, flat, gait prior on."""
    return make_tiny_checkpoint(tmp_path_factory.mktemp("tiny_flat"))


@pytest.fixture(scope="session")
def tiny_ckpt_vision(tmp_path_factory) -> Path:
    """Stairs with heightmap and depth (the student's image path)."""
    return make_tiny_checkpoint(tmp_path_factory.mktemp("tiny_vision"), perception=True)


def lab_tool(name: str):
    """The module of ``tools/NAME.py`` (lab tools are scripts, not a package)."""
    path = Path(__file__).resolve().parents[1] / "tools" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(f"tools_{name}", path)
    tool = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = tool  # a dataclass in the tool looks its module up there
    spec.loader.exec_module(tool)
    return tool
