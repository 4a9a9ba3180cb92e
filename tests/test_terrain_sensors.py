"""Terrain tiles, the bilinear ground lookup, the height scan and the depth camera."""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest

from tron1cli.env.sensors import (
    DepthCamera,
    HeightScan,
    add_depth_noise,
    depth_max_maps,
    render_depth,
)
from tron1cli.env.terrain import (
    TERRAIN_GROUPS,
    TERRAIN_TYPES,
    TerrainBank,
    TerrainConfig,
    difficulty,
    ground_height,
    make_tile,
    resolve_terrain,
)

CFG = TerrainConfig()
RES = CFG.resolution_m
R = CFG.R
COORDS = (np.arange(R) - 0.5 * (R - 1)) * RES
MID = R // 2  # a row/column just off the centre line (y or x = +res/2)


@pytest.fixture(scope="module")
def bank() -> TerrainBank:
    return TerrainBank(TERRAIN_TYPES, CFG, seed=3)


def top_tile(bank: TerrainBank, kind: str, level: int | None = None) -> np.ndarray:
    level = CFG.num_levels - 1 if level is None else level
    return bank.heights[bank.tile_index(bank.types.index(kind), level, 0)]


def test_groups_and_resolve():
    assert TERRAIN_GROUPS["mixed"] == TERRAIN_TYPES
    assert resolve_terrain("stairs") == ("stairs_up", "stairs_down")
    assert resolve_terrain("slopes") == ("slope_up", "slope_down")
    with pytest.raises(ValueError, match="'lava'"):
        resolve_terrain("lava")
    with pytest.raises(ValueError):
        TerrainBank(("flat", "lava"), CFG)


def test_config_validation_and_difficulty():
    assert R == 160
    with pytest.raises(ValueError):
        TerrainConfig(num_levels=0)
    with pytest.raises(ValueError):
        TerrainConfig(tile_size_m=-1.0)
    with pytest.raises(ValueError):
        TerrainConfig(resolution_m=0.03)  # 8 / 0.03 is not whole
    assert difficulty(0, 10) == 0.0
    assert difficulty(9, 10) == 1.0
    assert difficulty(0, 1) == 1.0
    with pytest.raises(ValueError):
        difficulty(10, 10)


def test_bank_layout(bank: TerrainBank):
    K = len(TERRAIN_TYPES) * CFG.num_levels * CFG.variants_per_level
    assert bank.heights.shape == (K, R, R) and bank.heights.dtype == np.float32
    assert bank.R == R and bank.res == RES and bank.size == CFG.tile_size_m
    k = bank.tile_index(4, 7, 1)
    assert bank.kind[k] == 4 and bank.level[k] == 7 and bank.variant[k] == 1
    assert np.array_equal(bank.tile_index(np.array([4, 0]), np.array([7, 0]), np.array([1, 0])), [k, 0])


@pytest.mark.parametrize("kind", TERRAIN_TYPES)
def test_every_type_builds(kind: str, bank: TerrainBank):
    centre = np.maximum(np.abs(COORDS)[None, :], np.abs(COORDS)[:, None]) <= 0.5 * CFG.platform_m
    for level in (0, CFG.num_levels - 1):
        h = top_tile(bank, kind, level)
        assert h.shape == (R, R) and h.dtype == np.float32
        assert np.all(np.isfinite(h))
        assert np.all(h[centre] == 0.0)
    tile = make_tile(kind, 1.0, CFG, np.random.default_rng(0))
    assert tile.shape == (R, R) and tile.dtype == np.float32


def test_stairs_steps_at_hardest(bank: TerrainBank):
    for kind, sign in (("stairs_up", 1.0), ("stairs_down", -1.0)):
        row = top_tile(bank, kind)[MID, MID:].astype(np.float64)  # walking along +x from the centre
        steps = np.diff(row)
        risers = steps[np.abs(steps) > 1e-6]
        assert len(risers) >= 10
        assert np.allclose(risers, sign * 0.20, atol=1e-3)
        edges = np.flatnonzero(np.abs(steps) > 1e-6)
        assert np.all(np.diff(edges) == round(CFG.step_tread_m / RES))
        assert COORDS[MID + edges[0]] < 0.5 * CFG.platform_m < COORDS[MID + edges[0] + 1]
    easy = top_tile(bank, "stairs_up", 0)[MID, MID:]
    assert np.allclose(np.diff(easy)[np.abs(np.diff(easy)) > 1e-6], 0.02, atol=1e-3)  # 2 cm at level 0


def test_slopes_rise_over_run(bank: TerrainBank):
    tan = CFG.slope_tan[1]
    inner, outer = 0.5 * CFG.platform_m, CFG.half_extent_m - CFG.border_m
    x = COORDS[MID:]
    on_slope = (x > inner + 0.05) & (x < outer - 0.05)
    for kind, sign in (("slope_up", 1.0), ("slope_down", -1.0)):
        h = top_tile(bank, kind)
        row = h[MID, MID:].astype(np.float64)
        gradient = np.polyfit(x[on_slope], row[on_slope], 1)[0]
        assert gradient == pytest.approx(sign * tan, abs=1e-3)
        assert row[-1] == pytest.approx(sign * tan * (outer - inner), abs=1e-3)  # the rim holds the top
        # the same along y and for walking in -x (a pyramid)
        assert np.allclose(h[MID:, MID], row, atol=1e-5)
        assert np.allclose(h[MID, : R - MID][::-1], row, atol=1e-5)
    assert np.all(top_tile(bank, "slope_up", 0) == 0.0)  # level 0: no slope


def test_rough_amplitude(bank: TerrainBank):
    for level in (0, CFG.num_levels // 2, CFG.num_levels - 1):
        lo, hi = CFG.rough_amp_m
        amp = lo + difficulty(level, CFG.num_levels) * (hi - lo)
        for variant in range(CFG.variants_per_level):
            h = bank.heights[bank.tile_index(TERRAIN_TYPES.index("rough"), level, variant)]
            assert np.abs(h).max() <= 0.5 * amp + 1e-6
            assert h.max() - h.min() >= 0.9 * amp
            assert abs(float(h.mean())) < 0.05 * amp


def test_discrete_blocks(bank: TerrainBank):
    h = top_tile(bank, "discrete")
    assert h.min() == 0.0 and h.max() <= CFG.block_height_m[1] + 1e-6
    assert h.max() > 0.25
    assert 0.05 < np.mean(h > 0) < 0.6
    assert top_tile(bank, "discrete", 0).max() <= CFG.block_height_m[0] + 1e-6


def test_same_seed_same_bank():
    a = TerrainBank(("rough", "discrete"), CFG, seed=7)
    b = TerrainBank(("rough", "discrete"), CFG, seed=7)
    c = TerrainBank(("rough", "discrete"), CFG, seed=8)
    assert np.array_equal(a.heights, b.heights)
    assert not np.array_equal(a.heights, c.heights)
    # a tile does not depend on the other types in the bank
    d = TerrainBank(("discrete",), CFG, seed=7)
    assert np.array_equal(d.heights, a.heights[a.kind == 1])


def test_ground_height_bilinear_and_clamped():
    h = np.zeros((2, 8, 8), dtype=np.float32)
    res = 0.5
    c = (np.arange(8) - 3.5) * res
    h[1] = (2.0 * c[None, :] + 0.5 * c[:, None]).astype(np.float32)  # a plane: bilinear is exact
    xy = np.array([[0.1, -0.3], [1.6, 0.2], [10.0, 0.0], [-10.0, -10.0]])
    got = ground_height(h, np.array([1, 1, 1, 1]), xy, res)
    xs = np.clip(xy[:, 0], c[0], c[-1])
    ys = np.clip(xy[:, 1], c[0], c[-1])
    assert np.allclose(got, 2.0 * xs + 0.5 * ys, atol=1e-5)
    assert np.all(ground_height(h, np.zeros(4, dtype=np.int32), xy, res) == 0.0)
    with pytest.raises(ValueError):
        ground_height(h, np.array([2]), np.zeros((1, 2)), res)


def step_bank() -> np.ndarray:
    h = np.zeros((2, R, R), dtype=np.float32)
    h[1][:, COORDS > 0.3] = 0.1  # a 0.1 m step up at x = +0.3 m on tile 1
    return h


def test_height_scan_reads_a_step():
    hs = HeightScan()
    off = hs.offsets()
    assert off.shape == (441, 2)
    assert (
        np.allclose(off[0], [-0.5, -0.5])
        and np.allclose(off[1], [-0.5, -0.45])
        and np.allclose(off[-1], [0.5, 0.5])
    )
    h = step_bank()
    bz = 0.8
    pos = np.array([[0.0, 0.0, bz]] * 3)
    yaw = np.array([0.0, math.pi / 2, 0.0])
    out = hs.scan(h, np.array([1, 1, 0]), pos, yaw, RES)
    assert out.shape == (3, 441) and out.dtype == np.float32
    ox, oy = off[:, 0], off[:, 1]
    # yaw 0: the step is ahead (base x > 0.3)
    assert np.allclose(out[0][ox > 0.31], 0.1 - bz, atol=1e-6)
    assert np.allclose(out[0][ox < 0.29], -bz, atol=1e-6)
    # yaw 90 deg: base forward is world +y, world +x is the base's right (base y < 0)
    assert np.allclose(out[1][oy < -0.31], 0.1 - bz, atol=1e-6)
    assert np.allclose(out[1][oy > -0.29], -bz, atol=1e-6)
    # flat tile: -base_z everywhere; clipping
    assert np.allclose(out[2], -bz)
    high = hs.scan(h, np.array([0]), np.array([[0.0, 0.0, 2.0]]), np.zeros(1), RES)
    assert np.all(high == -1.0)
    # the base displaced by 0.2 m along x sees the step 0.1 m ahead
    moved = hs.scan(h, np.array([1]), np.array([[0.2, 0.0, bz]]), np.zeros(1), RES)[0]
    assert np.allclose(moved[ox > 0.11], 0.1 - bz, atol=1e-6)
    assert np.allclose(moved[ox < 0.09], -bz, atol=1e-6)


def camera_rot(pitch: float, yaw: float = 0.0) -> np.ndarray:
    """MuJoCo-style camera matrix (columns x right, y up, z backward), pitched down by ``pitch``."""
    fwd = np.array([math.cos(pitch) * math.cos(yaw), math.cos(pitch) * math.sin(yaw), -math.sin(pitch)])
    right = np.array([math.sin(yaw), -math.cos(yaw), 0.0])
    back = -fwd
    up = np.cross(back, right)
    return np.stack([right, up, back], axis=1)


def test_intrinsics():
    cam = DepthCamera()
    fx, fy, cx, cy = cam.intrinsics()
    assert (cx, cy) == (40.0, 30.0)
    assert 2 * math.degrees(math.atan(cx / fx)) == pytest.approx(87.0)
    assert 2 * math.degrees(math.atan(cy / fy)) == pytest.approx(58.0)


@pytest.mark.parametrize("height,pitch_deg,yaw", [(0.5, 30.0, 0.0), (0.8, 15.0, 1.0), (0.35, 60.0, -2.5)])
def test_depth_on_flat_ground_matches_analytic(height, pitch_deg, yaw):
    cam = DepthCamera()
    pitch = math.radians(pitch_deg)
    rot = camera_rot(pitch, yaw)
    pos = np.array([0.7, -0.4, height])
    bank = np.zeros((1, R, R), dtype=np.float32)
    depth = render_depth(bank, np.zeros(1, dtype=np.int64), pos[None], rot[None], cam, RES)
    assert depth.shape == (1, cam.height, cam.width) and depth.dtype == np.float32
    fx, fy, cx, cy = cam.intrinsics()
    u, v = np.meshgrid(np.arange(cam.width), np.arange(cam.height))
    d_cam = np.stack([(u + 0.5 - cx) / fx, -(v + 0.5 - cy) / fy, -np.ones_like(u, dtype=float)], axis=-1)
    d_cam /= np.linalg.norm(d_cam, axis=-1, keepdims=True)
    d = d_cam @ rot.T
    axis = -rot[:, 2]
    with np.errstate(divide="ignore"):
        t = np.where(d[..., 2] < 0, height / -d[..., 2], np.inf)
    z = t * (d @ axis)
    got = depth[0]
    hit = (z >= cam.near) & (z <= cam.far - 1e-3)
    assert hit.sum() > 100
    assert np.max(np.abs(got[hit] - z[hit])) < 0.01
    sky = d[..., 2] >= 0
    assert sky.any() == (pitch_deg < 29.0)
    assert np.all(got[sky] == cam.far)
    assert np.all(got[z > cam.far + 1e-3] == cam.far)
    assert np.all(got[z < cam.near] == cam.near)


def test_depth_flat_blocks_solved_exactly_under_a_high_tile_top():
    """A 3 m tower in a far corner lifts the tile's top above the camera, so every ray marches
    the max-height blocks and ends in a flat block (the shortcut): still the analytic depth."""
    cam = DepthCamera(width=40, height=30)
    bank = np.full((1, R, R), 0.12, dtype=np.float32)
    bank[0, :6, :6] = 3.0
    maps = depth_max_maps(bank)
    assert maps.top[0] == 3.0 and maps.fine_min[0, 10, 10] == maps.fine[0, 10, 10] == np.float32(0.12)
    rot = camera_rot(math.radians(50.0), 0.7)
    pos = np.array([0.3, 0.2, 0.82])
    got = render_depth(bank, np.zeros(1, dtype=np.int64), pos[None], rot[None], cam, RES, max_maps=maps)[0]
    d = cam.pixel_rays() @ rot.T  # unit z-depth per unit t
    want = (pos[2] - np.float32(0.12)) / -d[..., 2]
    assert np.all(want < cam.far) and np.max(np.abs(got - want)) < 1e-5
    # a 1 cm bump in the middle of every 16 x 16 block: the large blocks are no longer flat,
    # most 4 x 4 ones still are; compare where the hit is 2 cells clear of any bump
    bank[0, 8::16, 8::16] = 0.13
    got = render_depth(bank, np.zeros(1, dtype=np.int64), pos[None], rot[None], cam, RES)[0]
    hit = (pos[None, None, :2] + want[..., None] * d[..., :2]) / RES + 0.5 * (R - 1)
    clear = np.all(np.abs(hit % 16 - 8) > 2.0, axis=-1)  # cells from the nearest bump
    assert clear.mean() > 0.4 and np.max(np.abs(got - want)[clear]) < 1e-5


def reference_depth(bank, k, pos, rot, cam, step=0.001):
    """Brute-force march in 1 mm steps of z-depth (slow, for a small camera only)."""
    rays = cam.pixel_rays().reshape(-1, 3) @ rot.T
    ts = np.arange(cam.near, cam.far + step, step)
    out = np.full(rays.shape[0], cam.far)
    for p, d in enumerate(rays):
        pts = pos + ts[:, None] * d
        g = ground_height(bank, np.full(len(ts), k), pts[:, :2], RES)
        below = np.flatnonzero(pts[:, 2] <= g)
        if below.size:
            out[p] = ts[below[0]]
    return out.reshape(cam.height, cam.width)


@pytest.mark.parametrize("kind", ["stairs_up", "stairs_down", "discrete", "rough", "slope_down"])
@pytest.mark.parametrize("pitch_deg,yaw,xy", [(35.0, 0.3, (0.2, 0.1)), (20.0, 2.0, (-2.5, 3.0))])
def test_depth_matches_brute_force(kind, pitch_deg, yaw, xy, bank: TerrainBank):
    cam = DepthCamera(width=16, height=12)
    k = bank.tile_index(bank.types.index(kind), CFG.num_levels - 1, 1)
    rot = camera_rot(math.radians(pitch_deg), yaw)
    pos = np.array([xy[0], xy[1], 0.7 + ground_height(bank.heights, [k], np.array([xy]), RES)[0]])
    got = render_depth(bank.heights, np.array([k]), pos[None], rot[None], cam, RES)[0]
    ref = reference_depth(bank.heights, k, pos, rot, cam)
    assert np.all((got >= cam.near) & (got <= cam.far))
    # the reference's first sample under the surface is at most one 1 mm step past the true hit;
    # it can also step over a corner that the ray clips by less than a millimetre, so it is never
    # earlier than the exact renderer, and agrees with it within a step almost everywhere
    assert np.all(got <= ref + 1e-4)
    assert np.mean(ref - got <= 1.1e-3) > 0.98


def test_depth_batches_envs_and_tiles(bank: TerrainBank):
    cam = DepthCamera()
    ks = np.array([bank.tile_index(4, 9, 0), 0, bank.tile_index(4, 9, 0)])
    rot = np.stack([camera_rot(0.5, 0.0)] * 3)
    pos = np.array([[0.0, 0.0, 0.6], [0.0, 0.0, 0.6], [0.0, 0.0, 0.6]])
    out = np.empty((3, cam.height, cam.width), dtype=np.float32)
    depth = render_depth(bank.heights, ks, pos, rot, cam, RES, out=out)
    assert depth is out
    assert np.array_equal(depth[0], depth[2])
    assert not np.array_equal(depth[0], depth[1])
    assert np.all(depth[0] <= depth[1] + 1e-6)  # rising stairs are nearer than flat ground


def test_max_maps_and_precomputed_maps(bank: TerrainBank):
    maps = depth_max_maps(bank.heights)
    k = bank.tile_index(bank.types.index("discrete"), CFG.num_levels - 1, 0)
    h = bank.heights[k]
    for by, bx in [(0, 0), (3, 7), (39, 39), (12, 0)]:
        block = h[4 * by : min(4 * by + 4, R - 1) + 1, 4 * bx : min(4 * bx + 4, R - 1) + 1]
        assert maps.fine[k, by, bx] == block.max()
    for cy, cx in [(0, 0), (9, 9), (4, 6)]:
        block = h[16 * cy : min(16 * cy + 16, R - 1) + 1, 16 * cx : min(16 * cx + 16, R - 1) + 1]
        assert maps.coarse[k, cy, cx] == block.max()
    assert maps.top[k] == h.max()
    cam = DepthCamera(width=20, height=15)
    ks = np.array([k, bank.tile_index(5, 9, 1), 0])
    pos = np.array([[0.3, 0.0, 0.7], [-1.0, 2.0, 0.6], [0.0, 0.0, 0.5]])
    rot = np.stack([camera_rot(0.6, 0.4), camera_rot(0.3, 2.0), camera_rot(0.5)])
    a = render_depth(bank.heights, ks, pos, rot, cam, RES)
    b = render_depth(bank.heights, ks, pos, rot, cam, RES, max_maps=maps)
    assert np.array_equal(a, b)


def test_depth_bad_pose_reads_far():
    cam = DepthCamera(width=8, height=6)
    bank = np.zeros((1, R, R), dtype=np.float32)
    pos = np.array([[np.nan, 0.0, 0.5], [0.0, 0.0, 0.5], [1e30, 0.0, 0.5]])
    rot = np.stack([camera_rot(0.5), camera_rot(0.5) * np.nan, camera_rot(0.5)])
    depth = render_depth(bank, np.zeros(3, dtype=np.int64), pos, rot, cam, RES)
    assert np.all(depth[:2] == cam.far)
    assert np.all(np.isfinite(depth))


def test_depth_noise():
    cam = DepthCamera()
    rng = np.random.default_rng(0)
    depth = rng.uniform(cam.near, cam.far, size=(64, cam.height, cam.width)).astype(np.float32)
    depth[0, 0, 0] = cam.near
    depth[0, 0, 1] = cam.far
    a = add_depth_noise(depth, cam, np.random.default_rng(5))
    b = add_depth_noise(depth, cam, np.random.default_rng(5))
    c = add_depth_noise(depth, cam, np.random.default_rng(6))
    assert a.shape == depth.shape and a.dtype == np.float32
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    holes = a == 0.0
    assert abs(holes.mean() - cam.hole_prob) < 0.003
    valid = a[~holes]
    assert valid.min() >= cam.near and valid.max() <= cam.far
    mid = ~holes & (depth > 0.5) & (depth < 2.5)  # away from the clip limits
    resid = (a - depth)[mid]
    expected = np.sqrt(np.mean((cam.noise_std_m + cam.noise_range_frac * depth[mid]) ** 2))
    assert resid.std() == pytest.approx(expected, rel=0.05)
    quiet = DepthCamera(noise_std_m=0.0, noise_range_frac=0.0, hole_prob=0.0)
    assert np.array_equal(add_depth_noise(depth, quiet, rng), depth)


def test_depth_noise_same_whatever_the_thread_count():
    cam = DepthCamera()
    depth = np.random.default_rng(1).uniform(0.3, 3.0, (8, cam.height, cam.width)).astype(np.float32)
    depth[0, :2] = 0.0  # no return stays no return
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = add_depth_noise(depth, cam, np.random.default_rng(9))
    finally:
        numba.set_num_threads(threads)
    assert np.array_equal(one, add_depth_noise(depth, cam, np.random.default_rng(9)))
    assert np.all(one[0, :2] == 0.0)


def test_type_seed_is_stable_and_tiles_depend_on_the_name_only(monkeypatch):
    from tron1cli.env import terrain

    # pinned: a salted hash() or a list position would change this between processes or edits
    assert terrain.type_seed("rough") == 772910865764258296
    assert terrain.type_seed("rough") != terrain.type_seed("rough ")
    cfg = TerrainConfig(num_levels=2, variants_per_level=1)
    before = TerrainBank(None, cfg, seed=5)

    def bumps(d: float, c: TerrainConfig, rng: np.random.Generator) -> np.ndarray:
        return rng.uniform(0.0, 0.05 * d, (c.R, c.R))

    # a new type registered in FRONT of every other one, and the old ones in reverse order
    monkeypatch.setattr(
        terrain,
        "TERRAINS",
        {"bumps": terrain.TerrainType(bumps, "bumps")} | dict(reversed(terrain.TERRAINS.items())),
    )
    after = TerrainBank(None, cfg, seed=5)
    assert after.types[0] == "bumps" and set(after.types) == set(before.types) | {"bumps"}
    for kind in before.types:
        for level in range(cfg.num_levels):
            a = before.heights[before.tile_index(before.types.index(kind), level, 0)]
            b = after.heights[after.tile_index(after.types.index(kind), level, 0)]
            assert np.array_equal(a, b), (kind, level)
    assert "bumps" in terrain.terrain_groups() and "bumps" in terrain.terrain_choices()
    assert np.any(after.heights[after.tile_index(0, 1, 0)] > 0)  # the new type's own tiles


@pytest.mark.parametrize("fov_delta_deg", [0.0, 1.0, -1.0])
def test_depth_of_a_wider_or_narrower_fov_follows_the_pinhole_model(fov_delta_deg: float):
    from tron1cli.env.sensors import fov_ray_scale

    # camera 1.5 m above a plane rising along x with slope 0.3, looking straight down (camera axes
    # = world axes): the ray of pixel column u meets the plane at z-depth H / (1 + s a k), with
    # a = (u + 0.5 - cx) / fx and k the field-of-view factor on the ray's x and y components
    cam = DepthCamera(noise_std_m=0.0, noise_range_frac=0.0, hole_prob=0.0)
    H, s = 1.5, 0.3
    bank = np.ascontiguousarray(np.broadcast_to(s * COORDS[None, :], (R, R))[None], dtype=np.float32)
    k = fov_ray_scale(cam, fov_delta_deg)
    img = render_depth(bank, [0], [[0.0, 0.0, H]], np.eye(3)[None], cam, RES, ray_scale=[k])
    fx, fy, cx, cy = cam.intrinsics()
    a = (np.arange(cam.width) + 0.5 - cx) / fx
    expected = H / (1.0 + s * a * k)
    assert np.allclose(img[0], expected[None, :], atol=1e-4)
    # k from the pinhole maths: tan of the half vertical FOV scales with it
    assert k == pytest.approx(
        math.tan(math.radians(29.0 + 0.5 * fov_delta_deg)) / math.tan(math.radians(29.0))
    )
    if fov_delta_deg:
        nominal = render_depth(bank, [0], [[0.0, 0.0, H]], np.eye(3)[None], cam, RES)
        edge = np.abs(img[0, :, 0] - nominal[0, :, 0]).min()
        assert edge > 5e-3  # the outer columns see the slope farther out (1 deg: about 1 cm here)


def test_camera_fov_randomisation_is_per_env_and_in_range():
    from tron1cli.config import EnvConfig, GaitConfig
    from tron1cli.env.core import Tron1Env
    from tron1cli.env.randomization import RandomizationConfig

    rand = RandomizationConfig(terms=("camera_fov",))
    env = Tron1Env(
        EnvConfig(
            num_envs=16,
            nthread=1,
            terrain="stairs",
            perception=True,
            randomization=rand,
            gait=GaitConfig(enabled=False),
            depth_from=0,
        )
    )
    env.reset()
    d = env.randomizer.camera_fov_delta
    assert np.all(np.abs(d) <= 1.0) and d.std() > 0.3
    k = env.depth_ray_scale(np.arange(16))
    cam = env.camera
    assert np.allclose(
        np.degrees(2 * np.arctan(k * math.tan(math.radians(0.5 * cam.fovy_deg)))), cam.fovy_deg + d
    )
    env.close()
