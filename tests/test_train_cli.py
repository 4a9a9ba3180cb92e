"""``tron1 train`` through the CLI: run directory, checkpoints, resume, determinism, bad input."""

import json
import math
import subprocess
import sys

import pytest
import torch
from conftest import tron1

from tron1cli.errors import Tron1Error
from tron1cli.train.checkpoint import load_checkpoint, save_checkpoint

SMALL = ["--envs", "16", "--steps-per-env", "8", "--hidden", "32,32"]


def metrics(run_dir):
    return [json.loads(x) for x in (run_dir / "metrics.jsonl").read_text().splitlines()]


def test_two_iterations_write_a_loadable_checkpoint_and_resume(tmp_path):
    run = tmp_path / "run"
    r = tron1("train", *SMALL, "--iterations", "2", "--run-dir", str(run))
    assert r.returncode == 0, r.stderr
    ck = load_checkpoint(run / "checkpoints" / "latest.pt")
    assert ck["iteration"] == 2 and ck["env_steps"] == 2 * 16 * 8
    cfg = json.loads((run / "config.json").read_text())
    assert cfg["env"]["num_envs"] == 16 and cfg["gait_prior"] is True
    assert cfg["reward"]["groups"] == ["stable", "loco"]
    m = metrics(run)
    assert [x["iteration"] for x in m] == [1, 2]
    for key in ("steps_per_s", "step_reward/stable", "learn/lr", "student/vel_tracking_error"):
        assert key in m[0]
    # resume continues the iteration count to the new total
    r = tron1("train", "--resume", "--iterations", "3", "--run-dir", str(run))
    assert r.returncode == 0, r.stderr
    # stderr is a pipe, not a terminal: plain progress lines (the first and the last iteration)
    lines = [x for x in r.stderr.splitlines() if x.startswith("iter ")]
    assert [x.split()[1] for x in lines] == ["3/3"] and "env steps)" in lines[0], r.stderr
    assert [x["iteration"] for x in metrics(run)] == [1, 2, 3]
    assert load_checkpoint(run / "checkpoints" / "latest.pt")["iteration"] == 3


def test_same_seed_same_first_iterations(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    for d in (a, b):
        assert tron1("train", *SMALL, "--iterations", "2", "--seed", "7", "--run-dir", str(d)).returncode == 0
    keys = ("step_reward/stable", "step_reward/loco", "learn/surrogate_loss", "learn/kl")
    for x, y in zip(metrics(a), metrics(b), strict=True):
        assert [x[k] for k in keys] == [y[k] for k in keys]


@pytest.mark.parametrize(
    "args,code,text",
    [
        (["--terrain", "lava"], 2, "unknown terrain 'lava'"),
        (["--ablation", "nope"], 2, "unknown ablation 'nope'"),
        (["--envs", "0"], 2, "--envs"),
        (["--iterations", "-1"], 2, "--iterations"),
        (["--hidden", "a,b"], 2, "--hidden"),
        (["--critic-weights", "speed=2"], 2, "unknown reward group 'speed'"),
        (["--ablation", "single-critic", "--critic-weights", "stable=0.5"], 2, "groups: all"),
        (["--terrain", "stairs", "--randomize-skip", "lava"], 2, "unknown randomisation terms ['lava']"),
        (["--preset", "fast"], 2, "unknown preset 'fast'; choose from flat, perceptive, teacher, paper"),
        (["--preset", "paper", "--resume"], 2, "--preset starts a new run"),
        (["--randomize-skip", "restitution"], 2, "needs Table III randomisation on"),
        (["--reward-weights", "lava=1"], 2, "unknown reward term 'lava'"),
        (["--reward-weights", "alive=inf"], 2, "alive=inf is not a finite number"),
        (["--reward-weights", "alive"], 2, "wants TERM=NUMBER pairs"),
        (["--learner", "lr"], 2, "--learner: wants KEY=VALUE pairs"),
        (["--learner", "lava=1"], 2, "unknown or non-scalar learner setting 'lava'; choose from num_epochs"),
        (["--learner", "precision=bf16"], 2, "precision has its own option: --precision"),
        (["--learner", "rec_batch_envs=0.5"], 2, "rec_batch_envs=0.5 is not an integer"),
        (["--learner", "rec_all_envs=maybe"], 2, "rec_all_envs=maybe is not true or false"),
        (["--learner", "gamma=2"], 2, "gamma and lam must lie in [0, 1]"),
    ],
)
def test_bad_options_exit_2_with_one_line(tmp_path, args, code, text):
    r = tron1("train", *args, "--run-dir", str(tmp_path / "x"))
    assert r.returncode == code
    lines = [x for x in r.stderr.splitlines() if x.strip()]
    assert len(lines) == 1 and text in lines[0], r.stderr


def test_resume_without_a_run_is_a_clear_error(tmp_path):
    r = tron1("train", "--resume", "--run-dir", str(tmp_path / "none"))
    assert r.returncode == 1
    assert "nothing to resume" in r.stderr and "Traceback" not in r.stderr


def test_corrupt_checkpoint_is_refused(tmp_path):
    p = tmp_path / "c.pt"
    save_checkpoint(p, {"x": torch.zeros(3)})
    assert load_checkpoint(p)["x"].shape == (3,)
    p.write_bytes(p.read_bytes()[:50])
    with pytest.raises(Tron1Error, match="cannot read checkpoint"):
        load_checkpoint(p)
    q = tmp_path / "foreign.pt"
    torch.save({"weights": torch.ones(1)}, q)
    with pytest.raises(Tron1Error, match="not a tron1cli checkpoint"):
        load_checkpoint(q)


def test_checkpoint_refuses_pickled_objects(tmp_path):
    from fractions import Fraction  # any importable class: weights_only must refuse to build it

    p = tmp_path / "evil.pt"
    torch.save({"format": "tron1cli-checkpoint", "version": 1, "obj": Fraction(1, 3)}, p)
    with pytest.raises(Tron1Error, match="cannot read checkpoint"):
        load_checkpoint(p)


def test_saved_reward_is_restored_not_rebuilt():
    from tron1cli.train.runner import RunConfig

    d = json.loads(json.dumps(RunConfig().to_dict()))
    d["reward"]["terms"]["alive"]["weight"] = 0.7  # a run trained with another default
    cfg = RunConfig.from_dict(d)
    assert cfg.reward.terms["alive"].weight == 0.7
    assert RunConfig.from_dict(cfg.to_dict()).to_dict() == cfg.to_dict()


def test_stairs_run_has_perception_and_logs_terrain_levels(tmp_path):
    run = tmp_path / "stairs"
    skip = ("--randomize-skip", "restitution,delay")
    r = tron1("train", *SMALL, "--terrain", "stairs", *skip, "--iterations", "1", "--run-dir", str(run))
    assert r.returncode == 0, r.stderr
    header = " ".join(r.stderr.split())
    assert "perception on, randomisation on except restitution, delay, pushes on" in header
    cfg = json.loads((run / "config.json").read_text())
    assert cfg["env"]["perception"] and cfg["env"]["depth_from"] == 8
    terms = cfg["env"]["randomization"]["terms"]
    assert "restitution" not in terms and "delay" not in terms and "friction" in terms
    (m,) = metrics(run)
    assert set(k for k in m if k.startswith("terrain/level/")) == {
        "terrain/level/stairs_up",
        "terrain/level/stairs_down",
    }
    for key in ("learn/rec_heightmap", "learn/rec_latent_h", "learn/rec_privileged"):
        assert m[key] >= 0


def test_killed_run_saves_and_resumes(tmp_path):
    import signal
    import time

    run = tmp_path / "killed"
    proc = subprocess.Popen(
        [sys.executable, "-m", "tron1cli", "train", *SMALL, "--iterations", "1000", "--run-dir", str(run)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={"OMP_NUM_THREADS": "1", "PATH": "/usr/bin:/bin"},
    )
    deadline = time.time() + 300
    while time.time() < deadline and not ((run / "metrics.jsonl").exists() and len(metrics(run)) >= 2):
        time.sleep(0.2)
    proc.send_signal(signal.SIGTERM)
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130 and "checkpoint saved" in stderr
    done = load_checkpoint(run / "checkpoints" / "latest.pt")["iteration"]
    assert done >= 2
    r = tron1("train", "--resume", "--iterations", str(done + 1), "--run-dir", str(run))
    assert r.returncode == 0, r.stderr
    assert load_checkpoint(run / "checkpoints" / "latest.pt")["iteration"] == done + 1


def test_train_streams_an_episode_to_rerun(tmp_path):
    from tron1cli.viz.rerun_stream import read_rrd

    rrd = tmp_path / "train.rrd"
    run = tmp_path / "run"
    r = tron1(
        "train",
        *SMALL,
        "--iterations",
        "2",
        "--run-dir",
        str(run),
        "--rerun",
        f"save={rrd}",
        "--rerun-every",
        "1",
    )
    assert r.returncode == 0, r.stderr
    data = read_rrd(rrd)
    assert "world/lipm/com" in data and "reward_group/stable" in data
    r = tron1("train", *SMALL, "--run-dir", str(tmp_path / "x"), "--rerun", "nowhere")
    assert r.returncode == 2 and "unknown target" in r.stderr


def test_default_critic_weights_follow_the_groups(tmp_path):
    r = tron1("train", *SMALL, "--iterations", "1", "--run-dir", str(tmp_path / "a"))
    assert r.returncode == 0, r.stderr
    c = json.loads((tmp_path / "a" / "config.json").read_text())
    assert c["learner"]["critic_weights"] == {"stable": 0.25}  # the flat preset's
    assert c["learner"]["num_epochs"] == 3 and "num_epochs=3" in " ".join(r.stderr.split())
    assert c["reward"]["terms"]["flat_orientation"] == {"weight": -5.0, "group": "loco", "gated": False}
    l2 = {"weight": 1.0, "group": "loco", "gated": False, "ramp": [150, 200]}  # ramped in
    assert c["reward"]["terms"]["track_lin_l2"] == l2
    r = tron1(
        "train", *SMALL, "--iterations", "1", "--ablation", "single-critic", "--run-dir", str(tmp_path / "b")
    )
    assert r.returncode == 0, r.stderr
    assert json.loads((tmp_path / "b" / "config.json").read_text())["learner"]["critic_weights"] == {}


def test_paper_preset_with_overrides_is_recorded_and_printed(tmp_path):
    r = tron1("train", "--preset", "paper", *SMALL, "--iterations", "1", "--run-dir", str(tmp_path / "p"))
    assert r.returncode == 0, r.stderr
    header = " ".join(r.stderr.split())
    assert "preset paper (overridden: envs, iterations, steps_per_env, hidden)" in header
    assert "gait prior off" in header and "critic weights equal" in header
    c = json.loads((tmp_path / "p" / "config.json").read_text())
    assert (c["preset"], c["gait_prior"], c["learner"]["critic_weights"]) == ("paper", False, {})
    assert c["env"]["perception"] and c["env"]["pushes"]["enabled"] and c["env"]["terrain"] == "mixed"
    assert "camera_fov" in c["env"]["randomization"]["terms"] and c["env"]["num_envs"] == 16
    assert c["learner"]["num_epochs"] == 5 and "learner default" in header


def test_resumed_run_keeps_its_terrain_levels(tmp_path):
    """A campaign resumed in a later run goes on from the levels it reached, not from 0."""
    from dataclasses import replace

    import numpy as np

    from tron1cli.config.presets import perceptive
    from tron1cli.train.runner import Trainer, run_config

    preset = replace(perceptive("stairs"), num_envs=8, steps_per_env=4, hidden=(16,))
    cfg = run_config(preset, nthread=1)
    first = Trainer(tmp_path, cfg)
    cur, bank = first.env.curriculum, first.env.bank
    cur.level[:] = np.arange(8) % bank.cfg.num_levels
    cur.tile[:] = bank.tile_index(cur.kind, cur.level, np.zeros(8, int))
    first.save()
    first.close()
    resumed = Trainer(tmp_path, resume=True)
    try:
        assert np.array_equal(resumed.env.curriculum.level, np.arange(8) % bank.cfg.num_levels)
        assert np.array_equal(resumed.env.curriculum.tile, cur.tile)
        with pytest.raises(ValueError, match="other levels than its tiles"):
            resumed.env.restore_curriculum({"level": cur.level + 1, "tile": cur.tile})
        with pytest.raises(ValueError, match="outside this terrain bank"):
            resumed.env.restore_curriculum({"level": cur.level, "tile": cur.tile + bank.K})
    finally:
        resumed.close()


def test_learner_settings_are_parsed_recorded_printed_and_kept_on_resume(tmp_path):
    run = tmp_path / "r"
    settings = "rec_batch_envs=4,entropy_coef=0.002,desired_kl=none,clip_value_loss=off"
    r = tron1("train", *SMALL, "--iterations", "1", "--learner", settings, "--run-dir", str(run))
    assert r.returncode == 0, r.stderr
    shown = (  # the flat preset's 3 epochs, then the settings given
        "learner num_epochs=3, desired_kl=none, entropy_coef=0.002, clip_value_loss=False, rec_batch_envs=4,"
    )
    assert shown in " ".join(r.stderr.split())
    c = json.loads((run / "config.json").read_text())
    lr = c["learner"]
    got = (lr["rec_batch_envs"], lr["entropy_coef"], lr["desired_kl"], lr["clip_value_loss"])
    assert got == (4, 0.002, None, False)
    assert lr["lr"] == 1e-3 and "learner" in c["preset_overrides"]  # the rest stays at the defaults
    resume = ("train", "--resume", "--iterations", "2", "--run-dir", str(run))
    r = tron1(*resume, "--learner", "rec_batch_envs=8")
    assert r.returncode == 2 and "started with --learner rec_batch_envs=4" in " ".join(r.stderr.split())
    r = tron1(*resume, "--learner", "entropy_coef=0.002")  # the value it was started with
    assert r.returncode == 0, r.stderr
    saved = json.loads(load_checkpoint(run / "checkpoints" / "latest.pt")["config"])["learner"]
    assert saved["rec_batch_envs"] == 4 and saved["desired_kl"] is None


def test_resume_takes_the_precision_given_now_like_the_threads(tmp_path):
    """--precision is the machine's choice (bf16 pays with AMX, is emulated and slow on AVX2): a
    resumed run computes in the precision given now, records it, and keeps the saved one otherwise."""
    run = tmp_path / "r"
    assert tron1("train", *SMALL, "--iterations", "1", "--run-dir", str(run)).returncode == 0
    resume = ("train", "--resume", "--run-dir", str(run))
    r = tron1(*resume, "--iterations", "2", "--precision", "bf16")
    assert r.returncode == 0, r.stderr
    assert "learner on cpu in bf16" in " ".join(r.stderr.split())
    saved = json.loads(load_checkpoint(run / "checkpoints" / "latest.pt")["config"])["learner"]
    assert saved["precision"] == "bf16"
    r = tron1(*resume, "--iterations", "3")
    assert r.returncode == 0 and "learner on cpu in bf16" in " ".join(r.stderr.split()), r.stderr
    r = tron1(*resume, "--iterations", "4", "--precision", "fp8")
    lines = [x for x in r.stderr.splitlines() if x.strip()]
    assert r.returncode == 2 and len(lines) == 1 and "--precision must be one of fp32, bf16" in lines[0]


def test_bf16_on_a_cpu_that_emulates_it_is_noted(monkeypatch, capsys):
    from tron1cli.cli import common
    from tron1cli.learn import perf

    monkeypatch.setattr(perf, "cpu_has_fast_bf16", lambda: False)
    assert common.resolve_precision("bf16", "cpu") == "bf16"
    assert "bf16 is emulated here" in capsys.readouterr().err
    for precision, device in (("fp32", "cpu"), ("bf16", "cuda")):
        assert common.resolve_precision(precision, device) == precision
        assert capsys.readouterr().err == ""
    monkeypatch.setattr(perf, "cpu_has_fast_bf16", lambda: True)
    common.resolve_precision("bf16", "cpu")
    assert capsys.readouterr().err == ""


def test_init_carries_terrain_levels_only_from_the_same_terrain_bank(tmp_path):
    """A new campaign phase (--init) starts on the levels its source reached when both runs train
    on the same terrain bank: each env on its own level and tile with the same env count and mix,
    else each on the level of a source env of its terrain type; another bank starts at level 0."""
    from dataclasses import replace

    import numpy as np

    from tron1cli.config.presets import perceptive
    from tron1cli.train.runner import Trainer, run_config

    preset = replace(perceptive("stairs"), num_envs=8, steps_per_env=4, hidden=(16,))
    source = Trainer(tmp_path / "a", run_config(preset, nthread=1))
    cur, bank = source.env.curriculum, source.env.bank
    cur.level[:] = np.arange(8) % bank.cfg.num_levels
    cur.tile[:] = bank.tile_index(cur.kind, cur.level, np.ones(8, int))
    ckpt = source.save()
    source.close()
    same = Trainer(tmp_path / "b", run_config(replace(preset, steps_per_env=2), nthread=1), init=ckpt)
    try:
        assert same.levels_carried and same.cfg.init_from.endswith("(iteration 0), terrain levels carried")
        assert np.array_equal(same.env.curriculum.level, cur.level)
        assert np.array_equal(same.env.curriculum.tile, cur.tile)
    finally:
        same.close()
    std = Trainer(tmp_path / "s", replace(run_config(preset, nthread=1), init_action_std=0.4), init=ckpt)
    try:  # --init-std: the source's weights, a fresh action std
        assert std.levels_carried and ", action std set to 0.4" in std.cfg.init_from
        assert torch.allclose(std.learner.model.log_std, torch.full((6,), math.log(0.4)))
    finally:
        std.close()
    # the source dealt stairs up to the even envs (levels 0, 2, 4, 6), stairs down to the odd ones
    reached = {t: cur.level[cur.kind == t].tolist() for t in (0, 1)}
    assert reached == {0: [0, 2, 4, 6], 1: [1, 3, 5, 7]}
    mix = {"stairs_up": 3.0, "stairs_down": 1.0}
    for other in (replace(preset, num_envs=16), replace(preset, terrain_mix=mix)):
        run_dir = tmp_path / f"n{other.num_envs}-{len(other.terrain_mix or {})}"
        moved = Trainer(run_dir, run_config(other, nthread=1), init=ckpt)
        try:  # dealt anew: per type, the source's levels in turn, each on a tile of its level
            c = moved.env.curriculum
            assert moved.levels_carried
            for t in (0, 1):
                got = c.level[c.kind == t]
                assert np.array_equal(got, np.resize(reached[t], len(got)))
            assert np.array_equal(bank.level[c.tile], c.level) and np.array_equal(bank.kind[c.tile], c.kind)
        finally:
            moved.close()
    fresh = Trainer(tmp_path / "slopes", run_config(replace(preset, terrain="slopes"), nthread=1), init=ckpt)
    try:
        assert not fresh.levels_carried and not fresh.cfg.init_from.endswith("carried")
        assert not fresh.env.curriculum.level.any()
    finally:
        fresh.close()


def test_reward_weights_are_recorded_printed_and_kept_on_resume(tmp_path):
    run = tmp_path / "r"
    r = tron1("train", *SMALL, "--iterations", "1", "--reward-weights", "alive=0.5", "--run-dir", str(run))
    assert r.returncode == 0, r.stderr
    assert "reward weights alive=0.5" in " ".join(r.stderr.split())
    c = json.loads((run / "config.json").read_text())
    assert c["reward"]["terms"]["alive"]["weight"] == 0.5 and "reward_weights" in c["preset_overrides"]
    r = tron1("train", "--resume", "--iterations", "2", "--reward-weights", "alive=1", "--run-dir", str(run))
    assert r.returncode == 2 and "started with --reward-weights alive=0.5" in " ".join(r.stderr.split())
    r = tron1("train", "--resume", "--iterations", "2", "--run-dir", str(run))
    assert r.returncode == 0, r.stderr
    assert load_checkpoint(run / "checkpoints" / "latest.pt")["iteration"] == 2


def test_reward_ramps_are_recorded_printed_and_kept_on_resume(tmp_path):
    run = tmp_path / "r"
    ramps = "track_lin_l2=10:20,alive=0:5"
    r = tron1("train", *SMALL, "--iterations", "1", "--reward-ramps", ramps, "--run-dir", str(run))
    assert r.returncode == 0, r.stderr
    header = " ".join(r.stderr.split())
    assert (
        "track_lin_l2=1 (from iteration 10 to 20)" in header and "alive=2 (from iteration 0 to 5)" in header
    )
    terms = json.loads((run / "config.json").read_text())["reward"]["terms"]
    assert terms["track_lin_l2"]["ramp"] == [10, 20] and terms["alive"]["ramp"] == [0, 5]
    resume = ("train", "--resume", "--iterations", "2", "--run-dir", str(run))
    r = tron1(*resume, "--reward-ramps", "track_lin_l2=none")
    assert r.returncode == 2 and "started with --reward-ramps track_lin_l2=10:20" in " ".join(
        r.stderr.split()
    )
    r = tron1(*resume, "--reward-ramps", "alive=0:5")  # the value it was started with
    assert r.returncode == 0, r.stderr
    r = tron1(
        "train",
        *SMALL,
        "--iterations",
        "1",
        "--reward-ramps",
        "track_lin_l2=none",
        "--run-dir",
        str(tmp_path / "n"),
    )
    assert r.returncode == 0, r.stderr
    terms = json.loads((tmp_path / "n" / "config.json").read_text())["reward"]["terms"]
    assert (
        "ramp" not in terms["track_lin_l2"] and terms["track_lin_l2"]["weight"] == 1.0
    )  # full from the start


@pytest.mark.parametrize(
    "value, message",
    [
        ("track_lin_l2=20:10", "START <= END"),
        ("track_lin_l2=5", "a ramp is START:END"),
        ("track_lin_l2=-1:4", "a ramp is START:END"),
        ("lava=1:2", "cannot ramp 'lava'"),
        ("track_lin_l2", "KEY=VALUE pairs"),
    ],
)
def test_bad_reward_ramps_are_one_line_exit_2(tmp_path, value, message):
    r = tron1("train", *SMALL, "--reward-ramps", value, "--run-dir", str(tmp_path / "x"))
    assert r.returncode == 2 and message in r.stderr and "Traceback" not in r.stderr
    assert len([x for x in r.stderr.splitlines() if x.strip()]) == 1


_BEFORE_TORCH = """
import sys
from typer.testing import CliRunner
from tron1cli.cli.main import app
for args in ({cases}):
    r = CliRunner().invoke(app, ["train", *args])
    print(r.exit_code, "torch" in sys.modules)
"""


def test_options_that_need_no_learner_are_refused_before_torch_loads():
    """A wrong terrain, ablation, network size or reward term is one line and exit 2 without the
    learner's imports (torch alone takes about 2 s on 2 cores)."""
    cases = (
        ["--terrain", "lava"],
        ["--ablation", "nope"],
        ["--hidden", "0"],
        ["--reward-weights", "nope=1"],
        ["--critic-weights", "stable=-1"],
        ["--reward-ramps", "nope=1:2"],
    )
    code = _BEFORE_TORCH.format(cases=", ".join(repr(c) for c in cases))
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert res.stdout.split("\n")[: len(cases)] == ["2 False"] * len(cases)
