"""The batched TRON1 environment: actions in, observation groups, rewards and episode ends out.

One step: action (N, 6) -> joint targets = default pose + 0.25 action (+ the gait's swing fold,
when set) -> PD inside MuJoCo
(position actuators, Kp 40, Kd 2.5, torque clipped to 80 N m) for ``decimation`` physics steps ->
robot state -> terminations -> rewards -> commands -> resets -> observations.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np

from tron1cli.config.env import FACE_CLIMB_GROUPS, EnvConfig
from tron1cli.env import robot, sensors, terminations
from tron1cli.env.commands import Commands
from tron1cli.env.curriculum import EpisodeEnds, TerrainCurriculum
from tron1cli.env.gait import clock_observation, desired_contact, fold_targets, leg_phases
from tron1cli.env.lipm import LipmTracker
from tron1cli.env.math3d import quat_from_euler, quat_to_mat, rotate_z, yaw_of
from tron1cli.env.observations import ObsLayout, assemble, proprio_values, push_history
from tron1cli.env.physics import make_physics
from tron1cli.env.randomization import Pusher, Randomizer
from tron1cli.env.rewards import RewardConfig, RewardManager
from tron1cli.env.scene import build_model
from tron1cli.env.state import RobotState, read_state
from tron1cli.env.terrain import (
    TERRAIN_GROUPS,
    TerrainBank,
    ground_height,
    highest_ground_height,
    mean_ground_height,
)

EDGE_MARGIN_M = 0.5  #: an env whose base comes this close to its tile's edge ends its episode (time-out)

ACTION_CLIP = 10.0  #: actions are clipped to +/- this before scaling


@dataclass
class StepResult:
    """What one env step returns; every array has N rows.

    obs: observation groups by name (see :class:`ObsLayout`), after resets.
    terminal_obs: the same groups before resets, for value bootstrapping of time-outs.
    rewards: reward per group (``stable``, ``loco``; one ``all`` group in the single-critic ablation).
    episode: figures of the episodes that ended this step (one entry per done env): ``length_s``
        (time walked since the reset), ``time_out``, ``staggered`` (the episode is the first after
        ``reset(stagger=True)``: its clock started at a random point, so a time-out cut it short;
        it moves no terrain level and is left out of training statistics), and ``reward/<term>``
        per-term sums.
    fall_causes: (N, len(terminations.FALL_CAUSES)) bool, what made each failed env fail (tilt,
        or a termination body touching the ground); False for every other env.
    """

    obs: dict[str, np.ndarray]
    terminal_obs: dict[str, np.ndarray]
    rewards: dict[str, np.ndarray]
    done: np.ndarray
    time_out: np.ndarray
    failed: np.ndarray
    unstable: np.ndarray
    fall_causes: np.ndarray
    episode: dict[str, np.ndarray] = field(default_factory=dict)


class Tron1Env:
    """N TRON1 worlds stepped together. See the module docstring for one step's order.

    backend: the physics engine (tron1cli.env.physics.BACKENDS), a setting of the machine.
    """

    def __init__(
        self, cfg: EnvConfig, reward_cfg: RewardConfig | None = None, backend: str = "mujoco"
    ) -> None:
        from tron1cli.memory import check_memory, env_bytes

        check_memory(cfg.num_envs, env_bytes(cfg))  # before any per-env array is made
        self.cfg = cfg
        self.reward_cfg = reward_cfg or RewardConfig()
        self.n = cfg.num_envs
        self.layout = ObsLayout(
            history_len=cfg.history_len,
            gait_clock=cfg.gait.enabled,
            heightmap_dim=sensors.HeightScan().num_points if cfg.perception else 0,
            depth_hw=(sensors.DepthCamera().height, sensors.DepthCamera().width) if cfg.perception else None,
        )
        self.rng = np.random.default_rng(cfg.seed)
        self.bank = TerrainBank.from_name(cfg.terrain, cfg.terrain_cfg, seed=cfg.seed)
        self.curriculum = TerrainCurriculum(
            self.bank,
            self.n,
            self.rng,
            cfg.max_init_level,
            enabled=cfg.curriculum,
            shares=cfg.type_shares(),
            rule=cfg.curriculum_rule,
            floors=cfg.type_floors(),
        )
        self.model = build_model(cfg.sim_dt, self.bank)
        if self.model.nhfield or cfg.randomization.terms:
            # one world per env: its own tile and its own randomised parameters
            # (memory: envs x one tile, not envs x the terrain)
            check_memory(self.n, env_bytes(cfg, self.model.nbuffer), "the envs and their worlds")
            models = [copy.copy(self.model) for _ in range(self.n)]
        else:
            models = [self.model] * self.n
        self.physics = make_physics(models, cfg.decimation, cfg.nthread, backend, self.bank)
        self._apply_tiles(np.arange(self.n))
        self.randomizer = Randomizer(cfg.randomization, self.physics, cfg.sim_dt, cfg.decimation)
        self.edge = self.bank.half_extent - EDGE_MARGIN_M
        self.height_scan = sensors.HeightScan() if cfg.perception else None
        self.camera = sensors.DepthCamera() if cfg.perception else None
        # (N, H, W) held frames with perception. Never written in place once handed out in an
        # observation: a render replaces it (copy-on-write), so observations need no copy of it.
        self.depth = np.zeros((self.n, 0, 0), dtype=np.float32)
        self._depth_stale = np.zeros(self.n, dtype=bool)  # reset since the last render
        self._depth_renderer = None  # a WarpDepthRenderer on a GPU, else the numba ray march
        if self.camera is not None:
            self.depth = np.full(
                (self.n, self.camera.height, self.camera.width), self.camera.far, dtype=np.float32
            )
            self._depth_max = sensors.depth_max_maps(self.bank.heights)
            # the ray march runs where the physics does when that is a GPU; on warp's CPU device
            # (one thread a kernel) the numba renderer is the faster one
            if self.physics.device != "cpu":
                from tron1cli.env.depth_warp import WarpDepthRenderer

                self._depth_renderer = WarpDepthRenderer(
                    self.bank.heights, self._depth_max, self.camera, self.bank.res, self.physics.device
                )
            cam = self.model.camera(robot.CAMERA_NAME)
            self._cam_pos_b = cam.pos.copy()
            self._cam_rot_b = quat_to_mat(cam.quat[None])[0]
        self._depth_clock = 0.0
        self.policy_dt = cfg.policy_dt
        self.max_episode_steps = cfg.max_episode_steps
        climb_types = [t for g in FACE_CLIMB_GROUPS for t in TERRAIN_GROUPS[g]]
        facing = np.isin(np.asarray(self.bank.types)[self.curriculum.kind], climb_types)
        self.commands = Commands(cfg.commands, self.n, cfg.gait, facing=facing)
        if self.reward_cfg.clock_terms and not cfg.gait.enabled:
            raise ValueError("the reward has gait-schedule terms but the env's gait prior is off")
        self.rewards = RewardManager(self.reward_cfg, self.n, self.policy_dt)
        self.lipm = LipmTracker(self.n, self.reward_cfg.lipm_kp, self.reward_cfg.z_c)
        nj = robot.NUM_JOINTS
        self.actions = np.zeros((self.n, nj))
        self.last_actions = np.zeros((self.n, nj))
        self.last_last_actions = np.zeros((self.n, nj))
        self.targets = np.tile(robot.DEFAULT_POSE, (self.n, 1))
        self.external_wrench = np.zeros((self.n, 6))  # world frame force (N), torque (N m) on the base
        self.pusher = Pusher(cfg.pushes, self.n, self.external_wrench)
        self._prev_targets = np.tile(robot.DEFAULT_POSE, (self.n, 1))
        self.episode_step = np.zeros(self.n, dtype=np.int64)
        self._steps_since_reset = np.zeros(self.n, dtype=np.int64)  # physics time = this x policy dt
        self.unstable_count = 0
        self._ctrl = np.zeros((self.n, cfg.decimation, nj))
        self._history = np.zeros((self.n, cfg.history_len, self.layout.proprio_dim), dtype=np.float32)
        self._noise = {k: getattr(cfg.noise, k) for k in ("ang_vel", "gravity", "joint_pos", "joint_vel")}
        self.state: RobotState | None = None
        self.obs: dict[str, np.ndarray] = {}

    # -- resets -----------------------------------------------------------------------------
    def reset(self, stagger: bool = False) -> dict[str, np.ndarray]:
        """Reset every env; return the first observation groups.

        stagger: start each episode's clock at a random point of the episode length, so that
        time-outs spread over time instead of arriving all at once (training).
        """
        ids = np.arange(self.n)
        self._reset_envs(ids)
        if stagger:
            self.episode_step[:] = self.rng.integers(0, self.max_episode_steps, self.n)
        self.state = read_state(self.physics)
        self._steer()
        self.lipm.reset(ids, self.state.foot_pos)
        self._depth_stale[:] = False
        self._render_depth(np.arange(self.cfg.depth_from, self.n))  # a first capture for every student
        self.obs = self._observe(ids_reset=ids)
        return self.obs

    def _reset_envs(self, ids: np.ndarray) -> None:
        k = len(ids)
        if k == 0:
            return
        c = self.cfg.init
        rng = self.rng
        qpos = np.zeros((k, self.physics.nq))
        qvel = np.zeros((k, self.physics.nv))
        qpos[:, 2] = c.base_height
        yaw = rng.uniform(-np.pi, np.pi, k) if c.random_yaw else np.zeros(k)
        tilt = rng.uniform(-c.tilt_noise, c.tilt_noise, (k, 2))
        qpos[:, 3:7] = quat_from_euler(tilt[:, 0], tilt[:, 1], yaw)
        jp = robot.DEFAULT_POSE + rng.uniform(-c.joint_pos_noise, c.joint_pos_noise, (k, robot.NUM_JOINTS))
        qpos[:, 7:] = np.clip(jp, robot.JOINT_RANGES[:, 0], robot.JOINT_RANGES[:, 1])
        qvel[:, 0:6] = rng.uniform(-c.base_vel_noise, c.base_vel_noise, (k, 6))
        qvel[:, 6:] = rng.uniform(-c.joint_vel_noise, c.joint_vel_noise, (k, robot.NUM_JOINTS))
        self.randomizer.apply(ids, rng)
        self.physics.set_state(ids, qpos, qvel)
        self.targets[ids] = robot.DEFAULT_POSE
        self.physics.forward(ids, self.targets[ids])
        self.actions[ids] = 0.0
        self.last_actions[ids] = 0.0
        self.last_last_actions[ids] = 0.0
        self.pusher.reset(ids, rng)
        self.episode_step[ids] = 0
        self._steps_since_reset[ids] = 0
        self.commands.resample(ids, rng)
        self.commands.restart_clock(ids)
        self._depth_stale[ids] = True  # an empty frame until the next capture (_refresh_depth)

    # -- stepping ---------------------------------------------------------------------------
    def step(self, actions: np.ndarray) -> StepResult:
        """Advance every env by one policy step with ``actions`` (N, 6), unitless."""
        if self.state is None:
            raise RuntimeError("call reset() before step()")
        self.last_last_actions[:] = self.last_actions
        self.last_actions[:] = self.actions
        self.actions[:] = np.clip(actions, -ACTION_CLIP, ACTION_CLIP)
        self._prev_targets[:] = self.targets
        self.targets[:] = robot.DEFAULT_POSE + robot.ACTION_SCALE * self.actions
        # the swing fold at the phase the policy saw with this action
        self.targets[:] = fold_targets(
            self.targets, self.commands.gait_phase, self.cfg.gait, robot.DEFAULT_POSE
        )
        self._ctrl[:] = self.targets[:, None, :]
        late = np.arange(self.cfg.decimation)[None, :] < self.randomizer.delay_steps[:, None]
        if late.any():  # system delay: the old target holds until the new one arrives
            self._ctrl[late] = np.broadcast_to(self._prev_targets[:, None, :], self._ctrl.shape)[late]
        self.pusher.tick(self.policy_dt, self.rng)
        self.randomizer.gate_restitution(self.state.foot_in_contact, self.state.foot_vel[:, :, 2])
        self.physics.step(self._ctrl, self.external_wrench)
        self.episode_step += 1
        self._steps_since_reset += 1

        phys = self.physics
        unstable = terminations.unstable_sim(
            phys.state, self._steps_since_reset * self.policy_dt, phys.qvel, self.cfg.termination.max_qvel
        )
        if unstable.any():
            # a diverged world's arrays are meaningless: put the env back to a clean state first
            bad = np.flatnonzero(unstable)
            self.unstable_count += len(bad)
            self._reset_envs(bad)
        self.state = read_state(phys)
        xy = self.state.base_pos[:, :2]
        term = terminations.check(
            self.cfg.termination,
            self.state.projected_gravity,
            self.state.body_contact,
            unstable,
            self.episode_step,
            self.max_episode_steps,
            left_tile=np.abs(xy).max(axis=1) > self.edge,
        )
        self._update_lipm()
        rewards = self.rewards.compute(self)
        if unstable.any():
            for r in rewards.values():
                r[unstable] = 0.0
        self.commands.tick(self.policy_dt, self.rng)

        done = term.done
        ids = np.flatnonzero(done)
        terminal_obs = self._observe(ids_reset=None, update_history=False) if len(ids) else {}
        scan_before = terminal_obs.get("heightmap")
        episode = {
            "length_s": self._steps_since_reset[ids] * self.policy_dt,
            "time_out": term.time_out[ids],
            "staggered": self.episode_step[ids] != self._steps_since_reset[ids],
        }
        for name, sums in self.rewards.pop_episode_sums(ids).items():
            episode[f"reward/{name}"] = sums
        if len(ids):
            full = ~episode["staggered"]  # a cut-short first episode would read as a slow walker
            judged = ids[full]
            commanded = np.linalg.norm(self.commands.value[judged, :2], axis=1) * episode["length_s"][full]
            ends = EpisodeEnds(np.linalg.norm(xy[judged], axis=1), commanded, term.failed[judged])
            changed = self.curriculum.update(judged, ends)
            self._apply_tiles(changed)
            self._reset_envs(ids)
            self.state.assign(ids, read_state(phys, ids))
            self.lipm.reset(ids, self.state.foot_pos[ids])
        self._steer()  # after the resets: their yaw
        self._depth_clock += self.policy_dt
        scheduled = self._depth_clock >= 1.0 / self.cfg.depth_hz
        if scheduled:
            self._depth_clock -= 1.0 / self.cfg.depth_hz
        self._refresh_depth(scheduled)
        self.obs = self._observe(ids_reset=ids, scan_before=scan_before)
        return StepResult(
            obs=self.obs,
            terminal_obs=terminal_obs,
            rewards=rewards,
            done=done,
            time_out=term.time_out,
            failed=term.failed,
            unstable=term.unstable,
            fall_causes=term.causes,
            episode=episode,
        )

    def pin_terrain_level(self, level: int) -> None:
        """Evaluation: every env on terrain ``level`` (-1 = hardest), no curriculum; call before reset."""
        self.curriculum.pin(level)
        self._apply_tiles(np.arange(self.n))

    def _apply_tiles(self, ids: np.ndarray) -> None:
        """Give the worlds of envs ``ids`` the height field of their curriculum tile (a plane, flat
        terrain, has no tile to swap)."""
        if self.model.nhfield:
            self.physics.set_tiles(ids, self.bank, self.curriculum.tile[ids])

    def curriculum_state(self) -> dict[str, np.ndarray]:
        """Each env's terrain level and tile (N,) each: what a resumed run needs to go on climbing."""
        return {"level": self.curriculum.level.copy(), "tile": self.curriculum.tile.copy()}

    def restore_curriculum(self, state: dict[str, np.ndarray]) -> None:
        """Put the envs on the levels of :meth:`curriculum_state`, taken from a run on this terrain
        bank; call before reset. Dealt the same terrain types (a resumed run), every env goes back
        to its own level and tile; otherwise (another env count or terrain mix) each env takes the
        level of a saved env of its type (:meth:`TerrainCurriculum.carry_levels`). Envs below their
        type's level floor then move up to it, on a new tile.

        ValueError when the state names tiles outside this bank or levels other than its tiles'."""
        level, tile = np.asarray(state["level"]), np.asarray(state["tile"])
        if level.ndim != 1 or tile.shape != level.shape or not len(level):
            raise ValueError(f"curriculum state of {level.shape} levels and {tile.shape} tiles")
        if tile.min() < 0 or tile.max() >= self.bank.K:
            raise ValueError("curriculum state names tiles outside this terrain bank")
        if np.any(self.bank.level[tile] != level):
            raise ValueError("curriculum state puts envs on other levels than its tiles")
        kind = self.bank.kind[tile]
        if np.array_equal(kind, self.curriculum.kind):
            self.curriculum.level[:] = level
            self.curriculum.tile[:] = tile
        else:
            self.curriculum.carry_levels(kind, level)
        self.curriculum.lift_to_floor()
        self._apply_tiles(np.arange(self.n))

    def ground_height(self, xy: np.ndarray) -> np.ndarray:
        """Terrain height (m) under world points ``xy`` (N, 2), each env on its own tile."""
        return ground_height(self.bank.heights, self.curriculum.tile, xy, self.bank.res)

    def highest_ground(self, xy: np.ndarray, reach_m: float) -> np.ndarray:
        """Highest terrain (m) within ``reach_m`` of world points ``xy`` (N, 2), each env on its own
        tile (:func:`tron1cli.env.terrain.highest_ground_height`)."""
        return highest_ground_height(self.bank.heights, self.curriculum.tile, xy, self.bank.res, reach_m)

    def lipm_ground_height(self, xy: np.ndarray) -> np.ndarray:
        """Ground height (m) of the LIPM constraint plane under world points ``xy`` (N, 2): the
        terrain averaged over a ``reward_cfg.lipm_ground_window_m`` square (README, eq. 2-3), so
        that a stair edge passing under the CoM does not make the intercept jump. 0 on a plane."""
        if not self.model.nhfield:
            return np.zeros(len(xy))
        side = self.reward_cfg.lipm_ground_window_m
        return mean_ground_height(self.bank.heights, self.curriculum.tile, xy, self.bank.res, side)

    def camera_pose(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World position (k, 3) and rotation (k, 3, 3; MuJoCo camera axes) of the depth camera."""
        rot_b = quat_to_mat(self.physics.qpos[ids, 3:7])
        offset = self._cam_pos_b + self.randomizer.camera_offset[ids]
        pos = self.physics.qpos[ids, 0:3] + np.einsum("nij,nj->ni", rot_b, offset)
        # mount pitch error: a rotation about the camera's own x (right) axis
        a = self.randomizer.camera_pitch[ids]
        c, s_ = np.cos(a), np.sin(a)
        rx = np.zeros((len(ids), 3, 3))
        rx[:, 0, 0] = 1.0
        rx[:, 1, 1], rx[:, 1, 2], rx[:, 2, 1], rx[:, 2, 2] = c, -s_, s_, c
        return pos, rot_b @ self._cam_rot_b @ rx

    def depth_ray_scale(self, ids: np.ndarray) -> np.ndarray:
        """Per-env factor (k,) on the depth camera's ray directions from its randomised field of
        view (1 for the nominal camera; see :func:`sensors.fov_ray_scale`)."""
        return sensors.fov_ray_scale(self.camera, self.randomizer.camera_fov_delta[ids])

    def _refresh_depth(self, scheduled: bool) -> None:
        """A 30 Hz capture (``scheduled``) renders every student's camera. Between captures a
        student reset since the last one holds an empty frame (0 = no return) until the next
        capture, at most one policy step: the camera keeps its own clock, and a new episode must
        not see the last one's view."""
        first = self.cfg.depth_from
        stale = first + np.flatnonzero(self._depth_stale[first:])
        self._depth_stale[:] = False
        if scheduled:
            self._render_depth(np.arange(first, self.n))
        elif len(stale) and self.camera is not None:
            self.set_depth(stale, np.zeros((len(stale),) + self.depth.shape[1:], dtype=np.float32))

    def _render_depth(self, ids: np.ndarray) -> None:
        """Render the depth camera of envs ``ids`` (the frame is then held until the next render).

        Only the terrain is rendered: the robot's own legs never appear in the image (the camera
        looks 50 deg down and forward, where the real legs are rarely in view).
        """
        if self.camera is None or len(ids) == 0:
            return
        pos, rot = self.camera_pose(ids)
        tiles, scale = self.curriculum.tile[ids], self.depth_ray_scale(ids)
        if self._depth_renderer is not None:
            img = self._depth_renderer.render(tiles, pos, rot, scale)
        else:
            img = sensors.render_depth(
                self.bank.heights,
                tiles,
                pos,
                rot,
                self.camera,
                self.bank.res,
                max_maps=self._depth_max,
                ray_scale=scale,
            )
        if self.cfg.noise.enabled:
            img = sensors.add_depth_noise(img, self.camera, self.rng, out=img)
        self.set_depth(ids, img)

    def set_depth(self, ids: np.ndarray, images: np.ndarray) -> None:
        """Hold ``images`` (k, H, W) as the depth frames of envs ``ids`` (copy-on-write: arrays
        already handed out in observations keep their frames)."""
        depth = self.depth.copy()
        depth[ids] = images
        self.depth = depth

    def _update_lipm(self) -> None:
        s = self.state
        self.lipm.update(
            contact_pos=s.foot_contact_pos,
            normal_force=s.foot_force[:, :, 2],
            com_pos=s.com_pos,
            com_vel_xy=s.com_vel[:, :2],
            v_cmd_xy_world=rotate_z(self.commands.value, yaw_of(s.base_quat)),
            ground_height=self.lipm_ground_height(s.com_pos[:, :2]),
            roll_rate=s.base_ang_vel_b[:, 0],
            pitch_rate=s.base_ang_vel_b[:, 1],
        )

    # -- observations -----------------------------------------------------------------------
    def term_values(self) -> dict[str, np.ndarray]:
        """Physical value of every observation term by name, each (N, dim)."""
        s = self.state
        return {
            **proprio_values(
                s.base_ang_vel_b,
                s.projected_gravity,
                s.joint_pos,
                s.joint_vel,
                self.commands.value,
                self.actions,
                robot.DEFAULT_POSE,
                clock_observation(self.commands.gait_phase, self.commands.gait_freq),
            ),
            "base_lin_vel": s.base_lin_vel_b,
            "joint_torque": s.joint_torque,
            "joint_acc": s.joint_acc,
            "foot_contact_force": s.foot_force.reshape(self.n, -1),
            "external_force": self.external_wrench[:, :3],
        }

    def desired_contact(self) -> np.ndarray:
        """Desired contact (N, 2) in [0, 1] of the left and right foot under the gait clock."""
        g = self.cfg.gait
        return desired_contact(leg_phases(self.commands.gait_phase, g.offset), g.stance, g.width)

    def _steer(self) -> None:
        """Heading mode: the yaw-rate commands from the robots' yaw (no work otherwise)."""
        if self.cfg.commands.heading:
            self.commands.steer(yaw_of(self.state.base_quat))

    def _observe(
        self, ids_reset: np.ndarray | None, update_history: bool = True, scan_before: np.ndarray | None = None
    ) -> dict[str, np.ndarray]:
        """Observation groups of the current state. ``scan_before``: the height scan of this same
        state before the envs ``ids_reset`` were reset, so that only those are scanned again."""
        values = self.term_values()
        lay = self.layout
        noise = self._noise if self.cfg.noise.enabled else None
        proprio = assemble(lay.proprio_terms, values, noise, self.rng)
        privileged = assemble(lay.privileged_terms, values)
        if update_history:
            push_history(self._history, proprio, ids_reset)
            history = self._history.reshape(self.n, -1).copy()
        else:
            history = np.concatenate([self._history[:, 1:], proprio[:, None, :]], axis=1).reshape(self.n, -1)
        obs = {"proprio": proprio, "history": history, "privileged": privileged}
        if self.height_scan is not None:
            s = self.state
            if scan_before is None or ids_reset is None:
                obs["heightmap"] = self.height_scan.scan(
                    self.bank.heights, self.curriculum.tile, s.base_pos, yaw_of(s.base_quat), self.bank.res
                )
            else:
                obs["heightmap"] = scan_before.copy()
                if len(ids_reset):
                    obs["heightmap"][ids_reset] = self.height_scan.scan(
                        self.bank.heights,
                        self.curriculum.tile[ids_reset],
                        s.base_pos[ids_reset],
                        yaw_of(s.base_quat[ids_reset]),
                        self.bank.res,
                    )
            obs["depth"] = self.depth  # shared, not copied: renders replace it (do not write to it)
        return obs

    def close(self) -> None:
        self.physics.close()
