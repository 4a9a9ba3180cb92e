"""``tron1 deploy-sim``: an exported policy in MuJoCo, run the way the robot runs it."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from tron1cli.cli.common import (
    GAIT_FREQ_HELP,
    SEED_MAX,
    VIDEO_HELP,
    VIDEO_SIZE_HELP,
    check_inputs,
    check_outputs,
    err,
    fail,
    finite,
    open_video,
    out,
    print_json,
    render_video,
    rerun_file,
    terrain_help,
)
from tron1cli.deploy.runs import runs_summary, summary_rows, summary_title
from tron1cli.viz.cells import figure
from tron1cli.viz.rerun_stream import open_stream, parse_rerun_option


def deploy_sim(
    policy: Path = typer.Argument(
        ..., help="Exported policy (.onnx), or a training checkpoint (.pt).", show_default=False
    ),
    terrain: str = typer.Option("flat", "--terrain", "-t", help=terrain_help()),
    level: int = typer.Option(0, "--level", help="Terrain difficulty level (0 easiest; -1 the hardest)."),
    cmd: str | None = typer.Option(
        None, "--cmd", help="Constant command vx,vy,yaw (m/s, m/s, rad/s) [default: 0.5,0,0]."
    ),
    cmd_file: Path | None = typer.Option(
        None,
        "--cmd-file",
        exists=True,
        dir_okay=False,
        help="Timed commands: CSV lines t_s,vx,vy,yaw, each holding until the next.",
    ),
    push: str = typer.Option("none", "--push", help="Random pushes on the base: none, moderate or extreme."),
    duration: float = typer.Option(10.0, "--duration", callback=finite, min=0.02, help="Simulated seconds."),
    realtime: bool = typer.Option(
        False, "--realtime", help="Pace the loop to the wall clock [default: as fast as possible]."
    ),
    seed: int = typer.Option(
        0, "--seed", min=0, max=SEED_MAX, help="Seed of the env, the terrain and the sensor noise."
    ),
    runs: int = typer.Option(
        1,
        "--runs",
        min=1,
        max=10_000,
        help="Runs with seeds SEED, SEED+1, ...: the table gives their survival with a 95 % interval "
        "(one run is an anecdote: a policy that falls in 1 run of 20 falls on some seed).",
    ),
    noise: bool = typer.Option(True, "--noise/--no-noise", help="Proprioceptive and depth sensor noise."),
    depth_latency_ms: float = typer.Option(
        0.0, "--depth-latency-ms", callback=finite, min=0.0, help="Latency added to every depth frame (ms)."
    ),
    physics_hz: float | None = typer.Option(
        500.0,
        "--physics-hz",
        callback=finite,
        min=1.0,
        help="Physics and PD rate, a multiple of the policy's 50 Hz: 500 (the robot's loop) or 1000.",
    ),
    randomize: bool = typer.Option(
        False, "--randomize", help="The policy's training randomisation instead of the nominal robot."
    ),
    viewer: bool = typer.Option(
        False, "--viewer", help="Show the MuJoCo viewer (needs a display; paces to the wall clock)."
    ),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object on stdout instead of a table."),
    rerun: str = typer.Option(
        "off", "--rerun", help="Stream the run to rerun: spawn, save=FILE.rrd, connect[=URL] or off."
    ),
    video: Path | None = typer.Option(
        None, "--video", metavar="FILE.mp4", help=VIDEO_HELP + "the robot, a camera following it."
    ),
    video_size: str | None = typer.Option(
        None, "--video-size", metavar="WxH", help=VIDEO_SIZE_HELP + " [default: 640x480]."
    ),
    gait_freq: float | None = typer.Option(None, "--gait-freq", callback=finite, help=GAIT_FREQ_HELP),
) -> None:
    """Run POLICY in MuJoCo: physics with PD at the physics rate, the policy at 50 Hz, the depth camera
    rendered in its own thread at 30 Hz with the newest ready frame handed to the policy.

    Reports survival, velocity tracking, LIPM CoM/ZMP figures, policy inference time, depth frame
    age and render time, and the real-time factor (simulated seconds per wall second).
    """
    check_inputs([policy])
    from tron1cli.deploy.pipeline import PUSHES, DeployConfig, check_display
    from tron1cli.deploy.schedule import CommandSchedule, parse_cmd
    from tron1cli.env.terrain import resolve_terrain
    from tron1cli.policy.runtime import load_policy

    try:
        resolve_terrain(terrain)
        if push not in PUSHES:
            raise ValueError(f"unknown --push '{push}'; choose from {', '.join(PUSHES)}")
        if cmd is not None and cmd_file is not None:
            raise ValueError("give --cmd or --cmd-file, not both")
        if cmd_file is not None:
            schedule = CommandSchedule.from_file(cmd_file)
        else:
            schedule = CommandSchedule.constant(parse_cmd(cmd if cmd is not None else "0.5,0,0"))
        target = parse_rerun_option(rerun)
        if runs > 1:
            one_run = [o for o, on in (("--video", video), ("--rerun", target), ("--viewer", viewer)) if on]
            if one_run:
                raise ValueError(f"{' and '.join(one_run)} show one run: give --runs 1 with them")
            if seed + runs - 1 > SEED_MAX:
                raise ValueError(f"--seed {seed} with --runs {runs} runs past the largest seed {SEED_MAX}")
    except ValueError as e:
        fail(str(e), 2)
    check_outputs(files=[rerun_file(target)], inputs=[x for x in (policy, cmd_file) if x is not None])
    if viewer:
        check_display()
    from tron1cli.viz.video import DEFAULT_SIZE

    recorder = open_video(video, video_size, DEFAULT_SIZE, inputs=[policy])
    cfg = DeployConfig(
        terrain=terrain,
        level=level,
        schedule=schedule,
        push=push,
        duration_s=duration,
        realtime=realtime,
        seed=seed,
        noise=noise,
        depth_latency_ms=depth_latency_ms,
        physics_hz=physics_hz,
        randomize=randomize,
        viewer=viewer,
        gait_freq_hz=gait_freq,
    )
    pol = load_policy(policy)
    stream = open_stream(target, recording_name=f"tron1 deploy-sim {policy.name}")
    steps = int(round(duration * 50))
    progress = Progress(
        TextColumn("[bold]deploy-sim"),
        MofNCompleteColumn(),
        BarColumn(bar_width=24),
        TextColumn("policy steps  {task.fields[tally]}"),
        TimeElapsedColumn(),
        console=err,
        transient=True,
        disable=as_json or not err.is_terminal,
    )
    done = [0]
    reps: list[dict] = []
    interrupted = False
    try:
        with progress:
            task = progress.add_task("run", total=steps * runs, tally="setting up the env and depth thread")

            def on_step(k: int, total: int) -> None:
                done[0] += 1
                if k == 1 and runs == 1:
                    progress.update(task, tally="")
                if k % 25 == 0 or k == total:
                    progress.update(task, completed=len(reps) * steps + k)

            for i in range(runs):
                reps.append(_run(pol, replace(cfg, seed=seed + i), stream, recorder, cmd, on_step))
                fell = sum(not r["survived"] for r in reps)
                tally = f"{len(reps)} of {runs} runs, {fell} fell" if runs > 1 else ""
                progress.update(task, completed=len(reps) * steps, tally=tally)
    except KeyboardInterrupt:
        if runs == 1 or not reps:
            kept = "no results written" + (", no video" if recorder is not None else "")
            if target is not None and target.kind == "save":
                kept += f"; the rerun recording {target.arg} holds what was streamed"
            fail(f"deploy-sim interrupted after {done[0]:,} policy steps: {kept}", 130)
        interrupted = True  # the finished runs are reported below
    finally:
        if stream is not None:
            stream.close()
    for rep in reps:
        if rep["unstable"]:
            err.print(
                "[bold yellow]warning:[/] the simulation went unstable (NaN, runaway velocity or a "
                f"MuJoCo auto-reset) at t = {rep['duration_s']:.2f} s"
                + (f" of seed {rep['seed']}'s run" if runs > 1 else "")
                + "; the run stopped there",
                highlight=False,
            )
    result = reps[0] if runs == 1 else {"summary": runs_summary(reps), "runs": reps}
    if as_json:
        print_json(result)
    else:
        out.print(_table(result) if runs == 1 else _runs_table(result["summary"]))
    if interrupted:
        n = len(reps)
        fail(f"deploy-sim interrupted in run {n + 1} of {runs}: the figures are the {n} finished", 130)
    render_video(recorder)


def _run(pol, cfg, stream, recorder, cmd: str | None, on_step) -> dict:
    """One deploy-sim run of ``pol`` under ``cfg``: its report (see DeploySim._report)."""
    from tron1cli.deploy.pipeline import DeploySim

    take = None
    if recorder is not None:
        take = recorder.take(
            [0], caption=f"{pol.path.name} on {cfg.terrain} level {cfg.level}, cmd {cmd or '0.5,0,0'}"
        )
    sim = DeploySim(pol, cfg, stream, take)
    try:
        return sim.run(on_step)
    finally:
        sim.close()


def _table(rep: dict) -> Table:
    ended = {
        "duration": "ran the full duration",
        "fell": f"fell: {rep['fell_by']}",
        "edge": "reached the edge of the terrain tile",
        "unstable": "simulation went UNSTABLE",
        "viewer closed": "viewer closed",
    }[rep["ended"]]
    t = Table(
        title=f"tron1 deploy-sim: {Path(rep['policy']).name} ({rep['policy_kind']}), "
        f"{rep['terrain_type']} level {rep['level']}, seed {rep['seed']}",
        caption=f"physics {rep['physics_hz']:g} Hz, policy {rep['policy_hz']:g} Hz, depth "
        + (f"{rep['depth_hz']:g} Hz in its own thread" if rep["depth_hz"] else "none (blind policy)")
        + (", paced to the wall clock" if rep["paced"] else ", as fast as possible"),
    )
    t.add_column("figure")
    t.add_column("value", justify="right")
    rows = [
        ("survived", f"{'yes' if rep['survived'] else 'NO'} ({ended})"),
        ("simulated time (s)", f"{rep['duration_s']:.2f} of {rep['requested_duration_s']:g}"),
        ("velocity tracking error |v_cmd,xy - v_xy| (m/s)", figure(rep["vel_tracking_error"])),
        ("LIPM CoM error |p_hat - p_com| (m)", figure(rep["com_error_m"])),
        ("CoM to ZMP |p_com - p_zmp| (m)", figure(rep["com_zmp_m"])),
        ("CoM height error |z - z_c| (m)", figure(rep["com_height_error_m"])),
        ("pushes", str(rep["pushes"])),
        (
            "policy inference p50 / p99 (ms)",
            f"{figure(rep['policy_ms_p50'])} / {figure(rep['policy_ms_p99'])}",
        ),
        ("real-time factor (sim s / wall s)", figure(rep["realtime_factor"], ".2f")),
    ]
    if rep["reconstruction_error_cm"] is not None:
        rows.insert(6, ("heightmap reconstruction error (cm)", figure(rep["reconstruction_error_cm"], ".2f")))
    if rep["depth_frames"] is not None:
        rows += [
            (
                "depth frames (rate, dropped)",
                f"{rep['depth_frames']} ({figure(rep['depth_rate_hz'], '.1f')} Hz, "
                f"{rep['depth_dropped']} dropped)",
            ),
            (
                "depth frame age p50 / p99 (ms of sim time)",
                f"{figure(rep['depth_age_ms_p50'], '.1f')} / {figure(rep['depth_age_ms_p99'], '.1f')}"
                + (f" (+{rep['depth_latency_ms']:g} ms added)" if rep["depth_latency_ms"] else ""),
            ),
            (
                "depth render p50 / p99 (ms)",
                f"{figure(rep['depth_render_ms_p50'], '.2f')} / {figure(rep['depth_render_ms_p99'], '.2f')}",
            ),
            ("depth render hidden behind the control loop", figure(rep["depth_hidden_share"], ".0%")),
        ]
    for name, value in rows:
        t.add_row(name, value)
    return t


def _runs_table(sm: dict) -> Table:
    """The survival and the pipeline's figures over ``--runs`` runs (see runs_summary)."""
    t = Table(title=f"tron1 deploy-sim: {summary_title(sm)}")
    t.add_column("figure")
    t.add_column("value", justify="right")
    for name, value in summary_rows(sm):
        t.add_row(name, value)
    return t
