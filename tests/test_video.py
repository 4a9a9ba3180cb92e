"""``--video``: MP4s rendered by MuJoCo offscreen (OSMesa on a CPU machine) and encoded by PyAV."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tron1cli.viz.video import (
    check_video_path,
    frame_strip,
    gl_backends,
    parse_size,
    strip_indices,
    strip_path,
)

SHIPPED = Path(__file__).resolve().parents[1] / "policies" / "tron1_flat.onnx"


def tron1(*args: str, **env: str) -> subprocess.CompletedProcess:
    """The CLI in a subprocess, with ``env`` added to a bare environment."""
    return subprocess.run(
        [sys.executable, "-m", "tron1cli", *args],
        capture_output=True,
        text=True,
        timeout=600,
        env={"OMP_NUM_THREADS": "1", "PATH": os.environ.get("PATH", "/usr/bin:/bin"), **env},
    )


def decode(path: Path) -> tuple[list[np.ndarray], float]:
    """Every frame of an MP4 (RGB arrays) and its frame rate, decoded by PyAV."""
    import av

    with av.open(str(path)) as c:
        rate = float(c.streams.video[0].average_rate)
        frames = [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]
    return frames, rate


def test_deploy_sim_video(tmp_path):
    """One second of the shipped policy: 30 frames of 320 x 240 at 30 fps that change over time."""
    out = tmp_path / "walk.mp4"
    r = tron1(
        "deploy-sim",
        str(SHIPPED),
        "--duration",
        "1",
        "--video",
        str(out),
        "--video-size",
        "320x240",
        "--json",
    )
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["survived"] is True  # the report is untouched by the video
    assert "video: " in r.stderr and "ms a frame to render" in r.stderr
    frames, rate = decode(out)
    assert len(frames) == 30 and rate == 30.0
    assert frames[0].shape == (240, 320, 3)
    diffs = [float(np.abs(frames[k].astype(int) - frames[0]).mean()) for k in (10, 20, 29)]
    assert all(d > 1.0 for d in diffs), diffs  # the robot walks, the camera follows, the clock runs
    assert frames[15].std() > 20  # not a blank image: terrain, sky and robot
    from PIL import Image

    strip = np.asarray(Image.open(strip_path(out)))  # five frames, 0 to 29, at full size
    assert strip.shape == (240, 5 * 320, 3) and f"strip {tmp_path / 'walk.png'}" in r.stderr
    for j, k in enumerate(strip_indices(30)):  # each tile is its video frame (up to H.264's loss)
        assert np.abs(strip[:, j * 320 : (j + 1) * 320].astype(int) - frames[k]).mean() < 6.0


def test_strip_frames_and_layout():
    """First and last frame always in; a row per segment; scaled down, never up, to the width."""
    assert strip_indices(30) == [0, 7, 14, 22, 29]
    assert strip_indices(3) == [0, 1, 2] and strip_indices(1) == [0] and strip_indices(0) == []
    a = [np.full((40, 60, 3), v, np.uint8) for v in (10, 20, 30)]
    out = frame_strip([a, a[:2]], max_width=1000)  # 3 x 60 px fits: no scaling
    assert out.shape == (80, 180, 3)
    assert out[0, 0, 0] == 10 and out[0, 179, 0] == 30 and out[79, 61, 0] == 20
    assert (out[40:, 120:] == 255).all()  # the short row is padded white
    small = frame_strip([a], max_width=90)  # scaled by 0.5
    assert small.shape == (20, 90, 3) and small[10, 45, 0] == 20
    with pytest.raises(ValueError):
        frame_strip([[]])
    assert strip_path(Path("out/walk.mp4")) == Path("out/walk.png")


def test_missing_backend_is_one_line(tmp_path):
    """An OpenGL backend that cannot load (here OSMesa forced against PyOpenGL's EGL platform, the
    path a missing libosmesa6 takes): one line naming the package, exit 1, the report still out."""
    out = tmp_path / "walk.mp4"
    r = tron1(
        "deploy-sim",
        str(SHIPPED),
        "--duration",
        "0.2",
        "--video",
        str(out),
        "--json",
        MUJOCO_GL="osmesa",
        PYOPENGL_PLATFORM="egl",
    )
    assert r.returncode == 1
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "libosmesa6" in lines[0] and "Traceback" not in r.stderr, r.stderr
    assert json.loads(r.stdout)["policy_steps"] == 10  # the run's JSON was written first
    assert not out.exists()


def test_missing_backend_keeps_eval_outputs(tmp_path):
    r = tron1(
        "eval",
        str(SHIPPED),
        "--terrain",
        "flat",
        "--envs",
        "2",
        "--steps",
        "5",
        "--out",
        str(tmp_path / "ev"),
        "--video",
        str(tmp_path / "ev.mp4"),
        MUJOCO_GL="osmesa",
        PYOPENGL_PLATFORM="egl",
    )
    assert r.returncode == 1
    assert "libosmesa6" in r.stderr.strip().splitlines()[-1]
    assert "success_rate" in r.stdout  # the table was printed
    assert (tmp_path / "ev" / "results.json").is_file()


@pytest.mark.parametrize("args", [("--video", "walk.avi"), ("--video", "w.mp4", "--video-size", "641x480")])
def test_bad_video_options_exit_2(args):
    r = tron1("deploy-sim", str(SHIPPED), "--duration", "0.1", *args)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr


def test_options_and_backend_choice():
    assert parse_size("640x480") == (640, 480)
    for bad in ("640", "64x48", "641x480", "axb"):
        with pytest.raises(ValueError):
            parse_size(bad)
    with pytest.raises(ValueError):
        check_video_path(Path("x.gif"))
    assert gl_backends({"MUJOCO_GL": "EGL"}) == ["egl"]  # the user's choice, as it is
    assert gl_backends({})[-1] == "osmesa"  # software rendering is the last resort


def test_eval_films_each_speed_of_a_sweep(tmp_path):
    """``eval --speeds --video``: one take under the training commands, then one per speed asked,
    each as long as its batch (10 policy steps at 50 Hz: 6 frames at 30 fps)."""
    out = tmp_path / "ev.mp4"
    args = ("eval", str(SHIPPED), "--terrain", "flat", "--envs", "2", "--steps", "10")
    r = tron1(*args, "--speeds", "vx:0.3,0.6", "--video", str(out), "--video-size", "160x120")
    assert r.returncode == 0, r.stderr
    frames, _ = decode(out)
    assert len(frames) == 3 * 6


def test_only_a_fall_is_marked_fell_an_edge_end_holds_the_pose_unmarked(tmp_path):
    from tron1cli.viz.video import VideoRecorder, _View

    take = VideoRecorder(tmp_path / "v.mp4", fps=30).take([0, 1])
    pose = np.arange(13.0)
    z3, z6 = np.zeros(3), np.zeros(6)
    take.views = [_View(i, "", {}, [pose], [z3], [z3], [z6], [False]) for i in (0, 1)]
    take.frames = 1
    # both episodes end at 0.1 s (frames 1 and 2 are new): env 0 fell, env 1 reached the edge
    take.step(None, 0.1, done=np.array([True, True]), failed=np.array([True, False]))
    assert take.views[0].ended == [False, True, True]
    assert take.views[1].ended == [False, False, False]
    for v in take.views:  # the last pose is held either way, not the reset one
        assert all(np.array_equal(q, pose) for q in v.qpos)
