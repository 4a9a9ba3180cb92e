"""Exteroceptive sensors computed from the terrain bank: the teacher's height scan and the
student's depth image. Pure numpy + numba; no MuJoCo.

Both read the bank of tiles (:class:`tron1cli.env.terrain.TerrainBank`) directly with each env's
tile index; positions are in the env's own world frame (the tile centred on the origin, z up).
Both use the one bilinear lookup of :mod:`tron1cli.env.terrain`.

Height scan (teacher, paper Table I): 21 x 21 = 441 points over 1.0 x 1.0 m around the base,
aligned with the base's yaw (roll and pitch ignored). Value = terrain height at the point MINUS
the base height, clipped to [-1, 1] m: flat ground under a base at 0.8 m reads -0.8 everywhere,
a 0.1 m step ahead reads -0.7 there.

Depth image (student, paper: 80 x 60 from a front-mounted RealSense D435i, 87 x 58 deg FOV):
a compiled ray march over the height field. Values are z-depth along the camera's optical axis
(what the D435i reports), not the length of the ray, in metres; terrain nearer than ``near``
reads ``near``, and pixels whose ray meets no terrain within z-depth ``far`` (sky, beyond range)
read ``far``. Only the terrain is rendered: the robot's own legs and body do NOT appear in the
image (a deliberate simplification; the camera is pitched forward, so the real legs are rarely
in view). :func:`add_depth_noise` then adds sensor noise and holes (0 = no return, as the D435i
reports).

Camera pose: position (N, 3) and rotation (N, 3, 3) in the world, the rotation's columns being
the camera's x (right), y (up) and z (BACKWARD) axes, as in MuJoCo (a camera looks along its -z;
``data.cam_xmat.reshape(-1, 3, 3)`` is exactly this matrix). The ray through pixel (u, v)
(u = column from the left, v = row from the top) has the camera-frame direction
``((u + 0.5 - cx) / fx, -(v + 0.5 - cy) / fy, -1)``, normalised.

Numba kernels compile on first use (a few seconds each, cached on disk afterwards); call
:func:`warmup` to pay that cost up front.
"""

from __future__ import annotations

import functools
import math
import statistics
import time
from dataclasses import dataclass
from typing import NamedTuple

import numba
import numpy as np

from tron1cli.env.terrain import as_bank, as_tile_idx, bilerp, ground_height

# Sides (in cells) of the square blocks of the two max-height maps the depth ray march skips over.
_BLOCK = 4
_BLOCK2 = 16
#: the least z-depth (m) a block jump must gain; a block the ray would cross in less is walked
#: cell by cell: through a block corner, rounding can put the ray back into the block it left
#: and two jumps of no length would alternate until the march gave up (a float32 march did)
_MIN_JUMP_M = 1e-5


# ---------------------------------------------------------------------------------------------
# Height scan


@dataclass(frozen=True)
class HeightScan:
    """Yaw-aligned grid of terrain heights around the base (teacher's h_t).

    num_x, num_y: points along the base's x (forward) and y (left); size_x_m, size_y_m: extent of
    the grid in metres, centred on the base; clip_lo_m, clip_hi_m: clip of (terrain - base z).
    """

    num_x: int = 21
    num_y: int = 21
    size_x_m: float = 1.0
    size_y_m: float = 1.0
    clip_lo_m: float = -1.0
    clip_hi_m: float = 1.0

    def __post_init__(self) -> None:
        if self.num_x < 1 or self.num_y < 1:
            raise ValueError("num_x and num_y must be >= 1")
        if self.size_x_m < 0 or self.size_y_m < 0:
            raise ValueError("size_x_m and size_y_m must be >= 0")
        if not self.clip_lo_m < self.clip_hi_m:
            raise ValueError("clip_lo_m must be < clip_hi_m")

    @property
    def num_points(self) -> int:
        """Points per scan (441 by default)."""
        return self.num_x * self.num_y

    def offsets(self) -> np.ndarray:
        """Scan points (num_x * num_y, 2) in the base yaw frame, metres.

        Row-major with x the slow index: point ``k = i * num_y + j`` is at
        ``x_i`` (rear to front, -size_x/2 .. +size_x/2) and ``y_j`` (right to left); a scan
        reshaped to (N, num_x, num_y) is indexed ``[env, x index, y index]``.
        """
        xs = np.linspace(-0.5 * self.size_x_m, 0.5 * self.size_x_m, self.num_x)
        ys = np.linspace(-0.5 * self.size_y_m, 0.5 * self.size_y_m, self.num_y)
        gx, gy = np.meshgrid(xs, ys, indexing="ij")
        return np.stack([gx.ravel(), gy.ravel()], axis=1)

    def scan(self, bank_heights, tile_idx, base_pos, yaw, res: float, out=None) -> np.ndarray:
        """Heights (N, num_points) float32: clip(terrain(point) - base_z, clip_lo_m, clip_hi_m).

        bank_heights (K, R, R); tile_idx (N,); base_pos (N, 3) world; yaw (N,) rad; res in metres.
        """
        h = as_bank(bank_heights)
        idx = as_tile_idx(tile_idx, h.shape[0])
        n = idx.shape[0]
        pos = np.ascontiguousarray(base_pos, dtype=np.float64)
        yw = np.ascontiguousarray(yaw, dtype=np.float64).reshape(-1)
        if pos.shape != (n, 3) or yw.shape != (n,):
            raise ValueError(f"base_pos must be ({n}, 3) and yaw ({n},), got {pos.shape}, {yw.shape}")
        if out is None:
            out = np.empty((n, self.num_points), dtype=np.float32)
        elif out.shape != (n, self.num_points) or out.dtype != np.float32 or not out.flags.c_contiguous:
            raise ValueError(f"out must be C-contiguous float32 ({n}, {self.num_points})")
        _scan_kernel(
            h.reshape(-1),
            h.shape[1],
            h.shape[2],
            idx,
            pos,
            yw,
            self.offsets(),
            1.0 / float(res),
            float(self.clip_lo_m),
            float(self.clip_hi_m),
            out,
        )
        return out


@numba.njit(cache=True, parallel=True)
def _scan_kernel(flat, nr, nc, tile_idx, base_pos, yaw, offsets, inv_res, lo, hi, out):
    m = offsets.shape[0]
    cx = 0.5 * (nc - 1)
    cy = 0.5 * (nr - 1)
    for n in numba.prange(tile_idx.shape[0]):
        base = tile_idx[n] * nr * nc
        c = math.cos(yaw[n]) * inv_res
        s = math.sin(yaw[n]) * inv_res
        bx = base_pos[n, 0] * inv_res + cx
        by = base_pos[n, 1] * inv_res + cy
        bz = base_pos[n, 2]
        for p in range(m):
            ox = offsets[p, 0]
            oy = offsets[p, 1]
            v = bilerp(flat, base, nr, nc, bx + c * ox - s * oy, by + s * ox + c * oy) - bz
            out[n, p] = min(max(v, lo), hi)


# ---------------------------------------------------------------------------------------------
# Depth camera


@dataclass(frozen=True)
class DepthCamera:
    """Pinhole depth camera after the RealSense D435i as used in the paper.

    width, height: pixels; fovx_deg, fovy_deg: full fields of view; near, far: z-depth range in
    metres; noise_std_m + noise_range_frac * depth: std of the Gaussian noise in metres;
    hole_prob: probability that a pixel reads 0 (no return).
    """

    width: int = 80
    height: int = 60
    fovx_deg: float = 87.0
    fovy_deg: float = 58.0
    near: float = 0.3
    far: float = 3.0
    noise_std_m: float = 0.01
    noise_range_frac: float = 0.005
    hole_prob: float = 0.01

    def __post_init__(self) -> None:
        if self.width < 1 or self.height < 1:
            raise ValueError("width and height must be >= 1")
        if not (0 < self.fovx_deg < 180 and 0 < self.fovy_deg < 180):
            raise ValueError("fields of view must be in (0, 180) deg")
        if not 0 < self.near < self.far:
            raise ValueError("need 0 < near < far")
        if self.noise_std_m < 0 or self.noise_range_frac < 0:
            raise ValueError("noise must be >= 0")
        if not 0 <= self.hole_prob <= 1:
            raise ValueError("hole_prob must be in [0, 1]")

    def intrinsics(self) -> tuple[float, float, float, float]:
        """(fx, fy, cx, cy) in pixels; the principal point is the image centre."""
        fx = 0.5 * self.width / math.tan(math.radians(0.5 * self.fovx_deg))
        fy = 0.5 * self.height / math.tan(math.radians(0.5 * self.fovy_deg))
        return fx, fy, 0.5 * self.width, 0.5 * self.height

    def pixel_rays(self) -> np.ndarray:
        """Camera-frame ray directions (height, width, 3) scaled to camera z = -1 (unit z-depth).

        Normalise them to get unit rays; a point at parameter t along such a ray has z-depth t.
        """
        fx, fy, cx, cy = self.intrinsics()
        u = (np.arange(self.width) + 0.5 - cx) / fx
        v = -(np.arange(self.height) + 0.5 - cy) / fy
        rays = np.empty((self.height, self.width, 3))
        rays[..., 0] = u[None, :]
        rays[..., 1] = v[:, None]
        rays[..., 2] = -1.0
        return rays


def fov_ray_scale(cam: DepthCamera, fovy_delta_deg) -> np.ndarray:
    """Factor on the rays' x and y components (and 1 / factor on fx, fy) that widens the vertical
    field of view by ``fovy_delta_deg`` (deg, scalar or (N,)): a focal-length change, so the
    horizontal field of view follows with the same factor on tan(fov / 2)."""
    half = np.radians(0.5 * cam.fovy_deg)
    return np.tan(half + np.radians(0.5 * np.asarray(fovy_delta_deg, dtype=np.float64))) / np.tan(half)


@numba.njit(cache=True, parallel=True)
def _max_maps_kernel(flat, nr, nc, tiles, fine, coarse, fine_min):
    """Max (and min) height over blocks of ``_BLOCK`` cells (samples on the block's edges
    included) into ``fine`` (``fine_min``), and max over groups of ``_BLOCK2 // _BLOCK`` fine
    blocks (the ranges nest) into ``coarse``."""
    nby = fine.shape[1]
    nbx = fine.shape[2]
    f = _BLOCK2 // _BLOCK
    for u in numba.prange(tiles.shape[0]):
        base = tiles[u] * nr * nc
        rowmax = np.empty((nr, nbx), dtype=np.float32)
        rowmin = np.empty((nr, nbx), dtype=np.float32)
        for i in range(nr):
            for bx in range(nbx):
                j0 = bx * _BLOCK
                hi = flat[base + i * nc + j0]
                lo = hi
                for j in range(j0 + 1, min(j0 + _BLOCK, nc - 1) + 1):
                    hi = max(hi, flat[base + i * nc + j])
                    lo = min(lo, flat[base + i * nc + j])
                rowmax[i, bx] = hi
                rowmin[i, bx] = lo
        for by in range(nby):
            i0 = by * _BLOCK
            for bx in range(nbx):
                hi = rowmax[i0, bx]
                lo = rowmin[i0, bx]
                for i in range(i0 + 1, min(i0 + _BLOCK, nr - 1) + 1):
                    hi = max(hi, rowmax[i, bx])
                    lo = min(lo, rowmin[i, bx])
                fine[u, by, bx] = hi
                fine_min[u, by, bx] = lo
        for cy in range(coarse.shape[1]):
            for cx in range(coarse.shape[2]):
                hi = fine[u, cy * f, cx * f]
                for by in range(cy * f, min(cy * f + f, nby)):
                    for bx in range(cx * f, min(cx * f + f, nbx)):
                        hi = max(hi, fine[u, by, bx])
                coarse[u, cy, cx] = hi


class DepthMaxMaps(NamedTuple):
    """Max- and min-height maps that let the depth ray march skip terrain the ray passes above
    and solve flat blocks (min == max: a tread, a block top, flat ground) in one step.

    fine: (T, nby, nbx) float32 max over blocks of 4 x 4 cells; coarse: (T, ., .) max over 16 x 16
    cells; top: (T,) float64 highest sample of each tile; fine_min: minima of the 4 x 4 blocks.
    Built by :func:`depth_max_maps`.
    """

    fine: np.ndarray
    coarse: np.ndarray
    top: np.ndarray
    fine_min: np.ndarray


def _max_maps(h: np.ndarray, tiles: np.ndarray) -> DepthMaxMaps:
    nr, nc = h.shape[1], h.shape[2]
    nby, nbx = -(-(nr - 1) // _BLOCK), -(-(nc - 1) // _BLOCK)
    f = _BLOCK2 // _BLOCK
    fine = np.empty((tiles.shape[0], nby, nbx), dtype=np.float32)
    coarse = np.empty((tiles.shape[0], -(-nby // f), -(-nbx // f)), dtype=np.float32)
    fine_min = np.empty_like(fine)
    tiles = np.ascontiguousarray(tiles, dtype=np.int64)
    _max_maps_kernel(h.reshape(-1), nr, nc, tiles, fine, coarse, fine_min)
    top = coarse.reshape(tiles.shape[0], -1).max(axis=1).astype(np.float64)
    return DepthMaxMaps(fine, coarse, top, fine_min)


def depth_max_maps(bank_heights) -> DepthMaxMaps:
    """Max- and min-height maps of every tile of a bank, for ``render_depth(..., max_maps=...)``.

    Build them once with the bank (about 30 us a tile) instead of per call for the tiles in use.
    """
    h = as_bank(bank_heights)
    return _max_maps(h, np.arange(h.shape[0], dtype=np.int64))


@numba.njit(cache=True, nogil=True, inline="always")
def _axis_enter(f0, g, ig, t, n):
    """Cell index along one axis at ray parameter t (-1 and n-1 are the unbounded outside cells),
    and the parameter at which the ray crosses into the next cell (inf if never); ig = 1 / g."""
    f = min(max(f0 + g * t, -1.0), float(n))
    j = int(math.floor(f))
    if j > n - 1:
        j = n - 1
    tn = math.inf
    if g > 0.0 and j < n - 1:
        tn = (j + 1 - f0) * ig
    elif g < 0.0 and j >= 0:
        tn = (j - f0) * ig
    return j, tn


@numba.njit(cache=True, nogil=True, inline="always")
def _block_exit(i, j, block, fx0, fy0, gx, gy, igx, igy, nr, nc, far):
    """Ray parameter at which the ray leaves the block of ``block`` x ``block`` cells holding cell (i, j)."""
    bi = i // block
    bj = j // block
    tb = far
    if gx > 0.0:
        tb = min(tb, (min((bj + 1) * block, nc - 1) - fx0) * igx)
    elif gx < 0.0:
        tb = min(tb, (bj * block - fx0) * igx)
    if gy > 0.0:
        tb = min(tb, (min((bi + 1) * block, nr - 1) - fy0) * igy)
    elif gy < 0.0:
        tb = min(tb, (bi * block - fy0) * igy)
    return tb


@numba.njit(cache=True, nogil=True, inline="always")
def _ray_start(flat, base, nr, nc, top, fx0, fy0, oz, gx, gy, dz, near, far):
    """Cheap start of a ray (inlined): the z-depth from which to march, or a final answer.

    Returns ``(t, done)``: with ``done`` true, ``t`` is the depth (a miss, an absurd pose, or a hit
    right where the ray sinks to the tile's highest sample ``top``, the usual case on flat
    ground); otherwise the ray is above the surface at ``t`` and :func:`_march` takes over.
    """
    ok = abs(fx0) < 1e9 and abs(fy0) < 1e9 and abs(oz) < 1e9
    if not (ok and abs(gx) < 1e9 and abs(gy) < 1e9 and abs(dz) < 1e9):
        return far, True  # NaN or absurd pose: report no return rather than index out of bounds
    t = near
    if dz >= 0.0:
        if oz + t * dz > top:
            return far, True  # above every sample and not descending
    else:
        t_top = (top - oz) / dz  # the ray is above every sample until it sinks to the highest one
        if t_top > t:
            t = t_top
    if t >= far:
        return far, True
    if oz + t * dz <= bilerp(flat, base, nr, nc, fx0 + gx * t, fy0 + gy * t):
        return t, True  # a hit right there, or a surface nearer than near
    return t, False


@numba.njit(cache=True, nogil=True, inline="always")
def _flat_hit(t, tb, za, dz, hi, lo):
    """Ray parameter at which a ray at height ``za`` at ``t`` and descending ``dz`` per unit t
    meets a flat block (``lo == hi``) of height ``hi``; inf if the block is not flat or the ray
    does not descend. The caller accepts it only within the block (<= ``tb``)."""
    if lo != hi or not dz < 0.0:
        return math.inf
    return max(t + (za - hi) / -dz, t)


# inlined into the render kernel: as a called function it cost a third of the render time
@numba.njit(cache=True, nogil=True, inline="always")
def _march(flat, base, nr, nc, bmax, bmax2, bmin, u, t, fx0, fy0, oz, gx, gy, dz, near, far):
    """z-depth of the first hit of the ray with the bilinear surface of one tile (see ``bilerp``).

    The ray is given in sample coordinates: column ``fx0 + gx t``, row ``fy0 + gy t``, height
    ``oz + dz t``, with ``t`` the z-depth, and starts at ``t`` above the surface. It walks the grid
    cell by cell (a 2-D DDA); in each cell the bilinear patch along the ray is a quadratic in t,
    solved exactly. A block of ``_BLOCK`` cells a side whose highest sample lies below the ray
    is crossed in one jump, and then so is the block of ``_BLOCK2`` cells holding it if the ray
    passes above that too (the large block is never looked at while the ray is inside a small
    block it cannot pass: near the hit, where rays spend their steps); a flat small block (lowest
    sample = highest) that the ray sinks into is solved in one step, the surface there being the
    plane z = height. (The block sides are module constants so that numba compiles the divisions
    by them into shifts.) ``bmax``, ``bmax2``, ``bmin``: the maps ``fine``, ``coarse`` and
    ``fine_min`` of :class:`DepthMaxMaps`.
    """
    inf = math.inf
    sx = 1 if gx > 0.0 else -1
    sy = 1 if gy > 0.0 else -1
    igx = 1.0 / gx if gx != 0.0 else inf
    igy = 1.0 / gy if gy != 0.0 else inf
    dtx = abs(igx)
    dty = abs(igy)
    j, tx = _axis_enter(fx0, gx, igx, t, nc)
    i, ty = _axis_enter(fy0, gy, igy, t, nr)
    nbx = bmax.shape[2]
    nbx2 = bmax2.shape[2]
    last_b = -1
    last_b2 = -1
    for _ in range(4 * (nr + nc) + 16):  # a ray crosses at most nr + nc cells; bounded for safety
        te = min(tx, ty, far)
        za = oz + t * dz
        if 0 <= i < nr - 1 and 0 <= j < nc - 1:
            b = (i // _BLOCK) * nbx + j // _BLOCK
            if b != last_b:
                last_b = b
                tb = _block_exit(i, j, _BLOCK, fx0, fy0, gx, gy, igx, igy, nr, nc, far)
                hi = bmax[u, i // _BLOCK, j // _BLOCK]
                if tb > t + _MIN_JUMP_M and min(za, oz + tb * dz) > hi:
                    # above this small block; the large one holding it can only be passed if so
                    b2 = (i // _BLOCK2) * nbx2 + j // _BLOCK2
                    if b2 != last_b2:
                        last_b2 = b2
                        tb2 = _block_exit(i, j, _BLOCK2, fx0, fy0, gx, gy, igx, igy, nr, nc, far)
                        if min(za, oz + tb2 * dz) > bmax2[u, i // _BLOCK2, j // _BLOCK2]:
                            tb = max(tb, tb2)
                    if tb >= far:
                        return far
                    t = tb
                    j, tx = _axis_enter(fx0, gx, igx, t, nc)
                    i, ty = _axis_enter(fy0, gy, igy, t, nr)
                    continue
                th = _flat_hit(t, tb, za, dz, hi, bmin[u, i // _BLOCK, j // _BLOCK])
                if th <= tb:
                    return min(max(th, near), far)
        # the four samples of this cell (outside the tile the edge samples repeat)
        jl = min(max(j, 0), nc - 1)
        jr = min(max(j + 1, 0), nc - 1)
        il = min(max(i, 0), nr - 1)
        ir = min(max(i + 1, 0), nr - 1)
        h00 = flat[base + il * nc + jl]
        h01 = flat[base + il * nc + jr]
        h10 = flat[base + ir * nc + jl]
        h11 = flat[base + ir * nc + jr]
        zb = oz + te * dz
        if min(za, zb) <= max(max(h00, h01), max(h10, h11)):
            # f(s) = ray z - surface z at t + s, a quadratic A s^2 + B s + C on [0, L]
            s0 = fx0 + gx * t - j
            r0 = fy0 + gy * t - i
            ex = h01 - h00
            ey = h10 - h00
            exy = h11 - h10 - ex
            c0 = za - (h00 + ex * s0 + ey * r0 + exy * s0 * r0)
            if c0 <= 0.0:
                return min(max(t, near), far)
            b1 = dz - ex * gx - ey * gy - exy * (s0 * gy + r0 * gx)
            a2 = -exy * gx * gy
            span = te - t
            hit = c0 + span * (b1 + span * a2) <= 0.0
            if not hit and a2 > 0.0:  # a dip below zero strictly inside the cell
                sv = -b1 / (2.0 * a2)
                hit = 0.0 < sv < span and c0 + sv * (b1 + sv * a2) <= 0.0
            if hit:
                # first root of the quadratic, in the form that is stable also as a2 -> 0
                den = -b1 + math.sqrt(max(b1 * b1 - 4.0 * a2 * c0, 0.0))
                s = 2.0 * c0 / den if den > 0.0 else span
                s = min(max(s, 0.0), span)
                return min(max(t + s, near), far)
        if te >= far:
            return far
        t = te
        if tx <= ty:
            j += sx
            tx = tx + dtx if (0 <= j < nc - 1) else inf
        else:
            i += sy
            ty = ty + dty if (0 <= i < nr - 1) else inf
    return far


@numba.njit(cache=True, parallel=True)
def _render_kernel(
    flat, nr, nc, tile_idx, uidx, bmax, bmax2, bmin, tops, cam_pos, cam_rot, rays, scale, near, far, res, out
):
    n_env = tile_idx.shape[0]
    hgt = rays.shape[0]
    wid = rays.shape[1]
    inv_res = 1.0 / res
    cx = 0.5 * (nc - 1)
    cy = 0.5 * (nr - 1)
    for job in numba.prange(n_env * hgt):
        n = job // hgt
        v = job - n * hgt
        base = tile_idx[n] * nr * nc
        u = uidx[n]
        fx0 = cam_pos[n, 0] * inv_res + cx
        fy0 = cam_pos[n, 1] * inv_res + cy
        oz = cam_pos[n, 2]
        top = tops[u]
        r00 = cam_rot[n, 0, 0]
        r01 = cam_rot[n, 0, 1]
        r02 = cam_rot[n, 0, 2]
        r10 = cam_rot[n, 1, 0]
        r11 = cam_rot[n, 1, 1]
        r12 = cam_rot[n, 1, 2]
        r20 = cam_rot[n, 2, 0]
        r21 = cam_rot[n, 2, 1]
        r22 = cam_rot[n, 2, 2]
        k = scale[n]
        for c in range(wid):
            a = rays[v, c, 0] * k
            b = rays[v, c, 1] * k
            # world direction = R @ (a, b, -1): unit z-depth per unit t
            gx = (r00 * a + r01 * b - r02) * inv_res
            gy = (r10 * a + r11 * b - r12) * inv_res
            dz = r20 * a + r21 * b - r22
            t, done = _ray_start(flat, base, nr, nc, top, fx0, fy0, oz, gx, gy, dz, near, far)
            if not done:
                t = _march(flat, base, nr, nc, bmax, bmax2, bmin, u, t, fx0, fy0, oz, gx, gy, dz, near, far)
            out[n, v, c] = t


def camera_poses(n: int, cam_pos, cam_rot) -> tuple[np.ndarray, np.ndarray]:
    """``cam_pos`` (n, 3) and ``cam_rot`` (n, 3, 3) as C-contiguous float64; ValueError otherwise."""
    pos = np.ascontiguousarray(cam_pos, dtype=np.float64)
    rot = np.ascontiguousarray(cam_rot, dtype=np.float64)
    if pos.shape != (n, 3) or rot.shape != (n, 3, 3):
        raise ValueError(f"cam_pos must be ({n}, 3) and cam_rot ({n}, 3, 3), got {pos.shape}, {rot.shape}")
    return pos, rot


def ray_scales(n: int, ray_scale) -> np.ndarray:
    """(n,) float64 ray factors (see :func:`render_depth`): ones for None; ValueError for another
    count or a factor <= 0."""
    if ray_scale is None:
        return np.ones(n)
    scale = np.ascontiguousarray(ray_scale, dtype=np.float64).reshape(-1)
    if scale.shape != (n,) or not np.all(scale > 0):
        raise ValueError(f"ray_scale must be ({n},) positive factors, got shape {scale.shape}")
    return scale


def check_max_maps(maps: DepthMaxMaps, num_tiles: int) -> DepthMaxMaps:
    """``maps`` if built for a bank of ``num_tiles`` tiles; ValueError otherwise."""
    if maps.fine.shape[0] != num_tiles or maps.top.shape != (num_tiles,):
        raise ValueError("max_maps were not built for this bank (use depth_max_maps(bank_heights))")
    return maps


def render_depth(
    bank_heights,
    tile_idx,
    cam_pos,
    cam_rot,
    cam: DepthCamera,
    res: float,
    out=None,
    *,
    max_maps: DepthMaxMaps | None = None,
    ray_scale: np.ndarray | None = None,
) -> np.ndarray:
    """Depth images (N, cam.height, cam.width) float32 of the terrain, z-depth in metres.

    bank_heights (K, R, R); tile_idx (N,); cam_pos (N, 3) world; cam_rot (N, 3, 3) world, columns
    = camera x (right), y (up), z (backward) as in MuJoCo; res: bank sample spacing in metres.
    ray_scale (N,): per-env factor on both focal lengths' inverses, i.e. on the ray's x and y
    components (> 1: a wider field of view; see :func:`fov_ray_scale`); None: the nominal camera.
    Values in [near, far]; no hit within ``far`` reads ``far``. The robot itself is not rendered.

    Ray march: each ray walks the height-field grid cell by cell from z-depth ``near`` (or from
    where it sinks to the tile's highest sample), and in each cell it meets the bilinear patch
    where a quadratic in the z-depth vanishes, solved in closed form: the hit is exact, not a
    step-and-refine estimate (stepping res/2 and bisecting missed 2-3 % of the pixels, by 5-30 cm,
    where rays graze stair edges and rough bumps). Blocks of 16 x 16 and of 4 x 4 cells that the
    ray passes above are crossed in one jump, by max-height maps: pass ``max_maps`` built once by
    :func:`depth_max_maps` for the whole bank, or leave it None to build them per call for the
    tiles in use (about 30 us a tile).
    """
    h = as_bank(bank_heights)
    idx = as_tile_idx(tile_idx, h.shape[0])
    n = idx.shape[0]
    pos, rot = camera_poses(n, cam_pos, cam_rot)
    shape = (n, cam.height, cam.width)
    if out is None:
        out = np.empty(shape, dtype=np.float32)
    elif out.shape != shape or out.dtype != np.float32 or not out.flags.c_contiguous:
        raise ValueError(f"out must be C-contiguous float32 {shape}")
    if n == 0:
        return out
    scale = ray_scales(n, ray_scale)
    if max_maps is None:
        tiles, uidx = np.unique(idx, return_inverse=True)
        maps = _max_maps(h, tiles)
        uidx = np.ascontiguousarray(uidx.reshape(-1), dtype=np.int64)
    else:
        maps = check_max_maps(max_maps, h.shape[0])
        uidx = idx
    _render_kernel(
        h.reshape(-1),
        h.shape[1],
        h.shape[2],
        idx,
        uidx,
        maps.fine,
        maps.coarse,
        maps.fine_min,
        maps.top,
        pos,
        rot,
        cam.pixel_rays(),
        scale,
        float(cam.near),
        float(cam.far),
        float(res),
        out,
    )
    return out


# Noise: a counter-based generator (a SplitMix64 hash of a per-call key and the pixel's index),
# so that the noise is parallel, independent of the thread count and fixed by the caller's rng.
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
_NORMAL_BITS = 16


@functools.cache
def _normal_table() -> np.ndarray:
    """Standard normal quantiles at (k + 0.5) / 2^16, k = 0 .. 2^16 - 1: a Gaussian quantised to
    65,536 equally likely levels (tails at +/-4.3 sigma), indexed by 16 random bits."""
    n = 1 << _NORMAL_BITS
    inv = statistics.NormalDist().inv_cdf
    return np.array([inv((k + 0.5) / n) for k in range(n)], dtype=np.float32)


@numba.njit(cache=True, parallel=True)
def _noise_kernel(d, out, key, std, frac, hole_below, near, far, table):
    mask = np.uint64((1 << _NORMAL_BITS) - 1)
    for i in numba.prange(d.shape[0]):
        x = key + np.uint64(i) * _GOLDEN
        x = (x ^ (x >> np.uint64(30))) * _MIX1
        x = (x ^ (x >> np.uint64(27))) * _MIX2
        x = x ^ (x >> np.uint64(31))
        v = d[i]
        if v <= 0.0 or (x >> np.uint64(32)) < hole_below:
            out[i] = 0.0
        else:
            z = table[np.int64(x & mask)]
            out[i] = min(max(v + z * (std + frac * v), near), far)


def add_depth_noise(depth, cam: DepthCamera, rng: np.random.Generator, out=None) -> np.ndarray:
    """Noisy copy of ``depth`` (N, H, W): Gaussian noise, then clip to [near, far], then holes.

    Noise std = ``noise_std_m + noise_range_frac * depth``; each pixel becomes a hole (0, no return)
    with probability ``hole_prob``; pixels already 0 stay 0. Compiled and parallel: every pixel
    draws from a hash of its index and one 64-bit key taken from ``rng`` per call, so the result
    is fixed by ``rng``'s state whatever the thread count. The Gaussian is quantised to 2^16
    equally likely levels (tails cut at 4.3 sigma); hole probabilities resolve to 2^-32.
    ``out``: a C-contiguous float32 array of the same shape to write into (``depth`` itself works).
    """
    d = np.ascontiguousarray(depth, dtype=np.float32)
    if out is None:
        out = np.empty_like(d)
    elif out.shape != d.shape or out.dtype != np.float32 or not out.flags.c_contiguous:
        raise ValueError(f"out must be C-contiguous float32 {d.shape}")
    if cam.noise_std_m == 0.0 and cam.noise_range_frac == 0.0 and cam.hole_prob == 0.0:
        out[...] = d
        return out
    key = np.uint64(rng.integers(0, 2**63, dtype=np.int64))
    hole_below = np.uint64(min(round(cam.hole_prob * 2.0**32), 2**32))
    _noise_kernel(
        d.reshape(-1),
        out.reshape(-1),
        key,
        np.float32(cam.noise_std_m),
        np.float32(cam.noise_range_frac),
        hole_below,
        np.float32(cam.near),
        np.float32(cam.far),
        _normal_table(),
    )
    return out


def warmup() -> float:
    """Compile (or load from numba's cache) every sensor kernel on tiny inputs; returns seconds."""
    start = time.perf_counter()
    bank = np.zeros((1, 8, 8), dtype=np.float32)
    idx = np.zeros(1, dtype=np.int64)
    ground_height(bank, idx, np.zeros((1, 2)), 0.05)
    HeightScan(num_x=2, num_y=2).scan(bank, idx, np.array([[0.0, 0.0, 0.5]]), np.zeros(1), 0.05)
    cam = DepthCamera(width=4, height=3)
    img = render_depth(bank, idx, np.array([[0.0, 0.0, 0.5]]), np.eye(3)[None], cam, 0.05)
    add_depth_noise(img, cam, np.random.default_rng(0))
    return time.perf_counter() - start
