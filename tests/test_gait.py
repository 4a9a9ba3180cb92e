"""The gait prior: schedule values, leg offset, layout growth, reward terms, consistency checks."""

import numpy as np
import pytest

from tron1cli.config import EnvConfig, GaitConfig
from tron1cli.env import robot
from tron1cli.env.core import Tron1Env
from tron1cli.env.gait import (
    FOLD_SHARE,
    clock_observation,
    desired_contact,
    fold_targets,
    leg_phases,
    swing_fold,
)
from tron1cli.env.observations import ObsLayout
from tron1cli.env.rewards import make_reward_config


def test_desired_contact_by_hand():
    # mid-stance 0.25: 0.5 (1 + tanh(6.25)) * (1 - 0.5 (1 + tanh(-6.25))) ~ 1 - 7.4e-6
    c = desired_contact(np.array([0.25, 0.75, 0.0, 0.5]), stance=0.5, width=0.04)
    t = np.tanh(6.25)
    np.testing.assert_allclose(c[0], (0.5 * (1 + t)) ** 2, rtol=1e-12)
    assert c[1] < 1e-5  # mid-swing
    # at both edges one step is exactly half-way and the other is saturated
    np.testing.assert_allclose(c[2], 0.5, atol=1e-6)
    np.testing.assert_allclose(c[3], 0.5, atol=1e-6)


def test_a_fixed_gait_frequency_stays_in_the_trained_range():
    g = GaitConfig()  # 1.5-2.5 Hz
    assert g.fixed(2.5).freq_hz == (2.5, 2.5) and g.fixed(1.5).freq_hz == (1.5, 1.5)
    assert g.deployed_hz() == 2.0 and g.deployed_hz(2.25) == 2.25
    for bad in (1.0, 2.51, float("nan")):
        with pytest.raises(ValueError, match="outside the trained range 1.5-2.5 Hz"):
            g.fixed(bad)
    off = GaitConfig(enabled=False)
    assert off.deployed_hz() == 0.0  # no clock is read
    with pytest.raises(ValueError, match="without the gait prior"):
        off.deployed_hz(2.0)


def test_legs_are_half_a_period_apart():
    phase = np.arange(100) / 100.0
    lp = leg_phases(phase, 0.5)
    np.testing.assert_allclose((lp[:, 1] - lp[:, 0]) % 1.0, 0.5)
    c = desired_contact(lp)
    # the right leg's schedule is the left one's shifted by half a period
    np.testing.assert_allclose(c[:, 1], np.roll(c[:, 0], -50), atol=1e-12)
    # away from the edges exactly one foot should be on the ground
    mid = (np.abs(lp[:, 0] - 0.25) < 0.15) | (np.abs(lp[:, 0] - 0.75) < 0.15)
    np.testing.assert_allclose(c[mid].sum(axis=1), 1.0, atol=1e-3)


def test_clock_observation():
    obs = clock_observation(np.array([0.0, 0.25]), np.array([2.0, 1.5]))
    np.testing.assert_allclose(obs, [[0, 1, 2.0], [1, 0, 1.5]], atol=1e-12)


def test_layout_grows_by_exactly_the_clock():
    off, on = ObsLayout(history_len=4), ObsLayout(history_len=4, gait_clock=True)
    assert on.proprio_dim - off.proprio_dim == 3
    assert on.privileged_dim - off.privileged_dim == 3
    assert on.history_dim - off.history_dim == 12
    assert off.proprio_dim == 27 and off.privileged_dim == 51


def test_clock_advances_and_restarts():
    env = Tron1Env(
        EnvConfig(num_envs=8, gait=GaitConfig(freq_hz=(2.0, 2.0))), make_reward_config(gait_prior=True)
    )
    obs = env.reset()
    assert obs["proprio"].shape == (8, 30)
    for _ in range(5):
        res = env.step(np.zeros((8, 6)))
    expected = np.where(res.done, 0.0, 5 * 2.0 * 0.02)
    np.testing.assert_allclose(env.commands.gait_phase, expected)
    assert {"reward/gait_swing_force", "reward/gait_stance_speed"} <= set(res.episode)
    env.close()


def test_gait_terms_need_the_clock():
    with pytest.raises(ValueError, match="gait prior is off"):
        Tron1Env(EnvConfig(num_envs=2, gait=GaitConfig(enabled=False)), make_reward_config(gait_prior=True))


def test_gait_terms_join_the_locomotion_group():
    cfg = make_reward_config(gait_prior=True)
    assert cfg.terms["gait_swing_force"].group == "loco" and cfg.groups == ("stable", "loco")
    single = make_reward_config("single-critic", gait_prior=True)
    assert single.groups == ("all",)
    assert "gait_swing_force" not in make_reward_config().terms


def test_swing_height_target_and_shortfall_by_hand():
    from tron1cli.env.gait import clearance_shortfall, swing_height_target

    # stance 0.5: phase 0.3 stands, 0.75 is mid-swing, 0.625 a quarter into it
    target = swing_height_target(np.array([[0.3, 0.75], [0.625, 0.5]]), stance=0.5, height=0.1)
    np.testing.assert_allclose(target, [[0.0, 0.1], [0.1 * np.sin(np.pi / 4), 0.0]], atol=1e-12)
    # mid-swing foot 4 cm up: 0.6 short; a standing foot is never short; above the target: 0
    clear = np.array([[0.0, 0.04], [0.2, 0.0]])
    np.testing.assert_allclose(clearance_shortfall(clear, target, 0.1), [0.6, 0.0])


def test_swing_clearance_is_measured_above_the_terrain_under_the_foot():
    """On a stair tile, a foot held at the same world height is higher above the lower step."""
    from tron1cli.env.rewards import TERMS, with_weights

    reward = with_weights(make_reward_config(gait_prior=True), {"gait_swing_clearance": -1.0})
    env = Tron1Env(EnvConfig(num_envs=2, terrain="stairs", max_init_level=9, curriculum=False), reward)
    try:
        env.reset()
        env.commands.gait_phase[:] = 0.25  # right leg (phase + 0.5) at mid-swing, left standing
        ground = env.ground_height(env.state.foot_pos[:, 1, :2])
        env.state.foot_pos[:, 1, 2] = ground + 0.032 + 0.03  # right sole 3 cm above its ground
        np.testing.assert_allclose(TERMS["gait_swing_clearance"](env), 0.7, atol=1e-9)
        env.state.foot_pos[:, 1, 2] = ground + 0.032 + 0.15
        np.testing.assert_allclose(TERMS["gait_swing_clearance"](env), 0.0, atol=1e-12)
    finally:
        env.close()


def test_swing_fold_by_hand():
    """Left leg at the fold's peak, right in stance; then the right leg a quarter into its swing
    (progress 0.25 of the fold's 0.6) and the left leg late in its swing, past the fold."""
    peak = 0.5 + 0.5 * FOLD_SHARE / 2  # leg phase at the fold's peak (stance 0.5)
    off = swing_fold(np.array([[peak, 0.25], [0.9, 0.625]]), 0.5, (0.5, 0.8))
    assert off.shape == (2, robot.NUM_JOINTS)
    np.testing.assert_allclose(off[0], [0.0, -0.5, 0.8, 0.0, 0.0, 0.0], atol=1e-12)
    w = np.sin(np.pi * 0.25 / FOLD_SHARE)
    np.testing.assert_allclose(off[1], [0.0, 0.0, 0.0, 0.0, 0.5 * w, -0.8 * w], atol=1e-12)


def test_the_swing_fold_lifts_the_foot_and_lands_in_the_targets():
    """The fold's signs flex each leg within its joint range, and the env adds it to the targets
    at the phase the policy saw."""
    mid = swing_fold(np.array([[0.75, 0.75]]), 0.5, (0.6, 1.0))[0]
    lo, hi = robot.JOINT_RANGES[:, 0], robot.JOINT_RANGES[:, 1]
    assert np.all((mid >= lo) & (mid <= hi))
    gait = GaitConfig(freq_hz=(2.0, 2.0), swing_fold_rad=(0.5, 0.8))
    env = Tron1Env(EnvConfig(num_envs=4, gait=gait), make_reward_config(gait_prior=True))
    env.reset()
    for _ in range(8):
        phase = env.commands.gait_phase.copy()
        env.step(np.zeros((4, 6)))
        want = robot.DEFAULT_POSE + swing_fold(leg_phases(phase, 0.5), 0.5, (0.5, 0.8))
        np.testing.assert_allclose(env.targets, want)
    assert np.abs(env.targets).max() > 0.1  # some leg swung within 8 steps at 2 Hz
    env.close()


def test_a_kept_fold_by_hand():
    """Left leg at the fold's peak (hip -0.5, knee +0.8), right leg in stance. Keeping 0.75 of the
    fold holds the left flexion at least 0.375 / 0.6 rad however the action unfolds it; flexion
    the action adds stays, and the stance leg is the action's alone."""
    phase = np.full(2, 0.5 + 0.5 * FOLD_SHARE / 2)  # the right leg, half a period behind, stands
    d = robot.DEFAULT_POSE
    unfold = d + np.array([[0.1, 0.4, -0.7, 0.2, -0.9, 0.9], [0.0, -0.2, 0.3, 0.0, 0.0, 0.0]])
    kept = GaitConfig(swing_fold_rad=(0.5, 0.8), swing_fold_keep=0.75)
    out = fold_targets(unfold, phase, kept, d)
    np.testing.assert_allclose(out[0] - d, [0.1, -0.375, 0.6, 0.2, -0.9, 0.9], atol=1e-12)
    np.testing.assert_allclose(out[1] - d, [0.0, -0.7, 1.1, 0.0, 0.0, 0.0], atol=1e-12)  # more flexion
    free = fold_targets(unfold, phase, GaitConfig(swing_fold_rad=(0.5, 0.8)), d)
    np.testing.assert_allclose(free, unfold + swing_fold(leg_phases(phase, 0.5), 0.5, (0.5, 0.8)))
    assert fold_targets(unfold, phase, GaitConfig(), d) is unfold  # no fold: the targets themselves


def test_the_env_keeps_the_fold_against_an_unfolding_action():
    gait = GaitConfig(freq_hz=(2.0, 2.0), swing_fold_rad=(0.5, 0.8), swing_fold_keep=0.5)
    env = Tron1Env(EnvConfig(num_envs=4, gait=gait), make_reward_config(gait_prior=True))
    env.reset()
    act = np.tile([0.0, 4.0, -4.0, 0.0, -4.0, 4.0], (4, 1))  # hip and knee as far from flexion as allowed
    held = 0
    for _ in range(8):
        phase = env.commands.gait_phase.copy()
        env.step(act)
        legs = leg_phases(phase, 0.5)
        want = fold_targets(
            robot.DEFAULT_POSE + robot.ACTION_SCALE * env.actions, phase, gait, robot.DEFAULT_POSE
        )
        np.testing.assert_allclose(env.targets, want)
        off = swing_fold(legs, 0.5, (0.5, 0.8))
        flex = np.sign(off) * (env.targets - robot.DEFAULT_POSE)
        assert np.all(flex[off != 0] >= 0.5 * np.abs(off[off != 0]) - 1e-12)
        held += int((off != 0).any())
    assert held > 0  # some leg was in its fold within 8 steps at 2 Hz
    env.close()


@pytest.mark.parametrize("keep", [-0.1, 1.5, float("nan")])
def test_a_bad_kept_share_is_refused(keep):
    with pytest.raises(ValueError, match="must lie in"):
        GaitConfig(swing_fold_rad=(0.5, 0.8), swing_fold_keep=keep)
    with pytest.raises(ValueError, match="needs a swing fold"):
        GaitConfig(swing_fold_keep=0.5)


@pytest.mark.parametrize("fold", [(0.5,), (0.5, float("nan"))])
def test_a_bad_swing_fold_is_refused(fold):
    with pytest.raises(ValueError, match="two finite angles"):
        GaitConfig(swing_fold_rad=fold)
    with pytest.raises(ValueError, match="needs the gait prior"):
        GaitConfig(enabled=False, swing_fold_rad=(0.5, 0.8))
