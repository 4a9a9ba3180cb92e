"""``tron1 train``: Vision-CTS PPO with the LIPM-guided reward on the chosen terrain."""

from __future__ import annotations

import math
import signal
import time
from dataclasses import replace
from pathlib import Path
from types import MappingProxyType

import typer
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.table import Table

from tron1cli.cli.common import (
    SEED_MAX,
    available_cores,
    backend_note,
    backend_option,
    check_backend,
    check_inputs,
    check_outputs,
    err,
    fail,
    finite,
    note,
    out,
    path_option,
    preset_default,
    rerun_file,
    resolve_device,
    resolve_precision,
    terrain_help,
    threads_option,
)
from tron1cli.config.env import GaitConfig, TerminationConfig
from tron1cli.config.presets import FLAT_REWARD_RAMPS, PRESETS
from tron1cli.env.randomization import ALL_TERMS
from tron1cli.env.rewards import (
    ABLATIONS,
    REWARD_SETTINGS,
    make_reward_config,
    with_ramps,
    with_settings,
    with_weights,
)
from tron1cli.env.robot import TERMINATION_BODIES


def _ramps_text(ramps) -> str:
    """{"a": (200, 250)} -> 'a=200:250' (the form ``--reward-ramps`` takes)."""
    return ",".join(f"{k}={a}:{b}" for k, (a, b) in ramps.items())


#: the options a preset sets; given explicitly, they override it
PRESET_OPTIONS = (
    "terrain",
    "envs",
    "iterations",
    "teacher_ratio",
    "gait_prior",
    "steps_per_env",
    "hidden",
    "critic_weights",
    "reward_weights",
    "reward_ramps",
    "reward_settings",
    "learner",
    "perception",
    "randomize",
    "randomize_skip",
    "pushes",
    "ablation",
    "terrain_mix",
    "init_level",
    "curriculum_rule",
    "face_climb",
    "heading",
    "heading_spread",
    "level_floor",
    "swing_fold",
    "swing_fold_keep",
    "gait_freq_range",
    "terminate_on",
)


def _fmt(v) -> str:
    return "-" if v is None or v != v else f"{v:.2f}"


def train(
    ctx: typer.Context,
    preset: str | None = typer.Option(
        None,
        "--preset",
        help=f"Start from a named preset: {', '.join(PRESETS)} [default: flat on flat ground, perceptive "
        "elsewhere]; options given explicitly override it (the run header lists them).",
        show_default=False,
    ),
    terrain: str = typer.Option("flat", "--terrain", "-t", help=terrain_help()),
    envs: int | None = typer.Option(
        None,
        "--envs",
        "-n",
        min=2,
        help=f"Parallel environments (teacher + student) [default: {preset_default('num_envs')}].",
        show_default=False,
    ),
    iterations: int | None = typer.Option(
        None,
        "--iterations",
        "-i",
        min=1,
        help=f"PPO iterations in total [default: {preset_default('iterations')}; on --resume: the "
        "run's own].",
        show_default=False,
    ),
    seed: int = typer.Option(0, "--seed", min=0, max=SEED_MAX, help="Seed of every random stream."),
    ablation: str = typer.Option(
        "none", "--ablation", "-a", help="none, no-stable-reward, single-critic, no-rfm, l2-velocity."
    ),
    run_dir: Path = typer.Option(
        Path("runs/latest"), "--run-dir", "-o", parser=path_option, metavar="DIR", help="Run directory."
    ),
    resume: bool = typer.Option(
        False, "--resume", help="Continue the run in --run-dir from its last checkpoint."
    ),
    init: Path | None = typer.Option(
        None,
        "--init",
        help="Start a new run from this checkpoint's weights wherever the shapes agree (a blind "
        "policy into a perceptive run: the new inputs' weights start at zero).",
        show_default=False,
    ),
    init_std: float | None = typer.Option(
        None,
        "--init-std",
        callback=finite,
        min=1e-3,
        help="With --init: start the policy's action std (every joint, action units) here instead "
        "of the checkpoint's, to explore again.",
        show_default=False,
    ),
    teacher_ratio: float = typer.Option(
        0.5, "--teacher-ratio", callback=finite, min=0.0, max=1.0, help="Share of teacher envs."
    ),
    gait_prior: bool = typer.Option(
        True,
        "--gait-prior/--no-gait-prior",
        help="Gait clock + contact-schedule reward (off: the paper exactly).",
    ),
    steps_per_env: int | None = typer.Option(
        None,
        "--steps-per-env",
        min=1,
        help=f"Rollout length per iteration (policy steps) [default: {preset_default('steps_per_env')}].",
        show_default=False,
    ),
    hidden: str | None = typer.Option(
        None,
        "--hidden",
        help=f"Actor and critic MLP sizes (the paper gives none) [default: {preset_default('hidden')}].",
        show_default=False,
    ),
    save_every: int = typer.Option(50, "--save-every", min=1, help="Checkpoint period (iterations)."),
    minutes: float = typer.Option(
        None, "--minutes", callback=finite, min=0.0, help="Stop after this much wall-clock time."
    ),
    threads: int = threads_option("Physics and torch threads; a resumed run takes the value given now"),
    device: str = typer.Option(
        "cpu", "--device", help="Where the learner runs: cpu or cuda (the simulator stays on the CPU)."
    ),
    backend: str = backend_option(),
    precision: str = typer.Option(
        "fp32",
        "--precision",
        help="The update's arithmetic: fp32, or bf16 (matrix products in bfloat16, float32 "
        "accumulation: several times faster on CPUs with AMX and on recent GPUs, several times "
        "slower on CPUs without native bfloat16); a resumed run takes the value given now.",
    ),
    perception: bool | None = typer.Option(
        None,
        "--perception/--no-perception",
        help="Heightmap for teachers, 30 Hz depth for students [default: on except on flat].",
        show_default=False,
    ),
    randomize: bool | None = typer.Option(
        None,
        "--randomize/--no-randomize",
        help="Table III domain randomisation [default: on except on flat].",
        show_default=False,
    ),
    randomize_skip: str = typer.Option(
        "",
        "--randomize-skip",
        help="Table III terms to leave out, comma-separated: " + ", ".join(ALL_TERMS) + ".",
    ),
    critic_weights: str = typer.Option(
        "",
        "--critic-weights",
        help="Weights of the per-group normalised advantages, e.g. stable=0.5,loco=1 "
        "[default: stable=0.25 on flat, 0.5 elsewhere, loco=1 (the paper leaves them open; "
        "measured to learn sooner)].",
    ),
    reward_weights: str = typer.Option(
        "",
        "--reward-weights",
        help="Per-second weights of reward terms replacing the defaults, e.g. alive=0.5 "
        "(terms: README, Reward; a run's own in its config.json).",
    ),
    reward_ramps: str = typer.Option(
        "",
        "--reward-ramps",
        help="Reward terms whose weight rises from 0 over training iterations, TERM=START:END, or "
        f"TERM=none for the full weight from the start [default: {_ramps_text(FLAT_REWARD_RAMPS)} "
        "on flat ground, none elsewhere].",
    ),
    reward_settings: str = typer.Option(
        "",
        "--reward-settings",
        metavar="NAME=VALUE,...",
        help="Numbers of the reward, e.g. gait_clearance_top_m=0.2 (swing apex rising with the terrain "
        "level) or z_c=0.54 (m).",
    ),
    learner: str = typer.Option(
        "",
        "--learner",
        help="Learner settings replacing the defaults, KEY=VALUE pairs, e.g. "
        "rec_batch_envs=256,entropy_coef=0.001 (the scalar fields of tron1cli.learn.LearnerConfig).",
    ),
    rerun: str = typer.Option(
        "off",
        "--rerun",
        help="Stream one student episode every --rerun-every iterations: spawn, save=FILE.rrd, "
        "connect[=URL] or off.",
    ),
    rerun_every: int = typer.Option(
        200, "--rerun-every", min=1, help="Iterations between streamed episodes."
    ),
    terrain_mix: str = typer.Option(
        "",
        "--terrain-mix",
        metavar="TYPE=SHARE,...",
        help="Share of the envs per terrain type of --terrain, e.g. stairs_up=4,stairs_down=2,rough=1 "
        "(types left out get none) [default: equal shares].",
    ),
    init_level: int = typer.Option(
        0, "--init-level", min=0, help="Envs start on terrain levels 0..LEVEL (9: any level)."
    ),
    curriculum_rule: str = typer.Option(
        "distance",
        "--curriculum-rule",
        help="How terrain levels move at episode ends: distance (up after walking far, down after "
        "walking under half the commanded distance), falls (down only after a fall) or uniform "
        "(every episode on a random level).",
    ),
    level_floor: str = typer.Option(
        "",
        "--level-floor",
        metavar="TYPE=LEVEL,...",
        help="Lowest terrain level per type, e.g. stairs_up=3: its envs start on it or above and "
        "are never moved below it [default: 0].",
    ),
    swing_fold: str = typer.Option(
        "0,0",
        "--swing-fold",
        metavar="HIP,KNEE",
        help="Hip and knee flexion (rad) the gait clock adds to a swinging leg's joint targets at the "
        "top of the swing, e.g. 0.5,0.8: the feet rise without the policy asking (ours, not the paper's; "
        "needs the gait prior; carried by the ONNX contract).",
    ),
    swing_fold_keep: float = typer.Option(
        0.0,
        "--swing-fold-keep",
        metavar="SHARE",
        help="Share of the swing fold the policy's action cannot take away, in [0, 1], e.g. 0.75: "
        "a folded hip or knee keeps at least that share of the fold's flexion (0: the policy may "
        "undo it all; needs --swing-fold).",
    ),
    gait_freq_range: str = typer.Option(
        "1.5,2.5",
        "--gait-freq-range",
        metavar="LO,HI",
        help="Range (Hz) of the gait clock's frequency, drawn with each command, e.g. 2,2.5 "
        "(deployment runs the middle of it unless told otherwise).",
    ),
    terminate_on: str = typer.Option(
        ",".join(TERMINATION_BODIES),
        "--terminate-on",
        metavar="BODIES",
        help="The bodies whose touching the ground ends an episode as a fall, from "
        f"{', '.join(TERMINATION_BODIES)}; e.g. base, as LimX's Isaac configs (a thigh brushing a "
        "stair nosing then costs the collision penalty, not the episode). Evaluation always "
        "judges falls by all three.",
    ),
    face_climb: bool = typer.Option(
        False,
        "--face-climb/--no-face-climb",
        help="On stairs and slopes, commands face the climb: forward only (|v_x|), no sideways speed.",
    ),
    heading: bool = typer.Option(
        False,
        "--heading/--no-heading",
        help="Heading mode: each command draws a world heading and the yaw-rate command steers the "
        "robot to it (0.5/s x heading error), so that tracking pays for walking straight, not in circles.",
    ),
    heading_spread: float = typer.Option(
        180.0,
        "--heading-spread",
        min=0.0,
        max=180.0,
        help="With --heading: each heading is drawn within this angle (degrees) of the robot's yaw "
        "(180: any heading; small: walk on about where it faces, no turn first).",
    ),
    pushes: bool | None = typer.Option(
        None,
        "--pushes/--no-pushes",
        help="Moderate random pushes (+/-50 N, +/-5 N m) [default: on except on flat].",
        show_default=False,
    ),
) -> None:
    """Train a policy; Ctrl-C saves a checkpoint, --resume continues a run."""
    from tron1cli.config.presets import for_terrain, make_preset
    from tron1cli.env.randomization import PushConfig, RandomizationConfig

    given = [n for n in PRESET_OPTIONS if _given(ctx, n)]
    if resume and preset is not None:
        fail("--preset starts a new run; --resume continues with the run's own configuration", 2)
    if init is not None and resume:
        fail("--init starts a new run from other weights; --resume continues this one", 2)
    if init_std is not None and init is None:
        fail(
            "--init-std sets the action std over --init's weights; a fresh run takes "
            "--learner init_noise_std=X",
            2,
        )
    if resume:
        _resume(
            ctx,
            run_dir,
            iterations,
            device,
            threads,
            save_every,
            minutes,
            rerun,
            rerun_every,
            precision,
            backend,
        )
        return
    try:
        if preset is not None:
            base = make_preset(preset)
        else:
            base = for_terrain(terrain)
    except ValueError as e:
        fail(str(e), 2)
    overridden = tuple(n for n in given if preset is not None or n != "terrain")  # terrain picks the preset
    terrain = terrain if "terrain" in given else base.terrain
    ablation = ablation if "ablation" in given else base.ablation
    if ablation not in ABLATIONS:
        fail(f"unknown ablation '{ablation}'; choose from {', '.join(ABLATIONS)}", 2)
    if terrain != "flat":
        from tron1cli.env.terrain import resolve_terrain

        try:
            resolve_terrain(terrain)
        except ValueError as e:
            fail(str(e), 2)
    sizes = base.hidden
    if "hidden" in given:
        try:
            sizes = tuple(int(x) for x in hidden.split(","))
            if not sizes or min(sizes) < 1:
                raise ValueError
        except ValueError:
            fail(f"--hidden wants positive integers separated by commas, got '{hidden}'", 2)
    from tron1cli.viz.rerun_stream import parse_rerun_option

    try:
        target = parse_rerun_option(rerun)
    except ValueError as e:
        fail(str(e), 2)
    gait_prior = gait_prior if "gait_prior" in given else base.gait_prior
    reward = make_reward_config(ablation, gait_prior=gait_prior)  # checked as the options below change it
    groups = reward.groups
    if "critic_weights" in given:
        weights = _parse_weights(critic_weights, "--critic-weights", "GROUP")
        bad = [k for k, w in weights.items() if w < 0]
        if bad:
            fail(f"--critic-weights: {bad[0]}={weights[bad[0]]} is not a finite number >= 0", 2)
        unknown = sorted(set(weights) - set(groups))
        if unknown:
            known = ", ".join(groups)
            fail(f"--critic-weights: unknown reward group '{unknown[0]}'; this run's groups: {known}", 2)
    else:  # the preset's weights of the groups this run has (an ablation may merge them)
        weights = {g: w for g, w in base.critic_weights.items() if g in groups}
    term_weights = dict(base.reward_weights)
    if "reward_weights" in given:
        term_weights |= _parse_weights(reward_weights, "--reward-weights", "TERM")
    try:
        reward = with_weights(reward, term_weights)
    except ValueError as e:
        fail(f"--reward-weights: {e}", 2)
    ramps = dict(base.reward_ramps)
    if "reward_ramps" in given:
        try:
            for term, ramp in _ramps(reward_ramps).items():
                if ramp is None:
                    ramps.pop(term, None)
                else:
                    ramps[term] = ramp
            with_ramps(reward, ramps)
        except ValueError as e:
            fail(f"--reward-ramps: {e}", 2)
    settings_r = dict(base.reward_settings)
    if "reward_settings" in given:
        settings_r |= _parse_weights(reward_settings, "--reward-settings", "NAME")
        try:
            with_settings(reward, settings_r)
        except ValueError as e:
            fail(f"--reward-settings: {e}", 2)
    randomization = base.randomization
    if "randomize" in given:
        randomization = RandomizationConfig.table_iii() if randomize else RandomizationConfig()
    if "randomize_skip" in given:
        try:  # the names first: an unknown term is wrong whether randomisation is on or not
            skipped = RandomizationConfig.table_iii(skip=_csv(randomize_skip))
        except ValueError as e:
            fail(f"--randomize-skip: {e}", 2)
        if not randomization.terms:
            fail("--randomize-skip needs Table III randomisation on (--randomize)", 2)
        randomization = skipped
    settings = {}
    if "learner" in given:
        try:
            settings = _learner_settings(learner)
        except ValueError as e:
            fail(f"--learner: {e}", 2)
    device = resolve_device(device)
    precision = resolve_precision(precision, device)
    check_backend(backend)
    threads = threads or available_cores()
    from tron1cli.train.layout import check_run_dir, checkpoint_dir

    check_run_dir(run_dir, resume)
    check_inputs([init], "--init checkpoint")
    check_outputs(files=[rerun_file(target)], inputs=[init] if init else ())
    # torch (2-3 s to import on 2 cores) loads from here on, once the options above are checked
    from tron1cli.learn import tune_glibc_malloc
    from tron1cli.train.runner import Trainer, run_config

    tune_glibc_malloc()
    try:
        push_cfg = base.pushes
        if "pushes" in given:
            push_cfg = PushConfig.moderate() if pushes else PushConfig()
        chosen = replace(
            base,
            terrain=terrain,
            num_envs=envs if "envs" in given else base.num_envs,
            iterations=iterations if "iterations" in given else base.iterations,
            steps_per_env=steps_per_env if "steps_per_env" in given else base.steps_per_env,
            hidden=sizes,
            teacher_ratio=teacher_ratio if "teacher_ratio" in given else base.teacher_ratio,
            gait_prior=gait_prior,
            critic_weights=MappingProxyType(weights),
            reward_weights=MappingProxyType(term_weights),
            reward_ramps=MappingProxyType(ramps),
            reward_settings=MappingProxyType(settings_r),
            perception=perception if "perception" in given else base.perception,
            randomization=randomization,
            pushes=push_cfg,
            ablation=ablation,
            terrain_mix=MappingProxyType(
                _parse_weights(terrain_mix, "--terrain-mix", "TYPE")
                if "terrain_mix" in given
                else base.terrain_mix
            ),
            init_level=init_level if "init_level" in given else base.init_level,
            curriculum_rule=curriculum_rule if "curriculum_rule" in given else base.curriculum_rule,
            face_climb=face_climb if "face_climb" in given else base.face_climb,
            heading=heading if "heading" in given else base.heading,
            heading_spread_deg=heading_spread if "heading_spread" in given else base.heading_spread_deg,
            swing_fold=_parse_fold(swing_fold) if "swing_fold" in given else base.swing_fold,
            swing_fold_keep=swing_fold_keep if "swing_fold_keep" in given else base.swing_fold_keep,
            gait_freq_hz=_parse_freq(gait_freq_range) if "gait_freq_range" in given else base.gait_freq_hz,
            terminate_on=tuple(_csv(terminate_on)) if "terminate_on" in given else base.terminate_on,
            level_floor=MappingProxyType(
                _parse_levels(level_floor) if "level_floor" in given else base.level_floor
            ),
        )
        cfg = run_config(
            chosen,
            seed=seed,
            nthread=threads,
            save_every=save_every,
            precision=precision,
            overrides=overridden,
        )
    except ValueError as e:
        fail(str(e), 2)
    cfg = replace(cfg, learner=replace(cfg.learner, **settings), init_action_std=init_std)
    from tron1cli.train.runner import check_batch

    try:
        check_batch(cfg)
    except ValueError as e:
        fail(str(e), 2)
    n_teacher = cfg.n_teacher
    if n_teacher >= cfg.env.num_envs and not cfg.env.perception:
        fail(
            f"--teacher-ratio {cfg.learner.teacher_ratio:g} of {cfg.env.num_envs} envs leaves no "
            "student env: the student is the policy that is exported and deployed; take a smaller ratio",
            2,
        )
    if n_teacher >= cfg.env.num_envs:
        err.print(
            f"teacher stage: all {cfg.env.num_envs} envs are teachers, no depth is rendered and no "
            "student is trained; finish it with --preset perceptive --init <its checkpoint>"
        )
    if init is not None and Path(init).resolve().parent == checkpoint_dir(run_dir).resolve():
        fail(f"--init {init} lies in this run's own checkpoints; give another run's checkpoint", 2)
    with err.status(f"building {cfg.env.num_envs} envs{backend_note(backend)}..."):
        trainer = Trainer(run_dir, cfg, device=device, threads=threads, init=init, backend=backend)
    _run(trainer, run_dir, target, minutes, rerun_every, resumed=False)


def _resume(
    ctx, run_dir, iterations, device, threads, save_every, minutes, rerun, rerun_every, precision, backend
) -> None:
    """``--resume``: the saved run goes on as saved; an option that would change it is refused
    (the machine's settings excepted: threads, device, precision and the physics backend)."""
    from tron1cli.viz.rerun_stream import parse_rerun_option

    try:
        target = parse_rerun_option(rerun)
    except ValueError as e:
        fail(str(e), 2)
    device = resolve_device(device)
    precision = resolve_precision(precision, device) if _given(ctx, "precision") else None  # None: as saved
    from tron1cli.train.layout import check_run_dir

    check_run_dir(run_dir, True)
    check_outputs(files=[rerun_file(target)])
    _refuse_changed_options(ctx, run_dir)
    check_backend(backend)
    from tron1cli.learn import tune_glibc_malloc
    from tron1cli.train.runner import Trainer

    tune_glibc_malloc()
    with err.status(f"resuming {run_dir}{backend_note(backend)}..."):
        trainer = Trainer(
            run_dir,
            resume=True,
            iterations=iterations,
            device=device,
            threads=threads or available_cores(),
            save_every=save_every if _given(ctx, "save_every") else None,
            precision=precision,
            backend=backend,
        )
    if trainer.dropped_metrics_line is not None:
        note(
            f"{run_dir}/metrics.jsonl: dropped its cut last line {trainer.dropped_metrics_line} "
            "(a run stopped while writing it)"
        )
    _run(trainer, run_dir, target, minutes, rerun_every, resumed=True)


#: what a run fixes (--resume keeps it): option -> its value in a saved RunConfig
def _saved_values(cfg) -> dict:
    from tron1cli.learn.config import tunable_fields

    e, lr = cfg.env, cfg.learner
    terms = e.randomization.terms
    return {
        "terrain": e.terrain,
        "envs": e.num_envs,
        "teacher_ratio": lr.teacher_ratio,
        "gait_prior": cfg.gait_prior,
        "steps_per_env": lr.num_steps_per_env,
        "hidden": tuple(lr.actor_hidden),
        "critic_weights": {k: float(v) for k, v in lr.critic_weights.items() if float(v) != 1.0},
        "reward_weights": {k: t.weight for k, t in cfg.reward.terms.items()},
        "reward_ramps": {k: t.ramp for k, t in cfg.reward.terms.items() if t.ramp},
        "reward_settings": {k: getattr(cfg.reward, k) for k in REWARD_SETTINGS},
        "learner": {k: getattr(lr, k) for k in tunable_fields()},
        "perception": e.perception,
        "randomize": bool(terms),
        "randomize_skip": frozenset(t for t in ALL_TERMS if t not in terms) if terms else frozenset(),
        "pushes": e.pushes.enabled,
        "ablation": cfg.ablation,
        "seed": e.seed,
        "terrain_mix": dict(e.terrain_mix),
        "init_level": e.max_init_level,
        "curriculum_rule": e.curriculum_rule,
        "face_climb": e.commands.face_climb,
        "heading": e.commands.heading,
        "heading_spread": round(math.degrees(e.commands.heading_spread_rad), 6),
        "level_floor": dict(e.level_floor),
        "swing_fold": tuple(e.gait.swing_fold_rad),
        "swing_fold_keep": e.gait.swing_fold_keep,
        "gait_freq_range": tuple(e.gait.freq_hz),
        "terminate_on": e.termination.bodies,
    }


def _as_saved(name: str, value):
    """A command-line value in the form of :func:`_saved_values` (the raw value if it cannot be)."""
    try:
        if name == "hidden":
            return tuple(int(x) for x in value.split(","))
        if name == "critic_weights":
            return {k: v for k, v in _pairs(value).items() if v != 1.0}
        if name in ("reward_weights", "reward_settings", "terrain_mix"):
            return _pairs(value)
        if name == "level_floor":
            return _parse_levels(value)
        if name == "swing_fold":
            return _parse_fold(value)
        if name == "gait_freq_range":
            return _parse_freq(value)
        if name == "reward_ramps":
            return _ramps(value)
        if name == "randomize_skip":
            return frozenset(_csv(value))
        if name == "terminate_on":
            return TerminationConfig(bodies=_csv(value)).bodies
    except ValueError:
        return value
    return value


def _shown(name: str, value) -> str:
    flag = "--" + name.replace("_", "-")
    if isinstance(value, bool):
        return flag if value else "--no-" + name.replace("_", "-")
    if isinstance(value, tuple):
        value = ",".join(str(x) for x in value)
    elif isinstance(value, dict):
        empty = "(none)" if name == "reward_ramps" else "(all 1)"
        value = ",".join(f"{k}={_value(v)}" for k, v in value.items()) or empty
    elif isinstance(value, frozenset):
        value = ",".join(t for t in ALL_TERMS if t in value) or "(none)"
    return f"{flag} {value}"


def _refuse_changed_options(ctx, run_dir: Path) -> None:
    """Exit 2 naming the saved value when an option given with --resume differs from the run's."""
    import json

    from tron1cli.train.checkpoint import load_checkpoint
    from tron1cli.train.layout import latest_checkpoint
    from tron1cli.train.runner import RunConfig

    state = load_checkpoint(latest_checkpoint(run_dir))
    try:
        run_cfg = RunConfig.from_dict(json.loads(state["config"]))
        saved = _saved_values(run_cfg)
    except (KeyError, TypeError, ValueError) as e:
        fail(f"{run_dir}: the checkpoint's run configuration is unreadable ({e})", 1)
    for name, was in saved.items():
        if not _given(ctx, name):
            continue
        if name == "learner":
            try:
                now = _learner_settings(ctx.params[name])
            except ValueError as e:
                fail(f"--learner: {e}", 2)
        else:
            now = _as_saved(name, ctx.params[name])
        if name == "teacher_ratio" and not isinstance(now, str):
            same = abs(float(now) - float(was)) < 1e-12
        elif name in ("reward_weights", "reward_ramps", "reward_settings", "learner") and isinstance(
            now, dict
        ):
            same = all(was.get(k) == v for k, v in now.items())  # only the keys given
            was = {k: was.get(k, None if name == "reward_ramps" else float("nan")) for k in now}
        else:
            same = now == was
        if not same:
            fail(
                f"{_shown(name, ctx.params[name]) if isinstance(now, str) else _shown(name, now)}: "
                f"the run in {run_dir} was started with {_shown(name, was)} and --resume continues "
                "it as saved; leave the option out, or start a new run in another --run-dir",
                2,
            )


def _value(v) -> str:
    if isinstance(v, tuple):  # a reward ramp
        return f"{v[0]}:{v[1]}"
    return f"{v:g}" if isinstance(v, float) else "none" if v is None else str(v)


def _settings(text: str) -> dict[str, str]:
    """``A=1,B=off`` -> {A: "1", B: "off"} (empty text: {}); ValueError on a pair without one ``=``."""
    pairs = [kv.split("=") for kv in text.split(",") if kv.strip()]
    if any(len(kv) != 2 for kv in pairs):
        raise ValueError(f"wants KEY=VALUE pairs separated by commas, got '{text}'")
    return {k.strip(): v.strip() for k, v in pairs}


def _ramps(text: str) -> dict[str, tuple[int, int] | None]:
    """``A=200:250,B=none`` -> {A: (200, 250), B: None}; ValueError, one line, on anything else."""
    out: dict[str, tuple[int, int] | None] = {}
    for term, value in _settings(text).items():
        if value.lower() == "none":
            out[term] = None
            continue
        start, sep, end = value.partition(":")
        if not (sep and start.isdigit() and end.isdigit()) or int(start) > int(end):
            raise ValueError(f"{term}={value}: a ramp is START:END iterations with START <= END, or none")
        out[term] = (int(start), int(end))
    if not out:
        raise ValueError(f"wants TERM=START:END pairs separated by commas, got '{text}'")
    return out


def _pairs(text: str) -> dict[str, float]:
    """``A=1,B=0.5`` -> {A: 1.0, B: 0.5}; ValueError on anything else."""
    return {k: float(v) for k, v in _settings(text).items()}


def _learner_settings(text: str) -> dict:
    """``--learner``'s text -> {field: value parsed as its default's type}; ValueError, one line,
    for anything :func:`tron1cli.learn.config.with_overrides` refuses or a text without pairs."""
    from tron1cli.learn.config import LearnerConfig, with_overrides

    pairs = _settings(text)
    if not pairs or "" in pairs:
        raise ValueError(f"wants KEY=VALUE pairs separated by commas, got '{text}'")
    parsed = with_overrides(LearnerConfig(), pairs)
    return {k: getattr(parsed, k) for k in pairs}


def _parse_weights(text: str, option: str, key: str) -> dict[str, float]:
    """:func:`_pairs` of an option's value, finite; exits 2 naming ``option`` on anything else."""
    try:
        weights = _pairs(text)
    except ValueError:
        fail(f"{option} wants {key}=NUMBER pairs separated by commas, got '{text}'", 2)
    bad = [k for k, w in weights.items() if not math.isfinite(w)]
    if not weights:
        fail(f"{option} is empty", 2)
    if bad:
        fail(f"{option}: {bad[0]}={weights[bad[0]]} is not a finite number", 2)
    return weights


def _parse_levels(text: str) -> dict[str, int]:
    """``--level-floor``'s ``TYPE=LEVEL,...`` -> {type: level}; ValueError, one line, otherwise
    (the types and the range of the levels are checked against the terrain by EnvConfig)."""
    try:
        pairs = _pairs(text)
    except ValueError:
        pairs = {}
    if not pairs:
        raise ValueError(f"--level-floor wants TYPE=LEVEL pairs separated by commas, got '{text}'")
    bad = [k for k, v in pairs.items() if not math.isfinite(v) or v != int(v)]
    if bad:
        raise ValueError(f"--level-floor: {bad[0]}={pairs[bad[0]]:g} is not a whole level")
    return {k: int(v) for k, v in pairs.items()}


def _parse_fold(text: str) -> tuple[float, float]:
    """``--swing-fold``'s ``HIP,KNEE`` -> (hip, knee) rad; ValueError, one line, otherwise."""
    try:
        fold = tuple(float(x) for x in text.split(","))
    except ValueError:
        fold = ()
    if len(fold) != 2 or not all(math.isfinite(x) for x in fold):
        raise ValueError(f"--swing-fold wants two angles HIP,KNEE in rad, e.g. 0.5,0.8, got '{text}'")
    return fold


def _parse_freq(text: str) -> tuple[float, float]:
    """``--gait-freq-range``'s ``LO,HI`` -> (lo, hi) Hz; ValueError, one line, otherwise."""
    try:
        lo, hi = (float(x) for x in text.split(","))
    except ValueError:
        lo = hi = float("nan")
    if not (0.0 < lo <= hi < math.inf):
        raise ValueError(
            f"--gait-freq-range wants two frequencies 0 < LO <= HI in Hz, e.g. 2,2.5, got '{text}'"
        )
    return lo, hi


def _terrain_summary(e) -> str:
    """The header's note on a run's terrain, command and gait options where they are not the defaults."""
    notes = []
    if e.terrain_mix:
        notes.append("mix " + ", ".join(f"{k}={v:g}" for k, v in e.terrain_mix.items()))
    if e.max_init_level:
        notes.append(f"starting on levels 0-{e.max_init_level}")
    if e.curriculum_rule != "distance":
        notes.append(f"curriculum rule {e.curriculum_rule}")
    if e.level_floor:
        notes.append("level floor " + ", ".join(f"{k}={v}" for k, v in e.level_floor.items()))
    if e.commands.face_climb:
        notes.append("commands facing the climb")
    if e.commands.heading:
        spread = math.degrees(e.commands.heading_spread_rad)
        notes.append("heading commands" + (f" within {spread:g} deg" if spread < 180.0 else ""))
    if any(e.gait.swing_fold_rad):
        notes.append("swing fold hip {:g}, knee {:g} rad".format(*e.gait.swing_fold_rad))
    if e.gait.swing_fold_keep:
        notes.append(f"{e.gait.swing_fold_keep:g} of the fold kept")
    if tuple(e.gait.freq_hz) != GaitConfig.freq_hz:
        notes.append("gait clock {:g}-{:g} Hz".format(*e.gait.freq_hz))
    if e.termination.bodies != TERMINATION_BODIES:
        notes.append("falls on " + ", ".join(e.termination.bodies) + " contact")
    return f" ({'; '.join(notes)})" if notes else ""


#: seconds between the plain progress lines written when stderr is not a terminal (a log file)
LOG_EVERY_S = 60.0


def _run(trainer, run_dir: Path, target, minutes, rerun_every, resumed: bool) -> None:
    """Train, print the header, the progress bar (a plain line a minute when stderr is not a
    terminal: a run under nohup or in CI) and the closing table."""
    from tron1cli.viz.rerun_stream import open_stream

    c = trainer.cfg
    if trainer.iteration >= c.iterations:
        trainer.close()
        out.print(
            f"{run_dir} is complete at iteration {trainer.iteration}: pass --iterations N to train further"
        )
        return
    err.print(
        f"[bold]tron1 train[/] {c.env.terrain}{_terrain_summary(c.env)}, {c.env.num_envs} envs "
        f"({trainer.n_teacher} teacher) x "
        f"{c.learner.num_steps_per_env} steps x {c.iterations:,} iterations, {_preset_summary(c)}, "
        f"ablation {c.ablation}, gait prior {'on' if c.gait_prior else 'off'}, "
        f"critic weights {_weights_summary(c.learner.critic_weights)}, "
        f"reward weights {_reward_summary(c)}, learner {_learner_summary(c)}, "
        f"perception {'on' if c.env.perception else 'off'}, randomisation "
        f"{_dr_summary(c.env.randomization.terms)}, pushes {'on' if c.env.pushes.enabled else 'off'}, "
        f"seed {c.env.seed}, {c.env.nthread} threads, "
        + (f"physics on warp ({trainer.env.physics.device}), " if trainer.backend == "warp" else "")
        + f"learner on {trainer.learner.device.type} in "
        f"{c.learner.precision} "
        f"-> {run_dir}"
        + (f" (resumed at iteration {trainer.iteration})" if resumed else "")
        + (f"; started from {c.init_from}" if c.init_from else "")
        + (f": {trainer.warm_start.summary()}" if trainer.warm_start else "")
    )
    progress = Progress(
        TextColumn("[bold]iter"),
        MofNCompleteColumn(),
        BarColumn(bar_width=8),
        TextColumn("{task.fields[figures]}"),
        TimeElapsedColumn(),
        TextColumn("eta"),
        TimeRemainingColumn(),
        console=err,
        disable=not err.is_terminal,  # a log file gets the plain lines of show() instead
    )
    task = progress.add_task("train", total=c.iterations, completed=trainer.iteration, figures="")

    logged = {"at": -math.inf}  # when the last plain line was written (time.monotonic)
    who = "student" if trainer.learner.n_student > 0 else "teacher"

    def show(m: dict) -> None:
        reward = sum(v for k, v in m.items() if k.startswith("step_reward/"))
        g = who  # the student's figures, the teacher's in a teacher stage; compact for 80 columns
        figs = (
            f"{m['steps_per_s']:,.0f}/s rew {_fmt(reward)} ep {_fmt(m.get(f'{g}/episode_length_s'))}s"
            f" surv {_fmt(m.get(f'{g}/survival'))} err {_fmt(m.get(f'{g}/vel_tracking_error'))}"
        )
        if "terrain/mean_level" in m:
            figs += f" lvl {_fmt(m['terrain/mean_level'])}"
        progress.update(task, completed=m["iteration"], figures=figs)
        now = time.monotonic()
        if not err.is_terminal and (now - logged["at"] >= LOG_EVERY_S or m["iteration"] >= c.iterations):
            logged["at"] = now
            err.print(
                f"iter {int(m['iteration'])}/{c.iterations} {figs} (collect {m['collect_s']:.1f} s, "
                f"learn {m['learn_s']:.1f} s, {m['wall_s'] / 60:.1f} min, {m['env_steps']:,} env steps)",
                soft_wrap=True,
            )

    def _terminate(signum, frame):  # `kill` (SIGTERM) saves like Ctrl-C does
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, _terminate)
    stream = open_stream(target, recording_name=f"tron1 train {run_dir}")
    try:
        with progress:
            last = trainer.run(show, max_minutes=minutes, stream=stream, stream_every=rerun_every)
    except KeyboardInterrupt:
        path = trainer.save()
        fail(f"interrupted at iteration {trainer.iteration}: checkpoint saved to {path}", 130)
    finally:
        trainer.close()
        if stream is not None:
            stream.close()
    t = Table(
        title=f"tron1 train: {trainer.iteration} iterations, {trainer.env_steps:,} env steps, "
        f"{trainer.wall_s / 60:.1f} min"
    )
    t.add_column("figure")
    t.add_column("teacher", justify="right")
    t.add_column("student", justify="right")
    for key, label in (
        ("survival", "survival (share of the last 1000 episodes)"),
        ("falls_per_min", "falls per robot-minute, last iteration"),
        ("episode_length_s", "episode length (s)"),
        ("vel_tracking_error", "velocity tracking error (m/s)"),
    ):
        t.add_row(label, _fmt(last.get(f"teacher/{key}")), _fmt(last.get(f"student/{key}")))
    out.print(t)
    out.print(f"checkpoint: {run_dir / 'checkpoints' / 'latest.pt'}")


def _given(ctx: typer.Context, name: str) -> bool:
    """Whether option ``name`` was given on the command line (not left at its default)."""
    source = ctx.get_parameter_source(name)
    return source is not None and source.name == "COMMANDLINE"


def _preset_summary(c) -> str:
    """'preset paper' or 'preset paper (overridden: envs, iterations)'."""
    over = f" (overridden: {', '.join(c.preset_overrides)})" if c.preset_overrides else ""
    return f"preset {c.preset}{over}"


def _reward_summary(c) -> str:
    """'default' or the terms whose weights differ from this version's defaults, e.g. 'alive=0.5'."""
    from tron1cli.env.rewards import make_reward_config

    default = make_reward_config(c.ablation, gait_prior=c.gait_prior).terms
    changed = [(k, t) for k, t in c.reward.terms.items() if k not in default or default[k] != t]
    return ", ".join(f"{k}={t.weight:g}" + _ramp_text(t) for k, t in changed) or "default"


def _ramp_text(t) -> str:
    """' (from iteration 200 to 250)' for a ramped reward term, '' otherwise."""
    return f" (from iteration {t.ramp[0]} to {t.ramp[1]})" if t.ramp else ""


def _learner_summary(c) -> str:
    """'default' or the ``--learner`` settings that differ from this version's defaults."""
    from tron1cli.learn.config import tunable_fields

    changed = {k: getattr(c.learner, k) for k, v in tunable_fields().items() if getattr(c.learner, k) != v}
    return ", ".join(f"{k}={_value(v)}" for k, v in changed.items()) or "default"


def _weights_summary(weights: dict[str, float]) -> str:
    """'equal' or e.g. 'stable=0.5' (groups not named weigh 1)."""
    named = {k: v for k, v in weights.items() if v != 1.0}
    return ", ".join(f"{k}={v:g}" for k, v in named.items()) if named else "equal"


def _csv(text: str) -> tuple[str, ...]:
    return tuple(x.strip() for x in text.split(",") if x.strip())


def _dr_summary(terms: tuple[str, ...]) -> str:
    """'on', 'off' or 'on except a, b' for the Table III terms in use."""
    from tron1cli.env.randomization import ALL_TERMS

    if not terms:
        return "off"
    left_out = [t for t in ALL_TERMS if t not in terms]
    return "on" + (f" except {', '.join(left_out)}" if left_out else "")
