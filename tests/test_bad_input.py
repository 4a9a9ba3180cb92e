"""Bad input, round 2 (issue 21): nothing lost, no non-finite policy shipped, one line for every
mistake, files written like any other. One section per class of the issue."""

from __future__ import annotations

import json
import math
import os
import stat
import subprocess
import sys
from pathlib import Path

import onnx
import pytest
import torch
from conftest import make_tiny_checkpoint, tron1

from tron1cli.errors import Tron1Error
from tron1cli.fileio import UMASK
from tron1cli.train.checkpoint import load_checkpoint, save_checkpoint

REPO = Path(__file__).resolve().parents[1]
FILE_MODE = 0o666 & ~UMASK


def one_error_line(r: subprocess.CompletedProcess, code: int, text: str = "") -> str:
    """The one stderr line of a refused command (nothing before it, no traceback)."""
    assert r.returncode == code, r.stderr
    assert r.stderr.count("\n") == 1 and r.stderr.startswith("error: "), repr(r.stderr)
    assert text in r.stderr, r.stderr
    return r.stderr


def rewrite(ckpt: Path, dest: Path, edit) -> Path:
    """A copy of checkpoint ``ckpt`` at ``dest`` with ``edit(state)`` applied."""
    state = load_checkpoint(ckpt)
    edit(state)
    save_checkpoint(dest, {k: v for k, v in state.items() if k not in ("format", "version")})
    return dest


def nan_weights(state: dict) -> None:
    model = state["learner"]["model"]
    name = next(k for k, v in model.items() if v.is_floating_point() and v.ndim == 2)
    model[name][0, 0] = float("nan")


@pytest.fixture(scope="module")
def onnx_file(tiny_ckpt, tmp_path_factory) -> Path:
    from tron1cli.policy.export import export_onnx

    return export_onnx(tiny_ckpt, tmp_path_factory.mktemp("onnx") / "p.onnx", parity_steps=5).path


def edited_onnx(src: Path, dest: Path, **fields) -> Path:
    """A copy of ``src`` with contract entries replaced (values JSON-encoded)."""
    model = onnx.load(str(src))
    for p in model.metadata_props:
        if p.key in fields:
            p.value = json.dumps(fields[p.key])
    onnx.save(model, str(dest))
    return dest


# -- 1. no command writes over its own input -------------------------------------------------


@pytest.mark.parametrize("same", ["{ckpt}", "{dir}/./{name}", "{dir}/link.pt"])
def test_export_refuses_to_write_over_its_checkpoint(tiny_ckpt, tmp_path, same):
    ckpt = tmp_path / "run.pt"
    ckpt.write_bytes(tiny_ckpt.read_bytes())
    (tmp_path / "link.pt").symlink_to(ckpt)
    before = ckpt.read_bytes()
    out = same.format(ckpt=ckpt, dir=tmp_path, name=ckpt.name)
    one_error_line(tron1("export-onnx", str(ckpt), "-o", out), 2, "would destroy it")
    assert ckpt.read_bytes() == before
    load_checkpoint(ckpt)  # the trained policy is still there


def test_export_over_an_existing_output_says_so(onnx_file, tiny_ckpt, tmp_path):
    out = tmp_path / "p.onnx"
    out.write_bytes(onnx_file.read_bytes())
    r = tron1("export-onnx", str(tiny_ckpt), "-o", str(out), "--parity-steps", "2", "--json")
    assert r.returncode == 0, r.stderr
    assert r.stderr == f"note: replaced the earlier {out}\n"


# -- 2. every output location is checked before the work -------------------------------------


@pytest.mark.parametrize(
    "args,text",
    [
        (["eval", "{ckpt}", "--out", "{file}"], "--out {file} is a file, not a folder"),
        (["eval", "{ckpt}", "--out", "{file}/sub"], "cannot make a folder there"),
        (["push-test", "{ckpt}", "--out", "{file}/sub"], "cannot make a folder there"),
        (["eval", "{ckpt}", "--rerun", "save={file}/x.rrd"], "cannot make a folder there"),
        (["deploy-sim", "{ckpt}", "--rerun", "save={file}/x.rrd"], "cannot make a folder there"),
        (["export-onnx", "{ckpt}", "-o", "{file}/x.onnx"], "cannot make a folder there"),
        (["export-onnx", "{ckpt}", "-o", "{tmp}"], "is a folder"),
        (["train", "--run-dir", "{file}"], "--run-dir {file} is a file"),
        (["train", "--run-dir", "{file}/run"], "cannot make a folder there"),
        (["train", "--rerun", "save={file}/x.rrd", "--run-dir", "{tmp}/r"], "cannot make a folder"),
    ],
)
def test_unusable_output_locations_are_refused_before_the_work(tiny_ckpt, tmp_path, args, text):
    blocker = tmp_path / "blocker.txt"
    blocker.write_text("in the way")
    fmt = {"ckpt": tiny_ckpt, "file": blocker, "tmp": tmp_path}
    r = tron1(*(a.format(**fmt) for a in args))
    one_error_line(r, 2, text.format(**fmt))
    assert blocker.read_text() == "in the way" and not (tmp_path / "r").exists()


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux's /proc")
def test_a_place_that_refuses_folders_is_refused_before_the_work(tmp_path):
    # os.access says yes for root everywhere; /proc still refuses a new folder
    r = tron1("train", "--run-dir", "/proc/tron1-run")
    one_error_line(r, 2, "--run-dir /proc/tron1-run: cannot create anything in /proc")


def test_the_writability_probe_leaves_nothing_behind(tmp_path):
    from tron1cli.fileio import check_output_dir

    assert check_output_dir(tmp_path / "a" / "b", "--out") is False
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "args,text",
    [
        (["--precision", "foo"], "--precision must be one of"),
        (["--learner", "foo=1"], "--learner: unknown or non-scalar learner setting 'foo'"),
        (["--run-dir", "{file}"], "is a file, not a folder"),
    ],
)
def test_train_refuses_bad_options_before_loading_torch(tmp_path, args, text):
    # the option checks alone refuse these: torch (2-3 s to import) is never loaded
    blocker = tmp_path / "blocker.txt"
    blocker.write_text("in the way")
    r = subprocess.run(
        [
            sys.executable,
            "-X",
            "importtime",
            "-m",
            "tron1cli",
            "train",
            *(a.format(file=blocker) for a in args),
        ],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )
    errors = [x for x in r.stderr.splitlines() if not x.startswith("import time:")]
    assert r.returncode == 2 and len(errors) == 1 and text in errors[0], r.stderr[-2000:]
    imported = {x.rsplit("|", 1)[-1].strip() for x in r.stderr.splitlines() if x.startswith("import time:")}
    assert "tron1cli.cli.train" in imported and "torch" not in imported


# -- 3. no non-finite policy ships; training that goes non-finite stops ------------------------


def test_export_refuses_non_finite_weights(tiny_ckpt, tmp_path):
    bad = rewrite(tiny_ckpt, tmp_path / "nan.pt", nan_weights)
    one_error_line(tron1("export-onnx", str(bad)), 1, "weights are not finite")
    assert not (tmp_path / "nan.onnx").exists()
    one_error_line(tron1("eval", str(bad), "--envs", "1", "--steps", "1"), 1, "not finite")


def test_parity_lets_no_nan_through(tiny_ckpt):
    import numpy as np

    from tron1cli.policy.export import parity
    from tron1cli.policy.runtime import load_policy

    ref, other = load_policy(tiny_ckpt), load_policy(tiny_ckpt)
    step = other.step
    other.step = lambda *a: tuple(np.full_like(x, np.nan) for x in step(*a))
    with pytest.raises(Tron1Error, match="not finite"):
        parity(ref, other, steps=2)


def test_onnx_with_non_finite_weights_is_refused(onnx_file, tmp_path):
    from onnx import numpy_helper

    from tron1cli.policy.runtime import load_policy

    model = onnx.load(str(onnx_file))
    init = next(i for i in model.graph.initializer if i.data_type == 1 and len(i.dims) == 2)
    arr = numpy_helper.to_array(init).copy()
    arr[0, 0] = math.inf
    init.CopyFrom(numpy_helper.from_array(arr, init.name))
    onnx.save(model, str(tmp_path / "inf.onnx"))
    with pytest.raises(Tron1Error, match="weights are not finite"):
        load_policy(tmp_path / "inf.onnx")


def _tiny_trainer(run_dir: Path, iterations: int, save_every: int):
    from dataclasses import replace

    from tron1cli.config import EnvConfig
    from tron1cli.learn import LearnerConfig
    from tron1cli.train.runner import RunConfig, Trainer

    env = EnvConfig(num_envs=4, nthread=1, depth_from=2)
    learner = replace(
        LearnerConfig(), num_steps_per_env=2, actor_hidden=(16,), critic_hidden=(16,), rec_batch_envs=2
    )
    return Trainer(run_dir, RunConfig(env=env, learner=learner, iterations=iterations, save_every=save_every))


def test_training_that_goes_non_finite_stops_and_resumes_from_the_last_good(tmp_path):
    from tron1cli.train.runner import NonFiniteTraining, Trainer

    trainer = _tiny_trainer(tmp_path, iterations=4, save_every=2)
    real = trainer.learner.update

    def poisoned(obs):
        stats = real(obs)
        if trainer.iteration == 2:  # the third update: a normaliser statistic goes NaN
            trainer.learner.model.norm_history.mean.fill_(math.nan)
        return stats

    trainer.learner.update = poisoned
    try:
        with pytest.raises(NonFiniteTraining, match=r"iteration 3 .*iteration 2\) is the last good"):
            trainer.run()
        with pytest.raises(NonFiniteTraining, match="not saving"):  # never over the good one
            trainer.save()
    finally:
        trainer.close()
    latest = tmp_path / "checkpoints" / "latest.pt"
    state = load_checkpoint(latest)
    assert state["iteration"] == 2
    assert all(torch.isfinite(v).all() for v in state["learner"]["model"].values() if v.is_floating_point())
    lines = (tmp_path / "metrics.jsonl").read_text().splitlines()
    assert [json.loads(x)["iteration"] for x in lines] == [1, 2]
    resumed = Trainer(tmp_path, resume=True)
    try:
        assert resumed.iteration == 2
        resumed.run()
    finally:
        resumed.close()
    assert load_checkpoint(latest)["iteration"] == 4
    lines = (tmp_path / "metrics.jsonl").read_text().splitlines()
    assert [json.loads(x)["iteration"] for x in lines] == [1, 2, 3, 4]


def test_a_non_finite_loss_stops_training(tmp_path):
    from tron1cli.train.runner import NonFiniteTraining

    trainer = _tiny_trainer(tmp_path, iterations=2, save_every=1)
    real = trainer.learner.update
    trainer.learner.update = lambda obs: {**real(obs), "value_loss": math.nan}
    try:
        with pytest.raises(NonFiniteTraining, match="value_loss is nan.*no checkpoint had been saved"):
            trainer.run()
    finally:
        trainer.close()
    assert not (tmp_path / "checkpoints" / "latest.pt").exists()


# -- 4. one line instead of a traceback ------------------------------------------------------


@pytest.mark.parametrize(
    "args,code,text",
    [
        (["export-onnx", "{empty}"], 1, "the file is empty"),
        (["eval", "{empty}"], 1, "the file is empty"),
        (["train", "--seed", "-1"], 2, "--seed"),
        (["eval", "{ckpt}", "--seed", "-1"], 2, "--seed"),
        (["push-test", "{ckpt}", "--seed", "-1"], 2, "--seed"),
        (["deploy-sim", "{ckpt}", "--seed", "-1"], 2, "--seed"),
        (["bench", "--seed", "-1"], 2, "--seed"),
        (["eval", "{ckpt}", "--level", "99"], 2, "--level 99 outside 0..9"),
        (["push-test", "{ckpt}", "--level", "99"], 2, "--level 99 outside 0..9"),
        (["push-test", "{ckpt}", "--level", "-11"], 2, "--level -11 outside 0..9"),
        (["bench", "--level", "99"], 2, "--level 99 outside 0..9"),
        (["eval", "{ckpt}", "--speeds", "nan"], 2, "not a finite number"),
        (["deploy-sim", "{ckpt}", "--depth-latency-ms", "inf"], 2, "inf is not a finite number"),
        (["train", "--critic-weights", "stable=nan"], 2, "stable=nan is not a finite number"),
        (["train", "--minutes", "nan"], 2, "--minutes"),
        (["export-onnx", "{ckpt}", "--tol", "nan"], 2, "--tol"),
    ],
)
def test_one_line_not_a_traceback(tiny_ckpt, tmp_path, args, code, text):
    (tmp_path / "empty.pt").write_bytes(b"")
    fmt = {"ckpt": tiny_ckpt, "empty": tmp_path / "empty.pt"}
    one_error_line(tron1(*(a.format(**fmt) for a in args)), code, text)


def test_deploy_robot_refuses_a_gait_frequency_before_connecting(onnx_file):
    one_error_line(
        tron1("deploy-robot", str(onnx_file), "--gait-freq", "2.6"), 2, "outside the trained range"
    )


@pytest.mark.parametrize(
    "fields,text",
    [
        ({"gru_hidden": 7}, "graph hidden has shape ['batch', 64], its contract says ['batch', 7]"),
        ({"kp_nm_per_rad": "NaN"}, "kp_nm_per_rad"),
        ({"torque_limit_nm": -1}, "torque_limit_nm = -1 is not a finite positive number"),
        ({"history_len": 4}, "history_len 4 disagrees"),
        ({"default_pose_rad": [0.0, 0.0]}, "default_pose_rad must hold 6"),
    ],
)
def test_onnx_contract_and_graph_are_checked_at_load(onnx_file, tmp_path, fields, text):
    from tron1cli.policy.runtime import load_policy

    bad = edited_onnx(onnx_file, tmp_path / "bad.onnx", **fields)
    with pytest.raises(Tron1Error) as e:
        load_policy(bad)
    assert text in str(e.value) and "\n" not in str(e.value)


def test_a_bad_onnx_is_one_line_through_the_cli(onnx_file, tmp_path):
    bad = edited_onnx(onnx_file, tmp_path / "bad.onnx", gru_hidden=7)
    one_error_line(tron1("deploy-sim", str(bad), "--duration", "0.1"), 1, "gru_hidden")


# -- 5. what cannot be meant is refused ------------------------------------------------------


@pytest.fixture(scope="module")
def saved_run(tmp_path_factory) -> Path:
    run = tmp_path_factory.mktemp("saved_run")
    make_tiny_checkpoint(run)
    return run


@pytest.mark.parametrize(
    "args,text",
    [
        (["--terrain", "stairs"], "--terrain stairs: the run in {run} was started with --terrain flat"),
        (["--envs", "16"], "was started with --envs 8"),
        (["--seed", "3"], "was started with --seed 0"),
        (["--hidden", "64"], "was started with --hidden 32"),
        (["--no-gait-prior"], "was started with --gait-prior"),
        (["--randomize"], "was started with --no-randomize"),
        (["--ablation", "single-critic"], "was started with --ablation none"),
        (["--terminate-on", "base"], "was started with --terminate-on base,thigh_L,thigh_R"),
    ],
)
def test_resume_refuses_an_option_the_saved_run_fixes(saved_run, args, text):
    before = (saved_run / "checkpoints" / "latest.pt").read_bytes()
    r = tron1("train", "--resume", *args, "--run-dir", str(saved_run))
    one_error_line(r, 2, text.format(run=saved_run))
    assert (saved_run / "checkpoints" / "latest.pt").read_bytes() == before


def test_resume_accepts_the_saved_values(saved_run):
    r = tron1(
        "train", "--resume", "--terrain", "flat", "--envs", "8", "--seed", "0",
        "--terminate-on", "thigh_R,base,thigh_L", "--run-dir", str(saved_run),
    )  # fmt: skip
    assert r.returncode == 0 and "complete at iteration 1" in r.stdout, r.stderr


@pytest.mark.parametrize(
    "args,text",
    [
        (["--teacher-ratio", "1.0"], "leaves no student env"),
        (["--teacher-ratio", "0.99", "--envs", "16"], "leaves no student env"),
        (["--randomize-skip", "lava"], "unknown randomisation terms ['lava']"),
        (["--init", "{run}/checkpoints/latest.pt"], "lies in this run's own checkpoints"),
    ],
)
def test_new_runs_that_cannot_be_meant_are_refused(saved_run, tmp_path, args, text):
    run = saved_run if "--init" in args else tmp_path / "r"
    fmt = {"run": saved_run}
    r = tron1("train", *(a.format(**fmt) for a in args), "--run-dir", str(run))
    one_error_line(r, 2, text)
    assert run == saved_run or not run.exists()


# -- 6. messages: exactly one line, nothing before it -----------------------------------------


def test_weight_shape_mismatch_is_one_line(tiny_ckpt, tmp_path):
    def widen(state):
        model = state["learner"]["model"]
        for name in [k for k, v in model.items() if v.ndim == 2][:2]:
            model[name] = torch.zeros(model[name].shape[0] + 1, model[name].shape[1])

    bad = rewrite(tiny_ckpt, tmp_path / "shape.pt", widen)
    line = one_error_line(tron1("export-onnx", str(bad)), 1, "weights of another shape")
    assert "and 1 more" in line


def test_pickled_objects_never_pass_on_torchs_advice(tmp_path):
    from fractions import Fraction

    p = tmp_path / "evil.pt"
    torch.save({"format": "tron1cli-checkpoint", "version": 1, "obj": Fraction(1, 3)}, p)
    with pytest.raises(Tron1Error) as e:
        load_checkpoint(p)
    assert "weights_only" not in str(e.value) and "pickled objects are never loaded" in str(e.value)


def _run_main(argv: list[str]) -> int:
    from tron1cli.cli import main as cli_main

    old = sys.argv
    sys.argv = ["tron1", *argv]
    try:
        cli_main.main()
    except SystemExit as e:
        return int(e.code)
    finally:
        sys.argv = old
    return 0


@pytest.mark.parametrize(
    "cmd,module,fn",
    [
        ("eval", "tron1cli.evaluation.protocol", "run_batch"),
        ("push-test", "tron1cli.evaluation.pushes", "run_push_test"),
    ],
)
def test_ctrl_c_says_what_was_written(tiny_ckpt, tmp_path, monkeypatch, capsys, cmd, module, fn):
    def interrupt(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(f"{module}.{fn}", interrupt)
    out = tmp_path / "out"
    code = _run_main([cmd, str(tiny_ckpt), "--envs", "14", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 130
    assert err.count("\n") == 1 and f"{cmd} interrupted after 0 of" in err, err
    assert f"no results written (--out {out} untouched)" in err and not out.exists()


# -- 7. hygiene: modes, stale temp files, MuJoCo's log ---------------------------------------


def test_written_files_follow_the_umask(onnx_file, tiny_ckpt, tmp_path):
    save_checkpoint(tmp_path / "c.pt", {"x": torch.zeros(1)})
    assert stat.S_IMODE((tmp_path / "c.pt").stat().st_mode) == FILE_MODE
    assert stat.S_IMODE(tiny_ckpt.stat().st_mode) == FILE_MODE
    assert stat.S_IMODE(onnx_file.stat().st_mode) == FILE_MODE
    out = tmp_path / "p.onnx"  # re-exporting over a file of another mode
    out.write_bytes(b"old")
    out.chmod(0o600)
    from tron1cli.policy.export import export_onnx

    export_onnx(tiny_ckpt, out, parity_steps=1)
    assert stat.S_IMODE(out.stat().st_mode) == FILE_MODE


def test_stale_temp_files_are_cleaned_at_the_next_start(saved_run, onnx_file, tiny_ckpt, tmp_path):
    from tron1cli.policy.export import export_onnx
    from tron1cli.train.runner import Trainer

    ckpts = saved_run / "checkpoints"
    stale = [ckpts / ".ckpt_00050.pt.k1ll3d.tmp", ckpts / ".latest.pt.abc123.tmp"]
    for p in stale:
        p.write_bytes(b"half a checkpoint")
    Trainer(saved_run, resume=True).close()
    assert not any(p.exists() for p in stale)
    assert (ckpts / "latest.pt").exists()
    old = tmp_path / ".p.onnx.zzz.tmp"
    other = tmp_path / ".q.onnx.zzz.tmp"  # another file's temp: left alone
    old.write_bytes(b"x")
    other.write_bytes(b"x")
    export_onnx(tiny_ckpt, tmp_path / "p.onnx", parity_steps=1)
    assert not old.exists() and other.exists()


def test_mujoco_warnings_are_one_line_on_stderr_and_no_log_file(tmp_path):
    code = (
        "import mujoco\n"
        "from tron1cli.cli.common import route_mujoco_warnings\n"
        "route_mujoco_warnings()\n"
        "m = mujoco.MjModel.from_xml_string('<mujoco><worldbody><body><freejoint/>"
        '<geom size=".1"/></body></worldbody></mujoco>\')\n'
        "for _ in range(2):\n"
        "    d = mujoco.MjData(m)\n"
        "    d.qpos[0] = float('nan')\n"
        "    mujoco.mj_step(m, d)\n"
    )
    r = subprocess.run(
        [sys.executable, "-c", code],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )
    assert r.returncode == 0, r.stderr
    assert r.stdout == "" and not (tmp_path / "MUJOCO_LOG.TXT").exists()
    assert r.stderr.count("\n") == 1 and r.stderr.startswith(
        "warning: MuJoCo: Nan, Inf or huge value in QPOS"
    )


def test_unknown_mujoco_gl_is_one_line_not_a_traceback():
    r = tron1("--version", env={"MUJOCO_GL": "bogus"}, timeout=120)
    lines = [x for x in r.stderr.splitlines() if x.strip()]
    assert r.returncode == 2 and len(lines) == 1 and "MUJOCO_GL: bogus" in lines[0], r.stderr
