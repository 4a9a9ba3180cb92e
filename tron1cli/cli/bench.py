"""``tron1 bench``: env-core throughput against the raw physics rate, measured in the same run."""

from __future__ import annotations

from dataclasses import replace

import typer
from rich.table import Table

from tron1cli.cli.common import (
    SEED_MAX,
    available_cores,
    backend_note,
    backend_option,
    check_backend,
    err,
    fail,
    out,
    preset_default,
    print_json,
    resolve_device,
    resolve_precision,
    terrain_help,
    threads_option,
    warn,
)

_RAW_ENVS = 1024
"""Envs of the env-rate benchmark (without --train)."""


def bench(
    envs: int | None = typer.Option(
        None,
        "--envs",
        "-n",
        min=1,
        help=f"Number of parallel environments [default: {_RAW_ENVS}; with --train, tron1 train's: "
        f"{preset_default('num_envs')}].",
        show_default=False,
    ),
    steps: int = typer.Option(100, "--steps", min=1, help="Timed policy steps (after 10 warm-up steps)."),
    threads: int = threads_option("Physics (and with --train torch) threads"),
    seed: int = typer.Option(0, "--seed", min=0, max=SEED_MAX, help="Random seed."),
    terrain: str = typer.Option("flat", "--terrain", "-t", help=terrain_help()),
    depth: bool = typer.Option(
        False,
        "--depth/--no-depth",
        help="Also time the perceptive env: height scans for every env, 30 Hz depth for the student half.",
    ),
    level: int = typer.Option(5, "--level", min=0, help="Terrain difficulty level the envs start on."),
    rounds: int = typer.Option(
        3, "--rounds", min=1, help="Alternating timing rounds; each rate is the median of its rounds."
    ),
    train: bool = typer.Option(
        False,
        "--train",
        help="Time whole training iterations (tron1 train's defaults for --terrain) against the raw "
        "rate of the same physics: collection and learning as ratios of it.",
    ),
    presets: str = typer.Option(
        "",
        "--preset",
        metavar="NAME[,NAME...]",
        help="With --train: the presets to time, one after another in this run, e.g. perceptive,teacher "
        "(Vision-CTS against the teacher stage) [default: tron1 train's for --terrain].",
        show_default=False,
    ),
    device: str = typer.Option("cpu", "--device", help="With --train: the learner's device, cpu or cuda."),
    precision: str = typer.Option(
        "fp32", "--precision", help="With --train: the update's arithmetic, fp32 or bf16."
    ),
    backend: str = backend_option(),
    json_out: bool = typer.Option(False, "--json", help="Print one JSON object instead of a table."),
) -> None:
    """Measure the env step rate and the raw physics rate of the same workload."""
    from tron1cli.benchmark import run_bench
    from tron1cli.env.terrain import resolve_terrain

    try:
        resolve_terrain(terrain)
        from tron1cli.config import EnvConfig
        from tron1cli.evaluation.protocol import check_level

        check_level(level, EnvConfig().terrain_cfg.num_levels)
    except ValueError as e:
        fail(str(e), 2)
    check_backend(backend)
    threads = threads or available_cores()
    if train:
        device = resolve_device(device)
        precision = resolve_precision(precision, device)
        _bench_train(envs, threads, seed, terrain, presets, rounds, device, precision, backend, json_out)
        return
    if presets:
        fail("--preset times training presets: it needs --train", 2)
    envs = envs or _RAW_ENVS
    what = f"stepping {envs} envs for {steps} policy steps, {rounds} rounds"
    with err.status(f"{what}{backend_note(backend)}..."):
        res = run_bench(
            envs,
            steps,
            seed=seed,
            nthread=threads,
            terrain=terrain,
            depth=depth,
            level=level,
            rounds=rounds,
            backend=backend,
        )
    _warn_unstable(res)
    if json_out:
        print_json(res)
        return
    t = Table(
        title=f"tron1 bench: {envs} envs, {terrain}, {threads} threads, {backend} physics, "
        f"median of {rounds} rounds"
    )
    t.add_column("what")
    t.add_column("policy steps/s", justify="right")
    t.add_row(f"raw {_RAW[backend]} (same states and controls)", f"{res['raw_steps_per_s']:,.0f}")
    t.add_row(
        "env core step (physics, obs, commands, terminations, resets)", f"{res['env_steps_per_s']:,.0f}"
    )
    lo, hi = res["ratio_spread"]
    t.add_row("ratio env / raw", f"{res['ratio']:.2f} (rounds {lo:.2f}-{hi:.2f})")
    if depth:
        t.add_row("env core step with height scans and 30 Hz depth", f"{res['env_depth_steps_per_s']:,.0f}")
        lo, hi = res["depth_ratio_spread"]
        t.add_row("ratio env with depth / raw", f"{res['depth_ratio']:.2f} (rounds {lo:.2f}-{hi:.2f})")
        t.add_row("height scans (441 points), every env", f"{res['heightmaps_per_s']:,.0f} /s")
        t.add_row(
            "depth images (80 x 60), every env",
            f"{res['depth_images_per_s']:,.0f} /s ({res['depth_ms_per_image']:.3f} ms each)",
        )
    out.print(t)


def _warn_unstable(res: dict) -> None:
    """One warning line when the bench reset diverged worlds (the rates then time resets too)."""
    if res["unstable_resets"]:
        warn(
            f"{res['unstable_resets']:,} worlds diverged and were reset during the bench: "
            "the env rates include those resets"
        )


#: what the raw rate times, per backend
_RAW = {"mujoco": "mujoco.rollout", "warp": "mujoco_warp.step"}


def _bench_train(
    envs: int | None,
    threads: int,
    seed: int,
    terrain: str,
    presets: str,
    rounds: int,
    device: str,
    precision: str,
    backend: str,
    as_json: bool,
):
    from tron1cli.benchmark import run_train_bench
    from tron1cli.config.presets import for_terrain, make_preset
    from tron1cli.learn import tune_glibc_malloc
    from tron1cli.train.runner import run_config

    tune_glibc_malloc()
    names = [p.strip() for p in presets.split(",") if p.strip()]
    try:  # the trainer sets torch's threads from the run's nthread
        chosen = [replace(make_preset(n), terrain=terrain) for n in names] or [for_terrain(terrain)]
        cfgs = [
            run_config(
                replace(p, num_envs=envs or p.num_envs), seed=seed, nthread=threads, precision=precision
            )
            for p in chosen
        ]
    except ValueError as e:
        fail(str(e), 2)
    results = []
    for p, cfg in zip(chosen, cfgs, strict=True):
        what = f"training {rounds} + 1 iterations of preset {p.name}, {cfg.env.num_envs} envs on {terrain}"
        with err.status(f"{what}{backend_note(backend)}..."):
            res = run_train_bench(cfg, rounds=rounds, device=device, backend=backend)
        res["preset"] = p.name
        _warn_unstable(res)
        results.append(res)
    if as_json:
        print_json(results[0] if len(results) == 1 else {"runs": results})
        return
    for res in results:
        print_train_table(res)
    base = results[0]
    for res in results[1:]:
        ratio = res["train_steps_per_s"] / base["train_steps_per_s"]
        out.print(
            f"{res['preset']} / {base['preset']}: {ratio:.2f}x "
            f"the env steps per second of a whole iteration ({res['train_steps_per_s']:,.0f} against "
            f"{base['train_steps_per_s']:,.0f})"
        )


def print_train_table(res: dict) -> None:
    """The table of a :func:`tron1cli.benchmark.run_train_bench` result."""
    t = Table(
        title=f"tron1 bench --train{' --preset ' + res['preset'] if 'preset' in res else ''}: "
        f"{res['num_envs']} envs x {res['steps_per_env']} steps, "
        f"{res['epochs']} epochs, "
        f"{res['terrain']}{' (perception)' if res['perception'] else ''}, {res['nthread']} threads, "
        f"{res['backend']} physics, "
        f"learner on {res['device']} in {res['precision']}, median of {res['rounds']} rounds"
    )
    for col, just in (
        ("what", "left"),
        ("env steps/s", "right"),
        ("s per iteration", "right"),
        ("ratio to raw", "right"),
    ):
        t.add_column(col, justify=just)
    t.add_row(
        f"raw {_RAW[res['backend']]} (same states and controls)", f"{res['raw_steps_per_s']:,.0f}", "", "1.00"
    )
    for key, label, secs in (
        ("train", "whole iteration (collection + learning)", res["collect_s"] + res["learn_s"]),
        ("collect", "collection (env steps, policy inference)", res["collect_s"]),
        ("learn", "learning (PPO epochs, estimators, image path)", res["learn_s"]),
    ):
        lo, hi = res[f"{key}_ratio_spread"]
        t.add_row(
            label,
            f"{res[f'{key}_steps_per_s']:,.0f}",
            f"{secs:.2f}",
            f"{res[f'{key}_ratio']:.2f} ({lo:.2f}-{hi:.2f})",
        )
    out.print(t)
    out.print(f"learning / collection time: {res['learn_over_collect']:.2f}")
