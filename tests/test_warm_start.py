"""``tron1 train --init``: a blind run's weights in a perceptive model compute what they did."""

from __future__ import annotations

import json

import torch
from conftest import tron1
from test_learn_cts import make
from test_train_cli import SMALL

from tron1cli.learn import ObsDims
from tron1cli.learn.models import VisionCTS
from tron1cli.learn.warm_start import warm_start

torch.set_num_threads(1)
GROUPS = ("stable", "loco")
BLIND = ObsDims(5, 15, 7)
PERCEPTIVE = ObsDims(5, 15, 7, heightmap=441, depth_hw=(12, 16))
CFG = make(BLIND).cfg  # the small networks of the learner tests


def test_perceptive_model_from_blind_weights_acts_and_values_as_the_blind_one():
    torch.manual_seed(0)
    blind = VisionCTS(BLIND, GROUPS, CFG)
    with torch.no_grad():  # non-trivial normaliser statistics, as a trained run has
        blind.norm_privileged.update(torch.randn(64, 7) * 3 + 1)
    torch.manual_seed(1)
    model = VisionCTS(PERCEPTIVE, GROUPS, CFG)
    fresh_h = model.teacher_h[0].weight.clone()
    report = warm_start(model, blind.state_dict())
    assert "actor.0.weight" in report.widened and "critics.stable.lat_in.weight" in report.widened
    assert "critics.loco.obs_in.weight" in report.widened and "teacher_e.0.weight" in report.copied
    assert any(n.startswith("teacher_h.") for n in report.fresh)
    assert torch.equal(model.teacher_h[0].weight, fresh_h)  # new modules keep their initialisation
    torch.testing.assert_close(model.norm_privileged.mean, blind.norm_privileged.mean)

    o, e = torch.randn(10, 5), torch.randn(10, 7)
    le = model.teacher_latents(e, None)[0]
    lh = torch.nn.functional.normalize(torch.randn(10, 6), dim=-1)  # any heightmap latent
    h = torch.randn(10, 441)  # any heightmap
    with torch.no_grad():
        torch.testing.assert_close(model.action_mean(o, le, lh), blind.action_mean(o, le, le[:, :0]))
        torch.testing.assert_close(model.values(e, h, le, lh), blind.values(e, None, le, le[:, :0]))
        torch.testing.assert_close(model.teacher_latents(e, h)[0], blind.teacher_latents(e, None)[0])


def test_train_init_from_a_blind_run_is_recorded_and_refused_with_resume(tmp_path):
    blind = tmp_path / "blind"
    assert tron1("train", *SMALL, "--iterations", "1", "--run-dir", str(blind)).returncode == 0
    ckpt = blind / "checkpoints" / "latest.pt"
    run = tmp_path / "stairs"
    r = tron1(
        "train",
        *SMALL,
        "--terrain",
        "stairs",
        "--iterations",
        "1",
        "--init",
        str(ckpt),
        "--run-dir",
        str(run),
    )
    assert r.returncode == 0, r.stderr
    header = "".join(r.stderr.split())  # rich wraps the header to the terminal's width
    assert f"startedfrom{ckpt}(iteration1)" in header and "5widened" in header
    assert json.loads((run / "config.json").read_text())["init_from"] == f"{ckpt} (iteration 1)"
    r = tron1("train", "--resume", "--init", str(ckpt), "--run-dir", str(run))
    assert r.returncode == 2 and "--init starts a new run" in r.stderr and "Traceback" not in r.stderr
    r = tron1("train", *SMALL, "--init", str(tmp_path / "nothing.pt"), "--run-dir", str(tmp_path / "x"))
    assert r.returncode == 1 and "checkpoint not found" in r.stderr and "Traceback" not in r.stderr
