"""Tests for the LIPM stability math (tron1cli.env.lipm) against hand-computed values."""

from __future__ import annotations

import numpy as np
import pytest

from tron1cli.env import lipm


def _contacts(feet: list[tuple[float, float, float]], forces: list[float]) -> tuple[np.ndarray, np.ndarray]:
    """One env's contacts as batched arrays: positions (1, F, 3), forces (1, F)."""
    return np.array([feet], dtype=np.float64), np.array([forces], dtype=np.float64)


def test_gravity_constant() -> None:
    assert lipm.G == 9.81


def test_zmp_single_support_is_the_contact_point_exactly() -> None:
    # Left foot loaded with 300 N, right foot at 0.5 N (< min_force 1 N): ZMP = left contact xy.
    pos, f = _contacts([(0.13, -0.07, 0.02), (0.5, 0.1, 0.1)], [300.0, 0.5])
    zmp = lipm.zmp_from_contacts(pos, f, last_zmp=np.array([[9.0, 9.0]]))
    np.testing.assert_array_equal(zmp, [[0.13, -0.07]])


def test_zmp_symmetric_double_support_is_the_midpoint() -> None:
    # 200 N on each foot: ((0.1 + 0.3) / 2, (0.1 - 0.1) / 2) = (0.2, 0.0).
    pos, f = _contacts([(0.1, 0.1, 0.0), (0.3, -0.1, 0.0)], [200.0, 200.0])
    zmp = lipm.zmp_from_contacts(pos, f, last_zmp=np.zeros((1, 2)))
    np.testing.assert_allclose(zmp, [[0.2, 0.0]], atol=1e-12)


def test_zmp_asymmetric_double_support_is_force_weighted() -> None:
    # x = (300 * 0.0 + 100 * 0.4) / 400 = 0.1; y = (300 * 0.2 + 100 * -0.2) / 400 = 40 / 400 = 0.1.
    pos, f = _contacts([(0.0, 0.2, 0.0), (0.4, -0.2, 0.0)], [300.0, 100.0])
    zmp = lipm.zmp_from_contacts(pos, f, last_zmp=np.zeros((1, 2)))
    np.testing.assert_allclose(zmp, [[0.1, 0.1]], atol=1e-12)


def test_zmp_in_flight_returns_last_zmp() -> None:
    # 0.0 N and exactly min_force (1.0 N, not strictly greater): no foot is loaded.
    pos, f = _contacts([(0.1, 0.1, 0.0), (0.3, -0.1, 0.0)], [0.0, 1.0])
    zmp = lipm.zmp_from_contacts(pos, f, last_zmp=np.array([[-0.4, 0.25]]), min_force=1.0)
    np.testing.assert_array_equal(zmp, [[-0.4, 0.25]])


def test_zmp_min_force_threshold_is_respected() -> None:
    # With min_force = 50 N the 40 N foot is ignored, leaving single support on the 60 N foot.
    pos, f = _contacts([(0.1, 0.1, 0.0), (0.3, -0.1, 0.0)], [40.0, 60.0])
    zmp = lipm.zmp_from_contacts(pos, f, last_zmp=np.zeros((1, 2)), min_force=50.0)
    np.testing.assert_array_equal(zmp, [[0.3, -0.1]])


def test_zmp_batch_mixes_cases_per_env() -> None:
    pos = np.array(
        [
            [(0.1, 0.1, 0.0), (0.3, -0.1, 0.0)],  # double support, equal forces -> (0.2, 0.0)
            [(0.1, 0.1, 0.0), (0.3, -0.1, 0.0)],  # single support on the right foot -> (0.3, -0.1)
            [(0.1, 0.1, 0.0), (0.3, -0.1, 0.0)],  # flight -> last_zmp (1.0, 2.0)
        ]
    )
    f = np.array([[100.0, 100.0], [0.0, 80.0], [0.0, 0.0]])
    last = np.array([[5.0, 5.0], [5.0, 5.0], [1.0, 2.0]])
    zmp = lipm.zmp_from_contacts(pos, f, last)
    assert zmp.shape == (3, 2)
    np.testing.assert_allclose(zmp, [[0.2, 0.0], [0.3, -0.1], [1.0, 2.0]], atol=1e-12)


def test_plane_intercept_is_com_height_above_ground() -> None:
    # 0.92 - 0.12 = 0.80; 0.70 - (-0.05) = 0.75.
    com = np.array([[0.0, 0.0, 0.92], [1.0, -1.0, 0.70]])
    z = lipm.plane_intercept(com, np.array([0.12, -0.05]))
    assert z.shape == (2,)
    np.testing.assert_allclose(z, [0.80, 0.75], atol=1e-12)


def test_desired_com_hand_value() -> None:
    # v_cmd - v = (1.0 - 0.5, 0.0 - 0.25) = (0.5, -0.25); z / g = 0.981 / 9.81 = 0.1; kp = 2
    # p_hat = (0.1, -0.05) + 0.1 * 2 * (0.5, -0.25) = (0.1 + 0.1, -0.05 - 0.05) = (0.2, -0.1).
    p_hat = lipm.desired_com(
        zmp=np.array([[0.1, -0.05]]),
        z=np.array([0.981]),
        v_cmd_xy=np.array([[1.0, 0.0]]),
        v_xy=np.array([[0.5, 0.25]]),
        kp=2.0,
    )
    np.testing.assert_allclose(p_hat, [[0.2, -0.1]], atol=1e-12)


def test_desired_com_equals_zmp_when_velocity_matches_command() -> None:
    zmp = np.array([[0.3, -0.2], [-1.0, 0.5]])
    v = np.array([[0.7, 0.1], [-0.2, 0.0]])
    p_hat = lipm.desired_com(zmp, np.array([0.8, 0.6]), v, v.copy(), kp=3.0)
    assert p_hat.shape == (2, 2)
    np.testing.assert_array_equal(p_hat, zmp)


def test_stable_reward_is_one_at_the_lipm_target() -> None:
    p = np.array([[0.2, -0.1], [1.0, 3.0]])
    z = np.array([0.8, 0.75])
    r = lipm.stable_reward(p, p.copy(), z, z.copy(), np.zeros(2), np.zeros(2))
    assert r.shape == (2,)
    np.testing.assert_array_equal(r, [1.0, 1.0])


def test_stable_reward_hand_value() -> None:
    # ||(0.03, 0.04)|| = 0.05; |0.8 - 0.7| = 0.1; |0.2| + |-0.15| = 0.35;
    # exp(-(0.05 + 0.1 + 0.35)) = exp(-0.5).
    r = lipm.stable_reward(
        p_hat=np.array([[0.03, 0.04]]),
        p_com_xy=np.array([[0.0, 0.0]]),
        z=np.array([0.7]),
        z_c=0.8,
        roll_rate=np.array([0.2]),
        pitch_rate=np.array([-0.15]),
    )
    np.testing.assert_allclose(r, [0.6065306597126334], rtol=1e-12)


def test_stable_reward_accepts_per_env_target_height() -> None:
    # env 0: |0.8 - 0.8| = 0 -> 1; env 1: |0.6 - 0.8| = 0.2 -> exp(-0.2) = 0.8187307530779818.
    r = lipm.stable_reward(
        np.zeros((2, 2)),
        np.zeros((2, 2)),
        np.array([0.8, 0.8]),
        np.array([0.8, 0.6]),
        np.zeros(2),
        np.zeros(2),
    )
    np.testing.assert_allclose(r, [1.0, 0.8187307530779818], rtol=1e-12)


@pytest.mark.parametrize(
    "which", ["p_x", "p_y", "z_above", "z_below", "roll", "pitch", "neg_roll", "neg_pitch"]
)
def test_stable_reward_strictly_decreases_as_any_error_grows(which: str) -> None:
    err = np.linspace(0.0, 2.0, 9)
    n = err.size
    p_hat = np.zeros((n, 2))
    z = np.full(n, 0.8)
    roll = np.zeros(n)
    pitch = np.zeros(n)
    if which == "p_x":
        p_hat[:, 0] = err
    elif which == "p_y":
        p_hat[:, 1] = -err
    elif which == "z_above":
        z = 0.8 + err
    elif which == "z_below":
        z = 0.8 - err
    elif which == "roll":
        roll = err
    elif which == "pitch":
        pitch = err
    elif which == "neg_roll":
        roll = -err
    else:
        pitch = -err
    r = lipm.stable_reward(p_hat, np.zeros((n, 2)), z, 0.8, roll, pitch)
    assert r[0] == 1.0
    assert np.all(np.diff(r) < 0.0)
    assert np.all((r > 0.0) & (r <= 1.0))
    # Each error enters the exponent linearly with unit weight.
    np.testing.assert_allclose(r, np.exp(-err), rtol=1e-12)


def _upright_climb(speed: float, ground: str) -> np.ndarray:
    """r_stable per policy step of a robot held upright (no CoM error, no rotation) whose CoM climbs
    the hardest stairs_up tile at ``speed`` (m/s) along +x, at the standing height above the
    staircase's mean slope; ``ground`` is ``window`` (the env's LIPM ground) or ``point``."""
    from tron1cli.env.rewards import RewardConfig
    from tron1cli.env.terrain import TerrainBank, TerrainConfig, ground_height, mean_ground_height

    cfg, reward = TerrainConfig(), RewardConfig()
    bank = TerrainBank(("stairs_up",), cfg, seed=0)
    h, tread, half = cfg.step_height_m[1], cfg.step_tread_m, 0.5 * cfg.platform_m
    x = np.arange(0.2, 3.0, speed * 0.02)  # one policy step (20 ms) apart
    xy = np.stack([x, np.full_like(x, 0.1)], axis=1)
    mean_slope = np.maximum(h * ((x - half) / tread + 0.5), 0.0)  # through the tread middles
    com = np.column_stack([xy, reward.z_c + mean_slope])
    tiles = np.full(len(x), bank.tile_index(0, cfg.num_levels - 1, 0))
    if ground == "window":
        g = mean_ground_height(bank.heights, tiles, xy, bank.res, reward.lipm_ground_window_m)
    else:
        g = ground_height(bank.heights, tiles, xy, bank.res)
    zero = np.zeros(len(x))
    return lipm.stable_reward(com[:, :2], com[:, :2], lipm.plane_intercept(com, g), reward.z_c, zero, zero)


@pytest.mark.parametrize("speed", [0.5, 1.0])
def test_r_stable_of_an_upright_stair_climb_has_no_steps(speed: float) -> None:
    r = _upright_climb(speed, "window")
    step = np.abs(np.diff(r) / r[:-1])
    assert step.max() < 0.02  # a few per cent at most between policy steps
    assert r.min() > 0.9  # on the staircase's slope the intercept stays near z_c


def test_point_ground_under_the_com_makes_r_stable_jump_at_stair_edges() -> None:
    r = _upright_climb(1.0, "point")  # the earlier definition: a 20 cm step at every edge
    assert np.abs(np.diff(r) / r[:-1]).max() > 0.05


def test_mean_ground_height_window_hand_values() -> None:
    from tron1cli.env.terrain import ground_height, mean_ground_height, window_offsets

    bank = np.zeros((1, 9, 9), dtype=np.float32)
    bank[0, :, 5:] = 0.2  # a 20 cm step between columns 4 and 5 (x = 0 and x = 0.05 m)
    idx = np.zeros(3, dtype=np.int64)
    xy = np.array([[-1.0, 0.0], [0.025, 0.0], [0.125, 0.0]])
    assert np.allclose(mean_ground_height(bank, idx, xy, 0.05, 0.0), ground_height(bank, idx, xy, 0.05))
    # a 0.1 m window (3 x 3 samples at -0.05, 0, 0.05 m): far left flat 0; centred mid-riser:
    # samples at x = -0.025 (0), 0.025 (0.1), 0.075 (0.2) -> 0.1; right: all 0.2 -> 0.2
    assert np.allclose(mean_ground_height(bank, idx, xy, 0.05, 0.1), [0.0, 0.1, 0.2])
    assert window_offsets(0.1, 0.05).shape == (9, 2)
    with pytest.raises(ValueError):
        window_offsets(-1.0, 0.05)
