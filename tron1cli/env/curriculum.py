"""Terrain curriculum: which difficulty level each env walks, moved at the end of its episodes.

Each env keeps its terrain type (dealt over the bank's types by their shares) and draws a new
variant tile whenever its level changes. How the level moves is the rule (:data:`RULES`):

- ``distance`` (the legged-robot literature's, Rudin et al.): an env that walked farther than
  ``up_distance`` from its spawn point (the tile centre) moves up one level; one that walked less
  than ``down_share`` of the distance its commands asked for moves down one.
- ``falls``: up as ``distance``; down only after a fall, so a slow survivor keeps its level.
- ``uniform``: no curriculum; every episode draws its level uniformly from all levels.

Levels stay within floor..num_levels - 1, the floor per terrain type (0 unless set).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

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


@dataclass(frozen=True)
class EpisodeEnds:
    """What the rules see of the episodes that ended, (k,) each: distance walked from the spawn
    point and distance commanded (m), and whether the episode ended in a fall."""

    distance: np.ndarray
    commanded: np.ndarray
    fell: np.ndarray


def _distance(cur: TerrainCurriculum, level: np.ndarray, e: EpisodeEnds) -> np.ndarray:
    up = e.distance > cur.up_distance
    down = (e.distance < cur.down_share * e.commanded) & ~up
    return level + up.astype(int) - down.astype(int)


def _falls(cur: TerrainCurriculum, level: np.ndarray, e: EpisodeEnds) -> np.ndarray:
    up = e.distance > cur.up_distance
    return level + up.astype(int) - (e.fell & ~up).astype(int)


def _uniform(cur: TerrainCurriculum, level: np.ndarray, e: EpisodeEnds) -> np.ndarray:
    return cur.rng.integers(0, cur.num_levels, len(level))


#: curriculum rule name -> the next level (k,) of the envs whose episodes ended (before clipping)
RULES: dict[str, Callable[[TerrainCurriculum, np.ndarray, EpisodeEnds], np.ndarray]] = {
    "distance": _distance,
    "falls": _falls,
    "uniform": _uniform,
}


def rule_named(name: str) -> Callable[[TerrainCurriculum, np.ndarray, EpisodeEnds], np.ndarray]:
    """The rule of :data:`RULES` called ``name``; ValueError, one line, for any other name."""
    if name not in RULES:
        raise ValueError(f"unknown curriculum rule '{name}'; choose from {', '.join(RULES)}")
    return RULES[name]


class TerrainCurriculum:
    """Per-env terrain type, level and tile index into ``bank``.

    up_distance: m walked from the tile centre to move up (default: 60 % of the half tile);
    down_share: fraction of the commanded distance below which an env moves down;
    max_init_level: envs start on levels 0..max_init_level;
    shares: share of the envs per bank type (None: equal shares);
    rule: how levels move (a key of :data:`RULES`);
    floors: lowest level per bank type (None: 0 for every type); envs start and stay at or above it.
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
        rule: str = "distance",
        floors: list[int] | np.ndarray | None = None,
    ) -> None:
        self.rule = rule_named(rule)
        self.bank = bank
        self.rng = rng
        self.enabled = enabled
        self.num_levels = bank.cfg.num_levels
        self.up_distance = up_distance if up_distance is not None else 0.6 * bank.half_extent
        self.down_share = down_share
        self.kind = deal_types(num_envs, np.ones(len(bank.types)) if shares is None else shares)
        top = min(max_init_level, self.num_levels - 1)
        per_type = np.zeros(len(bank.types), dtype=np.int64) if floors is None else np.asarray(floors)
        self.floor = per_type[self.kind]
        self.level = np.maximum(rng.integers(0, top + 1, num_envs), self.floor)
        self.tile = self._draw_tiles(np.arange(num_envs))

    def _draw_tiles(self, ids: np.ndarray) -> np.ndarray:
        variant = self.rng.integers(0, self.bank.cfg.variants_per_level, len(ids))
        return np.asarray(self.bank.tile_index(self.kind[ids], self.level[ids], variant))

    def update(self, ids: np.ndarray, ends: EpisodeEnds) -> np.ndarray:
        """Move envs ``ids`` (k,) whose episode ended as ``ends`` says, by the rule.

        Returns the ids whose tile changed (their worlds need the new height field).
        """
        if not self.enabled or len(ids) == 0:
            return np.empty(0, dtype=np.int64)
        new = np.clip(self.rule(self, self.level[ids], ends), self.floor[ids], self.num_levels - 1)
        changed = ids[new != self.level[ids]]
        self.level[ids] = new
        self.tile[changed] = self._draw_tiles(changed)
        return changed

    def carry_levels(self, kind: np.ndarray, level: np.ndarray) -> None:
        """Put the envs on the levels another curriculum on this bank reached, type by type: the
        i-th env of type t takes the level of the (i mod m)-th of that curriculum's m envs of type
        t, on a new tile; envs of a type it lacks keep their level. ``kind``, ``level``: (M,) each,
        that curriculum's type index (bank order) and level per env."""
        for t in range(len(self.bank.types)):
            mine, theirs = np.flatnonzero(self.kind == t), level[kind == t]
            if len(mine) and len(theirs):
                self.level[mine] = np.resize(theirs, len(mine))
        self.tile[:] = self._draw_tiles(np.arange(len(self.level)))

    def lift_to_floor(self) -> None:
        """Move envs below their type's floor (levels restored from another run) up to it, on a
        new tile."""
        low = np.flatnonzero(self.level < self.floor)
        self.level[low] = self.floor[low]
        self.tile[low] = self._draw_tiles(low)

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
