"""deploy-robot: an exported student policy driving a TRON1 (or ``sim-robot``) through LimX's SDK.

Observation: exactly the contract's. o_t is built by the env's own code
(:func:`tron1cli.env.observations.proprio_values`, :func:`~tron1cli.env.observations.assemble`,
:func:`~tron1cli.env.observations.push_history`) with the layout rebuilt from the policy's training
configuration and checked against the contract, so deploy-robot and training cannot drift apart.
Joints are mapped between the policy's order and the SDK's motor order by name
(:func:`map_motors`), never by position. The gait clock starts at phase 0 when the policy takes
over and advances by f x dt per policy step, f the middle of the trained range (as deploy-sim).

Phases, all at the contract's policy rate (50 Hz) on the wall clock, each step acting on the
first state message after its tick:

1. connect: wait for state and IMU messages (``connect_timeout_s``);
2. ramp: from the measured joint pose to the contract's default pose over ``ramp_s`` (smooth
   step), contract Kp/Kd; the robot should hang on its hoist (a point foot cannot stand);
3. policy: target = default pose + action scale x action, clipped to the joint ranges;
4. stop: the damping command (Kp 0, Kd > 0, zero torque) for ``damping_s``.

A perceptive policy holds the default pose after the ramp until its depth source has delivered
a frame (at most ``connect_timeout_s``), and each policy step takes the newest frame.

Safety trips (each one line on stderr, then damping): no state or IMU message for more than
``watchdog_s`` (lost link), no depth frame for more than ``depth_timeout_s`` (lost depth), base
tilt past ``max_tilt_rad``, a non-finite state or action, Ctrl-C.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from tron1cli.config.env import GaitConfig
from tron1cli.deploy.schedule import CommandSchedule
from tron1cli.env import robot
from tron1cli.env.core import ACTION_CLIP
from tron1cli.env.gait import clock_observation, fold_targets
from tron1cli.env.math3d import quat_rotate_inverse
from tron1cli.env.observations import ObsLayout, assemble, proprio_values, push_history
from tron1cli.errors import Tron1Error, UsageError
from tron1cli.policy.contract import check_matches_env, layout_of
from tron1cli.policy.runtime import Policy

#: joystick axes (SensorJoy.axes indices) of v_x, v_y and yaw rate, and their signs
JOY_AXES = ((1, 1.0), (0, 1.0), (3, 1.0))


def map_motors(joint_names: list[str], motor_names: list[str], where: str) -> np.ndarray:
    """Index into the SDK's motor arrays of each policy joint, matched by name (``hip_L`` is the
    motor ``hip_L`` or ``hip_L_Joint``, case aside). Tron1Error when the two sets differ."""
    key = {m.lower().removesuffix("_joint"): i for i, m in enumerate(motor_names)}
    missing = [j for j in joint_names if j.lower().removesuffix("_joint") not in key]
    if missing or len(joint_names) != len(motor_names) or len(key) != len(motor_names):
        why = f"no motor for {', '.join(missing)}" if missing else "another number of joints"
        raise Tron1Error(
            f"{where}: the policy's joints {list(joint_names)} do not match the robot's motors "
            f"{list(motor_names)} ({why})"
        )
    return np.array([key[j.lower().removesuffix("_joint")] for j in joint_names])


class Observer:
    """The student's observation from SDK messages, by the env's own code (module docstring)."""

    def __init__(
        self, layout: ObsLayout, default_pose: np.ndarray, gait_freq_hz: float, gait: GaitConfig | None = None
    ) -> None:
        """``gait``: the policy's gait prior (its swing fold, offset and stance; None: no fold)."""
        self.gait = gait or GaitConfig()
        self.layout = layout
        self.default_pose = np.asarray(default_pose, dtype=float)
        self.freq = np.array([gait_freq_hz])
        self.phase = np.zeros(1)
        self.last_action = np.zeros((1, len(default_pose)))
        self.hist = np.zeros((1, layout.history_len, layout.proprio_dim), dtype=np.float32)
        self.started = False

    def observe(self, q, dq, quat, gyro, command) -> np.ndarray:
        """History input (1, history_len x proprio) after one o_t of joint q (rad), dq (rad/s) in
        the policy's order, IMU quat (w, x, y, z), gyro (rad/s, base frame) and command (3,)."""
        quat = np.asarray(quat, dtype=float)[None]
        grav = quat_rotate_inverse(quat / np.linalg.norm(quat), np.array([[0.0, 0.0, -1.0]]))
        clock = clock_observation(self.phase, self.freq) if self.layout.gait_clock else None
        values = proprio_values(
            np.asarray(gyro, dtype=float)[None],
            grav,
            np.asarray(q, dtype=float)[None],
            np.asarray(dq, dtype=float)[None],
            np.asarray(command, dtype=float)[None],
            self.last_action,
            self.default_pose,
            clock,
        )
        proprio = assemble(self.layout.proprio_terms, values)
        push_history(self.hist, proprio, None if self.started else np.zeros(1, dtype=np.int64))
        self.started = True
        return self.hist.reshape(1, -1).copy()

    def folded(self, targets: np.ndarray, phase: np.ndarray) -> np.ndarray:
        """Joint targets (6,) rad with the swing fold at clock ``phase`` (1,), as the env applies
        it (``targets`` unchanged without one)."""
        return fold_targets(targets[None], phase, self.gait, self.default_pose)[0]

    def advance(self, action: np.ndarray, dt: float) -> np.ndarray:
        """Record the applied action (clipped as in the env) and tick the clock by ``dt`` (s);
        returns the clipped action."""
        self.last_action = np.clip(np.asarray(action, dtype=float).reshape(1, -1), -ACTION_CLIP, ACTION_CLIP)
        self.phase = (self.phase + self.freq * dt) % 1.0
        return self.last_action[0]


def tilt_of(quat) -> float:
    """Angle (rad) between the base's z axis and the vertical."""
    q = np.asarray(quat, dtype=float)[None]
    g = quat_rotate_inverse(q / np.linalg.norm(q), np.array([[0.0, 0.0, -1.0]]))[0]
    return float(math.acos(float(np.clip(-g[2], -1.0, 1.0))))


@dataclass(frozen=True)
class RobotConfig:
    """One deploy-robot run.

    ip: the robot's address (127.0.0.1 for sim-robot); schedule: velocity commands over policy
    time; joystick: commands from the SDK's joystick instead; duration_s: policy seconds (None:
    until Ctrl-C); ramp_s: the stand-up ramp; watchdog_s: longest silence of state or IMU;
    max_tilt_rad: base tilt limit; depth_timeout_s: oldest depth frame a perceptive policy may
    act on (30 Hz frames: 7 in a row lost); damping_kd: Kd of the damping command (N m s/rad); damping_s:
    how long it is sent at the end; connect_timeout_s: wait for the first messages; gait_freq_hz:
    the gait clock's frequency (Hz, in the policy's trained range), None for the middle of it.
    """

    ip: str = "127.0.0.1"
    schedule: CommandSchedule = field(default_factory=lambda: CommandSchedule.constant((0.0, 0.0, 0.0)))
    joystick: bool = False
    duration_s: float | None = None
    ramp_s: float = 2.0
    watchdog_s: float = 0.05
    max_tilt_rad: float = 0.8
    depth_timeout_s: float = 0.25
    damping_kd: float = 2.5
    damping_s: float = 0.3
    connect_timeout_s: float = 10.0
    gait_freq_hz: float | None = None


class Trip(Exception):
    """A safety trip: ``kind`` (lost link, lost depth, tilt, non-finite, interrupted) and one line of text."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


def _pct(v: list[float], q: float) -> float | None:
    return round(float(np.percentile(v, q)), 4) if v else None


class RobotController:
    """deploy-robot on one SDK link; :meth:`run` returns the report dict."""

    def __init__(self, policy: Policy, cfg: RobotConfig, link, depth=None) -> None:
        """``link``: a :class:`tron1cli.deploy.sdk.Link` (controller side, subscribed);
        ``depth``: a :class:`tron1cli.deploy.depth_source.DepthSource` for a perceptive policy."""
        c = policy.contract
        where = str(policy.path)
        self.motor_names = link.motor_names()
        self.perm = map_motors(list(c["joint_names"]), self.motor_names, where)  # the robot first
        layout = layout_of(policy.run_cfg)
        check_matches_env(c, layout, where)
        if policy.depth_hw is not None and depth is None:
            raise Tron1Error(
                f"{where} is a perceptive policy: it needs a depth source (--depth realsense or udp:PORT)"
            )
        self.policy, self.cfg, self.link, self.depth = policy, cfg, link, depth
        hw = policy.depth_hw
        self.blank_depth = np.zeros((1, *(hw or (1, 1))), dtype=np.float32)  # the input's shape
        self.default = np.asarray(c["default_pose_rad"], dtype=float)
        self.scale = float(c["action_scale_rad"])
        self.kp, self.kd = float(c["kp_nm_per_rad"]), float(c["kd_nm_s_per_rad"])
        self.dt = 1.0 / float(c["policy_hz"])
        self.ranges = robot.JOINT_RANGES  # the contract's joint order is ours (check_matches_env)
        try:
            freq = policy.run_cfg.env.gait.deployed_hz(cfg.gait_freq_hz)
        except ValueError as e:
            raise UsageError(f"--gait-freq: {e}") from None
        self.observer = Observer(layout, self.default, freq, policy.run_cfg.env.gait)
        cmds = policy.run_cfg.env.commands
        self.cmd_max = np.array(
            [max(map(abs, cmds.lin_vel_x)), max(map(abs, cmds.lin_vel_y)), max(map(abs, cmds.ang_vel_yaw))]
        )
        self.latency_ms: list[float] = []
        self.policy_ms: list[float] = []
        self.late_ms: list[float] = []
        self.tilt_max = 0.0
        self.depth_age_ms: list[float] = []
        self.warnings: list[str] = []

    # -- messages ---------------------------------------------------------------------------
    def _check_link(self) -> None:
        """Trip when state or IMU have been silent past the watchdog. A silence is checked again
        after a 5 ms wait first: when this process itself was descheduled, messages already in
        the socket are handed on then, and the link is judged, not this process's scheduling."""
        for kind in ("state", "imu"):
            m = self.link.get(kind)
            if m is None or time.perf_counter() - m.t <= self.cfg.watchdog_s:
                continue
            deadline = time.perf_counter() + 0.005
            while time.perf_counter() - self.link.get(kind).t > self.cfg.watchdog_s:
                if time.perf_counter() >= deadline:
                    break
                self.link.wait(0.001)
            m, now = self.link.get(kind), time.perf_counter()
            if now - m.t > self.cfg.watchdog_s:
                raise Trip(
                    "lost link",
                    f"lost the link to the robot: no {kind} message for {1e3 * (now - m.t):.0f} ms "
                    f"(watchdog {1e3 * self.cfg.watchdog_s:.0f} ms)",
                )

    def _fresh_state(self, after: int):
        """Wait for a state message newer than count ``after``; returns (state, imu) in the
        policy's joint order, checked (watchdog, finiteness, tilt)."""
        while True:
            st = self.link.get("state")
            if st is not None and st.count > after:
                break
            self._check_link()
            self.link.wait(0.002)
        imu = self.link.get("imu")
        q, dq = st.fields["q"], st.fields["dq"]
        if len(q) != len(self.motor_names) or len(dq) != len(self.motor_names):
            n = len(self.motor_names)
            raise Trip("bad state", f"a state message holds {len(q)} joints, the robot has {n}")
        quat, gyro = imu.fields["quat"], imu.fields["gyro"]
        if not all(np.all(np.isfinite(x)) for x in (q, dq, quat, gyro)) or not np.linalg.norm(quat) > 0:
            raise Trip("non-finite", "the robot sent a non-finite state or IMU message")
        tilt = tilt_of(quat)
        self.tilt_max = max(self.tilt_max, tilt)
        if tilt > self.cfg.max_tilt_rad:
            raise Trip("tilt", f"base tilted {tilt:.2f} rad, past the {self.cfg.max_tilt_rad:.2f} rad limit")
        return st, q[self.perm], dq[self.perm], quat, gyro

    def _send(self, q_des: np.ndarray, kp: float, kd: float) -> None:
        """One command: policy-order targets (rad) to the SDK's motor order."""
        n = len(self.motor_names)
        q = np.zeros(n)
        q[self.perm] = q_des
        zero = np.zeros(n)
        self.link.publish_command(q, zero, zero, np.full(n, kp), np.full(n, kd), self.motor_names)

    def _command(self, t: float) -> np.ndarray:
        if not self.cfg.joystick:
            return self.cfg.schedule.at(t)
        joy = self.link.get("joy")
        if joy is None:
            return np.zeros(3)
        axes = joy.fields["axes"]
        v = [sign * axes[i] if i < len(axes) else 0.0 for i, sign in JOY_AXES]
        return np.clip(np.array(v, dtype=float), -1.0, 1.0) * self.cmd_max

    # -- the run ----------------------------------------------------------------------------
    def connect(self) -> None:
        """Wait for the first state and IMU messages."""
        t0 = time.perf_counter()
        while self.link.get("state") is None or self.link.get("imu") is None:
            if time.perf_counter() - t0 > self.cfg.connect_timeout_s:
                raise Tron1Error(
                    f"no state and IMU messages from the robot at {self.cfg.ip} within "
                    f"{self.cfg.connect_timeout_s:g} s (is it on, in developer mode, on this network; "
                    "or is sim-robot running?)"
                )
            self.link.wait(0.05)

    def run(self, on_event: Callable[[str], None] | None = None) -> dict:
        """Connect, ramp, run the policy, damp; returns the report. ``on_event(line)`` is told of
        the phase changes and of a safety trip (one line each)."""
        say = on_event or (lambda line: None)
        cfg, pol, dt = self.cfg, self.policy, self.dt
        self.connect()
        hidden = pol.initial_hidden(1)
        pol.step(self.observer.hist.reshape(1, -1), self.blank_depth, hidden)  # warm-up, not timed
        ended, trip_line, steps = "duration", None, 0
        t_start = t_end = None
        count = self.link.get("state").count
        q_now = self.link.get("state").fields["q"][self.perm]
        try:
            # ramp
            say(f"ramping from the measured pose to the default pose over {cfg.ramp_s:g} s")
            q0 = q_now.copy()
            n_ramp = max(1, int(round(cfg.ramp_s / dt)))
            tick = time.perf_counter()
            for k in range(1, n_ramp + 1):
                tick = self._sleep_until(tick + dt)
                st, q_now, _, _, _ = self._fresh_state(count)
                count = st.count
                a = k / n_ramp
                self._send(q0 + (self.default - q0) * (a * a * (3.0 - 2.0 * a)), self.kp, self.kd)
            if self.depth is not None and self.depth.newest() is None:
                say("holding the default pose until the first depth frame")
                t_wait = time.perf_counter()
                while self.depth.newest() is None:
                    if time.perf_counter() - t_wait > cfg.connect_timeout_s:
                        raise Trip("lost depth", f"no depth frame within {cfg.connect_timeout_s:g} s")
                    tick = self._sleep_until(tick + dt)
                    st, q_now, _, _, _ = self._fresh_state(count)
                    count = st.count
                    self._send(self.default, self.kp, self.kd)
            # policy
            say("policy in control" + (f" for {cfg.duration_s:g} s" if cfg.duration_s else " (Ctrl-C stops)"))
            t_start = time.monotonic()
            total = None if cfg.duration_s is None else int(round(cfg.duration_s / dt))
            while total is None or steps < total:
                tick = self._sleep_until(tick + dt)
                st, q_now, dq, quat, gyro = self._fresh_state(count)
                count = st.count
                hist = self.observer.observe(q_now, dq, quat, gyro, self._command(steps * dt))
                t0 = time.perf_counter()
                action, hidden, _, _ = pol.step(hist, self._depth_in(), hidden)
                self.policy_ms.append(1e3 * (time.perf_counter() - t0))
                if not np.all(np.isfinite(action)):
                    raise Trip("non-finite", "the policy returned a non-finite action")
                phase = self.observer.phase  # the phase this action was computed for (advance replaces it)
                a = self.observer.advance(action[0], dt)
                q_des = self.observer.folded(self.default + self.scale * a, phase)
                q_des = np.clip(q_des, self.ranges[:, 0], self.ranges[:, 1])
                self._send(q_des, self.kp, self.kd)
                self.latency_ms.append(1e3 * (time.perf_counter() - st.t))
                steps += 1
            t_end = time.monotonic()
        except Trip as e:
            ended, trip_line = e.kind, str(e)
        except KeyboardInterrupt:
            ended, trip_line = "interrupted", "interrupted (Ctrl-C)"
        if t_start is not None and t_end is None:
            t_end = time.monotonic()
        self._damp(q_now, lost=ended == "lost link")
        return self._report(ended, trip_line, steps, t_start, t_end)

    def _depth_in(self) -> np.ndarray:
        """The policy's depth input: the newest frame (1, rows, cols); trips when it is too old."""
        if self.depth is None:
            return self.blank_depth
        age = self.depth.age_s()
        if age > self.cfg.depth_timeout_s:
            limit = 1e3 * self.cfg.depth_timeout_s
            raise Trip("lost depth", f"no depth frame for {1e3 * age:.0f} ms (limit {limit:.0f} ms)")
        self.depth_age_ms.append(1e3 * age)
        frame = self.depth.newest()
        return frame[None].astype(np.float32)

    def _sleep_until(self, t: float) -> float:
        """Sleep to ``t`` (perf_counter s) checking the watchdog; returns the next tick's base
        (``t``, or now when more than a period late: the loop does not burst to catch up)."""
        while True:
            now = time.perf_counter()
            if now >= t:
                break
            self._check_link()
            time.sleep(min(t - now, 0.002))
        self.late_ms.append(1e3 * (now - t))
        return t if now - t < self.dt else now

    def _damp(self, q_now: np.ndarray, lost: bool) -> None:
        """Send the damping command for ``damping_s`` (a few times only when the link is lost)."""
        t_end = time.perf_counter() + (0.05 if lost else self.cfg.damping_s)
        try:
            while True:
                self._send(q_now, 0.0, self.cfg.damping_kd)
                if time.perf_counter() >= t_end:
                    break
                time.sleep(0.01)
        except KeyboardInterrupt:
            self._send(q_now, 0.0, self.cfg.damping_kd)

    def _report(self, ended, trip_line, steps, t_start, t_end) -> dict:
        st, imu = self.link.get("state"), self.link.get("imu")
        cmd = None if self.cfg.joystick else [float(x) for x in self.cfg.schedule.at(0.0)]
        survived = ended == "duration"
        return {
            "policy": str(self.policy.path),
            "ip": self.cfg.ip,
            "survived": survived,
            "ended": ended,
            "safety_trip": trip_line,
            "policy_steps": steps,
            "duration_s": round(steps * self.dt, 4),
            "requested_duration_s": self.cfg.duration_s,
            "ramp_s": self.cfg.ramp_s,
            "command": cmd,
            "joystick": self.cfg.joystick,
            "gait_freq_hz": float(self.observer.freq[0]) if self.observer.layout.gait_clock else None,
            "motor_names": self.motor_names,
            "vel_tracking_error": None,  # the SDK carries no base velocity: see sim-robot --report
            "max_tilt_rad": round(self.tilt_max, 4),
            "latency_ms_p50": _pct(self.latency_ms, 50),
            "latency_ms_p99": _pct(self.latency_ms, 99),
            "latency_ms_max": round(max(self.latency_ms), 4) if self.latency_ms else None,
            "policy_ms_p50": _pct(self.policy_ms, 50),
            "policy_ms_p99": _pct(self.policy_ms, 99),
            "tick_late_ms_p99": _pct(self.late_ms, 99),
            "depth_age_ms_p50": _pct(self.depth_age_ms, 50),
            "depth_age_ms_p99": _pct(self.depth_age_ms, 99),
            "state_messages": 0 if st is None else st.count,
            "imu_messages": 0 if imu is None else imu.count,
            "policy_start_monotonic_s": t_start,
            "policy_end_monotonic_s": t_end,
            "policy_hz": 1.0 / self.dt,
        }
