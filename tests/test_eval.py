"""``tron1 eval`` and ``tron1 push-test``: protocol pieces, the full window, speed sweeps per
velocity dimension, determinism, JSON contract, bad input."""

from __future__ import annotations

import csv
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import tron1

from tron1cli.cli.evaluate import parse_groups, parse_speeds
from tron1cli.config.env import CommandConfig
from tron1cli.env.core import EDGE_MARGIN_M, Tron1Env
from tron1cli.env.math3d import rotate_z
from tron1cli.env.terrain import TerrainConfig
from tron1cli.errors import Tron1Error
from tron1cli.evaluation.protocol import (
    EvalSpec,
    aggregate,
    check_speed,
    eval_terrain_config,
    make_env,
    resolve_eval_terrains,
    run_batch,
    top_speed,
)
from tron1cli.evaluation.pushes import PUSH_TYPES, PushProtocol, push_wrenches
from tron1cli.policy.runtime import load_policy
from tron1cli.train.layout import policy_label


def test_a_policy_without_a_label_is_named_after_its_run_or_its_file(tmp_path, monkeypatch):
    assert policy_label(Path("runs/x/checkpoints/latest.pt")) == "x"
    assert policy_label(Path("policies/tron1_flat.onnx")) == "tron1_flat"
    monkeypatch.chdir(tmp_path)
    assert policy_label(Path("latest.pt")) == "latest"  # not in a run: the stem, never ""
    (tmp_path / "run7" / "checkpoints").mkdir(parents=True)
    monkeypatch.chdir(tmp_path / "run7")
    assert policy_label(Path("checkpoints/latest.pt")) == "run7"


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


def test_after_step_sees_every_walking_step(tiny_ckpt):
    walked = []

    def after_step(env: Tron1Env, res, walking: np.ndarray) -> None:
        walked.append(walking & ~res.done)

    res = run_batch(
        load_policy(tiny_ckpt), EvalSpec("stairs", 9, num_envs=4, steps=60), after_step=after_step
    )
    assert len(walked) == 60
    np.testing.assert_allclose(np.sum(walked, axis=0) * 0.02, res.exposure_s)


def test_reconstruction_error_for_a_vision_policy_on_stairs(tiny_ckpt_vision):
    res = run_batch(load_policy(tiny_ckpt_vision), EvalSpec("stairs", 5, num_envs=4, steps=20))
    assert res.metrics["reconstruction_error_cm"] is not None and res.metrics["reconstruction_error_cm"] > 0


def test_teacher_acts_on_privileged_observations_without_a_camera(tiny_ckpt_vision):
    import torch

    from tron1cli.learn import LearnerConfig, ObsDims, VisionCTS
    from tron1cli.train.checkpoint import load_checkpoint

    teacher = load_policy(tiny_ckpt_vision, "teacher")
    assert teacher.actor == "teacher" and load_policy(tiny_ckpt_vision).actor == "student"
    spec = EvalSpec("stairs", 3, num_envs=4, steps=15)
    env = make_env(teacher, spec)
    try:
        assert env.cfg.depth_from == env.n  # no student: no depth render
        obs = env.reset()
        hidden = teacher.initial_hidden(env.n)
        action, hidden_next, h_hat = teacher.act(obs, hidden)
    finally:
        env.close()
    # the same action by hand from the checkpoint's model: normalise, teacher latents, actor
    sd = load_checkpoint(tiny_ckpt_vision)["learner"]
    model = VisionCTS(
        ObsDims.from_dict(sd["dims"]), tuple(sd["groups"]), LearnerConfig.from_dict(sd["config"])
    )
    model.load_state_dict(sd["model"])
    with torch.no_grad():
        raw = {
            k: torch.from_numpy(np.asarray(obs[k], dtype=np.float32))
            for k in ("proprio", "history", "privileged", "heightmap")
        }
        ob = model.normalize(raw)
        le, lh = model.teacher_latents(ob["privileged"], ob["heightmap"])
        expected = model.action_mean(ob["proprio"], le, lh).numpy()
    np.testing.assert_allclose(action, expected, rtol=1e-6, atol=1e-6)
    assert h_hat.shape == (env.n, 0) and (hidden_next == hidden).all()
    res = run_batch(teacher, spec)
    assert res.metrics["reconstruction_error_cm"] is None and 0.0 <= res.metrics["success_rate"] <= 1.0
    with pytest.raises(Tron1Error, match="loaded as its teacher"):
        teacher.step(obs["history"], obs["depth"], hidden)


def test_teacher_needs_a_checkpoint(tiny_ckpt, tmp_path):
    from tron1cli.policy.export import export_onnx

    onnx = export_onnx(tiny_ckpt, tmp_path / "p.onnx", parity_steps=5).path
    with pytest.raises(Tron1Error, match="holds the student only"):
        load_policy(onnx, "teacher")
    with pytest.raises(ValueError, match="unknown actor"):
        load_policy(tiny_ckpt, "coach")
    r = tron1("eval", str(onnx), "--actor", "teacher", "--terrain", "flat", "--envs", "2", "--steps", "3")
    assert r.returncode != 0 and "student only" in r.stderr and "Traceback" not in r.stderr
    r = tron1("eval", str(tiny_ckpt), "--actor", "coach", "--terrain", "flat")
    assert r.returncode == 2 and "unknown --actor 'coach'" in r.stderr
    r = tron1(
        "eval",
        str(tiny_ckpt),
        "--actor",
        "teacher",
        "--terrain",
        "flat",
        "--envs",
        "2",
        "--steps",
        "5",
        "--json",
    )
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["protocol"]["actor"] == "teacher"


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
        "--speeds",
        "yaw:0.25",
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
        "exposure_s",
        "command_progress",
        "pitch_deg",
        "traverse_rate",
    ):
        assert set(m[key]) == {"mean", "std", "n"}
    assert m["success_rate"]["n"] == 2 and m["success_rate"]["std"] == 0.0  # same policy twice
    assert m["traverse_rate"]["mean"] <= m["success_rate"]["mean"]  # a traverse is a success
    # survivors are exposed the whole window (20 x 0.02 s), fallers less
    window = rep["protocol"]["window_s"]
    assert window == pytest.approx(0.4)
    assert m["success_rate"]["mean"] * window <= m["exposure_s"]["mean"] + 1e-9 <= window + 1e-9
    assert rep["coverage"]["ours"]["flat"]["left_terrain"] == 0
    sweeps = rep["success_by_speed"]
    assert list(sweeps) == ["vx", "yaw"] and sweeps["yaw"]["unit"] == "rad/s"
    assert set(sweeps["vx"]["results"]["ours"]["flat"]) == {"0.5", "1.0"}
    assert set(sweeps["yaw"]["results"]["ours"]["flat"]) == {"0.25"}
    progress = rep["progress_by_speed"]["vx"]["results"]["ours"]["flat"]
    assert set(progress) == {"0.5", "1.0"} and all(set(a) == {"mean", "std", "n"} for a in progress.values())
    ev = tmp_path / "ev"
    for f in ("results.json", "results.csv", "success_by_speed_vx.png", "success_by_speed_yaw.png"):
        assert (ev / f).stat().st_size > 0
    rows = list(csv.reader(open(ev / "success_by_speed_vx.csv")))
    assert rows[0][2] == "vx_mps" and [row[2] for row in rows[1:]] == ["0.5", "1.0"]
    assert rows[0][5:] == ["progress_mean", "progress_std"]
    assert [float(row[5]) for row in rows[1:]] == [progress["0.5"]["mean"], progress["1.0"]["mean"]]
    rows = list(csv.reader(open(ev / "success_by_speed_yaw.csv")))
    assert rows[0][2] == "yaw_radps" and [row[2] for row in rows[1:]] == ["0.25"]


def test_randomisation_reports_the_terms_applied(tiny_ckpt):
    """--randomize applies each policy's own training terms: a policy trained with none meets the
    nominal robot, and the caption and the JSON say so instead of 'on'."""
    from types import SimpleNamespace

    from tron1cli.cli.evaluate import _randomisation

    nominal = tron1("eval", str(tiny_ckpt), "--terrain", "flat", "--envs", "2", "--steps", "3")
    assert nominal.returncode == 0, nominal.stderr
    assert "randomisation on, but the policy trained with none: nominal robot" in " ".join(
        nominal.stdout.split()
    )
    r = tron1("eval", str(tiny_ckpt), "--terrain", "flat", "--envs", "2", "--steps", "3", "--json")
    assert json.loads(r.stdout)["protocol"]["randomization_terms"] == []

    def trained_with(*terms):
        return SimpleNamespace(
            run_cfg=SimpleNamespace(env=SimpleNamespace(randomization=SimpleNamespace(terms=terms)))
        )

    assert _randomisation(True, [trained_with("kp", "delay"), trained_with("delay")]) == (
        "on",
        ["delay", "kp"],
    )
    assert _randomisation(False, [trained_with("kp")]) == ("off", None)
    assert _randomisation(True, [trained_with()])[1] == []


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
        (["eval", "{ckpt}", "--speeds", "fast"], 2, "--speeds vx wants numbers"),
        (["eval", "{ckpt}", "--speeds", "vz:0.5"], 2, "unknown speed dimension 'vz'"),
        (["eval", "{ckpt}", "--speeds", "vx:nan"], 2, "not a finite number"),
        (["eval", "{ckpt}", "--speeds", "0.5", "--speeds", "yaw:inf"], 2, "not a finite number"),
        (
            ["eval", "{ckpt}", "--speeds", "vy:0.8"],
            2,
            "outside the policy's training command range [-0.5, 0.5]",
        ),
        (["eval", "{ckpt}", "--speeds", "1.25"], 2, "outside the policy's training command range [-1, 1]"),
        (["push-test", "{ckpt}", "--envs", "3"], 2, "greater than or equal to 14"),
        (["eval", "{ckpt}", "--gait-freq", "1"], 2, "--gait-freq: gait frequency 1 Hz lies outside"),
        (["eval", "{ckpt}", "--layouts", "0"], 2, "greater than or equal to 1"),
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


def test_command_progress_hand_computed():
    from tron1cli.evaluation.protocol import command_progress_terms

    cmd = np.array([[1.0, 0.0], [0.0, 0.5], [0.01, 0.0]])  # the last one is a standing command
    v = np.array([[0.5, 0.5], [0.0, -0.5], [3.0, 3.0]])
    along, asked = command_progress_terms(cmd, v)
    np.testing.assert_allclose(along, [0.5, -0.5, 0.0])
    np.testing.assert_allclose(asked, [1.0, 0.5, 0.0])


def test_pitch_is_signed_nose_down_positive():
    from tron1cli.evaluation.protocol import pitch_deg

    a = math.radians(11.0)
    g = np.array([[-math.sin(a), 0.0, -math.cos(a)], [math.sin(a), 0.0, -math.cos(a)], [0.0, 0.3, -0.95]])
    np.testing.assert_allclose(pitch_deg(g), [-11.0, 11.0, 0.0], atol=1e-9)


def test_traverse_is_a_success_that_walked_half_its_commanded_distance():
    from tron1cli.evaluation.protocol import traversed

    success = np.array([True, True, True, False, True, True])
    along = np.array([5.0, 2.4, 2.5, 5.0, 0.0, -1.0])  # m walked along the command
    asked = np.array([5.0, 5.0, 5.0, 5.0, 0.4, 5.0])  # m commanded; env 4 was asked to stand
    np.testing.assert_array_equal(traversed(success, along, asked), [True, False, True, False, True, False])


def test_heading_frame_push_rotates_with_the_robot():
    from tron1cli.evaluation.pushes import heading_to_world

    w = heading_to_world(np.array([[50.0, 0, 10, 5, 0, 1]]), np.array([np.pi / 2]))
    np.testing.assert_allclose(w, [[0.0, 50.0, 10.0, 0.0, 5.0, 1.0]], atol=1e-12)


def test_parse_speeds_per_dimension():
    plan = parse_speeds(["0.25,0.5", "yaw:0.5,1", "vy:0.25", "vx:0.75,0.5", "VY:-0.25"])
    assert plan == {"vx": [0.25, 0.5, 0.75], "vy": [0.25, -0.25], "yaw": [0.5, 1.0]}
    assert list(plan) == ["vx", "vy", "yaw"]  # one order, whatever the order of the options
    assert parse_speeds([]) == {}


def test_sweep_command_per_dimension_and_range_check(tiny_ckpt):
    trained = CommandConfig()  # v_x -1..1, v_y -0.5..0.5, yaw -0.5..0.5
    c = EvalSpec(speed=0.3, speed_dim="yaw").commands(trained)
    assert (c.lin_vel_x, c.lin_vel_y, c.ang_vel_yaw) == ((0.0, 0.0), (0.0, 0.0), (0.3, 0.3))
    assert c.standing_share == 0.0 and top_speed(c) == 0.0
    c = EvalSpec(speed=-0.5, speed_dim="vy").commands(trained)  # the range's end is inside
    assert c.lin_vel_y == (-0.5, -0.5) and top_speed(c) == 0.5
    assert EvalSpec().commands(trained) is trained
    with pytest.raises(ValueError, match=r"vy:0.51 m/s is outside .* \[-0.5, 0.5\] m/s"):
        check_speed(trained, "vy", 0.51)
    with pytest.raises(ValueError, match="unknown speed dimension"):
        EvalSpec(speed=0.3, speed_dim="vz")
    with pytest.raises(ValueError, match="not a finite number"):
        EvalSpec(speed=float("nan"))
    # every env of the batch holds the sweep command for the whole window
    env = make_env(load_policy(tiny_ckpt), EvalSpec("flat", num_envs=3, steps=5, speed=0.4, speed_dim="vy"))
    try:
        env.reset()
        for _ in range(5):
            env.step(np.zeros((3, 6)))
        np.testing.assert_array_equal(env.commands.value, [[0.0, 0.4, 0.0]] * 3)
    finally:
        env.close()


def test_a_fixed_gait_frequency_holds_for_every_env(tiny_ckpt):
    """--gait-freq: every env's clock runs at the asked frequency; without it, drawn per command."""
    pol = load_policy(tiny_ckpt)
    for asked in (2.5, None):
        env = make_env(pol, EvalSpec("flat", num_envs=16, steps=5, gait_freq_hz=asked))
        try:
            env.reset()
            freq = env.commands.gait_freq.copy()
        finally:
            env.close()
        if asked is None:
            assert freq.min() >= 1.5 and freq.max() <= 2.5 and freq.std() > 0.1
        else:
            np.testing.assert_array_equal(freq, 2.5)


def test_eval_tile_hand_computed():
    cfg = TerrainConfig()  # 8 m tile, 5 cm samples, 0.25 m rim, 40 blocks
    v = top_speed(CommandConfig())  # hypot(1.0, 0.5) = 1.118 m/s
    assert v == pytest.approx(1.1180340, abs=1e-6)
    big = eval_terrain_config(cfg, 10.0, v)
    # reach 10 s x (1.118 + 0.5) = 16.180 m; half side >= 16.180 + 0.5 + 0.25 + 0.05 = 16.980 m;
    # 2 x 16.980 / 0.05 = 679.2 -> 680 samples = 34.0 m
    assert big.tile_size_m == pytest.approx(34.0) and big.R == 680
    assert big.num_blocks == 798  # 40 x (33.5 / 7.5)^2 = 798.0: the same block density
    edge = big.half_extent_m - EDGE_MARGIN_M
    assert edge >= 16.180 and big.half_extent_m - big.border_m > edge  # the edge lies on the terrain
    assert (big.step_height_m, big.step_tread_m, big.slope_tan) == (
        cfg.step_height_m,
        cfg.step_tread_m,
        cfg.slope_tan,
    )
    assert eval_terrain_config(cfg, 2.0, 0.5) is cfg  # 2 s x 1 m/s fits the training tile


def carry_along_x(speed: float, clearance: float = 1.3, turn_at: int | None = None):
    """A ``before_step`` that carries every robot upright along world +x at ``speed`` (m/s),
    ``clearance`` above the ground under it: a perfect walker, to test the window's bookkeeping.
    From step ``turn_at`` on it faces and walks along +y instead (a walker that leaves its path)."""

    def before_step(env: Tron1Env, t: int) -> None:
        ids = np.arange(env.n)
        ph = env.physics
        qpos, qvel, time = ph.qpos.copy(), np.zeros((env.n, ph.nv)), ph.time.copy()
        qpos[:, 0], qpos[:, 1] = speed * t * env.policy_dt, 0.0
        qpos[:, 3:7] = [1.0, 0.0, 0.0, 0.0]
        qvel[:, 0] = speed
        if turn_at is not None and t >= turn_at:
            qpos[:, 0], qpos[:, 1] = speed * turn_at * env.policy_dt, speed * (t - turn_at) * env.policy_dt
            qpos[:, 3:7] = [np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)]  # yaw +90 deg
            qvel[:, 0], qvel[:, 1] = 0.0, speed
        qpos[:, 2] = env.ground_height(qpos[:, :2]) + clearance
        ph.set_state(ids, qpos, qvel)
        ph.state[:, 0] = time  # keep the sim clock (a reset clock reads as a diverged world)

    return before_step


def with_command_range(policy, lin_vel_x: tuple[float, float]):
    """The policy as if trained with forward commands over ``lin_vel_x`` (m/s), every robot
    spawned facing +x (so that the carried walkers walk the commanded path)."""
    env = policy.run_cfg.env
    policy.run_cfg = replace(
        policy.run_cfg,
        env=replace(
            env,
            commands=replace(env.commands, lin_vel_x=lin_vel_x),
            init=replace(env.init, random_yaw=False),
        ),
    )
    return policy


def test_full_window_at_1p25_mps_on_flat(tiny_ckpt):
    pol = with_command_range(load_policy(tiny_ckpt), (-1.5, 1.5))
    spec = EvalSpec("flat", num_envs=2, steps=500, speed=1.25, randomize=False)
    res = run_batch(pol, spec, before_step=carry_along_x(1.25))
    # 12.5 m in 10 s: far past the 8 m training tile's edge (3.475 m, reached at 2.8 s)
    assert res.max_reach_m == pytest.approx(1.25 * 500 * 0.02, abs=0.02)
    assert res.edge_m > res.max_reach_m > 3.475
    np.testing.assert_array_equal(res.exposure_s, [10.0, 10.0])
    assert res.metrics["exposure_s"] == pytest.approx(10.0) and res.metrics["success_rate"] == 1.0
    assert not res.left.any() and not res.fell.any()
    assert res.metrics["command_progress"] == pytest.approx(1.0, abs=0.01)  # all it was asked
    assert res.metrics["traverse_rate"] == 1.0
    assert res.metrics["pitch_deg"] == pytest.approx(0.0, abs=0.5)  # carried upright


def test_command_progress_counts_only_the_commanded_path(tiny_ckpt):
    """Commanded straight ahead, a walker that turns 90 degrees after half the window and walks on
    as fast along its new heading walked half its path: progress 0.5 (the base frame, where the
    command turns with the robot, would count all of it)."""
    pol = with_command_range(load_policy(tiny_ckpt), (-1.5, 1.5))
    spec = EvalSpec("flat", num_envs=2, steps=500, speed=0.5, randomize=False)
    res = run_batch(pol, spec, before_step=carry_along_x(0.5, turn_at=250))
    assert res.metrics["success_rate"] == 1.0
    assert res.metrics["command_progress"] == pytest.approx(0.5, abs=0.01)


def test_command_progress_in_heading_mode_runs_along_the_heading(tiny_ckpt):
    """With heading-mode training commands, the path of a moving command is the world heading the
    robot is steered to: a walker carried along +x is credited its world velocity along it."""
    pol = with_command_range(load_policy(tiny_ckpt), (0.2, 1.0))
    env_cfg = pol.run_cfg.env
    heading = replace(env_cfg.commands, heading=True, standing_share=0.0)
    pol.run_cfg = replace(pol.run_cfg, env=replace(env_cfg, commands=heading))
    carry = carry_along_x(0.5)
    sums = {"along": 0.0, "asked": 0.0}
    path = {}

    def before_step(env: Tron1Env, t: int) -> None:
        carry(env, t)
        c = env.commands
        assert c.steering.all()
        path["speed"] = np.linalg.norm(c.value[:, :2], axis=1)
        path["dir"] = rotate_z(c.value[:, :2] / path["speed"][:, None], c.heading)

    def after_step(env: Tron1Env, res, walking: np.ndarray) -> None:
        ok = walking & ~res.done
        v = env.state.base_lin_vel_w[ok, :2]
        sums["along"] += float(np.einsum("ij,ij->i", v, path["dir"][ok]).sum())
        sums["asked"] += float(path["speed"][ok].sum())

    spec = EvalSpec("flat", num_envs=4, steps=60, randomize=False)
    res = run_batch(pol, spec, before_step=before_step, after_step=after_step)
    assert not res.fell.any()
    assert res.metrics["command_progress"] == pytest.approx(sums["along"] / sums["asked"], abs=1e-9)


def test_eval_envs_stand_on_many_layouts_of_the_level_under_test(tiny_ckpt):
    env = make_env(load_policy(tiny_ckpt), EvalSpec("discrete", -1, num_envs=8, steps=1, layouts=4))
    assert env.bank.cfg.variants_per_level == 4
    tiles = env.curriculum.tile
    assert set(env.bank.level[tiles]) == {9} and len(set(tiles)) > 2
    layouts = {k: env.bank.heights[k] for k in set(tiles)}
    assert all(  # every layout its own blocks
        not np.array_equal(layouts[a], layouts[b]) for a in layouts for b in layouts if a < b
    )
    with pytest.raises(ValueError, match="layouts must be >= 1"):
        EvalSpec("discrete", layouts=0)


def test_env_past_the_training_tile_is_still_on_the_stairs_level(tiny_ckpt):
    seen = {}
    carry = carry_along_x(1.0)

    def before_step(env: Tron1Env, t: int) -> None:
        carry(env, t)
        if t == 405:  # 8.1 m out: the training tile ended at 3.975 m
            tile = env.curriculum.tile
            seen["types"] = [env.bank.types[k] for k in env.bank.kind[tile]]
            seen["levels"] = env.bank.level[tile].tolist()
            seen["ground"] = env.ground_height(np.array([[8.1, 0.0]] * env.n))

    res = run_batch(
        load_policy(tiny_ckpt), EvalSpec("stairs", -1, num_envs=2, steps=500), before_step=before_step
    )
    assert seen["types"] == ["stairs_up", "stairs_down"] and seen["levels"] == [9, 9]
    # level 9 steps are 0.20 m high, 0.30 m deep from the platform edge at 0.5 m:
    # ring floor((8.1 - 0.5) / 0.3) + 1 = 26, so 5.2 m up (or down)
    np.testing.assert_allclose(seen["ground"], [5.2, -5.2], atol=1e-5)
    np.testing.assert_array_equal(res.exposure_s, [10.0, 10.0])
    assert res.metrics["success_rate"] == 1.0 and res.max_reach_m > 9.9


def test_shipped_policy_walks_the_whole_window_beyond_the_old_tile():
    onnx = Path(__file__).resolve().parents[1] / "policies" / "tron1_flat.onnx"
    r = tron1("eval", str(onnx), "--terrain", "flat", "--envs", "8", "--no-randomize", "--json")
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout)
    assert rep["protocol"]["window_s"] == pytest.approx(10.0)
    assert rep["results"]["tron1_flat"]["flat"]["exposure_s"]["mean"] == pytest.approx(10.0)
    cov = rep["coverage"]["tron1_flat"]["flat"]
    assert cov["left_terrain"] == 0 and cov["max_reach_m"] > 8.0 / 2 - EDGE_MARGIN_M
