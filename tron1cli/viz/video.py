"""MP4 videos of a few envs: recorded in the run's process, rendered by MuJoCo in a child process.

Recording (:class:`VideoRecorder`, :class:`Take`) reads the recorded envs' generalised positions,
command, measured velocity and external wrench after every policy step; it costs microseconds a
step and never touches OpenGL, so a run records whatever else it does (training never records).
At 30 fps a frame falls between two 50 Hz policy steps: positions are interpolated (joints and
base position linearly, the base quaternion by normalised lerp).

Rendering runs in a child process (``python -m tron1cli.viz.video JOB OUT``) because MuJoCo reads
``MUJOCO_GL`` once, when it is imported (and imports that OpenGL backend with itself), and the
run's process imported it long before: the child gets ``MUJOCO_GL`` set before its first import.
:func:`gl_backends` tries ``egl`` first (a GPU's driver, or Mesa's EGL, which renders in software
without a GPU: ``libegl1``), then ``osmesa`` (Mesa's software renderer, ``libosmesa6``); a
``MUJOCO_GL`` set by the user is the only one tried. A backend that cannot load in the child
(an exception while MuJoCo is imported or while its renderer is made, or a crash before the
child says the renderer is ready) moves on to the next; when none loads, one line says which
system package to install (:func:`no_backend_message`). Each view gets a copy of its env's ground (the
height field cropped to where the robot went) with a checker texture, a low sun so that step
edges shade, the left foot orange and the right foot blue, the commanded (green) and measured
(blue, mean over the last 0.5 s: about one gait cycle) planar velocity as arrows above the base,
a push as a magenta (force) or purple (torque) arrow while it acts, and a camera that follows the
base and, slowly, its heading. Frames are encoded to H.264 by PyAV (FFmpeg's libraries, in its
wheel). Beside the video goes a still strip (``walk.mp4`` -> ``walk.png``): per segment a row of
:data:`STRIP_FRAMES` frames evenly spaced from the first to the last, for a README or an issue.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tempfile
import traceback
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from tron1cli.env.core import Tron1Env

FPS = 30
DEFAULT_SIZE = (640, 480)  #: width, height of deploy-sim and eval videos (px)
GRID_SIZE = (1280, 960)  #: push-test: a 4 x 4 grid of 320 x 240 views
GRID_COLS = 4
CROP_MARGIN_M = 6.0  #: ground kept around the recorded trajectory (m): what the camera sees
#: what to install when a backend cannot be loaded (Debian / Ubuntu package names; Debian's
#: libegl1 pulls Mesa's EGL driver, libegl-mesa0, which renders in software where no GPU is)
BACKEND_PACKAGES = {
    "egl": "libegl1",
    "osmesa": "libosmesa6",
    "glx": "libglfw3 and a display",
    "glfw": "libglfw3 and a display",
}
BACKEND_MISSING_RC = 3  #: the render child's exit code when the OpenGL backend is unavailable
GL_READY = "tron1-video: renderer ready"  #: the child's stdout line once its first renderer is made
FOOT_RGBA = {"foot_L_geom": (1.0, 0.45, 0.05, 1.0), "foot_R_geom": (0.1, 0.45, 1.0, 1.0)}
CMD_RGBA = (0.16, 0.86, 0.31, 1.0)
VEL_RGBA = (0.16, 0.47, 1.0, 1.0)
PUSH_F_RGBA = (0.9, 0.12, 0.78, 1.0)
PUSH_T_RGBA = (0.6, 0.12, 0.9, 1.0)
SUN_DIR = np.array([0.5, 0.3, -0.81]) / np.linalg.norm([0.5, 0.3, -0.81])  #: a low sun: risers shade
STRIP_FRAMES = 5  #: frames per segment in the still strip written beside each video
STRIP_MAX_WIDTH = 1600  #: the strip's width limit (px): frames are scaled down to fit a row


class VideoError(Exception):
    """Rendering or encoding failed; ``backend_missing`` when no OpenGL backend could be loaded."""

    def __init__(self, message: str, backend_missing: bool = False) -> None:
        super().__init__(message)
        self.backend_missing = backend_missing


def parse_size(text: str) -> tuple[int, int]:
    """``"640x480"`` -> (640, 480); ValueError unless both are even and in 64..4096."""
    w, sep, h = text.lower().partition("x")
    try:
        size = (int(w), int(h))
    except ValueError:
        raise ValueError(f"--video-size wants WIDTHxHEIGHT, e.g. 640x480, got '{text}'") from None
    if not sep or not all(64 <= v <= 4096 and v % 2 == 0 for v in size):
        raise ValueError(f"--video-size {text}: width and height must be even numbers in 64..4096")
    return size


def check_video_path(path: Path) -> Path:
    """Refuse (ValueError) a path that does not end in .mp4."""
    if path.suffix.lower() != ".mp4" or not path.stem:
        raise ValueError(f"--video {path}: the file must end in .mp4, e.g. --video walk.mp4")
    return path


def gl_backends(environ: dict[str, str] | None = None) -> list[str]:
    """MUJOCO_GL values to try, in order: the user's own alone, else ``egl`` (a GPU's, or Mesa's
    software EGL where there is none), then ``osmesa``."""
    env = os.environ if environ is None else environ
    user = env.get("MUJOCO_GL", "").strip().lower()
    return [user] if user else ["egl", "osmesa"]


def _install_hint(backend: str) -> str:
    """What to install for ``backend`` (a Debian / Ubuntu package and its apt-get line)."""
    pkg = BACKEND_PACKAGES.get(backend)
    if pkg is None:
        return "install an OpenGL library MuJoCo can use"
    return f"install {pkg} (e.g. apt-get install -y {pkg.split()[0]})"


def no_backend_message(tried: Sequence[str], user_set: bool, backend: str = "") -> str:
    """The one line for a video no OpenGL backend could render: what each try said and which
    system package to install (``backend``: the user's MUJOCO_GL when ``user_set``)."""
    if user_set:
        hint = f"{_install_hint(backend)}, or unset MUJOCO_GL to let tron1 try egl, then osmesa"
    else:
        hint = (
            "install libegl1 (Mesa's EGL, which renders without a GPU too) or libosmesa6, "
            "e.g. apt-get install -y libegl1"
        )
    return f"--video: MuJoCo could not render offscreen ({'; '.join(tried)}); {hint}"


def _is_gl_import(filename: str) -> bool:
    parts = Path(filename).parts
    return "mujoco" in parts and (
        parts[-1] == "gl_context.py" or any(p in parts for p in ("osmesa", "egl", "glfw", "cgl"))
    )


def gl_import_error(exc: BaseException, environ: dict[str, str] | None = None) -> str | None:
    """The one line for ``exc`` when it was raised while MuJoCo imported the OpenGL backend that a
    user's ``MUJOCO_GL`` names (MuJoCo imports it with itself: OSMesa without libosmesa6 raises
    ``AttributeError: 'NoneType' object has no attribute 'glGetError'`` there); None otherwise."""
    env = os.environ if environ is None else environ
    backend = env.get("MUJOCO_GL", "").strip().lower()
    tb = traceback.extract_tb(exc.__traceback__)
    if not backend or not any(_is_gl_import(f.filename) for f in tb):
        return None
    what = (str(exc).splitlines() or [""])[0]
    return (
        f"MUJOCO_GL={backend}: MuJoCo cannot load this OpenGL backend ({type(exc).__name__}: {what}); "
        f"{_install_hint(backend)}, or unset MUJOCO_GL"
    )


# ---------------------------------------------------------------------------------------------
# Recording (the run's process: no OpenGL)


def _ground(env: Tron1Env, i: int) -> dict[str, Any]:
    """A copy of env ``i``'s ground: a plane, or its height field (normalised data, size, z)."""
    m = env.physics.models[i]
    if m.nhfield == 0:
        return {"kind": "plane"}
    return {
        "kind": "hfield",
        "nrow": int(m.hfield_nrow[0]),
        "ncol": int(m.hfield_ncol[0]),
        "size": [float(v) for v in m.hfield_size[0]],
        "z": float(m.geom("ground").pos[2]),
        "data": np.array(m.hfield_data, dtype=np.float32),
    }


def _crop(ground: dict[str, Any], xy: np.ndarray, margin: float = CROP_MARGIN_M) -> dict[str, Any]:
    """The part of a height field within ``margin`` m of the points ``xy`` (n, 2), centre ``pos``."""
    if ground["kind"] != "hfield":
        return ground
    nrow, ncol = ground["nrow"], ground["ncol"]
    rx, ry = ground["size"][0], ground["size"][1]
    dx, dy = 2 * rx / (ncol - 1), 2 * ry / (nrow - 1)
    j0 = max(0, int(math.floor((xy[:, 0].min() - margin + rx) / dx)))
    j1 = min(ncol - 1, int(math.ceil((xy[:, 0].max() + margin + rx) / dx)))
    i0 = max(0, int(math.floor((xy[:, 1].min() - margin + ry) / dy)))
    i1 = min(nrow - 1, int(math.ceil((xy[:, 1].max() + margin + ry) / dy)))
    data = ground["data"].reshape(nrow, ncol)[i0 : i1 + 1, j0 : j1 + 1]
    out = dict(ground, nrow=i1 - i0 + 1, ncol=j1 - j0 + 1, data=np.ascontiguousarray(data).ravel())
    out["size"] = [(j1 - j0) * dx / 2, (i1 - i0) * dy / 2, *ground["size"][2:]]
    out["pos"] = [-rx + (j0 + j1) * dx / 2, -ry + (i0 + i1) * dy / 2]
    return out


@dataclass
class _View:
    """One recorded env: its ground and, per frame, qpos, command and velocity (world), wrench."""

    env: int
    label: str
    ground: dict[str, Any]
    qpos: list[np.ndarray] = field(default_factory=list)
    cmd: list[np.ndarray] = field(default_factory=list)
    vel: list[np.ndarray] = field(default_factory=list)
    wrench: list[np.ndarray] = field(default_factory=list)
    ended: list[bool] = field(default_factory=list)  # per frame: the env has fallen (FELL shown)
    done: bool = False
    fell: bool = False
    last: tuple[float, np.ndarray] | None = None  # (t, qpos) of the last policy-step sample


def _world_command(env: Tron1Env, i: int) -> np.ndarray:
    from tron1cli.env.math3d import yaw_of

    yaw = float(yaw_of(env.state.base_quat[i : i + 1])[0])
    c, s = math.cos(yaw), math.sin(yaw)
    v = env.commands.value[i]
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1], float(v[2])])


def _trailing_mean(x: np.ndarray, n: int) -> np.ndarray:
    """Mean of each row of ``x`` (F, d) and the ``n - 1`` before it (fewer at the start)."""
    c = np.cumsum(np.vstack([np.zeros((1, x.shape[1])), x]), axis=0)
    k = np.arange(1, len(x) + 1)
    lo = np.maximum(k - n, 0)
    return (c[k] - c[lo]) / (k - lo)[:, None]


def _lerp_qpos(a: np.ndarray, b: np.ndarray, w: float) -> np.ndarray:
    q = a + w * (b - a)
    qa, qb = a[3:7], b[3:7]
    qb = qb if float(np.dot(qa, qb)) >= 0 else -qb
    quat = qa + w * (qb - qa)
    q[3:7] = quat / np.linalg.norm(quat)
    return q


class Take:
    """One segment of the video: envs ``envs`` of one batch, shown side by side (a grid when more
    than one), from :meth:`start` (after the env's reset) to :meth:`stop`."""

    def __init__(self, recorder: VideoRecorder, envs: Sequence[int], labels: Sequence[str], caption: str):
        self.recorder = recorder
        self.envs = [int(e) for e in envs]
        self.labels = list(labels)
        self.caption = caption
        self.views: list[_View] = []
        self.frames = 0

    def start(self, env: Tron1Env) -> None:
        """Snapshot each view's ground and its state at t = 0 (the first frame's)."""
        self.views = [_View(i, lab, _ground(env, i)) for i, lab in zip(self.envs, self.labels, strict=True)]
        self._sample(env, 0.0, None)

    def step(
        self, env: Tron1Env, t_s: float, done: np.ndarray | None = None, failed: np.ndarray | None = None
    ) -> None:
        """After a policy step ending at ``t_s`` (s): frames up to ``t_s``; ``done`` (N,) ends views
        whose episode ended (their last pose is held), ``failed`` (N,) marks those of them that fell
        (``FELL``), not those that reached the tile's edge."""
        self._sample(env, t_s, done, failed)

    def _sample(
        self, env: Tron1Env, t_s: float, done: np.ndarray | None, failed: np.ndarray | None = None
    ) -> None:
        fps = self.recorder.fps
        n_new = max(0, int(math.ceil(t_s * fps - 1e-6)) - self.frames)  # frames at k / fps < t_s
        for v in self.views:
            if not v.done and done is not None and bool(done[v.env]):
                v.done = True  # the state now is the reset one: hold the last pose
                v.fell = failed is not None and bool(failed[v.env])
            if v.done:
                for _ in range(n_new):
                    v.qpos.append(v.qpos[-1])
                    v.cmd.append(v.cmd[-1])
                    v.vel.append(np.zeros(3))
                    v.wrench.append(np.zeros(6))
                    v.ended.append(v.fell)
                continue
            q = np.array(env.physics.qpos[v.env], dtype=np.float64)
            cmd = _world_command(env, v.env)
            vel = np.array(env.state.base_lin_vel_w[v.env], dtype=np.float64)
            wrench = np.array(env.external_wrench[v.env], dtype=np.float64)
            for k in range(self.frames, self.frames + n_new):
                t_f = k / fps
                if v.last is None or t_s <= v.last[0]:
                    qf = q
                else:
                    t0, q0 = v.last
                    qf = _lerp_qpos(q0, q, min(1.0, max(0.0, (t_f - t0) / (t_s - t0))))
                v.qpos.append(qf)
                v.cmd.append(cmd)
                v.vel.append(vel)
                v.wrench.append(wrench)
                v.ended.append(False)
            v.last = (t_s, q)
        self.frames += n_new

    def stop(self) -> None:
        """End the segment (it joins the recorder's video)."""
        if self.frames and self not in self.recorder.takes:
            self.recorder.takes.append(self)


class VideoRecorder:
    """Segments (:class:`Take`) of one video, rendered to ``path`` by :meth:`render`.

    ``size``: frame width, height (px; a take of several envs splits it into a grid of
    :data:`GRID_COLS` columns).
    """

    def __init__(self, path: Path, size: tuple[int, int] = DEFAULT_SIZE, fps: int = FPS) -> None:
        self.path = Path(path)
        self.size = size
        self.fps = fps
        self.takes: list[Take] = []

    def take(self, envs: Sequence[int], labels: Sequence[str] | None = None, caption: str = "") -> Take:
        return Take(self, envs, labels or [""] * len(envs), caption)

    @property
    def frames(self) -> int:
        return sum(t.frames for t in self.takes)

    def write_job(self, job: Path) -> None:
        """The recording as one .npz: a JSON ``meta`` and per view its frame arrays."""
        arrays: dict[str, np.ndarray] = {}
        segments = []
        for s, take in enumerate(self.takes):
            views = []
            for j, v in enumerate(take.views):
                qpos = np.asarray(v.qpos[: take.frames])
                ground = _crop(v.ground, qpos[:, :2])
                key = f"s{s}v{j}"
                if ground["kind"] == "hfield":
                    arrays[key + "_hfield"] = ground["data"]
                views.append({"label": v.label, "ground": {k: g for k, g in ground.items() if k != "data"}})
                arrays[key + "_qpos"] = qpos
                arrays[key + "_cmd"] = np.asarray(v.cmd[: take.frames])
                arrays[key + "_vel"] = _trailing_mean(np.asarray(v.vel[: take.frames]), self.fps // 2)
                arrays[key + "_wrench"] = np.asarray(v.wrench[: take.frames])
                arrays[key + "_ended"] = np.asarray(v.ended[: take.frames])
            segments.append({"caption": take.caption, "frames": take.frames, "views": views})
        meta = {"size": list(self.size), "fps": self.fps, "segments": segments}
        np.savez(job, meta=np.array(json.dumps(meta)), **arrays)

    def render(self, backends: list[str] | None = None) -> dict[str, Any]:
        """Render and encode the video in a child process; returns its figures (frames, size,
        backend, ms per frame for rendering and for encoding). Raises :class:`VideoError`."""
        if not self.frames:
            raise VideoError("--video: nothing was recorded")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise VideoError(f"--video {self.path}: cannot make its folder ({e.strerror or e})") from e
        user_set = bool(os.environ.get("MUJOCO_GL", "").strip())
        backends = backends or gl_backends()
        tried: list[str] = []
        with tempfile.TemporaryDirectory(prefix="tron1-video-") as tmp:
            job, stats = Path(tmp) / "job.npz", Path(tmp) / "stats.json"
            self.write_job(job)
            for backend in backends:
                env = dict(os.environ, MUJOCO_GL=backend)
                if not user_set:  # ours to choose: PyOpenGL follows it
                    env["PYOPENGL_PLATFORM"] = backend
                proc = subprocess.run(
                    [sys.executable, "-m", "tron1cli.viz.video", str(job), str(self.path), str(stats)],
                    env=env,
                    capture_output=True,
                    text=True,
                )
                if proc.returncode == 0:
                    return json.loads(stats.read_text())
                last = (proc.stderr.strip().splitlines() or [f"exit code {proc.returncode}"])[-1]
                # the backend did not load: the child said so, or died of a signal before its
                # renderer was made (a GL driver that crashes on start)
                gl_failed = proc.returncode == BACKEND_MISSING_RC or (
                    proc.returncode < 0 and GL_READY not in (proc.stdout or "")
                )
                if not gl_failed:
                    raise VideoError(f"--video {self.path}: rendering failed (MUJOCO_GL={backend}): {last}")
                tried.append(f"MUJOCO_GL={backend}: {last}")
        raise VideoError(no_backend_message(tried, user_set, backends[-1]), backend_missing=True)


# ---------------------------------------------------------------------------------------------
# Rendering (the child process: MUJOCO_GL is set before mujoco is imported)


def _video_model(ground: dict[str, Any], size: tuple[int, int]):
    """The robot on a copy of ``ground``: checker-textured, a low sun (no shadows), the feet coloured."""
    import mujoco

    from tron1cli.env import robot

    spec = robot.load_spec()
    spec.visual.global_.offwidth = max(size[0], 64)
    spec.visual.global_.offheight = max(size[1], 64)
    spec.visual.headlight.ambient = [0.3, 0.3, 0.3]
    spec.visual.headlight.diffuse = [0.25, 0.25, 0.25]
    for light in spec.worldbody.lights:  # the model's sun, from straight above: lower it
        light.dir = SUN_DIR
        light.diffuse = [0.85, 0.85, 0.8]
        light.castshadow = False  # a shadow pass doubles the software render time
    for g in spec.geoms:
        if g.name in FOOT_RGBA:
            g.rgba = FOOT_RGBA[g.name]
    spec.add_texture(
        name="sky",
        type=mujoco.mjtTexture.mjTEXTURE_SKYBOX,
        builtin=mujoco.mjtBuiltin.mjBUILTIN_GRADIENT,
        rgb1=[0.55, 0.7, 0.88],
        rgb2=[0.95, 0.96, 0.98],
        width=64,
        height=64,
    )
    spec.add_texture(
        name="checker",
        type=mujoco.mjtTexture.mjTEXTURE_2D,
        builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER,
        rgb1=[0.72, 0.74, 0.7],
        rgb2=[0.52, 0.56, 0.52],
        mark=mujoco.mjtMark.mjMARK_EDGE,
        markrgb=[0.35, 0.37, 0.35],
        width=256,
        height=256,
    )
    # one checker square per metre of texture repeat unit: 2 squares a repeat, so 0.5 m squares
    spec.add_material(name="ground", textures=["", "checker"], texrepeat=[1, 1], texuniform=True)
    style = dict(name="ground", material="ground", rgba=[1, 1, 1, 1], contype=0, conaffinity=0)
    if ground["kind"] == "plane":
        spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 1], **style)
        return spec.compile()
    nrow, ncol = ground["nrow"], ground["ncol"]
    spec.add_hfield(
        name="terrain", nrow=nrow, ncol=ncol, size=ground["size"], userdata=np.zeros(nrow * ncol).tolist()
    )
    x, y = ground.get("pos", (0.0, 0.0))
    below = dict(style, name="below")  # beyond the cropped field: a plane at its lowest level
    spec.worldbody.add_geom(
        type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 1], pos=[0, 0, ground["z"] - 0.03], **below
    )
    spec.worldbody.add_geom(
        type=mujoco.mjtGeom.mjGEOM_HFIELD, hfieldname="terrain", pos=[x, y, ground["z"]], **style
    )
    return spec.compile()


class _Camera:
    """A free camera on the base, smoothed (0.3 s in position, 2 s in heading), 3/4 from the left."""

    def __init__(self, mujoco: Any, distance: float) -> None:
        self.cam = mujoco.MjvCamera()
        self.cam.type = mujoco.mjtCamera.mjCAMERA_FREE
        self.cam.distance = distance
        self.cam.elevation = -18.0
        self.lookat: np.ndarray | None = None
        self.yaw = 0.0

    def follow(self, qpos: np.ndarray, dt: float) -> Any:
        base = np.array(qpos[:3]) - np.array([0.0, 0.0, 0.3])
        w, x, y, z = qpos[3:7]
        yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        if self.lookat is None:
            self.lookat, self.yaw = base, yaw
        else:
            self.lookat = self.lookat + (1 - math.exp(-dt / 0.3)) * (base - self.lookat)
            d = math.atan2(math.sin(yaw - self.yaw), math.cos(yaw - self.yaw))
            self.yaw += (1 - math.exp(-dt / 2.0)) * d
        self.cam.lookat[:] = self.lookat
        self.cam.azimuth = math.degrees(self.yaw) - 115.0
        return self.cam


def _arrow(mujoco: Any, scn: Any, a: np.ndarray, b: np.ndarray, width: float, rgba: tuple) -> None:
    if scn.ngeom >= scn.maxgeom or float(np.linalg.norm(b - a)) < 1e-3:
        return
    g = scn.geoms[scn.ngeom]
    mujoco.mjv_initGeom(
        g,
        mujoco.mjtGeom.mjGEOM_ARROW,
        np.zeros(3),
        np.zeros(3),
        np.eye(3).ravel(),
        np.asarray(rgba, np.float32),
    )
    mujoco.mjv_connector(g, mujoco.mjtGeom.mjGEOM_ARROW, width, a, b)
    scn.ngeom += 1


def _overlays(mujoco: Any, scn: Any, qpos: np.ndarray, cmd: np.ndarray, vel: np.ndarray, wrench: np.ndarray):
    """Velocity arrows above the base (1 m per m/s; command 0.2 m, measured 0.12 m above the base
    origin), the push at the base while it acts."""
    base = np.array(qpos[:3])
    for dz, v, rgba in ((0.2, cmd, CMD_RGBA), (0.12, vel, VEL_RGBA)):
        top = base + np.array([0.0, 0.0, dz])
        _arrow(mujoco, scn, top, top + np.array([v[0], v[1], 0.0]), 0.03, rgba)
    f, tq = wrench[:3], wrench[3:]
    if np.linalg.norm(f) > 0:  # a force: a 0.6 m arrow pointing at the base
        u = f / np.linalg.norm(f)
        _arrow(mujoco, scn, base - 0.75 * u, base - 0.12 * u, 0.04, PUSH_F_RGBA)
    if np.linalg.norm(tq) > 0:  # a torque: a 0.5 m arrow along its axis
        u = tq / np.linalg.norm(tq)
        _arrow(mujoco, scn, base, base + 0.5 * u, 0.03, PUSH_T_RGBA)


def _font(px: int):
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=px)
    except TypeError:  # Pillow < 10.1: a fixed bitmap font
        return ImageFont.load_default()


def _text(
    img: np.ndarray, lines: list[tuple[str, tuple[int, int, int]]], px: int, at: str = "top", lift: int = 0
) -> np.ndarray:
    """``lines`` (text, RGB) drawn at the top left, or at the bottom left ``lift`` px up."""
    from PIL import Image, ImageDraw

    im = Image.fromarray(img)
    d = ImageDraw.Draw(im)
    font = _font(px)
    y = 4 if at == "top" else img.shape[0] - 4 - lift - len(lines) * (px + 3)
    for text, color in lines:
        d.text((6, y), text, fill=color, font=font, stroke_width=2, stroke_fill=(20, 20, 20))
        y += px + 3
    return np.asarray(im)


def _legend(img: np.ndarray, px: int) -> np.ndarray:
    items = [
        ("command", CMD_RGBA),
        ("measured", VEL_RGBA),
        ("push", PUSH_F_RGBA),
        ("left foot", FOOT_RGBA["foot_L_geom"]),
        ("right foot", FOOT_RGBA["foot_R_geom"]),
    ]
    from PIL import Image, ImageDraw

    im = Image.fromarray(img)
    d = ImageDraw.Draw(im)
    font = _font(px)
    x, y = 6, img.shape[0] - px - 6
    for name, rgba in items:
        c = tuple(int(255 * v) for v in rgba[:3])
        d.rectangle([x, y + 2, x + px - 2, y + px], fill=c)
        d.text(
            (x + px + 2, y), name, fill=(240, 240, 240), font=font, stroke_width=2, stroke_fill=(20, 20, 20)
        )
        x += px + 8 + int(d.textlength(name, font=font))
    return np.asarray(im)


def _view_text(
    label: str, t: float, cmd: np.ndarray, vel: np.ndarray, wrench: np.ndarray, ended: bool
) -> list[tuple[str, tuple[int, int, int]]]:
    lines = [(f"{label}  t = {t:4.2f} s" if label else f"t = {t:5.2f} s", (245, 245, 245))]
    lines.append((f"cmd {math.hypot(cmd[0], cmd[1]):.2f} m/s, yaw {cmd[2]:+.2f} rad/s", (120, 235, 140)))
    lines.append((f"measured {math.hypot(vel[0], vel[1]):.2f} m/s (0.5 s mean)", (130, 175, 255)))
    if np.any(wrench[:3]):
        lines.append((f"push {np.linalg.norm(wrench[:3]):.0f} N", (240, 110, 220)))
    if np.any(wrench[3:]):
        lines.append((f"push {np.linalg.norm(wrench[3:]):.1f} N m", (200, 130, 255)))
    if ended:
        lines.append(("FELL", (255, 80, 80)))
    return lines


def strip_path(video: Path) -> Path:
    """Where the still strip of ``video`` goes: the same name with ``.png``."""
    return Path(video).with_suffix(".png")


def strip_indices(frames: int, n: int = STRIP_FRAMES) -> list[int]:
    """Up to ``n`` frame indices evenly spaced over ``frames`` frames, the first and last included."""
    if frames <= 0:
        return []
    return sorted({int(i) for i in np.linspace(0, frames - 1, min(n, frames)).round()})


def frame_strip(rows: list[list[np.ndarray]], max_width: int = STRIP_MAX_WIDTH) -> np.ndarray:
    """Tile frames (each (H, W, 3) uint8, all one size) into one image: a row per list, left to
    right, scaled by one factor so that the widest row fits ``max_width`` px (never enlarged)."""
    from PIL import Image

    rows = [r for r in rows if r]
    if not rows:
        raise ValueError("frame_strip needs at least one frame")
    h, w = rows[0][0].shape[:2]
    cols = max(len(r) for r in rows)
    scale = min(1.0, max_width / (cols * w))
    tw, th = max(1, round(w * scale)), max(1, round(h * scale))
    out = np.full((th * len(rows), tw * cols, 3), 255, np.uint8)
    for i, row in enumerate(rows):
        for j, f in enumerate(row):
            img = f if (tw, th) == (w, h) else np.asarray(Image.fromarray(f).resize((tw, th), Image.LANCZOS))
            out[i * th : (i + 1) * th, j * tw : (j + 1) * tw] = img
    return out


def render_job(job: Path, out: Path, stats: Path) -> None:
    """Render a recording (:meth:`VideoRecorder.write_job`) to ``out`` (H.264 MP4) and write its
    figures to ``stats``. Exits :data:`BACKEND_MISSING_RC` when the OpenGL backend ``MUJOCO_GL``
    names cannot be loaded (MuJoCo imports it with itself) or no context can be made."""
    import time

    import av

    try:  # the run's process imported mujoco already: what fails here is MUJOCO_GL's backend
        import mujoco
    except Exception as e:  # e.g. OSMesa without libosmesa6: AttributeError from PyOpenGL
        print(f"{type(e).__name__}: {(str(e).splitlines() or [''])[0]}", file=sys.stderr)
        sys.exit(BACKEND_MISSING_RC)

    z = np.load(job)
    meta = json.loads(str(z["meta"]))
    width, height = meta["size"]
    fps = int(meta["fps"])
    segments = meta["segments"]
    render_s = encode_s = 0.0
    frames = 0
    strip_rows: list[list[np.ndarray]] = []
    with av.open(str(out), "w") as container:
        codec = "libx264" if "libx264" in av.codecs_available else "mpeg4"
        stream = container.add_stream(codec, rate=fps)
        stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
        if codec == "libx264":
            stream.options = {"crf": "23", "preset": "veryfast"}
        for s, seg in enumerate(segments):
            n_views = len(seg["views"])
            cols = 1 if n_views == 1 else GRID_COLS
            rows = -(-n_views // cols)
            tw, th = (width // cols) & ~1, (height // rows) & ~1
            px = max(10, th // 26)
            views = []
            keep = set(strip_indices(seg["frames"]))
            strip_rows.append([])
            for j, v in enumerate(seg["views"]):
                key = f"s{s}v{j}"
                model = _video_model(v["ground"], (tw, th))
                if v["ground"]["kind"] == "hfield":
                    model.hfield_data[:] = z[key + "_hfield"]
                try:
                    r = mujoco.Renderer(model, th, tw)
                except Exception as e:  # the GL backend: ImportError, RuntimeError, GLError, ...
                    print(f"{type(e).__name__}: {(str(e).splitlines() or [''])[0]}", file=sys.stderr)
                    sys.exit(BACKEND_MISSING_RC)
                if s == 0 and j == 0:
                    print(GL_READY, flush=True)
                arrays = {k: z[f"{key}_{k}"] for k in ("qpos", "cmd", "vel", "wrench", "ended")}
                views.append((v["label"], model, mujoco.MjData(model), r, _Camera(mujoco, 2.4), arrays))
            try:
                for k in range(seg["frames"]):
                    t0 = time.perf_counter()
                    frame = np.zeros((height, width, 3), np.uint8)
                    for j, (label, model, data, r, cam, a) in enumerate(views):
                        data.qpos[:] = a["qpos"][k]
                        mujoco.mj_kinematics(model, data)
                        r.update_scene(data, camera=cam.follow(a["qpos"][k], 1.0 / fps))
                        _overlays(mujoco, r.scene, a["qpos"][k], a["cmd"][k], a["vel"][k], a["wrench"][k])
                        img = r.render()
                        lines = _view_text(
                            label, k / fps, a["cmd"][k], a["vel"][k], a["wrench"][k], a["ended"][k]
                        )
                        img = _text(img, lines, px)
                        rr, cc = divmod(j, cols)
                        frame[rr * th : rr * th + th, cc * tw : cc * tw + tw] = img
                    bottom = max(12, min(height // 34, 18))
                    frame = _legend(frame, bottom)
                    if seg["caption"]:
                        frame = _text(
                            frame, [(seg["caption"], (255, 230, 120))], bottom, "bottom", bottom + 8
                        )
                    if k in keep:
                        strip_rows[-1].append(frame)
                    t1 = time.perf_counter()
                    for packet in stream.encode(av.VideoFrame.from_ndarray(frame, format="rgb24")):
                        container.mux(packet)
                    render_s += t1 - t0
                    encode_s += time.perf_counter() - t1
                    frames += 1
            finally:
                for *_, r, _cam, _a in views:
                    r.close()
        t1 = time.perf_counter()
        for packet in stream.encode():
            container.mux(packet)
        encode_s += time.perf_counter() - t1
    from PIL import Image

    strip = strip_path(out)
    Image.fromarray(frame_strip(strip_rows)).save(strip)
    stats.write_text(
        json.dumps(
            {
                "path": str(out),
                "strip": str(strip),
                "frames": frames,
                "fps": fps,
                "width": width,
                "height": height,
                "segments": len(segments),
                "backend": os.environ.get("MUJOCO_GL", ""),
                "codec": codec,
                "render_ms_per_frame": 1e3 * render_s / max(frames, 1),
                "encode_ms_per_frame": 1e3 * encode_s / max(frames, 1),
            }
        )
    )


if __name__ == "__main__":
    render_job(Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3]))
