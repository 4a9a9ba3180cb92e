"""``tron1 deploy-robot`` and ``tron1 sim-robot``: the ONNX policy on LimX's SDK, and our MuJoCo model
as the simulated robot it can talk to."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from tron1cli.cli.common import (
    GAIT_FREQ_HELP,
    check_inputs,
    err,
    fail,
    finite,
    note,
    out,
    print_json,
    terrain_help,
)
from tron1cli.errors import UsageError
from tron1cli.viz.cells import figure

EXIT = {"duration": 0, "interrupted": 130}  # every other end (a safety trip) exits 1


def deploy_robot(
    policy: Path = typer.Argument(..., help="Exported policy (.onnx).", show_default=False),
    ip: str = typer.Option("127.0.0.1", "--ip", help="The robot's address (127.0.0.1: sim-robot here)."),
    cmd: str | None = typer.Option(
        None, "--cmd", help="Constant command vx,vy,yaw (m/s, m/s, rad/s) [default: 0,0,0]."
    ),
    joystick: bool = typer.Option(False, "--joystick", help="Commands from the robot's joystick (SDK)."),
    duration: float | None = typer.Option(
        None, "--duration", callback=finite, min=0.02, help="Seconds of policy [default: until Ctrl-C]."
    ),
    ramp: float = typer.Option(
        2.0, "--ramp", callback=finite, min=0.1, help="Seconds of the ramp to the default pose."
    ),
    max_tilt: float = typer.Option(
        0.8, "--max-tilt", callback=finite, min=0.05, max=1.5, help="Base tilt (rad) that trips to damping."
    ),
    watchdog_ms: float = typer.Option(
        50.0, "--watchdog-ms", callback=finite, min=5.0, max=1000.0, help="Longest state or IMU silence (ms)."
    ),
    depth: str = typer.Option(
        "none",
        "--depth",
        help="Depth source of a perceptive policy: none, realsense (pyrealsense2) or udp[:PORT] "
        "(frames from sim-robot --depth-to, port 47017 by default).",
    ),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object on stdout instead of a table."),
    gait_freq: float | None = typer.Option(None, "--gait-freq", callback=finite, help=GAIT_FREQ_HELP),
) -> None:
    """Run POLICY on a TRON1 through LimX's SDK: 50 Hz, the observation of its contract, joints mapped
    by motor name; a ramp to the default pose first; damping (Kp 0) when state or IMU stop for more
    than --watchdog-ms, the base tilts past --max-tilt, or on Ctrl-C.

    Reports survival, loop latency (state message to published command) and policy time.
    """
    check_inputs([policy])
    from tron1cli.deploy.depth_link import DEFAULT_PORT, parse_address
    from tron1cli.deploy.robot import RobotConfig, RobotController
    from tron1cli.deploy.schedule import CommandSchedule, parse_cmd
    from tron1cli.deploy.sdk import Link
    from tron1cli.policy.runtime import load_policy

    try:
        if depth not in ("none", "realsense", "udp") and not depth.startswith("udp:"):
            raise ValueError(f"unknown --depth '{depth}'; choose from none, realsense, udp[:PORT]")
        port = parse_address(depth.removeprefix("udp"), "")[1] if depth.startswith("udp:") else DEFAULT_PORT
        if cmd is not None and joystick:
            raise ValueError("give --cmd or --joystick, not both")
        schedule = CommandSchedule.constant(parse_cmd(cmd if cmd is not None else "0,0,0"))
    except (ValueError, UsageError) as e:
        fail(f"--depth: {e}" if isinstance(e, UsageError) else str(e), 2)
    if policy.suffix != ".onnx":
        fail(f"deploy-robot runs exported policies (.onnx); export {policy} with tron1 export-onnx", 2)
    pol = load_policy(policy)
    try:  # before connecting: a frequency the policy cannot run is a usage error
        pol.run_cfg.env.gait.deployed_hz(gait_freq)
    except ValueError as e:
        fail(f"--gait-freq: {e}", 2)
    cfg = RobotConfig(
        ip=ip,
        schedule=schedule,
        joystick=joystick,
        duration_s=duration,
        ramp_s=ramp,
        max_tilt_rad=max_tilt,
        watchdog_s=watchdog_ms / 1e3,
        gait_freq_hz=gait_freq,
    )
    source = None
    if depth != "none" and pol.depth_hw is None:
        note(f"{policy} is blind: --depth {depth} is not used")
    elif depth == "realsense":
        from tron1cli.deploy.depth_source import RealSenseDepth

        source = RealSenseDepth(pol.contract["depth"])
    elif depth != "none":
        from tron1cli.deploy.depth_link import UdpDepth

        try:
            source = UdpDepth(port, *pol.depth_hw)
        except UsageError as e:
            fail(f"--depth: {e}", 2)
    link = Link(ip)
    link.subscribe_robot(joystick=joystick)
    ctrl = RobotController(pol, cfg, link, source)
    if source is not None:
        source.start()
    note(f"connected to the SDK on {ip}; waiting for the robot's state and IMU")
    rep = ctrl.run(lambda line: note(line))
    if as_json:
        print_json(rep)
    else:
        out.print(_table(rep))
    code = EXIT.get(rep["ended"], 1)
    if rep["safety_trip"]:
        fail(f"{rep['safety_trip']}; sent the damping command (Kp 0, Kd {cfg.damping_kd:g})", code)
    note(f"policy stopped after {rep['duration_s']:g} s; sent the damping command (Kp 0)")


def _table(rep: dict) -> Table:
    t = Table(title=f"tron1 deploy-robot: {Path(rep['policy']).name} on {rep['ip']}")
    t.add_column("figure")
    t.add_column("value", justify="right")
    rows = [
        ("survived", f"{'yes' if rep['survived'] else 'NO'} ({rep['ended']})"),
        ("policy time (s)", f"{rep['duration_s']:.2f}"),
        ("command", "joystick" if rep["joystick"] else ",".join(f"{v:g}" for v in rep["command"])),
        ("largest base tilt (rad)", figure(rep["max_tilt_rad"])),
        (
            "latency state -> command p50 / p99 (ms)",
            f"{figure(rep['latency_ms_p50'])} / {figure(rep['latency_ms_p99'])}",
        ),
        (
            "policy inference p50 / p99 (ms)",
            f"{figure(rep['policy_ms_p50'])} / {figure(rep['policy_ms_p99'])}",
        ),
        ("state / IMU messages", f"{rep['state_messages']} / {rep['imu_messages']}"),
    ]
    if rep.get("depth_age_ms_p50") is not None:
        ages = f"{figure(rep['depth_age_ms_p50'])} / {figure(rep['depth_age_ms_p99'])}"
        rows.append(("depth frame age p50 / p99 (ms)", ages))
    for name, value in rows:
        t.add_row(name, value)
    return t


def sim_robot(
    terrain: str = typer.Option("flat", "--terrain", "-t", help=terrain_help()),
    level: int = typer.Option(0, "--level", help="Terrain difficulty level (0 easiest; -1 the hardest)."),
    ip: str = typer.Option("127.0.0.1", "--ip", help="Address of the SDK's simulator side."),
    physics_hz: float = typer.Option(
        500.0, "--physics-hz", callback=finite, min=50.0, max=4000.0, help="Physics and PD rate (Hz)."
    ),
    hoist: float = typer.Option(
        2.0,
        "--hoist",
        callback=finite,
        min=0.0,
        help="Seconds after the first command at which the hoist lets go (deploy-robot's --ramp).",
    ),
    noise: bool = typer.Option(True, "--noise/--no-noise", help="Training's sensor noise on state and IMU."),
    duration: float | None = typer.Option(
        None, "--duration", callback=finite, min=0.1, help="Wall seconds to run [default: until Ctrl-C]."
    ),
    seed: int = typer.Option(0, "--seed", min=0, max=2**32 - 1, help="Seed of the terrain and the noise."),
    reach: float | None = typer.Option(
        None,
        "--reach",
        callback=finite,
        min=0.0,
        max=100.0,
        metavar="M",
        help="Metres the robot may walk from the start in any direction and stay on the terrain "
        "under test, e.g. 6 for 10 s at 0.5 m/s [default: the 8 m training tile].",
    ),
    report: Path | None = typer.Option(
        None, "--report", metavar="FILE.json", help="Write the run's figures and base velocity log here."
    ),
    depth_to: str | None = typer.Option(
        None,
        "--depth-to",
        metavar="HOST:PORT",
        help="Render the depth camera at 30 Hz and send its frames here over UDP, for "
        "deploy-robot --depth udp[:PORT] (the SDK carries no images) [default: no camera].",
    ),
) -> None:
    """Our MuJoCo TRON1 as a simulated robot on the SDK's simulator side, for deploy-robot: PD on the
    received Kp, Kd, q, dq, tau at the physics rate, state and IMU published at it; the base hangs
    on a hoist until --hoist seconds after the first command.
    """
    from tron1cli.cli.common import check_outputs
    from tron1cli.deploy.depth_link import parse_address
    from tron1cli.deploy.sdk import Link
    from tron1cli.deploy.sim_robot import SimRobot, SimRobotConfig, write_report

    check_outputs(files=[("--report", report)])
    try:
        target = None if depth_to is None else parse_address(depth_to)
    except UsageError as e:
        fail(f"--depth-to: {e}", 2)
    cfg = SimRobotConfig(
        terrain=terrain,
        level=level,
        physics_hz=physics_hz,
        hoist_s=hoist,
        noise=noise,
        duration_s=duration,
        seed=seed,
        depth_to=target,
        reach_m=reach,
    )
    with err.status("building the world..."):
        try:
            sim = SimRobot(cfg, None)  # options checked before the SDK starts
        except UsageError as e:
            fail(str(e), 2)
    sim.link = Link(ip, sim=True)
    sim.link.subscribe_commands()
    note(
        f"sim-robot: TRON1 on {sim.terrain_type} level {level}, physics {physics_hz:g} Hz, hoisted; "
        f"SDK simulator side on {ip}"
        + (f"; depth frames to {target[0]}:{target[1]}" if target else "")
        + "; Ctrl-C stops"
    )
    rep = sim.run()
    if report is not None:
        write_report(rep, report)
    note(
        f"sim-robot stopped: {rep['sim_s']:.2f} s simulated in {rep['wall_s']:.2f} s "
        f"({rep['slips']} slips), {rep['commands_received']} commands received"
    )
