"""``--video`` picks an OpenGL backend that loads: EGL first (Mesa's EGL renders without a GPU),
then OSMesa; a user's ``MUJOCO_GL`` alone; one line naming the package when none loads."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tron1cli.viz import video
from tron1cli.viz.video import (
    BACKEND_MISSING_RC,
    GL_READY,
    VideoError,
    VideoRecorder,
    _View,
    gl_backends,
    gl_import_error,
)


def _recorder(path: Path, frames: int = 3, size: tuple[int, int] = (160, 120)) -> VideoRecorder:
    """A recording of the robot standing on a plane, made without an env."""
    from tron1cli.env import robot

    qpos = np.array(robot.load_spec().compile().qpos0, dtype=np.float64)
    qpos[2] = 0.83
    rec = VideoRecorder(path, size)
    take = rec.take([0], ["standing"], "a test")
    take.views = [
        _View(
            0,
            "standing",
            {"kind": "plane"},
            qpos=[qpos] * frames,
            cmd=[np.zeros(3)] * frames,
            vel=[np.zeros(3)] * frames,
            wrench=[np.zeros(6)] * frames,
            ended=[False] * frames,
        )
    ]
    take.frames = frames
    take.stop()
    return rec


class _FakeChild:
    """Stands in for ``subprocess.run`` of the render child: one answer per backend tried."""

    def __init__(self, answers: dict[str, tuple[int, str, str]]):
        self.answers = answers
        self.calls: list[dict[str, str]] = []

    def __call__(self, cmd, env, capture_output, text):
        self.calls.append(env)
        rc, out, err = self.answers[env["MUJOCO_GL"]]
        if rc == 0:
            Path(cmd[-1]).write_text(json.dumps({"backend": env["MUJOCO_GL"]}))
        return subprocess.CompletedProcess(cmd, rc, out, err)


NO_OSMESA = "AttributeError: 'NoneType' object has no attribute 'glGetError'"


def test_egl_is_tried_first_on_any_machine():
    """Mesa's EGL renders in software where no GPU is, so it is not kept for GPU machines."""
    assert gl_backends({}) == ["egl", "osmesa"]
    assert gl_backends({"MUJOCO_GL": " OSMesa "}) == ["osmesa"]  # the user's own, alone


def test_a_backend_that_does_not_load_moves_on_to_the_next(tmp_path, monkeypatch):
    monkeypatch.delenv("MUJOCO_GL", raising=False)
    child = _FakeChild(
        {"egl": (BACKEND_MISSING_RC, "", "RuntimeError: no EGL display"), "osmesa": (0, "", "")}
    )
    monkeypatch.setattr(video.subprocess, "run", child)
    st = _recorder(tmp_path / "walk.mp4").render()
    assert st["backend"] == "osmesa"
    assert [(c["MUJOCO_GL"], c["PYOPENGL_PLATFORM"]) for c in child.calls] == [
        ("egl", "egl"),
        ("osmesa", "osmesa"),
    ]


def test_a_crash_before_the_renderer_is_ready_moves_on(tmp_path, monkeypatch):
    monkeypatch.delenv("MUJOCO_GL", raising=False)
    child = _FakeChild({"egl": (-11, "", ""), "osmesa": (0, "", "")})
    monkeypatch.setattr(video.subprocess, "run", child)
    assert _recorder(tmp_path / "walk.mp4").render()["backend"] == "osmesa"


def test_a_failure_after_the_renderer_is_ready_is_an_error(tmp_path, monkeypatch):
    monkeypatch.delenv("MUJOCO_GL", raising=False)
    child = _FakeChild({"egl": (-11, GL_READY + "\n", ""), "osmesa": (0, "", "")})
    monkeypatch.setattr(video.subprocess, "run", child)
    with pytest.raises(VideoError, match="rendering failed") as e:
        _recorder(tmp_path / "walk.mp4").render()
    assert not e.value.backend_missing and len(child.calls) == 1


def test_no_backend_is_one_line_naming_both_packages(tmp_path, monkeypatch):
    monkeypatch.delenv("MUJOCO_GL", raising=False)
    child = _FakeChild(
        {
            "egl": (BACKEND_MISSING_RC, "", "ImportError: no libEGL"),
            "osmesa": (BACKEND_MISSING_RC, "", NO_OSMESA),
        }
    )
    monkeypatch.setattr(video.subprocess, "run", child)
    with pytest.raises(VideoError) as e:
        _recorder(tmp_path / "walk.mp4").render()
    msg = str(e.value)
    assert e.value.backend_missing and "\n" not in msg
    assert "libegl1" in msg and "libosmesa6" in msg and "MUJOCO_GL=egl" in msg and NO_OSMESA in msg


def test_the_users_backend_alone_and_its_package(tmp_path, monkeypatch):
    monkeypatch.setenv("MUJOCO_GL", "osmesa")
    monkeypatch.delenv("PYOPENGL_PLATFORM", raising=False)
    child = _FakeChild({"osmesa": (BACKEND_MISSING_RC, "", NO_OSMESA)})
    monkeypatch.setattr(video.subprocess, "run", child)
    with pytest.raises(VideoError) as e:
        _recorder(tmp_path / "walk.mp4").render()
    assert len(child.calls) == 1 and "PYOPENGL_PLATFORM" not in child.calls[0]
    msg = str(e.value)
    assert "apt-get install -y libosmesa6" in msg and "unset MUJOCO_GL" in msg and "libegl1" not in msg


def test_the_child_says_backend_missing_when_mujoco_cannot_import(tmp_path):
    """MuJoCo imports MUJOCO_GL's backend with itself (OSMesa without libosmesa6 raises there): the
    render child exits with the backend-missing code, not a traceback's exit 1."""
    code = (
        "import sys, runpy; sys.modules['mujoco'] = None; sys.argv = ['video', *sys.argv[1:]]; "
        "runpy.run_module('tron1cli.viz.video', run_name='__main__')"
    )
    args = [str(tmp_path / "job.npz"), str(tmp_path / "out.mp4"), str(tmp_path / "stats.json")]
    r = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=300)
    assert r.returncode == BACKEND_MISSING_RC, r.stderr
    assert "import of mujoco halted" in r.stderr.strip().splitlines()[-1], r.stderr


def test_a_broken_users_backend_at_import_is_one_line():
    """What ``tron1`` prints when a user's MUJOCO_GL names a backend MuJoCo cannot import."""
    where = os.path.join("site-packages", "mujoco", "osmesa", "__init__.py")
    with pytest.raises(AttributeError) as raised:
        exec(compile(f"raise AttributeError({NO_OSMESA.split(': ', 1)[1]!r})", where, "exec"))
    line = gl_import_error(raised.value, {"MUJOCO_GL": "osmesa"})
    assert line is not None and "\n" not in line
    assert line.startswith("MUJOCO_GL=osmesa") and "glGetError" in line and "libosmesa6" in line
    assert gl_import_error(raised.value, {}) is None  # no MUJOCO_GL of the user's: not this
    assert gl_import_error(AttributeError("elsewhere"), {"MUJOCO_GL": "osmesa"}) is None


def test_a_real_video_renders_with_a_backend_that_loads(tmp_path, monkeypatch):
    """Three frames through the real child: on a machine with Mesa's EGL and no libosmesa6 this
    renders with egl (osmesa alone failed there); where neither loads it is one line and a skip."""
    monkeypatch.delenv("MUJOCO_GL", raising=False)
    out = tmp_path / "stand.mp4"
    try:
        st = _recorder(out).render()
    except VideoError as e:
        if e.backend_missing:
            pytest.skip(str(e))
        raise
    assert st["frames"] == 3 and st["backend"] in ("egl", "osmesa")
    assert out.stat().st_size > 0 and Path(st["strip"]).is_file()
