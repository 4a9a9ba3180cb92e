"""tools/branch_run.py: a run branched with another teacher share and more terrain layouts a
level resumes as that run."""

from __future__ import annotations

import json

import pytest

from tests.conftest import lab_tool, make_tiny_checkpoint, tron1
from tron1cli.errors import Tron1Error
from tron1cli.train.checkpoint import load_training_checkpoint
from tron1cli.train.runner import RunConfig


@pytest.mark.slow  # trains a tiny run and resumes it through the CLI (about 25 s on 2 cores)
def test_branch_moves_the_depth_split_and_the_layouts_and_resumes(tmp_path):
    tool = lab_tool("branch_run")
    src = make_tiny_checkpoint(tmp_path / "src", perception=True).parents[1]  # 8 envs, 4 teachers
    before = load_training_checkpoint(src / "checkpoints" / "latest.pt")["curriculum"]
    dst = tmp_path / "dst"
    assert tool.branch(src, dst, 0.25, layouts=5) == 1
    after = load_training_checkpoint(dst / "checkpoints" / "latest.pt")
    for cfg in (json.loads((dst / "config.json").read_text()), json.loads(after["config"])):
        assert cfg["learner"]["teacher_ratio"] == 0.25 and cfg["env"]["depth_from"] == 2
        assert RunConfig.from_dict(cfg).n_teacher == 2  # the split RunConfig checks
        assert cfg["env"]["terrain_cfg"]["variants_per_level"] == 5
    old, new = before["tile"].numpy(), after["curriculum"]["tile"].numpy()
    assert (new // 5 == old // 2).all()  # each env on its own type and level, 2 -> 5 layouts
    assert (after["curriculum"]["level"] == before["level"]).all()
    assert (dst / "metrics.jsonl").read_text() == (src / "metrics.jsonl").read_text()
    r = tron1("train", "--resume", "--iterations", "2", "--run-dir", str(dst))
    assert r.returncode == 0, r.stderr
    ck = load_training_checkpoint(dst / "checkpoints" / "latest.pt")
    assert ck["iteration"] == 2 and ck["learner"]["n_teacher"] == 2
    with pytest.raises(Tron1Error, match="exists"):
        tool.branch(src, dst, 0.25)
    with pytest.raises(Tron1Error, match="no teacher or no student"):
        tool.branch(src, tmp_path / "none", 0.0)
    with pytest.raises(Tron1Error, match="nothing to change"):
        tool.branch(src, tmp_path / "none")


def test_branched_configuration_hand_computed():
    tool = lab_tool("branch_run")
    config = {
        "learner": {"teacher_ratio": 0.5},
        "env": {"num_envs": 8, "terrain_cfg": {"variants_per_level": 2}},
    }
    out = tool.branched(config, 0.25, layouts=5)
    assert out["learner"]["teacher_ratio"] == 0.25 and out["env"]["depth_from"] == 2
    assert out["env"]["terrain_cfg"]["variants_per_level"] == 5
    assert config["learner"]["teacher_ratio"] == 0.5  # the input is left as it was
    assert tool.branched(config, layouts=3)["learner"] == config["learner"]


def test_relaid_tiles_maps_hand_computed_indices():
    tool = lab_tool("branch_run")
    tiles = tool.relaid_tiles([0, 1, 2, 3, 19], old=2, new=4, seed=0)
    assert list(tiles // 4) == [0, 0, 1, 1, 9]  # (type, level) groups of 2 -> groups of 4
