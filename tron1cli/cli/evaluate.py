"""``tron1 eval`` and ``tron1 push-test``: the paper's evaluation protocols on the command line."""

from __future__ import annotations

import csv
import json
import math
from contextlib import contextmanager
from dataclasses import asdict, replace
from pathlib import Path

import typer
from rich import box
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from tron1cli.cli.common import (
    SEED_MAX,
    VIDEO_HELP,
    VIDEO_SIZE_HELP,
    backend_option,
    check_backend,
    check_inputs,
    check_outputs,
    err,
    fail,
    finite,
    open_video,
    out,
    path_option,
    print_json,
    render_video,
    rerun_file,
    terrain_help,
)
from tron1cli.errors import Tron1Error
from tron1cli.evaluation.metric_names import EVAL_LAYOUTS, METRICS, PERCENT_METRICS
from tron1cli.fileio import atomic_write, write_file
from tron1cli.train.layout import policy_label
from tron1cli.viz.cells import mean_std, speed_cell
from tron1cli.viz.rerun_stream import open_stream, parse_rerun_option

RERUN_FORMS = "spawn, save=FILE.rrd, connect[=URL] or off."
POLICY_HELP = (
    "Policy groups: [LABEL=]PATH[,PATH...] (a checkpoint .pt or an exported .onnx; several = seeds)."
)


def parse_groups(tokens: list[str]) -> dict[str, list[Path]]:
    """``["ours=a.pt,b.pt", "c.onnx"]`` -> {"ours": [a.pt, b.pt], "c": [c.onnx]}; labels must be unique."""
    groups: dict[str, list[Path]] = {}
    for tok in tokens:
        label, _, rest = tok.rpartition("=") if "=" in tok else ("", "", tok)
        paths = [Path(p) for p in rest.split(",") if p]
        if not paths:
            raise ValueError(f"no policy path in '{tok}'")
        label = label or policy_label(paths[0])
        if label in groups:
            raise ValueError(f"label '{label}' given twice; name groups as LABEL=PATH")
        groups[label] = paths
    return groups


def _policy_groups(tokens: list[str]) -> dict[str, list[Path]]:
    """:func:`parse_groups` with every path checked to be a file, before the heavy imports."""
    try:
        groups = parse_groups(tokens)
    except ValueError as e:
        fail(str(e), 2)
    check_inputs(p for paths in groups.values() for p in paths)
    return groups


SPEED_DIM_NAMES = ("vx", "vy", "yaw")  #: as tron1cli.evaluation.protocol.SPEED_DIMS (kept light here)


def parse_floats(text: str, what: str) -> list[float]:
    try:
        vals = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise ValueError(f"{what} wants numbers separated by commas, got '{text}'") from None
    if not vals:
        raise ValueError(f"{what} is empty")
    return vals


def parse_speeds(tokens: list[str]) -> dict[str, list[float]]:
    """``--speeds`` values -> speeds per velocity dimension, in order, without repeats.

    ``["0.25,0.5", "vy:0.25", "yaw:0.5,1", "vx:0.75"]`` -> {"vx": [0.25, 0.5, 0.75], "vy": [0.25],
    "yaw": [0.5, 1.0]}: ``DIM:LIST`` with DIM one of vx, vy (m/s) or yaw (rad/s); a bare list is vx.
    Refuses (ValueError) an unknown dimension and non-finite numbers.
    """
    plan: dict[str, list[float]] = {}
    for tok in tokens:
        dim, sep, values = tok.partition(":")
        if not sep:
            dim, values = "vx", tok
        dim = dim.strip().lower()
        if dim not in SPEED_DIM_NAMES:
            raise ValueError(f"unknown speed dimension '{dim}' in --speeds {tok}; choose from vx, vy, yaw")
        for v in parse_floats(values, f"--speeds {dim}"):
            if not math.isfinite(v):
                raise ValueError(f"--speeds {dim}: {v} is not a finite number")
            if v not in plan.setdefault(dim, []):
                plan[dim].append(v)
    return {d: plan[d] for d in SPEED_DIM_NAMES if d in plan}


@contextmanager
def progress_bar(total: int, what: str):
    prog = Progress(
        TextColumn(f"[bold]{what}"),
        MofNCompleteColumn(),
        BarColumn(bar_width=24),
        TextColumn("{task.fields[now]}"),
        TimeElapsedColumn(),
        console=err,
        transient=True,
        disable=not err.is_terminal,  # a log gets no bar (and no blank line where it stood)
    )
    task = prog.add_task(what, total=total, now="")
    done = [0]

    def advance(label: str):
        def on_step(_t: int) -> None:
            done[0] += 1
            prog.update(task, completed=done[0], now=label)

        return on_step

    advance.done = done  # policy steps run so far (for the interrupted message)
    with prog:
        yield advance


def interrupted(cmd: str, done: int, total: int, target, out_dir) -> None:
    """Ctrl-C during the batches: one line saying so and what was written, exit 130."""
    wrote = "no results written" + (f" (--out {out_dir} untouched)" if out_dir is not None else "")
    if target is not None and target.kind == "save":
        wrote += f"; the rerun recording {target.arg} holds what was streamed"
    fail(f"{cmd} interrupted after {done:,} of {total:,} policy steps: {wrote}", 130)


def check_levels(loaded: dict, level: int) -> None:
    """Exit 2 unless --level names a level of every policy's terrain generator."""
    from tron1cli.evaluation.protocol import check_level

    try:
        for pols in loaded.values():
            for p in pols:
                check_level(level, p.run_cfg.env.terrain_cfg.num_levels)
    except ValueError as e:
        fail(str(e), 2)


def eval_cmd(
    policies: list[str] = typer.Argument(..., help=POLICY_HELP, show_default=False),
    terrain: str = typer.Option("all", "--terrain", "-t", help=terrain_help(("all",))),
    level: int = typer.Option(-1, "--level", help="Terrain difficulty level (0 easiest; -1 the hardest)."),
    envs: int | None = typer.Option(
        None,
        "--envs",
        "-n",
        min=1,
        help="Envs per batch [default: 1024, as the paper; 128 with --climb].",
        show_default=False,
    ),
    steps: int = typer.Option(
        500, "--steps", min=1, help="Policy steps per batch (500 = 10 s, as the paper)."
    ),
    randomize: bool = typer.Option(
        True,
        "--randomize/--no-randomize",
        help="The policy's own training randomisation (the Table III terms it trained with) on/off; "
        "a policy trained without any meets the nominal robot either way.",
    ),
    climb: bool = typer.Option(
        False,
        "--climb",
        help="The climb probe: one checkpoint's teacher and student on stairs up at levels 3, 6 and 9 "
        "(8, 14, 20 cm risers): success, traverse, command progress, risers climbed per env.",
    ),
    speeds: list[str] | None = typer.Option(
        None,
        "--speeds",
        metavar="[DIM:]LIST",
        help="Also success rate by commanded speed (Fig. 5), per velocity dimension: DIM:LIST with "
        "DIM vx or vy (m/s) or yaw (rad/s), e.g. --speeds vx:0.25,0.5 --speeds yaw:0.5; "
        "a bare list is vx. Repeatable; within the policy's training command range.",
    ),
    metrics: str = typer.Option(
        "",
        "--metrics",
        help="Metrics to show (default all): " + ", ".join(METRICS),
    ),
    seed: int = typer.Option(0, "--seed", min=0, max=SEED_MAX, help="Seed of the eval envs."),
    layouts: int = typer.Option(
        EVAL_LAYOUTS,
        "--layouts",
        min=1,
        help="Random terrain layouts drawn at the level under test, one per env at random (discrete "
        "and rough; a training run draws its config's terrain_cfg.variants_per_level).",
    ),
    actor: str | None = typer.Option(
        None,
        "--actor",
        help="Who acts: student (the deployed policy: history and depth) or teacher (a checkpoint's "
        "privileged e_t and true heightmap; measures the teacher-student gap) [default: student; "
        "both with --climb].",
        show_default=False,
    ),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object on stdout instead of tables."),
    out_dir: Path | None = typer.Option(
        None,
        "--out",
        parser=path_option,
        metavar="DIR",
        help="Write results.json, results.csv and plots here.",
    ),
    rerun: str = typer.Option("off", "--rerun", help="Stream env 0 of the first batch: " + RERUN_FORMS),
    video: Path | None = typer.Option(
        None,
        "--video",
        metavar="FILE.mp4",
        help=VIDEO_HELP
        + "env 0 of each terrain's batch (the first policy of each method) under the training "
        "commands, then at each --speeds speed, one after another, each captioned.",
    ),
    video_size: str | None = typer.Option(
        None, "--video-size", metavar="WxH", help=VIDEO_SIZE_HELP + " [default: 640x480]."
    ),
    gait_freq: float | None = typer.Option(
        None,
        "--gait-freq",
        callback=finite,
        help="Hold the gait clock at this frequency (Hz, within every policy's trained range) "
        "[default: drawn with each command, as in training].",
    ),
    backend: str = backend_option(),
) -> None:
    """Table I metrics (success, orientation, angular velocity, tracking, reconstruction) per terrain.

    Full window: only a fall ends an env's window, and every env walks terrain of the type and
    level under test for all of it (the eval tile is sized from the window and the fastest command).
    success_rate: share of envs not fallen in the window; orientation_error: |g_b - (0,0,-1)|;
    angular_velocity_error: mean |w_x|, |w_y| (rad/s); velocity_tracking_error: |v_cmd,xy - v_xy|
    (m/s, base frame); reconstruction_error_cm: mean |h_hat - h| of the student's heightmap (cm);
    exposure_s: mean time an env walked the terrain under test (s; survivors: the whole window);
    command_progress: distance walked along the commanded path over the distance commanded (ours);
    pitch_deg: mean signed base pitch (degrees, + nose down); traverse_rate: share of envs that
    succeeded and walked at least half their commanded distance.
    """
    groups = _policy_groups(policies)
    if climb:
        _climb(groups, terrain, level, speeds, actor, envs, steps, randomize, seed, as_json, out_dir)
        return
    envs = envs or 1024
    actor = actor or "student"
    from tron1cli.evaluation.protocol import (
        SPEED_DIMS,
        EvalSpec,
        aggregate,
        check_speed,
        resolve_eval_terrains,
        run_batch,
    )
    from tron1cli.policy.contract import ACTORS

    try:
        if actor not in ACTORS:
            raise ValueError(f"unknown --actor '{actor}'; choose from {', '.join(ACTORS)}")
        terrains = resolve_eval_terrains(terrain)
        plan = parse_speeds(speeds or [])
        shown = [m.strip() for m in metrics.split(",") if m.strip()] or list(METRICS)
        bad = [m for m in shown if m not in METRICS]
        if bad:
            raise ValueError(f"unknown metric '{bad[0]}'; choose from {', '.join(METRICS)}")
        target = parse_rerun_option(rerun)
    except ValueError as e:
        fail(str(e), 2)
    check_backend(backend)
    inputs = [p for paths in groups.values() for p in paths]
    check_outputs(files=[rerun_file(target)], dirs=[("--out", out_dir)], inputs=inputs)

    from tron1cli.policy.runtime import load_policy
    from tron1cli.viz.video import DEFAULT_SIZE

    recorder = open_video(video, video_size, DEFAULT_SIZE)
    loaded = {label: [load_policy(p, actor) for p in paths] for label, paths in groups.items()}
    check_levels(loaded, level)
    try:  # a sweep speed must lie inside every policy's training command range
        for pols in loaded.values():
            for p in pols:
                for dim, values in plan.items():
                    for v in values:
                        check_speed(p.run_cfg.env.commands, dim, v)
    except ValueError as e:
        fail(f"--speeds: {e} ({p.path})", 2)
    try:  # so must a fixed gait frequency
        for pols in loaded.values():
            for p in pols:
                p.run_cfg.env.gait.deployed_hz(gait_freq)
    except ValueError as e:
        fail(f"--gait-freq: {e} ({p.path})", 2)
    n_pol = sum(len(v) for v in loaded.values())
    n_speeds = sum(len(v) for v in plan.values())
    total = n_pol * steps * len(terrains) * (1 + n_speeds)
    results: dict = {label: {} for label in loaded}
    coverage: dict = {label: {} for label in loaded}
    # per swept dimension, method, terrain and speed: success (by_speed) and command progress
    by_speed: dict = {dim: {label: {t: {} for t in terrains} for label in loaded} for dim in plan}
    progress_by_speed: dict = {dim: {label: {t: {} for t in terrains} for label in loaded} for dim in plan}
    stream = open_stream(target, recording_name="tron1 eval")
    with progress_bar(total, "eval") as advance:
        try:
            for label, pols in loaded.items():
                for t in terrains:
                    spec = EvalSpec(
                        t,
                        level,
                        envs,
                        steps,
                        randomize,
                        seed=seed,
                        gait_freq_hz=gait_freq,
                        backend=backend,
                        layouts=layouts,
                    )
                    where = f"{label} on {t}, " + ("hardest level" if level == -1 else f"level {level}")
                    runs = []
                    for k, p in enumerate(pols):
                        take = _take(recorder, k, f"{where}, training commands, env 0 of {envs}")
                        runs.append(run_batch(p, spec, advance(f"{label} {t}"), stream=stream, video=take))
                        if stream is not None:  # the first batch only: one episode on one timeline
                            stream.close()
                            stream = None
                    results[label][t] = {m: aggregate([r.metrics[m] for r in runs]) for m in METRICS}
                    coverage[label][t] = _coverage(runs)
                    for dim, values in plan.items():
                        unit = SPEED_DIMS[dim].unit
                        for v in values:
                            sr = [
                                run_batch(
                                    p,
                                    replace(spec, speed=v, speed_dim=dim),
                                    advance(f"{label} {t} {dim} {v:g} {unit}"),
                                    video=_take(recorder, k, f"{where}, {dim} {v:g} {unit}, env 0 of {envs}"),
                                )
                                for k, p in enumerate(pols)
                            ]
                            by_speed[dim][label][t][v] = aggregate([r.metrics["success_rate"] for r in sr])
                            progress_by_speed[dim][label][t][v] = aggregate(
                                [r.metrics["command_progress"] for r in sr]
                            )
                            _warn_left(sr, f"{label} {t} {dim}:{v:g}")
                    _warn_left(runs, f"{label} {t}")
        except KeyboardInterrupt:
            if stream is not None:
                stream.close()
            interrupted("eval", advance.done[0], total, target, out_dir)

    first = next(iter(next(iter(coverage.values())).values()))
    rand_word, rand_terms = _randomisation(randomize, [p for ps in loaded.values() for p in ps])
    report = {
        "protocol": {
            "name": "full-window",
            "terrains": list(terrains),
            "level": level,
            "envs": envs,
            "steps": steps,
            "window_s": steps * next(iter(loaded.values()))[0].run_cfg.env.policy_dt,
            "randomize": randomize,
            "randomization_terms": rand_terms,
            "seed": seed,
            "layouts": layouts,
            "actor": actor,
            "gait_freq_hz": gait_freq,
            "eval_tile_m": first["tile_m"],
            "backend": backend,
        },
        "policies": {label: [str(p) for p in paths] for label, paths in groups.items()},
        "results": results,
        "coverage": coverage,
    }
    sweeps = (("success_by_speed", by_speed), ("progress_by_speed", progress_by_speed)) if plan else ()
    for key, sweep in sweeps:
        report[key] = {
            dim: {
                "unit": SPEED_DIMS[dim].unit,
                "results": {
                    lab: {t: {str(v): m for v, m in d.items()} for t, d in per.items()}
                    for lab, per in sweep[dim].items()
                },
            }
            for dim in plan
        }
    replaced = out_dir is not None and (out_dir / "results.json").exists()
    if out_dir is not None:
        _write_eval_outputs(out_dir, report, by_speed, progress_by_speed)
    if as_json:
        print_json(report)
        render_video(recorder)
        return
    table = Table(
        title="tron1 eval (Table I)",
        caption=f"{actor}s, level {level}, {envs} envs x {steps} steps, "
        f"randomisation {rand_word}, "
        + ("" if gait_freq is None else f"gait {gait_freq:g} Hz, ")
        + f"full window ({first['tile_m']:g} m tiles, {layouts} layouts), seed {seed}; "
        "mean ± std over the policies of a method; "
        "success and traverse in %",
    )
    table.add_column("method")
    table.add_column("metric")
    for t in terrains:
        table.add_column(t, justify="right")
    for label in loaded:
        for i, m in enumerate(shown):
            cells = (mean_std(results[label][t][m], m in PERCENT_METRICS) for t in terrains)
            table.add_row(label if i == 0 else "", m, *cells, end_section=i == len(shown) - 1)
    out.print(table)
    for dim, values in plan.items():
        d = SPEED_DIMS[dim]
        table = Table(
            title=f"success rate (%) / command progress by commanded {d.words}",
            caption="a success that stands still has progress near 0",
        )
        table.add_column("method / terrain")
        for v in values:
            table.add_column(f"{v:g} {d.unit}", justify="right")
        for label in loaded:
            for t in terrains:
                cells = (
                    speed_cell(by_speed[dim][label][t][v], progress_by_speed[dim][label][t][v])
                    for v in values
                )
                table.add_row(f"{label} / {t}", *cells)
        out.print(table)
    if out_dir is not None:
        out.print(f"results written to {out_dir}/" + (" (replacing the earlier ones)" if replaced else ""))
    render_video(recorder)


def _take(recorder, k: int, caption: str):
    """The video take of env 0 for the first policy (``k == 0``) of a method; None otherwise."""
    return recorder.take([0], caption=caption) if recorder is not None and k == 0 else None


def _randomisation(randomize: bool, policies) -> tuple[str, list[str] | None]:
    """The caption's word for the randomisation an eval applies, and its Table III terms for the
    JSON (None when off): ``--randomize`` applies each policy's own training terms, so a policy
    trained without any meets the nominal robot, and the caption says so."""
    if not randomize:
        return "off", None
    terms = sorted({t for p in policies for t in p.run_cfg.env.randomization.terms})
    if not terms:
        return "on, but the policy trained with none: nominal robot", terms
    return "on", terms


def _climb(groups, terrain, level, speeds, actor, envs, steps, randomize, seed, as_json, out_dir) -> None:
    """``tron1 eval CKPT --climb``: the climb probe (tron1cli.evaluation.climb) of one checkpoint."""
    from tron1cli.evaluation.climb import CLIMB_ENVS, CLIMB_LEVELS, CLIMB_TERRAIN, climb_probe
    from tron1cli.policy.contract import ACTORS

    paths = [p for ps in groups.values() for p in ps]
    if len(paths) != 1 or paths[0].suffix == ".onnx":
        fail("--climb scores one checkpoint (.pt): its teacher and its student", 2)
    if terrain != "all" or level != -1 or speeds:
        fail(
            "--climb sets its own terrain and levels (stairs up, 3, 6, 9); "
            "leave out --terrain, --level and --speeds",
            2,
        )
    if actor is not None and actor not in ACTORS:
        fail(f"unknown --actor '{actor}'; choose from {', '.join(ACTORS)}", 2)
    check_outputs(dirs=[("--out", out_dir)], inputs=paths)
    from tron1cli.policy.runtime import load_policy

    path, envs = paths[0], envs or CLIMB_ENVS
    policies = {"teacher": load_policy(path, "teacher")} if actor in (None, "teacher") else {}
    if actor in (None, "student"):
        try:
            policies["student"] = load_policy(path, "student")
        except Tron1Error as e:
            if actor == "student":
                raise
            err.print(f"[yellow]note:[/] no student row: {e}", highlight=False)
    total = len(policies) * len(CLIMB_LEVELS) * steps
    with progress_bar(total, "climb") as advance:
        try:
            rows = climb_probe(
                policies,
                envs,
                steps,
                seed,
                randomize=randomize,
                on_batch=lambda a, lv: advance(f"{a} level {lv}"),
            )
        except KeyboardInterrupt:
            interrupted("eval --climb", advance.done[0], total, None, out_dir)
    rand_word, rand_terms = _randomisation(randomize, policies.values())
    report = {
        "protocol": {
            "name": "climb probe",
            "terrain": CLIMB_TERRAIN,
            "levels": list(CLIMB_LEVELS),
            "envs": envs,
            "steps": steps,
            "randomize": randomize,
            "randomization_terms": rand_terms,
            "seed": seed,
        },
        "policy": str(path),
        "rows": [asdict(r) for r in rows],
    }
    if out_dir is not None:
        _write_climb_outputs(out_dir, report)
    if as_json:
        print_json(report)
        return
    table = Table(
        title=f"climb probe: {policy_label(path)}",
        caption=f"stairs up, {envs} envs x {steps} steps, training commands, randomisation "
        f"{rand_word}, full window; cm: riser height; success and traverse in %, progress: command "
        "progress, risers: climbed per env; fell by: % of envs whose fall came with the base "
        "tilted past the limit / the base / a thigh touching the ground",
        box=box.SIMPLE_HEAD,
        collapse_padding=True,  # 80 columns
    )
    for col in ("actor", "level", "cm", "success", "traverse", "progress", "risers", "pitch°", "fell by"):
        table.add_column(col, justify="left" if col == "actor" else "right")
    for r in rows:
        table.add_row(
            r.actor,
            str(r.level),
            f"{100 * r.riser_m:.0f}",
            f"{100 * r.success:.1f}",
            f"{100 * r.traverse:.1f}",
            "-" if r.progress is None else f"{r.progress:.2f}",
            f"{r.risers:.2f}",
            "-" if r.pitch_deg is None else f"{r.pitch_deg:+.1f}",
            "/".join(f"{100 * v:.0f}" for v in (r.fell_tilt, r.fell_base, r.fell_thigh)),
        )
    out.print(table)
    if out_dir is not None:
        out.print(f"results written to {out_dir}/")


def _write_climb_outputs(out_dir: Path, report: dict) -> None:
    """climb.json and climb.csv in ``out_dir``, each written atomically."""
    import io

    out_dir.mkdir(parents=True, exist_ok=True)
    atomic_write(out_dir / "climb.json", lambda f: f.write(json.dumps(report, indent=2).encode()))
    buf = io.StringIO()
    w = csv.writer(buf)
    rows = report["rows"]
    w.writerow(list(rows[0]))
    for r in rows:
        w.writerow(list(r.values()))
    atomic_write(out_dir / "climb.csv", lambda f: f.write(buf.getvalue().encode()))


def _coverage(runs: list) -> dict:
    """How far the envs of one method's batches went on the eval tile (max over its policies)."""
    return {
        "tile_m": runs[0].tile_m,
        "edge_m": runs[0].edge_m,
        "max_reach_m": max(r.max_reach_m for r in runs),
        "left_terrain": int(sum(int(r.left.sum()) for r in runs)),
    }


def _warn_left(runs: list, what: str) -> None:
    n = sum(int(r.left.sum()) for r in runs)
    if n:
        err.print(
            f"[yellow]warning:[/] {what}: {n} envs reached the edge of the eval tile; counted as failures",
            highlight=False,
        )


def _csv_text(rows: list[list]) -> str:
    """CSV rows as the text csv.writer gives a file."""
    import io

    buf = io.StringIO()
    csv.writer(buf).writerows(rows)
    return buf.getvalue()


def _write_eval_outputs(out_dir: Path, report: dict, by_speed: dict, progress_by_speed: dict) -> None:
    """results.json, results.csv and, per swept dimension, success_by_speed_DIM.csv (success and
    command progress by speed) and success_by_speed_DIM.png."""
    from tron1cli.evaluation.protocol import SPEED_DIMS
    from tron1cli.viz.plots import success_by_speed

    out_dir.mkdir(parents=True, exist_ok=True)
    # each file written whole or not at all (a full disk keeps the earlier one)
    write_file(out_dir / "results.json", json.dumps(report, indent=2))
    rows = [["method", "terrain", "metric", "mean", "std", "n"]]
    for label, per in report["results"].items():
        for t, ms in per.items():
            for m, a in ms.items():
                rows.append([label, t, m, a["mean"], a["std"], a["n"]])
    write_file(out_dir / "results.csv", _csv_text(rows))
    for dim, per_label in by_speed.items():
        unit = SPEED_DIMS[dim].unit
        speed = f"{dim}_{unit.replace('/', 'p')}"
        rows = [["method", "terrain", speed, "success_mean", "success_std", "progress_mean", "progress_std"]]
        for label, per in per_label.items():
            for t, d in per.items():
                for v, a in d.items():
                    p = progress_by_speed[dim][label][t][v]
                    rows.append([label, t, v, a["mean"], a["std"], p["mean"], p["std"]])
        write_file(out_dir / f"success_by_speed_{dim}.csv", _csv_text(rows))
        terrains = next(iter(per_label.values()))
        curves = {
            (label if len(terrains) == 1 else f"{label} / {t}"): per[t]
            for label, per in per_label.items()
            for t in per
        }
        words = SPEED_DIMS[dim].words
        success_by_speed(
            curves,
            out_dir / f"success_by_speed_{dim}.png",
            title=f"success by commanded {words}",
            xlabel=f"commanded {words} {dim} ({unit})",
        )


def push_test(
    policies: list[str] = typer.Argument(..., help=POLICY_HELP, show_default=False),
    extreme: bool = typer.Option(
        False, "--extreme", help="+/-400 N, +/-20 N m on flat ground (else moderate)."
    ),
    terrain: str | None = typer.Option(
        None, "--terrain", "-t", help="Terrain [default: mixed for moderate, flat for --extreme]."
    ),
    level: int = typer.Option(-1, "--level", help="Terrain difficulty level (-1 the hardest)."),
    envs: int = typer.Option(
        1024,
        "--envs",
        "-n",
        min=14,
        help="Envs per policy (1024, as the paper; spread over the 14 push types).",
    ),
    randomize: bool = typer.Option(
        True,
        "--randomize/--no-randomize",
        help="The policy's own training randomisation (the Table III terms it trained with) on/off; "
        "a policy trained without any meets the nominal robot either way.",
    ),
    seed: int = typer.Option(0, "--seed", min=0, max=SEED_MAX, help="Seed of the envs and the mixed pushes."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object on stdout instead of tables."),
    out_dir: Path | None = typer.Option(
        None,
        "--out",
        parser=path_option,
        metavar="DIR",
        help="Write results.json, results.csv and the plot here.",
    ),
    rerun: str = typer.Option("off", "--rerun", help="Stream one pushed env: " + RERUN_FORMS),
    watch: str = typer.Option("+Fx", "--watch", help="Push type of the env --rerun streams."),
    video: Path | None = typer.Option(
        None,
        "--video",
        metavar="FILE.mp4",
        help=VIDEO_HELP + "the first env of every push type in a 4 x 4 grid, the push as an arrow "
        "(the first policy of each method).",
    ),
    video_size: str | None = typer.Option(
        None, "--video-size", metavar="WxH", help=VIDEO_SIZE_HELP + " of the grid [default: 1280x960]."
    ),
    backend: str = backend_option(),
) -> None:
    """Push recovery (Fig. 6): one push per env at t = 2 s, survival 3 s after it, per push type.

    Moderate: 50 N or 5 N m for 0.2 s; extreme: 400 N or 20 N m for 0.1 s; along +/-x, +/-y, +/-z
    of the heading frame, or a mixed random wrench on all axes; 'none' is the unpushed control.
    Full window, as in eval: only a fall ends an env's window.
    """

    groups = _policy_groups(policies)
    from tron1cli.evaluation.protocol import aggregate, resolve_eval_terrains
    from tron1cli.evaluation.pushes import PUSH_TYPES, PushProtocol, run_push_test

    proto = PushProtocol.extreme() if extreme else PushProtocol.moderate()
    try:
        if terrain is not None:
            (t,) = resolve_eval_terrains(terrain) if terrain != "all" else ("mixed",)
            proto = replace(proto, terrain=t)
        if watch not in PUSH_TYPES:
            raise ValueError(f"unknown push type '{watch}'; choose from {', '.join(PUSH_TYPES)}")
        target = parse_rerun_option(rerun)
    except ValueError as e:
        fail(str(e), 2)
    check_backend(backend)
    inputs = [p for paths in groups.values() for p in paths]
    check_outputs(files=[rerun_file(target)], dirs=[("--out", out_dir)], inputs=inputs)
    from tron1cli.policy.runtime import load_policy
    from tron1cli.viz.plots import push_survival
    from tron1cli.viz.video import GRID_SIZE

    recorder = open_video(video, video_size, GRID_SIZE)
    loaded = {label: [load_policy(p) for p in paths] for label, paths in groups.items()}
    check_levels(loaded, level)
    stream = open_stream(target, recording_name=f"tron1 push-test {proto.name}")
    steps = proto.steps(next(iter(loaded.values()))[0].run_cfg.env.policy_dt)
    survival: dict = {}
    overall: dict = {}
    exposure: dict = {}
    coverage: dict = {}
    per_type = (envs // len(PUSH_TYPES), -(-envs // len(PUSH_TYPES)))
    total = steps * sum(len(v) for v in loaded.values())
    with progress_bar(total, "push-test") as advance:
        try:
            for label, pols in loaded.items():
                res = []
                for k, p in enumerate(pols):
                    rec = recorder if k == 0 else None
                    res.append(
                        run_push_test(
                            p,
                            proto,
                            envs,
                            level,
                            seed,
                            randomize,
                            advance(label),
                            stream,
                            watch,
                            rec,
                            backend,
                        )
                    )
                    if stream is not None:  # the first policy only
                        stream.close()
                        stream = None
                survival[label] = {k: aggregate([r.survival[k] for r in res]) for k in PUSH_TYPES}
                overall[label] = aggregate([r.survival_rate for r in res])
                exposure[label] = aggregate([r.exposure_s for r in res])
                coverage[label] = _coverage([r.batch for r in res])
                _warn_left([r.batch for r in res], label)
        except KeyboardInterrupt:
            if stream is not None:
                stream.close()
            interrupted("push-test", advance.done[0], total, target, out_dir)

    report = {
        "protocol": {
            "name": proto.name,
            "window": "full-window",
            "eval_tile_m": next(iter(coverage.values()))["tile_m"],
            "force_n": proto.force_n,
            "torque_nm": proto.torque_nm,
            "duration_s": proto.duration_s,
            "push_at_s": proto.push_at_s,
            "watch_s": proto.watch_s,
            "terrain": proto.terrain,
            "level": level,
            "backend": backend,
            "envs": envs,
            "seed": seed,
            "randomize": randomize,
            "randomization_terms": _randomisation(randomize, [p for ps in loaded.values() for p in ps])[1],
        },
        "policies": {label: [str(p) for p in paths] for label, paths in groups.items()},
        "methods": {
            label: {
                "survival_rate": overall[label]["mean"],
                "survival_rate_std": overall[label]["std"],
                "per_push": {k: v["mean"] for k, v in survival[label].items()},
                "per_push_std": {k: v["std"] for k, v in survival[label].items()},
                "exposure_s": exposure[label]["mean"],
            }
            for label in loaded
        },
        "coverage": coverage,
    }
    if len(loaded) == 1:  # one method: its figures at the top level too
        (only,) = report["methods"].values()
        report["survival_rate"] = only["survival_rate"]
        report["per_push"] = only["per_push"]
    replaced = out_dir is not None and (out_dir / "results.json").exists()
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
        write_file(out_dir / "results.json", json.dumps(report, indent=2))
        rows = [["method", "push", "survival_mean", "survival_std"]]
        for label in loaded:
            for k, a in survival[label].items():
                rows.append([label, k, a["mean"], a["std"]])
        write_file(out_dir / "results.csv", _csv_text(rows))
        push_survival(
            {label: {k: a["mean"] for k, a in survival[label].items()} for label in loaded},
            out_dir / "push_survival.png",
            title=f"{proto.name} pushes on {proto.terrain}",
        )
    if as_json:
        print_json(report)
        render_video(recorder)
        return
    lo, hi = per_type
    per_push = f"{lo}" if lo == hi else f"{lo}-{hi}"
    table = Table(
        title=f"{proto.name} push survival (%) on {proto.terrain}, level {level}, {per_push} envs per push"
    )
    table.add_column("push")
    for label in loaded:
        table.add_column(label, justify="right")
    for k in PUSH_TYPES:
        table.add_row(k, *(mean_std(survival[label][k], True) for label in loaded))
    table.add_row("[bold]overall (pushed)", *(mean_std(overall[label], True) for label in loaded))
    out.print(table)
    if out_dir is not None:
        out.print(f"results written to {out_dir}/" + (" (replacing the earlier ones)" if replaced else ""))
    render_video(recorder)
