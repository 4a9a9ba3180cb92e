"""Learner configuration and the observation sizes the environment hands the learner.

Both are frozen dataclasses; ``__post_init__`` validates and never mutates.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace
from typing import Any

_ACTIVATIONS = ("elu", "relu", "tanh")
PRECISIONS = ("fp32", "bf16")


def _positive_ints(name: str, values: tuple[int, ...], allow_empty: bool = False) -> None:
    if not allow_empty and len(values) == 0:
        raise ValueError(f"{name} must not be empty")
    if any(int(v) != v or v <= 0 for v in values):
        raise ValueError(f"{name} must hold positive integers, got {values}")


@dataclass(frozen=True)
class ObsDims:
    """Widths of the observation groups of one run (fixed for the run).

    proprio: P, width of the student's o_t (the ``proprio`` group).
    history: H * P, width of o^H_t (the last H o_t, oldest first; its last P entries are o_t).
    privileged: E, width of the teacher's e_t.
    heightmap: width of the teacher's height scan h_t (441 in the paper; heights in m relative to the
        base); 0 when the run has no height scan.
    depth_hw: (rows, cols) of the student's depth image in m ((60, 80) in the paper); None when absent.
        A depth image needs a height scan (it is what the student's image path learns to reconstruct).
    action: A, width of the action (6 joint position offsets).
    """

    proprio: int
    history: int
    privileged: int
    heightmap: int = 0
    depth_hw: tuple[int, int] | None = None
    action: int = 6

    def __post_init__(self) -> None:
        for name in ("proprio", "history", "privileged", "action"):
            v = getattr(self, name)
            if int(v) != v or v <= 0:
                raise ValueError(f"ObsDims.{name} must be a positive integer, got {v}")
        if self.history % self.proprio != 0:
            raise ValueError(
                f"ObsDims.history ({self.history}) must be a multiple of proprio ({self.proprio})"
            )
        if int(self.heightmap) != self.heightmap or self.heightmap < 0:
            raise ValueError(f"ObsDims.heightmap must be a non-negative integer, got {self.heightmap}")
        if self.depth_hw is not None:
            if len(self.depth_hw) != 2:
                raise ValueError(f"ObsDims.depth_hw must be (rows, cols), got {self.depth_hw}")
            _positive_ints("ObsDims.depth_hw", tuple(self.depth_hw))
            if self.heightmap == 0:
                raise ValueError("a depth image needs a height scan (heightmap > 0) to learn from")

    @property
    def history_len(self) -> int:
        """H, the number of o_t in o^H_t."""
        return self.history // self.proprio

    @property
    def has_heightmap(self) -> bool:
        return self.heightmap > 0

    @property
    def has_depth(self) -> bool:
        return self.depth_hw is not None

    def to_dict(self) -> dict[str, Any]:
        """Plain python types only (lists, not tuples), for checkpoints."""
        d = asdict(self)
        d["depth_hw"] = None if self.depth_hw is None else list(self.depth_hw)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ObsDims:
        """The inverse of :meth:`to_dict`; ValueError naming a field of the wrong kind."""
        import typing

        from tron1cli.config.serde import check_value

        if not isinstance(d, dict):
            raise ValueError(f"observation dims should be an object, got {type(d).__name__}")
        hints = typing.get_type_hints(cls)
        for k, v in d.items():
            if k in hints:
                check_value(hints[k], v, f"observation dims.{k}")
        d = dict(d)
        if d.get("depth_hw") is not None:
            d["depth_hw"] = tuple(d["depth_hw"])
        return cls(**d)


@dataclass(frozen=True)
class LearnerConfig:
    """Vision-CTS PPO with one critic per reward group.

    Rollout and PPO
        num_steps_per_env: T, env steps collected per env per iteration (policy steps, 20 ms each).
        num_epochs: passes over the rollout per iteration.
        num_minibatches: minibatches per epoch (each holds T * N / num_minibatches samples).
        clip: PPO ratio clip epsilon (dimensionless); also the value-function clip when
            ``clip_value_loss`` (in return units).
        gamma: discount per policy step; lam: GAE lambda.
        lr: initial Adam learning rate of the PPO parameters (teacher encoders, policy, critics).
        desired_kl: target KL (nats, per sample) of the adaptive learning rate; None keeps lr fixed.
            Above 2 x target the lr is divided by ``lr_factor``, below target / 2 multiplied by it,
            bounded to [lr_min, lr_max].
        entropy_coef: entropy bonus weight at iteration 0, decaying linearly to entropy_coef_final at
            iteration ``entropy_decay_iters`` (0 = use the final value at once) and constant after.
        value_coef: weight of the (summed) value losses; clip_value_loss: PPO-style clipped value loss.
        max_grad_norm: global gradient-norm clip of each optimiser step.
        init_noise_std: initial action standard deviation (action units; state independent, learned).

    Networks (hidden sizes per layer; activation one of elu, relu, tanh)
        actor_hidden, critic_hidden: policy MLP and each critic MLP.
        latent_e, latent_h: widths of the privileged and heightmap latents (L2-normalised).
        encoder_hidden: teacher e_t encoder and the student privileged estimator's encoder.
        heightmap_encoder_hidden: teacher h_t encoder (and the student's history-only h estimator when
            the run has a height scan but no depth image).
        decoder_hidden: the estimators' decoders (latent -> e_hat, latent -> h_hat).
        cnn_channels: the three stride-2 conv layers of the depth CNN; depth_feature: its output width
            and that of the MLP on o^H_t feeding the GRU; gru_hidden: the GRU state width.
        depth_max: depth (m) is clamped to [0, depth_max] and scaled to [0, 1] inside the model; the env
            should hand in no-return pixels as depth_max or more.

    Concurrent teacher-student
        teacher_ratio: share of envs in the teacher group (envs [0, round(N * ratio)) are teachers;
            :func:`teacher_count`).
        critic_weights: reward group -> weight of its normalised advantage in the sum (missing = 1.0).
        rec_coef: weight of the reconstruction loss; rec_lr: its own Adam learning rate (fixed).
        rec_all_envs: the MLP estimators (privileged, and the history-only heightmap estimator) also
            regress on the teacher envs' history (it is free data); the image path uses student envs.
        rec_batch_envs: student envs sampled per iteration for the image path's reconstruction loss.
        rec_epochs: passes of the image path over those envs' T steps per iteration (each pass from
            the GRU states saved at the rollout's start; T / tbptt optimiser steps a pass).
        tbptt: truncated back-propagation length (policy steps) through the GRU; one optimiser step
            per tbptt chunk.
        reencode_h: the policy reads, as the student's heightmap latent, the teacher's heightmap
            encoder applied to the student's reconstruction, enc^{t,h}(h_hat), in place of the
            estimator's own latent (the paper's; False). The estimator still learns by the same
            regressions; the re-encoded latent lies where the teacher's latents lie, which the
            shared policy knows. A departure from the paper, off by default.
        rec_reencode_coef: weight, in the heightmap estimator's loss, of a third regression:
            MSE(enc^{t,h}(h_hat), l^{t,h}), the re-encoded latent against the teacher's (the
            teacher encoder frozen, its gradient reaching the estimator through h_hat). It weights
            the reconstruction's errors by how much the teacher's encoder minds them; 0 (the
            paper) leaves the loss as it is. A departure from the paper.
        student_warmup: updates during which the student envs act on the teacher latents of their
            own e_t, h_t (teacher forcing) while their estimators learn as usual: the image path then
            learns on a walker's states, and no PPO sample carries an untrained student latent. For
            a student stage warm-started from a teacher stage; 0 (the paper) forces nothing.

    Observations
        obs_normalization: running mean / std normalisation of proprio, history, privileged (per
            feature) and heightmap (one shared mean / std); normalizer_clip: clip in sigmas.

    Arithmetic
        precision: ``fp32``, or ``bf16``: the update's matrix products and convolutions in
            bfloat16 with float32 accumulation (autocast; parameters, optimiser state, losses and
            collection stay float32). Several times faster on CPUs with AMX tiles (Intel Xeon 4th
            generation and later) and on recent GPUs; slower where bfloat16 is emulated.
    """

    num_steps_per_env: int = 24
    num_epochs: int = 5
    num_minibatches: int = 4
    clip: float = 0.2
    gamma: float = 0.99
    lam: float = 0.95
    lr: float = 1e-3
    desired_kl: float | None = 0.01
    lr_factor: float = 1.5
    lr_min: float = 1e-5
    lr_max: float = 1e-2
    entropy_coef: float = 0.01
    entropy_coef_final: float = 0.001
    entropy_decay_iters: int = 1000
    value_coef: float = 1.0
    clip_value_loss: bool = True
    max_grad_norm: float = 1.0
    init_noise_std: float = 1.0
    actor_hidden: tuple[int, ...] = (256, 128, 64)
    critic_hidden: tuple[int, ...] = (256, 128, 64)
    activation: str = "elu"
    latent_e: int = 16
    latent_h: int = 32
    encoder_hidden: tuple[int, ...] = (128, 64)
    heightmap_encoder_hidden: tuple[int, ...] = (128, 64)
    decoder_hidden: tuple[int, ...] = (128,)
    cnn_channels: tuple[int, int, int] = (8, 16, 32)
    depth_feature: int = 64
    gru_hidden: int = 64
    depth_max: float = 3.0
    teacher_ratio: float = 0.5
    critic_weights: dict[str, float] = field(default_factory=dict)
    rec_coef: float = 1.0
    rec_lr: float = 1e-3
    rec_all_envs: bool = True
    rec_batch_envs: int = 128
    rec_epochs: int = 1
    tbptt: int = 8
    reencode_h: bool = False
    rec_reencode_coef: float = 0.0
    student_warmup: int = 0
    obs_normalization: bool = True
    normalizer_clip: float = 5.0
    precision: str = "fp32"

    def __post_init__(self) -> None:
        for name in (
            "num_steps_per_env",
            "num_epochs",
            "num_minibatches",
            "latent_e",
            "latent_h",
            "depth_feature",
            "gru_hidden",
            "rec_batch_envs",
            "rec_epochs",
            "tbptt",
        ):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v <= 0:
                raise ValueError(f"{name} must be a positive integer, got {v!r}")
        for name in ("entropy_decay_iters", "student_warmup"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 0:
                raise ValueError(f"{name} must be a non-negative integer, got {v!r}")
        for name in (
            "clip",
            "lr",
            "lr_min",
            "lr_max",
            "max_grad_norm",
            "init_noise_std",
            "depth_max",
            "rec_lr",
            "normalizer_clip",
        ):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)!r}")
        if not 0.0 <= self.gamma <= 1.0 or not 0.0 <= self.lam <= 1.0:
            raise ValueError("gamma and lam must lie in [0, 1]")
        if self.desired_kl is not None and not self.desired_kl > 0:
            raise ValueError("desired_kl must be positive or None")
        if not self.lr_factor > 1.0:
            raise ValueError("lr_factor must exceed 1")
        if not self.lr_min <= self.lr <= self.lr_max:
            raise ValueError(f"lr {self.lr} must lie in [lr_min, lr_max] = [{self.lr_min}, {self.lr_max}]")
        for name in ("entropy_coef", "entropy_coef_final", "value_coef", "rec_coef", "rec_reencode_coef"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be non-negative")
        for name in (
            "actor_hidden",
            "critic_hidden",
            "encoder_hidden",
            "heightmap_encoder_hidden",
            "decoder_hidden",
        ):
            _positive_ints(name, tuple(getattr(self, name)), allow_empty=True)
        _positive_ints("cnn_channels", tuple(self.cnn_channels))
        if len(self.cnn_channels) != 3:
            raise ValueError("cnn_channels must name the channels of exactly three conv layers")
        if self.precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {PRECISIONS}, got {self.precision!r}")
        if self.activation not in _ACTIVATIONS:
            raise ValueError(f"activation must be one of {_ACTIVATIONS}, got {self.activation!r}")
        if not 0.0 <= self.teacher_ratio <= 1.0:
            raise ValueError("teacher_ratio must lie in [0, 1]")
        for g, w in self.critic_weights.items():
            if not isinstance(g, str) or not g:
                raise ValueError("critic_weights keys must be reward-group names")
            if not w >= 0:
                raise ValueError(f"critic weight of {g!r} must be non-negative, got {w!r}")

    def to_dict(self) -> dict[str, Any]:
        """Plain python types only (tuples as lists), for checkpoints and run records."""
        return {
            k: (list(v) if isinstance(v, tuple) else (dict(v) if isinstance(v, dict) else v))
            for k, v in asdict(self).items()
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> LearnerConfig:
        """The inverse of :meth:`to_dict`; ValueError naming a field of the wrong kind."""
        from tron1cli.config.serde import from_plain

        return from_plain(cls, d, "learner config")


def teacher_count(num_envs: int, teacher_ratio: float) -> int:
    """Envs in the teacher group of ``num_envs`` at ``teacher_ratio``: envs ``[0, count)`` are
    teachers, the rest students (whose depth the env renders from there)."""
    return int(round(num_envs * teacher_ratio))


#: LearnerConfig fields that ``tron1 train`` sets through an option of their own
OWN_OPTIONS = {
    "num_steps_per_env": "--steps-per-env",
    "actor_hidden": "--hidden",
    "critic_hidden": "--hidden",
    "teacher_ratio": "--teacher-ratio",
    "critic_weights": "--critic-weights",
    "precision": "--precision",
}
_TRUE, _FALSE = ("true", "on", "yes", "1"), ("false", "off", "no", "0")


def tunable_fields() -> dict[str, Any]:
    """The scalar LearnerConfig fields ``tron1 train --learner`` may set, name -> default value."""
    default = LearnerConfig()
    return {
        k: v
        for k, v in asdict(default).items()
        if k not in OWN_OPTIONS and (v is None or isinstance(v, (bool, int, float, str)))
    }


def with_overrides(cfg: LearnerConfig, values: dict[str, str]) -> LearnerConfig:
    """``cfg`` with scalar fields replaced from text (``{"rec_batch_envs": "256"}``), each parsed as
    the type of its default (``none`` for an optional number such as ``desired_kl``).

    ValueError, one line, for an unknown or non-scalar field, a field with its own option, a value
    that does not parse, or one the config refuses."""
    tunable = tunable_fields()
    parsed: dict[str, Any] = {}
    for name, text in values.items():
        if name in OWN_OPTIONS:
            raise ValueError(f"{name} has its own option: {OWN_OPTIONS[name]}")
        if name not in tunable:
            known = ", ".join(tunable)
            raise ValueError(f"unknown or non-scalar learner setting '{name}'; choose from {known}")
        default, t = tunable[name], text.strip().lower()
        try:
            if name == "desired_kl" and t == "none":
                parsed[name] = None
            elif isinstance(default, bool):
                if t not in _TRUE + _FALSE:
                    raise ValueError
                parsed[name] = t in _TRUE
            elif isinstance(default, int):
                parsed[name] = int(t)
            elif isinstance(default, float) or default is None:
                parsed[name] = float(t)
            else:
                parsed[name] = text.strip()
        except ValueError:
            kind = "true or false" if isinstance(default, bool) else "an integer"
            kind = "a number" if isinstance(default, float) or default is None else kind
            raise ValueError(f"{name}={text} is not {kind}") from None
        if isinstance(parsed[name], float) and not math.isfinite(parsed[name]):
            raise ValueError(f"{name}={text} is not a finite number")
    return replace(cfg, **parsed)
