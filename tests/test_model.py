"""Our TRON1 MJCF against the public figures (tron1-facts.md)."""

import mujoco
import numpy as np
import pytest

from tron1cli.env import robot
from tron1cli.env.scene import build_model


@pytest.fixture(scope="module")
def model():
    return build_model()


def test_total_mass(model):
    assert model.body_subtreemass[0] == pytest.approx(robot.TOTAL_MASS, abs=0.05)


def test_zero_pose_heights(model):
    d = mujoco.MjData(model)
    d.qpos[2] = 1.0  # base origin 1 m above the world origin
    mujoco.mj_forward(model, d)
    soles = [d.site(f"{f}_site").xpos[2] - robot.FOOT_RADIUS for f in robot.FOOT_NAMES]
    assert soles[0] == pytest.approx(soles[1], abs=1e-9)
    assert 1.0 - soles[0] == pytest.approx(0.812, abs=0.005)
    com_z = d.subtree_com[model.body("base").id][2]
    assert com_z - soles[0] == pytest.approx(0.561, abs=0.005)


def test_crouched_pose_heights(model):
    """Hip +/-0.4, knee +/-0.8 (L +, R -): base 0.654 m and CoM 0.416 m above the soles (facts)."""
    d = mujoco.MjData(model)
    d.qpos[2] = 1.0
    d.qpos[7:] = [0.0, 0.4, 0.8, 0.0, -0.4, -0.8]
    mujoco.mj_forward(model, d)
    sole = d.site("foot_L_site").xpos[2] - robot.FOOT_RADIUS
    assert d.site("foot_R_site").xpos[2] - robot.FOOT_RADIUS == pytest.approx(sole, abs=1e-9)
    assert 1.0 - sole == pytest.approx(0.654, abs=0.005)
    assert d.subtree_com[1][2] - sole == pytest.approx(0.416, abs=0.005)


def test_joint_order_and_ranges(model):
    names = tuple(model.joint(i).name for i in range(1, model.njnt))
    assert names == robot.JOINT_NAMES
    np.testing.assert_allclose(model.jnt_range[1:], robot.JOINT_RANGES)
    assert tuple(model.actuator(i).name for i in range(model.nu)) == robot.JOINT_NAMES
    np.testing.assert_allclose(model.actuator_forcerange, [[-80, 80]] * 6)
    np.testing.assert_allclose(model.actuator_gainprm[:, 0], robot.KP)
    np.testing.assert_allclose(model.actuator_biasprm[:, 2], -robot.KD)


def test_camera_and_imu_exist(model):
    cam = model.camera(robot.CAMERA_NAME)
    assert cam.fovy[0] == pytest.approx(robot.CAMERA_FOVY_DEG)
    np.testing.assert_allclose(cam.pos, robot.CAMERA_POS)
    # optical axis (-z of the camera) points forward and 50 deg below the horizon
    d = mujoco.MjData(model)
    mujoco.mj_forward(model, d)
    axis = -d.cam_xmat[cam.id].reshape(3, 3)[:, 2]
    assert axis[0] > 0
    assert np.degrees(np.arcsin(-axis[2])) == pytest.approx(robot.CAMERA_PITCH_DEG, abs=0.01)
    assert model.site("imu").id >= 0


def _fixed_base_model():
    spec = robot.load_spec()
    spec.delete(spec.joint("root"))
    return spec.compile()


def test_pd_drives_joints_with_the_base_held():
    """With the base fixed in the air, PD reaches mirrored targets within 0.1 rad in 0.5 s."""
    m = _fixed_base_model()
    d = mujoco.MjData(m)
    target = np.array([0.0, 0.4, 0.8, 0.0, -0.4, -0.8])
    d.ctrl[:] = target
    for _ in range(int(0.5 / m.opt.timestep)):
        mujoco.mj_step(m, d)
    q = d.qpos.copy()
    assert np.all(np.abs(q - target) < 0.1)
    assert np.all(np.sign(q[[1, 2]]) == 1) and np.all(np.sign(q[[4, 5]]) == -1)
    # mirrored commands give a mirrored pose: feet at the same x, z and opposite y
    fl, fr = d.site("foot_L_site").xpos, d.site("foot_R_site").xpos
    np.testing.assert_allclose([fl[0], fl[2]], [fr[0], fr[2]], atol=2e-3)
    assert fl[1] == pytest.approx(-fr[1], abs=2e-3)


def test_missing_asset_is_a_clear_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="robot model not found"):
        robot.load_spec(tmp_path / "nope.xml")


_INCLINE = """<mujoco><option timestep="{dt}" integrator="implicitfast" cone="{cone}" impratio="{imp}"/>
<worldbody><geom type="plane" size="5 5 .1" axisangle="{axis} {deg}" friction="{mu} 0.005 0.0001"/>
<body pos="0 0 0.06"><joint type="slide" axis="1 0 0"/><joint type="slide" axis="0 1 0"/>
<joint type="slide" axis="0 0 1"/><geom type="sphere" size="0.03" mass="2" friction="{mu} 0.005 0.0001"/>
</body></worldbody></mujoco>"""


@pytest.mark.parametrize("axis", ["0 1 0", "0.7071 0.7071 0"])  # down-slope along x; diagonal
def test_point_foot_holds_a_slope_as_coulomb_says(model, axis):
    """With the asset's contact model a point foot (a sphere that cannot roll) on the hardest slope
    (32.1 deg, tan 0.628) holds at friction 0.7 whichever way the slope falls, and slides at 0.5:
    Coulomb's threshold, not the pyramidal cone's (which let it slide at 0.8 on the diagonal)."""
    from tron1cli.env.terrain import TerrainConfig

    cone = {mujoco.mjtCone.mjCONE_ELLIPTIC: "elliptic", mujoco.mjtCone.mjCONE_PYRAMIDAL: "pyramidal"}
    deg = np.degrees(np.arctan(TerrainConfig().slope_tan[1]))
    speed = {}
    for mu in (0.5, 0.7):
        xml = _INCLINE.format(
            dt=model.opt.timestep,
            cone=cone[model.opt.cone],
            imp=model.opt.impratio,
            axis=axis,
            deg=deg,
            mu=mu,
        )
        m = mujoco.MjModel.from_xml_string(xml)
        d = mujoco.MjData(m)
        mujoco.mj_step(m, d, round(1.0 / m.opt.timestep))  # settle
        x0 = d.qpos.copy()
        mujoco.mj_step(m, d, round(2.0 / m.opt.timestep))
        speed[mu] = np.linalg.norm(d.qpos - x0) / 2.0
    assert speed[0.7] < 0.002  # m/s: held (creep under 2 mm/s)
    assert speed[0.5] > 0.5  # below tan(32.1 deg) it slides away
