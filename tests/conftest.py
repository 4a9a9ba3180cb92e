"""Shared fixtures: tiny trained checkpoints (one PPO iteration) to drive the policy tools."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest


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
