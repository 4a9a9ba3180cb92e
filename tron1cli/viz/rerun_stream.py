"""Stream one env of a :class:`~tron1cli.env.core.Tron1Env` to the rerun viewer (or an ``.rrd`` file).

What is logged, on the timelines ``step`` (policy steps) and ``sim_time`` (seconds):

* the world: the env's terrain tile as a mesh (again whenever the env changes tile), the robot's
  bodies as their MuJoCo shapes (static) moved by per-body poses, foot contact points and ground
  reaction forces;
* the LIPM: CoM, desired CoM p_hat, ZMP, the constraint plane at its intercept z and at the target
  z_c, commanded and actual velocity arrows, the push wrench;
* perception (``cfg.perception``): the depth image under a pinhole at the camera's pose (the viewer
  projects it into 3-D), the true height scan and the reconstructed one (``extras['h_hat']``) as
  points around the robot and as 21 x 21 images, and their error;
* scalars: every reward term and group, commands, tracking figures, actions.

Entity paths live in :data:`PATHS` only. Usage (rerun is imported only when a stream opens, so a
command run without ``--rerun`` pays nothing)::

    stream = open_stream(parse_rerun_option(rerun_opt))  # None when the option is off
    ...
    if stream:
        stream.log_step(env, 0, step, step * env.policy_dt, extras={"h_hat": h_hat})
    ...
    if stream:
        stream.close()

The option's syntax is in :data:`RERUN_HELP`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from tron1cli.env import robot
from tron1cli.env.math3d import yaw_of
from tron1cli.errors import Tron1Error

if TYPE_CHECKING:
    from tron1cli.env.core import Tron1Env

RERUN_HELP = (
    "Stream one env to rerun: 'spawn' (open a viewer), 'save=FILE.rrd' (or just FILE.rrd), "
    "'connect' or 'connect=URL' (a running viewer, default rerun+http://127.0.0.1:9876/proxy), 'off'."
)
DEFAULT_CONNECT_URL = "rerun+http://127.0.0.1:9876/proxy"

CONTACT_FORCE_SCALE = 0.002  #: m of arrow per N of ground reaction (body weight ~0.36 m)
PUSH_FORCE_SCALE = 0.004  #: m of arrow per N of push force (400 N -> 1.6 m)
PUSH_TORQUE_SCALE = 0.05  #: m of arrow per N m of push torque
PLANE_HALF_SIDE = 0.25  #: m, half side of the square drawn for the constraint plane
HEIGHTMAP_RANGE = (-1.0, 0.0)  #: m, colour range of the height-scan images (terrain - base z)
HEIGHTMAP_ERROR_RANGE = 0.2  #: m, +/- colour range of the reconstruction error


# ---------------------------------------------------------------------------------------------
# Entity paths: the one place they are defined


@dataclass(frozen=True)
class EntityPaths:
    """Every entity path the stream writes (rerun paths, no leading slash).

    3-D entities live under ``world`` (z up, metres, the env's own frame: tile centred on the
    origin). Robot body ``b``: ``world/robot/b`` (a Transform3D per step) with its static shapes
    under ``world/robot/b/geom/<geom>``. The camera: ``world/camera`` (Transform3D per step, static
    Pinhole) with the depth image in ``world/camera/depth``. Height scans: 441 3-D points in
    ``world/heightmap/{true,reconstructed,error}`` and 21 x 21 images (tensors, row 0 = front,
    column 0 = left) in ``heightmap/{true,reconstructed,error}``. Scalars: ``reward/<term>`` (the
    term's reward of the step, weight x dt applied, as ``env.rewards.last_terms``),
    ``reward_group/<group>`` (their sums), ``command/{lin_vel_x,lin_vel_y,yaw_rate}``,
    ``tracking/<name>`` (measured velocities and errors, LIPM figures), ``action/<joint>``,
    ``extra/<name>`` (scalars passed in ``extras``).
    """

    world: str = "world"
    terrain: str = "world/terrain"
    robot: str = "world/robot"
    contacts: str = "world/contacts"
    contact_forces: str = "world/contacts/force"
    com: str = "world/lipm/com"
    desired_com: str = "world/lipm/desired_com"
    zmp: str = "world/lipm/zmp"
    plane: str = "world/lipm/plane"
    velocity_command: str = "world/velocity/command"
    velocity_actual: str = "world/velocity/actual"
    push: str = "world/push"
    camera: str = "world/camera"
    depth: str = "world/camera/depth"
    heightmap_points: str = "world/heightmap"
    heightmap: str = "heightmap"
    reward: str = "reward"
    reward_group: str = "reward_group"
    command: str = "command"
    tracking: str = "tracking"
    action: str = "action"
    extra: str = "extra"

    def body(self, name: str) -> str:
        """Pose entity of robot body ``name``."""
        return f"{self.robot}/{name}"

    def hm_points(self, which: str) -> str:
        """3-D points of height scan ``which`` (true, reconstructed, error)."""
        return f"{self.heightmap_points}/{which}"

    def hm_image(self, which: str) -> str:
        """21 x 21 image of height scan ``which`` (true, reconstructed, error)."""
        return f"{self.heightmap}/{which}"

    def scalar(self, group: str, name: str) -> str:
        """Scalar ``name`` under ``group`` (e.g. ``PATHS.reward``)."""
        return f"{group}/{name}"


PATHS = EntityPaths()
HEIGHTMAP_KINDS = ("true", "reconstructed", "error")


# ---------------------------------------------------------------------------------------------
# The --rerun option


@dataclass(frozen=True)
class RerunTarget:
    """Where a stream goes: ``spawn`` a viewer, ``save`` to ``arg`` (a .rrd path), ``connect`` to
    ``arg`` (a gRPC URL)."""

    kind: Literal["spawn", "save", "connect"]
    arg: str | None = None

    def __str__(self) -> str:
        return self.kind if self.arg is None else f"{self.kind}={self.arg}"


_OFF = ("", "off", "none", "no", "false", "0")


def parse_rerun_option(text: str | None) -> RerunTarget | None:
    """Parse a ``--rerun`` value; None when off. ValueError with the valid forms otherwise.

    Forms: ``spawn``; ``save=FILE.rrd`` or a bare ``FILE.rrd``; ``connect`` or ``connect=URL``
    (scheme ``rerun://``, ``rerun+http://`` or ``rerun+https://``); ``off`` / ``none`` / empty.
    """
    if text is None:
        return None
    raw = text.strip()
    if raw.lower() in _OFF:
        return None
    forms = "use spawn, save=FILE.rrd, connect[=URL] or off"
    kind, sep, arg = raw.partition("=")
    kind = kind.strip().lower()
    arg = arg.strip()
    if not sep and raw.lower().endswith(".rrd"):
        kind, arg = "save", raw
    if kind == "spawn":
        if sep:
            raise ValueError(f"--rerun '{text}': spawn takes no value; {forms}")
        return RerunTarget("spawn")
    if kind == "save":
        if not arg:
            raise ValueError(f"--rerun '{text}': save needs a file, e.g. save=run.rrd")
        if not arg.lower().endswith(".rrd") or Path(arg).name.lower() == ".rrd":
            raise ValueError(f"--rerun '{text}': the file must end in .rrd, e.g. save=run.rrd")
        return RerunTarget("save", arg)
    if kind == "connect":
        if sep and not arg:
            raise ValueError(f"--rerun '{text}': connect= needs a URL, e.g. connect={DEFAULT_CONNECT_URL}")
        url = arg or DEFAULT_CONNECT_URL
        if not url.startswith(("rerun://", "rerun+http://", "rerun+https://")):
            raise ValueError(
                f"--rerun '{text}': the URL must start with rerun://, rerun+http:// or rerun+https://"
            )
        return RerunTarget("connect", url)
    raise ValueError(f"--rerun '{text}': unknown target '{kind}'; {forms}")


def open_stream(
    target: RerunTarget | str | None, app_id: str = "tron1", recording_name: str | None = None
) -> RerunStream | None:
    """A :class:`RerunStream` to ``target`` (a parsed target or an option string); None when off.

    ValueError for a bad option string (a usage error), :class:`~tron1cli.errors.Tron1Error` when
    the sink cannot be opened (an unwritable file, ...).
    """
    if isinstance(target, str):
        target = parse_rerun_option(target)
    if target is None:
        return None
    return RerunStream(target, app_id=app_id, recording_name=recording_name)


# ---------------------------------------------------------------------------------------------
# Small geometry helpers (pure numpy)


def terrain_mesh(heights: np.ndarray, res: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Triangle mesh of one tile ``heights`` (R, R) [row=y, col=x], ``res`` m apart, centred on 0.

    Returns vertex positions (R*R, 3) float32 m, triangle indices (2 (R-1)^2, 3) uint32 (counter-
    clockwise seen from above) and vertex normals (R*R, 3) float32.
    """
    h = np.asarray(heights, dtype=np.float32)
    r = h.shape[0]
    c = (np.arange(r) - 0.5 * (r - 1)) * res
    gx, gy = np.meshgrid(c, c, indexing="xy")  # gx[i, j] = x of column j, gy[i, j] = y of row i
    verts = np.stack([gx.ravel(), gy.ravel(), h.ravel()], axis=1).astype(np.float32)
    idx = np.arange(r * r, dtype=np.uint32).reshape(r, r)
    v00, v01, v10, v11 = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    tris = np.concatenate(
        [np.stack([v00, v01, v11], -1).reshape(-1, 3), np.stack([v00, v11, v10], -1).reshape(-1, 3)]
    )
    dhdy, dhdx = np.gradient(h, res)
    normals = np.stack([-dhdx.ravel(), -dhdy.ravel(), np.ones(r * r, np.float32)], axis=1)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return verts, tris, normals.astype(np.float32)


def _height_colors(z: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """uint8 RGB (n, 3): low terrain green-grey, high terrain sand."""
    t = np.clip((z - lo) / max(hi - lo, 1e-6), 0.0, 1.0)[:, None]
    low, high = np.array([90, 120, 95]), np.array([205, 185, 140])
    return (low + t * (high - low)).astype(np.uint8)


def _signed_colors(e: np.ndarray, span: float) -> np.ndarray:
    """uint8 RGB (n, 3): blue (negative) - white (0) - red (positive), saturating at +/- span."""
    t = np.clip(e / span, -1.0, 1.0)[:, None]
    white = np.array([235, 235, 235])
    red, blue = np.array([220, 40, 40]), np.array([40, 80, 220])
    return np.where(t >= 0, white + t * (red - white), white - t * (blue - white)).astype(np.uint8)


def scan_points(offsets: np.ndarray, heights: np.ndarray, base_pos: np.ndarray, yaw: float) -> np.ndarray:
    """World points (P, 3) of a height scan: base-yaw-frame ``offsets`` (P, 2) m, ``heights`` (P,) m
    relative to the base height, base position (3,) m, heading ``yaw`` rad."""
    c, s = math.cos(yaw), math.sin(yaw)
    pts = np.empty((len(offsets), 3), dtype=np.float32)
    pts[:, 0] = base_pos[0] + c * offsets[:, 0] - s * offsets[:, 1]
    pts[:, 1] = base_pos[1] + s * offsets[:, 0] + c * offsets[:, 1]
    pts[:, 2] = base_pos[2] + heights
    return pts


def scan_image(heights: np.ndarray, num_x: int, num_y: int) -> np.ndarray:
    """A scan (num_x * num_y,) as a top-down image (num_x, num_y): row 0 = front, column 0 = left."""
    return np.ascontiguousarray(np.asarray(heights, dtype=np.float32).reshape(num_x, num_y)[::-1, ::-1])


def _square(x: float, y: float, z: float, half: float) -> np.ndarray:
    """Closed horizontal square (5, 3) of half side ``half`` m centred on (x, y, z)."""
    return np.array(
        [[x - half, y - half, z], [x + half, y - half, z], [x + half, y + half, z], [x - half, y + half, z]]
        + [[x - half, y - half, z]],
        dtype=np.float32,
    )


def tile_height(h: np.ndarray, x: float, y: float, res: float) -> float:
    """Bilinear height (m) of one tile ``h`` (R, R) [row=y, col=x] at world (x, y), clamped to the
    tile like :func:`tron1cli.env.terrain.ground_height` (which, being a parallel kernel, costs
    milliseconds for a single point)."""
    r = h.shape[0]
    fx = min(max(x / res + 0.5 * (r - 1), 0.0), r - 1.0)
    fy = min(max(y / res + 0.5 * (r - 1), 0.0), r - 1.0)
    j, i = min(int(fx), r - 2), min(int(fy), r - 2)
    tx, ty = fx - j, fy - i
    h0 = h[i, j] + (h[i, j + 1] - h[i, j]) * tx
    h1 = h[i + 1, j] + (h[i + 1, j + 1] - h[i + 1, j]) * tx
    return float(h0 + (h1 - h0) * ty)


# ---------------------------------------------------------------------------------------------
# The stream


class RerunStream:
    """One rerun recording (its own ``rr.RecordingStream``, never the global one) of one env.

    ``log_step`` logs everything listed in the module docstring; the first call (or a call after
    the env changed tile) also logs the world (:meth:`log_world`). Scalars are buffered and sent
    as columns every ``scalar_batch`` steps (and at :meth:`close`): one call per series instead of
    one per step, so live time series trail the 3-D view by up to that many steps.
    """

    def __init__(
        self,
        target: RerunTarget,
        app_id: str = "tron1",
        recording_name: str | None = None,
        scalar_batch: int = 10,
    ) -> None:
        import rerun as rr

        self.rr = rr
        self.target = target
        self.rec = rr.RecordingStream(app_id, make_default=False, make_thread_default=False)
        bp = default_blueprint()
        try:
            if target.kind == "save":
                path = Path(str(target.arg))
                path.parent.mkdir(parents=True, exist_ok=True)
                self.rec.save(path, default_blueprint=bp)
            elif target.kind == "connect":
                self.rec.connect_grpc(target.arg, default_blueprint=bp)
            else:
                self.rec.spawn(default_blueprint=bp)
        except (OSError, RuntimeError) as e:  # an unwritable file, no viewer binary, ...
            raise Tron1Error(f"rerun {target}: {e}") from e
        if recording_name:
            self.rec.send_recording_name(recording_name)
        self.scalar_batch = max(1, int(scalar_batch))
        self._static_done = False
        self._tile: int | None = None
        self._last_depth: np.ndarray | None = None
        self._mj_data: Any = None
        self._bodies: list[tuple[int, str]] = []  # (body id, name) of bodies with shapes
        self._offsets: np.ndarray | None = None
        self._pushing = False
        self._now: tuple[int, float] | None = None  # (step, sim_time) being logged; None: never set
        self._scalars: dict[str, tuple[list[int], list[float], list[float]]] = {}
        self._steps_buffered = 0
        self._closed = False

    # -- context manager ---------------------------------------------------------------------
    def __enter__(self) -> RerunStream:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- time -------------------------------------------------------------------------------
    def set_time(self, step: int, sim_time: float) -> None:
        """Set the ``step`` (policy steps) and ``sim_time`` (s) timelines of what is logged next."""
        self._now = (int(step), float(sim_time))
        self.rec.set_time("step", sequence=self._now[0])
        self.rec.set_time("sim_time", duration=self._now[1])

    # -- world ------------------------------------------------------------------------------
    def log_world(
        self, env: Tron1Env, i: int, step: int | None = None, sim_time: float | None = None
    ) -> None:
        """Log env ``i``'s world: static robot shapes and camera intrinsics (once), and its
        terrain tile as a mesh at the current time (or at ``step`` / ``sim_time`` when given).

        The tile is logged on the timelines, not as static data, so that scrubbing back shows the
        tile the robot stood on then; it is logged again only when the env changes tile.
        """
        rr = self.rr
        if step is not None or self._now is None:
            self.set_time(step or 0, sim_time or 0.0)
        if not self._static_done:
            self._log_static(env, i)
        tile = int(env.curriculum.tile[i])
        bank = env.bank
        verts, tris, normals = terrain_mesh(bank.heights[tile], bank.res)
        lo, hi = float(bank.heights.min()), float(bank.heights.max())
        self.rec.log(
            PATHS.terrain,
            rr.Mesh3D(
                vertex_positions=verts,
                triangle_indices=tris,
                vertex_normals=normals,
                vertex_colors=_height_colors(verts[:, 2], lo, max(hi, lo + 0.05)),
            ),
        )
        self._tile = tile

    def _log_static(self, env: Tron1Env, i: int) -> None:
        import mujoco

        rr = self.rr
        self.rec.log(PATHS.world, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        model = env.physics.models[i]
        self._mj_data = mujoco.MjData(model)
        self._bodies = []
        for b in range(1, model.nbody):
            geoms = [g for g in range(model.ngeom) if model.geom_bodyid[g] == b]
            if not geoms:
                continue
            name = model.body(b).name
            self._bodies.append((b, name))
            for g in geoms:
                shape = _geom_archetype(rr, model, g)
                if shape is not None:
                    self.rec.log(f"{PATHS.body(name)}/geom/{model.geom(g).name or g}", shape, static=True)
        if env.camera is not None:
            cam = env.camera
            fx, fy, cx, cy = cam.intrinsics()
            self.rec.log(
                PATHS.camera,
                rr.Pinhole(
                    focal_length=[fx, fy],
                    principal_point=[cx, cy],
                    width=cam.width,
                    height=cam.height,
                    camera_xyz=rr.ViewCoordinates.RUB,  # MuJoCo camera: x right, y up, looks along -z
                    image_plane_distance=0.3,
                ),
                static=True,
            )
        if env.height_scan is not None:
            self._offsets = env.height_scan.offsets()
        self._log_styles()
        self._static_done = True

    def _log_styles(self) -> None:
        """Static colours, radii and labels; per-step logs then carry geometry only (cheaper)."""
        rr, rec = self.rr, self.rec

        def points(path: str, color: list[int], radius: float, label: str | None = None) -> None:
            labels = None if label is None else [label]
            rec.log(path, rr.Points3D.from_fields(colors=[color], radii=[radius], labels=labels), static=True)

        def arrows(path: str, color: list[int]) -> None:
            rec.log(path, rr.Arrows3D.from_fields(colors=[color]), static=True)

        points(PATHS.contacts, [255, 200, 0], 0.02)
        arrows(PATHS.contact_forces, [255, 140, 0])
        points(PATHS.com, [40, 120, 255], 0.03, "CoM")
        points(PATHS.desired_com, [40, 220, 80], 0.03, "p_hat")
        points(PATHS.zmp, [230, 50, 50], 0.03, "ZMP")
        rec.log(
            PATHS.plane,
            rr.LineStrips3D.from_fields(
                colors=[[40, 120, 255], [40, 220, 80]], labels=["plane z", "target z_c"], radii=[0.004]
            ),
            static=True,
        )
        arrows(PATHS.velocity_command, [40, 220, 80])
        arrows(PATHS.velocity_actual, [40, 120, 255])
        rec.log(PATHS.push, rr.Arrows3D.from_fields(colors=[[230, 30, 200], [150, 30, 230]]), static=True)
        points(PATHS.hm_points("true"), [60, 200, 90], 0.008)
        points(PATHS.hm_points("reconstructed"), [250, 150, 30], 0.008)
        rec.log(PATHS.hm_points("error"), rr.Points3D.from_fields(radii=[0.012]), static=True)

    # -- one step ---------------------------------------------------------------------------
    def log_step(
        self,
        env: Tron1Env,
        i: int,
        step: int,
        sim_time: float,
        extras: dict[str, Any] | None = None,
    ) -> None:
        """Log env ``i`` after a step, at ``step`` (policy steps) and ``sim_time`` (s).

        extras: optional; ``h_hat`` the reconstructed height scan, (441,) or (N, 441), m relative to
        the base like ``obs['heightmap']``; any other key with a scalar value (or an (N,) array) is
        logged as ``extra/<key>``.
        """
        if env.state is None:
            raise RuntimeError("log_step needs a reset env (env.state is None)")
        hs, h_hat = env.height_scan, None
        if hs is not None and extras is not None and extras.get("h_hat") is not None:
            h_hat = _row(extras["h_hat"], i, env.n, hs.num_points, "extras['h_hat']")
        rr, rec = self.rr, self.rec
        self.set_time(step, sim_time)
        if not self._static_done or self._tile != int(env.curriculum.tile[i]):
            self.log_world(env, i)
        s = env.state
        base_pos = s.base_pos[i]
        yaw = float(yaw_of(s.base_quat[i : i + 1])[0])
        self._log_bodies(env, i)

        # contacts: colours and radii are static (see _log_styles), only geometry per step
        inc = s.foot_in_contact[i]
        cpos = s.foot_contact_pos[i][inc]
        rec.log(PATHS.contacts, rr.Points3D.from_fields(positions=cpos))
        rec.log(
            PATHS.contact_forces,
            rr.Arrows3D.from_fields(origins=cpos, vectors=s.foot_force[i][inc] * CONTACT_FORCE_SCALE),
        )

        # LIPM: the desired CoM at the target height z_c above the ground the intercept was
        # measured from, the ZMP on the terrain, the plane at z and at z_c
        lipm = env.lipm
        com = s.com_pos[i]
        ground = com[2] - float(lipm.z[i])
        z_c = float(lipm.z_c)
        p_hat, zmp = lipm.p_hat[i], lipm.zmp[i]
        zmp_z = tile_height(env.bank.heights[int(env.curriculum.tile[i])], zmp[0], zmp[1], env.bank.res)
        rec.log(PATHS.com, rr.Points3D.from_fields(positions=[com]))
        rec.log(PATHS.desired_com, rr.Points3D.from_fields(positions=[[p_hat[0], p_hat[1], ground + z_c]]))
        rec.log(PATHS.zmp, rr.Points3D.from_fields(positions=[[zmp[0], zmp[1], zmp_z]]))
        rec.log(
            PATHS.plane,
            rr.LineStrips3D.from_fields(
                strips=[
                    _square(com[0], com[1], ground + float(lipm.z[i]), PLANE_HALF_SIDE),
                    _square(com[0], com[1], ground + z_c, PLANE_HALF_SIDE),
                ]
            ),
        )

        # velocities (arrows from the base) and the push wrench
        cmd = env.commands.value[i]
        c, sn = math.cos(yaw), math.sin(yaw)
        cmd_w = [c * cmd[0] - sn * cmd[1], sn * cmd[0] + c * cmd[1], 0.0]
        rec.log(PATHS.velocity_command, rr.Arrows3D.from_fields(origins=[base_pos], vectors=[cmd_w]))
        rec.log(
            PATHS.velocity_actual, rr.Arrows3D.from_fields(origins=[base_pos], vectors=[s.base_lin_vel_w[i]])
        )
        wrench = env.external_wrench[i]
        if np.any(wrench):
            rec.log(
                PATHS.push,
                rr.Arrows3D.from_fields(
                    origins=[base_pos, base_pos],
                    vectors=[wrench[:3] * PUSH_FORCE_SCALE, wrench[3:] * PUSH_TORQUE_SCALE],
                    labels=[f"{np.linalg.norm(wrench[:3]):.0f} N", f"{np.linalg.norm(wrench[3:]):.1f} N m"],
                ),
            )
        elif self._pushing:  # the push just ended: clear the arrows
            rec.log(PATHS.push, rr.Arrows3D.from_fields(origins=[], vectors=[], labels=[]))
        self._pushing = bool(np.any(wrench))

        # perception
        if env.camera is not None:
            self._log_camera(env, i)
        self._log_heightmaps(env, i, base_pos, yaw, h_hat)

        self._log_scalars(env, i, extras)
        self._steps_buffered += 1
        if self._steps_buffered >= self.scalar_batch:
            self.flush_scalars()

    def _log_bodies(self, env: Tron1Env, i: int) -> None:
        import mujoco

        from tron1cli.env.physics import STATE_SPEC

        rr = self.rr
        model = env.physics.models[i]
        d = self._mj_data
        mujoco.mj_setState(model, d, env.physics.state[i], STATE_SPEC)
        mujoco.mj_kinematics(model, d)
        for b, name in self._bodies:
            q = d.xquat[b]
            self.rec.log(
                PATHS.body(name),
                rr.Transform3D(
                    translation=d.xpos[b], quaternion=rr.Quaternion(xyzw=[q[1], q[2], q[3], q[0]])
                ),
            )

    def _log_camera(self, env: Tron1Env, i: int) -> None:
        rr = self.rr
        pos, rot = env.camera_pose(np.array([i]))
        self.rec.log(PATHS.camera, rr.Transform3D(translation=pos[0], mat3x3=rot[0]))
        depth = env.depth[i]
        if self._last_depth is not None and np.array_equal(depth, self._last_depth):
            return  # the env holds frames between renders (depth_hz); the viewer shows the latest
        self._last_depth = depth.copy()
        cam = env.camera
        assert cam is not None
        self.rec.log(PATHS.depth, rr.DepthImage(depth, meter=1.0, depth_range=(0.0, cam.far)))

    def _log_heightmaps(
        self, env: Tron1Env, i: int, base_pos: np.ndarray, yaw: float, h_hat: np.ndarray | None
    ) -> None:
        rr, rec = self.rr, self.rec
        hs = env.height_scan
        if hs is None or self._offsets is None:
            return
        true = env.obs["heightmap"][i] if "heightmap" in env.obs else None
        rec_h = h_hat
        for which, h in (("true", true), ("reconstructed", rec_h)):
            if h is None:
                continue
            pts = scan_points(self._offsets, h, base_pos, yaw)
            rec.log(PATHS.hm_points(which), rr.Points3D.from_fields(positions=pts))
            img = scan_image(h, hs.num_x, hs.num_y)
            rec.log(PATHS.hm_image(which), rr.Tensor(img, value_range=HEIGHTMAP_RANGE))
        if true is not None and rec_h is not None:
            err = rec_h - true
            pts = scan_points(self._offsets, true, base_pos, yaw)
            colors = _signed_colors(err, HEIGHTMAP_ERROR_RANGE)
            rec.log(PATHS.hm_points("error"), rr.Points3D.from_fields(positions=pts, colors=colors))
            span = (-HEIGHTMAP_ERROR_RANGE, HEIGHTMAP_ERROR_RANGE)
            rec.log(PATHS.hm_image("error"), rr.Tensor(scan_image(err, hs.num_x, hs.num_y), value_range=span))
            self._scalar(PATHS.scalar(PATHS.tracking, "heightmap_mae"), float(np.abs(err).mean()))

    def _scalar(self, path: str, value: float) -> None:
        assert self._now is not None
        steps, times, values = self._scalars.setdefault(path, ([], [], []))
        steps.append(self._now[0])
        times.append(self._now[1])
        values.append(value)

    def _log_scalars(self, env: Tron1Env, i: int, extras: dict[str, Any] | None) -> None:
        s, lipm, p = env.state, env.lipm, PATHS
        assert s is not None
        terms = env.rewards.last_terms  # per-term rewards of the last step, weight x dt applied
        groups: dict[str, float] = {}
        for name, cfg in env.reward_cfg.terms.items():
            if name in terms:
                v = float(terms[name][i])
                self._scalar(p.scalar(p.reward, name), v)
                groups[cfg.group] = groups.get(cfg.group, 0.0) + v
        for g, v in groups.items():
            self._scalar(p.scalar(p.reward_group, g), v)
        cmd = env.commands.value[i]
        v_b = s.base_lin_vel_b[i]
        w_z = float(s.base_ang_vel_b[i, 2])
        values = {
            p.scalar(p.command, "lin_vel_x"): cmd[0],
            p.scalar(p.command, "lin_vel_y"): cmd[1],
            p.scalar(p.command, "yaw_rate"): cmd[2],
            p.scalar(p.tracking, "lin_vel_x"): v_b[0],
            p.scalar(p.tracking, "lin_vel_y"): v_b[1],
            p.scalar(p.tracking, "yaw_rate"): w_z,
            p.scalar(p.tracking, "lin_vel_error"): math.hypot(cmd[0] - v_b[0], cmd[1] - v_b[1]),
            p.scalar(p.tracking, "yaw_rate_error"): abs(cmd[2] - w_z),
            p.scalar(p.tracking, "com_error"): np.linalg.norm(lipm.p_hat[i] - lipm.p_com[i]),
            p.scalar(p.tracking, "plane_z"): lipm.z[i],
            p.scalar(p.tracking, "plane_z_error"): lipm.z_c - lipm.z[i],
            p.scalar(p.tracking, "r_stable"): lipm.r_stable[i],
        }
        for j, name in enumerate(robot.JOINT_NAMES):
            values[p.scalar(p.action, name)] = env.actions[i, j]
        for path, v in values.items():
            self._scalar(path, float(v))
        for key, value in (extras or {}).items():
            if key == "h_hat":
                continue
            arr = np.asarray(value)
            if arr.ndim == 1 and arr.shape[0] == env.n:
                arr = arr[i]
            if arr.ndim == 0 and np.issubdtype(arr.dtype, np.number):
                self._scalar(p.scalar(p.extra, key), float(arr))

    def flush_scalars(self) -> None:
        """Send the buffered scalars, one ``send_columns`` per series."""
        rr = self.rr
        for path, (steps, times, values) in self._scalars.items():
            if not steps:
                continue
            self.rec.send_columns(
                path,
                indexes=[
                    rr.TimeColumn("step", sequence=np.asarray(steps, dtype=np.int64)),
                    rr.TimeColumn("sim_time", duration=np.asarray(times, dtype=np.float64)),
                ],
                columns=rr.Scalars.columns(scalars=np.asarray(values, dtype=np.float64)),
            )
            steps.clear()
            times.clear()
            values.clear()
        self._steps_buffered = 0

    # -- end --------------------------------------------------------------------------------
    def close(self) -> None:
        """Flush everything to the sink and close it (a saved file is complete afterwards)."""
        if self._closed:
            return
        self._closed = True
        self.flush_scalars()
        self.rec.flush()
        self.rec.disconnect()


def _row(value: Any, i: int, n: int, dim: int, what: str) -> np.ndarray:
    """Row ``i`` of ``value`` given as (dim,) or (n, dim), float32; ValueError otherwise."""
    a = np.asarray(value, dtype=np.float32)
    if a.ndim == 2 and a.shape == (n, dim):
        return a[i]
    if a.shape == (dim,):
        return a
    raise ValueError(f"{what} must be ({dim},) or ({n}, {dim}), got shape {a.shape}")


def _geom_archetype(rr: Any, model: Any, g: int) -> Any:
    """The rerun shape of MuJoCo geom ``g`` in its body's frame; None for types not drawn."""
    import mujoco

    gt = mujoco.mjtGeom
    t = int(model.geom_type[g])
    size = model.geom_size[g]
    pos = model.geom_pos[g]
    qw = model.geom_quat[g]
    quat = rr.Quaternion(xyzw=[qw[1], qw[2], qw[3], qw[0]])
    color = (np.clip(model.geom_rgba[g], 0.0, 1.0) * 255).astype(np.uint8)
    solid = rr.components.FillMode.Solid
    if t == gt.mjGEOM_BOX:
        return rr.Boxes3D(
            half_sizes=[size], centers=[pos], quaternions=[quat], colors=[color], fill_mode=solid
        )
    if t == gt.mjGEOM_CYLINDER:
        return rr.Cylinders3D(
            lengths=[2 * size[1]],
            radii=[size[0]],
            centers=[pos],
            quaternions=[quat],
            colors=[color],
            fill_mode=solid,
        )
    if t == gt.mjGEOM_SPHERE:
        return rr.Ellipsoids3D(half_sizes=[[size[0]] * 3], centers=[pos], colors=[color], fill_mode=solid)
    if t == gt.mjGEOM_ELLIPSOID:
        return rr.Ellipsoids3D(
            half_sizes=[size], centers=[pos], quaternions=[quat], colors=[color], fill_mode=solid
        )
    if t == gt.mjGEOM_CAPSULE:
        rot = np.zeros(9)
        mujoco.mju_quat2Mat(rot, qw)
        start = pos - rot.reshape(3, 3)[:, 2] * size[1]  # rerun capsules start at their origin, along +z
        return rr.Capsules3D(
            lengths=[2 * size[1]], radii=[size[0]], translations=[start], quaternions=[quat], colors=[color]
        )
    return None


def default_blueprint() -> Any:
    """3-D view | (depth view, height-scan images, time series in tabs)."""
    import rerun.blueprint as rrb

    p = PATHS
    hm_views = [rrb.TensorView(origin=p.hm_image(k), name=f"heightmap {k}") for k in HEIGHTMAP_KINDS]
    series = rrb.Tabs(
        rrb.TimeSeriesView(origin=p.reward, name="reward terms"),
        rrb.TimeSeriesView(origin=p.reward_group, name="reward groups"),
        rrb.TimeSeriesView(
            origin="/",
            contents=[
                f"{p.command}/**",
                f"{p.tracking}/lin_vel_x",
                f"{p.tracking}/lin_vel_y",
                f"{p.tracking}/yaw_rate",
            ],
            name="velocity",
        ),
        rrb.TimeSeriesView(origin="/", contents=[f"{p.tracking}/**", f"{p.extra}/**"], name="tracking"),
        rrb.TimeSeriesView(origin=p.action, name="actions"),
        name="time series",
    )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin=p.world, name="world"),
            rrb.Vertical(
                rrb.Spatial2DView(origin=p.camera, name="depth"),
                rrb.Horizontal(*hm_views, name="heightmaps"),
                series,
                row_shares=[1.0, 0.8, 1.4],
            ),
            column_shares=[1.4, 1.0],
        ),
    )


# ---------------------------------------------------------------------------------------------
# Reading a saved recording back (tests, checks)


def read_rrd(path: str | Path, static: bool = False) -> dict[str, list[dict[str, Any]]]:
    """The entities of the first recording in ``path``, read with rerun's own reader
    (``rerun.chunk.RrdReader``): entity path (no leading slash) -> its rows in ``step`` order, each
    a dict column name (``step``, ``sim_time`` in s, ``Points3D:positions``, ...) -> value.

    Temporal data only, unless ``static``: then static data only (rows without timelines).
    """
    from rerun.chunk import RrdReader

    out: dict[str, list[dict[str, Any]]] = {}
    for chunk in RrdReader(str(path)).stream():
        if chunk.is_static != static or chunk.is_empty:
            continue
        rb = chunk.to_record_batch()
        names = [n for n in rb.schema.names if not n.startswith("rerun.controls") and n != "log_time"]
        cols = {n: rb.column(n).to_pylist() for n in names if n != "sim_time"}
        if "sim_time" in names:  # a duration column: nanoseconds -> seconds
            cols["sim_time"] = [v * 1e-9 for v in rb.column("sim_time").cast("int64").to_pylist()]
        rows = out.setdefault(str(chunk.entity_path).lstrip("/"), [])
        rows.extend({n: cols[n][k] for n in names} for k in range(rb.num_rows))
    for rows in out.values():
        rows.sort(key=lambda r: r.get("step") or 0)
    return out
