"""sim-robot: our MuJoCo TRON1 as a simulated robot on the simulator side of LimX's SDK.

As LimX's own MuJoCo simulator stands in for the robot: physics paced to the wall clock at
``physics_hz`` (500 Hz, the robot's loop); at every physics step the newest received command
(Kp, Kd, q, dq, tau per motor) drives the joints through a PD law evaluated inside MuJoCo
(tau = Kp (q_des - q) + Kd (dq_des - dq) + tau_ff, clipped to 80 N m: the position actuators'
gains are set from the command, so the PD runs at the physics rate with MuJoCo's implicit
damping, exactly as in training and deploy-sim), and the joint state and the IMU (quat w, x, y,
z; gyro rad/s and acc m/s^2 in the base frame) are published, with the sensor noise of training
unless ``noise`` is off. Motors are mapped to MuJoCo joints by name.

Before the first command the motors are off and the base hangs on a hoist at the training reset
height (0.83 m above the ground); the hoist lets go ``hoist_s`` after the first command (set it to
deploy-robot's ramp), so the policy starts as in training, from the default pose just above the
ground. When the loop falls behind the wall clock by more than ``MAX_LAG_S`` it slips (counted)
instead of bursting to catch up.

With ``depth_to`` set, the robot's D435i is rendered at 30 Hz of simulation time by the training
renderer (the same ray march and, with ``noise``, the same sensor noise) in its own thread and
sent as UDP datagrams (:mod:`tron1cli.deploy.depth_link`), since the SDK has no image channel.
"""

from __future__ import annotations

import json
import signal
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from tron1cli.config.env import EnvConfig, NoiseConfig
from tron1cli.deploy.sdk import PF_TRON1A_MOTORS
from tron1cli.env import robot, sensors
from tron1cli.env.math3d import quat_rotate_inverse, quat_to_mat
from tron1cli.env.scene import build_model, set_tile
from tron1cli.env.terrain import TerrainBank, ground_height, resolve_terrain
from tron1cli.errors import UsageError
from tron1cli.evaluation.protocol import terrain_for_reach

MAX_LAG_S = 0.1  #: behind the wall clock by more than this, the loop slips instead of catching up
HOIST_HEIGHT_M = 0.83  #: base origin above the ground while hoisted (the training reset height)
FALL_TILT_RAD = 0.8  #: the base counts as fallen past this tilt ...
FALL_HEIGHT_M = 0.35  #: ... or below this height above the ground


@dataclass(frozen=True)
class SimRobotConfig:
    """terrain, level: as in deploy-sim (the tile at the origin); physics_hz: physics and PD rate;
    hoist_s: seconds after the first command at which the hoist lets go (None: never); noise:
    training's sensor noise on the published state and IMU; duration_s: wall seconds to run
    (None: until stopped); seed: terrain and noise seed; depth_to: (host, port) to send the
    depth camera's frames to (None: no camera); depth_hz: their rate in simulation time; reach_m:
    metres the robot may walk from the start in any direction and stay on the terrain under test
    (None: the training tile)."""

    terrain: str = "flat"
    level: int = 0
    physics_hz: float = 500.0
    hoist_s: float | None = 2.0
    noise: bool = True
    duration_s: float | None = None
    seed: int = 0
    depth_to: tuple[str, int] | None = None
    depth_hz: float = 30.0
    reach_m: float | None = None


class SimRobot:
    """The simulated robot on one SDK link (simulator side); :meth:`run` until stopped."""

    def __init__(self, cfg: SimRobotConfig, link, motor_names: list[str] | None = None) -> None:
        try:
            types = resolve_terrain(cfg.terrain)
        except ValueError as e:
            raise UsageError(str(e)) from None
        tcfg = EnvConfig().terrain_cfg
        if cfg.reach_m is not None:
            tcfg = terrain_for_reach(tcfg, cfg.reach_m)
        if not (cfg.level == -1 or 0 <= cfg.level < tcfg.num_levels):
            raise UsageError(f"--level {cfg.level} outside 0..{tcfg.num_levels - 1} (or -1 for the hardest)")
        self.cfg, self.link = cfg, link
        bank = TerrainBank.from_name(cfg.terrain, tcfg, seed=cfg.seed)
        self.model = build_model(1.0 / cfg.physics_hz, bank)
        kind = int(np.random.default_rng([cfg.seed, 7]).integers(len(types)))
        tile = int(np.flatnonzero((bank.kind == kind) & (bank.level == cfg.level % tcfg.num_levels))[0])
        self.terrain_type, ground = types[kind], 0.0
        if self.model.nhfield:
            set_tile(self.model, bank, tile)
            ground = float(ground_height(bank.heights, np.array([tile]), np.zeros((1, 2)), bank.res)[0])
        self.ground = ground
        self.bank, self.tile = bank, tile
        m = self.model
        m.actuator_gainprm[:, 0] = 1.0  # ctrl = Kp q_des + Kd dq_des + tau; bias -Kp q - Kd dq
        m.actuator_biasprm[:, 1:3] = 0.0
        m.actuator_ctrllimited[:] = 0
        self.data = mujoco.MjData(m)
        names = motor_names or list(PF_TRON1A_MOTORS)
        key = {j.lower(): i for i, j in enumerate(robot.JOINT_NAMES)}
        self.motor_to_joint = np.array([key[n.lower().removesuffix("_joint")] for n in names])
        self.n_motors = len(names)
        d = self.data
        d.qpos[:] = 0.0
        d.qpos[2] = ground + HOIST_HEIGHT_M
        d.qpos[3] = 1.0
        d.qpos[7:] = [0.0, 0.3, 0.3, 0.0, -0.3, -0.3]  # limp legs, not the default pose
        self.hoist_pose = d.qpos[:7].copy()
        mujoco.mj_forward(m, d)
        self.noise = NoiseConfig() if cfg.noise else None
        self.rng = np.random.default_rng([cfg.seed, 19])
        self.stop = False
        # figures
        self.log_t: list[float] = []  # monotonic s, every 1/50 s of physics
        self.log_v: list[list[float]] = []  # base linear velocity, base frame (m/s)
        self.fell_at: float | None = None
        self.steps = 0
        self.slips = 0
        self.commands = 0
        self.released_at: float | None = None
        self.camera = _Camera(self, cfg) if cfg.depth_to is not None else None

    def _apply(self, cmd) -> None:
        f = cmd.fields
        if min(len(f[k]) for k in ("q", "dq", "tau", "kp", "kd")) < self.n_motors:
            return  # not a command for this robot
        j = self.motor_to_joint
        kp, kd = np.zeros(robot.NUM_JOINTS), np.zeros(robot.NUM_JOINTS)
        u = np.zeros(robot.NUM_JOINTS)
        kp[j], kd[j] = f["kp"][: self.n_motors], f["kd"][: self.n_motors]
        u[j] = kp[j] * f["q"][: self.n_motors] + kd[j] * f["dq"][: self.n_motors] + f["tau"][: self.n_motors]
        if not (np.all(np.isfinite(u)) and np.all(np.isfinite(kd))):
            return
        self.model.actuator_biasprm[:, 1] = -kp
        self.model.actuator_biasprm[:, 2] = -kd
        self.data.ctrl[:] = u

    def _publish(self) -> None:
        d, nz = self.data, self.noise
        q, dq = d.qpos[7:].copy(), d.qvel[6:].copy()
        quat, gyro = d.qpos[3:7].copy(), d.qvel[3:6].copy()
        if nz is not None:
            q += self.rng.normal(0.0, nz.joint_pos, q.shape)
            dq += self.rng.normal(0.0, nz.joint_vel, dq.shape)
            gyro += self.rng.normal(0.0, nz.ang_vel, 3)
            rx, ry = self.rng.normal(0.0, nz.gravity, 2)  # a small tilt of the measured orientation
            dquat = np.array([1.0, rx / 2, ry / 2, 0.0])
            quat = _quat_mul(quat, dquat / np.linalg.norm(dquat))
        acc_w = d.qacc[0:3] - self.model.opt.gravity
        acc = quat_rotate_inverse(d.qpos[None, 3:7], acc_w[None])[0]
        tau = d.actuator_force.copy()
        j = self.motor_to_joint
        self.link.publish_state(q[j], dq[j], tau[j])
        self.link.publish_imu(quat, gyro, acc)

    def run(self) -> dict:
        """Step until stopped (SIGINT, SIGTERM, ``duration_s``); returns the report."""
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda *_: setattr(self, "stop", True))
        m, d, cfg = self.model, self.data, self.cfg
        dt = m.opt.timestep
        log_every = max(1, int(round(0.02 / dt)))
        last_count, first_cmd = 0, None
        wall0 = time.perf_counter()
        t_next = wall0
        if self.camera is not None:
            self.camera.start()
        while not self.stop:
            now = time.perf_counter()
            if cfg.duration_s is not None and now - wall0 >= cfg.duration_s:
                break
            cmd = self.link.get("cmd")
            if cmd is not None and cmd.count != last_count:
                last_count = cmd.count
                self._apply(cmd)
                if first_cmd is None:
                    first_cmd = now
            hoisted = self.released_at is None
            due = first_cmd is not None and cfg.hoist_s is not None and now - first_cmd >= cfg.hoist_s
            if hoisted and due:
                self.released_at = time.monotonic()
                hoisted = False
            if hoisted:
                d.qpos[:7], d.qvel[:6] = self.hoist_pose, 0.0
            mujoco.mj_step(m, d)
            if hoisted:
                d.qpos[:7], d.qvel[:6] = self.hoist_pose, 0.0
            self._publish()
            self.steps += 1
            if self.camera is not None:
                self.camera.tick(self.steps * dt)
            if self.steps % log_every == 0:
                self._log()
            t_next += dt
            lag = time.perf_counter() - t_next
            if lag > MAX_LAG_S:
                t_next += lag
                self.slips += 1
            elif lag < 0:
                time.sleep(-lag)
        self.commands = last_count
        if self.camera is not None:
            self.camera.close()
        return self.report(time.perf_counter() - wall0)

    def _log(self) -> None:
        d = self.data
        quat = d.qpos[None, 3:7]
        v_b = quat_rotate_inverse(quat, d.qvel[None, 0:3])[0]
        self.log_t.append(time.monotonic())
        self.log_v.append([float(v_b[0]), float(v_b[1])])
        if self.fell_at is None and self.released_at is not None:
            up = quat_to_mat(quat)[0][2, 2]
            if np.arccos(np.clip(up, -1, 1)) > FALL_TILT_RAD or d.qpos[2] - self.ground < FALL_HEIGHT_M:
                self.fell_at = time.monotonic()

    def report(self, wall_s: float) -> dict:
        sim_s = self.steps * self.model.opt.timestep
        return {
            "terrain_type": self.terrain_type,
            "level": self.cfg.level,
            "physics_hz": self.cfg.physics_hz,
            "physics_steps": self.steps,
            "sim_s": round(sim_s, 4),
            "wall_s": round(wall_s, 4),
            "realtime_factor": round(sim_s / wall_s, 4) if wall_s > 0 else None,
            "slips": self.slips,
            "depth_frames_sent": None if self.camera is None else self.camera.sender.sent,
            "depth_render_ms_p50": None if self.camera is None else self.camera.render_ms_p50(),
            "commands_received": self.commands,
            "released_monotonic_s": self.released_at,
            "fell_monotonic_s": self.fell_at,
            "log_monotonic_s": self.log_t,
            "log_base_vel_b": self.log_v,
        }


class _Camera:
    """The sim-robot's depth camera: :meth:`tick` (physics loop) snapshots the camera pose every
    1/depth_hz of simulation time; a thread renders the newest snapshot and sends it."""

    def __init__(self, sim: SimRobot, cfg: SimRobotConfig) -> None:
        from tron1cli.deploy.depth_link import DepthSender

        self.sim, self.cam = sim, sensors.DepthCamera()
        self.cam_id = sim.model.camera(robot.CAMERA_NAME).id
        self.period = 1.0 / cfg.depth_hz
        self.heights = sim.bank.heights[sim.tile : sim.tile + 1]  # the one tile it stands on
        self.maps = sensors.depth_max_maps(self.heights)
        self.noise = cfg.noise
        self.rng = np.random.default_rng([cfg.seed, 30])
        self.sender = DepthSender(*cfg.depth_to)
        self.next_t = 0.0
        self.seq = 0
        self.render_ms: list[float] = []
        self._pending: tuple[int, float, np.ndarray, np.ndarray] | None = None
        self._cond = threading.Condition()
        self._stop = False
        self._thread = threading.Thread(target=self._run, name="tron1-sim-camera", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def tick(self, t: float) -> None:
        if t < self.next_t:
            return
        self.next_t += self.period
        d = self.sim.data
        pose = (self.seq, t, d.cam_xpos[self.cam_id].copy(), d.cam_xmat[self.cam_id].reshape(3, 3).copy())
        self.seq += 1
        with self._cond:
            self._pending = pose  # a frame the renderer has not taken yet is dropped, as by a driver
            self._cond.notify()

    def _run(self) -> None:
        import numba

        numba.set_num_threads(1)
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._pending is not None or self._stop)
                if self._stop:
                    return
                seq, t, pos, rot = self._pending
                self._pending = None
            t0 = time.perf_counter()
            img = sensors.render_depth(
                self.heights,
                np.zeros(1, np.int64),
                pos[None],
                rot[None],
                self.cam,
                self.sim.bank.res,
                max_maps=self.maps,
            )
            if self.noise:
                img = sensors.add_depth_noise(img, self.cam, self.rng)
            self.render_ms.append(1e3 * (time.perf_counter() - t0))
            self.sender.send(img[0], seq, t)

    def render_ms_p50(self) -> float | None:
        return round(float(np.median(self.render_ms)), 3) if self.render_ms else None

    def close(self) -> None:
        with self._cond:
            self._stop = True
            self._cond.notify()
        self._thread.join(timeout=2.0)
        self.sender.close()


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ]
    )


def write_report(rep: dict, path: Path) -> None:
    from tron1cli.fileio import write_file

    write_file(Path(path), json.dumps(rep) + "\n")
