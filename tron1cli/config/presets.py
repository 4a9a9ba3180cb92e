"""Training presets: named factories of the settings ``tron1 train`` starts from.

One registry entry per preset (:data:`PRESETS`); the CLI only picks one and applies the options
the user gave explicitly on top (each such override is recorded and printed in the run header).
Without ``--preset`` the CLI picks ``flat`` on flat ground and ``perceptive`` elsewhere.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from types import MappingProxyType

from tron1cli.config.env import GaitConfig, TerminationConfig
from tron1cli.env.randomization import PushConfig, RandomizationConfig
from tron1cli.learn.config import LearnerConfig

#: the learner's defaults, which a preset starts from (plain dataclasses: no torch import)
_LEARNER = LearnerConfig()

DEFAULT_STABLE_WEIGHT = 0.5
"""Weight of the stability critic's normalised advantage in our presets (the locomotion one has
1; the paper gives none, equal weights are the natural reading): with 1, the 20-min flat run
tracked 0.43 m/s; with 0.5, about 0.3 m/s (README, policies/README.md)."""

FLAT_STABLE_WEIGHT = 0.25
"""The flat preset's stability weight: with the tilt penalty below, 0.25 took ``tron1 eval``
success after 90 iterations from 69 % (0.5) to 95 % (README, "Learning to walk on flat")."""

FLAT_NUM_ENVS = 512
"""The flat preset's parallel envs. Measured at 24 steps an iteration (AVX2 EPYC, 2026-12-03): 512
envs instead of 1024 gave twice the policy updates per env step at the same cost per env step, and seeds 11-13
walked (``tron1 eval`` >= 90 %, <= 0.3 m/s) after 3.7 M env steps, where 1024 envs needed 7.4 M
(README, "Learning to walk on flat")."""

FLAT_STEPS_PER_ENV = 12
"""The flat preset's rollout: 512 envs x 12 steps an iteration (600 iterations, the same 3.7 M env
steps as 300 of 24). Twice the policy updates per env step again, at the same cost per env step:
seed 11's ``tron1 eval`` after 2.2 M env steps tracked 0.311 m/s instead of 0.385 (README,
"Learning to walk on flat")."""

FLAT_EPOCHS = 3
"""The flat preset's PPO epochs over each rollout (the learner's default, 5, elsewhere). An iteration
costs about 0.74 of a 5-epoch one; seeds 11-13 (AVX-512 EPYC, 2026-12-03) kept 98-100 % of the robots up after
200 iterations (the cost of 150 with 5 epochs, after which 80-93 % stood) and tracked 0.26-0.30
m/s after 450 (the cost of 333; 5 epochs after 350: 0.26-0.32) (README, "Learning to walk on
flat")."""

FLAT_REWARD_WEIGHTS = {"flat_orientation": -5.0, "track_lin_l2": 1.0}
"""The flat preset's extra reward terms (README, "Learning to walk on flat"):

- ``flat_orientation``: base tilt, -5 a second at sin^2 = 1. The paper's reward alone leaned the
  first policies over until they fell; with it ``tron1 eval`` success after 90 iterations went
  from 23 % to 69 %.
- ``track_lin_l2``: exp(-4 |v_cmd - v|^2), 1 a second, not gated by r_stable, on top of the
  paper's decoupled tracking terms, ramped in by :data:`FLAT_REWARD_RAMPS`."""

FLAT_REWARD_RAMPS = {"track_lin_l2": (150, 200)}
"""Iterations over which the flat preset's l2 tracking term rises from 0 to its weight. From the
first iteration it taught seeds 11 and 12 to walk sooner (``tron1 eval`` 0.255 and 0.266 m/s after
400 iterations, where without it seed 12 tracked 0.321 after 437) but to survive later (53-57 %
of robots up after 150 iterations, 86 % after 200; without it 90 % after 143): the main job's 3
minutes ended with robots that fall. Ramped in from iteration 200 to 250 (AVX-512 EPYC, 2026-12-03) the robots
learnt to stay up first; from 150 to 200 (2026-12-04, seeds 11-13, 3 epochs) they still stand
(96-99 % after 200 iterations, against 98-100 %) and walk sooner (0.288-0.356 m/s after 350
iterations, against 0.316-0.383); from 100 to 150 they walked later than either."""


@dataclass(frozen=True)
class TrainPreset:
    """What a training run starts from.

    terrain: CLI terrain name; num_envs: parallel envs; iterations: PPO iterations;
    steps_per_env: rollout length per iteration (policy steps); epochs: PPO epochs over each rollout;
    hidden: actor and critic MLP sizes;
    teacher_ratio: teacher share of the envs; gait_prior: clock + contact schedule (ours);
    critic_weights: reward group -> weight of its normalised advantage (missing: 1);
    reward_weights: reward term -> per-second weight replacing the default one (missing: default);
    reward_ramps: reward term -> (start, end) iterations over which its weight rises from 0;
    reward_settings: RewardConfig number -> value (``z_c``, ``gait_clearance_top_m``, ...);
    perception: heightmap and depth; randomization: Table III terms; pushes: random pushes;
    terrain_mix: terrain type -> share of the envs (empty: equal shares); init_level: envs start
    on terrain levels 0..init_level; curriculum_rule: how levels move (distance, falls, uniform);
    face_climb: commands face the climb on stairs and slopes (``CommandConfig.face_climb``);
    heading: heading-mode commands (``CommandConfig.heading``); heading_spread_deg: their headings
    within this angle (degrees) of the robot's yaw;
    level_floor: terrain type -> lowest level its envs start on or move down to;
    swing_fold: (hip, knee) rad added to a swinging leg's targets (``GaitConfig.swing_fold_rad``);
    swing_fold_keep: the share of it the action cannot take away (``GaitConfig.swing_fold_keep``);
    gait_freq_hz: range of the gait clock's frequency, drawn with each command (``GaitConfig.freq_hz``);
    terminate_on: the bodies whose ground contact ends an episode (``TerminationConfig.bodies``).
    """

    name: str
    terrain: str = "flat"
    num_envs: int = 1024
    iterations: int = 300
    steps_per_env: int = _LEARNER.num_steps_per_env
    epochs: int = _LEARNER.num_epochs
    hidden: tuple[int, ...] = _LEARNER.actor_hidden
    teacher_ratio: float = 0.5
    gait_prior: bool = True
    critic_weights: Mapping[str, float] = field(
        default_factory=lambda: MappingProxyType({"stable": DEFAULT_STABLE_WEIGHT})
    )
    reward_weights: Mapping[str, float] = field(default_factory=lambda: MappingProxyType({}))
    reward_ramps: Mapping[str, tuple[int, int]] = field(default_factory=lambda: MappingProxyType({}))
    reward_settings: Mapping[str, float] = field(default_factory=lambda: MappingProxyType({}))
    perception: bool = False
    randomization: RandomizationConfig = field(default_factory=RandomizationConfig)
    pushes: PushConfig = field(default_factory=PushConfig)
    ablation: str = "none"
    terrain_mix: Mapping[str, float] = field(default_factory=lambda: MappingProxyType({}))
    init_level: int = 0
    curriculum_rule: str = "distance"
    face_climb: bool = False
    heading: bool = False
    heading_spread_deg: float = 180.0
    level_floor: Mapping[str, int] = field(default_factory=lambda: MappingProxyType({}))
    swing_fold: tuple[float, float] = (0.0, 0.0)
    swing_fold_keep: float = 0.0
    gait_freq_hz: tuple[float, float] = GaitConfig.freq_hz
    terminate_on: tuple[str, ...] = TerminationConfig.bodies

    def __post_init__(self) -> None:
        if min(self.iterations, self.steps_per_env, self.epochs) < 1 or self.num_envs < 2:
            raise ValueError("a preset needs >= 2 envs and >= 1 iteration, step per env and epoch")
        if not 0.0 <= self.teacher_ratio <= 1.0:
            raise ValueError("teacher_ratio must lie in [0, 1]")


def flat() -> TrainPreset:
    """The quick start: blind, on flat ground, nominal robot, 512 envs x 12 steps, 3 epochs, gait prior on,
    the tilt penalty, the l2 tracking term from iteration 150 and the stability critic at 0.25;
    600 iterations (3.7 M env steps)."""
    return TrainPreset(
        name="flat",
        num_envs=FLAT_NUM_ENVS,
        steps_per_env=FLAT_STEPS_PER_ENV,
        epochs=FLAT_EPOCHS,
        iterations=600,
        critic_weights=MappingProxyType({"stable": FLAT_STABLE_WEIGHT}),
        reward_weights=MappingProxyType(FLAT_REWARD_WEIGHTS),
        reward_ramps=MappingProxyType(FLAT_REWARD_RAMPS),
    )


def perceptive(terrain: str = "mixed") -> TrainPreset:
    """Our perceptive training: heightmap teachers, depth students, Table III, moderate pushes,
    with the gait prior and the stability critic at weight 0.5."""
    return TrainPreset(
        name="perceptive",
        terrain=terrain,
        perception=True,
        randomization=RandomizationConfig.table_iii(),
        pushes=PushConfig.moderate(),
    )


def teacher(terrain: str = "mixed") -> TrainPreset:
    """The teacher stage: :func:`perceptive` with every env a teacher, so no depth is rendered and
    no student is trained; its weights warm-start the Vision-CTS stage (``--preset perceptive
    --init``), where the students join. Cheaper samples for learning to climb (docs/training.md)."""
    return replace(perceptive(terrain), name="teacher", teacher_ratio=1.0)


def paper() -> TrainPreset:
    """The paper's method and sizes (Sec. V-A): no gait prior, both critics weighted 1, 2048 envs
    (half teachers) x 24 steps x 10,000 iterations on every terrain type with the curriculum,
    perception, Table III and pushes. The paper gives no network sizes; ours are kept."""
    return TrainPreset(
        name="paper",
        terrain="mixed",
        num_envs=2048,
        iterations=10_000,
        gait_prior=False,
        critic_weights=MappingProxyType({}),
        perception=True,
        randomization=RandomizationConfig.table_iii(),
        pushes=PushConfig.moderate(),
    )


def for_terrain(terrain: str) -> TrainPreset:
    """The preset ``tron1 train --terrain T`` starts from without ``--preset``."""
    return flat() if terrain == "flat" else perceptive(terrain)


#: preset name -> factory; ``tron1 train --preset NAME``
PRESETS: dict[str, Callable[[], TrainPreset]] = {
    "flat": flat,
    "perceptive": perceptive,
    "teacher": teacher,
    "paper": paper,
}


def make_preset(name: str) -> TrainPreset:
    """A fresh preset by name; ValueError names the valid ones."""
    try:
        return PRESETS[name]()
    except KeyError:
        raise ValueError(f"unknown preset '{name}'; choose from {', '.join(PRESETS)}") from None
