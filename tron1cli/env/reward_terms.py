"""Per-term reward math of the LIPM-guided paper (Sec. IV-C, Table II), pure numpy.

Every function takes batched arrays with the environment axis first (``N`` envs) and returns an
``(N,)`` float64 array.  Shapes: planar velocities ``(N, 2)`` in m/s (world or heading frame, the
caller's choice as long as command and measurement agree), yaw rates ``(N,)`` rad/s, joint
quantities ``(N, J)`` (rad, rad/s, rad/s^2, N m), actions ``(N, A)`` (policy units).

The functions return the *unweighted* term: tracking terms lie in [0, 1], penalties are
non-negative; the Table II weights (e.g. -2.0 for ``v_z^2``) are applied by the caller.  The two
fusions at the end combine stable and linear-tracking rewards as in Table II (RFM) or as a plain
weighted sum (ablation).
"""

from __future__ import annotations

import numpy as np


def _f64(x: np.ndarray) -> np.ndarray:
    return np.asarray(x, dtype=np.float64)


def direction_error(v_cmd_xy: np.ndarray, v_xy: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """Direction error ``d_e = cos(v_cmd, v) - 1`` in [-2, 0], ``(N,)``.

    ``v_cmd_xy`` and ``v_xy`` are (N, 2) in m/s.  Degenerate cases:

    * ``||v_cmd|| < eps`` (standing command): ``d_e = 0``; no direction to track, the magnitude
      term handles standing still.
    * command non-zero but ``||v|| < eps``: ``d_e = -1`` (cosine taken as 0, i.e. orthogonal:
      neither aligned nor opposed).
    """
    cmd = _f64(v_cmd_xy)
    vel = _f64(v_xy)
    n_cmd = np.linalg.norm(cmd, axis=-1)
    n_vel = np.linalg.norm(vel, axis=-1)
    has_cmd = n_cmd >= eps
    has_vel = n_vel >= eps
    denom = np.where(has_cmd & has_vel, n_cmd * n_vel, 1.0)
    cos = np.clip(np.sum(cmd * vel, axis=-1) / denom, -1.0, 1.0)
    cos = np.where(has_vel, cos, 0.0)
    return np.where(has_cmd, cos - 1.0, 0.0)


def magnitude_error(v_cmd_xy: np.ndarray, v_xy: np.ndarray) -> np.ndarray:
    """Magnitude error ``m_e = -(||v_cmd|| - ||v||)^2`` in (m/s)^2, ``(N,)``, always <= 0."""
    d = np.linalg.norm(_f64(v_cmd_xy), axis=-1) - np.linalg.norm(_f64(v_xy), axis=-1)
    return -(d**2)


def track_direction(v_cmd_xy: np.ndarray, v_xy: np.ndarray) -> np.ndarray:
    """Direction tracking reward ``exp(4 d_e)`` in [exp(-8), 1], ``(N,)``."""
    return np.exp(4.0 * direction_error(v_cmd_xy, v_xy))


def track_magnitude(v_cmd_xy: np.ndarray, v_xy: np.ndarray) -> np.ndarray:
    """Speed-magnitude tracking reward ``exp(4 m_e)`` in (0, 1], ``(N,)``."""
    return np.exp(4.0 * magnitude_error(v_cmd_xy, v_xy))


def track_lin_vel_l2(v_cmd_xy: np.ndarray, v_xy: np.ndarray, alpha: float = 4.0) -> np.ndarray:
    """Coupled l2 velocity tracking (eq. 6, ablation) ``exp(-alpha ||v_cmd - v||^2)``, ``(N,)``."""
    err = _f64(v_cmd_xy) - _f64(v_xy)
    return np.exp(-alpha * np.sum(err * err, axis=-1))


def track_progress(v_cmd_xy: np.ndarray, v_xy: np.ndarray, min_cmd: float = 0.1) -> np.ndarray:
    """Share of the commanded planar speed made along the command, ``clip(v . c / |c|^2, 0, 1)``,
    ``(N,)``; 0 for a command slower than ``min_cmd`` m/s. Linear and 0 for a robot that stands,
    unlike the kernels above, which pay a standing robot ``exp(-alpha |c|^2)`` of their maximum."""
    cmd = _f64(v_cmd_xy)
    c2 = np.sum(cmd * cmd, axis=-1)
    moving = c2 >= min_cmd**2
    share = np.sum(cmd * _f64(v_xy), axis=-1) / np.where(moving, c2, 1.0)
    return np.where(moving, np.clip(share, 0.0, 1.0), 0.0)


def track_yaw_rate(w_cmd: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Yaw-rate tracking ``exp(-4 (w_cmd - w)^2)``, ``w_cmd`` and ``w`` (N,) in rad/s."""
    return np.exp(-4.0 * (_f64(w_cmd) - _f64(w)) ** 2)


def lin_vel_z_sq(v_z: np.ndarray) -> np.ndarray:
    """Vertical base velocity penalty ``v_z^2`` in (m/s)^2, ``v_z`` (N,)."""
    return _f64(v_z) ** 2


def flat_orientation_sq(gravity_b: np.ndarray) -> np.ndarray:
    """Base tilt penalty ``g_x^2 + g_y^2`` (sin^2 of the tilt angle), ``gravity_b`` (N, 3) the unit
    gravity direction in the base frame (0 upright; not in the paper's Table II, whose orientation
    row is commented out)."""
    g = _f64(gravity_b)
    return g[:, 0] ** 2 + g[:, 1] ** 2


def joint_acc_sq(qdd: np.ndarray) -> np.ndarray:
    """Joint acceleration penalty ``sum_j qdd_j^2`` in (rad/s^2)^2, ``qdd`` (N, J)."""
    return np.sum(_f64(qdd) ** 2, axis=-1)


def joint_power(tau: np.ndarray, qd: np.ndarray) -> np.ndarray:
    """Joint power penalty ``sum_j |tau_j| |qd_j|`` in W, ``tau`` (N, J) N m, ``qd`` (N, J) rad/s."""
    return np.sum(np.abs(_f64(tau)) * np.abs(_f64(qd)), axis=-1)


def torque_sq(tau: np.ndarray) -> np.ndarray:
    """Joint torque penalty ``sum_j tau_j^2`` in (N m)^2, ``tau`` (N, J)."""
    return np.sum(_f64(tau) ** 2, axis=-1)


def action_rate(a: np.ndarray, a_prev: np.ndarray) -> np.ndarray:
    """Action rate penalty ``sum (a_t - a_{t-1})^2``, actions (N, A)."""
    d = _f64(a) - _f64(a_prev)
    return np.sum(d * d, axis=-1)


def action_smoothness(a: np.ndarray, a_prev: np.ndarray, a_prev2: np.ndarray) -> np.ndarray:
    """Action smoothness penalty ``sum (a_t - 2 a_{t-1} + a_{t-2})^2``, actions (N, A).

    Table II prints ``a_t - 2 a_{t-1} - a_{t-2}``; that is a typo for the second difference,
    which is what is implemented (a constant action sequence costs nothing).
    """
    d = _f64(a) - 2.0 * _f64(a_prev) + _f64(a_prev2)
    return np.sum(d * d, axis=-1)


def collisions(count: np.ndarray) -> np.ndarray:
    """Collision penalty: the number of undesired contacts ``count`` (N,), as float64."""
    return _f64(count)


def height_error_sq(z: np.ndarray, target: float) -> np.ndarray:
    """Height penalty ``(z - target)^2`` in m^2, heights ``z`` (N,) and ``target`` in m."""
    return (_f64(z) - float(target)) ** 2


def foot_stumble(foot_force: np.ndarray, ratio: float = 2.0) -> np.ndarray:
    """Stumble penalty: the number of feet (N,) whose ground force is more horizontal than
    vertical by ``ratio`` (``|F_xy| > ratio |F_z|``), as when a swinging foot strikes a riser's
    face; ``foot_force`` (N, F, 3) N, world frame. A foot in the air (zero force) does not count."""
    f = _f64(foot_force)
    horizontal = np.linalg.norm(f[..., :2], axis=-1)
    return np.sum(horizontal > ratio * np.abs(f[..., 2]), axis=-1).astype(np.float64)


def thigh_clearance_shortfall(gap: np.ndarray, margin: float) -> np.ndarray:
    """Thigh clearance penalty (N,): sum over thighs of min(1, max(0, margin - gap) / margin), 1 a
    thigh at or below the ground near it; ``gap`` (N, T) m between each thigh's surface and the
    highest ground near it, ``margin`` m. Warns before the contact that ends an episode (a
    backward knee meeting a block)."""
    return np.sum(np.clip((margin - _f64(gap)) / margin, 0.0, 1.0), axis=-1)


def joint_limit_violations(
    q: np.ndarray,
    qd: np.ndarray,
    q_range: np.ndarray,
    qd_limit: float,
    margin: float = 0.0,
) -> np.ndarray:
    """Number of joint-limit violations per env, as float64 ``(N,)``.

    Counts joints with ``q < lo + margin`` or ``q > hi - margin`` (``q`` (N, J) rad, ``q_range``
    (J, 2) rows ``[lo, hi]`` rad) plus joints with ``|qd| > qd_limit`` (``qd`` (N, J) rad/s).
    A joint outside both its position and its velocity limit counts twice.
    """
    q = _f64(q)
    rng = _f64(q_range)
    lo = rng[:, 0] + margin
    hi = rng[:, 1] - margin
    pos_out = (q < lo) | (q > hi)
    vel_out = np.abs(_f64(qd)) > qd_limit
    return (np.sum(pos_out, axis=-1) + np.sum(vel_out, axis=-1)).astype(np.float64)


def fuse_rfm(
    r_stable: np.ndarray,
    r_dir: np.ndarray,
    r_mag: np.ndarray,
    w_dir: float = 0.5,
    w_mag: float = 0.5,
) -> np.ndarray:
    """Stable-tracking fusion (Table II): ``r_stable + w_dir r_dir + w_mag r_stable r_mag``, ``(N,)``.

    Stability gates the speed-magnitude term (d/d r_mag = w_mag r_stable), while direction
    tracking keeps a fixed weight so the heading is still learned when the robot is unstable.
    """
    rs = _f64(r_stable)
    return rs + w_dir * _f64(r_dir) + w_mag * rs * _f64(r_mag)


def fuse_sum(
    r_stable: np.ndarray,
    r_dir: np.ndarray,
    r_mag: np.ndarray,
    w_dir: float = 0.5,
    w_mag: float = 0.5,
) -> np.ndarray:
    """Plain weighted sum (no-RFM ablation): ``r_stable + w_dir r_dir + w_mag r_mag``, ``(N,)``."""
    return _f64(r_stable) + w_dir * _f64(r_dir) + w_mag * _f64(r_mag)
