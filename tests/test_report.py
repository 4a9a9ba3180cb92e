"""``tron1 report``: a run's or a campaign's progress from its metrics files alone."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tron1cli.viz.campaign import campaign_phases, campaign_table, read_metrics


def tron1(*args: str) -> subprocess.CompletedProcess:
    env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "COLUMNS": "80"}
    return subprocess.run(
        [sys.executable, "-m", "tron1cli", *args], capture_output=True, text=True, timeout=300, env=env
    )


def _run(d: Path, n: int, level0: float = 0.0) -> Path:
    d.mkdir()
    rows = [
        {
            "iteration": k,
            "wall_s": 60.0 * k,
            "env_steps": 10**5 * k,
            "student/survival": 0.1 * k,
            "terrain/level/stairs_up": level0 + k,
        }
        for k in range(1, n + 1)
    ]
    (d / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    return d


@pytest.fixture
def campaign(tmp_path) -> list[Path]:
    return [_run(tmp_path / "a", 3), _run(tmp_path / "b", 2, level0=3.0)]


def test_markdown_is_the_cards_table(campaign):
    r = tron1("report", *map(str, campaign), "--every-min", "2", "--smooth", "2", "--markdown")
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == campaign_table(campaign_phases(campaign), every_min=2.0, smooth=2)


def test_tables_figures_and_curves(campaign, tmp_path):
    png = tmp_path / "out" / "curves.png"
    args = ["--every-min", "2", "--smooth", "2", "--png", str(png), "--x", "env_steps"]
    r = tron1("report", *map(str, campaign), *args)
    assert r.returncode == 0, r.stderr
    assert "training" in r.stdout and "terrain level per type" in r.stdout
    assert "2 run directories, 5 iterations, 0.5 M env steps, 5 wall-clock minutes" in r.stdout
    # the last line (minute 5, phase 2, iteration 2): student survival mean of 0.1 and 0.2, stairs
    # up the mean of levels 4 and 5 within phase 2
    lines = [line.split() for line in r.stdout.splitlines() if line.strip().startswith("5 ")]
    assert ["5", "2", "2", "0.5", "-", "0.15"] == lines[0][:6] and lines[1][4] == "4.5"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and f"curves written to {png}" in r.stderr


def test_a_cut_off_last_line_is_left_out_and_a_corrupt_one_refused(tmp_path):
    run = _run(tmp_path / "r", 3)
    with open(run / "metrics.jsonl", "a") as f:
        f.write('{"iteration": 4, "wall')  # a run killed while writing
    assert [m["iteration"] for m in read_metrics(run)] == [1, 2, 3]
    text = (run / "metrics.jsonl").read_text().splitlines()
    (run / "metrics.jsonl").write_text("\n".join([text[0], "garbage", *text[1:]]))
    with pytest.raises(ValueError, match="line 2 is not JSON"):
        read_metrics(run)


@pytest.mark.parametrize(
    "make,code,text",
    [
        (lambda d: [str(d / "nowhere")], 1, "no metrics.jsonl (not a training run directory)"),
        (lambda d: [str(_run(d / "x", 0))], 1, "holds no iteration yet"),
        (lambda d: [str(_run(d / "x", 2)), "--png", str(d / "c.txt")], 2, "must end in .png"),
        (lambda d: [str(_run(d / "x", 2)), "--every-min", "0"], 2, "--every-min"),
        (lambda d: [str(_run(d / "x", 2)), "--x", "hours"], 2, "--x hours: must be one of minutes"),
    ],
)
def test_bad_input_is_one_line(tmp_path, make, code, text):
    r = tron1("report", *make(tmp_path))
    assert r.returncode == code and text in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
