"""Environment configuration. Every field carries its unit; ``__post_init__`` validates only."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace

from tron1cli.env.curriculum import rule_named
from tron1cli.env.randomization import PushConfig, RandomizationConfig
from tron1cli.env.robot import TERMINATION_BODIES
from tron1cli.env.terrain import TerrainConfig, resolve_terrain


def _check_range(name: str, lo_hi: tuple[float, float]) -> None:
    lo, hi = lo_hi
    if not lo <= hi:
        raise ValueError(f"{name}: lower bound {lo} exceeds upper bound {hi}")


#: terrain groups (tron1cli.env.terrain.TERRAIN_GROUPS) whose commands face the climb with
#: ``CommandConfig.face_climb``
FACE_CLIMB_GROUPS: tuple[str, ...] = ("stairs", "slopes")


@dataclass(frozen=True)
class CommandConfig:
    """Velocity commands, sampled uniformly per env.

    lin_vel_x, lin_vel_y: m/s (base yaw frame); ang_vel_yaw: rad/s; resample_s: interval range (s)
    between resamples; standing_share: fraction of commands that are exactly zero; face_climb:
    on stairs and slopes (:data:`FACE_CLIMB_GROUPS`) the command faces the climb: forward speed
    drawn as |v_x| and no sideways speed (yaw rate as drawn), as the humanoid configs of Isaac Lab
    command their rough-terrain robots; heading: heading mode, each command draws a world heading
    (uniform, rad) instead of a yaw rate, and every policy step the yaw-rate command is
    ``heading_kp * wrap(heading - yaw)`` clipped to ``ang_vel_yaw`` (a robot that turns away from
    its heading is asked to turn back, so that walking straight in the world is what tracking
    pays; the policy still sees a yaw rate); heading_kp: 1/s; heading_spread_rad: the heading is
    drawn uniformly within this angle (rad, 0-pi) of the robot's yaw at its first step under the
    command (pi: any heading; small: walk on about where it faces, no turn first).
    """

    lin_vel_x: tuple[float, float] = (-1.0, 1.0)
    lin_vel_y: tuple[float, float] = (-0.5, 0.5)
    ang_vel_yaw: tuple[float, float] = (-0.5, 0.5)
    resample_s: tuple[float, float] = (4.0, 8.0)
    standing_share: float = 0.1
    face_climb: bool = False
    heading: bool = False
    heading_kp: float = 0.5
    heading_spread_rad: float = math.pi

    def __post_init__(self) -> None:
        if not 0.0 <= self.heading_spread_rad <= math.pi:
            raise ValueError(f"heading_spread_rad must lie in [0, pi], got {self.heading_spread_rad!r}")
        if not (math.isfinite(self.heading_kp) and self.heading_kp > 0):
            raise ValueError(f"heading_kp must be positive, got {self.heading_kp!r}")
        for name in ("lin_vel_x", "lin_vel_y", "ang_vel_yaw", "resample_s"):
            _check_range(name, getattr(self, name))
        if self.resample_s[0] <= 0:
            raise ValueError("resample_s must be positive")
        if not 0.0 <= self.standing_share <= 1.0:
            raise ValueError("standing_share must lie in [0, 1]")


@dataclass(frozen=True)
class NoiseConfig:
    """Gaussian observation noise on the student's proprioception (sigma in physical units)."""

    enabled: bool = True
    ang_vel: float = 0.05  # rad/s
    gravity: float = 0.025  # unit vector components
    joint_pos: float = 0.01  # rad
    joint_vel: float = 0.01  # rad/s

    def __post_init__(self) -> None:
        if min(self.ang_vel, self.gravity, self.joint_pos, self.joint_vel) < 0:
            raise ValueError("noise sigmas must be non-negative")


@dataclass(frozen=True)
class InitConfig:
    """Randomised initial state at reset.

    base_height: base origin height above the ground (m); joint_pos_noise: uniform +/- (rad) around
    the default pose; base_vel_noise: uniform +/- (m/s, rad/s); tilt_noise: roll/pitch +/- (rad);
    random_yaw: initial heading uniform in [-pi, pi).
    """

    base_height: float = 0.83
    joint_pos_noise: float = 0.1
    joint_vel_noise: float = 0.1
    base_vel_noise: float = 0.2
    tilt_noise: float = 0.05
    random_yaw: bool = True


@dataclass(frozen=True)
class TerminationConfig:
    """When an episode ends. Angles in rad, time in s."""

    max_roll: float = 0.8
    max_pitch: float = 0.8
    contact_bodies: bool = True  # one of ``bodies`` touching the ground ends the episode
    bodies: tuple[str, ...] = TERMINATION_BODIES  # (LimX's Isaac configs: the base alone)
    episode_length_s: float = 20.0
    max_qvel: float = 200.0  # |qvel| above this counts as an unstable simulation

    def __post_init__(self) -> None:
        if self.episode_length_s <= 0:
            raise ValueError("episode_length_s must be positive")
        bad = [b for b in self.bodies if b not in TERMINATION_BODIES]
        if bad or not self.bodies or len(set(self.bodies)) != len(self.bodies):
            raise ValueError(
                f"termination bodies: choose one or more of {', '.join(TERMINATION_BODIES)}, "
                f"each once; got {','.join(self.bodies) or '(none)'}"
            )
        # one spelling per choice (the robot's order), so equal choices compare equal on --resume
        object.__setattr__(self, "bodies", tuple(b for b in TERMINATION_BODIES if b in self.bodies))

    def judged(self, episode_length_s: float) -> TerminationConfig:
        """The terminations evaluation and deployment judge by, whatever a policy trained with:
        every termination body's contact is a fall (a thigh on a stair nosing too), episodes of
        ``episode_length_s``; the tilt limits are the policy's own."""
        every = dict(contact_bodies=True, bodies=TERMINATION_BODIES)
        return replace(self, **every, episode_length_s=episode_length_s)


@dataclass(frozen=True)
class GaitConfig:
    """The switchable gait prior (see tron1cli/env/gait.py).

    enabled: clock in o_t and e_t plus the contact-schedule reward terms; freq_hz: range of the
    gait frequency, sampled with each velocity command; offset: right leg's phase lag (periods);
    stance: stance fraction of the period; width: smoothing of the schedule's edges (periods);
    swing_fold_rad: (hip, knee) flexion added to a swinging leg's joint targets at its peak (rad;
    (0, 0): none; tron1cli.env.gait.swing_fold); swing_fold_keep: the share of the fold the
    action cannot take away (0: none, the policy may undo it all; tron1cli.env.gait.fold_targets).
    """

    enabled: bool = True
    freq_hz: tuple[float, float] = (1.5, 2.5)
    offset: float = 0.5
    stance: float = 0.5
    width: float = 0.04
    swing_fold_rad: tuple[float, float] = (0.0, 0.0)
    swing_fold_keep: float = 0.0

    def __post_init__(self) -> None:
        _check_range("freq_hz", self.freq_hz)
        fold = self.swing_fold_rad
        if len(fold) != 2 or not all(isinstance(x, int | float) and math.isfinite(x) for x in fold):
            raise ValueError(f"swing fold wants two finite angles (hip, knee) in rad, got {fold}")
        if any(fold) and not self.enabled:
            raise ValueError("a swing fold needs the gait prior (its clock says when a leg swings)")
        keep = self.swing_fold_keep
        if not (isinstance(keep, int | float) and 0.0 <= keep <= 1.0):
            raise ValueError(f"the swing fold's kept share must lie in [0, 1], got {keep}")
        if keep and not any(fold):
            raise ValueError("a kept share of the swing fold needs a swing fold")
        if self.freq_hz[0] <= 0:
            raise ValueError("gait frequencies must be positive")
        if not 0.0 < self.stance < 1.0:
            raise ValueError("stance fraction must lie in (0, 1)")

    def deployed_hz(self, asked_hz: float | None = None) -> float:
        """The one clock frequency a deployment runs (Hz): ``asked_hz``, checked as in
        :meth:`fixed`, else the middle of the trained range; 0 without the prior (no clock is read)."""
        if asked_hz is None:
            return 0.5 * (self.freq_hz[0] + self.freq_hz[1]) if self.enabled else 0.0
        return self.fixed(asked_hz).freq_hz[0]

    def fixed(self, freq_hz: float) -> GaitConfig:
        """This prior with its clock held at ``freq_hz`` (Hz) for every command; it must lie in
        the trained range. ValueError for a policy without the prior or a frequency outside it."""
        if not self.enabled:
            raise ValueError("the policy was trained without the gait prior: it has no gait frequency")
        lo, hi = self.freq_hz
        if not lo <= freq_hz <= hi:  # NaN fails too
            raise ValueError(f"gait frequency {freq_hz:g} Hz lies outside the trained range {lo:g}-{hi:g} Hz")
        return replace(self, freq_hz=(float(freq_hz), float(freq_hz)))


@dataclass(frozen=True)
class EnvConfig:
    """The batched TRON1 environment.

    num_envs: worlds stepped together; sim_dt: physics step (s); decimation: physics steps per
    policy step (policy dt = sim_dt * decimation); history_len: past student observations o_t
    stacked into o^H_t; nthread: physics threads; seed: master seed of every random stream;
    terrain_mix: terrain type -> share of the envs (types of ``terrain`` left out get none; empty:
    equal shares); max_init_level: envs start on levels 0..max_init_level; curriculum_rule: how
    levels move (tron1cli.env.curriculum.RULES: distance, falls, uniform); level_floor: terrain
    type -> the lowest level its envs start on or move down to (missing: 0).
    """

    num_envs: int = 1024
    sim_dt: float = 0.005
    decimation: int = 4
    history_len: int = 5
    nthread: int = 2
    seed: int = 0
    terrain: str = "flat"
    terrain_cfg: TerrainConfig = field(default_factory=TerrainConfig)
    curriculum: bool = True
    max_init_level: int = 0
    terrain_mix: dict[str, float] = field(default_factory=dict)
    curriculum_rule: str = "distance"
    level_floor: dict[str, int] = field(default_factory=dict)
    perception: bool = False
    depth_hz: float = 30.0
    depth_from: int = 0
    randomization: RandomizationConfig = field(default_factory=RandomizationConfig)
    pushes: PushConfig = field(default_factory=PushConfig)
    commands: CommandConfig = field(default_factory=CommandConfig)
    gait: GaitConfig = field(default_factory=GaitConfig)
    noise: NoiseConfig = field(default_factory=NoiseConfig)
    init: InitConfig = field(default_factory=InitConfig)
    termination: TerminationConfig = field(default_factory=TerminationConfig)

    def __post_init__(self) -> None:
        if self.num_envs < 1:
            raise ValueError(f"num_envs must be a positive integer, got {self.num_envs}")
        if self.decimation < 1:
            raise ValueError(f"decimation must be >= 1, got {self.decimation}")
        if self.sim_dt <= 0:
            raise ValueError(f"sim_dt must be positive, got {self.sim_dt}")
        if self.history_len < 1:
            raise ValueError(f"history_len must be >= 1, got {self.history_len}")
        if self.nthread < 1:
            raise ValueError(f"nthread must be >= 1, got {self.nthread}")
        if not 0 <= self.max_init_level < self.terrain_cfg.num_levels:
            raise ValueError(f"max_init_level must lie in 0..{self.terrain_cfg.num_levels - 1}")
        if self.terrain_mix:
            self.type_shares()
        rule_named(self.curriculum_rule)
        if self.level_floor:
            self.type_floors()

    def type_shares(self) -> list[float] | None:
        """Share of the envs per type of ``terrain`` (in bank order) from ``terrain_mix``, or None
        for equal shares; ValueError for a type outside ``terrain``, a share that is not a finite
        number >= 0, or shares that are all 0."""
        if not self.terrain_mix:
            return None
        types = resolve_terrain(self.terrain)
        for name, w in self.terrain_mix.items():
            if name not in types:
                raise ValueError(
                    f"terrain mix: '{name}' is not a type of '{self.terrain}' ({', '.join(types)})"
                )
            if not (isinstance(w, int | float) and math.isfinite(w) and w >= 0):
                raise ValueError(f"terrain mix: {name}={w} is not a finite number >= 0")
        shares = [float(self.terrain_mix.get(t, 0.0)) for t in types]
        if sum(shares) <= 0:
            raise ValueError("terrain mix: every share is 0")
        return shares

    def type_floors(self) -> list[int] | None:
        """Lowest level per type of ``terrain`` (in bank order) from ``level_floor``, or None for
        none; ValueError for a type outside ``terrain`` or a level outside 0..num_levels - 1."""
        if not self.level_floor:
            return None
        types = resolve_terrain(self.terrain)
        top = self.terrain_cfg.num_levels - 1
        for name, lv in self.level_floor.items():
            if name not in types:
                raise ValueError(
                    f"level floor: '{name}' is not a type of '{self.terrain}' ({', '.join(types)})"
                )
            number = isinstance(lv, int | float) and not isinstance(lv, bool) and math.isfinite(lv)
            if not number or lv != int(lv) or not 0 <= lv <= top:
                raise ValueError(f"level floor: {name}={lv} is not a level in 0..{top}")
        return [int(self.level_floor.get(t, 0)) for t in types]

    @property
    def policy_dt(self) -> float:
        """Policy period (s): 0.02 s (50 Hz) by default."""
        return self.sim_dt * self.decimation

    @property
    def max_episode_steps(self) -> int:
        """Policy steps in one episode before a time-out."""
        return int(round(self.termination.episode_length_s / self.policy_dt))

    def to_dict(self) -> dict:
        """Plain-dict form saved with every run."""
        return asdict(self)
