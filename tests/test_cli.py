"""The ``tron1`` command as a user runs it: exit codes, one-line errors, JSON output."""

import json
import os
import subprocess
import sys

import pytest
import torch


def tron1(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "tron1cli", *args], capture_output=True, text=True, timeout=300
    )


def test_version():
    r = tron1("--version")
    assert r.returncode == 0
    assert r.stdout.startswith("tron1 ")


def test_help_lists_only_working_commands():
    r = tron1("--help")
    assert r.returncode == 0
    assert "bench" in r.stdout


def test_help_shows_the_defaults_written_in_brackets():
    """Help texts spell computed defaults as "[default: ...]"; rich markup once ate them as tags."""
    r = subprocess.run(
        [sys.executable, "-m", "tron1cli", "train", "--help"],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "COLUMNS": "400"},
    )
    assert r.returncode == 0
    assert "[default: 512 on flat ground, 1024 elsewhere]" in r.stdout
    assert "[default: the cores available]" in r.stdout
    assert "[default: 256,128,64]" in r.stdout  # --hidden: the value every preset shares


_BEFORE_TORCH = """
import sys
from typer.testing import CliRunner
from tron1cli.cli.main import app
for args in {cases}:
    r = CliRunner().invoke(app, args)
    print(r.exit_code, "torch" in sys.modules, " ".join(r.output.split()))
"""


def _refusals_before_torch(cases: list[list[str]]) -> list[str]:
    """'<exit code> <torch imported> <output>' of each case, run in one fresh interpreter."""
    code = _BEFORE_TORCH.format(cases=repr(cases))
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return r.stdout.splitlines()


def test_a_missing_policy_is_refused_before_torch_is_imported(tmp_path):
    """A mistyped path costs no start-up: each command refuses it before importing torch."""
    missing = str(tmp_path / "nope.onnx")
    commands = ("eval", "push-test", "deploy-sim", "deploy-robot", "export-onnx")
    lines = _refusals_before_torch([[c, missing] for c in commands])
    assert len(lines) == len(commands)
    for line in lines:
        assert line.startswith("1 False") and "not found" in line and "nope.onnx" in line, line


def test_eval_options_are_refused_before_torch_is_imported(tmp_path):
    policy = tmp_path / "p.onnx"
    policy.write_bytes(b"not read before the options are checked")
    cases = [
        ["eval", str(policy), "--terrain", "lava"],
        ["eval", str(policy), "--actor", "ghost"],
        ["push-test", str(policy), "--terrain", "lava"],
        ["push-test", str(policy), "--watch", "shove"],
    ]
    lines = _refusals_before_torch(cases)
    assert [x[:7] for x in lines] == ["2 False"] * len(cases), lines
    assert "unknown terrain 'lava'" in lines[0] and "unknown --actor 'ghost'" in lines[1]


@pytest.mark.parametrize(
    "args",
    [
        ("bench", "--envs", "0"),
        ("bench", "--envs", "many"),
        ("bench", "--rounds", "0"),
        ("bench", "--bogus"),
        ("bench", "--train", "--precision", "fp16"),
        ("train", "--device", "tpu"),
        ("train", "--precision", "fp8"),
        ("no-such-command",),
    ],
)
def test_usage_errors_are_one_line_exit_2(args):
    r = tron1(*args)
    assert r.returncode == 2
    lines = [x for x in r.stderr.splitlines() if x.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:")
    assert "Traceback" not in r.stderr


def test_bench_json():
    r = tron1("bench", "--envs", "32", "--steps", "5", "--rounds", "3", "--json")
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    for key in ("raw_steps_per_s", "env_steps_per_s", "ratio", "num_envs"):
        assert key in res
    assert res["num_envs"] == 32 and res["rounds"] == 3
    assert res["raw_steps_per_s"] > 0 and 0 < res["ratio"] < 2
    lo, hi = res["ratio_spread"]
    assert lo <= res["ratio"] <= hi  # the ratio of medians lies within the per-round ratios
    assert res["unstable_resets"] == 0 and "warning" not in r.stderr  # a healthy engine


def test_bench_says_when_it_timed_resets_of_diverged_worlds(monkeypatch):
    """A bench whose env reset diverged worlds says so in one warning line (the warp clock bug
    found on the H200 on 2026-12-04 would have shown here: every world past 2 s was reset as unstable)."""
    from typer.testing import CliRunner

    import tron1cli.benchmark
    from tron1cli.cli.main import app

    real = tron1cli.benchmark.run_bench
    monkeypatch.setattr(
        tron1cli.benchmark, "run_bench", lambda *a, **k: {**real(*a, **k), "unstable_resets": 1234}
    )
    r = CliRunner().invoke(app, ["bench", "--envs", "8", "--steps", "2", "--rounds", "1", "--json"])
    assert r.exit_code == 0, r.output
    assert "warning: 1,234 worlds diverged and were reset during the bench" in r.output


def test_bench_train_json_splits_an_iteration_into_ratios_of_raw():
    r = tron1("bench", "--train", "--envs", "16", "--rounds", "2", "--threads", "1", "--json")
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    assert res["num_envs"] == 16 and res["rounds"] == 2 and res["nthread"] == 1
    assert res["terrain"] == "flat" and res["perception"] is False and res["precision"] == "fp32"
    assert res["epochs"] == 3  # the flat preset's PPO epochs, as train would use
    steps, raw = 16 * res["steps_per_env"], res["raw_steps_per_s"]
    assert res["collect_steps_per_s"] == pytest.approx(steps / res["collect_s"])
    assert res["learn_over_collect"] == pytest.approx(res["learn_s"] / res["collect_s"])
    for part in ("train", "collect", "learn"):
        assert res[f"{part}_ratio"] == pytest.approx(res[f"{part}_steps_per_s"] / raw)
        lo, hi = res[f"{part}_ratio_spread"]
        assert lo <= res[f"{part}_ratio"] <= hi
    assert res["train_steps_per_s"] < min(res["collect_steps_per_s"], res["learn_steps_per_s"])
    assert res["unstable_resets"] == 0


def test_bench_train_times_the_env_count_train_would_use(monkeypatch):
    from typer.testing import CliRunner

    import tron1cli.benchmark
    from tron1cli.cli.main import app
    from tron1cli.config.presets import flat, perceptive

    timed = []

    def record(cfg, **kwargs):  # stands in for the timing itself: the config is what is checked
        timed.append(cfg.env.num_envs)
        raise SystemExit(0)

    monkeypatch.setattr(tron1cli.benchmark, "run_train_bench", record)
    for args in ([], ["--terrain", "stairs"], ["--envs", "16"]):
        assert CliRunner().invoke(app, ["bench", "--train", *args]).exit_code == 0
    assert timed == [flat().num_envs, perceptive().num_envs, 16]


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a GPU")
def test_device_cuda_without_a_gpu_is_one_line():
    r = tron1("train", "--device", "cuda", "--iterations", "1")
    assert r.returncode == 2 and "torch sees no CUDA GPU" in r.stderr and "Traceback" not in r.stderr


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_train_on_cuda(tmp_path):
    r = tron1("train", "--device", "cuda", "--envs", "16", "--iterations", "1", "--run-dir", str(tmp_path))
    assert r.returncode == 0, r.stderr
