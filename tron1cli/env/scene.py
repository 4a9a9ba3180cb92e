"""Build the MuJoCo world of one env: our TRON1 model standing on the ground.

The ground is a plane on flat terrain, otherwise a height field holding one tile of a
:class:`~tron1cli.env.terrain.TerrainBank`, centred on the world origin where the robot spawns.
Every env's model has the same height-field size and z range (those of the whole bank), so a
tile is swapped by rewriting ``hfield_data`` alone (:func:`set_tile`).
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from tron1cli.env import robot
from tron1cli.env.terrain import TerrainBank

GROUND_NAME = "ground"
HFIELD_BASE_M = 0.5  #: thickness of the height field's solid base below its lowest point (m)


def _ground_style() -> dict:
    return dict(name=GROUND_NAME, contype=1, conaffinity=0, rgba=[0.55, 0.6, 0.55, 1.0])


def build_model(
    sim_dt: float = 0.005,
    bank: TerrainBank | None = None,
    asset: Path | None = None,
    all_tiles: bool = False,
) -> mujoco.MjModel:
    """The robot on the ground, with physics step ``sim_dt`` (s).

    bank: terrain tiles; None or an all-flat bank gives a plane. The ground is the only geom the
    robot collides with (contype 1 / conaffinity 0 against the robot's contype 0 / conaffinity 1),
    so there are no self-collisions.
    all_tiles: one height field per tile of the bank (tile k in height field k), the ground on
    tile 0; an engine that batches ``geom_dataid`` puts each world on its own tile by pointing
    the ground at another height field. Default: one height field, written by :func:`set_tile`.
    """
    spec = robot.load_spec(asset)
    spec.option.timestep = sim_dt
    if bank is None or not np.any(bank.heights):
        spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0.0, 0.0, 1.0], **_ground_style())
        return spec.compile()
    lo, hi = hfield_range(bank)
    half = (bank.R - 1) / 2 * bank.res
    names = [f"terrain_{k}" for k in range(bank.K)] if all_tiles else ["terrain"]
    for name in names:
        spec.add_hfield(
            name=name,
            nrow=bank.R,
            ncol=bank.R,
            size=[half, half, hi - lo, HFIELD_BASE_M],
            userdata=np.zeros(bank.R * bank.R).tolist(),
        )
    spec.worldbody.add_geom(
        type=mujoco.mjtGeom.mjGEOM_HFIELD, hfieldname=names[0], pos=[0, 0, lo], **_ground_style()
    )
    model = spec.compile()
    for k in range(len(names)):
        set_tile(model, bank, k, hfield=k)
    return model


def hfield_range(bank: TerrainBank) -> tuple[float, float]:
    """Lowest and highest terrain height of the bank (m); a flat bank gets a 1 cm range."""
    lo, hi = float(bank.heights.min()), float(bank.heights.max())
    return lo, max(hi, lo + 0.01)


def set_tile(model: mujoco.MjModel, bank: TerrainBank, tile: int, hfield: int = 0) -> None:
    """Write tile ``tile`` of ``bank`` into the model's height field ``hfield`` (row 0 at -y,
    column 0 at -x).

    The bank's height range is read back from the model (the ground's z offset and the height
    field's z size, set by :func:`build_model`), not recomputed over the whole bank per call.
    """
    lo = float(model.geom(GROUND_NAME).pos[2])
    span = float(model.hfield_size[hfield, 2])
    adr = int(model.hfield_adr[hfield])
    model.hfield_data[adr : adr + bank.R * bank.R] = ((bank.heights[tile] - lo) / span).ravel()
