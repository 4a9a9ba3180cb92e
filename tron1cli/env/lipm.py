"""LIPM-guided stability math (paper Sec. III and the stable reward of Sec. IV-C), pure numpy.

Conventions
-----------
* Every function is batched: the environment axis comes first (``N`` envs); per-env scalars are
  ``(N,)`` arrays, planar vectors ``(N, 2)``, 3-D points ``(N, 3)``.  Outputs are float64.
* Frames: all positions are in the world frame with ``+z`` up; planar quantities are the world
  ``x, y`` components.  Velocities are in m/s, angular rates in rad/s, forces in N, lengths in m.
* The linear inverted pendulum with a constraint plane (Kajita) gives
  ``p_com = (z / g) * pdd_com + p_zmp`` where ``z`` is the intercept of the CoM constraint plane.
  Choosing ``pdd_com = kp (v_cmd - v)`` (a P-controller on the velocity error) yields the desired
  CoM of eq. 2: ``p_hat = p_zmp + (z / g) kp (v_cmd - v)``.
* The constraint plane is fitted by the *caller*: :func:`plane_intercept` only measures the CoM
  height above a ground height the caller chooses (e.g. the mean terrain height sampled under
  the robot, or the mean height of the feet's contact points).  The plane's normal is left free
  as in the paper, so only the intercept enters the reward.
* The ZMP of a point-foot robot is the centre of pressure of the loaded contacts.  In flight no
  foot carries load, the ZMP is undefined, and the last support point is held (the caller passes
  the previous step's ZMP, initialised e.g. to the CoM ground projection at reset).
"""

from __future__ import annotations

import numpy as np

G = 9.81
"""Gravitational acceleration (m/s^2)."""


def zmp_from_contacts(
    contact_pos: np.ndarray,
    normal_force: np.ndarray,
    last_zmp: np.ndarray,
    min_force: float = 1.0,
) -> np.ndarray:
    """Centre of pressure of the loaded feet, ``(N, 2)`` in m (world ``x, y``).

    ``contact_pos`` (N, F, 3) are the feet's contact points (m), ``normal_force`` (N, F) the normal
    contact forces (N).  A foot is loaded when its normal force is strictly greater than
    ``min_force``; the ZMP is ``sum_i f_i p_i,xy / sum_i f_i`` over loaded feet.  Weights are
    normalised before the weighted sum, so in single support the result is that foot's contact
    point bit for bit.  Envs with no loaded foot (flight) return ``last_zmp`` (N, 2), the last
    support point.
    """
    pos = np.asarray(contact_pos, dtype=np.float64)
    force = np.asarray(normal_force, dtype=np.float64)
    last = np.asarray(last_zmp, dtype=np.float64)
    w = np.where(force > min_force, force, 0.0)
    total = w.sum(axis=1)
    support = total > 0.0
    w_norm = w / np.where(support, total, 1.0)[:, None]
    cop = np.einsum("nf,nfk->nk", w_norm, pos[..., :2])
    return np.where(support[:, None], cop, last)


def plane_intercept(com_pos: np.ndarray, ground_height: np.ndarray) -> np.ndarray:
    """Intercept ``z`` (N,) in m of the CoM constraint plane, relative to the terrain.

    Defined as the CoM height above the ground height under the robot:
    ``z = com_pos[:, 2] - ground_height``.  ``com_pos`` (N, 3) is the world CoM (m) and
    ``ground_height`` (N,) the terrain height (m) the caller fitted under the robot.
    """
    com = np.asarray(com_pos, dtype=np.float64)
    return com[:, 2] - np.asarray(ground_height, dtype=np.float64)


def desired_com(
    zmp: np.ndarray,
    z: np.ndarray,
    v_cmd_xy: np.ndarray,
    v_xy: np.ndarray,
    kp: float,
) -> np.ndarray:
    """Desired planar CoM (eq. 2), ``(N, 2)`` in m: ``p_hat = p_zmp + (z / g) kp (v_cmd - v)``.

    ``zmp`` (N, 2) m, ``z`` (N,) m, ``v_cmd_xy`` and ``v_xy`` (N, 2) m/s, ``kp`` the feedback gain
    (1/s), so ``kp (v_cmd - v)`` is the commanded CoM acceleration (m/s^2).
    """
    zmp = np.asarray(zmp, dtype=np.float64)
    z = np.asarray(z, dtype=np.float64)
    err = np.asarray(v_cmd_xy, dtype=np.float64) - np.asarray(v_xy, dtype=np.float64)
    return zmp + (z / G)[:, None] * kp * err


def stable_reward(
    p_hat: np.ndarray,
    p_com_xy: np.ndarray,
    z: np.ndarray,
    z_c: float | np.ndarray,
    roll_rate: np.ndarray,
    pitch_rate: np.ndarray,
) -> np.ndarray:
    """Stable reward (eq. 4), ``(N,)`` in (0, 1].

    ``exp(-||p_hat - p_com||_2 - |z_c - z| - (|roll_rate| + |pitch_rate|))`` with ``p_hat``,
    ``p_com_xy`` (N, 2) in m, ``z`` (N,) m, ``z_c`` the standing-height intercept (m, scalar or
    (N,)), and the base roll/pitch rates (N,) in rad/s.  It is 1 exactly on the LIPM target.
    Table II prints the exponent without its minus sign; eq. 4 (negated errors) is the correct
    form, since the reward must lie in (0, 1] and fall as the errors grow.
    """
    p_e = np.asarray(p_hat, dtype=np.float64) - np.asarray(p_com_xy, dtype=np.float64)
    z_e = np.asarray(z_c, dtype=np.float64) - np.asarray(z, dtype=np.float64)
    w_e = np.abs(np.asarray(roll_rate, dtype=np.float64)) + np.abs(np.asarray(pitch_rate, dtype=np.float64))
    return np.exp(-np.linalg.norm(p_e, axis=-1) - np.abs(z_e) - w_e)


class LipmTracker:
    """Per-env LIPM quantities of the current step, with the ZMP held through flight phases.

    Attributes (N rows each, world frame): ``zmp`` (N, 2), ``z`` (N,) plane intercept,
    ``p_hat`` (N, 2) desired CoM, ``p_com`` (N, 2) actual CoM, ``r_stable`` (N,).
    """

    def __init__(self, num_envs: int, kp: float, z_c: float) -> None:
        self.kp = kp
        self.z_c = z_c
        self.zmp = np.zeros((num_envs, 2))
        self.z = np.full(num_envs, z_c)
        self.p_hat = np.zeros((num_envs, 2))
        self.p_com = np.zeros((num_envs, 2))
        self.r_stable = np.ones(num_envs)

    def reset(self, ids: np.ndarray, foot_pos: np.ndarray) -> None:
        """Start envs ``ids`` with the ZMP midway between their feet (``foot_pos`` (k, 2, 3))."""
        self.zmp[ids] = foot_pos[:, :, :2].mean(axis=1)

    def update(
        self,
        contact_pos: np.ndarray,
        normal_force: np.ndarray,
        com_pos: np.ndarray,
        com_vel_xy: np.ndarray,
        v_cmd_xy_world: np.ndarray,
        ground_height: np.ndarray,
        roll_rate: np.ndarray,
        pitch_rate: np.ndarray,
    ) -> None:
        """Recompute every quantity from one step's state (shapes as in the functions above)."""
        self.zmp = zmp_from_contacts(contact_pos, normal_force, self.zmp)
        self.z = plane_intercept(com_pos, ground_height)
        self.p_com = com_pos[:, :2].copy()
        self.p_hat = desired_com(self.zmp, self.z, v_cmd_xy_world, com_vel_xy, self.kp)
        self.r_stable = stable_reward(self.p_hat, self.p_com, self.z, self.z_c, roll_rate, pitch_rate)
