"""The deployment contract of a student policy: everything a runtime needs besides the weights.

One dict, built from a run's configuration and observation layout. It is stored in the metadata
of every exported ONNX file (each top-level key as one JSON-encoded metadata entry) and checked
against the env a policy is asked to drive, so a policy never silently meets observations laid
out differently from those it was trained on.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping

from tron1cli.env import robot, sensors
from tron1cli.env.observations import ObsLayout
from tron1cli.errors import Tron1Error

FORMAT = "tron1cli-policy"
VERSION = 1

#: ONNX graph inputs and outputs, in order (StudentPolicy.forward's signature).
INPUTS = ("history", "depth", "hidden")
OUTPUTS = ("action", "hidden_next", "h_hat", "e_hat")

#: who acts when a policy runs: the student (depth and history; the one an ONNX export holds) or,
#: from a training checkpoint only, the teacher (privileged state and the heightmap)
ACTORS = ("student", "teacher")


def layout_of(run_cfg) -> ObsLayout:
    """The observation layout a run's env has (same rule as Tron1Env)."""
    env = run_cfg.env
    return ObsLayout(
        history_len=env.history_len,
        gait_clock=env.gait.enabled,
        heightmap_dim=sensors.HeightScan().num_points if env.perception else 0,
        depth_hw=(sensors.DepthCamera().height, sensors.DepthCamera().width) if env.perception else None,
    )


def build_contract(run_cfg, gru_hidden: int, source: str) -> dict:
    """The contract of the student policy of ``run_cfg`` (a RunConfig), exported from ``source``."""
    env = run_cfg.env
    layout = layout_of(run_cfg)
    cam = sensors.DepthCamera()
    fx, fy, cx, cy = cam.intrinsics()
    return {
        "format": FORMAT,
        "version": VERSION,
        "source_checkpoint": source,
        "joint_names": list(robot.JOINT_NAMES),
        "default_pose_rad": [float(x) for x in robot.DEFAULT_POSE],
        "action_scale_rad": robot.ACTION_SCALE,
        "kp_nm_per_rad": robot.KP,
        "kd_nm_s_per_rad": robot.KD,
        "torque_limit_nm": robot.TORQUE_LIMIT,
        "sim_dt_s": env.sim_dt,
        "decimation": env.decimation,
        "policy_hz": 1.0 / env.policy_dt,
        "depth_hz": env.depth_hz,
        "history_len": env.history_len,
        "gru_hidden": gru_hidden,
        "obs_layout": layout.to_dict(),
        "gait_clock": {
            "enabled": env.gait.enabled,
            "inputs": ["sin(2 pi phase)", "cos(2 pi phase)", "frequency_hz"] if env.gait.enabled else [],
            "freq_hz": list(env.gait.freq_hz),
            "offset": env.gait.offset,
            "stance": env.gait.stance,
            "swing_fold_rad": [float(x) for x in env.gait.swing_fold_rad],
            "swing_fold_keep": float(env.gait.swing_fold_keep),
        },
        "depth": None
        if layout.depth_hw is None
        else {
            "rows": cam.height,
            "cols": cam.width,
            "range_m": [cam.near, cam.far],
            "fov_deg": [cam.fovx_deg, cam.fovy_deg],
            "intrinsics_px": {"fx": fx, "fy": fy, "cx": cx, "cy": cy},
            "camera_pos_base_m": [float(x) for x in robot.CAMERA_POS],
            "camera_pitch_down_deg": robot.CAMERA_PITCH_DEG,
        },
        "inputs": list(INPUTS),
        "outputs": list(OUTPUTS),
        "run_config": run_cfg.to_dict(),
    }


def to_metadata(contract: Mapping) -> dict[str, str]:
    """ONNX metadata_props: one JSON string per top-level key."""
    return {k: json.dumps(v) for k, v in contract.items()}


def from_metadata(props: Mapping[str, str], where: str) -> dict:
    """Inverse of :func:`to_metadata`; raises :class:`Tron1Error` when it is not our contract."""
    try:
        contract = {k: json.loads(v) for k, v in props.items()}
    except json.JSONDecodeError as e:
        raise Tron1Error(f"{where}: unreadable policy metadata ({e})") from e
    if contract.get("format") != FORMAT:
        raise Tron1Error(f"{where} is not a tron1 policy (no '{FORMAT}' contract in its metadata)")
    if contract.get("version") != VERSION:
        raise Tron1Error(
            f"{where}: policy contract version {contract.get('version')}, this tron1 reads {VERSION}"
        )
    missing = [k for k in ("obs_layout", "run_config", "joint_names", "gru_hidden") if k not in contract]
    if missing:
        raise Tron1Error(f"{where}: policy contract lacks {', '.join(missing)}")
    validate(contract, where)
    return contract


def _is_number(x) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def _is_count(x) -> bool:
    return isinstance(x, int) and not isinstance(x, bool) and x >= 1


def _kind(value) -> str:
    """How a JSON value reads in an error message."""
    from tron1cli.config.serde import _kind as kind

    return kind(value)


def _check_types(contract: Mapping, where: str) -> None:
    """Refuse a contract field of the wrong JSON kind (a number where a list belongs, a list
    where an object does), naming it: every reader of a contract relies on these forms."""

    def bad(key: str, want: str, value) -> Tron1Error:
        shown = repr(value) if len(repr(value)) <= 40 else repr(value)[:37] + "..."
        return Tron1Error(f"{where}: contract field {key} should be {want}, got {_kind(value)} ({shown})")

    def str_list(key: str, value) -> None:
        if not isinstance(value, list) or not all(isinstance(x, str) for x in value):
            raise bad(key, "a list of names", value)

    if "source_checkpoint" in contract and not isinstance(contract["source_checkpoint"], str):
        raise bad("source_checkpoint", "a string", contract["source_checkpoint"])
    str_list("joint_names", contract["joint_names"])
    for key in ("inputs", "outputs"):
        if key in contract:
            str_list(key, contract[key])
    for key in ("obs_layout", "run_config"):
        if not isinstance(contract[key], dict):
            raise bad(key, "an object", contract[key])
    layout = contract["obs_layout"]
    if "sizes" in layout and not isinstance(layout["sizes"], dict):
        raise bad("obs_layout.sizes", "an object", layout["sizes"])
    if "gait_clock" in layout and not isinstance(layout["gait_clock"], bool):
        raise bad("obs_layout.gait_clock", "true or false", layout["gait_clock"])
    if "gait_clock" in contract:
        gc = contract["gait_clock"]
        if not isinstance(gc, dict):
            raise bad("gait_clock", "an object", gc)
        if "freq_hz" in gc and not (
            isinstance(gc["freq_hz"], list) and all(_is_number(x) for x in gc["freq_hz"])
        ):
            raise bad("gait_clock.freq_hz", "a list of numbers", gc["freq_hz"])
        fold = gc.get("swing_fold_rad", [0.0, 0.0])
        if not (isinstance(fold, list) and len(fold) == 2 and all(_is_number(x) for x in fold)):
            raise bad("gait_clock.swing_fold_rad", "a list of two numbers", fold)
        keep = gc.get("swing_fold_keep", 0.0)
        if not (_is_number(keep) and 0.0 <= keep <= 1.0):
            raise bad("gait_clock.swing_fold_keep", "a number in [0, 1]", keep)
    depth = contract.get("depth")
    if depth is not None:
        if not isinstance(depth, dict):
            raise bad("depth", "an object or null", depth)
        for key in ("rows", "cols"):
            if not _is_count(depth.get(key)):
                raise bad(f"depth.{key}", "a positive integer", depth.get(key))
        for key in ("range_m", "fov_deg"):
            v = depth.get(key)
            if not (isinstance(v, list) and len(v) == 2 and all(_is_number(x) and x > 0 for x in v)):
                raise bad(f"depth.{key}", "a list of two positive numbers", v)


def validate(contract: Mapping, where: str) -> None:
    """Refuse (:class:`Tron1Error`) a contract whose fields cannot be meant: a field of the wrong
    JSON kind, a gain, rate or scale that is not a finite positive number, a count that is not a
    positive integer, a history length or width that disagrees with the observation layout."""
    _check_types(contract, where)
    positive = ("action_scale_rad", "kp_nm_per_rad", "kd_nm_s_per_rad", "torque_limit_nm")
    positive += ("sim_dt_s", "policy_hz", "depth_hz")
    for key in positive:
        if key in contract and not (_is_number(contract[key]) and contract[key] > 0):
            raise Tron1Error(
                f"{where}: contract field {key} = {contract[key]!r} is not a finite positive number"
            )
    if "default_pose_rad" in contract:
        pose = contract["default_pose_rad"]
        if (
            not isinstance(pose, list)
            or len(pose) != len(robot.JOINT_NAMES)
            or not all(map(_is_number, pose))
        ):
            raise Tron1Error(
                f"{where}: contract field default_pose_rad must hold {len(robot.JOINT_NAMES)} finite "
                f"numbers, got {contract['default_pose_rad']!r}"
            )
    for key in ("decimation", "history_len", "gru_hidden"):
        if key in contract and not _is_count(contract[key]):
            raise Tron1Error(f"{where}: contract field {key} = {contract[key]!r} is not a positive integer")
    layout = contract["obs_layout"]
    try:
        sizes = layout["sizes"]
        hist_len, proprio, history = layout["history_len"], sizes["proprio"], sizes["history"]
    except (KeyError, TypeError) as e:
        raise Tron1Error(f"{where}: contract field obs_layout is incomplete (no {e})") from None
    if not all(_is_count(x) for x in (hist_len, proprio, history)):
        raise Tron1Error(f"{where}: obs_layout sizes must be positive integers, got {sizes!r}")
    if "history_len" in contract and contract["history_len"] != hist_len:
        raise Tron1Error(
            f"{where}: contract history_len {contract['history_len']} disagrees with obs_layout's {hist_len}"
        )
    if history != hist_len * proprio:
        raise Tron1Error(
            f"{where}: contract history width {history} is not history_len {hist_len} x proprio {proprio}"
        )
    hw = layout.get("depth_hw")
    if hw is not None and (not isinstance(hw, list) or len(hw) != 2 or not all(_is_count(x) for x in hw)):
        raise Tron1Error(f"{where}: contract obs_layout depth_hw = {hw!r} is not two positive integers")


def check_matches_env(contract: Mapping, layout: ObsLayout, where: str) -> None:
    """Refuse an env whose observation layout differs from the policy's, with one clear line."""
    if list(contract["joint_names"]) != list(robot.JOINT_NAMES):
        raise Tron1Error(
            f"{where}: joint order {contract['joint_names']} differs from {list(robot.JOINT_NAMES)}"
        )
    want, have = contract["obs_layout"], layout.to_dict()
    if want == have:
        return
    if want.get("gait_clock") != have.get("gait_clock"):
        on = "with" if want.get("gait_clock") else "without"
        raise Tron1Error(
            f"{where} was trained {on} the gait prior; the env has it {'on' if have['gait_clock'] else 'off'}"
        )
    diff = [k for k in want if want.get(k) != have.get(k)]
    raise Tron1Error(f"{where}: observation layout differs from the env's ({', '.join(diff)})")
