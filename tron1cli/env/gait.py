"""Gait prior: a per-env phase clock and the desired contact schedule it implies.

The clock is a switchable aid (DESIGN.md, "Learning to step on a CPU"), not part of the paper's
method. Each env has a gait frequency f (Hz) and a phase phi in [0, 1) that advances by f * dt each
policy step and restarts at 0 at reset. The left leg's phase is phi, the right leg's phi + offset
(0.5: half a period apart). A leg should stand while its phase is below the stance fraction
(0.5) and swing for the rest of the period. A standing command keeps the clock running: the
robot steps in place, since a point-foot biped cannot stand still.

An optional swing fold (:func:`swing_fold`) adds a hip and knee flexion to the joint targets of a
swinging leg, so the foot rises without the policy asking: the policy then acts as a residual over
a gait that already lifts its feet. It changes what an action means, so it is part of the
policy's contract (``gait_clock.swing_fold_rad``) and deployments apply it too.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from tron1cli.env import robot

if TYPE_CHECKING:
    from tron1cli.config.env import GaitConfig

_HIP = (robot.JOINT_NAMES.index("hip_L"), robot.JOINT_NAMES.index("hip_R"))
_KNEE = (robot.JOINT_NAMES.index("knee_L"), robot.JOINT_NAMES.index("knee_R"))


def leg_phases(phase: np.ndarray, offset: float = 0.5) -> np.ndarray:
    """Phase of each leg (N, 2) in [0, 1): left = phase, right = phase + offset (mod 1)."""
    return np.stack([phase % 1.0, (phase + offset) % 1.0], axis=1)


def _step(x: np.ndarray, width: float) -> np.ndarray:
    """Smooth step from 0 to 1 around x = 0, with transition width ``width`` (phase units)."""
    return 0.5 * (1.0 + np.tanh(x / width))


def desired_contact(leg_phase: np.ndarray, stance: float = 0.5, width: float = 0.04) -> np.ndarray:
    """Smoothed desired contact in [0, 1] of legs at ``leg_phase`` (any shape, values in [0, 1)).

    1 in the middle of stance [0, stance), 0 in the middle of swing, 0.5 at both transitions; the
    transitions are tanh steps of width ``width``. The wrap-around copy keeps the schedule
    periodic (a phase just below 1 is about to land).
    """
    p = leg_phase
    on = _step(p, width) * (1.0 - _step(p - stance, width))
    wrap = _step(p - 1.0, width) * (1.0 - _step(p - 1.0 - stance, width))
    return on + wrap


def clock_observation(phase: np.ndarray, freq: np.ndarray) -> np.ndarray:
    """The clock as the policy sees it (N, 3): sin(2 pi phase), cos(2 pi phase), frequency (Hz)."""
    a = 2.0 * np.pi * phase
    return np.stack([np.sin(a), np.cos(a), freq], axis=1)


def swing_height_target(leg_phase: np.ndarray, stance: float = 0.5, height: float = 0.1) -> np.ndarray:
    """Sole height (m) above the terrain a leg at ``leg_phase`` should reach: ``height x
    sin(pi s)`` at swing progress s in [0, 1] (0 at lift-off and touch-down, ``height`` mid-swing),
    0 in stance. Same shape as ``leg_phase``."""
    s = (np.asarray(leg_phase, dtype=np.float64) - stance) / (1.0 - stance)
    return np.where(s > 0.0, height * np.sin(np.pi * np.clip(s, 0.0, 1.0)), 0.0)


def clearance_shortfall(clearance: np.ndarray, target: np.ndarray, height: float = 0.1) -> np.ndarray:
    """Penalty (N,) of feet below their swing target: sum over feet of max(0, target - clearance)
    / height, so 1 a second for one foot dragging at mid-swing; ``clearance`` and ``target`` (N, 2) m."""
    short = np.maximum(np.asarray(target, dtype=np.float64) - clearance, 0.0) / height
    return short.sum(axis=-1)


#: share of the swing over which the fold rises and falls back; the last 40 % has none, since the
#: PD joints lag their targets by about 0.1 s: over the whole swing a foot would still be 13-19 cm
#: up when the clock says it lands, over the first 60 % it is down to 1-4 cm (leg in the air, Kp 40,
#: swings of 0.20-0.33 s)
FOLD_SHARE = 0.6


def swing_fold(leg_phase: np.ndarray, stance: float, fold_rad: tuple[float, float]) -> np.ndarray:
    """Joint-target offsets (N, 6), in ``robot.JOINT_NAMES`` order, of legs at ``leg_phase`` (N, 2).

    A swinging leg flexes its hip by ``fold_rad[0]`` and its knee by ``fold_rad[1]`` (rad) times
    sin(pi s / FOLD_SHARE) at swing progress s < FOLD_SHARE, 0 after it and in stance. Flexion
    that lifts the foot is (hip -, knee +) on the left leg and (hip +, knee -) on the right (the
    joint axes are mirrored): hip 0.5, knee 0.8 rad lift a foot 17-20 cm at mid-swing from the
    crouch (leg in the air, Kp 40, swings of 0.20-0.33 s).
    """
    s = (np.asarray(leg_phase, dtype=np.float64) - stance) / (1.0 - stance) / FOLD_SHARE
    w = np.where((s > 0.0) & (s < 1.0), np.sin(np.pi * np.clip(s, 0.0, 1.0)), 0.0)
    out = np.zeros((w.shape[0], robot.NUM_JOINTS))
    for leg, sign in ((0, 1.0), (1, -1.0)):
        out[:, _HIP[leg]] = -sign * fold_rad[0] * w[:, leg]
        out[:, _KNEE[leg]] = sign * fold_rad[1] * w[:, leg]
    return out


def fold_targets(
    targets: np.ndarray, phase: np.ndarray, gait: GaitConfig, default_pose: np.ndarray
) -> np.ndarray:
    """Joint targets (N, 6) rad: ``targets`` (the default pose plus the scaled action) with the
    swing fold of ``gait`` at clock ``phase`` (N,) added (:func:`swing_fold`); ``targets`` itself
    when ``gait`` has no fold. The env core and deploy-robot both call this.

    ``gait.swing_fold_keep`` in [0, 1] limits the policy's authority over the fold: while a joint
    is folded, its flexion from ``default_pose`` stays at least keep x the fold's, whatever the
    action asks (0: no limit; 1: the action can add flexion but never take the fold's away).
    """
    if not any(gait.swing_fold_rad):
        return targets
    off = swing_fold(leg_phases(phase, gait.offset), gait.stance, gait.swing_fold_rad)
    out = targets + off
    if gait.swing_fold_keep > 0.0:
        sign = np.sign(off)
        flex = np.maximum(sign * (out - default_pose), gait.swing_fold_keep * np.abs(off))
        out = np.where(sign != 0.0, default_pose + sign * flex, out)
    return out
