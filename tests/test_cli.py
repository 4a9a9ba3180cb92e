"""The ``tron1`` command as a user runs it: exit codes, one-line errors, JSON output."""

import json
import subprocess
import sys

import pytest


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


@pytest.mark.parametrize(
    "args",
    [
        ("bench", "--envs", "0"),
        ("bench", "--envs", "many"),
        ("bench", "--rounds", "0"),
        ("bench", "--bogus"),
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
