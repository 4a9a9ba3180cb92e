"""The paper's evaluation protocol (section V-B) on the one env core.

A batch of N envs runs a deterministic student policy (checkpoint or ONNX, through
:class:`tron1cli.policy.runtime.Policy`) for S policy steps on one terrain at a fixed difficulty
level, with the policy's own observation layout and, unless switched off, its training
randomisation. Envs never time out inside the window; an env that falls stops counting (and
fails), one that reaches the edge of its tile has crossed the terrain and stops counting (and
succeeds).

Metrics (Table I), averaged over the steps of envs still walking:

- ``success_rate`` (0-1): share of envs that did not fall during the S steps;
- ``orientation_error``: |g_b - (0, 0, -1)|, g_b the unit gravity direction in the base frame;
- ``angular_velocity_error`` (rad/s): mean of |w_x| and |w_y|, base frame;
- ``velocity_tracking_error`` (m/s): |v_cmd,xy - v_xy|, base frame;
- ``reconstruction_error_cm``: mean |h_hat - h| over the 441 heightmap points, in cm (student
  with perception only; None otherwise).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from tron1cli.config.env import CommandConfig
from tron1cli.env.core import Tron1Env
from tron1cli.env.randomization import PushConfig, RandomizationConfig
from tron1cli.env.terrain import TERRAIN_GROUPS
from tron1cli.policy.contract import check_matches_env
from tron1cli.policy.runtime import Policy

METRICS = (
    "success_rate",
    "orientation_error",
    "angular_velocity_error",
    "velocity_tracking_error",
    "reconstruction_error_cm",
)
#: the Table I columns, in order; ``all`` on the command line means these
EVAL_TERRAINS = ("stairs", "slopes", "discrete", "rough", "flat")
TERRAIN_ALIASES = {"slope": "slopes", "stair": "stairs"}


def resolve_eval_terrains(name: str) -> tuple[str, ...]:
    """CLI terrain name -> terrain groups to evaluate on (``all``: every Table I column)."""
    name = TERRAIN_ALIASES.get(name, name)
    if name == "all":
        return EVAL_TERRAINS
    if name not in TERRAIN_GROUPS:
        raise ValueError(f"unknown terrain '{name}'; choose from all, {', '.join(TERRAIN_GROUPS)}")
    return (name,)


@dataclass(frozen=True)
class EvalSpec:
    """One evaluation batch.

    terrain: terrain group (``stairs``, ``flat``, ...); level: difficulty level (-1 = hardest);
    num_envs, steps: batch size and window (policy steps, 50 Hz); randomize: the policy's training
    randomisation (off: nominal model); speed: when set, every env is commanded v_x = speed (m/s),
    v_y = 0, no yaw (Fig. 5); otherwise the training command distribution; pushes: random pushes
    during the window (push tests set their own wrench instead).
    """

    terrain: str = "flat"
    level: int = -1
    num_envs: int = 128
    steps: int = 500
    randomize: bool = True
    speed: float | None = None
    seed: int = 0
    pushes: PushConfig | None = None

    def __post_init__(self) -> None:
        if self.num_envs < 1 or self.steps < 1:
            raise ValueError("envs and steps must be positive")


def make_env(policy: Policy, spec: EvalSpec) -> Tron1Env:
    """The policy's own env, re-configured for evaluation by ``spec``; refuses a layout mismatch."""
    base = policy.run_cfg.env
    commands = base.commands
    if spec.speed is not None:
        s = float(spec.speed)
        commands = CommandConfig(
            lin_vel_x=(s, s),
            lin_vel_y=(0.0, 0.0),
            ang_vel_yaw=(0.0, 0.0),
            resample_s=(1e9, 1e9),
            standing_share=0.0,
        )
    cfg = replace(
        base,
        num_envs=spec.num_envs,
        seed=spec.seed,
        terrain=spec.terrain,
        curriculum=False,
        depth_from=0,
        randomization=base.randomization if spec.randomize else RandomizationConfig(),
        pushes=spec.pushes or PushConfig(),
        commands=commands,
        termination=replace(base.termination, episode_length_s=(spec.steps + 10) * base.policy_dt),
    )
    env = Tron1Env(cfg, policy.run_cfg.reward)
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


@dataclass
class EvalResult:
    """Figures of one batch: ``metrics`` (keys :data:`METRICS`), per-env ``fell`` mask, counts."""

    metrics: dict[str, float | None]
    fell: np.ndarray
    unstable_resets: int


def run_batch(
    policy: Policy,
    spec: EvalSpec,
    on_step: Callable[[int], None] | None = None,
    before_step: Callable[[Tron1Env, int], None] | None = None,
    stream=None,
    stream_env: int = 0,
) -> EvalResult:
    """Run one batch; ``before_step(env, t)`` may set commands or wrenches (push tests);
    ``stream`` (a :class:`tron1cli.viz.rerun_stream.RerunStream`) gets env ``stream_env`` each step."""
    env = make_env(policy, spec)
    try:
        n = env.n
        obs = env.reset()
        hidden = policy.initial_hidden(n)
        fell = np.zeros(n, dtype=bool)
        crossed = np.zeros(n, dtype=bool)
        sums = dict.fromkeys(METRICS[1:], 0.0)
        count = 0
        rec_sum, rec_count = 0.0, 0
        for t in range(spec.steps):
            walking = ~fell & ~crossed
            action, hidden, h_hat, _ = policy.step(obs["history"], policy.depth_input(obs, n), hidden)
            if h_hat.shape[1] and "heightmap" in obs:
                err = np.abs(h_hat[walking] - obs["heightmap"][walking])
                rec_sum += float(err.sum())
                rec_count += err.size
            if before_step is not None:
                before_step(env, t)
            if stream is not None:
                stream.log_step(env, stream_env, t, t * env.policy_dt, extras={"h_hat": h_hat})
            res = env.step(action)
            fell |= walking & (res.failed | res.unstable)
            crossed |= walking & res.time_out
            ok = walking & ~res.done
            s = env.state
            errs = frame_errors(
                s.projected_gravity[ok],
                s.base_ang_vel_b[ok],
                env.commands.value[ok, :2],
                s.base_lin_vel_b[ok, :2],
            )
            for key, e in zip(METRICS[1:4], errs, strict=True):
                sums[key] += float(e.sum())
            count += int(ok.sum())
            hidden[res.done] = 0.0
            obs = res.obs
            if on_step is not None:
                on_step(t + 1)
        metrics: dict[str, float | None] = {"success_rate": float(1.0 - fell.mean())}
        for k in METRICS[1:4]:
            metrics[k] = sums[k] / count if count else None
        metrics["reconstruction_error_cm"] = 100.0 * rec_sum / rec_count if rec_count else None
        return EvalResult(metrics, fell, env.unstable_count)
    finally:
        env.close()


def aggregate(values: list[float | None]) -> dict[str, float | int | None]:
    """Mean and std (population) over policies of one group; None entries are skipped."""
    v = np.array([x for x in values if x is not None], dtype=float)
    if v.size == 0:
        return {"mean": None, "std": None, "n": 0}
    return {"mean": float(v.mean()), "std": float(v.std()), "n": int(v.size)}
