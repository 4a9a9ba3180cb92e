"""``tron1 bench``: env-core throughput against the raw MuJoCo rate, measured in the same run."""

from __future__ import annotations

import typer
from rich.table import Table

from tron1cli.cli.common import err, fail, out, print_json, terrain_help


def bench(
    envs: int = typer.Option(1024, "--envs", "-n", min=1, help="Number of parallel environments."),
    steps: int = typer.Option(100, "--steps", min=1, help="Timed policy steps (after 10 warm-up steps)."),
    threads: int = typer.Option(2, "--threads", min=1, help="Physics threads."),
    seed: int = typer.Option(0, "--seed", help="Random seed."),
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
    json_out: bool = typer.Option(False, "--json", help="Print one JSON object instead of a table."),
) -> None:
    """Measure the env step rate and the raw mujoco.rollout rate of the same workload."""
    from tron1cli.benchmark import run_bench
    from tron1cli.env.terrain import resolve_terrain

    try:
        resolve_terrain(terrain)
    except ValueError as e:
        fail(str(e), 2)
    with err.status(f"stepping {envs} envs for {steps} policy steps, {rounds} rounds..."):
        res = run_bench(
            envs, steps, seed=seed, nthread=threads, terrain=terrain, depth=depth, level=level, rounds=rounds
        )
    if json_out:
        print_json(res)
        return
    t = Table(title=f"tron1 bench: {envs} envs, {terrain}, {threads} threads, median of {rounds} rounds")
    t.add_column("what")
    t.add_column("policy steps/s", justify="right")
    t.add_row("raw mujoco.rollout (same states and controls)", f"{res['raw_steps_per_s']:,.0f}")
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
