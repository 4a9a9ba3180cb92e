"""Build the MuJoCo world of one env: our TRON1 model standing on the ground."""

from __future__ import annotations

from pathlib import Path

import mujoco

from tron1cli.env import robot

GROUND_NAME = "ground"


def build_model(sim_dt: float = 0.005, asset: Path | None = None) -> mujoco.MjModel:
    """The robot on a flat ground plane, with physics step ``sim_dt`` (s).

    The ground is the only geom the robot collides with (contype 1 / conaffinity 0 against the
    robot's contype 0 / conaffinity 1), so there are no self-collisions.
    """
    spec = robot.load_spec(asset)
    spec.option.timestep = sim_dt
    spec.worldbody.add_geom(
        name=GROUND_NAME,
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[0.0, 0.0, 1.0],
        contype=1,
        conaffinity=0,
        rgba=[0.55, 0.6, 0.55, 1.0],
    )
    return spec.compile()
