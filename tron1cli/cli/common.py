"""Shared console handles and the one-line error convention of every subcommand."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

from rich.console import Console
from rich.markup import escape

from tron1cli.errors import one_line

#: results go to stdout, progress and errors to stderr
out = Console()
err = Console(stderr=True)


def terrain_help(extra: tuple[str, ...] = ()) -> str:
    """Help text listing the CLI terrain names of the terrain registry (plus ``extra``)."""
    from tron1cli.env.terrain import terrain_choices

    return terrain_choices(extra) + "."


def preset_default(field: str) -> str:
    """A preset setting as help texts show its default: the flat preset's value and the perceptive
    one's (``"512 on flat ground, 1024 elsewhere"``), or the one value both share (a tuple as
    ``"256,128,64"``)."""
    from tron1cli.config.presets import flat, perceptive

    def text(v: object) -> str:
        return ",".join(map(str, v)) if isinstance(v, tuple) else str(v)

    on_flat, elsewhere = text(getattr(flat(), field)), text(getattr(perceptive(), field))
    return on_flat if on_flat == elsewhere else f"{on_flat} on flat ground, {elsewhere} elsewhere"


def fail(message: str, code: int = 1) -> None:
    """Print one line on stderr and exit with ``code`` (1 runtime, 2 usage); a message of several
    lines is joined into one."""
    err.print(f"[bold red]error:[/] {escape(one_line(message))}", highlight=False, soft_wrap=True)
    sys.exit(code)


def warn(message: str) -> None:
    """One warning line on stderr."""
    err.print(f"[yellow]warning:[/] {escape(one_line(message))}", highlight=False, soft_wrap=True)


def note(message: str) -> None:
    """One informational line on stderr (e.g. that an existing output file is replaced)."""
    err.print(f"note: {escape(one_line(message))}", highlight=False, soft_wrap=True)


def input_problem(path: Path | str, what: str = "policy") -> str | None:
    """Why ``path`` cannot be read as an input file (one line), or None when it can: not found, a
    folder, a broken link, a symbolic link loop."""
    p = Path(path)
    if p.is_file():
        return None
    if p.is_symlink():
        try:
            p.resolve(strict=True)
        except RuntimeError:  # Python 3.11-3.12 on a loop
            return f"{what} {path}: a symbolic link loop"
        except OSError as e:
            import errno

            if e.errno == errno.ELOOP:
                return f"{what} {path}: a symbolic link loop"
            return f"{what} {path}: a broken link (to {os.readlink(p)})"
    if p.is_dir():
        return f"{what} {path} is a folder, not a file"
    return f"{what} not found: {path}"


def check_inputs(paths, what: str = "policy") -> None:
    """Exit 1 with ``<what> not found: PATH`` (or what else is wrong: :func:`input_problem`) for the
    first of ``paths`` that is not a file: called before a command imports torch and the env, so
    a mistyped path costs no start-up."""
    for path in paths:
        problem = None if path is None else input_problem(path, what)
        if problem is not None:
            fail(problem, 1)


def path_option(value) -> Path:
    """Parser of an output path option: refuses an empty one (``--out ""`` would be the current
    folder), exit 2."""
    import typer

    if isinstance(value, Path):
        return value
    if not str(value).strip():
        raise typer.BadParameter("an empty path; give a file or folder name")
    return Path(value)


def check_outputs(files=(), dirs=(), inputs=()) -> list[Path]:
    """Check every output location before the work starts (exit 2 naming the problem).

    files, dirs: (option, path) pairs (None entries and paths skipped); inputs: the command's own
    input files, never to be written over. Returns the output files that exist already (to be
    replaced: the caller says so once the work succeeded)."""
    from tron1cli.errors import UsageError
    from tron1cli.fileio import check_output_dir, check_output_file

    existing = []
    try:
        for option, path in dirs:
            if path is not None:
                check_output_dir(path, option, inputs)
        for entry in files:
            if entry is not None and entry[1] is not None:
                option, path = entry
                if check_output_file(path, option, inputs):
                    existing.append(Path(path))
    except UsageError as e:
        fail(str(e), e.exit_code)
    return existing


def rerun_file(target) -> tuple[str, Path] | None:
    """The (option, file) a ``--rerun save=FILE`` target writes, for :func:`check_outputs`."""
    if target is not None and target.kind == "save":
        return ("--rerun", Path(target.arg))
    return None


def print_json(obj: dict) -> None:
    """One JSON object on stdout, nothing else."""
    sys.stdout.write(json.dumps(obj, indent=2, sort_keys=False) + "\n")
    sys.stdout.flush()


def threads_option(what: str):
    """The ``--threads`` option of a command (None: :func:`available_cores`)."""
    import typer

    return typer.Option(
        None, "--threads", min=1, help=f"{what} [default: the cores available].", show_default=False
    )


def backend_option():
    """The ``--backend`` option of a command that steps physics."""
    import typer

    return typer.Option(
        "mujoco",
        "--backend",
        help="Physics engine: mujoco (MuJoCo on the CPU) or warp (MuJoCo Warp on the GPU when warp "
        "sees one, else on its CPU device; pip install -e '.[warp]').",
    )


def check_backend(backend: str) -> None:
    """Exit 2 on an unknown ``--backend``, or on warp not installed."""
    from tron1cli.env.physics import BACKENDS

    if backend not in BACKENDS:
        fail(f"--backend: unknown physics backend '{backend}'; choose {' or '.join(BACKENDS)}", 2)
    if backend == "warp":
        from tron1cli.env.physics_warp import warp_device

        try:
            warp_device()
        except ImportError as e:
            fail(f"--backend warp: {e}", 2)


def backend_note(backend: str) -> str:
    """What a status line adds while envs are built: warp compiles its kernels on a machine's
    first run (90 s on an H200 machine's 16 cores and on 2 CPU cores; cached after)."""
    return " (warp: a machine's first run compiles its kernels, about 90 s)" if backend == "warp" else ""


def available_cores() -> int:
    """CPU cores this process may run on (its affinity mask; all cores where that is unknown)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def resolve_device(name: str) -> str:
    """``cpu`` or ``cuda`` (the learner's device); exits 2 naming the problem otherwise."""
    if name not in ("cpu", "cuda"):
        fail(f"--device must be cpu or cuda, got '{name}'", 2)
    if name == "cuda":
        import torch

        if not torch.cuda.is_available():
            fail(
                "--device cuda: torch sees no CUDA GPU on this machine (this torch build: "
                f"{torch.__version__}); use --device cpu",
                2,
            )
    return name


def resolve_precision(name: str, device: str) -> str:
    """``fp32`` or ``bf16`` (the update's arithmetic); exits 2 otherwise. bf16 on a CPU that would
    emulate it is allowed, with a one-line note that fp32 is faster there."""
    from tron1cli.learn.config import PRECISIONS

    if name not in PRECISIONS:
        fail(f"--precision must be one of {', '.join(PRECISIONS)}, got '{name}'", 2)
    if name == "bf16" and device == "cpu":
        from tron1cli.learn.perf import cpu_has_fast_bf16

        if not cpu_has_fast_bf16():
            err.print(
                "note: this CPU has no native bfloat16 (AVX-512 or AMX): bf16 is emulated here and "
                "several times slower than fp32; --precision fp32 is the faster choice"
            )
    return name


_MUJOCO_SEEN: set[str] = set()


def route_mujoco_warnings() -> None:
    """MuJoCo's warnings as our own one-line warnings on stderr, each kind once per run, instead of
    its console print on stdout and its ``MUJOCO_LOG.TXT`` in the current folder."""
    import mujoco

    cfg = mujoco.MjLogConfig.get()
    cfg.logto_file = False
    cfg.logto_console = False
    cfg.set()

    def on_warning(message: str) -> None:
        kind = message.split(" Time =")[0].strip()
        if kind not in _MUJOCO_SEEN:  # the env counts and resets unstable worlds itself
            _MUJOCO_SEEN.add(kind)
            warn(f"MuJoCo: {kind} (further such warnings are not shown)")

    mujoco.set_mju_user_warning(on_warning)


#: the largest --seed (numpy, torch and the terrain generator all take 32-bit seeds)
SEED_MAX = 2**32 - 1


def finite(value: float | None) -> float | None:
    """Option callback: refuse nan and inf (a range check lets NaN through: it compares false)."""
    import math

    import typer

    if value is not None and not math.isfinite(value):
        raise typer.BadParameter(f"{value} is not a finite number")
    return value


GAIT_FREQ_HELP = (
    "Hold the gait clock at this frequency (Hz, within the policy's trained range, 1.5-2.5 for ours) "
    "[default: the middle of that range]."
)
VIDEO_HELP = "Record an MP4 video (30 fps, real time; a PNG strip of 5 frames goes beside it) to this file: "
VIDEO_SIZE_HELP = "Video frame size WIDTHxHEIGHT (even numbers)"


def open_video(path, size: str | None, default: tuple[int, int], inputs=()):
    """A :class:`tron1cli.viz.video.VideoRecorder` for ``--video PATH --video-size WxH``; None
    without ``--video``. Exits 2 on a bad path or size, and on a place the video and its strip
    cannot be written (a file in the way, no permission; as --out is checked), before the run."""
    if path is None:
        return None
    from tron1cli.viz.video import VideoRecorder, check_video_path, parse_size, strip_path

    try:
        check_video_path(path)
        wh = parse_size(size) if size else default
    except ValueError as e:
        fail(str(e), 2)
    check_outputs(files=[("--video", Path(path)), ("--video", strip_path(Path(path)))], inputs=inputs)
    return VideoRecorder(path, wh)


def render_video(recorder) -> None:
    """Render and encode a recorded video after the run's results are out; a missing OpenGL
    backend or a failed render is one line on stderr and exit code 1."""
    if recorder is None:
        return
    from tron1cli.viz.video import VideoError

    try:
        with err.status(f"rendering {recorder.frames} video frames..."):
            st = recorder.render()
    except VideoError as e:
        fail(str(e), 1)
    err.print(
        f"video: {st['path']}, strip {st['strip']} "
        f"({st['frames']} frames, {st['width']}x{st['height']}, {st['fps']} fps; "
        f"MUJOCO_GL={st['backend']}: {st['render_ms_per_frame']:.0f} ms a frame to render, "
        f"{st['encode_ms_per_frame']:.1f} ms to encode)",
        highlight=False,
        soft_wrap=True,
    )
