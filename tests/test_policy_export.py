"""Policy contract, loading (checkpoint or ONNX) and ONNX export with its parity check."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import onnx
import pytest
from conftest import write_foreign_onnx

from tron1cli.config import GaitConfig
from tron1cli.env.core import Tron1Env
from tron1cli.errors import Tron1Error
from tron1cli.policy import contract as pc
from tron1cli.policy.export import export_onnx
from tron1cli.policy.runtime import load_policy


@pytest.fixture(scope="module")
def vision_onnx(tiny_ckpt_vision, tmp_path_factory):
    return export_onnx(tiny_ckpt_vision, tmp_path_factory.mktemp("onnx") / "v.onnx", parity_steps=200)


def test_export_parity_and_contract(vision_onnx, tiny_ckpt_vision):
    rep = vision_onnx
    assert rep.parity_steps == 200 and rep.max_abs_diff <= 1e-4 and rep.per_output["h_hat"] <= 1e-4
    model = onnx.load(str(rep.path))
    onnx.checker.check_model(model)
    meta = {p.key: json.loads(p.value) for p in model.metadata_props}
    assert meta["format"] == pc.FORMAT and meta["joint_names"][0] == "abad_L"
    assert meta["obs_layout"]["sizes"]["heightmap"] == 441 and meta["depth"]["rows"] == 60
    assert meta["gait_clock"]["enabled"] and meta["source_checkpoint"] == str(tiny_ckpt_vision)
    assert meta["gait_clock"]["swing_fold_rad"] == [0.0, 0.0]  # an action means what it did without one
    assert meta["gait_clock"]["swing_fold_keep"] == 0.0
    assert [i.name for i in model.graph.input] == list(pc.INPUTS)


def test_onnx_and_checkpoint_agree_on_a_batch(vision_onnx, tiny_ckpt_vision):
    a, b = load_policy(vision_onnx.path), load_policy(tiny_ckpt_vision)
    assert (a.kind, b.kind) == ("onnx", "checkpoint") and a.depth_hw == (60, 80)
    rng = np.random.default_rng(0)
    hist = rng.normal(size=(3, a.contract["obs_layout"]["sizes"]["history"])).astype(np.float32)
    depth = rng.uniform(0.3, 3.0, (3, 60, 80)).astype(np.float32)
    outs_a = a.step(hist, depth, a.initial_hidden(3))
    outs_b = b.step(hist, depth, b.initial_hidden(3))
    for x, y in zip(outs_a, outs_b, strict=True):
        np.testing.assert_allclose(x, y, atol=1e-4)
    assert outs_a[0].shape == (3, 6) and outs_a[2].shape == (3, 441)


def test_prior_on_policy_refuses_env_without_prior(tiny_ckpt):
    pol = load_policy(tiny_ckpt)
    env = Tron1Env(replace(pol.run_cfg.env, num_envs=1, gait=GaitConfig(enabled=False)))
    with pytest.raises(Tron1Error, match="trained with the gait prior"):
        pc.check_matches_env(pol.contract, env.layout, "policy")
    env.close()


def test_bad_policy_files(tmp_path):
    with pytest.raises(Tron1Error, match="not found"):
        load_policy(tmp_path / "nope.onnx")
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"\x00garbage" * 10)
    with pytest.raises(Tron1Error):
        load_policy(junk)
    foreign = write_foreign_onnx(tmp_path / "foreign.onnx")  # a valid ONNX model that is not ours
    with pytest.raises(Tron1Error, match="not a tron1 policy"):
        load_policy(foreign)
    bad_ckpt = tmp_path / "bad.pt"
    bad_ckpt.write_bytes(b"not a zip")
    with pytest.raises(Tron1Error, match="cannot read checkpoint"):
        load_policy(bad_ckpt)
