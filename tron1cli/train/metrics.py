"""Per-iteration training figures: episode outcomes by agent group, tracking error, reward terms."""

from __future__ import annotations

import json
from collections import deque
from pathlib import Path

import numpy as np
import torch

from tron1cli.fileio import write_file

GROUPS = ("teacher", "student")


def trim_metrics(path: Path, iteration: int) -> int | None:
    """Make ``metrics.jsonl`` at ``path`` fit a run that goes on after ``iteration``: drop the
    lines of later iterations (they will be redone) and a cut last line (a run killed, or a disk
    that filled, while writing it: appended to, it would make one corrupt line of two), and end
    the file with a newline. Other unreadable lines are kept rather than guessed at. Returns the
    number of the cut line it dropped, if any."""
    path = Path(path)
    if not path.is_file():
        return None
    data = path.read_bytes()
    lines = data.decode(errors="surrogateescape").splitlines(keepends=True)
    keep, cut = [], None
    for k, line in enumerate(lines):
        try:
            row = json.loads(line)
            later = int(row["iteration"]) > iteration
        except (ValueError, KeyError, TypeError):
            if k == len(lines) - 1:
                cut = k + 1
                continue
            keep.append(line)  # a corrupt line before the last: kept rather than guess
            continue
        if not later:
            keep.append(line if line.endswith("\n") else line + "\n")
    text = "".join(keep)
    if text.encode(errors="surrogateescape") != data:
        write_file(path, text.encode(errors="surrogateescape"))
    return cut


class EpisodeStats:
    """Rolling figures over the last ``window`` finished episodes of each agent group.

    survival: share of finished episodes that ended by time-out rather than by a fall or an
    unstable simulation; length_s: mean episode length (s). Reward-term sums are averaged over the
    episodes that finished during the current iteration. The first episode of each env after a
    staggered reset (cut short by its random start on the clock) is counted in ``episodes`` only.

    A 20 s episode that times out at iteration k began 1000 policy steps earlier (83 iterations of
    12 steps, 42 of 24), so survival lags the policy; ``falls_per_min`` does not: the episodes of
    this iteration that did not end by time-out (staggered ones too) per minute of robot time the
    group spent in it (``step_s``: the policy step, s).
    """

    def __init__(self, window: int = 1000, step_s: float = 0.02) -> None:
        self.outcomes = {g: deque(maxlen=window) for g in GROUPS}
        self.lengths = {g: deque(maxlen=window) for g in GROUPS}
        self.step_s = step_s
        self._terms: dict[str, list[np.ndarray]] = {}
        self._track: dict[str, list[float]] = {g: [] for g in GROUPS}
        self._falls = {g: 0 for g in GROUPS}
        self._robot_steps = {g: 0 for g in GROUPS}
        self.episodes = 0

    def add_episodes(self, ids: np.ndarray, episode: dict[str, np.ndarray], n_teacher: int) -> None:
        """Record the episodes that ended in envs ``ids`` (the step's ``episode`` dict)."""
        if len(ids) == 0:
            return
        self.episodes += len(ids)
        full = ~episode["staggered"]
        is_student = ids >= n_teacher
        for g, in_group in (("teacher", ~is_student), ("student", is_student)):
            mask = full & in_group
            self.outcomes[g].extend(episode["time_out"][mask].tolist())
            self.lengths[g].extend(episode["length_s"][mask].tolist())
            self._falls[g] += int((in_group & ~episode["time_out"]).sum())
        for k, v in episode.items():
            if k.startswith("reward/") and full.any():
                self._terms.setdefault(k, []).append(v[full])

    def state_dict(self) -> dict[str, torch.Tensor]:
        """The rolling windows as tensors, so that a resumed run's survival and episode length go
        on from the episodes before it instead of from its first (short, falling) ones."""
        out = {}
        for g in GROUPS:
            out[f"{g}/outcomes"] = torch.tensor(list(self.outcomes[g]), dtype=torch.bool)
            out[f"{g}/lengths"] = torch.tensor(list(self.lengths[g]), dtype=torch.float64)
        return out

    def load_state_dict(self, sd: dict[str, torch.Tensor]) -> None:
        """Refill the rolling windows from :meth:`state_dict` (the newest ``window`` entries)."""
        for g in GROUPS:
            self.outcomes[g].clear()
            self.outcomes[g].extend(sd[f"{g}/outcomes"].tolist())
            self.lengths[g].clear()
            self.lengths[g].extend(sd[f"{g}/lengths"].tolist())

    def add_step(self, err: np.ndarray, n_teacher: int) -> None:
        """Record one step of every env: its velocity tracking error (N,) in m/s."""
        self._track["teacher"].append(float(err[:n_teacher].mean()) if n_teacher else np.nan)
        self._track["student"].append(float(err[n_teacher:].mean()) if n_teacher < len(err) else np.nan)
        self._robot_steps["teacher"] += n_teacher
        self._robot_steps["student"] += len(err) - n_teacher

    def summary(self) -> dict[str, float]:
        """Figures of this iteration; clears the per-iteration accumulators."""
        out: dict[str, float] = {}
        for g in GROUPS:
            o = self.outcomes[g]
            out[f"{g}/survival"] = float(np.mean(o)) if o else float("nan")
            out[f"{g}/episode_length_s"] = (
                float(np.mean(self.lengths[g])) if self.lengths[g] else float("nan")
            )
            out[f"{g}/vel_tracking_error"] = (
                float(np.mean(self._track[g])) if self._track[g] else float("nan")
            )
            minutes = self._robot_steps[g] * self.step_s / 60.0
            out[f"{g}/falls_per_min"] = self._falls[g] / minutes if minutes else float("nan")
            self._track[g], self._falls[g], self._robot_steps[g] = [], 0, 0
        for k, chunks in self._terms.items():  # "reward/<term>" -> "episode_reward/<term>"
            out["episode_" + k] = float(np.concatenate(chunks).mean())
        self._terms = {}
        return out
