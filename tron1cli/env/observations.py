"""Observation layout: the one definition of every observation group and its size.

Groups (paper Table I):

- ``proprio`` o_t (student, noisy in training): base angular velocity 3, projected gravity 3,
  joint positions 6 (relative to the default pose), joint velocities 6, command 3, last action 6.
- ``history`` o^H_t: the last ``history_len`` o_t, oldest first.
- ``privileged`` e_t (teacher): the same terms noise-free ("proprioception GT" 27), base linear
  velocity 3, joint torques 6, joint accelerations 6, foot contact forces 6, external force 3.
- with perception on: ``heightmap`` h_t (teacher, 441 = 21 x 21 terrain heights relative to the
  base, m) and ``depth`` d_t (student, 60 x 80 z-depth image, m).

With the gait prior on, the clock (sin, cos of the phase and the frequency: 3) ends o_t, so it is
in o_t, o^H_t and e_t alike (30 / 54 wide); with it off the layout is exactly the paper's.

Sizes are derived from the term tuples, never typed in. Each term is a named entry with a scale
(applied after noise) and a noise sigma in physical units.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ObsTerm:
    """One named observation entry.

    name: key into the term arrays; dim: width; scale: multiplier applied to the physical value;
    noise_key: the NoiseConfig field whose sigma (physical units) perturbs the student copy.
    """

    name: str
    dim: int
    scale: float = 1.0
    noise_key: str | None = None


PROPRIO_TERMS: tuple[ObsTerm, ...] = (
    ObsTerm("base_ang_vel", 3, 0.25, "ang_vel"),
    ObsTerm("projected_gravity", 3, 1.0, "gravity"),
    ObsTerm("joint_pos", 6, 1.0, "joint_pos"),
    ObsTerm("joint_vel", 6, 0.05, "joint_vel"),
    ObsTerm("command", 3, 1.0),
    ObsTerm("last_action", 6, 1.0),
)

GAIT_CLOCK_TERM = ObsTerm("gait_clock", 3, 1.0)

PRIVILEGED_EXTRA_TERMS: tuple[ObsTerm, ...] = (
    ObsTerm("base_lin_vel", 3, 1.0),
    ObsTerm("joint_torque", 6, 1.0 / 40.0),
    ObsTerm("joint_acc", 6, 1.0 / 500.0),
    ObsTerm("foot_contact_force", 6, 1.0 / 100.0),
    ObsTerm("external_force", 3, 1.0 / 50.0),
)


@dataclass(frozen=True)
class ObsLayout:
    """Derived sizes and slices of every observation group.

    history_len: number of o_t stacked in o^H_t; gait_clock: the gait prior's clock ends o_t.
    """

    history_len: int = 5
    gait_clock: bool = False
    heightmap_dim: int = 0
    depth_hw: tuple[int, int] | None = None

    @property
    def proprio_terms(self) -> tuple[ObsTerm, ...]:
        return PROPRIO_TERMS + ((GAIT_CLOCK_TERM,) if self.gait_clock else ())

    @property
    def privileged_terms(self) -> tuple[ObsTerm, ...]:
        return self.proprio_terms + PRIVILEGED_EXTRA_TERMS

    @property
    def proprio_dim(self) -> int:
        return sum(t.dim for t in self.proprio_terms)

    @property
    def privileged_dim(self) -> int:
        return sum(t.dim for t in self.privileged_terms)

    @property
    def history_dim(self) -> int:
        return self.history_len * self.proprio_dim

    def sizes(self) -> dict[str, int]:
        """Width of every group, by name."""
        sizes = {"proprio": self.proprio_dim, "history": self.history_dim, "privileged": self.privileged_dim}
        if self.heightmap_dim:
            sizes["heightmap"] = self.heightmap_dim
        if self.depth_hw is not None:
            sizes["depth"] = self.depth_hw[0] * self.depth_hw[1]
        return sizes

    def slices(self, group: str) -> dict[str, slice]:
        """Slice of every term inside one group (``proprio`` or ``privileged``)."""
        terms = self.proprio_terms if group == "proprio" else self.privileged_terms
        out, a = {}, 0
        for t in terms:
            out[t.name] = slice(a, a + t.dim)
            a += t.dim
        return out

    def to_dict(self) -> dict:
        """Contract form (for checkpoints and ONNX metadata)."""
        return {
            "history_len": self.history_len,
            "gait_clock": self.gait_clock,
            "heightmap_dim": self.heightmap_dim,
            "depth_hw": list(self.depth_hw) if self.depth_hw else None,
            "sizes": self.sizes(),
            "proprio": [[t.name, t.dim, t.scale] for t in self.proprio_terms],
            "privileged": [[t.name, t.dim, t.scale] for t in self.privileged_terms],
        }


def assemble(
    terms: tuple[ObsTerm, ...],
    values: Mapping[str, np.ndarray],
    noise: Mapping[str, float] | None = None,
    rng: np.random.Generator | None = None,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """Concatenate scaled terms into one (N, dim) float32 array.

    Args:
        terms: the group's terms, in order.
        values: physical values by term name, each (N, term.dim).
        noise: sigma by noise key; when given with ``rng``, Gaussian noise is added before scaling.
        rng: generator for the noise.
        out: optional preallocated (N, dim) float32 output.
    """
    n = next(iter(values.values())).shape[0]
    if out is None:
        out = np.empty((n, sum(t.dim for t in terms)), dtype=np.float32)
    a = 0
    for t in terms:
        v = values[t.name]
        if noise is not None and rng is not None and t.noise_key is not None:
            sigma = noise[t.noise_key]
            if sigma > 0:
                v = v + rng.normal(0.0, sigma, size=v.shape)
        out[:, a : a + t.dim] = v * t.scale
        a += t.dim
    return out


def proprio_values(
    ang_vel_b: np.ndarray,
    projected_gravity: np.ndarray,
    joint_pos: np.ndarray,
    joint_vel: np.ndarray,
    command: np.ndarray,
    last_action: np.ndarray,
    default_pose: np.ndarray,
    gait_clock: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """Physical values of the o_t terms by name, each (N, dim): the one mapping from robot
    quantities to the student's observation, used by the env and by ``deploy-robot`` alike.

    ang_vel_b: base angular velocity (rad/s, base frame); projected_gravity: unit gravity
    direction in the base frame; joint_pos, joint_vel: rad, rad/s in the policy's joint order;
    command: v_x, v_y (m/s), yaw rate (rad/s); last_action: the last applied action (unitless);
    default_pose: rad, subtracted from joint_pos; gait_clock: (N, 3) sin, cos, frequency (Hz).
    """
    values = {
        "base_ang_vel": ang_vel_b,
        "projected_gravity": projected_gravity,
        "joint_pos": joint_pos - default_pose,
        "joint_vel": joint_vel,
        "command": command,
        "last_action": last_action,
    }
    if gait_clock is not None:
        values["gait_clock"] = gait_clock
    return values


def push_history(hist: np.ndarray, proprio: np.ndarray, ids_reset: np.ndarray | None = None) -> None:
    """Shift the (N, history_len, proprio_dim) history in place and append ``proprio`` (N, dim);
    rows ``ids_reset`` (a new episode) are filled with ``proprio`` throughout."""
    hist[:, :-1] = hist[:, 1:]
    hist[:, -1] = proprio
    if ids_reset is not None and len(ids_reset):
        hist[ids_reset] = proprio[ids_reset, None, :]
