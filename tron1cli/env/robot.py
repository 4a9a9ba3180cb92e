"""TRON1 point-foot constants: the one source of truth for joint order, default pose and gains.

Figures are from shared/reference/tron1-facts.md; the MJCF in ``assets/`` is authored from the
same figures, and :func:`load_spec` checks that the two agree on joint and actuator order.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import mujoco
import numpy as np

#: Joint order of the robot's SDK, used for actions, observations and the ONNX contract.
JOINT_NAMES: tuple[str, ...] = ("abad_L", "hip_L", "knee_L", "abad_R", "hip_R", "knee_R")
NUM_JOINTS = len(JOINT_NAMES)
FOOT_NAMES: tuple[str, ...] = ("foot_L", "foot_R")

#: Default joint pose (rad), LimX's training convention: straight legs.
DEFAULT_POSE = np.zeros(NUM_JOINTS)
#: Action scale: joint target = DEFAULT_POSE + ACTION_SCALE * action (rad per unit action).
ACTION_SCALE = 0.25
KP = 40.0  #: PD stiffness (N m / rad), paper and LimX Isaac Lab training.
KD = 2.5  #: PD damping (N m s / rad).
TORQUE_LIMIT = 80.0  #: motor peak torque (N m).
VELOCITY_LIMIT = 15.0  #: motor speed limit (rad/s); counted by the joint-limit penalty.

TOTAL_MASS = 18.593  #: kg, feet included (URDF figure).
BASE_HEIGHT_ZERO_POSE = 0.812  #: base origin above the foot soles with every joint at 0 (m).
COM_HEIGHT_ZERO_POSE = 0.561  #: whole-body CoM above the soles with every joint at 0 (m).
FOOT_RADIUS = 0.032  #: m; the contact point is this far below the foot centre.
THIGH_RADIUS = 0.035  #: m, radius of the thigh cylinders (sites ``thigh_{L,R}_end`` end their axes).

#: Joint ranges (rad), in JOINT_NAMES order.
JOINT_RANGES = np.array(
    [
        [-0.38397, 1.39626],
        [-1.01229, 1.39626],
        [-0.872665, 1.361357],
        [-1.39626, 0.38397],
        [-1.39626, 1.01229],
        [-1.361357, 0.872665],
    ]
)

#: Depth camera (D435i) mount in the base frame: position (m) and downward pitch (deg).
CAMERA_NAME = "depth_cam"
CAMERA_POS = np.array([0.175, 0.0, -0.03])
CAMERA_PITCH_DEG = 50.0
CAMERA_FOVY_DEG = 58.0
CAMERA_FOVX_DEG = 87.0

#: Bodies whose contact with the ground ends an episode.
TERMINATION_BODIES: tuple[str, ...] = ("base", "thigh_L", "thigh_R")
#: Bodies whose contact with the ground counts as a collision in the reward.
COLLISION_BODIES: tuple[str, ...] = ("thigh_L", "thigh_R", "shank_L", "shank_R", "abad_L", "abad_R")


def asset_path() -> Path:
    """Path of the packaged MJCF (``assets/tron1_pointfoot.xml``)."""
    packaged = resources.files("tron1cli") / "assets" / "tron1_pointfoot.xml"
    if packaged.is_file():
        return Path(str(packaged))
    return Path(__file__).resolve().parents[2] / "assets" / "tron1_pointfoot.xml"


def load_spec(path: Path | None = None) -> mujoco.MjSpec:
    """Load the robot MJCF as an editable spec; raises FileNotFoundError with the path if missing."""
    path = path or asset_path()
    if not path.is_file():
        raise FileNotFoundError(f"robot model not found: {path}")
    spec = mujoco.MjSpec.from_file(str(path))
    names = tuple(a.name for a in spec.actuators)
    if names != JOINT_NAMES:
        raise ValueError(f"{path}: actuator order {names} differs from JOINT_NAMES {JOINT_NAMES}")
    return spec
