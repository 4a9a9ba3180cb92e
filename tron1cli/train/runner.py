"""The training loop: env core <-> Vision-CTS learner, with checkpoints, metrics and resume.

What a run directory holds: :mod:`tron1cli.train.layout`.
"""

from __future__ import annotations

import errno
import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from tron1cli import __version__
from tron1cli.config import CommandConfig, EnvConfig, GaitConfig, TerminationConfig
from tron1cli.config.presets import TrainPreset
from tron1cli.config.serde import from_plain, to_plain
from tron1cli.env.core import Tron1Env
from tron1cli.env.rewards import RewardConfig, make_reward_config, with_ramps, with_settings, with_weights
from tron1cli.errors import Tron1Error, UsageError, describe
from tron1cli.fileio import atomic_write, clean_stale_temps
from tron1cli.learn import LearnerConfig, ObsDims, VisionCTSLearner
from tron1cli.learn.config import teacher_count
from tron1cli.learn.warm_start import WarmStart, warm_start
from tron1cli.train.checkpoint import load_training_checkpoint, nonfinite_weights, save_checkpoint
from tron1cli.train.layout import CONFIG, METRICS, RunLock, checkpoint_dir, latest_checkpoint
from tron1cli.train.metrics import EpisodeStats, trim_metrics


@dataclass(frozen=True)
class RunConfig:
    """Everything that defines a training run; saved as ``config.json`` and in every checkpoint.

    iterations: PPO iterations in total (a resumed run continues to this count); save_every:
    checkpoint period (iterations); ablation: reward preset name; gait_prior: clock + schedule;
    preset: the ``tron1 train --preset`` the run started from (``tron1cli.config.presets``) and
    preset_overrides: the options given explicitly on top of it; init_from: the checkpoint whose
    weights the run started from (``tron1 train --init``; None: a fresh initialisation);
    init_action_std: with ``init_from``, the action standard deviation (action units, every
    joint) the policy starts at instead of the source's (``--init-std``); None: the source's.
    """

    env: EnvConfig = field(default_factory=EnvConfig)
    learner: LearnerConfig = field(default_factory=LearnerConfig)
    ablation: str = "none"
    gait_prior: bool = True
    iterations: int = 1000
    save_every: int = 50
    preset: str = "none"
    preset_overrides: tuple[str, ...] = ()
    init_from: str | None = None
    init_action_std: float | None = None
    #: the reward a saved run was trained with (restored from its config); None: built from
    #: ``ablation`` and ``gait_prior`` with this version's defaults
    saved_reward: RewardConfig | None = field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        if self.iterations < 1:
            raise ValueError(f"iterations must be positive, got {self.iterations}")
        if self.save_every < 1:
            raise ValueError(f"save_every must be positive, got {self.save_every}")
        if self.init_action_std is not None and not (
            math.isfinite(self.init_action_std) and self.init_action_std > 0
        ):
            raise ValueError(f"init_action_std must be a positive number, got {self.init_action_std}")
        if self.gait_prior != self.env.gait.enabled:
            raise ValueError("gait_prior and env.gait.enabled disagree")
        if self.env.perception and self.env.depth_from != self.n_teacher:
            raise ValueError(
                f"env.depth_from is {self.env.depth_from} but the students start at env {self.n_teacher} "
                f"(num_envs {self.env.num_envs} x learner.teacher_ratio {self.learner.teacher_ratio}): "
                "students without depth images would train blind"
            )
        clocked = self.reward.clock_terms
        if clocked and not self.gait_prior:
            raise ValueError(f"reward term {clocked[0]} follows the gait clock: it needs --gait-prior")

    @property
    def n_teacher(self) -> int:
        """Envs in the teacher group: ``[0, n_teacher)`` teachers, the rest students."""
        return teacher_count(self.env.num_envs, self.learner.teacher_ratio)

    @property
    def reward(self) -> RewardConfig:
        return self.saved_reward or make_reward_config(self.ablation, gait_prior=self.gait_prior)

    def to_dict(self) -> dict:
        d = to_plain(replace(self, saved_reward=None))
        del d["saved_reward"]
        d["reward"] = self.reward.to_dict()  # resolved: a resumed or evaluated run gets exactly this
        d["tron1cli_version"] = __version__
        return d

    @classmethod
    def from_dict(cls, d: dict) -> RunConfig:
        """The inverse of :meth:`to_dict`; ValueError, one line naming the field, for anything
        else (a field of the wrong kind, a value the configuration refuses)."""
        if not isinstance(d, dict):
            raise ValueError(f"the run configuration should be an object, got {type(d).__name__}")
        reward = d.get("reward")
        try:
            plain = {k: v for k, v in d.items() if k not in ("reward", "tron1cli_version")}
            cfg = from_plain(cls, plain, "run_config")
            if reward is None:
                return cfg
            if not isinstance(reward, dict) or not isinstance(reward.get("terms"), dict):
                raise ValueError("the run configuration's reward should be an object with terms")
            if not all(isinstance(t, dict) for t in reward["terms"].values()):
                raise ValueError("the run configuration's reward terms should be objects")
            return replace(cfg, saved_reward=RewardConfig.from_dict(reward))
        except (TypeError, KeyError, AttributeError) as e:
            raise ValueError(f"run configuration: {describe(e)}") from None


def run_config(
    preset: TrainPreset,
    seed: int = 0,
    nthread: int = 2,
    save_every: int = 50,
    precision: str = "fp32",
    overrides: tuple[str, ...] = (),
) -> RunConfig:
    """The run a preset (with any options already applied to it) describes; ValueError if invalid.

    The preset's critic weights are kept for the reward groups the run has (an ablation may merge
    them); teachers see the heightmap, students the depth image. overrides: the options given on
    top of the preset, recorded with the run.
    """
    reward = make_reward_config(preset.ablation, gait_prior=preset.gait_prior)
    reward = with_ramps(with_weights(reward, preset.reward_weights), preset.reward_ramps)
    reward = with_settings(reward, preset.reward_settings)
    groups = reward.groups
    env_cfg = EnvConfig(
        num_envs=preset.num_envs,
        seed=seed,
        terrain=preset.terrain,
        nthread=nthread,
        gait=GaitConfig(
            enabled=preset.gait_prior,
            freq_hz=tuple(preset.gait_freq_hz),
            swing_fold_rad=tuple(preset.swing_fold),
            swing_fold_keep=preset.swing_fold_keep,
        ),
        perception=preset.perception,
        depth_from=teacher_count(preset.num_envs, preset.teacher_ratio),
        randomization=preset.randomization,
        pushes=preset.pushes,
        terrain_mix=dict(preset.terrain_mix),
        max_init_level=preset.init_level,
        curriculum_rule=preset.curriculum_rule,
        level_floor=dict(preset.level_floor),
        commands=CommandConfig(
            face_climb=preset.face_climb,
            heading=preset.heading,
            heading_spread_rad=math.radians(preset.heading_spread_deg),
        ),
        termination=TerminationConfig(bodies=tuple(preset.terminate_on)),
    )
    learner_cfg = replace(
        LearnerConfig(),
        teacher_ratio=preset.teacher_ratio,
        num_steps_per_env=preset.steps_per_env,
        num_epochs=preset.epochs,
        actor_hidden=preset.hidden,
        critic_hidden=preset.hidden,
        critic_weights={g: w for g, w in preset.critic_weights.items() if g in groups},
        precision=precision,
    )
    return RunConfig(
        env=env_cfg,
        learner=learner_cfg,
        ablation=preset.ablation,
        gait_prior=preset.gait_prior,
        iterations=preset.iterations,
        save_every=save_every,
        preset=preset.name,
        preset_overrides=tuple(overrides),
        saved_reward=reward
        if preset.reward_weights or preset.reward_ramps or preset.reward_settings
        else None,
    )


def check_batch(cfg: RunConfig) -> None:
    """ValueError unless every PPO minibatch of ``cfg`` holds samples: the envs times the steps
    per env must be at least the minibatches (an empty one makes every loss NaN)."""
    n, steps = cfg.env.num_envs, cfg.learner.num_steps_per_env
    mb = cfg.learner.num_minibatches
    if n * steps < mb:
        raise ValueError(
            f"--envs {n} x --steps-per-env {steps} gives {n * steps} samples an iteration, fewer than "
            f"the {mb} minibatches of an update (--learner num_minibatches={mb}); take more envs or "
            "steps, or fewer minibatches"
        )


def rollout_memory(cfg: RunConfig) -> int:
    """Bytes a run's env and rollout storage need at least per env (:mod:`tron1cli.memory`)."""
    from tron1cli.memory import env_bytes, rollout_bytes
    from tron1cli.policy.contract import layout_of

    sizes = layout_of(cfg).sizes()
    return env_bytes(cfg.env) + rollout_bytes(
        sizes, cfg.learner.num_steps_per_env, groups=len(cfg.reward.groups)
    )


def _why(e: OSError) -> str:
    """An OSError of a write as a few words ("no space left on the device", ...)."""
    if e.errno == errno.ENOSPC:
        return "no space left on the device"
    if e.errno == errno.EDQUOT:
        return "the disk quota is used up"
    return e.strerror or describe(e)


def obs_dims(env: Tron1Env) -> ObsDims:
    sizes = env.layout.sizes()
    return ObsDims(
        proprio=sizes["proprio"],
        history=sizes["history"],
        privileged=sizes["privileged"],
        heightmap=sizes.get("heightmap", 0),
        depth_hw=env.layout.depth_hw,
    )


def tracking_error(env: Tron1Env) -> np.ndarray:
    """Planar velocity tracking error (N,) in m/s, base frame: |v_cmd,xy - v_xy|."""
    return np.linalg.norm(env.commands.value[:, :2] - env.state.base_lin_vel_b[:, :2], axis=1)


class Trainer:
    """One training run in ``run_dir``.

    A new run takes ``cfg``; ``resume`` continues the run saved in ``checkpoints/latest.pt`` with
    its saved configuration, up to ``iterations`` in total when given (else the saved total).
    device: where the learner computes (``cpu`` or ``cuda``); the env core always runs on the CPU.
    threads: physics and torch threads of a resumed run (a new run takes ``cfg.env.nthread``).
    init: a checkpoint whose weights a new run starts from wherever the shapes agree
    (:mod:`tron1cli.learn.warm_start`). save_every: a resumed run's new checkpoint period.
    precision: a resumed run's update arithmetic (``fp32`` or ``bf16``; None: as saved), a setting
    of the machine like ``threads``: it changes no state, only how fast the update computes.
    backend: the physics engine (tron1cli.env.physics.BACKENDS), a setting of the machine like
    ``device``: a run does not record it, and a resumed run takes the value given now.
    """

    def __init__(
        self,
        run_dir: Path,
        cfg: RunConfig | None = None,
        resume: bool = False,
        iterations: int | None = None,
        device: str = "cpu",
        threads: int | None = None,
        init: Path | None = None,
        save_every: int | None = None,
        precision: str | None = None,
        backend: str = "mujoco",
    ) -> None:
        self.run_dir = Path(run_dir)
        self.ckpt_dir = checkpoint_dir(self.run_dir)
        self.latest = latest_checkpoint(self.run_dir)
        self.metrics_path = self.run_dir / METRICS
        if init is not None and resume:
            raise UsageError("--init starts a new run from other weights; --resume continues this one")
        made = not self.run_dir.exists()
        self.lock = RunLock(self.run_dir).acquire()  # one training process per run directory
        try:
            self._setup(cfg, resume, iterations, device, threads, init, save_every, precision, backend)
        except BaseException:
            if hasattr(self, "env"):
                self.env.close()
            self.lock.release()
            if made:  # a run refused before it began leaves no empty folder behind
                try:
                    self.run_dir.rmdir()
                except OSError:
                    pass
            raise

    def _setup(self, cfg, resume, iterations, device, threads, init, save_every, precision, backend) -> None:
        state = None
        source = load_training_checkpoint(init) if init is not None else None
        if source is not None:
            bad = nonfinite_weights(source["learner"]["model"])
            if bad:
                raise Tron1Error(
                    f"--init {init}: the policy's weights are not finite (NaN or inf in {bad[0]}); "
                    "start from an earlier checkpoint of that run"
                )
        if resume:
            state = load_training_checkpoint(self.latest)
            try:
                cfg = RunConfig.from_dict(json.loads(state["config"]))
            except ValueError as e:
                raise Tron1Error(f"{self.latest}: the run configuration is unreadable ({e})") from None
            if iterations is not None:
                cfg = replace(cfg, iterations=iterations)
            if threads is not None:  # the machine may differ from the one the run started on
                cfg = replace(cfg, env=replace(cfg.env, nthread=threads))
            if save_every is not None:
                cfg = replace(cfg, save_every=save_every)
            if precision is not None:
                cfg = replace(cfg, learner=replace(cfg.learner, precision=precision))
        elif cfg is None:
            raise UsageError("a new run needs a configuration")
        elif self.latest.exists():
            raise UsageError(f"{self.run_dir} already holds a run: pass --resume to continue it")
        self.cfg = cfg
        from tron1cli.memory import check_memory

        check_memory(cfg.env.num_envs, rollout_memory(cfg), "the envs and their rollout storage")
        # a save killed midway leaves its temp file; nothing else would ever remove it
        clean_stale_temps(self.ckpt_dir)
        clean_stale_temps(self.run_dir, f".{CONFIG}")
        torch.manual_seed(cfg.env.seed)
        torch.set_num_threads(cfg.env.nthread)
        self.env = Tron1Env(cfg.env, cfg.reward, backend=backend)
        self.backend = backend
        self.n_teacher = cfg.n_teacher
        self.learner = VisionCTSLearner(
            obs_dims(self.env),
            cfg.env.num_envs,
            cfg.reward.groups,
            cfg.learner,
            device=device,
            seed=cfg.env.seed,
        )
        self.iteration = 0
        self.env_steps = 0
        self.wall_s = 0.0
        #: what --init copied (None without it, and on resume)
        self.warm_start: WarmStart | None = None
        #: --init put the envs on the source run's terrain levels (:meth:`_carry_levels`)
        self.levels_carried = False
        if source is not None:
            self.warm_start = warm_start(self.learner.model, source["learner"]["model"])
            if not self.warm_start.copied and not self.warm_start.widened:
                raise Tron1Error(f"--init {init}: the checkpoint shares no weights with this run's networks")
            origin = f"{init} (iteration {int(source['iteration'])})"
            if cfg.init_action_std is not None:
                with torch.no_grad():
                    self.learner.model.log_std.fill_(math.log(cfg.init_action_std))
                origin += f", action std set to {cfg.init_action_std:g}"
            self.levels_carried = self._carry_levels(source)
            if self.levels_carried:
                origin += ", terrain levels carried"
            self.cfg = cfg = replace(cfg, init_from=origin)
        if state is not None:
            try:
                self.learner.load_state_dict(state["learner"])
            except (KeyError, TypeError, ValueError, RuntimeError) as e:
                raise Tron1Error(
                    f"{self.latest}: its learner state does not fit the run ({describe(e)})"
                ) from e
            self._restore_levels(state)
            self.iteration = int(state["iteration"])
            self.env_steps = int(state["env_steps"])
            self.wall_s = float(state.get("wall_s", 0.0))
        #: the iteration of the checkpoint on disk (None before the first save)
        self.saved_iteration: int | None = self.iteration if state is not None else None
        #: the number of a cut last line of metrics.jsonl dropped at the start (None: none was)
        self.dropped_metrics_line = self._trim_metrics()
        self.stats = EpisodeStats(step_s=self.env.policy_dt)
        if state is not None and "episode_stats" in state:  # older checkpoints: start empty
            self.stats.load_state_dict(state["episode_stats"])

    def _carry_levels(self, source: dict) -> bool:
        """``--init``: start the envs on the terrain levels the source run reached, when it trained
        on the same terrain bank (terrain, tile geometry, seed), so a new phase of a campaign does
        not climb the curriculum again from level 0: each env on its own level and tile with the
        same env count and terrain mix, else on the level of a source env of its terrain type
        (:meth:`Tron1Env.restore_curriculum`)."""
        if not self.cfg.env.curriculum:
            return False
        mine = self.cfg.to_dict()["env"]
        theirs = json.loads(source["config"]).get("env")
        if not isinstance(theirs, dict):
            return False
        if any(theirs.get(k) != mine[k] for k in ("terrain", "terrain_cfg", "seed")):
            return False
        return self._restore_levels(source)

    def _restore_levels(self, ckpt: dict) -> bool:
        """Put the envs on the terrain levels and tiles saved in checkpoint ``ckpt``, when it holds
        them and this run has terrain; whether it did."""
        if "curriculum" not in ckpt or not self.env.model.nhfield:
            return False
        self.env.restore_curriculum({k: v.numpy() for k, v in ckpt["curriculum"].items()})
        return True

    # -- persistence ------------------------------------------------------------------------
    def nonfinite(self) -> list[str]:
        """Names of the model's parameters and buffers (normaliser statistics included) holding
        NaN or inf; one pass over the model, done once per iteration."""
        named = [(k, v) for k, v in self.learner.model.state_dict().items() if v.is_floating_point()]
        ok = torch.stack([torch.isfinite(v).all() for _, v in named]) if named else torch.ones(0)
        if bool(ok.all()):
            return []
        return [k for (k, _), good in zip(named, ok.tolist(), strict=True) if not good]

    def _stop_nonfinite(self, what: str) -> None:
        kept = (
            f"{self.latest} (iteration {self.saved_iteration}) is the last good checkpoint; --resume "
            "continues from it"
            if self.saved_iteration is not None
            else "no checkpoint had been saved yet"
        )
        raise NonFiniteTraining(
            f"training went non-finite in iteration {self.iteration + 1} ({what}); stopped without "
            f"saving it: {kept}"
        )

    def check_finite(self, learn_stats: dict) -> None:
        """Stop (:class:`NonFiniteTraining`) when a loss or the model went NaN or inf."""
        bad = [k for k, v in learn_stats.items() if "loss" in k and not math.isfinite(float(v))]
        if bad:
            self._stop_nonfinite(f"{bad[0]} is {learn_stats[bad[0]]}")
        names = self.nonfinite()
        if names:
            more = f" and {len(names) - 1} more" if len(names) > 1 else ""
            self._stop_nonfinite(f"non-finite values in {names[0]}{more}")

    def _trim_metrics(self) -> int | None:
        """Drop metrics lines past the checkpoint resumed from (iterations that will be redone; a
        new run: all) and a cut last line (:func:`tron1cli.train.metrics.trim_metrics`)."""
        try:
            return trim_metrics(self.metrics_path, self.iteration)
        except OSError as e:
            raise self._write_failed(e, self.metrics_path) from e

    def _write_failed(self, e: OSError, path: Path) -> Tron1Error:
        """One line for a write that failed (a disk that filled): what failed and what was kept."""
        kept = (
            f"{self.latest} (iteration {self.saved_iteration}) is the last good checkpoint; --resume "
            "continues from it once there is room"
            if self.saved_iteration is not None
            else "no checkpoint had been saved yet"
        )
        return Tron1Error(f"cannot write {path}: {_why(e)}; {kept}")

    def save(self) -> Path:
        names = self.nonfinite()
        if names:  # never replace a good checkpoint with a broken one
            raise NonFiniteTraining(
                f"not saving iteration {self.iteration}: non-finite values in {names[0]}; "
                f"{self.latest} keeps the last good state"
            )
        payload = {
            "config": json.dumps(self.cfg.to_dict()),
            "learner": self.learner.state_dict(),
            "iteration": self.iteration,
            "env_steps": self.env_steps,
            "wall_s": self.wall_s,
            "obs_layout": json.dumps(self.env.layout.to_dict()),
            "curriculum": {k: torch.from_numpy(v) for k, v in self.env.curriculum_state().items()},
            "episode_stats": self.stats.state_dict(),
        }
        try:  # a failed save (a full disk) leaves the checkpoint it would replace as it was
            save_checkpoint(self.latest, payload)
        except OSError as e:
            raise self._write_failed(e, self.latest) from e
        self.saved_iteration = self.iteration
        if self.iteration % self.cfg.save_every == 0 or self.iteration == self.cfg.iterations:
            path = self.ckpt_dir / f"ckpt_{self.iteration:05d}.pt"
            try:
                save_checkpoint(path, payload)
            except OSError as e:
                raise self._write_failed(e, path) from e
        return self.latest

    def _write_config(self) -> None:
        data = json.dumps(self.cfg.to_dict(), indent=2).encode()
        try:
            atomic_write(self.run_dir / CONFIG, lambda f: f.write(data), fsync=False)
        except OSError as e:
            raise self._write_failed(e, self.run_dir / CONFIG) from e

    # -- the loop ---------------------------------------------------------------------------
    def iterate(
        self, obs: dict, before_step: Callable | None = None, after_step: Callable | None = None
    ) -> tuple[dict, dict]:
        """One PPO iteration from observation ``obs``: T env steps, then the update.

        before_step(env, t) and after_step(env, t, result): called around each env step (t: step in
        the rollout; result: what ``env.step`` returned).
        Returns (next observation, metrics of the iteration).
        """
        t0 = time.perf_counter()
        env, learner, n_t = self.env, self.learner, self.n_teacher
        T = self.cfg.learner.num_steps_per_env
        group_reward = {g: 0.0 for g in env.reward_cfg.groups}
        env.rewards.set_iteration(self.iteration)
        for t in range(T):
            actions = learner.act(obs)
            if before_step is not None:
                before_step(env, t)
            res = env.step(actions)
            if after_step is not None:
                after_step(env, t, res)
            learner.process_step(res.rewards, res.done, res.time_out, res.terminal_obs)
            for g, r in res.rewards.items():
                group_reward[g] += float(r.mean())
            self.stats.add_episodes(np.flatnonzero(res.done), res.episode, n_t)
            self.stats.add_step(tracking_error(env), n_t)
            obs = res.obs
        t1 = time.perf_counter()
        learn_stats = learner.update(obs)
        self.check_finite(learn_stats)
        t2 = time.perf_counter()
        self.iteration += 1
        steps = T * env.n
        self.env_steps += steps
        self.wall_s += t2 - t0
        m = {
            "iteration": self.iteration,
            "env_steps": self.env_steps,
            "wall_s": round(self.wall_s, 3),
            "steps_per_s": steps / (t2 - t0),
            "collect_s": t1 - t0,
            "learn_s": t2 - t1,
            "unstable_resets": env.unstable_count,
        }
        m.update({f"step_reward/{g}": v / T for g, v in group_reward.items()})
        m.update(self.stats.summary())
        if env.model.nhfield:  # terrain level per type (0 easiest .. num_levels - 1)
            levels = env.curriculum.mean_levels()
            m.update({f"terrain/level/{t}": v for t, v in levels.items()})
            m["terrain/mean_level"] = float(env.curriculum.level.mean())
        m.update({f"learn/{k}": v for k, v in learn_stats.items()})
        return obs, m

    def run(
        self,
        on_iteration: Callable[[dict], None] | None = None,
        max_minutes: float | None = None,
        stream=None,
        stream_every: int = 200,
    ) -> dict:
        """Train until ``cfg.iterations`` (or ``max_minutes`` of wall clock); returns the last metrics.

        stream: a rerun stream (:mod:`tron1cli.viz.rerun_stream`); every ``stream_every``
        iterations it follows the first student env (the first env when all are teachers) from
        that iteration until its episode ends, on a global ``step`` timeline.
        """
        self._write_config()
        watched = min(self.n_teacher, self.env.n - 1)
        following = False
        start = time.perf_counter()
        obs = self.env.reset(stagger=True)
        T = self.cfg.learner.num_steps_per_env
        last: dict = {}

        def log(env: Tron1Env, t: int) -> None:
            nonlocal following
            if following:
                step = self.iteration * T + t
                stream.log_step(env, watched, step, step * env.policy_dt)

        def unfollow(env: Tron1Env, t: int, res) -> None:
            nonlocal following
            following &= not res.done[watched]

        try:  # unbuffered: a failed write is seen here, not again when the file closes
            mlog = open(self.metrics_path, "ab", buffering=0)  # noqa: SIM115
        except OSError as e:
            raise self._write_failed(e, self.metrics_path) from e
        with mlog:
            while self.iteration < self.cfg.iterations:
                following |= stream is not None and self.iteration % stream_every == 0
                hooks = (log, unfollow) if following else (None, None)
                obs, m = self.iterate(obs, *hooks)
                line = json.dumps(
                    {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in m.items()}
                )
                try:  # a line cut here (a full disk) is dropped by the next start (trim_metrics)
                    view = memoryview((line + "\n").encode())
                    while view:
                        view = view[mlog.write(view) :]
                except OSError as e:
                    raise self._write_failed(e, self.metrics_path) from e
                if self.iteration % self.cfg.save_every == 0:
                    self.save()
                last = m
                if on_iteration is not None:
                    on_iteration(m)
                if max_minutes is not None and time.perf_counter() - start >= 60.0 * max_minutes:
                    break
        self.save()
        return last

    def close(self) -> None:
        try:
            self.env.close()
        finally:
            self.lock.release()


class NonFiniteTraining(Tron1Error):
    """A loss, a weight or a normaliser statistic went NaN or inf; the run stops unsaved."""
