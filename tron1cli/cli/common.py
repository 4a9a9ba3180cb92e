"""Shared console handles and the one-line error convention of every subcommand."""

from __future__ import annotations

import json
import os
import sys

from rich.console import Console

#: results go to stdout, progress and errors to stderr
out = Console()
err = Console(stderr=True)


def terrain_help(extra: tuple[str, ...] = ()) -> str:
    """Help text listing the CLI terrain names of the terrain registry (plus ``extra``)."""
    from tron1cli.env.terrain import terrain_choices

    return terrain_choices(extra) + "."


def fail(message: str, code: int = 1) -> None:
    """Print one line on stderr and exit with ``code`` (1 runtime, 2 usage)."""
    err.print(f"[bold red]error:[/] {message}", highlight=False, soft_wrap=True)
    sys.exit(code)


def print_json(obj: dict) -> None:
    """One JSON object on stdout, nothing else."""
    sys.stdout.write(json.dumps(obj, indent=2, sort_keys=False) + "\n")
    sys.stdout.flush()


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


VIDEO_HELP = "Record an MP4 video (30 fps, real time) to this file: "
VIDEO_SIZE_HELP = "Video frame size WIDTHxHEIGHT (even numbers)"


def open_video(path, size: str | None, default: tuple[int, int]):
    """A :class:`tron1cli.viz.video.VideoRecorder` for ``--video PATH --video-size WxH``; None
    without ``--video``. Exits 2 on a bad path or size (before the run)."""
    if path is None:
        return None
    from tron1cli.viz.video import VideoRecorder, check_video_path, parse_size

    try:
        check_video_path(path)
        wh = parse_size(size) if size else default
    except ValueError as e:
        fail(str(e), 2)
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
        f"video: {st['path']} ({st['frames']} frames, {st['width']}x{st['height']}, {st['fps']} fps; "
        f"MUJOCO_GL={st['backend']}: {st['render_ms_per_frame']:.0f} ms a frame to render, "
        f"{st['encode_ms_per_frame']:.1f} ms to encode)",
        highlight=False,
        soft_wrap=True,
    )
