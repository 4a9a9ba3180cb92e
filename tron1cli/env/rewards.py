"""The reward system: named terms, their weights and groups, the LIPM-guided fusion, ablations.

Terms live in one registry keyed by name (:data:`TERMS`); a :class:`RewardConfig` says which
terms are on, with which weight, in which group, and whether the stable reward gates them (the
reward fusion module, RFM). The paper's reward (Table II) is

    r = r_stable + 0.5 exp(4 d_e) + 0.5 r_stable exp(4 m_e) + r_reg

with the stability group {stable} and the locomotion group {tracking, regularisers} for the
double critic. Ablations are data: presets that remove, swap or regroup entries
(:data:`ABLATIONS`), never branches in the code.

With the gait prior on (the default of ``tron1 train``; see tron1cli/env/gait.py) two more
locomotion terms follow a left/right contact schedule: ``gait_swing_force`` penalises ground
force on a foot that should swing, ``gait_stance_speed`` the speed of a foot that should stand.
A survival bonus ``alive`` comes with them. With the prior off the reward is exactly the paper's.

Every weight is multiplied by the policy period dt (0.02 s), for every term alike, as in the
legged-robot literature the Table II weights come from; episode sums are therefore in
"weight x seconds".
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import TYPE_CHECKING

import numpy as np

from tron1cli.config.serde import to_plain
from tron1cli.env import gait, robot
from tron1cli.env import reward_terms as rt

if TYPE_CHECKING:
    from tron1cli.env.core import Tron1Env

STABLE = "stable"
LOCO = "loco"
ALL = "all"


@dataclass(frozen=True)
class TermCfg:
    """One reward entry: ``weight`` (per second), ``group`` (critic), ``gated`` by r_stable (RFM).

    ramp: ``(start, end)`` training iterations (completed PPO updates) over which the weight rises
    linearly from 0 to ``weight`` (0 before ``start``, full from ``end``); None: full throughout.
    """

    weight: float
    group: str = LOCO
    gated: bool = False
    ramp: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        if self.ramp is not None:
            start, end = self.ramp
            if int(start) != start or int(end) != end or not 0 <= start <= end:
                raise ValueError(f"a ramp is (start, end) iterations with 0 <= start <= end, got {self.ramp}")
            object.__setattr__(self, "ramp", (int(start), int(end)))

    def scale(self, iteration: int) -> float:
        """The share of ``weight`` in force at training iteration ``iteration`` (0 to 1)."""
        if self.ramp is None or iteration >= self.ramp[1]:
            return 1.0
        start, end = self.ramp
        return 0.0 if iteration < start else (iteration - start) / (end - start)


def _paper_terms() -> dict[str, TermCfg]:
    return {
        "stable": TermCfg(1.0, STABLE),
        "track_lin_dir": TermCfg(0.5),
        "track_lin_mag": TermCfg(0.5, gated=True),
        "track_yaw": TermCfg(0.5),
        "lin_vel_z": TermCfg(-2.0),
        "joint_acc": TermCfg(-2.5e-7),
        "joint_power": TermCfg(-2e-5),
        "torque": TermCfg(-1e-4),
        "action_rate": TermCfg(-0.01),
        "action_smoothness": TermCfg(-0.01),
        "collision": TermCfg(-1.0),
        "joint_limit": TermCfg(-2.0),
    }


@dataclass(frozen=True)
class RewardConfig:
    """Which reward terms are on and how they combine.

    terms: name -> TermCfg; lipm_kp: gain k_p of eq. 2 (1/s); z_c: upright standing intercept of
    the CoM plane (m, the CoM height of the default pose); lipm_ground_window_m: side (m) of the
    square of terrain under the CoM whose mean height is the plane's ground (0: the one point
    under the CoM; README, eq. 2-3); l2_alpha: scale of the l2 velocity
    term; gait_clearance_m: swing apex (m above the terrain under the foot) the clearance term
    asks for; gait_clearance_top_m: when set, the apex rises linearly with the env's terrain level
    from ``gait_clearance_m`` (level 0) to this (the top level), so that higher risers get higher
    steps; gait_clearance_reach_m: the apex is measured from the highest terrain within this
    distance (m) of the foot (0: the terrain under it), so a foot nearing a riser is asked to clear
    the tread above; thigh_clearance_m: the gap (m) between a thigh and the highest ground within
    ``THIGH_REACH_M`` of its lower end below which the ``thigh_clearance`` term starts to penalise;
    ablation: the preset this config came from (recorded with the run).
    """

    terms: Mapping[str, TermCfg] = field(default_factory=lambda: MappingProxyType(_paper_terms()))
    lipm_kp: float = 1.0
    z_c: float = robot.COM_HEIGHT_ZERO_POSE
    lipm_ground_window_m: float = 0.6
    l2_alpha: float = 4.0
    gait_force_scale: float = 20.0
    gait_speed_scale: float = 0.5
    gait_clearance_m: float = 0.1
    gait_clearance_top_m: float | None = None
    gait_clearance_reach_m: float = 0.0
    thigh_clearance_m: float = 0.05
    ablation: str = "none"

    def __post_init__(self) -> None:
        unknown = set(self.terms) - set(TERMS)
        if unknown:
            raise ValueError(f"unknown reward terms: {sorted(unknown)}")
        if not self.terms:
            raise ValueError("a reward needs at least one term")
        for name in ("gait_clearance_m", "gait_clearance_top_m", "z_c", "thigh_clearance_m"):
            v = getattr(self, name)
            if v is not None and not (isinstance(v, int | float) and 0.0 < v < 10.0):
                raise ValueError(f"{name} must be a positive length in metres, got {v!r}")
        if not 0.0 <= self.gait_clearance_reach_m < 1.0:
            reach = self.gait_clearance_reach_m
            raise ValueError(f"gait_clearance_reach_m must lie in [0, 1) m, got {reach!r}")
        if not self.lipm_ground_window_m >= 0.0:
            raise ValueError(f"lipm_ground_window_m must be >= 0, got {self.lipm_ground_window_m!r}")

    @property
    def clock_terms(self) -> tuple[str, ...]:
        """The terms that follow the gait prior's clock (``gait_*``): they need the prior on."""
        return tuple(k for k in self.terms if k.startswith("gait_"))

    @property
    def groups(self) -> tuple[str, ...]:
        """Reward groups in a fixed order (stable first), one critic each."""
        gs = {t.group for t in self.terms.values()}
        return tuple(sorted(gs, key=lambda g: (g != STABLE, g)))

    def to_dict(self) -> dict:
        return {
            "terms": {k: _term_dict(v) for k, v in self.terms.items()},
            "lipm_kp": self.lipm_kp,
            "z_c": self.z_c,
            "lipm_ground_window_m": self.lipm_ground_window_m,
            "l2_alpha": self.l2_alpha,
            "gait_force_scale": self.gait_force_scale,
            "gait_speed_scale": self.gait_speed_scale,
            "gait_clearance_m": self.gait_clearance_m,
            **(
                {}
                if self.gait_clearance_top_m is None
                else {"gait_clearance_top_m": self.gait_clearance_top_m}
            ),
            **(
                {"gait_clearance_reach_m": self.gait_clearance_reach_m} if self.gait_clearance_reach_m else {}
            ),
            **({"thigh_clearance_m": self.thigh_clearance_m} if "thigh_clearance" in self.terms else {}),
            "ablation": self.ablation,
            "groups": list(self.groups),
        }

    @classmethod
    def from_dict(cls, d: Mapping) -> RewardConfig:
        terms = {k: TermCfg(**v) for k, v in d["terms"].items()}
        scalars = {k: v for k, v in d.items() if k not in ("terms", "groups")}
        return cls(terms=MappingProxyType(terms), **scalars)


def _term_dict(t: TermCfg) -> dict:
    """A term as :func:`to_plain` writes it, without ``ramp`` when it has none (the form configs
    written before ramps have)."""
    d = to_plain(t)
    if d["ramp"] is None:
        del d["ramp"]
    return d


def _with(cfg: RewardConfig, terms: dict[str, TermCfg], name: str) -> RewardConfig:
    return replace(cfg, terms=MappingProxyType(terms), ablation=name)


def _no_stable_reward(cfg: RewardConfig) -> RewardConfig:
    terms = {k: replace(v, gated=False) for k, v in cfg.terms.items() if k != "stable"}
    return _with(cfg, terms, "no-stable-reward")


def _single_critic(cfg: RewardConfig) -> RewardConfig:
    return _with(cfg, {k: replace(v, group=ALL) for k, v in cfg.terms.items()}, "single-critic")


def _no_rfm(cfg: RewardConfig) -> RewardConfig:
    return _with(cfg, {k: replace(v, gated=False) for k, v in cfg.terms.items()}, "no-rfm")


def _l2_velocity(cfg: RewardConfig) -> RewardConfig:
    terms = {k: v for k, v in cfg.terms.items() if k not in ("track_lin_dir", "track_lin_mag")}
    terms["track_lin_l2"] = TermCfg(1.0, LOCO, gated=True)  # eq. 3 with eq. 6: r_stable (1 + r_vel)
    return _with(cfg, terms, "l2-velocity")


#: The paper's ablations (Sec. V-B, Table IV), each a function of a config returning a config.
ABLATIONS: dict[str, Callable[[RewardConfig], RewardConfig]] = {
    "none": lambda c: c,
    "no-stable-reward": _no_stable_reward,
    "single-critic": _single_critic,
    "no-rfm": _no_rfm,
    "l2-velocity": _l2_velocity,
}


#: The gait prior's terms (locomotion group), weights per second: the contact schedule, and a
#: survival bonus so that living is worth more than the early regularisation penalties cost
#: (without it the first policies learn to fall fast; DESIGN.md's working recipe had one too).
GAIT_TERMS: dict[str, TermCfg] = {
    "gait_swing_force": TermCfg(-1.0),
    "gait_stance_speed": TermCfg(-1.0),
    "alive": TermCfg(2.0),
}


def with_ramps(cfg: RewardConfig, ramps: Mapping[str, tuple[int, int]]) -> RewardConfig:
    """``cfg`` with some of its terms ramped in over training iterations (:class:`TermCfg`);
    ValueError for a term ``cfg`` lacks or a ramp that is not ``0 <= start <= end``."""
    missing = sorted(set(ramps) - set(cfg.terms))
    if missing:
        raise ValueError(f"cannot ramp '{missing[0]}': the reward has no such term (give it a weight)")
    terms = dict(cfg.terms) | {k: replace(cfg.terms[k], ramp=r) for k, r in ramps.items()}
    return replace(cfg, terms=MappingProxyType(terms))


def with_weights(cfg: RewardConfig, weights: Mapping[str, float]) -> RewardConfig:
    """``cfg`` with the per-second weights of some terms replaced (``tron1 train --reward-weights
    alive=0.5``); a registered term ``cfg`` lacks joins the locomotion group (or the one group of
    a single critic). ValueError for a name not in :data:`TERMS` or a weight that is not finite."""
    for name, w in weights.items():
        if name not in TERMS:
            raise ValueError(f"unknown reward term '{name}'; the terms: {', '.join(TERMS)}")
        if not np.isfinite(w):
            raise ValueError(f"{name}={w} is not a finite number")
    group = ALL if cfg.groups == (ALL,) else LOCO
    terms = dict(cfg.terms)
    for name, w in weights.items():
        terms[name] = replace(terms.get(name, TermCfg(0.0, group)), weight=float(w))
    return replace(cfg, terms=MappingProxyType(terms))


#: the RewardConfig numbers ``tron1 train --reward-settings`` may set
REWARD_SETTINGS = (
    "z_c",
    "lipm_kp",
    "lipm_ground_window_m",
    "l2_alpha",
    "gait_force_scale",
    "gait_speed_scale",
    "gait_clearance_m",
    "gait_clearance_top_m",
    "gait_clearance_reach_m",
    "thigh_clearance_m",
)


def with_settings(cfg: RewardConfig, settings: Mapping[str, float]) -> RewardConfig:
    """``cfg`` with some of its numbers (:data:`REWARD_SETTINGS`) replaced; ValueError, one line,
    for another name or a value the config refuses."""
    for name in settings:
        if name not in REWARD_SETTINGS:
            raise ValueError(f"unknown reward setting '{name}'; choose from {', '.join(REWARD_SETTINGS)}")
    return replace(cfg, **{k: float(v) for k, v in settings.items()})


def make_reward_config(ablation: str = "none", gait_prior: bool = False, **overrides) -> RewardConfig:
    """The paper's reward, plus the gait terms when ``gait_prior``, with an ablation preset applied.

    The ablation acts on the paper's terms; the gait terms join the locomotion group (or the one
    group of the single-critic ablation). ValueError names the valid presets.
    """
    if ablation not in ABLATIONS:
        raise ValueError(f"unknown ablation '{ablation}'; choose from {', '.join(ABLATIONS)}")
    cfg = ABLATIONS[ablation](RewardConfig(**overrides))
    if gait_prior:
        group = ALL if cfg.groups == (ALL,) else LOCO
        terms = dict(cfg.terms) | {k: replace(v, group=group) for k, v in GAIT_TERMS.items()}
        cfg = replace(cfg, terms=MappingProxyType(terms))
    return cfg


# -- term registry: plain functions of the env, one value per env ------------------------------
def _v_cmd(env: Tron1Env) -> np.ndarray:
    return env.commands.value[:, :2]


def _v_xy(env: Tron1Env) -> np.ndarray:
    return env.state.base_lin_vel_b[:, :2]


def _swing_force(env: Tron1Env) -> np.ndarray:
    f = np.linalg.norm(env.state.foot_force, axis=-1) / env.reward_cfg.gait_force_scale
    return np.sum((1.0 - env.desired_contact()) * (1.0 - np.exp(-(f**2))), axis=1)


def swing_apex_m(cfg: RewardConfig, level: np.ndarray, num_levels: int) -> np.ndarray:
    """Swing apex (N, 1) m the clearance term asks of envs on terrain ``level`` (N,):
    ``gait_clearance_m``, or rising with the level to ``gait_clearance_top_m`` when that is set."""
    h = np.full((len(level), 1), cfg.gait_clearance_m)
    if cfg.gait_clearance_top_m is not None and num_levels > 1:
        h += (cfg.gait_clearance_top_m - cfg.gait_clearance_m) * (
            np.asarray(level)[:, None] / (num_levels - 1)
        )
    return h


def _swing_clearance(env: Tron1Env) -> np.ndarray:
    g = env.cfg.gait
    h = swing_apex_m(env.reward_cfg, env.curriculum.level, env.curriculum.num_levels)
    target = gait.swing_height_target(gait.leg_phases(env.commands.gait_phase, g.offset), g.stance, h)
    feet = env.state.foot_pos
    reach = env.reward_cfg.gait_clearance_reach_m
    ground = np.stack([env.highest_ground(feet[:, i, :2], reach) for i in range(feet.shape[1])], axis=1)
    return gait.clearance_shortfall(feet[:, :, 2] - robot.FOOT_RADIUS - ground, target, h)


#: m: the ground a thigh end is measured from is the highest within this of its point
THIGH_REACH_M = 0.10


def _thigh_clearance(env: Tron1Env) -> np.ndarray:
    ends = env.state.thigh_end_pos
    ground = np.stack([env.highest_ground(ends[:, i, :2], THIGH_REACH_M) for i in range(2)], axis=1)
    gap = ends[:, :, 2] - robot.THIGH_RADIUS - ground
    return rt.thigh_clearance_shortfall(gap, env.reward_cfg.thigh_clearance_m)


def _stance_speed(env: Tron1Env) -> np.ndarray:
    v = np.linalg.norm(env.state.foot_vel, axis=-1) / env.reward_cfg.gait_speed_scale
    return np.sum(env.desired_contact() * (1.0 - np.exp(-(v**2))), axis=1)


TERMS: dict[str, Callable[[Tron1Env], np.ndarray]] = {
    "stable": lambda env: env.lipm.r_stable,
    "track_lin_dir": lambda env: rt.track_direction(_v_cmd(env), _v_xy(env)),
    "track_lin_mag": lambda env: rt.track_magnitude(_v_cmd(env), _v_xy(env)),
    "track_lin_l2": lambda env: rt.track_lin_vel_l2(_v_cmd(env), _v_xy(env), env.reward_cfg.l2_alpha),
    "track_progress": lambda env: rt.track_progress(_v_cmd(env), _v_xy(env)),
    "track_yaw": lambda env: rt.track_yaw_rate(env.commands.value[:, 2], env.state.base_ang_vel_b[:, 2]),
    "lin_vel_z": lambda env: rt.lin_vel_z_sq(env.state.base_lin_vel_b[:, 2]),
    "flat_orientation": lambda env: rt.flat_orientation_sq(env.state.projected_gravity),
    "joint_acc": lambda env: rt.joint_acc_sq(env.state.joint_acc),
    "joint_power": lambda env: rt.joint_power(env.state.joint_torque, env.state.joint_vel),
    "torque": lambda env: rt.torque_sq(env.state.joint_torque),
    "action_rate": lambda env: rt.action_rate(env.actions, env.last_actions),
    "action_smoothness": lambda env: rt.action_smoothness(
        env.actions, env.last_actions, env.last_last_actions
    ),
    "collision": lambda env: rt.collisions(env.state.collision_count),
    "joint_limit": lambda env: rt.joint_limit_violations(
        env.state.joint_pos, env.state.joint_vel, robot.JOINT_RANGES, robot.VELOCITY_LIMIT
    ),
    "foot_stumble": lambda env: rt.foot_stumble(env.state.foot_force),
    "com_height": lambda env: rt.height_error_sq(env.lipm.z, env.reward_cfg.z_c),
    "gait_swing_force": _swing_force,
    "gait_stance_speed": _stance_speed,
    "gait_swing_clearance": _swing_clearance,
    "thigh_clearance": _thigh_clearance,
    "alive": lambda env: np.ones(env.n),
}


class RewardManager:
    """Evaluates the configured terms each step and keeps per-term episode sums.

    ``compute`` returns the reward of every group, (N,) each, already multiplied by dt.
    """

    def __init__(self, cfg: RewardConfig, num_envs: int, dt: float) -> None:
        self.cfg = cfg
        self.dt = dt
        self.episode_sums = {name: np.zeros(num_envs) for name in cfg.terms}
        self.last_terms: dict[str, np.ndarray] = {}
        # full weights (the reward a policy was trained for) until the trainer sets an iteration
        self._weights = {k: t.weight for k, t in cfg.terms.items()}

    def set_iteration(self, iteration: int) -> None:
        """Weigh ramped terms (:class:`TermCfg`) as at training iteration ``iteration``."""
        self._weights = {k: t.weight * t.scale(iteration) for k, t in self.cfg.terms.items()}

    def compute(self, env: Tron1Env) -> dict[str, np.ndarray]:
        groups = {g: np.zeros(env.n) for g in self.cfg.groups}
        r_stable = env.lipm.r_stable
        for name, t in self.cfg.terms.items():
            value = TERMS[name](env) * (self._weights[name] * self.dt)
            if t.gated:
                value = value * r_stable
            self.last_terms[name] = value
            self.episode_sums[name] += value
            groups[t.group] += value
        return groups

    def pop_episode_sums(self, ids: np.ndarray) -> dict[str, np.ndarray]:
        """Per-term sums of the episodes that ended in envs ``ids``; resets those sums."""
        out = {}
        for name, s in self.episode_sums.items():
            out[name] = s[ids].copy()
            s[ids] = 0.0
        return out
