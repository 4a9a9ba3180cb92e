"""The paper's evaluation protocol (section V-B) on the one env core: the full window.

A batch of N envs runs a deterministic student policy (checkpoint or ONNX, through
:class:`tron1cli.policy.runtime.Policy`) for S policy steps on one terrain at a fixed difficulty
level, with the policy's own observation layout and, unless switched off, its training
randomisation. Only a fall ends an env's window: envs never time out inside it, and every env
stays on terrain of the type and level under test for all of it. For that the eval tile is the
training tile's terrain (same generator, same level, same step height, slope or block density)
on a larger square, sized from the window and the fastest command (:func:`eval_terrain_config`)
so that a robot leaving the centre at that speed plus :data:`SPEED_SLACK_MPS` stays inside the
edge margin. An env that reaches the edge all the same counts as a failure (``left``), never
as a success, and the batch reports how far the envs went (``max_reach_m``).

Metrics (Table I), averaged over the steps of envs still walking:

- ``success_rate`` (0-1): share of envs that did not fall (or leave the tile) in the S steps; a
  fall is the base tilting past the policy's limits or the base or a thigh touching the ground,
  whichever bodies the policy trained to fall on (``TerminationConfig.judged``);
- ``orientation_error``: |g_b - (0, 0, -1)|, g_b the unit gravity direction in the base frame;
- ``angular_velocity_error`` (rad/s): mean of |w_x| and |w_y|, base frame;
- ``velocity_tracking_error`` (m/s): |v_cmd,xy - v_xy|, base frame;
- ``reconstruction_error_cm``: mean |h_hat - h| over the 441 heightmap points, in cm (student
  with perception only; None otherwise);
- ``exposure_s`` (s): mean time an env spent walking on the terrain under test (a survivor:
  the whole window, S x 0.02 s; a faller: until its fall);
- ``command_progress`` (ours, not the paper's): the distance walked along the commanded path
  over the distance commanded, sum_t v_xy . d_t over sum_t |v_cmd| (world frame, steps of
  walking envs with a moving command), where d_t is the command's direction turned to the path's
  heading: the robot's yaw when the command was drawn, turned since by the commanded yaw rate
  (with heading-mode commands, the world heading the robot is steered to). A
  robot that turns away from its path (walks along a riser, or circles on the landing, instead
  of up the stairs) earns only the cosine of its error, however fast it walks. Success is
  survival, as in the paper, so a robot that stands still in front of a staircase succeeds; this
  says how much of the commanded walking it did (1: all of it; 0: none; None without a moving
  command).
- ``pitch_deg`` (ours): mean signed base pitch (ZYX Euler, as the tilt termination) in degrees,
  positive nose down; the orientation error's direction (a policy that walks leaning back reads negative);
- ``traverse_rate`` (ours, 0-1): share of envs that succeeded *and* walked at least
  :data:`TRAVERSE_SHARE` of the distance commanded to them along their command (the curriculum's
  promotion rule); an env asked for less than :data:`TRAVERSE_MIN_ASKED_M` in the whole window
  counts by success alone. A survivor standing before the stairs is a success, not a traverse.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from tron1cli.config.env import CommandConfig
from tron1cli.env.core import EDGE_MARGIN_M, StepResult, Tron1Env
from tron1cli.env.math3d import roll_pitch, rotate_z, yaw_of
from tron1cli.env.randomization import PushConfig, RandomizationConfig
from tron1cli.env.terminations import FALL_CAUSES
from tron1cli.env.terrain import TERRAIN_GROUPS, TERRAIN_TYPES, TerrainConfig
from tron1cli.evaluation.metric_names import EVAL_LAYOUTS, METRICS
from tron1cli.policy.contract import check_matches_env

if TYPE_CHECKING:  # torch stays out of the CLI's option checks
    from tron1cli.policy.runtime import Policy

#: a traverse: a success that walked at least this share of its commanded distance
TRAVERSE_SHARE = 0.5
#: an env commanded less than this distance (m) in its window is judged by success alone
TRAVERSE_MIN_ASKED_M = 0.5
#: the Table I columns, in order; ``all`` on the command line means these
EVAL_TERRAINS = ("stairs", "slopes", "discrete", "rough", "flat")
TERRAIN_ALIASES = {"slope": "slopes", "stair": "stairs"}

#: how much faster than its fastest command a robot is assumed to move when the eval tile is
#: sized (m/s). Measured on the shipped flat policy (1024 envs, 10 s): the farthest env got
#: 11.1 m from the centre on level-0 stairs (1.11 m/s on average; top command 1.12 m/s)
SPEED_SLACK_MPS = 0.5


class SpeedDim(NamedTuple):
    """One velocity dimension of the success-by-speed sweep (Fig. 5)."""

    column: int  # index into the command (v_x, v_y, yaw rate)
    field: str  # the CommandConfig range it is checked against
    unit: str
    words: str  # for titles: "forward speed", ...


SPEED_DIMS: dict[str, SpeedDim] = {
    "vx": SpeedDim(0, "lin_vel_x", "m/s", "forward speed"),
    "vy": SpeedDim(1, "lin_vel_y", "m/s", "lateral speed"),
    "yaw": SpeedDim(2, "ang_vel_yaw", "rad/s", "yaw rate"),
}


def check_speed_form(dim: str, value: float | None = None) -> None:
    """Refuse (ValueError) an unknown speed dimension or a non-finite speed."""
    if dim not in SPEED_DIMS:
        raise ValueError(f"unknown speed dimension '{dim}'; choose from {', '.join(SPEED_DIMS)}")
    if value is not None and not math.isfinite(value):
        raise ValueError(f"speed {dim}:{value} is not a finite number")


def check_level(level: int, num_levels: int) -> None:
    """ValueError unless ``level`` names one of ``num_levels`` levels, or is -1 (the hardest)."""
    if not (level == -1 or 0 <= level < num_levels):
        raise ValueError(f"--level {level} outside 0..{num_levels - 1} (or -1 for the hardest)")


def check_speed(commands: CommandConfig, dim: str, value: float) -> None:
    """Refuse (ValueError) an unknown dimension, a non-finite value, or one outside the policy's
    training command range ``commands`` for that dimension."""
    check_speed_form(dim, value)
    d = SPEED_DIMS[dim]
    lo, hi = getattr(commands, d.field)
    if not lo <= value <= hi:
        raise ValueError(
            f"speed {dim}:{value:g} {d.unit} is outside the policy's training command range "
            f"[{lo:g}, {hi:g}] {d.unit}"
        )


def top_speed(commands: CommandConfig) -> float:
    """Fastest planar speed (m/s) a command of ``commands`` can ask for: |(v_x, v_y)| at the corners."""
    vx = max(abs(v) for v in commands.lin_vel_x)
    vy = max(abs(v) for v in commands.lin_vel_y)
    return float(math.hypot(vx, vy))


def eval_terrain_config(cfg: TerrainConfig, window_s: float, speed_mps: float) -> TerrainConfig:
    """The training terrain ``cfg`` on a tile large enough for a whole window: a robot leaving the
    tile centre at ``speed_mps + SPEED_SLACK_MPS`` for ``window_s`` (see :func:`terrain_for_reach`)."""
    return terrain_for_reach(cfg, window_s * (speed_mps + SPEED_SLACK_MPS))


def terrain_for_reach(cfg: TerrainConfig, reach_m: float) -> TerrainConfig:
    """The training terrain ``cfg`` on a tile where a robot ``reach_m`` (m) from the tile centre in
    any direction stays ``EDGE_MARGIN_M`` inside the terrain.

    Half side >= reach + margin + rim, rounded up to whole samples; never smaller than the training
    tile. Discrete tiles get blocks in proportion to the terrain area (same density); every other
    type is scale-free (same step height and tread, slope, noise amplitude and cell).
    """
    half = reach_m + EDGE_MARGIN_M + cfg.border_m + cfg.resolution_m
    samples = math.ceil(2.0 * half / cfg.resolution_m - 1e-9)
    side = max(cfg.tile_size_m, round(samples * cfg.resolution_m, 9))
    if side == cfg.tile_size_m:
        return cfg
    area = (side - 2 * cfg.border_m) ** 2 / (cfg.tile_size_m - 2 * cfg.border_m) ** 2
    return replace(cfg, tile_size_m=side, num_blocks=int(round(cfg.num_blocks * area)))


def resolve_eval_terrains(name: str) -> tuple[str, ...]:
    """CLI terrain name -> terrain groups to evaluate on (``all``: every Table I column; one type,
    e.g. ``stairs_up``, evaluates that type alone)."""
    name = TERRAIN_ALIASES.get(name, name)
    if name == "all":
        return EVAL_TERRAINS
    if name not in TERRAIN_GROUPS and name not in TERRAIN_TYPES:
        raise ValueError(
            f"unknown terrain '{name}'; choose from all, {', '.join(TERRAIN_GROUPS)} "
            f"(or one type: {', '.join(TERRAIN_TYPES)})"
        )
    return (name,)


@dataclass(frozen=True)
class EvalSpec:
    """One evaluation batch.

    terrain: terrain group (``stairs``, ``flat``, ...); level: difficulty level (-1 = hardest);
    num_envs, steps: batch size and window (policy steps, 50 Hz); randomize: the policy's training
    randomisation (off: nominal model); speed: when set, every env is commanded ``speed`` along
    ``speed_dim`` (``vx``, ``vy`` in m/s, ``yaw`` in rad/s) and zero on the other two, for the whole
    window (Fig. 5); otherwise the training command distribution; pushes: random pushes during the
    window (push tests set their own wrench instead); gait_freq_hz: hold the gait clock at this
    frequency (Hz, in the policy's trained range) instead of drawing it with each command;
    backend: the physics engine (tron1cli.env.physics.BACKENDS); layouts: random tiles drawn for
    the level under test, one per env at random (:data:`EVAL_LAYOUTS`).
    """

    terrain: str = "flat"
    level: int = -1
    num_envs: int = 1024
    steps: int = 500
    randomize: bool = True
    speed: float | None = None
    seed: int = 0
    pushes: PushConfig | None = None
    speed_dim: str = "vx"
    gait_freq_hz: float | None = None
    backend: str = "mujoco"
    layouts: int = EVAL_LAYOUTS

    def __post_init__(self) -> None:
        if self.num_envs < 1 or self.steps < 1:
            raise ValueError("envs and steps must be positive")
        if self.layouts < 1:
            raise ValueError(f"layouts must be >= 1, got {self.layouts}")
        check_speed_form(self.speed_dim, self.speed)

    def commands(self, trained: CommandConfig) -> CommandConfig:
        """The command distribution of the batch: the training one ``trained``, or the fixed sweep
        command (checked against ``trained``'s range)."""
        if self.speed is None:
            return trained
        check_speed(trained, self.speed_dim, self.speed)
        fixed = [(0.0, 0.0)] * 3
        fixed[SPEED_DIMS[self.speed_dim].column] = (float(self.speed), float(self.speed))
        return CommandConfig(
            lin_vel_x=fixed[0],
            lin_vel_y=fixed[1],
            ang_vel_yaw=fixed[2],
            resample_s=(1e9, 1e9),
            standing_share=0.0,
        )


def make_env(policy: Policy, spec: EvalSpec) -> Tron1Env:
    """The policy's own env, re-configured for evaluation by ``spec`` on a full-window tile
    (:func:`eval_terrain_config`); refuses a layout mismatch or a sweep speed outside the policy's
    command range."""
    base = policy.run_cfg.env
    commands = spec.commands(base.commands)
    window_s = spec.steps * base.policy_dt
    cfg = replace(
        base,
        num_envs=spec.num_envs,
        seed=spec.seed,
        terrain=spec.terrain,
        terrain_mix={},  # every env on the terrain under test
        level_floor={},  # and on the level under test
        curriculum=False,
        depth_from=spec.num_envs if policy.actor == "teacher" else 0,  # a teacher needs no camera
        randomization=base.randomization if spec.randomize else RandomizationConfig(),
        pushes=spec.pushes or PushConfig(),
        commands=commands,
        gait=base.gait if spec.gait_freq_hz is None else base.gait.fixed(spec.gait_freq_hz),
        terrain_cfg=replace(
            eval_terrain_config(base.terrain_cfg, window_s, top_speed(commands)),
            variants_per_level=spec.layouts,
        ),
        termination=base.termination.judged((spec.steps + 10) * base.policy_dt),
    )
    env = Tron1Env(cfg, policy.run_cfg.reward, backend=spec.backend)
    check_matches_env(policy.contract, env.layout, str(policy.path))
    env.pin_terrain_level(spec.level)
    return env


def frame_errors(
    gravity_b: np.ndarray, ang_vel_b: np.ndarray, v_cmd_xy: np.ndarray, v_xy: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-env errors (N,) of one step: orientation |g_b - (0,0,-1)|, angular velocity
    (|w_x| + |w_y|) / 2 (rad/s), velocity tracking |v_cmd,xy - v_xy| (m/s); base-frame inputs."""
    orient = np.linalg.norm(gravity_b - np.array([0.0, 0.0, -1.0]), axis=1)
    ang = 0.5 * np.abs(ang_vel_b[:, :2]).sum(axis=1)
    track = np.linalg.norm(v_cmd_xy - v_xy, axis=1)
    return orient, ang, track


def pitch_deg(gravity_b: np.ndarray) -> np.ndarray:
    """Signed base pitch (k,) in degrees, positive nose down, of base-frame gravity directions (k, 3):
    the pitch the tilt termination checks (:func:`tron1cli.env.math3d.roll_pitch`)."""
    return np.degrees(roll_pitch(gravity_b)[1])


def command_progress_terms(
    v_cmd_xy: np.ndarray, v_xy: np.ndarray, min_cmd: float = 0.05
) -> tuple[np.ndarray, np.ndarray]:
    """Per env (k, 2 inputs in one frame, m/s): the speed along the command, v_xy . v_cmd / |v_cmd|,
    and the commanded speed |v_cmd|, both (k,) m/s and 0 where the command is not faster than
    ``min_cmd`` (a standing command asks for no distance)."""
    speed = np.linalg.norm(v_cmd_xy, axis=1)
    moving = speed > min_cmd
    along = np.zeros(len(speed))
    along[moving] = np.einsum("ij,ij->i", v_xy[moving], v_cmd_xy[moving]) / speed[moving]
    return along, np.where(moving, speed, 0.0)


def traversed(success: np.ndarray, along_m: np.ndarray, asked_m: np.ndarray) -> np.ndarray:
    """Per-env traverse (N,) bool: a success that walked at least :data:`TRAVERSE_SHARE` of the
    distance commanded along the command (``along_m``, ``asked_m`` (N,) in m over the window);
    an env asked for less than :data:`TRAVERSE_MIN_ASKED_M` is judged by ``success`` alone."""
    walked = along_m >= TRAVERSE_SHARE * asked_m
    return success & ((asked_m < TRAVERSE_MIN_ASKED_M) | walked)


@dataclass
class EvalResult:
    """Figures of one batch.

    metrics: keys :data:`METRICS`; fell: per-env mask of falls (incl. unstable simulations);
    left: per-env mask of envs that reached the edge of the eval tile (failures too; expected
    none); exposure_s: per-env time walked on the terrain under test (s); tile_m: side of the eval
    tile (m); edge_m: distance from the centre (inf-norm, m) at which an env leaves it;
    max_reach_m: farthest any walking env got from the centre (inf-norm, m); rise_m: per env, the
    highest the ground under its base got above the ground under its spawn point while it walked (m);
    fall_causes: (N, len(FALL_CAUSES)) bool, what ended each env's window in a fall (tilt, or a
    termination body touching the ground; all False for a survivor or an unstable simulation).
    """

    metrics: dict[str, float | None]
    fell: np.ndarray
    left: np.ndarray
    exposure_s: np.ndarray
    tile_m: float
    edge_m: float
    max_reach_m: float
    unstable_resets: int
    rise_m: np.ndarray
    fall_causes: np.ndarray

    @property
    def failed(self) -> np.ndarray:
        """Envs whose window did not end in success: fell or left the terrain under test."""
        return self.fell | self.left


def run_batch(
    policy: Policy,
    spec: EvalSpec,
    on_step: Callable[[int], None] | None = None,
    before_step: Callable[[Tron1Env, int], None] | None = None,
    after_step: Callable[[Tron1Env, StepResult, np.ndarray], None] | None = None,
    stream=None,
    stream_env: int = 0,
    video=None,
) -> EvalResult:
    """Run one batch; ``before_step(env, t)`` may set commands or wrenches (push tests);
    ``after_step(env, res, walking)`` sees each step's result with the (N,) mask of envs that were
    still walking before it (lab tools take their own figures there);
    ``stream`` (a :class:`tron1cli.viz.rerun_stream.RerunStream`) gets env ``stream_env`` each step;
    ``video`` (a :class:`tron1cli.viz.video.Take`) records its envs."""
    env = make_env(policy, spec)
    try:
        n = env.n
        obs = env.reset()
        if video is not None:
            video.start(env)
        hidden = policy.initial_hidden(n)
        fell = np.zeros(n, dtype=bool)
        left = np.zeros(n, dtype=bool)
        causes = np.zeros((n, len(FALL_CAUSES)), dtype=bool)
        exposed = np.zeros(n, dtype=np.int64)  # policy steps walked on the terrain
        reach = 0.0
        sums = dict.fromkeys(METRICS[1:4], 0.0)
        count = 0
        rec_sum, rec_count = 0.0, 0
        pitch_sum = 0.0
        along = np.zeros(n)  # per env: distance walked along the command, distance commanded (m)
        asked = np.zeros(n)
        ground0 = env.ground_height(env.state.base_pos[:, :2])
        rise = np.zeros(n)
        # the heading of each env's commanded path (rad, world): its yaw when the command was
        # drawn, turned since by the commanded yaw rate
        path_yaw = yaw_of(env.state.base_quat)
        cmd_prev = env.commands.value[:, :2].copy()
        for t in range(spec.steps):
            walking = ~fell & ~left
            action, hidden, h_hat = policy.act(obs, hidden)
            if h_hat.shape[1] and "heightmap" in obs:
                err = np.abs(h_hat[walking] - obs["heightmap"][walking])
                rec_sum += float(err.sum())
                rec_count += err.size
            if before_step is not None:
                before_step(env, t)
            if stream is not None:
                extras = {"h_hat": h_hat} if h_hat.shape[1] else None
                stream.log_step(env, stream_env, t, t * env.policy_dt, extras=extras)
            cmd = env.commands.value.copy()  # the command in force during this step
            fresh = np.any(cmd[:, :2] != cmd_prev, axis=1)
            path_yaw[fresh] = yaw_of(env.state.base_quat[fresh])
            cmd_prev = cmd[:, :2]
            # heading mode: the path runs along the world heading the robot is steered to
            path_yaw = np.where(env.commands.steering, env.commands.heading, path_yaw)
            res = env.step(action)
            if video is not None:
                video.step(env, (t + 1) * env.policy_dt, res.done, res.failed)
            if after_step is not None:
                after_step(env, res, walking)
            falls = walking & (res.failed | res.unstable)
            causes[falls] = res.fall_causes[falls]
            fell |= falls
            # the episode outlasts the window, so a walking env's time-out is the tile's edge
            left |= walking & res.time_out
            ok = walking & ~res.done
            exposed += ok
            s = env.state
            if ok.any():
                reach = max(reach, float(np.abs(s.base_pos[ok, :2]).max()))
                up = env.ground_height(s.base_pos[:, :2]) - ground0
                rise[ok] = np.maximum(rise[ok], up[ok])
            errs = frame_errors(
                s.projected_gravity[ok],
                s.base_ang_vel_b[ok],
                env.commands.value[ok, :2],
                s.base_lin_vel_b[ok, :2],
            )
            for key, e in zip(METRICS[1:4], errs, strict=True):
                sums[key] += float(e.sum())
            pitch_sum += float(pitch_deg(s.projected_gravity[ok]).sum())
            a, c = command_progress_terms(rotate_z(cmd[ok], path_yaw[ok]), s.base_lin_vel_w[ok, :2])
            path_yaw += cmd[:, 2] * env.policy_dt
            along[ok] += a * env.policy_dt
            asked[ok] += c * env.policy_dt
            count += int(ok.sum())
            hidden[res.done] = 0.0
            obs = res.obs
            if on_step is not None:
                on_step(t + 1)
        if video is not None:
            video.stop()
        exposure = exposed * env.policy_dt
        metrics: dict[str, float | None] = {"success_rate": float(1.0 - (fell | left).mean())}
        for k in METRICS[1:4]:
            metrics[k] = sums[k] / count if count else None
        metrics["reconstruction_error_cm"] = 100.0 * rec_sum / rec_count if rec_count else None
        metrics["exposure_s"] = float(exposure.mean())
        total_asked = float(asked.sum())
        metrics["command_progress"] = float(along.sum()) / total_asked if total_asked > 0.0 else None
        metrics["pitch_deg"] = pitch_sum / count if count else None
        metrics["traverse_rate"] = float(traversed(~(fell | left), along, asked).mean())
        return EvalResult(
            metrics,
            fell,
            left,
            exposure,
            tile_m=env.bank.size,
            edge_m=round(float(env.edge), 9),
            max_reach_m=reach,
            unstable_resets=env.unstable_count,
            rise_m=rise,
            fall_causes=causes,
        )
    finally:
        env.close()


def aggregate(values: list[float | None]) -> dict[str, float | int | None]:
    """Mean and std (population) over policies of one group; None entries are skipped."""
    v = np.array([x for x in values if x is not None], dtype=float)
    if v.size == 0:
        return {"mean": None, "std": None, "n": 0}
    return {"mean": float(v.mean()), "std": float(v.std()), "n": int(v.size)}
