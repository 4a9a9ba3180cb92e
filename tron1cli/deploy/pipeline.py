"""deploy-sim: an exported student policy driving one TRON1 in MuJoCo as the robot's computer would.

Rates (those of the policy's contract unless overridden): physics at ``physics_hz`` with the PD
loop inside MuJoCo (position actuators, so the PD runs at the physics rate), the policy at
``policy_hz`` (50 Hz), the depth camera at ``depth_hz`` (30 Hz) in its own thread
(:class:`tron1cli.deploy.depth.DepthPipeline`), whose newest ready frame each policy step uses.

Observations come from the one env core (:class:`tron1cli.env.core.Tron1Env`, one env), built
from the policy's own training configuration, so they are assembled by the same code as in
training: proprioception with its noise, the history, the gait clock (advanced by the env at the
policy rate). The env's own lockstep depth rendering is switched off (``depth_from = 1``); the
depth thread renders with the same renderer and noise model instead.

The run is one episode: it ends at ``duration_s``, or earlier when the robot falls, when the
simulation goes unstable, or when it reaches the edge of its terrain tile (on a height field;
flat ground is a plane without an edge). The tile is sized as eval's are
(:func:`tron1cli.evaluation.protocol.eval_terrain_config`): the schedule's fastest command held
for the whole run stays on the terrain. Commands are pinned (no resampling) and follow the
schedule; a schedule change reaches the observation at the next policy step.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from tron1cli.config.env import CommandConfig
from tron1cli.deploy.depth import DepthFrame, DepthPipeline
from tron1cli.deploy.schedule import CommandSchedule
from tron1cli.env import sensors
from tron1cli.env.core import Tron1Env
from tron1cli.env.randomization import PushConfig, RandomizationConfig
from tron1cli.env.terminations import cause_words
from tron1cli.env.terrain import resolve_terrain
from tron1cli.errors import Tron1Error, UsageError
from tron1cli.evaluation.protocol import eval_terrain_config
from tron1cli.policy.contract import check_matches_env
from tron1cli.policy.runtime import Policy

PUSHES = {"none": PushConfig, "moderate": PushConfig.moderate, "extreme": PushConfig.extreme}


@dataclass(frozen=True)
class DeployConfig:
    """One deploy-sim run.

    terrain: terrain group (flat, rough, slopes, stairs, discrete, mixed; one type of a group is
    drawn from ``seed``); level: difficulty (0 easiest, negative from the hardest); schedule:
    velocity commands; push: none, moderate or extreme random pushes; duration_s: simulated
    seconds; realtime: pace the loop to the wall clock; seed: env, terrain and noise seed; noise:
    proprioceptive and depth sensor noise; depth_latency_ms: latency added to every depth frame;
    physics_hz: physics (and PD) rate, None for the policy's own; randomize: the policy's training
    randomisation instead of the nominal robot; viewer: MuJoCo passive viewer (needs a display);
    gait_freq_hz: the gait clock's frequency (Hz, in the policy's trained range), None for the
    middle of that range.
    """

    terrain: str = "flat"
    level: int = 0
    schedule: CommandSchedule = field(default_factory=lambda: CommandSchedule.constant((0.5, 0.0, 0.0)))
    push: str = "none"
    duration_s: float = 10.0
    realtime: bool = False
    seed: int = 0
    noise: bool = True
    depth_latency_ms: float = 0.0
    physics_hz: float | None = None
    randomize: bool = False
    viewer: bool = False
    gait_freq_hz: float | None = None


def check_display() -> None:
    """Raise Tron1Error unless a window can be opened (Linux: DISPLAY or WAYLAND_DISPLAY set)."""
    display = os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    if sys.platform.startswith("linux") and not display:
        raise Tron1Error("--viewer needs a display, but neither DISPLAY nor WAYLAND_DISPLAY is set")


def _numba_thread_safe() -> bool:
    """Whether numba's threading layer takes parallel kernels from two threads at once."""
    import numba

    try:
        return numba.threading_layer() != "workqueue"
    except ValueError:  # no parallel kernel has run yet
        return False


def _pct(values: list[float], q: float) -> float | None:
    return float(np.percentile(values, q)) if values else None


def _mean(total: float, count: int) -> float | None:
    return total / count if count else None


def _rounded(rep: dict) -> dict:
    return {k: round(v, 6) if isinstance(v, float) else v for k, v in rep.items()}


class _Viewer:
    """The MuJoCo passive viewer showing env 0's state after every policy step."""

    def __init__(self, model) -> None:
        check_display()
        import mujoco
        import mujoco.viewer

        self._mj = mujoco
        self.model = model
        self.data = mujoco.MjData(model)
        try:
            self.handle = mujoco.viewer.launch_passive(model, self.data)
        except Exception as e:  # GLFW and GL errors come in many types
            raise Tron1Error(f"cannot open the MuJoCo viewer: {type(e).__name__}: {e}") from e

    def sync(self, state_row: np.ndarray) -> bool:
        """Show ``state_row`` (a FULLPHYSICS state); False once the user closed the window."""
        from tron1cli.env.physics import STATE_SPEC

        if not self.handle.is_running():
            return False
        with self.handle.lock():
            self._mj.mj_setState(self.model, self.data, state_row, STATE_SPEC)
            self._mj.mj_forward(self.model, self.data)
        self.handle.sync()
        return True

    def close(self) -> None:
        self.handle.close()


class DeploySim:
    """One deploy-sim run of ``policy`` under ``cfg``; :meth:`run` returns the report dict."""

    def __init__(self, policy: Policy, cfg: DeployConfig, stream=None, video=None) -> None:
        """``stream``: an optional rerun stream (:mod:`tron1cli.viz.rerun_stream`) fed every policy
        step with the robot, the LIPM targets, the depth frame the policy used and h_hat;
        ``video``: an optional :class:`tron1cli.viz.video.Take` recording the robot."""
        self.policy = policy
        self.cfg = cfg
        self.stream = stream
        self.video = video
        self.env = Tron1Env(self._env_config(), policy.run_cfg.reward)
        self.depth: DepthPipeline | None = None
        self.frame_ages_ms: list[float] = []
        self._viewer: _Viewer | None = None
        try:
            check_matches_env(policy.contract, self.env.layout, str(policy.path))
            self._pin_terrain()
            sensors.warmup()  # compile (or load) the numba kernels before anything is timed
            self.numba_lock = None if _numba_thread_safe() else threading.Lock()
            if policy.depth_hw is not None:
                self.depth = DepthPipeline(
                    self.env, cfg.depth_latency_ms / 1e3, cfg.noise, cfg.seed, self.numba_lock
                )
            if cfg.viewer:
                self._viewer = _Viewer(self.env.physics.models[0])
        except BaseException:
            self.close()
            raise

    # -- set-up -----------------------------------------------------------------------------
    def _env_config(self):
        cfg, base = self.cfg, self.policy.run_cfg.env
        try:
            resolve_terrain(cfg.terrain)
        except ValueError as e:
            raise UsageError(str(e)) from None
        if cfg.push not in PUSHES:
            raise UsageError(f"unknown push level '{cfg.push}'; choose from {', '.join(PUSHES)}")
        if not cfg.duration_s > 0:
            raise UsageError(f"--duration must be positive, got {cfg.duration_s:g}")
        if cfg.depth_latency_ms < 0:
            raise UsageError(f"--depth-latency-ms must be >= 0, got {cfg.depth_latency_ms:g}")
        n_levels = base.terrain_cfg.num_levels
        if not (cfg.level == -1 or 0 <= cfg.level < n_levels):
            raise UsageError(f"--level {cfg.level} outside 0..{n_levels - 1} (or -1 for the hardest)")
        sim_dt, decimation = base.sim_dt, base.decimation
        if cfg.physics_hz is not None:
            sim_dt = 1.0 / cfg.physics_hz
            decimation = int(round(base.policy_dt / sim_dt))
            if decimation < 1 or abs(decimation * sim_dt - base.policy_dt) > 1e-9:
                raise UsageError(
                    f"--physics-hz {cfg.physics_hz:g} is not a whole multiple of the policy rate "
                    f"{1.0 / base.policy_dt:g} Hz"
                )
        v = cfg.schedule.at(0.0)
        commands = CommandConfig(  # the first command is drawn at reset, later ones are imposed
            lin_vel_x=(v[0], v[0]),
            lin_vel_y=(v[1], v[1]),
            ang_vel_yaw=(v[2], v[2]),
            resample_s=(1e9, 1e9),
            standing_share=0.0,
        )
        gait = base.gait
        try:  # one fixed frequency, the middle of the trained range unless asked
            if gait.enabled or cfg.gait_freq_hz is not None:
                gait = gait.fixed(gait.deployed_hz(cfg.gait_freq_hz))
        except ValueError as e:
            raise UsageError(f"--gait-freq: {e}") from None
        return replace(
            base,
            num_envs=1,
            nthread=1,
            seed=cfg.seed,
            sim_dt=sim_dt,
            decimation=decimation,
            terrain=cfg.terrain,
            terrain_cfg=eval_terrain_config(base.terrain_cfg, cfg.duration_s, cfg.schedule.max_speed()),
            terrain_mix={},
            level_floor={},
            curriculum=False,
            depth_from=1,  # the env renders no depth itself: the depth thread does
            randomization=base.randomization if cfg.randomize else RandomizationConfig(),
            pushes=PUSHES[cfg.push](),
            commands=commands,
            gait=gait,
            noise=replace(base.noise, enabled=cfg.noise),
            termination=base.termination.judged(cfg.duration_s + 1.0),
        )

    def _pin_terrain(self) -> None:
        env = self.env
        types = env.bank.types
        if len(types) > 1:  # one env always gets the group's first type: draw one instead
            env.curriculum.kind[:] = np.random.default_rng([self.cfg.seed, 7]).integers(len(types))
        env.pin_terrain_level(self.cfg.level)
        if env.model.nhfield == 0:
            env.edge = np.inf  # a plane has no edge
        self.terrain_type = types[int(env.curriculum.kind[0])]

    # -- the run ----------------------------------------------------------------------------
    def run(self, on_step: Callable[[int, int], None] | None = None) -> dict:
        """Run the episode; ``on_step(step, total)`` after every policy step. Returns the report
        (see :meth:`_report`).

        The control loop runs numba's kernels (ground height, height scan) on its own thread only:
        for one env, waking numba's worker threads costs more than the kernel (milliseconds per
        call on a busy machine).
        """
        import numba

        threads = numba.get_num_threads()  # a per-thread setting
        numba.set_num_threads(1)
        try:
            return self._run(on_step)
        finally:
            numba.set_num_threads(threads)

    def _run(self, on_step: Callable[[int, int], None] | None) -> dict:
        cfg, env, pol, depth = self.cfg, self.env, self.policy, self.depth
        dt = env.policy_dt
        total = int(round(cfg.duration_s / dt))
        ids = np.zeros(1, dtype=np.int64)
        lock = self.numba_lock or contextlib.nullcontext()
        obs = env.reset()
        if self.video is not None:
            self.video.start(env)
        hidden = pol.initial_hidden(1)
        d_in = pol.depth_input(obs, 1)
        pol.step(obs["history"], d_in, hidden)  # warm-up run of the runtime, not timed
        frame: DepthFrame | None = None
        capture_dt = 1.0 / float(pol.contract["depth_hz"])
        next_capture = capture_dt
        if depth is not None:
            depth.start()
            depth.capture(0.0)
            frame = depth.first()
        cmd = cfg.schedule.at(0.0)
        s = {"vel": 0.0, "com": 0.0, "zmp": 0.0, "z": 0.0, "stable": 0.0, "recon": 0.0}
        count, recon_count, pushes, pushing = 0, 0, 0, False
        policy_ms: list[float] = []
        ages_ms: list[float] = []
        self.frame_ages_ms = ages_ms  # per policy step: age (ms of sim time) of the depth frame used
        ended, steps, fell_by = "duration", 0, None
        pace = cfg.realtime or cfg.viewer
        wall0 = time.perf_counter()
        for k in range(total):
            t = k * dt
            if depth is not None:
                frame = depth.newest(t) or frame
                ages_ms.append(1e3 * (t - frame.t_capture))
                d_in = frame.image[None]
            t0 = time.perf_counter()
            action, hidden, h_hat, _ = pol.step(obs["history"], d_in, hidden)
            policy_ms.append(1e3 * (time.perf_counter() - t0))
            if h_hat.size and "heightmap" in obs:
                s["recon"] += float(np.abs(h_hat - obs["heightmap"]).mean())
                recon_count += 1
            if self.stream is not None:
                if depth is not None:
                    # the frame the policy just used (the env renders none itself)
                    env.set_depth(np.array([0]), frame.image[None])
                self.stream.log_step(env, 0, k, t, extras={"h_hat": h_hat})
            with lock:
                res = env.step(action)
            steps = k + 1
            if self.video is not None:
                self.video.step(env, steps * dt, res.done, res.failed)
            if res.done[0]:
                ended = "unstable" if res.unstable[0] else "fell" if res.failed[0] else "edge"
                fell_by = cause_words(res.fall_causes[0]) if res.failed[0] else None
                break
            obs = res.obs
            st, lp = env.state, env.lipm
            s["vel"] += float(np.linalg.norm(env.commands.value[0, :2] - st.base_lin_vel_b[0, :2]))
            s["com"] += float(np.linalg.norm(lp.p_hat[0] - lp.p_com[0]))
            s["zmp"] += float(np.linalg.norm(lp.p_com[0] - lp.zmp[0]))
            s["z"] += float(abs(lp.z[0] - lp.z_c))
            s["stable"] += float(lp.r_stable[0])
            count += 1
            now_pushing = bool(np.any(env.external_wrench[0] != 0.0))
            pushes += int(now_pushing and not pushing)
            pushing = now_pushing
            t_next = steps * dt
            if depth is not None and steps < total and t_next >= next_capture - 1e-9:
                depth.capture(t_next)
                next_capture += capture_dt
            new_cmd = cfg.schedule.at(t_next)
            if not np.array_equal(new_cmd, cmd):
                cmd = new_cmd
                env.commands.set(ids, cmd[None])
            if self._viewer is not None and not self._viewer.sync(env.physics.state[0]):
                ended = "viewer closed"
                break
            if pace:
                lag = wall0 + t_next - time.perf_counter()
                if lag > 0:
                    time.sleep(lag)
            if on_step is not None:
                on_step(steps, total)
        wall_s = time.perf_counter() - wall0
        sim_s = steps * dt
        if self.video is not None:
            self.video.stop()
        return self._report(
            sim_s=sim_s,
            wall_s=wall_s,
            steps=steps,
            ended=ended,
            fell_by=fell_by,
            means={k: _mean(v, recon_count if k == "recon" else count) for k, v in s.items()},
            pushes=pushes,
            policy_ms=policy_ms,
            ages_ms=ages_ms,
        )

    def _report(self, sim_s, wall_s, steps, ended, fell_by, means, pushes, policy_ms, ages_ms) -> dict:
        """Survival, tracking, LIPM figures, timing and depth latency of one run, as one flat dict.

        Units in the keys. vel_tracking_error: mean |v_cmd,xy - v_xy| (base frame, m/s);
        com_error_m: mean |p_hat - p_com| (LIPM desired CoM minus actual, planar); com_zmp_m: mean
        |p_com - p_zmp| (planar); com_height_error_m: mean |z - z_c|; depth_age_ms: age in
        simulation time of the frame each policy step used; depth_render_ms: wall-clock render
        time; depth_hidden_share: share of render time the control loop did not wait for (0 would
        be a lockstep loop); fell_by: what ended a fall (``tilt``, ``base``, ``thigh_L``, ``thigh_R``
        joined by ``+``; None without a fall).
        """
        cfg, env, pol, depth = self.cfg, self.env, self.policy, self.depth
        rep = {
            "policy": str(pol.path),
            "policy_kind": pol.kind,
            "terrain": cfg.terrain,
            "terrain_type": self.terrain_type,
            "level": int(env.curriculum.level[0]),
            "survived": ended not in ("fell", "unstable"),
            "ended": ended,
            "fell_by": fell_by,
            "unstable": ended == "unstable",
            "duration_s": round(sim_s, 6),
            "requested_duration_s": cfg.duration_s,
            "policy_steps": steps,
            "physics_hz": 1.0 / env.cfg.sim_dt,
            "policy_hz": 1.0 / env.policy_dt,
            "depth_hz": float(pol.contract["depth_hz"]) if depth is not None else None,
            "gait_freq_hz": float(env.commands.gait_freq[0]) if env.cfg.gait.enabled else None,
            "vel_tracking_error": means["vel"],
            "com_error_m": means["com"],
            "com_zmp_m": means["zmp"],
            "com_height_error_m": means["z"],
            "stable_reward": means["stable"],
            "reconstruction_error_cm": None if means["recon"] is None else 100.0 * means["recon"],
            "pushes": pushes,
            "policy_ms_p50": _pct(policy_ms, 50),
            "policy_ms_p99": _pct(policy_ms, 99),
            "policy_ms_max": max(policy_ms) if policy_ms else None,
            "wall_s": wall_s,
            "realtime_factor": sim_s / wall_s if wall_s > 0 else None,
            "paced": cfg.realtime or cfg.viewer,
            "seed": cfg.seed,
            "noise": cfg.noise,
            "depth_latency_ms": cfg.depth_latency_ms if depth is not None else None,
        }
        if depth is None:
            rep.update(dict.fromkeys(DEPTH_KEYS))
            return _rounded(rep)
        caps = depth.capture_times
        rep.update(
            {
                "depth_frames": depth.rendered,
                "depth_dropped": depth.dropped,
                "depth_rate_hz": (len(caps) - 1) / (caps[-1] - caps[0]) if len(caps) > 1 else None,
                "depth_age_ms_p50": _pct(ages_ms, 50),
                "depth_age_ms_p99": _pct(ages_ms, 99),
                "depth_age_ms_max": max(ages_ms) if ages_ms else None,
                "depth_render_ms_p50": _pct(depth.render_ms, 50),
                "depth_render_ms_p99": _pct(depth.render_ms, 99),
                "depth_hidden_share": max(0.0, 1.0 - depth.wait_s / depth.busy_s) if depth.busy_s else None,
                "depth_thread_separate": threading.get_ident() not in depth.render_thread_ids,
            }
        )
        return _rounded(rep)

    def close(self) -> None:
        if self.depth is not None:
            self.depth.close()
        if self._viewer is not None:
            self._viewer.close()
        self.env.close()


DEPTH_KEYS = (
    "depth_frames",
    "depth_dropped",
    "depth_rate_hz",
    "depth_age_ms_p50",
    "depth_age_ms_p99",
    "depth_age_ms_max",
    "depth_render_ms_p50",
    "depth_render_ms_p99",
    "depth_hidden_share",
    "depth_thread_separate",
)
