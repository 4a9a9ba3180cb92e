"""Terrain curriculum: envs move up a difficulty level after walking far, down after not.

As in the legged-robot literature (Rudin et al., "learning to walk in minutes"): at the end of an
episode an env that walked farther than ``up_distance`` from its spawn point (the tile centre)
moves up one level; one that walked less than ``down_share`` of the distance its commands asked
for moves down one. Envs that pass the top level stay there. Each env keeps its terrain type,
assigned round-robin over the bank's types, and draws a new variant tile at every change.
"""

from __future__ import annotations

import numpy as np

from tron1cli.env.terrain import TerrainBank


def deal_types(num_envs: int, shares: np.ndarray) -> np.ndarray:
    """Terrain type index (num_envs,) per env in proportion to ``shares`` (one per type, >= 0, not all
    0), interleaved so that every run of consecutive envs (the teacher or the student block) gets
    close to the same proportions: env i takes the type furthest below its share of i + 1 envs
    (ties to the lower index). Equal shares give the round-robin ``i % len(shares)``."""
    w = np.asarray(shares, dtype=np.float64)
    w = w / w.sum()
    count = np.zeros(len(w))
    kind = np.empty(num_envs, dtype=np.int64)
    for i in range(num_envs):
        k = int(np.argmax((i + 1) * w - count + 1e-9 * (w > 0)))
        kind[i] = k
        count[k] += 1
    return kind


class TerrainCurriculum:
    """Per-env terrain type, level and tile index into ``bank``.

    up_distance: m walked from the tile centre to move up (default: 60 % of the half tile);
    down_share: fraction of the commanded distance below which an env moves down;
    max_init_level: envs start on levels 0..max_init_level;
    shares: share of the envs per bank type (None: equal shares).
    """

    def __init__(
        self,
        bank: TerrainBank,
        num_envs: int,
        rng: np.random.Generator,
        max_init_level: int = 0,
        up_distance: float | None = None,
        down_share: float = 0.5,
        enabled: bool = True,
        shares: np.ndarray | None = None,
    ) -> None:
        self.bank = bank
        self.rng = rng
        self.enabled = enabled
        self.num_levels = bank.cfg.num_levels
        self.up_distance = up_distance if up_distance is not None else 0.6 * bank.half_extent
        self.down_share = down_share
        self.kind = deal_types(num_envs, np.ones(len(bank.types)) if shares is None else shares)
        top = min(max_init_level, self.num_levels - 1)
        self.level = rng.integers(0, top + 1, num_envs)
        self.tile = self._draw_tiles(np.arange(num_envs))

    def _draw_tiles(self, ids: np.ndarray) -> np.ndarray:
        variant = self.rng.integers(0, self.bank.cfg.variants_per_level, len(ids))
        return np.asarray(self.bank.tile_index(self.kind[ids], self.level[ids], variant))

    def update(self, ids: np.ndarray, distance: np.ndarray, commanded: np.ndarray) -> np.ndarray:
        """Move envs ``ids`` whose episode ended; distance walked and commanded (m), (k,) each.

        Returns the ids whose tile changed (their worlds need the new height field).
        """
        if not self.enabled or len(ids) == 0:
            return np.empty(0, dtype=np.int64)
        up = distance > self.up_distance
        down = (distance < self.down_share * commanded) & ~up
        new = np.clip(self.level[ids] + up.astype(int) - down.astype(int), 0, self.num_levels - 1)
        changed = ids[new != self.level[ids]]
        self.level[ids] = new
        self.tile[changed] = self._draw_tiles(changed)
        return changed

    def pin(self, level: int) -> None:
        """Put every env on ``level`` (negative: from the top, -1 = hardest) and stop moving them."""
        if not -self.num_levels <= level < self.num_levels:
            raise ValueError(f"terrain level {level} outside 0..{self.num_levels - 1}")
        self.enabled = False
        self.level[:] = level % self.num_levels
        self.tile[:] = self._draw_tiles(np.arange(len(self.level)))

    def mean_levels(self) -> dict[str, float]:
        """Mean level per terrain type (0 = easiest, num_levels - 1 = the paper's hardest)."""
        return {
            t: float(self.level[self.kind == i].mean())
            for i, t in enumerate(self.bank.types)
            if np.any(self.kind == i)
        }
