"""``tron1 eval`` and ``tron1 push-test``: protocol pieces, determinism, JSON contract, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import tron1

from tron1cli.cli.evaluate import parse_groups
from tron1cli.evaluation.protocol import EvalSpec, aggregate, resolve_eval_terrains, run_batch
from tron1cli.evaluation.pushes import PUSH_TYPES, PushProtocol, push_wrenches
from tron1cli.policy.runtime import load_policy


def test_parse_groups(tmp_path):
    g = parse_groups(["ours=a.pt,b.pt", "runs/x/checkpoints/latest.pt", "c.onnx"])
    assert list(g) == ["ours", "x", "c"] and [p.name for p in g["ours"]] == ["a.pt", "b.pt"]
    with pytest.raises(ValueError, match="given twice"):
        parse_groups(["a.pt", "a.onnx"])
    with pytest.raises(ValueError, match="no policy path"):
        parse_groups(["ours="])


def test_terrain_names():
    assert resolve_eval_terrains("all") == ("stairs", "slopes", "discrete", "rough", "flat")
    assert resolve_eval_terrains("slope") == ("slopes",)
    with pytest.raises(ValueError, match="unknown terrain 'lava'"):
        resolve_eval_terrains("lava")


def test_aggregate_mean_std_skips_missing():
    a = aggregate([0.5, 1.0, None])
    assert a == {"mean": 0.75, "std": 0.25, "n": 2}
    assert aggregate([None])["mean"] is None


def test_push_wrenches_hand_computed():
    types = np.arange(len(PUSH_TYPES))
    w = push_wrenches(types, PushProtocol.moderate(), np.random.default_rng(0))
    idx = {name: i for i, name in enumerate(PUSH_TYPES)}
    assert (w[idx["none"]] == 0).all()
    np.testing.assert_array_equal(w[idx["+Fx"]], [50, 0, 0, 0, 0, 0])
    np.testing.assert_array_equal(w[idx["-Fy"]], [0, -50, 0, 0, 0, 0])
    np.testing.assert_array_equal(w[idx["-Tz"]], [0, 0, 0, 0, 0, -5])
    mixed = w[idx["mixed"]]
    assert (np.abs(mixed[:3]) <= 50).all() and (np.abs(mixed[3:]) <= 5).all() and np.abs(mixed).sum() > 0
    assert PushProtocol.extreme().force_n == 400 and PushProtocol.extreme().terrain == "flat"
    assert PushProtocol.moderate().steps(0.02) == 260


def test_same_seed_same_metrics_and_checkpoint_equals_onnx(tiny_ckpt, tmp_path):
    from tron1cli.policy.export import export_onnx

    spec = EvalSpec("flat", -1, num_envs=6, steps=40, seed=3)
    pol = load_policy(tiny_ckpt)
    a, b = run_batch(pol, spec), run_batch(pol, spec)
    assert a.metrics == b.metrics and 0.0 <= a.metrics["success_rate"] <= 1.0
    assert a.metrics["reconstruction_error_cm"] is None  # blind policy
    onnx_pol = load_policy(export_onnx(tiny_ckpt, tmp_path / "p.onnx", parity_steps=20).path)
    c = run_batch(onnx_pol, spec)
    assert c.metrics["success_rate"] == a.metrics["success_rate"]
    np.testing.assert_allclose(
        c.metrics["velocity_tracking_error"], a.metrics["velocity_tracking_error"], rtol=1e-3
    )


def test_reconstruction_error_for_a_vision_policy_on_stairs(tiny_ckpt_vision):
    res = run_batch(load_policy(tiny_ckpt_vision), EvalSpec("stairs", 5, num_envs=4, steps=20))
    assert res.metrics["reconstruction_error_cm"] is not None and res.metrics["reconstruction_error_cm"] > 0


def test_eval_cli_json_and_outputs(tiny_ckpt, tmp_path):
    r = tron1(
        "eval",
        f"ours={tiny_ckpt},{tiny_ckpt}",
        "--terrain",
        "flat",
        "--envs",
        "4",
        "--steps",
        "20",
        "--speeds",
        "0.5,1.0",
        "--json",
        "--out",
        str(tmp_path / "ev"),
    )
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout)
    m = rep["results"]["ours"]["flat"]
    for key in (
        "success_rate",
        "orientation_error",
        "angular_velocity_error",
        "velocity_tracking_error",
        "reconstruction_error_cm",
    ):
        assert set(m[key]) == {"mean", "std", "n"}
    assert m["success_rate"]["n"] == 2 and m["success_rate"]["std"] == 0.0  # same policy twice
    assert set(rep["success_by_speed"]["ours"]["flat"]) == {"0.5", "1.0"}
    for f in ("results.json", "results.csv", "success_by_speed.csv", "success_by_speed_flat.png"):
        assert (tmp_path / "ev" / f).stat().st_size > 0


def test_push_test_cli_json(tiny_ckpt, tmp_path):
    r = tron1(
        "push-test", str(tiny_ckpt), "--terrain", "flat", "--envs", "14", "--json", "--out", str(tmp_path)
    )
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout)
    assert 0.0 <= rep["survival_rate"] <= 1.0 and list(rep["per_push"]) == list(PUSH_TYPES)
    assert (tmp_path / "push_survival.png").stat().st_size > 0


@pytest.mark.parametrize(
    "args, code, text",
    [
        (["eval", "missing.pt"], 1, "policy not found"),
        (["eval", "{ckpt}", "--terrain", "lava"], 2, "unknown terrain"),
        (["eval", "{ckpt}", "--metrics", "speed"], 2, "unknown metric"),
        (["eval", "{ckpt}", "--speeds", "fast"], 2, "--speeds wants numbers"),
        (["push-test", "{ckpt}", "--envs", "3"], 2, "greater than or equal to 14"),
    ],
)
def test_bad_input_one_line(tiny_ckpt, args, code, text):
    r = tron1(*(a.format(ckpt=tiny_ckpt) for a in args))
    assert r.returncode == code and text in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr


def test_eval_streams_reconstruction_to_rerun(tiny_ckpt_vision, tmp_path):
    from tron1cli.viz.rerun_stream import read_rrd

    rrd = tmp_path / "eval.rrd"
    r = tron1(
        "eval",
        str(tiny_ckpt_vision),
        "--terrain",
        "stairs",
        "--level",
        "3",
        "--envs",
        "2",
        "--steps",
        "12",
        "--rerun",
        f"save={rrd}",
        "--json",
    )
    assert r.returncode == 0, r.stderr
    data = read_rrd(rrd)
    for path in (
        "world/lipm/com",
        "world/lipm/desired_com",
        "world/lipm/zmp",
        "world/camera/depth",
        "world/heightmap/true",
        "world/heightmap/reconstructed",
    ):
        assert path in data, path


def test_frame_errors_hand_computed():
    from tron1cli.evaluation.protocol import frame_errors

    th = 0.3
    g = np.array([[0.0, 0.0, -1.0], [np.sin(th), 0.0, -np.cos(th)]])
    w = np.array([[0.2, -0.4, 5.0], [0.0, 0.0, 0.0]])
    o, a, v = frame_errors(g, w, np.array([[1.0, 0.0], [0.0, 0.0]]), np.array([[0.4, 0.8], [0.3, -0.4]]))
    np.testing.assert_allclose(o, [0.0, 2 * np.sin(th / 2)])
    np.testing.assert_allclose(a, [0.3, 0.0])
    np.testing.assert_allclose(v, [1.0, 0.5])


def test_heading_frame_push_rotates_with_the_robot():
    from tron1cli.evaluation.pushes import heading_to_world

    w = heading_to_world(np.array([[50.0, 0, 10, 5, 0, 1]]), np.array([np.pi / 2]))
    np.testing.assert_allclose(w, [[0.0, 50.0, 10.0, 0.0, 5.0, 1.0]], atol=1e-12)
