"""The batched env core: shapes, layout, determinism, terminations, resets."""

from dataclasses import replace

import numpy as np
import pytest

from tron1cli.config import CommandConfig, EnvConfig, GaitConfig, NoiseConfig, TerminationConfig
from tron1cli.env import robot, terminations
from tron1cli.env.core import Tron1Env
from tron1cli.env.math3d import yaw_of
from tron1cli.env.observations import ObsLayout
from tron1cli.env.rewards import make_reward_config

PAPER = GaitConfig(enabled=False)  # the paper's layout exactly: no gait clock


def make_env(n=16, **kw) -> Tron1Env:
    kw.setdefault("gait", PAPER)
    return Tron1Env(EnvConfig(num_envs=n, nthread=2, **kw))


def test_layout_sizes_match_table_i():
    lay = ObsLayout(history_len=5)
    assert lay.proprio_dim == 27
    assert lay.privileged_dim == 51
    assert lay.history_dim == 5 * 27
    sl = lay.slices("privileged")
    assert sl["external_force"] == slice(48, 51)
    assert sl["last_action"] == slice(21, 27)


def test_step_shapes_and_finite():
    env = make_env(32, history_len=3)
    obs = env.reset()
    assert obs["proprio"].shape == (32, 27)
    assert obs["history"].shape == (32, 81)
    assert obs["privileged"].shape == (32, 51)
    rng = np.random.default_rng(0)
    for _ in range(60):
        res = env.step(rng.normal(0, 0.3, (32, 6)))
        for v in res.obs.values():
            assert np.isfinite(v).all()
        assert res.done.shape == (32,)
    # the newest history entry is the current o_t
    np.testing.assert_array_equal(res.obs["history"][:, -27:], res.obs["proprio"])
    env.close()


def test_pd_targets_are_default_plus_scaled_action():
    env = make_env(4)
    env.reset()
    a = np.tile([1.0, -2.0, 0.5, 0.0, 3.0, -1.0], (4, 1))
    env.step(a)
    np.testing.assert_allclose(env.targets, robot.DEFAULT_POSE + 0.25 * a)
    np.testing.assert_allclose(env.physics.control[:, :, :6], np.repeat(env.targets[:, None], 4, axis=1))
    # torques never exceed the motors' 80 N m
    assert np.abs(env.state.joint_torque).max() <= robot.TORQUE_LIMIT + 1e-9
    env.close()


def _rollout(seed):
    env = make_env(8, seed=seed)
    env.reset()
    rng = np.random.default_rng(123)
    traj = []
    for _ in range(80):
        res = env.step(rng.normal(0, 0.5, (8, 6)))
        traj.append(res.obs["privileged"].copy())
    env.close()
    return np.stack(traj)


def test_same_seed_same_trajectory_bit_for_bit():
    a, b = _rollout(3), _rollout(3)
    np.testing.assert_array_equal(a, b)
    c = _rollout(4)
    assert not np.array_equal(a, c)


def test_noise_only_on_the_student_copy():
    env = make_env(8)
    obs = env.reset()
    lay = env.layout
    p = obs["proprio"][:, lay.slices("proprio")["joint_pos"]]
    e = obs["privileged"][:, lay.slices("privileged")["joint_pos"]]
    assert not np.allclose(p, e)
    assert np.abs(p - e).max() < 0.06  # 0.01 rad sigma
    env.close()
    quiet = make_env(8, noise=NoiseConfig(enabled=False))
    obs = quiet.reset()
    np.testing.assert_array_equal(obs["proprio"], obs["privileged"][:, :27])
    quiet.close()


def test_time_out_is_not_a_failure():
    env = make_env(
        4,
        termination=TerminationConfig(episode_length_s=0.1, max_roll=10, max_pitch=10, contact_bodies=False),
    )
    env.reset()
    for _ in range(5):
        res = env.step(np.zeros((4, 6)))
    assert res.time_out.all() and not res.failed.any()
    np.testing.assert_allclose(res.episode["length_s"], 0.1)
    assert (env.episode_step == 0).all()
    env.close()


def test_falls_terminate_and_reset():
    env = make_env(16)
    env.reset()
    failed = 0
    for _ in range(150):  # 3 s of zero action: a point-foot biped falls
        res = env.step(np.zeros((16, 6)))
        failed += res.failed.sum()
        assert not res.time_out.any()
    assert failed >= 16
    assert (env.state.base_pos[:, 2] > 0.3).all()  # every fallen env was put back up
    env.close()


def test_unstable_sim_resets_that_env_and_counts_it():
    env = make_env(4)
    env.reset()
    env.physics.state[2, env.physics.qvel_slice] = 1e9  # blow one world up
    res = env.step(np.zeros((4, 6)))
    assert res.unstable.tolist() == [False, False, True, False]
    assert env.unstable_count == 1
    assert np.isfinite(env.physics.state).all()
    assert env.episode_step[2] == 0
    env.close()


def test_fall_causes_of_one_step_hand_built():
    """Tilt past either limit and each termination body's contact, per env; an unstable world and
    a switched-off body contact are no causes; a time-out is no fall."""
    cfg = TerminationConfig(max_roll=0.8, max_pitch=0.8)
    up = np.array([0.0, 0.0, -1.0])
    rolled = np.array([0.0, np.sin(1.0), -np.cos(1.0)])  # 1 rad of roll
    gravity = np.array([up, rolled, up, up, rolled, up])
    contact = np.zeros((6, 3), dtype=bool)
    contact[2, 0] = contact[3, 2] = contact[1, 0] = True  # base (env 1 and 2), thigh_R (env 3)
    unstable = np.array([False, False, False, False, True, False])
    steps = np.array([1, 1, 1, 1, 1, 100])
    t = terminations.check(cfg, gravity, contact, unstable, steps, 100)
    assert terminations.FALL_CAUSES == ("tilt", "base", "thigh_L", "thigh_R")
    assert t.failed.tolist() == [False, True, True, True, False, False]
    assert t.time_out.tolist() == [False] * 5 + [True]
    assert [terminations.cause_words(c) for c in t.causes] == ["", "tilt+base", "base", "thigh_R", "", ""]
    off = terminations.check(replace(cfg, contact_bodies=False), gravity, contact, unstable, steps, 100)
    assert [terminations.cause_words(c) for c in off.causes] == ["", "tilt", "", "", "", ""]
    base_only = replace(cfg, bodies=("base",))  # a thigh on the ground is no fall
    t = terminations.check(base_only, gravity, contact, unstable, steps, 100)
    assert [terminations.cause_words(c) for c in t.causes] == ["", "tilt+base", "base", "", "", ""]
    assert base_only.judged(5.0) == replace(cfg, episode_length_s=5.0)  # evaluation counts them all
    assert TerminationConfig(bodies=("thigh_R", "base")).bodies == ("base", "thigh_R")  # one spelling


def test_a_robot_laid_on_its_side_falls_by_tilt():
    env = make_env(2)
    env.reset()
    qpos = env.physics.state[:, env.physics.qpos_slice]
    qpos[0, 3:7] = [np.cos(0.5), np.sin(0.5), 0.0, 0.0]  # env 0 rolled by 1 rad
    env.physics.state[:, env.physics.qpos_slice] = qpos
    res = env.step(np.zeros((2, 6)))
    assert res.failed.tolist() == [True, False]
    assert res.fall_causes[0, 0] and not res.fall_causes[1].any()
    env.close()


def test_commands_in_range_with_standing_share():
    env = make_env(512)
    env.reset()
    c = env.commands.value
    cfg = env.cfg.commands
    assert (c[:, 0] >= cfg.lin_vel_x[0]).all() and (c[:, 0] <= cfg.lin_vel_x[1]).all()
    assert (np.abs(c[:, 2]) <= cfg.ang_vel_yaw[1]).all()
    standing = (c == 0).all(axis=1).mean()
    assert 0.03 < standing < 0.2
    env.close()


def test_face_climb_commands_forward_on_stairs_and_slopes_only():
    """With face_climb, envs on stairs and slopes get v_x >= 0 and no v_y; the others keep the
    whole range (both signs of v_x, sideways speed)."""
    env = make_env(280, terrain="mixed", commands=CommandConfig(face_climb=True))
    env.reset()
    for _ in range(3):  # three draws per env
        env.commands.resample(np.arange(env.n), env.rng)
        types = np.asarray(env.bank.types)[env.curriculum.kind]
        climb = np.isin(types, ["stairs_up", "stairs_down", "slope_up", "slope_down"])
        c = env.commands.value
        assert (env.commands.facing == climb).all()
        assert (c[climb, 0] >= 0).all() and (c[climb, 1] == 0).all()
        assert (c[~climb, 0] < 0).any() and (c[~climb, 1] != 0).any()
        assert (c[climb, 2] < 0).any()  # the yaw rate keeps both signs
    env.close()


def test_heading_mode_steers_the_yaw_rate_to_a_world_heading():
    """Heading mode: the yaw-rate command is 0.5/s x the wrapped heading error, clipped to the
    yaw range; standing and imposed commands are not steered; a robot that holds its heading is
    asked for no turn."""
    from tron1cli.env.commands import Commands

    cmds = Commands(CommandConfig(heading=True, standing_share=0.0), 4)
    cmds.resample(np.arange(4), np.random.default_rng(0))
    assert (cmds.value[:, 2] == 0).all() and cmds.steering.all()
    cmds.steer(np.zeros(4))  # anchors the drawn headings to the robot's yaw
    cmds.heading[:] = [0.2, -0.4, 3.0, -3.0]
    cmds.steer(np.array([0.0, 0.0, -3.0, 3.0]))
    # errors 0.2, -0.4, 6.0 - 2 pi = -0.283, -6.0 + 2 pi = 0.283; x 0.5; all within +/-0.5
    np.testing.assert_allclose(cmds.value[:, 2], [0.1, -0.2, -0.1416, 0.1416], atol=1e-4)
    cmds.steer(np.array([2.0, -2.0, 0.0, 0.0]))  # errors -1.8, 1.6, 3.0, -3.0: clipped
    np.testing.assert_allclose(cmds.value[:, 2], [-0.5, 0.5, 0.5, -0.5])
    cmds.set(np.array([0]), np.array([[0.5, 0.0, 0.0]]))
    cmds.steer(np.array([2.0, -2.0, 0.0, 0.0]))
    assert cmds.value[0, 2] == 0.0  # imposed: not steered
    off = Commands(CommandConfig(), 4)
    off.resample(np.arange(4), np.random.default_rng(0))
    before = off.value.copy()
    off.steer(np.full(4, 1.0))
    np.testing.assert_array_equal(off.value, before)


def test_heading_is_drawn_within_its_spread_of_the_robot_yaw():
    """A heading is drawn as an offset within +/- heading_spread_rad and anchored to the yaw the
    robot has at the first steer() after the draw (later steers do not move it)."""
    from tron1cli.env.commands import Commands

    n = 2000
    cmds = Commands(CommandConfig(heading=True, heading_spread_rad=0.3), n)
    cmds.resample(np.arange(n), np.random.default_rng(1))
    yaw = np.random.default_rng(2).uniform(-np.pi, np.pi, n)
    cmds.steer(yaw)
    off = np.angle(np.exp(1j * (cmds.heading - yaw)))
    assert np.abs(off).max() <= 0.3 + 1e-12 and np.abs(off).max() > 0.29
    anchored = cmds.heading.copy()
    cmds.steer(yaw + 1.0)
    np.testing.assert_array_equal(cmds.heading, anchored)
    with pytest.raises(ValueError, match="heading_spread_rad"):
        CommandConfig(heading_spread_rad=4.0)


def test_heading_mode_in_the_env_turns_the_robot_back_and_keeps_the_other_draws():
    """In the env the yaw-rate command follows the base yaw each step; the commands drawn besides
    the heading are those of the same seed without heading mode."""
    env = make_env(16, terrain="flat", commands=CommandConfig(heading=True))
    plain = make_env(16, terrain="flat")
    env.reset()
    plain.reset()
    np.testing.assert_array_equal(env.commands.value[:, :2], plain.commands.value[:, :2])
    env.step(np.zeros((16, 6)))
    steering = env.commands.steering
    assert steering.any()
    yaw = yaw_of(env.state.base_quat)
    err = np.angle(np.exp(1j * (env.commands.heading - yaw)))
    np.testing.assert_allclose(env.commands.value[steering, 2], np.clip(0.5 * err, -0.5, 0.5)[steering])
    env.close()
    plain.close()


def test_commands_face_nothing_by_default():
    env = make_env(64, terrain="stairs")
    env.reset()
    assert not env.cfg.commands.face_climb
    assert (env.commands.value[:, 0] < 0).any()
    env.close()


@pytest.mark.parametrize("bad", [dict(num_envs=0), dict(decimation=0), dict(history_len=0), dict(sim_dt=-1)])
def test_bad_config_is_refused(bad):
    with pytest.raises(ValueError):
        EnvConfig(**bad)


@pytest.mark.parametrize("ablation,groups", [("none", {"stable", "loco"}), ("single-critic", {"all"})])
def test_step_returns_reward_groups_and_term_sums(ablation, groups):
    env = Tron1Env(EnvConfig(num_envs=16, gait=PAPER), make_reward_config(ablation))
    env.reset()
    ended = 0
    for _ in range(100):
        res = env.step(np.zeros((16, 6)))
        assert set(res.rewards) == groups
        assert all(r.shape == (16,) and np.isfinite(r).all() for r in res.rewards.values())
        ended += res.done.sum()
        if res.done.any():
            assert res.episode["reward/stable"].shape == (res.done.sum(),)
    assert ended > 0
    assert (env.lipm.r_stable > 0).all() and (env.lipm.r_stable <= 1).all()
    env.close()
