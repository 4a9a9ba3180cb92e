"""Velocity command schedules for deploy-sim: one constant command, or timed commands from a file.

A command is (v_x, v_y, yaw rate): m/s in the base yaw frame and rad/s, as in training. A file
holds CSV lines ``t_s,vx,vy,yaw``; each command holds from its time ``t_s`` (s of simulation
time) until the next line's. Before the first line the command is zero (stand, stepping in
place). Blank lines and lines starting with ``#`` are skipped, and so is a header line.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np


def parse_cmd(text: str) -> tuple[float, float, float]:
    """``"0.5,0,0.2"`` -> (0.5, 0.0, 0.2); raises ValueError on anything else."""
    parts = [p.strip() for p in text.split(",")]
    try:
        vals = tuple(float(p) for p in parts)
    except ValueError:
        vals = ()
    if len(vals) != 3 or not all(math.isfinite(v) for v in vals):
        raise ValueError(f"--cmd wants three numbers vx,vy,yaw (m/s, m/s, rad/s), got '{text}'")
    return vals  # type: ignore[return-value]


@dataclass(frozen=True)
class CommandSchedule:
    """Piecewise-constant commands: ``times`` (k,) s, increasing, and ``values`` (k, 3)."""

    times: np.ndarray
    values: np.ndarray

    @classmethod
    def constant(cls, cmd: tuple[float, float, float]) -> CommandSchedule:
        return cls(np.zeros(1), np.array([cmd], dtype=float))

    @classmethod
    def from_file(cls, path: Path) -> CommandSchedule:
        """Read ``t_s,vx,vy,yaw`` lines; raises ValueError naming the file and line of a bad one."""
        rows: list[tuple[float, ...]] = []
        try:
            text = Path(path).read_text()
        except UnicodeDecodeError as e:
            raise ValueError(
                f"--cmd-file {path}: not a text file (byte {e.start} is not UTF-8); want CSV lines "
                "t_s,vx,vy,yaw"
            ) from None
        except OSError as e:
            raise ValueError(f"--cmd-file {path}: cannot read it ({e.strerror or e})") from None
        if "\x00" in text:
            raise ValueError(
                f"--cmd-file {path}: not a text file (it holds NUL bytes); want CSV lines t_s,vx,vy,yaw"
            )
        for no, line in enumerate(text.splitlines(), start=1):
            s = line.strip()
            if not s or s.startswith("#"):
                continue
            parts = [p.strip() for p in s.split(",")]
            try:
                vals = tuple(float(p) for p in parts)
            except ValueError:
                if not rows and parts and not parts[0][:1].isdigit() and parts[0][:1] not in "+-.":
                    continue  # a header line such as "t_s,vx,vy,yaw"
                vals = ()
            if len(vals) != 4 or not all(math.isfinite(v) for v in vals):
                raise ValueError(f"{path}:{no}: want t_s,vx,vy,yaw (four numbers), got '{s}'")
            if vals[0] < 0 or (rows and vals[0] <= rows[-1][0]):
                raise ValueError(f"{path}:{no}: times must be >= 0 and increasing, got {vals[0]:g} s")
            rows.append(vals)
        if not rows:
            raise ValueError(f"{path}: no commands (want CSV lines t_s,vx,vy,yaw)")
        arr = np.array(rows, dtype=float)
        return cls(arr[:, 0], arr[:, 1:])

    def max_speed(self) -> float:
        """The fastest planar command of the schedule, max hypot(v_x, v_y) (m/s)."""
        return float(np.hypot(self.values[:, 0], self.values[:, 1]).max())

    def at(self, t: float) -> np.ndarray:
        """The command (3,) in force at simulation time ``t`` (s); zero before the first entry."""
        k = int(np.searchsorted(self.times, t + 1e-9, side="right")) - 1
        return np.zeros(3) if k < 0 else self.values[k].copy()
