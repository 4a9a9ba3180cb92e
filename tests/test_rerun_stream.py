"""The rerun stream: the --rerun option, and a short stairs run saved to .rrd and read back."""

from __future__ import annotations

import subprocess
import sys
import time

import numpy as np
import pytest

from tron1cli.env import robot
from tron1cli.viz.rerun_stream import (
    DEFAULT_CONNECT_URL,
    PATHS,
    RerunTarget,
    open_stream,
    parse_rerun_option,
    tile_height,
)


@pytest.mark.parametrize(
    "text, expected",
    [
        ("spawn", RerunTarget("spawn")),
        (" Spawn ", RerunTarget("spawn")),
        ("save=run.rrd", RerunTarget("save", "run.rrd")),
        ("save=out/dir/x.RRD", RerunTarget("save", "out/dir/x.RRD")),
        ("run.rrd", RerunTarget("save", "run.rrd")),
        ("connect", RerunTarget("connect", DEFAULT_CONNECT_URL)),
        (
            "connect=rerun+http://10.0.0.2:9876/proxy",
            RerunTarget("connect", "rerun+http://10.0.0.2:9876/proxy"),
        ),
        ("off", None),
        ("none", None),
        ("", None),
        (None, None),
    ],
)
def test_parse_good_options(text, expected):
    assert parse_rerun_option(text) == expected


@pytest.mark.parametrize(
    "text, match",
    [
        ("sav=x.rrd", "unknown target 'sav'"),
        ("viewer", "unknown target"),
        ("save", "save needs a file"),
        ("save=", "save needs a file"),
        ("save=x.txt", "must end in .rrd"),
        ("save=.rrd", "must end in .rrd"),
        ("spawn=9876", "spawn takes no value"),
        ("connect=", "connect= needs a URL"),
        ("connect=http://localhost:9876", "must start with rerun://"),
    ],
)
def test_parse_bad_options(text, match):
    with pytest.raises(ValueError, match=match) as info:
        parse_rerun_option(text)
    assert "--rerun" in str(info.value)


def test_unwritable_file_is_a_clean_error(tmp_path):
    from tron1cli.errors import Tron1Error

    blocker = tmp_path / "blocker"
    blocker.write_text("")  # a file where the directory should be
    with pytest.raises(Tron1Error, match="rerun save="):
        open_stream(f"save={blocker}/run.rrd")


def test_off_is_free():
    assert open_stream(None) is None and open_stream("off") is None
    code = (
        "import sys, tron1cli.viz.rerun_stream as m; m.parse_rerun_option('spawn'); "
        "print('rerun' in sys.modules)"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert res.stdout.strip() == "False"  # rerun itself is imported only when a stream opens


def _depth(row: dict) -> np.ndarray:
    fmt = row["DepthImage:format"][0]
    buf = bytes(row["DepthImage:buffer"][0])
    return np.frombuffer(buf, dtype=np.float32).reshape(fmt["height"], fmt["width"])


def _positions(row: dict, component: str = "Points3D:positions") -> np.ndarray:
    return np.asarray(row[component], dtype=np.float64)


def test_stairs_run_saved_and_read_back(tmp_path):
    from tron1cli.config.env import EnvConfig
    from tron1cli.env.core import Tron1Env
    from tron1cli.env.randomization import PushConfig
    from tron1cli.viz.rerun_stream import read_rrd

    pushes = PushConfig(enabled=True, interval_s=(0.1, 0.2), duration_s=0.1)  # several pushes in 0.6 s
    cfg = EnvConfig(num_envs=2, nthread=1, terrain="stairs", perception=True, curriculum=True, pushes=pushes)
    env = Tron1Env(cfg)
    env.reset()
    path = tmp_path / "sub" / "run.rrd"
    other_path = tmp_path / "other.rrd"
    stream = open_stream(f"save={path}")
    other = open_stream(RerunTarget("save", str(other_path)))  # a second stream must not interfere
    assert stream is not None and other is not None
    rng = np.random.default_rng(0)
    steps, cost = 30, []
    for k in range(steps):
        env.step(np.zeros((env.n, robot.NUM_JOINTS)))
        h_hat = env.obs["heightmap"] + rng.normal(0.0, 0.02, env.obs["heightmap"].shape).astype(np.float32)
        t0 = time.perf_counter()
        stream.log_step(env, 0, k, (k + 1) * env.policy_dt, extras={"h_hat": h_hat, "value": 1.5})
        cost.append(time.perf_counter() - t0)
        if k < 3:
            other.log_step(env, 1, k, (k + 1) * env.policy_dt)
    with pytest.raises(ValueError, match="h_hat"):
        other.log_step(env, 1, 3, 0.08, extras={"h_hat": np.zeros(10)})
    stream.close()
    other.close()
    print(f"log_step: first {cost[0] * 1e3:.1f} ms, then median {np.median(cost[1:]) * 1e3:.2f} ms")

    d = read_rrd(path)
    # the LIPM targets
    for p in (PATHS.com, PATHS.desired_com, PATHS.zmp, PATHS.plane):
        assert len(d[p]) == steps, p
    assert [r["step"] for r in d[PATHS.com]] == list(range(steps))
    assert np.allclose([r["sim_time"] for r in d[PATHS.com]], (np.arange(steps) + 1) * env.policy_dt)
    com = np.concatenate([_positions(r) for r in d[PATHS.com]])
    assert com.shape == (steps, 3) and np.all((com[:, 2] > 0.1) & (com[:, 2] < 1.2))
    p_hat = np.concatenate([_positions(r) for r in d[PATHS.desired_com]])
    assert np.all(np.linalg.norm(p_hat[:, :2] - com[:, :2], axis=1) < 1.0)
    assert np.all((p_hat[:, 2] > 0.1) & (p_hat[:, 2] < 1.2))
    zmp = np.concatenate([_positions(r) for r in d[PATHS.zmp]])
    assert np.all(np.abs(zmp[:, 2]) < 0.5) and np.all(np.abs(zmp[:, :2]) < env.bank.half_extent)
    # the last step matches the env
    assert np.allclose(com[-1], env.state.com_pos[0], atol=1e-5)
    assert np.allclose(p_hat[-1, :2], env.lipm.p_hat[0], atol=1e-5)

    # depth under a pinhole at the camera pose
    depth_rows = d[PATHS.depth]
    assert 1 <= len(depth_rows) <= steps
    for r in depth_rows:
        img = _depth(r)
        assert img.shape == (60, 80)
        assert np.all((img >= 0.0) & (img <= env.camera.far + 1e-6))
    assert np.array_equal(_depth(depth_rows[-1]), env.depth[0])
    assert len(d[PATHS.camera]) == steps and "Transform3D:mat3x3" in d[PATHS.camera][0]
    static = read_rrd(path, static=True)
    pinhole = static[PATHS.camera][0]
    assert pinhole["Pinhole:resolution"][0] == [80.0, 60.0]

    # both heightmaps as points around the robot and as 21 x 21 images, and their error
    base = env.state.base_pos[0]
    for which in ("true", "reconstructed", "error"):
        rows = d[PATHS.hm_points(which)]
        assert len(rows) == steps
        pts = _positions(rows[-1])
        assert pts.shape == (441, 3)
        assert np.all(np.abs(pts[:, :2] - base[:2]) < 0.75)  # within the 1 x 1 m yaw-aligned grid
        img_rows = d[PATHS.hm_image(which)]
        assert len(img_rows) == steps
        tensor = img_rows[-1]["Tensor:data"][0]
        assert tensor["shape"] == [21, 21] and len(tensor["buffer"]) == 441
    true_pts = _positions(d[PATHS.hm_points("true")][-1])  # in scan order, z = base z + height
    assert np.allclose(true_pts[:, 2] - base[2], env.obs["heightmap"][0], atol=1e-5)
    true_img = np.asarray(d[PATHS.hm_image("true")][-1]["Tensor:data"][0]["buffer"])
    assert np.all((true_img >= -1.0) & (true_img <= 1.0))
    err_img = np.asarray(d[PATHS.hm_image("error")][-1]["Tensor:data"][0]["buffer"])
    assert 0.0 < np.abs(err_img).mean() < 0.1

    # one world frame: depth pixels unprojected through the logged camera pose (pinhole, x right,
    # y up, looking along -z) land on the logged terrain mesh, and so do the foot contacts
    verts = np.asarray(d[PATHS.terrain][-1]["Mesh3D:vertex_positions"])
    heights = verts[:, 2].reshape(env.bank.R, env.bank.R)
    cam_rows = {r["step"]: r for r in d[PATHS.camera]}
    fx, fy, cx, cy = env.camera.intrinsics()
    for r in depth_rows[-3:]:
        cam = cam_rows[r["step"]]
        rot = np.asarray(cam["Transform3D:mat3x3"][0]).reshape(3, 3).T  # stored column-major
        pos = np.asarray(cam["Transform3D:translation"][0])
        img = _depth(r)
        v, u = np.nonzero(img > 0)
        z = img[v, u].astype(np.float64)
        p_cam = np.stack([(u + 0.5 - cx) / fx * z, -(v + 0.5 - cy) / fy * z, -z], axis=1)
        p_w = pos + p_cam @ rot.T
        ground = np.array([tile_height(heights, x, y, env.bank.res) for x, y in p_w[:, :2]])
        hit = img[v, u] < env.camera.far - 0.05
        assert np.median(np.abs(p_w[hit, 2] - ground[hit])) < 0.025  # depth noise ~1 cm
    for r in d[PATHS.contacts]:
        for x, y, z in _positions(r):
            assert abs(z - tile_height(heights, x, y, env.bank.res)) < 0.02

    # world: terrain mesh, robot bodies, contacts, arrows
    mesh = d[PATHS.terrain][0]
    r_ = env.bank.R
    assert len(mesh["Mesh3D:vertex_positions"]) == r_ * r_
    assert len(mesh["Mesh3D:triangle_indices"]) == 2 * (r_ - 1) ** 2
    for body in ("base", "thigh_L", "shank_R", "foot_L"):
        assert len(d[PATHS.body(body)]) == steps
    assert any(k.startswith(PATHS.body("base") + "/geom/") for k in static)
    for p in (PATHS.contacts, PATHS.contact_forces, PATHS.velocity_command, PATHS.velocity_actual):
        assert len(d[p]) == steps, p
    pushed = [len(r["Arrows3D:vectors"]) for r in d[PATHS.push]]
    assert 2 in pushed and 0 in pushed  # force and torque arrows while pushed, cleared after

    # scalars: every reward term and group, commands, tracking, actions, extras
    for term in env.reward_cfg.terms:
        vals = [r["Scalars:scalars"][0] for r in d[PATHS.scalar(PATHS.reward, term)]]
        assert len(vals) == steps and np.isfinite(vals).all(), term
    assert np.isclose(
        d[PATHS.scalar(PATHS.reward, "stable")][-1]["Scalars:scalars"][0], env.rewards.last_terms["stable"][0]
    )
    for g in env.reward_cfg.groups:
        assert len(d[PATHS.scalar(PATHS.reward_group, g)]) == steps
    for name in ("lin_vel_x", "lin_vel_y", "yaw_rate"):
        assert len(d[PATHS.scalar(PATHS.command, name)]) == steps
    for name in ("lin_vel_error", "com_error", "plane_z", "heightmap_mae"):
        assert len(d[PATHS.scalar(PATHS.tracking, name)]) == steps
    for j in robot.JOINT_NAMES:
        assert [r["Scalars:scalars"][0] for r in d[PATHS.scalar(PATHS.action, j)]] == [0.0] * steps
    assert d[PATHS.scalar(PATHS.extra, "value")][0]["Scalars:scalars"] == [1.5]

    # the second stream holds only its own three steps of env 1
    o = read_rrd(other_path)
    assert [r["step"] for r in o[PATHS.com]] == [0, 1, 2]  # the failed call logged nothing
    assert PATHS.hm_points("reconstructed") not in o
    env.close()


def testtile_height_matches_the_env_ground_height():
    from tron1cli.env.terrain import TerrainBank, ground_height

    bank = TerrainBank(("stairs_up", "rough"), seed=1)
    rng = np.random.default_rng(0)
    xy = rng.uniform(-4.5, 4.5, (50, 2))  # some beyond the tile: clamped to the edge
    tiles = rng.integers(0, bank.K, 50)
    want = ground_height(bank.heights, tiles, xy, bank.res)
    got = [tile_height(bank.heights[t], x, y, bank.res) for t, (x, y) in zip(tiles, xy, strict=True)]
    assert np.allclose(got, want, atol=1e-5)


def test_blind_flat_env_streams_without_perception(tmp_path):
    from tron1cli.config.env import EnvConfig
    from tron1cli.env.core import Tron1Env
    from tron1cli.viz.rerun_stream import read_rrd

    env = Tron1Env(EnvConfig(num_envs=1, nthread=1, terrain="flat"))
    env.reset()
    with open_stream(f"save={tmp_path / 'blind.rrd'}") as stream:
        for k in range(3):
            env.step(np.zeros((1, robot.NUM_JOINTS)))
            stream.log_step(env, 0, k, k * env.policy_dt, extras={"h_hat": np.zeros(441), "value": [0.5]})
    d = read_rrd(tmp_path / "blind.rrd")
    assert len(d[PATHS.com]) == 3 and len(d[PATHS.terrain]) == 1
    assert not any(k.startswith((PATHS.camera, PATHS.heightmap_points, PATHS.heightmap + "/")) for k in d)
    assert [r["Scalars:scalars"][0] for r in d[PATHS.scalar(PATHS.extra, "value")]] == [0.5] * 3
    env.close()
