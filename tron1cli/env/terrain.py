"""Terrain tiles: a bank of small height fields, one per env, generated once.

Every env is its own small MuJoCo world standing on ONE terrain tile. A :class:`TerrainBank`
holds ``K = len(types) x num_levels x variants_per_level`` tiles as one float32 array
``heights`` of shape ``(K, R, R)`` (metres); each env keeps an index into it, the env core copies
the tile into that env's MuJoCo height field when the env changes tile, and the sensors
(:mod:`tron1cli.env.sensors`) read the bank directly with each env's tile index.

Conventions (shared by the generator, :func:`ground_height` and the sensors):

* A tile is indexed ``[row, col] = [i, j]`` with the row along world **y** and the column along
  world **x**, and is centred on the env's origin: sample ``(i, j)`` lies at
  ``x = (j - (R-1)/2) * res``, ``y = (i - (R-1)/2) * res``. With the defaults (8 m tile,
  5 cm resolution) ``R = 160`` and the outermost samples sit at +-3.975 m.
* Between samples the terrain is bilinear; points outside the tile take the height of the nearest
  edge sample (the rim is flat, so this is the natural continuation).
* The square centre platform (``platform_m`` a side) is flat at height **0** on every type, so
  the robot always spawns at ground z = 0 at the tile centre. Heights elsewhere may be negative
  (descending types), so the MuJoCo height field needs an offset; with MuJoCo's hfield
  ``size = (rx, ry, top, base)``, use ``rx = ry = (R-1)/2 * res`` so that hfield samples coincide
  with ours (MuJoCo's hfield data is row-major with row 0 at -y and column 0 at -x, as here;
  worth one mj_ray check when wiring it up). MuJoCo
  collides with two triangles per cell, the sensors with the bilinear surface: they differ by a
  few millimetres inside a cell, and a stair riser is a one-cell-wide (5 cm) ramp in both.
* ``border_m`` is a flat rim along the tile edge: the terrain stops changing there (it stays at
  whatever height it reached; 0 for rough and discrete tiles).

Terrain types are a registry (:data:`TERRAINS`, name -> generator function and CLI group;
:func:`register_terrain` adds one). Each type's tiles are seeded from its name by a stable hash
(:func:`type_seed`), so adding a type never changes another's tiles, and the CLI's terrain lists
come from the registry (:func:`terrain_choices`). The registered types and how ``difficulty``
d in [0, 1] scales them (d = 1 is the paper's hardest):

* ``flat``: all zeros.
* ``rough``: uniform noise on a coarse grid (``rough_cell_m``) interpolated bilinearly to the
  tile; the peak-to-peak amplitude ``A = lerp(rough_amp_m, d)`` (2 cm easiest, 15 cm hardest) and
  heights lie in ``[-A/2, A/2]`` (zero mean, so the platform is level with the average ground).
* ``slope_up`` / ``slope_down``: a square pyramid with slope ``tan = lerp(slope_tan, d)``
  (0.628 = 32.1 deg hardest). ``slope_up``: the centre is a pit and the ground RISES as the robot
  walks away from the centre; ``slope_down``: the centre is a summit and the ground FALLS.
* ``stairs_up`` / ``stairs_down``: pyramid stairs of concentric square rings ``step_tread_m``
  (0.30 m) deep, the first step at the platform edge, step height ``lerp(step_height_m, d)``
  (2 cm easiest, 20 cm hardest, 2 cm a level); ``_up`` climbs and ``_down`` descends walking
  away from the centre. The easiest step is 2 cm, not the 5 cm of Rudin et al.: a policy from
  flat ground lifts its feet about 2 cm, and with 5 cm at level 0 it learned to stop at the
  first riser instead of climbing (README, the perceptive campaign).
* ``discrete``: ``num_blocks`` random axis-aligned rectangular blocks, sides uniform in
  ``block_size_m`` (0.3-1.0 m), heights uniform in ``[block_height_m[0], lerp(block_height_m, d)]``
  (2-36 cm hardest). Blocks are POSITIVE only (obstacles standing on the ground at 0, overlapping
  blocks take the higher top): the ground the robot stands on stays at 0, as on the platform.
  Platform and rim are cleared to 0.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from dataclasses import dataclass

import numba
import numpy as np

MIXED = "mixed"  #: the CLI terrain name for every registered type, round-robin


def _check_range(name: str, rng: tuple[float, float]) -> None:
    lo, hi = rng
    if not (0.0 <= lo <= hi) or not np.isfinite(hi):
        raise ValueError(f"{name} must be a range 0 <= lo <= hi, got {rng!r}")


@dataclass(frozen=True)
class TerrainConfig:
    """Geometry of the terrain tiles. Lengths in metres; ranges are (easiest, hardest) values.

    tile_size_m: side of a square tile; ``R = tile_size_m / resolution_m`` samples a side.
    resolution_m: spacing of the height samples.
    num_levels: difficulty levels, level 0 easiest, level ``num_levels-1`` the paper's hardest.
    variants_per_level: random tiles generated per (type, level).
    platform_m: side of the flat square (height 0) at the centre where the robot spawns.
    border_m: width of the flat rim along the tile edge.
    rough_amp_m: peak-to-peak amplitude of the rough-terrain noise.
    rough_cell_m: spacing of the coarse noise grid that is interpolated onto the tile.
    slope_tan: tangent of the pyramid slope (0.628 = 32.1 deg).
    step_height_m: height of one stair step; step_tread_m: depth of one step.
    block_size_m: side lengths of discrete blocks; block_height_m: heights of discrete blocks
    (a block's height is uniform between the lower value and the level's upper value).
    num_blocks: discrete blocks per tile.
    """

    tile_size_m: float = 8.0
    resolution_m: float = 0.05
    num_levels: int = 10
    variants_per_level: int = 2
    platform_m: float = 1.0
    border_m: float = 0.25
    rough_amp_m: tuple[float, float] = (0.02, 0.15)
    rough_cell_m: float = 0.10
    slope_tan: tuple[float, float] = (0.0, 0.628)
    step_height_m: tuple[float, float] = (0.02, 0.20)
    step_tread_m: float = 0.30
    block_size_m: tuple[float, float] = (0.3, 1.0)
    block_height_m: tuple[float, float] = (0.02, 0.36)
    num_blocks: int = 40

    def __post_init__(self) -> None:
        for name in ("tile_size_m", "resolution_m", "rough_cell_m", "step_tread_m"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be positive, got {value!r}")
        n = self.tile_size_m / self.resolution_m
        if abs(n - round(n)) > 1e-6 * max(1.0, n) or round(n) < 8:
            raise ValueError(f"tile_size_m / resolution_m must be a whole number >= 8, got {n:g}")
        if self.num_levels < 1:
            raise ValueError(f"num_levels must be >= 1, got {self.num_levels!r}")
        if self.variants_per_level < 1:
            raise ValueError(f"variants_per_level must be >= 1, got {self.variants_per_level!r}")
        if self.num_blocks < 0:
            raise ValueError(f"num_blocks must be >= 0, got {self.num_blocks!r}")
        if self.platform_m < 0 or self.border_m < 0:
            raise ValueError("platform_m and border_m must be >= 0")
        if self.platform_m + 2 * self.border_m >= self.tile_size_m - 2 * self.resolution_m:
            raise ValueError("platform_m + 2 * border_m leaves no room for terrain on the tile")
        for name in ("rough_amp_m", "slope_tan", "step_height_m", "block_size_m", "block_height_m"):
            _check_range(name, getattr(self, name))
        if self.block_size_m[0] <= 0:
            raise ValueError("block_size_m must be positive")

    @property
    def R(self) -> int:
        """Height samples along each side of a tile."""
        return int(round(self.tile_size_m / self.resolution_m))

    @property
    def half_extent_m(self) -> float:
        """Coordinate of the outermost samples, ``(R-1)/2 * res`` (the MuJoCo hfield radius)."""
        return 0.5 * (self.R - 1) * self.resolution_m


def difficulty(level: int, num_levels: int) -> float:
    """Difficulty in [0, 1] of ``level`` (0 easiest); the top level is 1.0, the paper's hardest."""
    if num_levels < 1:
        raise ValueError(f"num_levels must be >= 1, got {num_levels!r}")
    if not 0 <= level < num_levels:
        raise ValueError(f"level must be in [0, {num_levels - 1}], got {level!r}")
    if num_levels == 1:
        return 1.0
    return float(level) / float(num_levels - 1)


def _lerp(rng: tuple[float, float], d: float) -> float:
    return float(rng[0] + d * (rng[1] - rng[0]))


def _coords(cfg: TerrainConfig) -> np.ndarray:
    return (np.arange(cfg.R) - 0.5 * (cfg.R - 1)) * cfg.resolution_m


# -- the terrain-type registry -----------------------------------------------------------------
#: A tile generator: (difficulty in [0, 1], config, generator) -> (R, R) heights in metres, index
#: [row=y, col=x], centred on (0, 0). :func:`make_tile` zeroes the centre platform afterwards.
TileGenerator = Callable[[float, "TerrainConfig", np.random.Generator], np.ndarray]


@dataclass(frozen=True)
class TerrainType:
    """One registered terrain type: its tile ``generate`` function and the CLI ``group`` it joins."""

    generate: TileGenerator
    group: str


#: name -> terrain type, in the order types appear in a bank and in the ``mixed`` group. A type's
#: tiles are seeded from its name (:func:`type_seed`), so adding, removing or reordering entries
#: never changes another type's tiles.
TERRAINS: dict[str, TerrainType] = {}


def register_terrain(name: str, group: str | None = None) -> Callable[[TileGenerator], TileGenerator]:
    """Decorator: register a tile generator as terrain type ``name`` in CLI group ``group``
    (default: its own name). A name registered twice raises ValueError."""

    def add(fn: TileGenerator) -> TileGenerator:
        if name in TERRAINS or name == MIXED:
            raise ValueError(f"terrain type {name!r} is already registered")
        TERRAINS[name] = TerrainType(fn, group or name)
        return fn

    return add


def type_seed(name: str) -> int:
    """A stable 64-bit seed word of a terrain type's name (the first 8 bytes of its SHA-256;
    unlike ``hash()``, the same in every process)."""
    return int.from_bytes(hashlib.sha256(name.encode("utf-8")).digest()[:8], "little")


def _rings(cfg: TerrainConfig) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Square-ring geometry of a tile: Chebyshev distance from the centre (R, R), distance walked
    outward from the platform edge (frozen in the rim), platform half side and rim start (m)."""
    c = _coords(cfg)
    d_inf = np.maximum(np.abs(c)[None, :], np.abs(c)[:, None])
    p = 0.5 * cfg.platform_m
    outer = cfg.half_extent_m - cfg.border_m
    return d_inf, np.clip(d_inf, p, outer) - p, p, outer


@register_terrain("flat")
def _flat(difficulty: float, cfg: TerrainConfig, rng: np.random.Generator) -> np.ndarray:
    return np.zeros((cfg.R, cfg.R))


@register_terrain("rough")
def _rough(difficulty: float, cfg: TerrainConfig, rng: np.random.Generator) -> np.ndarray:
    R, res = cfg.R, cfg.resolution_m
    d_inf, _, p, outer = _rings(cfg)
    amp = _lerp(cfg.rough_amp_m, difficulty)
    step = max(1, int(round(cfg.rough_cell_m / res)))
    nc = (R - 1) // step + 2
    coarse = rng.uniform(-0.5 * amp, 0.5 * amp, size=(nc, nc))
    f = np.arange(R) / step
    i0 = np.minimum(f.astype(np.int64), nc - 2)
    t = f - i0
    rows = coarse[i0] * (1 - t)[:, None] + coarse[i0 + 1] * t[:, None]  # interpolate along y
    h = rows[:, i0] * (1 - t)[None, :] + rows[:, i0 + 1] * t[None, :]  # then along x
    h[(d_inf <= p) | (d_inf > outer)] = 0.0
    return h


def _slope(sign: float) -> TileGenerator:
    def generate(difficulty: float, cfg: TerrainConfig, rng: np.random.Generator) -> np.ndarray:
        return sign * _lerp(cfg.slope_tan, difficulty) * _rings(cfg)[1]

    return generate


def riser_m(cfg: TerrainConfig, level: int) -> float:
    """Riser height (m) of the stairs of terrain ``level`` (0 easiest)."""
    return _lerp(cfg.step_height_m, difficulty(level, cfg.num_levels))


def _stairs(sign: float) -> TileGenerator:
    def generate(difficulty: float, cfg: TerrainConfig, rng: np.random.Generator) -> np.ndarray:
        run = _rings(cfg)[1]
        ring = np.where(run > 0, np.floor(run / cfg.step_tread_m) + 1, 0.0)
        return sign * _lerp(cfg.step_height_m, difficulty) * ring

    return generate


register_terrain("slope_up", "slopes")(_slope(1.0))
register_terrain("slope_down", "slopes")(_slope(-1.0))
register_terrain("stairs_up", "stairs")(_stairs(1.0))
register_terrain("stairs_down", "stairs")(_stairs(-1.0))


@register_terrain("discrete")
def _discrete(difficulty: float, cfg: TerrainConfig, rng: np.random.Generator) -> np.ndarray:
    R, res = cfg.R, cfg.resolution_m
    d_inf, _, p, outer = _rings(cfg)
    h = np.zeros((R, R))
    hmax = _lerp(cfg.block_height_m, difficulty)
    lo_size, hi_size = cfg.block_size_m
    c0 = _coords(cfg)[0]
    for _ in range(cfg.num_blocks):
        sx, sy = rng.uniform(lo_size, hi_size, size=2)
        cx, cy = rng.uniform(-outer, outer, size=2)
        top = rng.uniform(cfg.block_height_m[0], hmax)
        j0 = max(0, int(np.ceil((cx - 0.5 * sx - c0) / res)))
        j1 = min(R, int(np.floor((cx + 0.5 * sx - c0) / res)) + 1)
        i0 = max(0, int(np.ceil((cy - 0.5 * sy - c0) / res)))
        i1 = min(R, int(np.floor((cy + 0.5 * sy - c0) / res)) + 1)
        if i1 > i0 and j1 > j0:
            np.maximum(h[i0:i1, j0:j1], top, out=h[i0:i1, j0:j1])
    h[(d_inf <= p) | (d_inf > outer)] = 0.0
    return h


def terrain_groups() -> dict[str, tuple[str, ...]]:
    """CLI terrain names -> terrain types, derived from :data:`TERRAINS` (groups in registration
    order, then ``mixed``: every type)."""
    groups: dict[str, list[str]] = {}
    for name, t in TERRAINS.items():
        groups.setdefault(t.group, []).append(name)
    return {g: tuple(v) for g, v in groups.items()} | {MIXED: tuple(TERRAINS)}


def terrain_choices(extra: tuple[str, ...] = ()) -> str:
    """The CLI terrain names as help text, e.g. ``flat, rough, slopes, stairs, discrete or mixed
    (or one type: flat, rough, slope_up, ...)``."""
    names = [*terrain_groups(), *extra]
    types = [t for t in TERRAINS if t not in names]
    return ", ".join(names[:-1]) + " or " + names[-1] + f" (or one type: {', '.join(types)})"


#: The registered type names and the CLI groups, derived from the registry at import.
TERRAIN_TYPES: tuple[str, ...] = tuple(TERRAINS)
TERRAIN_GROUPS: dict[str, tuple[str, ...]] = terrain_groups()


def resolve_terrain(name: str) -> tuple[str, ...]:
    """Terrain types for a CLI terrain name: a group (a key of :func:`terrain_groups`) or one
    registered type (``stairs_up``: that type alone)."""
    groups = terrain_groups()
    if name in groups:
        return groups[name]
    if name in TERRAINS:
        return (name,)
    raise ValueError(
        f"unknown terrain {name!r}; choose from {', '.join(groups)} (or one type: {', '.join(TERRAINS)})"
    )


def make_tile(kind: str, difficulty: float, cfg: TerrainConfig, rng: np.random.Generator) -> np.ndarray:
    """One tile of terrain ``kind`` at ``difficulty`` in [0, 1]: float32 (R, R) heights in metres.

    Index ``[row=y, col=x]``, centred on (0, 0); the centre platform is at height 0 (see the module
    docstring). Only ``rough`` and ``discrete`` draw from ``rng``.
    """
    if kind not in TERRAINS:
        raise ValueError(f"unknown terrain type {kind!r}; choose from {', '.join(TERRAINS)}")
    if not 0.0 <= difficulty <= 1.0:
        raise ValueError(f"difficulty must be in [0, 1], got {difficulty!r}")
    h = np.array(TERRAINS[kind].generate(difficulty, cfg, rng), dtype=np.float64)
    if h.shape != (cfg.R, cfg.R):
        raise ValueError(f"terrain {kind!r} generated shape {h.shape}, expected {(cfg.R, cfg.R)}")
    h[_rings(cfg)[0] <= 0.5 * cfg.platform_m] = 0.0
    return np.ascontiguousarray(h, dtype=np.float32)


class TerrainBank:
    """All tiles for a set of terrain types: ``heights`` float32 (K, R, R) in metres.

    Tile ``k`` has type ``types[kind[k]]``, level ``level[k]`` and variant ``variant[k]``, ordered
    ``k = (kind_idx * num_levels + level) * variants_per_level + variant``. Every tile is drawn from
    its own generator seeded by (seed, :func:`type_seed` of the type's name, level, variant), so the
    same seed gives the same bank and a tile depends neither on which other types are in the bank
    nor on which types are registered. ``types`` None: every registered type.
    """

    def __init__(
        self,
        types: tuple[str, ...] | list[str] | None = None,
        cfg: TerrainConfig | None = None,
        seed: int = 0,
    ) -> None:
        types = tuple(TERRAINS) if types is None else tuple(types)
        if not types:
            raise ValueError("a terrain bank needs at least one terrain type")
        for t in types:
            if t not in TERRAINS:
                raise ValueError(f"unknown terrain type {t!r}; choose from {', '.join(TERRAINS)}")
        if len(set(types)) != len(types):
            raise ValueError(f"terrain types repeat: {types!r}")
        seed = int(seed)
        if seed < 0:
            raise ValueError(f"seed must be >= 0, got {seed}")
        cfg = TerrainConfig() if cfg is None else cfg
        self.types = types
        self.cfg = cfg
        self.seed = seed
        L, V = cfg.num_levels, cfg.variants_per_level
        K = len(types) * L * V
        self.kind = np.repeat(np.arange(len(types)), L * V)
        self.level = np.tile(np.repeat(np.arange(L), V), len(types))
        self.variant = np.tile(np.arange(V), len(types) * L)
        self.heights = np.empty((K, cfg.R, cfg.R), dtype=np.float32)
        for k in range(K):
            name = types[self.kind[k]]
            lvl = int(self.level[k])
            rng = np.random.default_rng([seed, type_seed(name), lvl, int(self.variant[k])])
            self.heights[k] = make_tile(name, difficulty(lvl, L), cfg, rng)

    @classmethod
    def from_name(cls, name: str, cfg: TerrainConfig | None = None, seed: int = 0) -> TerrainBank:
        """Bank for a CLI terrain name (a key of :data:`TERRAIN_GROUPS`)."""
        return cls(resolve_terrain(name), cfg, seed)

    @property
    def K(self) -> int:
        """Number of tiles."""
        return self.heights.shape[0]

    @property
    def R(self) -> int:
        """Samples along each side of a tile."""
        return self.cfg.R

    @property
    def res(self) -> float:
        """Sample spacing in metres."""
        return self.cfg.resolution_m

    @property
    def size(self) -> float:
        """Tile side in metres (``R * res``)."""
        return self.cfg.tile_size_m

    @property
    def half_extent(self) -> float:
        """Coordinate of the outermost samples, ``(R-1)/2 * res``."""
        return self.cfg.half_extent_m

    def tile_index(self, kind_idx, level, variant):
        """Bank index of (type index into ``types``, level, variant); scalars or arrays."""
        kind_idx, level, variant = np.asarray(kind_idx), np.asarray(level), np.asarray(variant)
        L, V = self.cfg.num_levels, self.cfg.variants_per_level
        if np.any((kind_idx < 0) | (kind_idx >= len(self.types))):
            raise ValueError(f"kind_idx out of range [0, {len(self.types) - 1}]")
        if np.any((level < 0) | (level >= L)):
            raise ValueError(f"level out of range [0, {L - 1}]")
        if np.any((variant < 0) | (variant >= V)):
            raise ValueError(f"variant out of range [0, {V - 1}]")
        idx = (kind_idx * L + level) * V + variant
        return int(idx) if idx.ndim == 0 else idx.astype(np.int64)


# ---------------------------------------------------------------------------------------------
# The one bilinear lookup, shared by ground_height, the height scan and the depth ray march.
# Note: numba's on-disk cache of a kernel in another module that inlines this function is keyed on
# that module's source only; after editing this function, delete the numba cache files
# (tron1cli/env/__pycache__/*.nbi and *.nbc).


@numba.njit(cache=True, nogil=True, inline="always")
def bilerp(flat, base, nr, nc, fx, fy):
    """Bilinear terrain height at SAMPLE coordinates (column fx, row fy) of one tile.

    ``flat`` is the bank raveled (``heights.reshape(-1)``, no copy), ``base = k * nr * nc`` the
    start of tile k, ``nr`` x ``nc`` its samples (flat indexing is markedly faster in numba than
    3-D indexing). World (x, y) maps to ``fx = x / res + (nc-1)/2``, ``fy = y / res + (nr-1)/2``.
    Coordinates outside the tile clamp to its edge (NaN clamps to sample 0: never out of bounds).
    """
    if not fx > 0.0:
        fx = 0.0
    elif fx > nc - 1.0:
        fx = nc - 1.0
    if not fy > 0.0:
        fy = 0.0
    elif fy > nr - 1.0:
        fy = nr - 1.0
    j = min(int(fx), nc - 2)
    i = min(int(fy), nr - 2)
    tx = fx - j
    ty = fy - i
    q = base + i * nc + j
    h00 = flat[q]
    h01 = flat[q + 1]
    h10 = flat[q + nc]
    h11 = flat[q + nc + 1]
    h0 = h00 + (h01 - h00) * tx
    h1 = h10 + (h11 - h10) * tx
    return h0 + (h1 - h0) * ty


@numba.njit(cache=True, parallel=True)
def _ground_height_kernel(flat, nr, nc, tile_idx, xy, inv_res, out):
    cx = 0.5 * (nc - 1)
    cy = 0.5 * (nr - 1)
    for n in numba.prange(tile_idx.shape[0]):
        out[n] = bilerp(flat, tile_idx[n] * nr * nc, nr, nc, xy[n, 0] * inv_res + cx, xy[n, 1] * inv_res + cy)


def as_bank(bank_heights) -> np.ndarray:
    """``bank_heights`` as a C-contiguous float32 (K, R, R) array (no copy when it already is one)."""
    h = np.ascontiguousarray(bank_heights, dtype=np.float32)
    if h.ndim != 3 or h.shape[1] < 2 or h.shape[2] < 2:
        raise ValueError(f"bank heights must be (K, R, R) with R >= 2, got shape {h.shape}")
    return h


def as_tile_idx(tile_idx, num_tiles: int) -> np.ndarray:
    """``tile_idx`` as a C-contiguous int64 (N,) array, checked against the bank size."""
    idx = np.ascontiguousarray(tile_idx, dtype=np.int64).reshape(-1)
    if idx.size and (idx.min() < 0 or idx.max() >= num_tiles):
        raise ValueError(f"tile index out of range [0, {num_tiles - 1}]")
    return idx


def ground_height(bank_heights, tile_idx, xy, res: float) -> np.ndarray:
    """Terrain height (N,) float64 at world points ``xy`` (N, 2) on tiles ``tile_idx`` (N,).

    Bilinear between samples; points outside the tile take the nearest edge value.
    """
    h = as_bank(bank_heights)
    idx = as_tile_idx(tile_idx, h.shape[0])
    pts = np.ascontiguousarray(xy, dtype=np.float64)
    if pts.shape != (idx.shape[0], 2):
        raise ValueError(f"xy must be ({idx.shape[0]}, 2), got {pts.shape}")
    out = np.empty(idx.shape[0], dtype=np.float64)
    _ground_height_kernel(h.reshape(-1), h.shape[1], h.shape[2], idx, pts, 1.0 / float(res), out)
    return out


@numba.njit(cache=True, parallel=True)
def _mean_height_kernel(flat, nr, nc, tile_idx, xy, inv_res, offsets, out):
    cx = 0.5 * (nc - 1)
    cy = 0.5 * (nr - 1)
    m = offsets.shape[0]
    for n in numba.prange(tile_idx.shape[0]):
        base = tile_idx[n] * nr * nc
        acc = 0.0
        for p in range(m):
            fx = (xy[n, 0] + offsets[p, 0]) * inv_res + cx
            fy = (xy[n, 1] + offsets[p, 1]) * inv_res + cy
            acc += bilerp(flat, base, nr, nc, fx, fy)
        out[n] = acc / m


def window_offsets(side_m: float, res: float) -> np.ndarray:
    """World-aligned square grid (k, 2) of offsets (m) over ``side_m`` x ``side_m``, centred on 0,
    spaced at most ``res``; side 0 gives the single point (0, 0)."""
    if not side_m >= 0.0:
        raise ValueError(f"window side must be >= 0, got {side_m!r}")
    k = int(np.ceil(side_m / res - 1e-9)) + 1
    s = np.linspace(-0.5 * side_m, 0.5 * side_m, k)
    gx, gy = np.meshgrid(s, s, indexing="ij")
    return np.ascontiguousarray(np.stack([gx.ravel(), gy.ravel()], axis=1))


#: unit directions of the ring :func:`highest_ground_height` samples around each point
_RING = np.array([[np.cos(a), np.sin(a)] for a in np.arange(8) * np.pi / 4])


def highest_ground_height(bank_heights, tile_idx, xy, res: float, reach_m: float) -> np.ndarray:
    """Highest terrain height (N,) float64 at the world points ``xy`` (N, 2) and at 8 points around
    each, ``reach_m`` (m) away in every 45-degree direction: a foot within ``reach_m`` of a riser
    sees the tread above it. ``reach_m`` 0 is :func:`ground_height` at ``xy``."""
    top = ground_height(bank_heights, tile_idx, xy, res)
    if reach_m > 0.0:
        for d in _RING:
            np.maximum(top, ground_height(bank_heights, tile_idx, xy + reach_m * d, res), out=top)
    return top


def mean_ground_height(bank_heights, tile_idx, xy, res: float, side_m: float) -> np.ndarray:
    """Terrain height (N,) float64 averaged over a world-aligned ``side_m`` square around each of
    the world points ``xy`` (N, 2) (m), sampled at the bank resolution ``res`` (m) or finer.

    The mean of the continuous bilinear surface at points that move with ``xy``: continuous in
    ``xy``, and over a staircase a ramp instead of steps (over a window of whole treads, exactly
    the staircase's mean slope). ``side_m`` 0 is :func:`ground_height` at ``xy``.
    """
    h = as_bank(bank_heights)
    idx = as_tile_idx(tile_idx, h.shape[0])
    pts = np.ascontiguousarray(xy, dtype=np.float64)
    if pts.shape != (idx.shape[0], 2):
        raise ValueError(f"xy must be ({idx.shape[0]}, 2), got {pts.shape}")
    out = np.empty(idx.shape[0], dtype=np.float64)
    offsets = window_offsets(side_m, float(res))
    _mean_height_kernel(h.reshape(-1), h.shape[1], h.shape[2], idx, pts, 1.0 / float(res), offsets, out)
    return out
