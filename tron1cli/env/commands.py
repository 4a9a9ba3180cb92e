"""Velocity commands: v_x, v_y (m/s, base yaw frame) and yaw rate (rad/s) per env."""

from __future__ import annotations

import numpy as np

from tron1cli.config.env import CommandConfig, GaitConfig
from tron1cli.env.math3d import wrap_angle


class Commands:
    """Per-env velocity commands and gait clock, resampled together at random intervals.

    Attributes:
        value: current command (N, 3): v_x, v_y, yaw rate.
        time_left: seconds until each env's next resample (N,).
        gait_freq: gait frequency (N,) in Hz; gait_phase: clock phase (N,) in [0, 1).
        facing: (N,) bool, the envs whose commands face the climb (with ``cfg.face_climb``).
        heading: world heading (N,) in rad that each env is steered to (with ``cfg.heading``; drawn
        as an offset from the robot's yaw, which the first :meth:`steer` after a draw adds);
        steering: (N,) bool, the envs whose yaw rate :meth:`steer` sets (heading mode, moving
        command, not imposed by :meth:`set`).
    """

    def __init__(
        self,
        cfg: CommandConfig,
        num_envs: int,
        gait: GaitConfig | None = None,
        facing: np.ndarray | None = None,
    ) -> None:
        self.cfg = cfg
        self.gait = gait or GaitConfig()
        self.facing = np.zeros(num_envs, dtype=bool) if facing is None else np.asarray(facing, dtype=bool)
        if self.facing.shape != (num_envs,):
            raise ValueError(f"facing must be ({num_envs},), got {self.facing.shape}")
        self.value = np.zeros((num_envs, 3))
        self.time_left = np.zeros(num_envs)
        self.gait_freq = np.full(num_envs, float(np.mean(self.gait.freq_hz)))
        self.gait_phase = np.zeros(num_envs)
        self.heading = np.zeros(num_envs)
        self.steering = np.zeros(num_envs, dtype=bool)
        self._unanchored = np.zeros(num_envs, dtype=bool)  # heading still an offset from the yaw

    def resample(self, ids: np.ndarray, rng: np.random.Generator) -> None:
        """Draw new commands and resample intervals for envs ``ids``."""
        k = len(ids)
        if k == 0:
            return
        c = self.cfg
        lo = np.array([c.lin_vel_x[0], c.lin_vel_y[0], c.ang_vel_yaw[0]])
        hi = np.array([c.lin_vel_x[1], c.lin_vel_y[1], c.ang_vel_yaw[1]])
        cmd = rng.uniform(lo, hi, size=(k, 3))
        if c.face_climb:
            up = self.facing[ids]
            cmd[up, 0] = np.abs(cmd[up, 0])
            cmd[up, 1] = 0.0
        standing = rng.random(k) < c.standing_share
        cmd[standing] = 0.0
        self.value[ids] = cmd
        self.time_left[ids] = rng.uniform(*c.resample_s, size=k)
        self.gait_freq[ids] = rng.uniform(*self.gait.freq_hz, size=k)
        if c.heading:  # drawn last, so that the other draws do not depend on the mode
            self.heading[ids] = rng.uniform(-c.heading_spread_rad, c.heading_spread_rad, size=k)
            self._unanchored[ids] = True
            self.value[ids, 2] = 0.0  # until steer() sees the robot's yaw
            self.steering[ids] = ~standing

    def steer(self, yaw: np.ndarray) -> None:
        """Heading mode: set the yaw-rate command of the steering envs from their yaw (N,) in rad,
        ``heading_kp * wrap(heading - yaw)`` clipped to the yaw-rate range, after anchoring the
        headings drawn since the last call to the robot's yaw. No-op otherwise."""
        fresh = self._unanchored
        self.heading[fresh] = wrap_angle(self.heading[fresh] + yaw[fresh])
        fresh[:] = False
        if not self.steering.any():
            return
        c, ids = self.cfg, np.flatnonzero(self.steering)
        err = wrap_angle(self.heading[ids] - yaw[ids])
        self.value[ids, 2] = np.clip(c.heading_kp * err, *c.ang_vel_yaw)

    def restart_clock(self, ids: np.ndarray) -> None:
        """Restart the gait clock of envs ``ids`` at phase 0 (at reset)."""
        self.gait_phase[ids] = 0.0

    def tick(self, dt: float, rng: np.random.Generator) -> np.ndarray:
        """Advance the clocks and timers by ``dt`` (s); resample those that ran out; return their ids."""
        self.gait_phase = (self.gait_phase + self.gait_freq * dt) % 1.0
        self.time_left -= dt
        due = np.flatnonzero(self.time_left <= 0.0)
        self.resample(due, rng)
        return due

    def set(self, ids: np.ndarray, value: np.ndarray, hold_s: float = np.inf) -> None:
        """Impose commands (k, 3) on envs ``ids`` for ``hold_s`` seconds (eval, deploy); heading
        mode stops steering them."""
        self.value[ids] = value
        self.steering[ids] = False
        self.time_left[ids] = hold_s
