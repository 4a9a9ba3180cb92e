"""``tron1 deploy-sim``: the ONNX policy in MuJoCo with its depth camera in its own thread."""

from __future__ import annotations

import json
import sys
import threading
from dataclasses import replace

import numpy as np
import onnx
import pytest
import typer
from conftest import write_foreign_onnx

import tron1cli.cli.main as cli_main
from tron1cli.cli.deploy_sim import deploy_sim
from tron1cli.deploy.pipeline import DeployConfig, DeploySim
from tron1cli.deploy.schedule import CommandSchedule, parse_cmd
from tron1cli.env.terminations import FALL_CAUSES
from tron1cli.policy.export import export_onnx
from tron1cli.policy.runtime import load_policy

REPORT_KEYS = (
    "survived",
    "duration_s",
    "vel_tracking_error",
    "policy_ms_p50",
    "policy_ms_p99",
    "realtime_factor",
    "com_error_m",
    "depth_age_ms_p50",
    "depth_age_ms_p99",
    "depth_render_ms_p50",
    "unstable",
)


@pytest.fixture(scope="module")
def vision_onnx(tiny_ckpt_vision, tmp_path_factory):
    return export_onnx(tiny_ckpt_vision, tmp_path_factory.mktemp("deploy") / "v.onnx", parity_steps=20).path


def run_cli(monkeypatch, capsys, *args: str) -> tuple[int, str, str]:
    """Run ``tron1 deploy-sim ARGS`` through the real entry point's error handling."""
    app = typer.Typer(add_completion=False, pretty_exceptions_enable=False)
    app.callback()(lambda: None)
    app.command("deploy-sim")(deploy_sim)
    monkeypatch.setattr(cli_main, "app", app)
    monkeypatch.setattr(sys, "argv", ["tron1", "deploy-sim", *args])
    with pytest.raises(SystemExit) as e:
        cli_main.main()
    cap = capsys.readouterr()
    return e.value.code, cap.out, cap.err


@pytest.fixture
def no_falls(monkeypatch):
    """The untrained policy falls within a second: let the run go on with the robot on the ground,
    so that the pipeline's timing can be watched over seconds."""
    orig = DeploySim._env_config

    def patched(self):
        c = orig(self)
        return replace(
            c, termination=replace(c.termination, max_roll=9.0, max_pitch=9.0, contact_bodies=False)
        )

    monkeypatch.setattr(DeploySim, "_env_config", patched)


def test_json_report(vision_onnx, monkeypatch, capsys):
    code, out, err = run_cli(
        monkeypatch, capsys, str(vision_onnx), "--terrain", "stairs", "--duration", "2", "--json"
    )
    assert code == 0, err
    rep = json.loads(out)  # exactly one JSON object on stdout
    for k in REPORT_KEYS:
        assert k in rep, k
    assert isinstance(rep["survived"], bool) and rep["unstable"] is False
    assert 0.0 < rep["duration_s"] <= 2.0 and rep["policy_steps"] == round(rep["duration_s"] * 50)
    assert rep["survived"] == (rep["ended"] == "duration")
    if rep["ended"] == "fell":  # what ended it, in words
        assert rep["fell_by"] and set(rep["fell_by"].split("+")) <= set(FALL_CAUSES)
    else:
        assert rep["fell_by"] is None
    assert 0.0 < rep["policy_ms_p50"] <= rep["policy_ms_p99"] and rep["realtime_factor"] > 0
    assert rep["vel_tracking_error"] >= 0 and rep["com_error_m"] >= 0
    assert (rep["physics_hz"], rep["policy_hz"], rep["depth_hz"]) == (500.0, 50.0, 30.0)  # the robot's loop
    assert rep["terrain_type"] in ("stairs_up", "stairs_down") and rep["depth_thread_separate"] is True


def test_a_fall_is_named_by_its_cause(vision_onnx, monkeypatch, capsys):
    """A tilt limit no robot can keep (1e-6 rad) ends the run at once, as a fall by tilt."""
    orig = DeploySim._env_config

    def strict(self):
        c = orig(self)
        return replace(c, termination=replace(c.termination, max_roll=1e-6, max_pitch=1e-6))

    monkeypatch.setattr(DeploySim, "_env_config", strict)
    code, out, err = run_cli(monkeypatch, capsys, str(vision_onnx), "--duration", "1", "--json")
    rep = json.loads(out)
    assert rep["ended"] == "fell" and rep["policy_steps"] == 1
    assert "tilt" in rep["fell_by"].split("+")
    code, out, err = run_cli(monkeypatch, capsys, str(vision_onnx), "--duration", "1")
    assert "NO (fell: tilt" in out


@pytest.mark.parametrize("latency_ms", [0.0, 50.0])
def test_depth_thread_runs_at_its_own_rate(vision_onnx, no_falls, latency_ms):
    pol = load_policy(vision_onnx)
    sim = DeploySim(pol, DeployConfig(terrain="stairs", duration_s=3.0, depth_latency_ms=latency_ms))
    try:
        rep = sim.run()
        caps = np.array(sim.depth.capture_times)
        ids = sim.depth.render_thread_ids
    finally:
        sim.close()
    assert rep["ended"] == "duration" and rep["duration_s"] == 3.0
    # 30 Hz of simulation time, captured at the 50 Hz step boundaries (20 or 40 ms apart)
    assert len(caps) == 90 and set(np.round(np.diff(caps), 6)) <= {0.02, 0.04}
    assert abs(rep["depth_rate_hz"] - 30.0) < 0.5
    # every capture is rendered or dropped (the last may still be rendering); how many are dropped
    # and how much render time the loop hides depend on the machine's load: reported, not asserted
    assert len(caps) - 1 <= rep["depth_frames"] + rep["depth_dropped"] <= len(caps)
    assert rep["depth_frames"] > 0 and 0.0 <= rep["depth_hidden_share"] <= 1.0
    # rendered in another thread than the control loop's
    assert ids and threading.get_ident() not in ids
    # a frame is never used at its own capture step (it is still rendering), nor before the
    # added latency has passed; its age stays bounded by the capture spacing, the latency, two of
    # the longest measured renders (its own and the one it may wait behind: render time counts
    # in simulation time, see tron1cli/deploy/depth.py) and one step
    ages = np.array(sim.frame_ages_ms[5:])
    assert ages.min() >= 20.0 * (np.floor(latency_ms / 20.0) + 1.0) - 1e-6
    assert ages.max() <= 40.0 + latency_ms + 2 * max(sim.depth.render_ms) + 40.0 + 1e-6
    assert rep["depth_age_ms_p99"] <= max(sim.frame_ages_ms) + 1e-6


def test_serialised_numba_fallback(vision_onnx, no_falls, monkeypatch):
    """Where numba's threading layer is not thread-safe (workqueue), renders and env steps take turns."""
    import tron1cli.deploy.pipeline as pipeline

    monkeypatch.setattr(pipeline, "_numba_thread_safe", lambda: False)
    sim = DeploySim(load_policy(vision_onnx), DeployConfig(terrain="rough", duration_s=1.0))
    try:
        rep = sim.run()
    finally:
        sim.close()
    assert sim.numba_lock is not None and rep["ended"] == "duration" and rep["depth_frames"] >= 28


def test_gait_clock_and_command_schedule(tiny_ckpt, tmp_path, no_falls):
    """A blind checkpoint (.pt): the env advances the gait clock at 50 Hz; commands follow the file."""
    f = tmp_path / "cmds.csv"
    f.write_text("t_s,vx,vy,yaw\n# walk, then turn\n0,0.3,0,0\n0.5,0.6,0.1,0.4\n")
    sched = CommandSchedule.from_file(f)
    pol = load_policy(tiny_ckpt)
    sim = DeploySim(pol, DeployConfig(schedule=sched, duration_s=1.0))
    seen = []
    try:
        rep = sim.run(lambda k, total: seen.append((k, sim.env.commands.value[0].copy())))
        freq, phase = sim.env.commands.gait_freq[0], sim.env.commands.gait_phase[0]
    finally:
        sim.close()
    assert sim.depth is None and rep["depth_frames"] is None and rep["policy_kind"] == "checkpoint"
    steps = rep["policy_steps"]
    assert steps == 50 and freq == rep["gait_freq_hz"] == 2.0
    expected = (steps * 0.02 * freq) % 1.0
    assert min(abs(phase - expected), 1.0 - abs(phase - expected)) < 1e-9
    cmds = dict(seen)
    np.testing.assert_allclose(cmds[10], [0.3, 0.0, 0.0])
    np.testing.assert_allclose(cmds[25], [0.6, 0.1, 0.4])  # changed at t = 0.5 s
    np.testing.assert_allclose(cmds[50], [0.6, 0.1, 0.4])


def test_the_tile_holds_the_fastest_command_for_the_whole_run(tiny_ckpt):
    """10 s at 0.5 m/s from the tile centre reaches 5 m: the 8 m training tile would end after 4,
    so the tile is sized as eval's (reach at the speed plus its slack, margin and rim inside)."""
    from tron1cli.env.core import EDGE_MARGIN_M
    from tron1cli.evaluation.protocol import SPEED_SLACK_MPS

    pol = load_policy(tiny_ckpt)
    sched = CommandSchedule(np.array([0.0, 2.0]), np.array([[0.3, 0.0, 0.0], [0.3, -0.4, 0.2]]))
    assert sched.max_speed() == pytest.approx(0.5)
    trained = pol.run_cfg.env.terrain_cfg
    for duration, grown in ((10.0, True), (1.0, False)):
        sim = DeploySim(pol, DeployConfig(terrain="stairs", schedule=sched, duration_s=duration))
        try:
            tile = sim.env.bank.cfg
        finally:
            sim.close()
        reach = duration * (0.5 + SPEED_SLACK_MPS)
        assert tile.tile_size_m / 2 >= reach + EDGE_MARGIN_M + tile.border_m
        assert (tile.tile_size_m > trained.tile_size_m) == grown  # never below the training tile
        assert tile.step_height_m == trained.step_height_m and tile.step_tread_m == trained.step_tread_m


def test_gait_frequency_can_be_set(tiny_ckpt, no_falls):
    """--gait-freq holds the clock at the asked frequency for the whole run."""
    sim = DeploySim(load_policy(tiny_ckpt), DeployConfig(duration_s=0.2, gait_freq_hz=2.5))
    try:
        rep = sim.run()
        phase = sim.env.commands.gait_phase[0]
    finally:
        sim.close()
    assert rep["gait_freq_hz"] == 2.5
    assert min(abs(phase - 0.5), 1.0 - abs(phase - 0.5)) < 1e-9  # 10 steps x 0.02 s x 2.5 Hz


def test_realtime_paces_to_the_wall_clock(tiny_ckpt, no_falls):
    sim = DeploySim(load_policy(tiny_ckpt), DeployConfig(duration_s=0.5, realtime=True))
    try:
        rep = sim.run()
    finally:
        sim.close()
    assert rep["paced"] and 0.8 < rep["realtime_factor"] <= 1.02


def test_unstable_simulation_is_reported(tiny_ckpt, monkeypatch, capsys):
    orig = DeploySim._env_config

    def patched(self):  # any joint speed counts as a runaway: the first step is "unstable"
        c = orig(self)
        return replace(c, termination=replace(c.termination, max_qvel=1e-6))

    monkeypatch.setattr(DeploySim, "_env_config", patched)
    code, out, err = run_cli(monkeypatch, capsys, str(tiny_ckpt), "--json")
    rep = json.loads(out)
    assert code == 0 and rep["unstable"] is True and rep["survived"] is False and rep["ended"] == "unstable"
    assert "unstable" in err


def _tampered_layout(src, path):
    model = onnx.load(str(src))
    for p in model.metadata_props:
        if p.key == "obs_layout":
            layout = json.loads(p.value)  # self-consistent (sizes agree), but not the env's scaling
            layout["proprio"][0][2] = 2.0 * layout["proprio"][0][2]
            p.value = json.dumps(layout)
    onnx.save(model, str(path))
    return path


def test_runs_report_survival_over_consecutive_seeds(tiny_ckpt, monkeypatch, capsys):
    """--runs 3 --seed 4 runs seeds 4, 5 and 6, each the run --seed S alone gives; the summary
    counts what fell and puts the share in its Wilson interval."""
    base = (str(tiny_ckpt), "--terrain", "rough", "--duration", "0.6", "--json")
    code, out, _ = run_cli(monkeypatch, capsys, *base, "--runs", "3", "--seed", "4")
    assert code == 0
    res = json.loads(out)
    sm, reps = res["summary"], res["runs"]
    assert [r["seed"] for r in reps] == [4, 5, 6] and sm["seeds"] == [4, 6] and sm["runs"] == 3
    alone = json.loads(run_cli(monkeypatch, capsys, *base, "--seed", "5")[1])
    for key in ("survived", "ended", "policy_steps", "vel_tracking_error", "com_error_m"):
        assert reps[1][key] == alone[key]
    fell = [r for r in reps if not r["survived"]]
    assert sm["survived"] == 3 - len(fell) and sm["survival"] == pytest.approx(sm["survived"] / 3)
    assert [f["seed"] for f in sm["falls"]] == [r["seed"] for r in fell]
    lo, hi = sm["survival_ci95"]
    assert 0.0 <= lo <= sm["survival"] <= hi <= 1.0
    assert sm["simulated_s"] == pytest.approx(sum(r["duration_s"] for r in reps))
    code, out, _ = run_cli(monkeypatch, capsys, *base[:-1], "--runs", "2")
    assert code == 0 and "survived" in out and " of 2 (" in out


def test_runs_interrupted_report_the_finished_ones(tiny_ckpt, monkeypatch, capsys):
    """Ctrl-C in the third of five runs: the two finished are reported, then exit 130."""
    calls = [0]
    run = DeploySim.run

    def interrupt_third(self, on_step=None):
        calls[0] += 1
        if calls[0] == 3:
            raise KeyboardInterrupt
        return run(self, on_step)

    monkeypatch.setattr(DeploySim, "run", interrupt_third)
    code, out, err = run_cli(
        monkeypatch, capsys, str(tiny_ckpt), "--duration", "0.2", "--runs", "5", "--json"
    )
    assert code == 130 and "interrupted in run 3 of 5: the figures are the 2 finished" in err
    res = json.loads(out)
    assert res["summary"]["runs"] == 2 and [r["seed"] for r in res["runs"]] == [0, 1]


def test_runs_summary_by_hand():
    from tron1cli.deploy.runs import runs_summary

    def rep(seed, survived, t, rtf, rate):
        return {
            "policy": "p.onnx", "terrain": "stairs_up", "terrain_type": "stairs_up", "level": 9,
            "requested_duration_s": 10.0, "seed": seed, "survived": survived, "duration_s": t,
            "ended": "duration" if survived else "fell", "fell_by": None if survived else "base",
            "vel_tracking_error": 0.2, "reconstruction_error_cm": None, "depth_rate_hz": rate,
            "depth_dropped": 1, "depth_age_ms_p99": rate, "policy_ms_p99": 0.5, "realtime_factor": rtf,
        }  # fmt: skip

    sm = runs_summary(
        [rep(0, False, 3.34, 6.0, 30.0), rep(1, True, 10.0, 8.0, 29.9), rep(2, True, 10.0, 7.0, 30.1)]
    )
    assert sm["survived"] == 2 and sm["falls"] == [
        {"seed": 0, "t_s": 3.34, "ended": "fell", "fell_by": "base"}
    ]
    # Wilson, 2 of 3, z = 1.96: centre (2/3 + 0.6403) / 2.2805 = 0.5731, half 0.3654
    assert sm["survival_ci95"] == pytest.approx([0.2077, 0.9385], abs=1e-4)
    assert (sm["realtime_factor_min"], sm["realtime_factor_median"]) == (6.0, 7.0)
    assert (sm["depth_rate_hz_min"], sm["depth_rate_hz_max"], sm["depth_dropped"]) == (29.9, 30.1, 3)
    assert sm["reconstruction_error_cm_mean"] is None and sm["simulated_s"] == pytest.approx(23.34)
    with pytest.raises(ValueError, match="no runs"):
        runs_summary([])


@pytest.mark.parametrize(
    "make,text",
    [
        (lambda d, v: d / "missing.onnx", "policy not found"),
        (lambda d, v: write_foreign_onnx(d / "foreign.onnx"), "not a tron1 policy"),
        (lambda d, v: _tampered_layout(v, d / "tampered.onnx"), "observation layout differs"),
    ],
)
def test_bad_policy_file_exits_1_with_one_line(make, text, vision_onnx, tmp_path, monkeypatch, capsys):
    code, out, err = run_cli(monkeypatch, capsys, str(make(tmp_path, vision_onnx)), "--duration", "0.1")
    assert code == 1 and out == ""
    assert err.startswith("error: ") and text in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize(
    "args,text",
    [
        (["--push", "huge"], "unknown --push"),
        (["--terrain", "moon"], "unknown terrain"),
        (["--cmd", "1,2"], "three numbers"),
        (["--level", "99"], "outside 0..9"),
        (["--physics-hz", "333"], "whole multiple"),
        (["--duration", "0"], "--duration"),
        (["--gait-freq", "3"], "--gait-freq: gait frequency 3 Hz lies outside the trained range 1.5-2.5 Hz"),
        (["--gait-freq", "nan"], "not a finite number"),
        (["--runs", "0"], "--runs"),
        (["--runs", "2", "--video", "x.mp4"], "--video show one run: give --runs 1"),
        (["--runs", "2", "--rerun", "save=x.rrd", "--viewer"], "--rerun and --viewer show one run"),
        (["--runs", "2", "--seed", str(2**32 - 1)], "runs past the largest seed"),
    ],
)
def test_bad_option_exits_2(args, text, tiny_ckpt, monkeypatch, capsys):
    code, out, err = run_cli(monkeypatch, capsys, str(tiny_ckpt), *args)
    assert code == 2 and text in err and len(err.strip().splitlines()) == 1


def test_viewer_without_display_is_one_line(tiny_ckpt, monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    code, out, err = run_cli(monkeypatch, capsys, str(tiny_ckpt), "--viewer")
    assert code == 1 and "needs a display" in err and len(err.strip().splitlines()) == 1


def test_schedule_parsing(tmp_path):
    assert parse_cmd("0.5, 0,-0.2") == (0.5, 0.0, -0.2)
    with pytest.raises(ValueError):
        parse_cmd("fast")
    s = CommandSchedule.constant((0.4, 0.0, 0.1))
    np.testing.assert_allclose(s.at(0.0), [0.4, 0.0, 0.1])
    f = tmp_path / "c.csv"
    f.write_text("1.0,0.5,0,0\n3.0,0,0,0.5\n")
    s = CommandSchedule.from_file(f)
    np.testing.assert_allclose(s.at(0.5), [0, 0, 0])  # before the first line: stand
    np.testing.assert_allclose(s.at(1.0), [0.5, 0, 0])
    np.testing.assert_allclose(s.at(9.0), [0, 0, 0.5])
    for bad in ("0,1,2\n", "1,0,0,0\n0.5,0,0,0\n", "0,a,0,0\n1,x,0,0\n", "# nothing\n"):
        f.write_text(bad)
        with pytest.raises(ValueError, match="c.csv"):
            CommandSchedule.from_file(f)


def test_deploy_sim_rerun_recording_reads_back(vision_onnx, no_falls, tmp_path, monkeypatch, capsys):
    """Issue 8's check: a short deploy-sim run saved to .rrd and read back with rerun's reader."""
    from tron1cli.viz.rerun_stream import PATHS, read_rrd

    rrd = tmp_path / "deploy.rrd"
    code, out, err = run_cli(
        monkeypatch,
        capsys,
        str(vision_onnx),
        "--terrain",
        "stairs",
        "--level",
        "3",
        "--duration",
        "1",
        "--rerun",
        f"save={rrd}",
        "--json",
    )
    assert code == 0, err
    d = read_rrd(rrd)
    steps = json.loads(out)["policy_steps"]
    for path in (PATHS.com, PATHS.desired_com, PATHS.zmp):
        pts = np.concatenate(
            [np.asarray(r["Points3D:positions"], dtype=float).reshape(-1, 3) for r in d[path]]
        )
        assert pts.shape == (steps, 3) and np.all(np.isfinite(pts))
    com = np.concatenate(
        [np.asarray(r["Points3D:positions"], dtype=float).reshape(-1, 3) for r in d[PATHS.com]]
    )
    assert np.all((com[:, 2] > 0.0) & (com[:, 2] < 1.2))
    depth_rows = d[PATHS.depth]
    assert 20 <= len(depth_rows) <= 31  # the frames the policy used, 30 Hz over 1 s
    fmt = depth_rows[-1]["DepthImage:format"][0]
    img = np.frombuffer(bytes(depth_rows[-1]["DepthImage:buffer"][0]), dtype=np.float32)
    assert (fmt["height"], fmt["width"]) == (60, 80) and np.all((img >= 0) & (img <= 3.0 + 1e-6))
    for which in ("true", "reconstructed"):
        rows = d[PATHS.hm_points(which)]
        assert len(rows) == steps
        pts = np.asarray(rows[-1]["Points3D:positions"], dtype=float).reshape(-1, 3)
        assert pts.shape == (441, 3) and np.all(np.isfinite(pts))
