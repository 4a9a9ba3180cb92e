"""``tron1 bench``: env-core throughput against the raw MuJoCo rate, measured in the same run."""

from __future__ import annotations

import typer
from rich.table import Table

from tron1cli.cli.common import err, out, print_json


def bench(
    envs: int = typer.Option(1024, "--envs", "-n", min=1, help="Number of parallel environments."),
    steps: int = typer.Option(100, "--steps", min=1, help="Timed policy steps (after 10 warm-up steps)."),
    threads: int = typer.Option(2, "--threads", min=1, help="Physics threads."),
    seed: int = typer.Option(0, "--seed", help="Random seed."),
    json_out: bool = typer.Option(False, "--json", help="Print one JSON object instead of a table."),
) -> None:
    """Measure the env step rate and the raw mujoco.rollout rate of the same workload."""
    from tron1cli.benchmark import run_bench

    with err.status(f"stepping {envs} envs for {steps} policy steps..."):
        res = run_bench(num_envs=envs, steps=steps, seed=seed, nthread=threads)
    if json_out:
        print_json(res)
        return
    t = Table(title=f"tron1 bench: {envs} envs, flat, decimation {res['decimation']}, {threads} threads")
    t.add_column("what")
    t.add_column("policy steps/s", justify="right")
    t.add_row("raw mujoco.rollout (same states and controls)", f"{res['raw_steps_per_s']:,.0f}")
    t.add_row(
        "env core step (physics, obs, commands, terminations, resets)", f"{res['env_steps_per_s']:,.0f}"
    )
    t.add_row("ratio env / raw", f"{res['ratio']:.2f}")
    out.print(t)
