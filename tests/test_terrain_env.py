"""The env core on terrain, with sensors, Table III randomisation, pushes and the curriculum."""

import numpy as np
import pytest

from tron1cli.config import EnvConfig, GaitConfig, NoiseConfig
from tron1cli.env.core import Tron1Env
from tron1cli.env.math3d import yaw_of
from tron1cli.env.randomization import (
    PushConfig,
    RandomizationConfig,
    damping_ratio_for_restitution,
    impact_damping_ratio,
)
from tron1cli.env.sensors import render_depth
from tron1cli.env.terrain import TERRAIN_GROUPS

FULL = dict(perception=True, randomization=RandomizationConfig.table_iii(), pushes=PushConfig.moderate())


def make(terrain="stairs", n=8, **kw):
    cfg = (
        dict(num_envs=n, nthread=1, terrain=terrain, gait=GaitConfig(enabled=False), depth_from=n // 2) | FULL
    )
    cfg.update(kw)
    return Tron1Env(EnvConfig(**cfg))


@pytest.mark.parametrize("terrain", sorted(TERRAIN_GROUPS))
def test_every_terrain_steps_with_all_sensors_and_randomisation(terrain):
    env = make(terrain, max_init_level=9)
    obs = env.reset()
    rng = np.random.default_rng(0)
    for _ in range(20):
        res = env.step(rng.normal(0, 0.3, (8, 6)))
    for k, shape in {
        "proprio": (8, 27),
        "privileged": (8, 51),
        "heightmap": (8, 441),
        "depth": (8, 60, 80),
    }.items():
        assert res.obs[k].shape == shape, k
        assert np.isfinite(res.obs[k]).all(), k
    assert obs["depth"][4:].max() <= env.camera.far
    env.close()


def test_randomised_quantities_stay_in_range_and_differ_between_envs():
    env = make("flat", n=32)
    env.reset()
    ms = env.physics.models
    base = ms[0].body("base").id
    mass = np.array([m.body_mass[base] for m in ms])
    nominal = env.randomizer.nominal_mass
    assert ((mass >= nominal - 1) & (mass <= nominal + 3)).all() and mass.std() > 0.3
    shift = np.array([m.body_ipos[base] for m in ms]) - env.randomizer.nominal_ipos
    assert (np.abs(shift) <= [0.03, 0.02, 0.03]).all() and shift.std(axis=0).min() > 0.005
    fric = np.array([m.geom_friction[m.geom("ground").id, 0] for m in ms])
    assert ((fric >= 0.4) & (fric <= 1.2)).all() and fric.std() > 0.1
    zeta = env.randomizer.impact_zeta  # the damping ratio of a foot's impact above 0.5 m/s
    lo, hi = impact_damping_ratio(np.array([0.75, 0.25]))
    assert ((zeta >= lo - 1e-9) & (zeta <= hi + 1e-9)).all() and zeta.std() > 0.02
    resting = np.array([m.geom_solref[m.geom("foot_L_geom").id] for m in ms])
    assert np.allclose(resting, [0.02, 1.0])  # feet at rest: MuJoCo's critically damped contact
    kp = np.array([m.actuator_gainprm[0, 0] for m in ms])
    assert ((kp >= 40 * 0.64 - 1e-9) & (kp <= 40 * 1.44 + 1e-9)).all() and kp.std() > 1
    limit = np.array([m.actuator_forcerange[0, 1] for m in ms])
    assert ((limit >= 64 - 1e-9) & (limit <= 96 + 1e-9)).all()
    d = env.randomizer.delay_steps
    assert ((d >= 0) & (d <= 4)).all() and len(set(d.tolist())) > 1
    assert (np.abs(env.randomizer.camera_offset) <= 0.01).all()
    assert (np.abs(np.degrees(env.randomizer.camera_pitch)) <= 1.0).all()
    env.close()


def test_restitution_to_damping_ratio():
    # e = exp(-pi zeta / sqrt(1 - zeta^2)): zeta = 0.5 gives e = exp(-pi / sqrt(3)) = 0.1630
    np.testing.assert_allclose(damping_ratio_for_restitution(np.array([np.exp(-np.pi / np.sqrt(3))])), [0.5])


def test_delay_holds_the_old_target():
    env = make("flat", n=4, randomization=RandomizationConfig(terms=("delay",), delay_s=(0.01, 0.01)))
    env.reset()
    env.step(np.zeros((4, 6)))
    a = np.ones((4, 6))
    env.step(a)
    ctrl = env.physics.control[:, :, :6]
    np.testing.assert_allclose(ctrl[:, :2], 0.0)  # 10 ms = 2 substeps of the old (default) target
    np.testing.assert_allclose(ctrl[:, 2:], 0.25)
    env.close()


def test_push_applies_the_requested_wrench():
    """A pure force on the base changes the whole robot's momentum by F dt (measured in the sim)."""
    env = make("flat", n=2, randomization=RandomizationConfig(), pushes=PushConfig())
    env.reset()
    env.physics.state[:, 3] = 5.0  # lift both robots high into the air: no contact
    force = np.array([[40.0, -30.0, 20.0, 0, 0, 0], [0.0, 0.0, 0.0, 0, 0, 0]])
    env.physics.forward(np.arange(2), env.targets)
    v0 = env.physics.sensordata[:, -1, env.physics.sensor_slices["com_vel"]].copy()
    env.external_wrench[:] = force
    env.physics.step(env._ctrl, env.external_wrench)
    v1 = env.physics.sensordata[:, -1, env.physics.sensor_slices["com_vel"]]
    dt = 3 * env.cfg.sim_dt  # the sensor row lags the state by one substep
    mass = env.physics.models[0].body_subtreemass[1]
    dv = v1 - v0 - np.array([0, 0, -9.81]) * dt
    np.testing.assert_allclose(dv[0], force[0, :3] / mass * dt, atol=2e-3)
    np.testing.assert_allclose(dv[1], 0.0, atol=2e-3)
    env.close()


def test_pushes_are_in_range_and_in_the_teacher_observation():
    env = make(
        "flat",
        n=64,
        randomization=RandomizationConfig(),
        pushes=PushConfig(enabled=True, interval_s=(0.02, 0.1), duration_s=0.1),
    )
    env.reset()
    res = env.step(np.zeros((64, 6)))
    res = env.step(np.zeros((64, 6)))
    w = env.external_wrench
    assert (np.abs(w[:, :3]) <= 50).all() and (np.abs(w[:, 3:]) <= 5).all() and np.abs(w).max() > 10
    sl = env.layout.slices("privileged")["external_force"]
    np.testing.assert_allclose(res.obs["privileged"][~res.done, sl], w[~res.done, :3] / 50.0, rtol=1e-5)
    env.close()


def test_extreme_preset():
    assert PushConfig.extreme().force_n == (400.0, 400.0, 400.0) and PushConfig.extreme().torque_nm[0] == 20.0


def test_a_staggered_first_episode_moves_no_level_and_reports_its_true_length():
    """After reset(stagger=True) (every start or resume of a training run) each env's first episode
    begins at a random point of the clock, so a time-out cuts it short: it must not read as a slow
    walker and demote its env; a full episode that walked nowhere is demoted as before."""
    env = make(
        "stairs",
        n=8,
        max_init_level=0,
        perception=False,
        randomization=RandomizationConfig(),
        pushes=PushConfig(),
    )
    env.reset(stagger=True)
    env.curriculum.level[:] = 3
    env.curriculum.tile[:] = env.bank.tile_index(env.curriculum.kind, env.curriculum.level, np.zeros(8, int))
    env.commands.set(np.arange(8), np.tile([0.5, 0.0, 0.0], (8, 1)))  # 10 m asked over 20 s
    last = env.max_episode_steps - 1
    env.episode_step[:] = last  # all time out at the next step
    env._steps_since_reset[4:] = last  # envs 4-7 walked a whole episode (nowhere), 0-3 one step
    env.physics.state[4:, 0] = last * env.policy_dt  # their sim clock agrees (else: "diverged")
    res = env.step(np.zeros((8, 6)))
    assert res.time_out.all()
    np.testing.assert_array_equal(res.episode["staggered"], [True] * 4 + [False] * 4)
    np.testing.assert_allclose(res.episode["length_s"], [0.02] * 4 + [20.0] * 4)
    assert env.curriculum.level.tolist() == [3] * 4 + [2] * 4
    env.close()


def test_held_depth_frames_and_scans_after_resets():
    """Observations keep their depth frames (renders replace the array, never write into it); a
    student that just reset holds a capture of its new pose, or an empty frame until the next
    30 Hz capture; the scan patched after resets equals a full scan of the new state."""
    env = make("stairs", n=8, max_init_level=5, noise=NoiseConfig(enabled=False))
    first = env.reset()
    kept = first["depth"].copy()
    rng = np.random.default_rng(1)
    seen = {"captured": 0, "empty": 0}
    for k in range(16):
        if k % 3 == 1:
            env.episode_step[[2, 6]] = env.max_episode_steps - 1  # a teacher and a student time out
        res = env.step(rng.normal(0, 0.3, (8, 6)))
        s = env.state
        scan = env.height_scan.scan(
            env.bank.heights, env.curriculum.tile, s.base_pos, yaw_of(s.base_quat), env.bank.res
        )
        np.testing.assert_array_equal(res.obs["heightmap"], scan)
        if res.time_out[6]:
            pos, rot = env.camera_pose(np.array([6]))
            fresh = render_depth(
                env.bank.heights,
                env.curriculum.tile[[6]],
                pos,
                rot,
                env.camera,
                env.bank.res,
                ray_scale=env.depth_ray_scale(np.array([6])),
            )
            if np.array_equal(res.obs["depth"][6], fresh[0]):
                seen["captured"] += 1
            else:
                assert np.all(res.obs["depth"][6] == 0.0)
                seen["empty"] += 1
                nxt = env.step(np.zeros((8, 6))).obs["depth"][6]  # captures are never two steps apart
                assert not np.any(nxt == 0.0)
    assert seen["captured"] >= 1 and seen["empty"] >= 1, seen
    np.testing.assert_array_equal(first["depth"], kept)
    assert not np.array_equal(env.obs["depth"][4:], kept[4:])
    env.close()


def test_same_seed_same_terrain_and_trajectory():
    def run():
        env = make("mixed", n=6, seed=5, max_init_level=5)
        env.reset()
        out = [env.step(np.full((6, 6), 0.2)).obs["privileged"].copy() for _ in range(15)]
        tiles = env.curriculum.tile.copy()
        env.close()
        return np.stack(out), tiles

    (a, ta), (b, tb) = run(), run()
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(ta, tb)


def test_bench_reports_sensor_rates():
    from tron1cli.benchmark import run_bench

    res = run_bench(num_envs=8, steps=3, warmup=1, nthread=1, terrain="stairs", depth=True)
    assert res["terrain"] == "stairs" and res["depth"] is True
    keys = (
        "raw_steps_per_s",
        "env_steps_per_s",
        "env_depth_steps_per_s",
        "heightmaps_per_s",
        "depth_images_per_s",
    )
    for key in keys:
        assert res[key] > 0
    assert res["depth_ms_per_image"] == pytest.approx(1e3 / res["depth_images_per_s"])
    assert res["depth_ratio"] == pytest.approx(res["env_depth_steps_per_s"] / res["raw_steps_per_s"])


def test_lipm_ground_is_the_windowed_terrain_mean_under_the_com():
    from tron1cli.env.terrain import mean_ground_height

    env = make("stairs", n=4, max_init_level=9, perception=False, randomization=RandomizationConfig())
    env.reset()
    env.step(np.zeros((4, 6)))
    com_xy = env.state.com_pos[:, :2]
    side = env.reward_cfg.lipm_ground_window_m
    expected = mean_ground_height(env.bank.heights, env.curriculum.tile, com_xy, env.bank.res, side)
    assert side > 0 and np.allclose(env.lipm.z, env.state.com_pos[:, 2] - expected)
    env.close()
    flat = make("flat", n=2, perception=False, randomization=RandomizationConfig())
    flat.reset()
    flat.step(np.zeros((2, 6)))
    assert np.array_equal(flat.lipm.z, flat.state.com_pos[:, 2])  # a plane: the CoM height itself
    flat.close()


def test_one_terrain_type_is_a_terrain_name():
    from tron1cli.env.terrain import resolve_terrain, terrain_choices
    from tron1cli.evaluation.protocol import resolve_eval_terrains

    assert resolve_terrain("stairs_up") == ("stairs_up",)
    assert resolve_terrain("stairs") == ("stairs_up", "stairs_down")
    assert resolve_eval_terrains("slope_down") == ("slope_down",)
    assert "(or one type: " in terrain_choices() and "stairs_up" in terrain_choices()
    with pytest.raises(ValueError, match="or one type: flat, rough, slope_up"):
        resolve_terrain("lava")
