"""Entry point of the ``tron1`` command: registers the subcommands and maps errors to exit codes."""

from __future__ import annotations

import functools
import sys

import typer
from typer.exceptions import TyperException

from tron1cli import __version__

try:  # MuJoCo reads MUJOCO_GL when it is first imported, and refuses a value it does not know
    from tron1cli.cli import bench as bench_cmd
    from tron1cli.cli import deploy_robot as deploy_robot_cmd
    from tron1cli.cli import deploy_sim as deploy_sim_cmd
    from tron1cli.cli import evaluate as evaluate_cmd
    from tron1cli.cli import export as export_cmd
    from tron1cli.cli import report as report_cmd
    from tron1cli.cli import train as train_cmd
except RuntimeError as e:
    if "MUJOCO_GL" not in str(e):
        raise
    sys.stderr.write(f"error: {e} (egl, osmesa or glfw; or leave it unset)\n")
    sys.exit(2)
except Exception as e:  # a known MUJOCO_GL whose OpenGL backend cannot load (a missing package)
    from tron1cli.viz.video import gl_import_error

    line = gl_import_error(e)
    if line is None:
        raise
    sys.stderr.write(f"error: {line}\n")
    sys.exit(1)
from tron1cli.cli.common import fail, route_mujoco_warnings
from tron1cli.errors import Interrupted, Tron1Error

app = typer.Typer(
    name="tron1",
    help="Train, test and deploy LIPM-guided perceptive locomotion for the LimX TRON1 point-foot biped.",
    invoke_without_command=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode="markdown",  # help texts say "[default: ...]"; rich markup would eat it as a tag
)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"tron1 {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    ctx: typer.Context,
    version: bool = typer.Option(
        False, "--version", callback=_version, is_eager=True, help="Print the version and exit."
    ),
) -> None:
    """Train, test and deploy LIPM-guided perceptive locomotion for the LimX TRON1 point-foot biped."""
    if ctx.invoked_subcommand is None:
        typer.echo(ctx.get_help())


#: what a command keeps when Ctrl-C stops it where it has no handler of its own (train saves a
#: checkpoint, eval and push-test count the policy steps run, deploy-robot stops the robot)
KEPT_ON_INTERRUPT = {
    "train": "no training iteration had run; nothing was saved",
    "export-onnx": "nothing written (an earlier output file is left as it was)",
    "report": "nothing written",
}


def _interruptible(name: str, command):
    """``command`` with Ctrl-C turned into :class:`Interrupted` (one line, exit 130): typer itself
    would swallow KeyboardInterrupt and exit 130 with nothing said."""

    @functools.wraps(command)
    def run(*args, **kwargs):
        try:
            return command(*args, **kwargs)
        except KeyboardInterrupt:
            kept = KEPT_ON_INTERRUPT.get(name, "no results written")
            raise Interrupted(f"{name} interrupted: {kept}") from None

    return run


# in the order a user meets them (`tron1 --help` lists them as registered)
for _name, _command in (
    ("train", train_cmd.train),
    ("eval", evaluate_cmd.eval_cmd),
    ("push-test", evaluate_cmd.push_test),
    ("export-onnx", export_cmd.export_onnx),
    ("deploy-sim", deploy_sim_cmd.deploy_sim),
    ("deploy-robot", deploy_robot_cmd.deploy_robot),
    ("sim-robot", deploy_robot_cmd.sim_robot),
    ("report", report_cmd.report),
    ("bench", bench_cmd.bench),
):
    app.command(_name)(_interruptible(_name, _command))


def main() -> None:
    """Run the CLI: a user's mistake gives one line on stderr and exit 2, a runtime failure exit 1.

    A command that started LimX's SDK ends through :func:`tron1cli.deploy.sdk.leave` (no
    interpreter teardown under the SDK's threads)."""
    try:
        _main()
    except SystemExit as e:
        from tron1cli.deploy import sdk

        if sdk.in_use():
            sdk.leave(e.code if isinstance(e.code, int) else 1)
        raise


def _main() -> None:
    try:
        route_mujoco_warnings()
        code = app(standalone_mode=False)
    except TyperException as e:  # typer's usage errors: bad option, bad value, missing argument
        fail(e.format_message().splitlines()[0], getattr(e, "exit_code", 2))
    except typer.Abort:
        fail("aborted", 130)
    except Tron1Error as e:
        fail(str(e), e.exit_code)
    except FileNotFoundError as e:
        fail(str(e), 1)
    except OSError as e:  # a disk full, a permission taken away while running, ...
        where = f"{e.filename}: " if e.filename else ""
        fail(f"{where}{e.strerror or e}", 1)
    except KeyboardInterrupt:
        fail("interrupted", 130)
    if code == 130:  # Ctrl-C while typer parsed the command line: typer says nothing
        fail("interrupted", 130)
    sys.exit(code if isinstance(code, int) else 0)


if __name__ == "__main__":
    main()
