"""Batched rigid-body helpers on numpy arrays (quaternions in MuJoCo's w, x, y, z order)."""

from __future__ import annotations

import numpy as np


def quat_rotate_inverse(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate world vectors ``v`` (N, 3) into the frames of unit quaternions ``q`` (N, 4)."""
    w = q[:, :1]
    u = q[:, 1:]
    t = 2.0 * np.cross(u, v)
    return v - w * t + np.cross(u, t)


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate body-frame vectors ``v`` (N, 3) into the world by unit quaternions ``q`` (N, 4)."""
    w = q[:, :1]
    u = q[:, 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def yaw_of(q: np.ndarray) -> np.ndarray:
    """Heading angle (rad) of unit quaternions ``q`` (N, 4), in (-pi, pi]."""
    w, x, y, z = q.T
    return np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Angles ``a`` (rad, any shape) wrapped to (-pi, pi]."""
    return np.angle(np.exp(1j * np.asarray(a)))


def roll_pitch(gravity_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Roll and pitch (N,) in rad (ZYX Euler; pitch positive nose down) from the unit gravity
    direction in the base frame (N, 3)."""
    g = gravity_b
    return np.arctan2(-g[:, 1], -g[:, 2]), np.arctan2(g[:, 0], np.hypot(g[:, 1], g[:, 2]))


def quat_from_euler(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Unit quaternions (N, 4) from intrinsic z-y-x (yaw, pitch, roll) angles in rad."""
    cr, sr = np.cos(roll / 2), np.sin(roll / 2)
    cp, sp = np.cos(pitch / 2), np.sin(pitch / 2)
    cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
    return np.stack(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ],
        axis=-1,
    )


def rotate_z(v: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotate the x, y components of ``v`` (N, >=2) by ``angle`` (N,) about z; returns (N, 2)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1]], axis=-1)


def quat_to_mat(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (N, 3, 3) of unit quaternions ``q`` (N, 4)."""
    w, x, y, z = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
        ],
        axis=-2,
    )
