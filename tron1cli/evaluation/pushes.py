"""Push-recovery protocol (paper Fig. 6): one push per env, by axis and direction, and survival.

Every env walks under the training command distribution. At ``push_at_s`` it receives one
push for ``duration_s``: a force along +/-x, +/-y or +/-z, or a torque about one of those axes,
at the protocol's full magnitude, or a ``mixed`` wrench drawn uniformly within the ranges on all
six axes at once; ``none`` envs are the unpushed control. Axes are those of the robot's heading
frame (x forward, y left, z up) at the push's start. An env survives when it has not fallen
``watch_s`` after the push ends. Env ``i`` gets push type ``i mod len(PUSH_TYPES)``. The batch
runs under the full-window protocol of :mod:`tron1cli.evaluation.protocol`: only a fall ends an
env's window, on a tile sized so that no env leaves the terrain under test.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from tron1cli.env.core import Tron1Env
from tron1cli.env.math3d import rotate_z, yaw_of
from tron1cli.evaluation.protocol import EvalResult, EvalSpec, run_batch

if TYPE_CHECKING:
    from tron1cli.policy.runtime import Policy

_AXES = ("x", "y", "z")
#: push type -> index of the wrench entry it drives (0-2 force, 3-5 torque) and its sign
AXIS_PUSHES: dict[str, tuple[int, float]] = {
    f"{sign}{kind}{ax}": (off + i, 1.0 if sign == "+" else -1.0)
    for kind, off in (("F", 0), ("T", 3))
    for i, ax in enumerate(_AXES)
    for sign in ("+", "-")
}
PUSH_TYPES: tuple[str, ...] = ("none", *AXIS_PUSHES, "mixed")


@dataclass(frozen=True)
class PushProtocol:
    """Magnitudes (N, N m), timing (s) and the terrain of one push test."""

    name: str
    force_n: float
    torque_nm: float
    duration_s: float
    terrain: str
    push_at_s: float = 2.0
    watch_s: float = 3.0

    @classmethod
    def moderate(cls) -> PushProtocol:
        """Paper: within +/-50 N and +/-5 N m, on the complex terrains."""
        return cls("moderate", 50.0, 5.0, 0.2, terrain="mixed")

    @classmethod
    def extreme(cls) -> PushProtocol:
        """Paper: +/-400 N and +/-20 N m, on flat ground (a short, hard shove)."""
        return cls("extreme", 400.0, 20.0, 0.1, terrain="flat")

    def steps(self, policy_dt: float) -> int:
        return int(round((self.push_at_s + self.duration_s + self.watch_s) / policy_dt))


def push_wrenches(types: np.ndarray, proto: PushProtocol, rng: np.random.Generator) -> np.ndarray:
    """Heading-frame wrench (N, 6) of each env's push type (indices into PUSH_TYPES)."""
    scale = np.array([proto.force_n] * 3 + [proto.torque_nm] * 3)
    w = np.zeros((len(types), 6))
    for t, name in enumerate(PUSH_TYPES):
        rows = types == t
        if name in AXIS_PUSHES:
            j, sign = AXIS_PUSHES[name]
            w[rows, j] = sign * scale[j]
        elif name == "mixed":
            w[rows] = rng.uniform(-1.0, 1.0, (int(rows.sum()), 6)) * scale
    return w


def heading_to_world(wrench_h: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Wrenches (N, 6) from each robot's heading frame (yaw (N,) rad) to the world frame."""
    w = np.array(wrench_h, dtype=float, copy=True)
    w[:, 0:2] = rotate_z(wrench_h[:, 0:2], yaw)
    w[:, 3:5] = rotate_z(wrench_h[:, 3:5], yaw)
    return w


@dataclass
class PushResult:
    """Survival (0-1) per push type and over every pushed env (the control excluded); envs per
    type (min, max: ``num_envs`` need not divide by the 14 types); mean exposure (s) and the
    batch's full-window figures (:class:`tron1cli.evaluation.protocol.EvalResult`)."""

    survival: dict[str, float]
    survival_rate: float
    envs_per_type: tuple[int, int]
    exposure_s: float
    batch: EvalResult


def run_push_test(
    policy: Policy,
    proto: PushProtocol,
    num_envs: int,
    level: int = -1,
    seed: int = 0,
    randomize: bool = True,
    on_step: Callable[[int], None] | None = None,
    stream=None,
    watch: str = "+Fx",
    video=None,
    backend: str = "mujoco",
) -> PushResult:
    """One batch of ``num_envs`` under ``proto``; ``stream`` (rerun) gets the first env whose push
    type is ``watch``; ``video`` (a :class:`tron1cli.viz.video.VideoRecorder`) gets one take of
    the first env of every push type, side by side; ``backend``: the physics engine."""
    from types import SimpleNamespace

    from tron1cli.memory import check_memory, env_bytes

    # before the per-env push arrays below: an env count the machine cannot hold is refused at once
    lean = SimpleNamespace(num_envs=num_envs, perception=policy.run_cfg.env.perception, depth_from=num_envs)
    check_memory(num_envs, env_bytes(lean) + 13 * 8)
    dt = policy.run_cfg.env.policy_dt
    spec = EvalSpec(
        terrain=proto.terrain,
        level=level,
        num_envs=num_envs,
        steps=proto.steps(dt),
        randomize=randomize,
        seed=seed,
        backend=backend,
    )
    types = np.arange(num_envs) % len(PUSH_TYPES)
    wrench_h = push_wrenches(types, proto, np.random.default_rng(seed + 1))
    start = int(round(proto.push_at_s / dt))
    stop = start + max(1, int(round(proto.duration_s / dt)))
    world = np.zeros_like(wrench_h)

    def push(env: Tron1Env, t: int) -> None:
        if t == start:  # heading frame -> world, frozen for the push
            world[:] = heading_to_world(wrench_h, yaw_of(env.state.base_quat))
        if start <= t < stop:
            env.external_wrench[:] = world
        elif t == stop:
            env.external_wrench[:] = 0.0

    take = None
    if video is not None:
        caption = f"{policy.path.name}: {proto.name} pushes at {proto.push_at_s:g} s on {proto.terrain}"
        take = video.take(range(len(PUSH_TYPES)), PUSH_TYPES, caption)
    res = run_batch(
        policy,
        spec,
        on_step=on_step,
        before_step=push,
        stream=stream,
        stream_env=PUSH_TYPES.index(watch),
        video=take,
    )
    failed = res.failed  # fell, or (never expected) left the terrain under test
    survival = {name: float(1.0 - failed[types == t].mean()) for t, name in enumerate(PUSH_TYPES)}
    pushed = types != 0
    counts = np.bincount(types, minlength=len(PUSH_TYPES))
    return PushResult(
        survival,
        float(1.0 - failed[pushed].mean()),
        (int(counts.min()), int(counts.max())),
        float(res.exposure_s.mean()),
        res,
    )
