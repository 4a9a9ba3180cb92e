"""The reward system: Table II weights and groups, RFM gating, dt scaling, ablation presets."""

from types import SimpleNamespace

import numpy as np
import pytest

from tron1cli.env import robot
from tron1cli.env.rewards import ABLATIONS, TERMS, RewardConfig, RewardManager, TermCfg, make_reward_config

DT = 0.02


def fake_env(n=3):
    """An env-shaped namespace with hand-set values: v_cmd (1, 0), v (0.5, 0), r_stable 0.6."""
    state = SimpleNamespace(
        base_lin_vel_b=np.tile([0.5, 0.0, 0.1], (n, 1)),
        base_ang_vel_b=np.tile([0.0, 0.0, 0.2], (n, 1)),
        joint_acc=np.full((n, 6), 10.0),
        joint_torque=np.full((n, 6), 2.0),
        joint_vel=np.full((n, 6), 1.0),
        joint_pos=np.zeros((n, 6)),
        collision_count=np.array([0, 1, 2])[:n],
    )
    return SimpleNamespace(
        n=n,
        state=state,
        commands=SimpleNamespace(value=np.tile([1.0, 0.0, 0.0], (n, 1))),
        actions=np.full((n, 6), 0.5),
        last_actions=np.zeros((n, 6)),
        last_last_actions=np.zeros((n, 6)),
        lipm=SimpleNamespace(r_stable=np.full(n, 0.6)),
        reward_cfg=RewardConfig(),
    )


def test_paper_groups_and_weights():
    cfg = make_reward_config()
    assert cfg.groups == ("stable", "loco")
    assert cfg.terms["stable"].group == "stable" and cfg.terms["stable"].weight == 1.0
    assert cfg.terms["track_lin_mag"].gated and not cfg.terms["track_lin_dir"].gated
    assert cfg.terms["joint_acc"].weight == -2.5e-7
    assert cfg.terms["joint_limit"].weight == -2.0


def test_fused_reward_by_hand():
    env = fake_env()
    mgr = RewardManager(make_reward_config(), env.n, DT)
    g = mgr.compute(env)
    # stable: 0.6; dir: cos = 1 -> exp(0) = 1 -> 0.5; mag: exp(4 * -(1 - 0.5)^2) = exp(-1) gated by 0.6
    # yaw: exp(-4 * 0.04) * 0.5; v_z^2 = 0.01 * -2; acc 6 * 100 * -2.5e-7; power 6 * 2 * -2e-5;
    # torque 6 * 4 * -1e-4; action rate 6 * 0.25 * -0.01; smoothness 6 * 0.25 * -0.01; collisions.
    loco = (
        0.5
        + 0.5 * 0.6 * np.exp(-1.0)
        + 0.5 * np.exp(-0.16)
        - 2.0 * 0.01
        - 2.5e-7 * 600
        - 2e-5 * 12
        - 1e-4 * 24
        - 0.01 * 1.5
        - 0.01 * 1.5
    )
    np.testing.assert_allclose(g["stable"], 0.6 * DT)
    np.testing.assert_allclose(g["loco"], (loco - np.array([0, 1, 2])) * DT)


def test_magnitude_term_gradient_is_r_stable():
    env = fake_env()
    mgr = RewardManager(make_reward_config(), env.n, DT)
    mgr.compute(env)
    mag = TERMS["track_lin_mag"](env)
    np.testing.assert_allclose(mgr.last_terms["track_lin_mag"], 0.5 * DT * 0.6 * mag)


def test_episode_sums_accumulate_and_pop():
    env = fake_env()
    mgr = RewardManager(make_reward_config(), env.n, DT)
    mgr.compute(env)
    mgr.compute(env)
    sums = mgr.pop_episode_sums(np.array([1]))
    np.testing.assert_allclose(sums["stable"], [2 * 0.6 * DT])
    assert mgr.episode_sums["stable"][1] == 0.0 and mgr.episode_sums["stable"][0] > 0


def _diff(a: RewardConfig, b: RewardConfig) -> set[str]:
    keys = set(a.terms) | set(b.terms)
    return {k for k in keys if a.terms.get(k) != b.terms.get(k)}


def test_each_ablation_changes_exactly_what_it_names():
    base = make_reward_config()
    assert _diff(base, make_reward_config("no-stable-reward")) == {"stable", "track_lin_mag"}
    no_stable = make_reward_config("no-stable-reward")
    assert "stable" not in no_stable.terms and not no_stable.terms["track_lin_mag"].gated
    no_rfm = make_reward_config("no-rfm")
    assert _diff(base, no_rfm) == {"track_lin_mag"} and no_rfm.terms["track_lin_mag"].weight == 0.5
    single = make_reward_config("single-critic")
    assert single.groups == ("all",)
    assert {k: (v.weight, v.gated) for k, v in single.terms.items()} == {
        k: (v.weight, v.gated) for k, v in base.terms.items()
    }
    l2 = make_reward_config("l2-velocity")
    assert _diff(base, l2) == {"track_lin_dir", "track_lin_mag", "track_lin_l2"}
    assert l2.terms["track_lin_l2"].gated


def test_no_rfm_is_a_plain_sum():
    env = fake_env()
    g = RewardManager(make_reward_config("no-rfm"), env.n, DT).compute(env)
    g_rfm = RewardManager(make_reward_config(), env.n, DT).compute(env)
    mag = 0.5 * np.exp(-1.0) * DT
    np.testing.assert_allclose(g["loco"] - g_rfm["loco"], mag - 0.6 * mag)


def test_l2_velocity_term_by_hand():
    env = fake_env()
    v = TERMS["track_lin_l2"](env)
    np.testing.assert_allclose(v, np.exp(-4.0 * 0.25))


def test_unknown_ablation_names_the_choices():
    with pytest.raises(ValueError, match="unknown ablation 'nope'; choose from none, no-stable-reward"):
        make_reward_config("nope")
    assert set(ABLATIONS) == {"none", "no-stable-reward", "single-critic", "no-rfm", "l2-velocity"}


def test_config_round_trips_through_a_dict():
    cfg = make_reward_config("l2-velocity", lipm_kp=2.0)
    back = RewardConfig.from_dict(cfg.to_dict())
    assert dict(back.terms) == dict(cfg.terms)
    assert (back.lipm_kp, back.ablation, back.groups) == (2.0, "l2-velocity", ("stable", "loco"))


def test_joint_limit_counts_velocity_too():
    env = fake_env(1)
    env.state.joint_vel[:] = robot.VELOCITY_LIMIT + 1
    env.state.joint_pos[0, 0] = robot.JOINT_RANGES[0, 1] + 0.1
    assert TERMS["joint_limit"](env)[0] == 7


def test_with_weights_replaces_only_the_named_terms():
    from tron1cli.env.rewards import with_weights

    base = make_reward_config(gait_prior=True)
    cfg = with_weights(base, {"alive": 0.5, "torque": -2e-4})
    assert cfg.terms["alive"].weight == 0.5 and cfg.terms["torque"].weight == -2e-4
    assert cfg.terms["alive"].group == base.terms["alive"].group
    assert {k: v for k, v in cfg.terms.items() if k not in ("alive", "torque")} == {
        k: v for k, v in base.terms.items() if k not in ("alive", "torque")
    }
    with pytest.raises(ValueError, match="unknown reward term 'lava'"):
        with_weights(base, {"lava": 1.0})
    added = with_weights(make_reward_config(gait_prior=False), {"gait_swing_clearance": -1.0})
    assert added.terms["gait_swing_clearance"] == TermCfg(-1.0, "loco")
    single = with_weights(make_reward_config("single-critic"), {"alive": 1.0})
    assert single.terms["alive"].group == "all" and single.groups == ("all",)
    with pytest.raises(ValueError, match="not a finite number"):
        with_weights(base, {"stable": float("nan")})


def test_a_ramped_term_rises_from_zero_over_its_iterations():
    t = TermCfg(2.0, ramp=(200, 250))
    assert [t.scale(i) for i in (0, 199, 200, 225, 250, 10_000)] == [0.0, 0.0, 0.0, 0.5, 1.0, 1.0]
    assert TermCfg(1.0, ramp=(5, 5)).scale(4) == 0.0 and TermCfg(1.0, ramp=(5, 5)).scale(5) == 1.0
    assert TermCfg(1.0).scale(0) == 1.0
    for bad in ((10, 5), (-1, 3), (1.5, 3)):
        with pytest.raises(ValueError, match="0 <= start <= end"):
            TermCfg(1.0, ramp=bad)


def test_a_ramped_term_pays_nothing_before_its_start_and_its_weight_after():
    from tron1cli.env.rewards import with_ramps, with_weights

    env = fake_env()
    base = make_reward_config(gait_prior=False)
    cfg = with_ramps(with_weights(base, {"track_lin_l2": 1.0}), {"track_lin_l2": (10, 20)})
    mgr, plain = RewardManager(cfg, env.n, DT), RewardManager(base, env.n, DT)
    l2 = TERMS["track_lin_l2"](env)
    full = mgr.compute(env)["loco"]  # outside training (eval, deploy-sim): the full weight
    mgr.set_iteration(0)
    before = mgr.compute(env)
    np.testing.assert_array_equal(before["loco"], plain.compute(env)["loco"])  # bit for bit
    assert not mgr.last_terms["track_lin_l2"].any()
    np.testing.assert_allclose(full - before["loco"], DT * l2)
    mgr.set_iteration(15)
    np.testing.assert_allclose(mgr.compute(env)["loco"] - before["loco"], 0.5 * DT * l2)
    mgr.set_iteration(20)
    np.testing.assert_allclose(mgr.compute(env)["loco"] - before["loco"], DT * l2)
    # the ramp survives the run's config.json
    assert RewardConfig.from_dict(cfg.to_dict()) == cfg
    assert cfg.to_dict()["terms"]["track_lin_l2"]["ramp"] == [10, 20]
    assert "ramp" not in cfg.to_dict()["terms"]["stable"]
    with pytest.raises(ValueError, match="cannot ramp 'alive'"):
        with_ramps(base, {"alive": (0, 10)})


def test_thigh_clearance_measures_the_thigh_end_from_the_highest_ground_near_it():
    import mujoco

    from tron1cli.env.rewards import THIGH_REACH_M

    # the site ends the thigh cylinder's axis, 0.24 m down the 0.30 m hip-knee line: with every
    # joint at 0 and the base 0.812 m up it is 0.344 m above the soles, 0.14 m behind the base
    model = robot.load_spec().compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    base = data.body("base").xpos
    np.testing.assert_allclose(data.site("thigh_L_end").xpos - base, [-0.14144, 0.105, -0.468])
    np.testing.assert_allclose(data.site("thigh_R_end").xpos - base, [-0.14144, -0.105, -0.468])
    assert model.geom("thigh_L_geom").size[0] == model.geom("thigh_R_geom").size[0] == robot.THIGH_RADIUS

    env = fake_env(3)
    ends = np.array([[0.0, 0.1, 0.344], [0.0, -0.1, 0.344]])  # a standing robot's thigh ends (m)
    env.state.thigh_end_pos = np.tile(ends, (3, 1, 1))
    block = np.array([0.0, 0.30, 0.33])  # ground near both ends: flat, a 30 cm block, a 33 cm block
    reached = []

    def highest_ground(xy, reach):
        reached.append(reach)
        return block.copy()

    env.highest_ground = highest_ground
    # gaps 0.309, 0.009 and -0.021 m for both thighs: (0.05 - gap) / 0.05 each, at most 1
    np.testing.assert_allclose(TERMS["thigh_clearance"](env), [0.0, 2 * 0.82, 2.0])
    assert reached == [THIGH_REACH_M, THIGH_REACH_M]


def test_thigh_clearance_margin_is_a_reward_setting_recorded_with_the_term():
    from tron1cli.env.rewards import with_settings, with_weights

    cfg = with_settings(with_weights(RewardConfig(), {"thigh_clearance": -2.0}), {"thigh_clearance_m": 0.08})
    assert RewardConfig.from_dict(cfg.to_dict()).thigh_clearance_m == 0.08
    assert "thigh_clearance_m" not in RewardConfig().to_dict()  # older runs' configs unchanged
    with pytest.raises(ValueError, match="thigh_clearance_m must be a positive length"):
        RewardConfig(thigh_clearance_m=0.0)
