"""Named robot quantities read from the batched physics arrays (no MjData access).

The free joint's position, orientation and velocities, and the joint positions and velocities,
come from the state at the end of the step. Quantities that need kinematics or dynamics (CoM,
feet, contact forces, actuator torques) come from MuJoCo sensors, which rollout records at the
start of the last physics substep: they lag the state by one substep (5 ms by default).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from tron1cli.env import robot
from tron1cli.env.math3d import quat_rotate_inverse
from tron1cli.env.physics import BatchedPhysics

_GRAVITY_DIR = np.array([0.0, 0.0, -1.0])


@dataclass
class RobotState:
    """Per-env robot state; every field has the env dimension first. World frame unless ``_b``."""

    base_pos: np.ndarray  # (N, 3) m
    base_quat: np.ndarray  # (N, 4) w, x, y, z
    base_lin_vel_w: np.ndarray  # (N, 3) m/s
    base_lin_vel_b: np.ndarray  # (N, 3) m/s, base frame
    base_ang_vel_b: np.ndarray  # (N, 3) rad/s, base frame
    projected_gravity: np.ndarray  # (N, 3) unit gravity direction in the base frame
    joint_pos: np.ndarray  # (N, 6) rad, JOINT_NAMES order
    joint_vel: np.ndarray  # (N, 6) rad/s
    joint_acc: np.ndarray  # (N, 6) rad/s^2, finite difference over the last substep
    joint_torque: np.ndarray  # (N, 6) N m, actuator output
    com_pos: np.ndarray  # (N, 3) m, whole-body CoM
    com_vel: np.ndarray  # (N, 3) m/s
    foot_pos: np.ndarray  # (N, 2, 3) m, foot sphere centres (L, R)
    foot_vel: np.ndarray  # (N, 2, 3) m/s
    thigh_end_pos: np.ndarray  # (N, 2, 3) m, lower end of each thigh cylinder's axis (L, R)
    foot_force: np.ndarray  # (N, 2, 3) N, ground reaction on each foot, world frame
    foot_contact_pos: np.ndarray  # (N, 2, 3) m, contact centroid (only meaningful in contact)
    foot_in_contact: np.ndarray  # (N, 2) bool
    body_contact: np.ndarray  # (N, len(TERMINATION_BODIES)) bool: each termination body touches the ground
    collision_count: np.ndarray  # (N,) int: collision bodies touching the ground

    def assign(self, ids: np.ndarray, other: RobotState) -> None:
        """Overwrite rows ``ids`` with the rows of ``other`` (which has len(ids) rows)."""
        for f in fields(self):
            getattr(self, f.name)[ids] = getattr(other, f.name)


def read_state(phys: BatchedPhysics, ids: np.ndarray | None = None) -> RobotState:
    """Read a :class:`RobotState` for all envs, or for rows ``ids`` only.

    Base pose and velocities, gravity and joints come from the state after the step; the MuJoCo
    sensor figures (CoM, feet, contact forces, joint torques) are those MuJoCo computed before the
    last substep's integration, i.e. one physics step (5 ms) older, as on a robot whose estimator
    runs at the physics rate.
    """
    rows = slice(None) if ids is None else ids
    st = phys.state[rows]
    qpos = st[:, phys.qpos_slice]
    qvel = st[:, phys.qvel_slice]
    quat = qpos[:, 3:7]
    sd = phys.sensordata[rows, -1]
    sl = phys.sensor_slices

    def sens(name: str) -> np.ndarray:
        return sd[:, sl[name]]

    if phys.nsub > 1:
        prev_qvel = phys.traj[rows, -2, phys.qvel_slice]
        joint_acc = (qvel[:, 6:] - prev_qvel[:, 6:]) / phys.dt
    else:
        joint_acc = np.zeros_like(qvel[:, 6:])
    feet = robot.FOOT_NAMES
    contact = [sens(f"{f}_contact") for f in feet]  # found, force (3), pos (3)
    found = np.stack([c[:, 0] for c in contact], axis=1)
    return RobotState(
        base_pos=qpos[:, 0:3].copy(),
        base_quat=quat.copy(),
        base_lin_vel_w=qvel[:, 0:3].copy(),
        base_lin_vel_b=quat_rotate_inverse(quat, qvel[:, 0:3]),
        base_ang_vel_b=qvel[:, 3:6].copy(),
        projected_gravity=quat_rotate_inverse(quat, np.broadcast_to(_GRAVITY_DIR, (len(quat), 3))),
        joint_pos=qpos[:, 7:].copy(),
        joint_vel=qvel[:, 6:].copy(),
        joint_acc=joint_acc,
        joint_torque=np.concatenate([sens(f"tau_{j}") for j in robot.JOINT_NAMES], axis=1),
        com_pos=sens("com_pos").copy(),
        com_vel=sens("com_vel").copy(),
        foot_pos=np.stack([sens(f"{f}_pos") for f in feet], axis=1),
        foot_vel=np.stack([sens(f"{f}_vel") for f in feet], axis=1),
        thigh_end_pos=np.stack([sens(f"thigh_{s}_end_pos") for s in ("L", "R")], axis=1),
        # the sensor reports the force the foot exerts on the ground; the reaction is its negative
        foot_force=-np.stack([c[:, 1:4] for c in contact], axis=1) * (found[:, :, None] > 0),
        foot_contact_pos=np.stack([c[:, 4:7] for c in contact], axis=1),
        foot_in_contact=found > 0,
        body_contact=np.stack([sens(f"{b}_contact")[:, 0] > 0 for b in robot.TERMINATION_BODIES], axis=1),
        collision_count=np.sum([sens(f"{b}_contact")[:, 0] > 0 for b in robot.COLLISION_BODIES], axis=0),
    )
