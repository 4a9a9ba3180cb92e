"""Bad input, round 3 (issue 44): nothing lost to a full disk, a cut line or a second run;
malformed files and absurd sizes in one line. One section per class of the issue."""

from __future__ import annotations

import errno
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import tron1
from test_bad_input import _run_main, _tiny_trainer, edited_onnx, nan_weights, one_error_line, rewrite

from tron1cli.errors import Tron1Error, UsageError
from tron1cli.train.checkpoint import load_checkpoint

REPO = Path(__file__).resolve().parents[1]


def tron1_in(cwd: Path, *args: str) -> subprocess.CompletedProcess:
    """The CLI run in folder ``cwd`` (a mistake that writes into the current folder lands there)."""
    return subprocess.run(
        [sys.executable, "-m", "tron1cli", *args],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=cwd,
        env={"OMP_NUM_THREADS": "1", "PATH": "/usr/bin:/bin", "PYTHONPATH": str(REPO)},
    )


@pytest.fixture(scope="module")
def policy_onnx(tiny_ckpt, tmp_path_factory) -> Path:
    from tron1cli.policy.export import export_onnx

    return export_onnx(tiny_ckpt, tmp_path_factory.mktemp("onnx3") / "p.onnx", parity_steps=2).path


def _copy_run(ckpt: Path, dest: Path) -> Path:
    """A copy of the run directory of checkpoint ``ckpt`` (``run/checkpoints/latest.pt``)."""
    shutil.copytree(ckpt.parent.parent, dest)
    return dest


class _FullDisk:
    """A file object that takes ``room`` bytes, then fails as a full disk does."""

    def __init__(self, f, room: int) -> None:
        self.f, self.room = f, room

    def write(self, data) -> int:
        data = bytes(data)
        if len(data) > self.room:
            self.f.write(data[: self.room])
            self.room = 0
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self.room -= len(data)
        return self.f.write(data)

    def __getattr__(self, name):
        return getattr(self.f, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.f.close()


def fill_disk(monkeypatch, room: int = 4096) -> None:
    """Every atomic write from now on meets a disk with ``room`` bytes left."""
    import tron1cli.fileio as fileio

    real = os.fdopen
    monkeypatch.setattr(fileio.os, "fdopen", lambda fd, mode="r": _FullDisk(real(fd, mode), room))


# -- 1. files that are almost right: one line naming the file, never a traceback -------------


@pytest.mark.parametrize(
    "args,text",
    [
        (["eval", "{loop}", "--envs", "1", "--steps", "1"], "policy {loop}: a symbolic link loop"),
        (
            ["train", "--init", "{loop}", "--run-dir", "{tmp}/r"],
            "--init checkpoint {loop}: a symbolic link loop",
        ),
    ],
)
def test_a_symlink_loop_is_one_line(tmp_path, args, text):
    loop = tmp_path / "loop.pt"
    (tmp_path / "other.pt").symlink_to(loop)
    loop.symlink_to(tmp_path / "other.pt")
    fmt = {"loop": loop, "tmp": tmp_path}
    one_error_line(tron1(*(a.format(**fmt) for a in args)), 1, text.format(**fmt))
    from tron1cli.train.layout import policy_label

    assert policy_label(loop) == "loop"


@pytest.mark.parametrize(
    "fields,text",
    [
        ({"joint_names": 5}, "joint_names should be a list of names, got a number"),
        ({"obs_layout": [1, 2]}, "obs_layout should be an object, got a list"),
        ({"run_config": [1]}, "run_config should be an object, got a list"),
        ({"run_config": {"env": 5}}, "run_config.env should be an object, got a number"),
        ({"run_config": {"env": {"num_envs": "many"}}}, "run_config.env.num_envs should be an integer"),
        ({"run_config": {"learner": {"actor_hidden": 64}}}, "learner.actor_hidden should be a list"),
        ({"gait_clock": [1.5, 2.5]}, "gait_clock should be an object, got a list"),
        ({"gait_clock": {"swing_fold_rad": 0.5}}, "swing_fold_rad should be a list of two numbers"),
        ({"gait_clock": {"swing_fold_keep": 1.5}}, "swing_fold_keep should be a number in [0, 1]"),
        ({"depth": 3}, "depth should be an object or null, got a number"),
        ({"default_pose_rad": 0.0}, "default_pose_rad must hold 6"),
        ({"kp_nm_per_rad": [40.0]}, "kp_nm_per_rad = [40.0] is not a finite positive number"),
    ],
)
def test_onnx_metadata_of_the_wrong_json_type_is_one_line(policy_onnx, tmp_path, fields, text):
    from tron1cli.policy.runtime import load_policy

    bad = edited_onnx(policy_onnx, tmp_path / "bad.onnx", **fields)
    with pytest.raises(Tron1Error) as e:
        load_policy(bad)
    assert text in str(e.value) and str(bad) in str(e.value) and "\n" not in str(e.value), str(e.value)


def test_onnx_metadata_of_the_wrong_type_through_the_cli(policy_onnx, tmp_path):
    bad = edited_onnx(policy_onnx, tmp_path / "bad.onnx", joint_names=5)
    one_error_line(tron1("deploy-sim", str(bad), "--duration", "0.1"), 1, "joint_names should be")


def _drop(key):
    return lambda state: state.pop(key)


def _set(key, value):
    return lambda state: state.__setitem__(key, value)


@pytest.mark.parametrize(
    "edit,text",
    [
        (_drop("learner"), "no learner state"),
        (lambda s: s["learner"].pop("model"), "holds no weights"),
        (lambda s: s["learner"].__setitem__("model", {"w": [1.0]}), "holds no weights"),
        (_set("config", "{not json"), "run configuration is not JSON"),
        (_set("config", "[1, 2]"), "not a JSON object"),
        (_set("iteration", "seven"), "iteration = 'seven' is not a count"),
        (_set("curriculum", [1, 2]), "curriculum is not a dict of tensors"),
    ],
)
def test_a_checkpoint_without_a_runs_form_is_one_line(tiny_ckpt, tmp_path, edit, text):
    from tron1cli.policy.runtime import load_policy
    from tron1cli.train.checkpoint import load_training_checkpoint

    bad = rewrite(tiny_ckpt, tmp_path / "bad.pt", edit)
    for load in (load_training_checkpoint, load_policy):
        with pytest.raises(Tron1Error) as e:
            load(bad)
        assert text in str(e.value) and str(bad) in str(e.value) and "\n" not in str(e.value)


def test_train_init_of_a_checkpoint_without_learner_state_is_one_line(tiny_ckpt, tmp_path):
    bad = rewrite(tiny_ckpt, tmp_path / "nolearner.pt", _drop("learner"))
    r = tron1("train", "--init", str(bad), "--iterations", "1", "--run-dir", str(tmp_path / "r"))
    one_error_line(r, 1, f"{bad}: not a usable training checkpoint (no learner state)")
    assert not (tmp_path / "r").exists()


def test_run_config_of_the_wrong_type_names_the_field():
    from tron1cli.train.runner import RunConfig

    good = RunConfig().to_dict()
    assert RunConfig.from_dict(json.loads(json.dumps(good))) == RunConfig()
    for bad, text in (
        ([], "should be an object"),
        ({**good, "iterations": "10"}, "run_config.iterations should be an integer"),
        ({**good, "gait_prior": 1}, "run_config.gait_prior should be true or false"),
        (
            {**good, "env": {**good["env"], "terrain_cfg": []}},
            "run_config.env.terrain_cfg should be an object",
        ),
        ({**good, "reward": [1]}, "reward should be an object"),
        (  # a teacher share edited by hand without the env's depth split: students would be blind
            {**good, "env": {**good["env"], "perception": True, "depth_from": 256}},
            "env.depth_from is 256 but the students start at env 512 ",
        ),
    ):
        with pytest.raises(ValueError, match=text):
            RunConfig.from_dict(bad)


# -- 2. absurd sizes: refused at once, in one line --------------------------------------------


@pytest.mark.parametrize(
    "args",
    [
        ["eval", "{ckpt}", "--envs", "100000000", "--steps", "1", "--terrain", "flat"],
        ["push-test", "{ckpt}", "--envs", "100000000"],
        ["train", "--envs", "100000000", "--run-dir", "{tmp}/r"],
    ],
)
def test_an_env_count_the_machine_cannot_hold_is_refused_at_once(tiny_ckpt, tmp_path, args):
    t0 = time.monotonic()
    r = tron1(*(a.format(ckpt=tiny_ckpt, tmp=tmp_path) for a in args))
    line = one_error_line(r, 2, "--envs 100,000,000: ")
    assert "of memory" in line and "this machine has available" in line and "or fewer fit" in line
    assert time.monotonic() - t0 < 30 and not (tmp_path / "r").exists()


def test_memory_is_checked_before_any_env_is_built(monkeypatch):
    import tron1cli.memory as memory
    from tron1cli.config import EnvConfig
    from tron1cli.env.core import Tron1Env

    monkeypatch.setattr(memory, "available_bytes", lambda: 64 * 2**20)  # 64 MiB left
    with pytest.raises(UsageError, match=r"--envs 50,000: envs need at least .* 64\.0 MiB"):
        Tron1Env(EnvConfig(num_envs=50_000, nthread=1))


def test_the_sizes_runs_use_are_never_refused():
    from dataclasses import replace

    from tron1cli.config.presets import flat, perceptive
    from tron1cli.memory import available_bytes, env_bytes
    from tron1cli.train.runner import rollout_memory, run_config

    for preset in (flat(), perceptive("stairs")):
        cfg = run_config(replace(preset, num_envs=4096))
        assert 4096 * rollout_memory(cfg) < 2**30  # 81 and 350 MiB: under any machine that trains
        assert 4096 * env_bytes(cfg.env) < 256 * 2**20
    assert available_bytes() is None or available_bytes() > 0


# -- 3. nothing lost: results, a second run, a cut metrics line, a full disk ------------------


def test_eval_results_are_written_whole_or_not_at_all(tmp_path, monkeypatch):
    from tron1cli.cli.evaluate import _write_eval_outputs

    out = tmp_path / "out"
    out.mkdir()
    (out / "results.json").write_text('{"earlier": "results"}')
    (out / "results.csv").write_text("earlier,results\n")
    agg = {"mean": 0.5, "std": 0.1, "n": 2}
    report = {"results": {"ours": {"flat": {f"m{k}": agg for k in range(400)}}}, "pad": "x" * 9000}
    fill_disk(monkeypatch)
    with pytest.raises(OSError) as e:
        _write_eval_outputs(out, report, {}, {})
    assert e.value.errno == errno.ENOSPC and e.value.filename == str(out / "results.json")
    assert (out / "results.json").read_text() == '{"earlier": "results"}'  # not cut to 4096 bytes
    assert (out / "results.csv").read_text() == "earlier,results\n"
    assert sorted(p.name for p in out.iterdir()) == ["results.csv", "results.json"]  # no temp files
    monkeypatch.undo()
    _write_eval_outputs(out, report, {}, {})
    assert json.loads((out / "results.json").read_text()) == report
    assert (out / "results.csv").read_text().count("\n") == 401


def test_a_second_training_process_in_a_run_dir_is_refused(tmp_path):
    from tron1cli.train.layout import LOCK

    first = _tiny_trainer(tmp_path, iterations=1, save_every=1)
    try:
        assert (tmp_path / LOCK).read_text().split()[0] == str(os.getpid())
        with pytest.raises(Tron1Error, match=f"--run-dir {tmp_path} is in use: another tron1 train"):
            _tiny_trainer(tmp_path, iterations=1, save_every=1)
    finally:
        first.close()
    assert not (tmp_path / LOCK).exists()
    _tiny_trainer(tmp_path, iterations=1, save_every=1).close()  # free again


def test_the_cli_refuses_a_locked_run_dir_and_takes_over_a_stale_lock(tmp_path):
    from tron1cli.train.layout import LOCK, RunLock, _start_time

    run = tmp_path / "run"
    run.mkdir()
    other = subprocess.Popen(["sleep", "60"])
    try:
        host = __import__("socket").gethostname()
        (run / LOCK).write_text(f"{other.pid} {host} {_start_time(other.pid)}\n")
        small = ["--iterations", "1", "--envs", "4", "--steps-per-env", "2", "--hidden", "16"]
        r = tron1("train", *small, "--run-dir", str(run))
        one_error_line(r, 1, f"another tron1 train (process {other.pid}) is training there")
        assert not (run / "checkpoints").exists()
    finally:
        other.kill()
        other.wait()
    lock = RunLock(run).acquire()  # its process is gone: the lock is stale and taken over
    assert (run / LOCK).read_text().split()[0] == str(os.getpid())
    lock.release()
    assert not (run / LOCK).exists()


def test_resume_drops_a_cut_metrics_line_and_report_says_when_it_skips_one(tiny_ckpt, tmp_path):
    from tron1cli.train.runner import Trainer

    run = _copy_run(tiny_ckpt, tmp_path / "run")
    metrics = run / "metrics.jsonl"
    with open(metrics, "a") as f:
        f.write('{"iteration": 2, "env_steps": 6')  # a crash mid-write
    r = tron1("report", str(run))
    assert r.returncode == 0, r.stderr
    assert r.stderr.startswith("warning: ") and f"{metrics} line 2 is cut off" in r.stderr, r.stderr
    trainer = Trainer(run, resume=True, iterations=3)
    try:
        assert trainer.dropped_metrics_line == 2
        trainer.run()
    finally:
        trainer.close()
    rows = [json.loads(x) for x in metrics.read_text().splitlines()]  # every line whole
    assert [m["iteration"] for m in rows] == [1, 2, 3]
    r = tron1("report", str(run))
    assert r.returncode == 0 and r.stderr == "" and "3 iterations" in r.stdout, r.stderr


def test_a_disk_that_fills_while_training_is_one_line_and_keeps_the_last_checkpoint(tmp_path, monkeypatch):
    trainer = _tiny_trainer(tmp_path, iterations=3, save_every=1)
    latest = tmp_path / "checkpoints" / "latest.pt"

    def on_iteration(m):
        if m["iteration"] == 1:  # saved; the disk fills before the next save
            fill_disk(monkeypatch, room=1000)

    try:
        with pytest.raises(Tron1Error) as e:
            trainer.run(on_iteration)
    finally:
        trainer.close()
        monkeypatch.undo()
    line = str(e.value)
    assert line.startswith(f"cannot write {latest}: no space left on the device;"), line
    assert f"{latest} (iteration 1) is the last good checkpoint" in line and "\n" not in line
    assert load_checkpoint(latest)["iteration"] == 1
    assert not list((tmp_path / "checkpoints").glob(".*.tmp"))


# -- 4. output paths are checked before the work ---------------------------------------------


@pytest.mark.parametrize(
    "args",
    [
        ["eval", "{ckpt}", "--envs", "1", "--steps", "1", "--terrain", "flat"],
        ["push-test", "{ckpt}", "--envs", "14", "--terrain", "flat"],
        ["deploy-sim", "{ckpt}", "--duration", "0.1"],
    ],
)
@pytest.mark.parametrize(
    "video,text",
    [
        ("{file}/walk.mp4", "--video {file}/walk.mp4: cannot make a folder there, {file} is a file"),
        ("{tmp}/walk.mp4", "--video {tmp}/walk.mp4 is a folder"),
    ],
)
def test_the_video_path_is_checked_before_the_run(tiny_ckpt, tmp_path, args, video, text):
    blocker = tmp_path / "blocker.txt"
    blocker.write_text("in the way")
    (tmp_path / "walk.mp4").mkdir()
    fmt = {"ckpt": tiny_ckpt, "file": blocker, "tmp": tmp_path}
    r = tron1(*(a.format(**fmt) for a in args), "--video", video.format(**fmt))
    one_error_line(r, 2, text.format(**fmt))


# -- 5. lines that say what is wrong and what to do ------------------------------------------


@pytest.mark.parametrize(
    "args",
    [
        ["export-onnx", "{onnx}"],
        ["export-onnx", "{as_pt}"],
        ["train", "--init", "{onnx}", "--run-dir", "{tmp}/r"],
    ],
)
def test_an_onnx_file_where_a_checkpoint_is_read_is_named_as_such(policy_onnx, tmp_path, args):
    as_pt = tmp_path / "policy.pt"
    as_pt.write_bytes(policy_onnx.read_bytes())
    fmt = {"onnx": policy_onnx, "as_pt": as_pt, "tmp": tmp_path}
    line = one_error_line(tron1(*(a.format(**fmt) for a in args)), 1, "is an exported ONNX policy")
    assert "need the training checkpoint (.pt) it was exported from" in line and "pickled" not in line
    assert not (tmp_path / "r").exists()


def test_an_onnx_file_named_pt_is_loaded_as_what_it_is(policy_onnx, tmp_path):
    from tron1cli.policy.runtime import load_policy

    as_pt = tmp_path / "policy.pt"
    as_pt.write_bytes(policy_onnx.read_bytes())
    assert load_policy(as_pt).kind == "onnx"
    with pytest.raises(Tron1Error, match="exported ONNX policy"):
        load_checkpoint(as_pt)


def test_train_init_refuses_non_finite_weights_before_building_anything(tiny_ckpt, tmp_path, monkeypatch):
    import tron1cli.train.runner as runner

    bad = rewrite(tiny_ckpt, tmp_path / "nan.pt", nan_weights)

    def no_env(*a, **k):
        raise AssertionError("the env was built")

    monkeypatch.setattr(runner, "Tron1Env", no_env)
    cfg = runner.RunConfig.from_dict(json.loads(load_checkpoint(tiny_ckpt)["config"]))
    with pytest.raises(Tron1Error, match=f"--init {bad}: the policy's weights are not finite"):
        runner.Trainer(tmp_path / "r", cfg, init=bad)
    assert not (tmp_path / "r").exists()


def test_a_binary_cmd_file_names_the_option_and_the_file(tmp_path):
    from tron1cli.deploy.schedule import CommandSchedule

    for name, data in (("a.bin", bytes(range(256))), ("b.bin", b"0,0.5,0,0\x00\x00")):
        p = tmp_path / name
        p.write_bytes(data)
        with pytest.raises(ValueError, match=f"--cmd-file {p}: not a text file"):
            CommandSchedule.from_file(p)


class _CtrlC:
    """Ctrl-C as soon as it is called."""

    def __init__(self, *a, **k):
        raise KeyboardInterrupt


class _CtrlCWhileRunning:
    """A DeploySim stopped by Ctrl-C while it runs."""

    def __init__(self, *a, **k):
        pass

    def run(self, on_step):
        raise KeyboardInterrupt

    def close(self):
        pass


@pytest.mark.parametrize(
    "argv,target,stop,text",
    [
        (
            ["export-onnx", "{ckpt}", "-o", "{tmp}/p.onnx"],
            "tron1cli.policy.export.export_onnx",
            _CtrlC,
            "export-onnx interrupted: nothing written",
        ),
        (
            ["deploy-sim", "{ckpt}"],
            "tron1cli.policy.runtime.load_policy",
            _CtrlC,
            "deploy-sim interrupted: no results",
        ),
        (
            ["deploy-sim", "{ckpt}"],
            "tron1cli.deploy.pipeline.DeploySim",
            _CtrlCWhileRunning,
            "deploy-sim interrupted after 0 policy steps: no results written",
        ),
        (
            ["report", "{tmp}"],
            "tron1cli.viz.campaign.campaign_phases",
            _CtrlC,
            "report interrupted: nothing written",
        ),
    ],
)
def test_ctrl_c_in_any_command_says_so(tiny_ckpt, tmp_path, monkeypatch, capsys, argv, target, stop, text):
    monkeypatch.setattr(target, stop)
    code = _run_main([a.format(ckpt=tiny_ckpt, tmp=tmp_path) for a in argv])
    err = capsys.readouterr().err
    assert code == 130 and err.count("\n") == 1 and err.startswith("error: ") and text in err, err


# -- 6. values that cannot be meant: exit 2, one line ----------------------------------------


@pytest.mark.parametrize(
    "args,text",
    [
        (
            ["eval", "{ckpt}", "--level", "-5", "--envs", "1", "--steps", "1", "--terrain", "flat"],
            "--level -5 outside 0..9 (or -1 for the hardest)",
        ),
        (["push-test", "{ckpt}", "--level", "-2", "--envs", "14", "--terrain", "flat"], "--level -2 outside"),
        (["deploy-sim", "{ckpt}", "--level", "-5", "--duration", "0.1"], "--level -5 outside"),
        (
            ["train", "--run-dir", "", "--iterations", "1", "--envs", "4", "--steps-per-env", "2"],
            "--run-dir' / '-o': an empty path",
        ),
        (
            ["eval", "{ckpt}", "--out", "", "--envs", "1", "--steps", "1", "--terrain", "flat"],
            "--out': an empty path",
        ),
        (
            ["export-onnx", "{ckpt}", "-o", "x.pt", "--parity-steps", "2"],
            "-o x.pt: an ONNX export's name ends in .onnx",
        ),
        (
            ["train", "--envs", "2", "--steps-per-env", "1", "--iterations", "1", "--run-dir", "r"],
            "--envs 2 x --steps-per-env 1 gives 2 samples",
        ),
    ],
)
def test_values_that_cannot_be_meant_are_refused(tiny_ckpt, tmp_path, args, text):
    r = tron1_in(tmp_path, *(a.format(ckpt=tiny_ckpt) for a in args))
    one_error_line(r, 2, text)
    assert list(tmp_path.iterdir()) == []  # nothing written into the current folder


def test_level_minus_one_is_still_the_hardest():
    from tron1cli.evaluation.protocol import check_level

    check_level(-1, 10)
    check_level(9, 10)
    for bad in (-2, -10, 10):
        with pytest.raises(ValueError, match="outside 0..9"):
            check_level(bad, 10)


def test_check_batch_accepts_the_smallest_batch_that_fills_every_minibatch():
    from dataclasses import replace

    from tron1cli.config import EnvConfig
    from tron1cli.learn import LearnerConfig
    from tron1cli.train.runner import RunConfig, check_batch

    learner = replace(LearnerConfig(), num_steps_per_env=2)
    check_batch(RunConfig(env=EnvConfig(num_envs=2), learner=learner))  # 4 samples, 4 minibatches
    with pytest.raises(ValueError, match="fewer than the 4 minibatches"):
        check_batch(RunConfig(env=EnvConfig(num_envs=3), learner=replace(learner, num_steps_per_env=1)))
