"""Restitution as the paper's simulator (PhysX in Isaac Lab) has it, reproduced in MuJoCo and
measured: a foot dropped onto the ground at the impact speeds the robot sees."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from tron1cli.env import robot
from tron1cli.env.physics import BatchedPhysics
from tron1cli.env.randomization import (
    RandomizationConfig,
    Randomizer,
    combined_restitution,
    damping_ratio_for_restitution,
    impact_damping_ratio,
)

_DROP = f"""
<mujoco>
  <option timestep="0.005" integrator="implicitfast"/>
  <default><geom solref="0.02 1"/></default>
  <worldbody>
    <geom name="ground" type="plane" size="0 0 1"/>
    <body name="base" pos="0 0 1"><freejoint/>
      <geom name="foot_L_geom" type="sphere" size="{robot.FOOT_RADIUS}" mass="1.5"/></body>
    <body name="other" pos="1 0 {robot.FOOT_RADIUS}"><freejoint/>
      <geom name="foot_R_geom" type="sphere" size="{robot.FOOT_RADIUS}" mass="1.5"/></body>
  </worldbody>
</mujoco>
"""


def measured_restitution(impact_speed: float, cfg: RandomizationConfig | None) -> float:
    """Rebound speed over impact speed of the foot sphere dropped at ``impact_speed`` (m/s), the
    env's gate (:meth:`Randomizer.gate_restitution`) run before every 20 ms policy step."""
    model = mujoco.MjModel.from_xml_string(_DROP)
    rnd = None
    if cfg is not None:
        rnd = Randomizer(cfg, BatchedPhysics([model], 4, nthread=1), 0.005, 4)
        rnd.apply(np.array([0]), np.random.default_rng(0))
    data = mujoco.MjData(model)
    r = robot.FOOT_RADIUS
    gap = 0.3 * impact_speed**2 / (2 * 9.81)  # lands within the first policy step
    data.qpos[2] = r + gap
    v0 = np.sqrt(impact_speed**2 - 2 * 9.81 * gap)
    data.qvel[2] = -v0
    approach, rebound, touched = 0.0, 0.0, False
    for _ in range(40):  # 0.8 s of policy steps
        if rnd is not None:
            in_contact = np.array([[data.qpos[2] - r < 1e-4, True]])
            rnd.gate_restitution(in_contact, np.array([[data.qvel[2], 0.0]]))
        for _ in range(4):
            vz = float(data.qvel[2])
            mujoco.mj_step(model, data)
            if (
                data.ncon
                and not touched
                and any(c.geom1 == 1 or c.geom2 == 1 for c in data.contact[: data.ncon])
            ):
                touched, approach = True, -vz
            if touched:
                rebound = max(rebound, float(data.qvel[2]))
    if rnd is not None:
        rnd.physics.close()
    assert touched and approach == pytest.approx(impact_speed, rel=0.1)
    return rebound / approach


HALF = dict(terms=("restitution",), restitution=(0.5, 0.5))


def test_combine_modes_as_physx() -> None:
    e = np.array([0.25, 0.75])
    assert np.allclose(combined_restitution(e, 1.0, "multiply"), e)  # LimX's TRON1 terrain
    assert np.allclose(combined_restitution(e, 0.0, "multiply"), 0.0)  # Isaac Lab's own terrain
    assert np.allclose(combined_restitution(e, 0.0, "average"), 0.5 * e)
    assert np.allclose(combined_restitution(e, 0.5, "max"), [0.5, 0.75])
    with pytest.raises(ValueError):
        RandomizationConfig(restitution_combine="sum")


def test_nominal_mujoco_contact_does_not_bounce() -> None:
    for v in (0.3, 0.7, 1.3):
        assert measured_restitution(v, None) < 0.15  # MuJoCo's soft contact: 0.08-0.13


@pytest.mark.parametrize("speed", [0.7, 1.3])  # the shipped policy's median and 99th percentile touchdowns
@pytest.mark.parametrize("e", [0.25, 0.5, 0.75])  # Table III's range and its middle
def test_impacts_above_the_bounce_threshold_bounce_with_the_combined_restitution(
    speed: float, e: float
) -> None:
    cfg = RandomizationConfig(terms=("restitution",), restitution=(e, e))
    assert measured_restitution(speed, cfg) == pytest.approx(e, abs=0.05)


def test_impact_damping_ratio_follows_the_measured_curve() -> None:
    e = np.array([0.1, 0.25, 0.5, 0.75, 1.0])
    zeta = impact_damping_ratio(e)
    assert zeta[0] == 1.0  # below MuJoCo's own rebound: no bounce armed
    assert np.all(np.diff(zeta[1:]) < 0)  # more restitution, less damping
    assert zeta[2] == pytest.approx(0.25, abs=0.01)  # measured: zeta 0.25 rebounds 0.503
    # the spring-damper formula would ask for less damping than MuJoCo's discrete contact needs
    assert zeta[1] > damping_ratio_for_restitution(np.array([0.25]))[0] + 0.1


def test_slow_impacts_and_isaac_labs_own_terrain_do_not_bounce() -> None:
    nominal = measured_restitution(0.3, None)
    assert measured_restitution(0.3, RandomizationConfig(**HALF)) == pytest.approx(nominal)  # below 0.5 m/s
    nominal = measured_restitution(1.0, None)
    assert measured_restitution(1.0, RandomizationConfig(**HALF, ground_restitution=0.0)) == pytest.approx(
        nominal
    )


def test_the_earlier_damping_mapping_bounces_at_every_speed() -> None:
    cfg = RandomizationConfig(**HALF, restitution_model="damping")
    assert measured_restitution(0.3, cfg) == pytest.approx(0.5, abs=0.15)
    assert damping_ratio_for_restitution(np.array([0.5]))[0] == pytest.approx(0.2155, abs=1e-3)
