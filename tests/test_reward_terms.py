"""Tests for the per-term reward math (tron1cli.env.reward_terms) against hand-computed values."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tron1cli.env import reward_terms as rt


def _v(*rows: tuple[float, ...]) -> np.ndarray:
    return np.array(rows, dtype=np.float64)


# --- direction / magnitude errors -------------------------------------------------------------


def test_direction_error_aligned_opposite_orthogonal_and_45_degrees() -> None:
    cmd = _v((1.0, 0.0), (1.0, 0.0), (1.0, 0.0), (1.0, 0.0))
    vel = _v((2.0, 0.0), (-0.5, 0.0), (0.0, 3.0), (1.0, 1.0))
    d = rt.direction_error(cmd, vel)
    assert d.shape == (4,)
    # aligned: 1 - 1 = 0; opposite: -1 - 1 = -2; orthogonal: 0 - 1 = -1; 45 deg: 1/sqrt(2) - 1.
    np.testing.assert_allclose(d, [0.0, -2.0, -1.0, 1.0 / math.sqrt(2.0) - 1.0], atol=1e-12)


def test_direction_error_zero_command_is_zero() -> None:
    # Standing command: no direction to track, whatever the robot does.
    cmd = _v((0.0, 0.0), (0.0, 0.0), (1e-8, 0.0))
    vel = _v((-1.0, 0.5), (0.0, 0.0), (-1.0, 0.0))
    np.testing.assert_array_equal(rt.direction_error(cmd, vel), [0.0, 0.0, 0.0])


def test_direction_error_zero_velocity_with_command_is_minus_one() -> None:
    cmd = _v((0.5, 0.0), (0.0, -1.0))
    vel = _v((0.0, 0.0), (1e-9, 0.0))
    np.testing.assert_array_equal(rt.direction_error(cmd, vel), [-1.0, -1.0])


def test_direction_error_stays_in_range_for_random_vectors() -> None:
    rng = np.random.default_rng(0)
    d = rt.direction_error(rng.normal(size=(200, 2)), rng.normal(size=(200, 2)))
    assert np.all((d >= -2.0) & (d <= 0.0))


def test_magnitude_error_hand_value() -> None:
    # ||(0.6, 0.8)|| = 1.0, ||(0, 0.5)|| = 0.5 -> -(1.0 - 0.5)^2 = -0.25; second env: -(0 - 5)^2 = -25.
    m = rt.magnitude_error(_v((0.6, 0.8), (0.0, 0.0)), _v((0.0, 0.5), (3.0, -4.0)))
    np.testing.assert_allclose(m, [-0.25, -25.0], atol=1e-12)


def test_magnitude_error_ignores_direction() -> None:
    # Same speed, opposite direction: zero magnitude error.
    np.testing.assert_allclose(rt.magnitude_error(_v((1.0, 0.0)), _v((-1.0, 0.0))), [0.0], atol=1e-15)


# --- tracking rewards ---------------------------------------------------------------------------


def test_track_direction_hand_values() -> None:
    # d_e = 0 -> 1; d_e = -1 -> exp(-4); d_e = -2 -> exp(-8).
    r = rt.track_direction(_v((1.0, 0.0), (1.0, 0.0), (1.0, 0.0)), _v((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0)))
    np.testing.assert_allclose(r, [1.0, math.exp(-4.0), math.exp(-8.0)], rtol=1e-12)


def test_track_magnitude_hand_value() -> None:
    # m_e = -0.25 -> exp(4 * -0.25) = exp(-1).
    r = rt.track_magnitude(_v((0.6, 0.8)), _v((0.0, 0.5)))
    np.testing.assert_allclose(r, [math.exp(-1.0)], rtol=1e-12)


def test_track_lin_vel_l2_hand_values() -> None:
    # v_cmd - v = (0.5, -0.5), squared norm 0.5: alpha 4 -> exp(-2); alpha 1 -> exp(-0.5).
    cmd, vel = _v((1.0, 0.0)), _v((0.5, 0.5))
    np.testing.assert_allclose(rt.track_lin_vel_l2(cmd, vel), [math.exp(-2.0)], rtol=1e-12)
    np.testing.assert_allclose(rt.track_lin_vel_l2(cmd, vel, alpha=1.0), [math.exp(-0.5)], rtol=1e-12)


def test_track_yaw_rate_hand_value() -> None:
    # (0.5 - 0)^2 = 0.25 -> exp(-1); (-0.2 - 0.3)^2 = 0.25 -> exp(-1); equal -> 1.
    r = rt.track_yaw_rate(np.array([0.5, -0.2, 0.7]), np.array([0.0, 0.3, 0.7]))
    np.testing.assert_allclose(r, [math.exp(-1.0), math.exp(-1.0), 1.0], rtol=1e-12)


# --- regularisation penalties -------------------------------------------------------------------


def test_lin_vel_z_sq() -> None:
    # (-0.3)^2 = 0.09; 0.5^2 = 0.25.
    np.testing.assert_allclose(rt.lin_vel_z_sq(np.array([-0.3, 0.5])), [0.09, 0.25], rtol=1e-12)


def test_joint_acc_sq() -> None:
    # 3^2 + (-4)^2 = 25; 1 + 1 = 2.
    np.testing.assert_allclose(rt.joint_acc_sq(_v((3.0, -4.0), (1.0, 1.0))), [25.0, 2.0], rtol=1e-12)


def test_joint_power() -> None:
    # |2| |-1| + |-3| |0.5| = 2 + 1.5 = 3.5 (absolute values: braking power also costs).
    np.testing.assert_allclose(rt.joint_power(_v((2.0, -3.0)), _v((-1.0, 0.5))), [3.5], rtol=1e-12)


def test_torque_sq() -> None:
    # 1 + 4 + 4 = 9.
    np.testing.assert_allclose(rt.torque_sq(_v((1.0, -2.0, 2.0))), [9.0], rtol=1e-12)


def test_action_rate() -> None:
    # (1 - 0.5)^2 + (2 - 2.5)^2 = 0.25 + 0.25 = 0.5.
    np.testing.assert_allclose(rt.action_rate(_v((1.0, 2.0)), _v((0.5, 2.5))), [0.5], rtol=1e-12)


def test_action_smoothness_is_the_second_difference() -> None:
    # env 0: a linear ramp 0 -> 0.5 -> 1 has zero second difference.
    # env 1: (1 - 0 + 1, 2 - 0 - 1) = (2, 1) -> 4 + 1 = 5 (the Table II typo a - 2a' - a'' would give 9).
    a = _v((1.0, 0.0), (1.0, 2.0))
    a1 = _v((0.5, 0.0), (0.0, 0.0))
    a2 = _v((0.0, 0.0), (1.0, -1.0))
    np.testing.assert_allclose(rt.action_smoothness(a, a1, a2), [0.0, 5.0], atol=1e-12)


def test_collisions_is_float_count() -> None:
    c = rt.collisions(np.array([0, 3, 1]))
    assert c.dtype == np.float64
    np.testing.assert_array_equal(c, [0.0, 3.0, 1.0])


def test_height_error_sq_hand_values() -> None:
    np.testing.assert_allclose(rt.height_error_sq(np.array([0.56, 0.42, 0.32]), 0.42), [0.0196, 0.0, 0.01])


def test_foot_stumble_counts_feet_pushed_more_sideways_than_up() -> None:
    f = np.array(
        [
            [[0.0, 0.0, 100.0], [30.0, 40.0, 100.0]],  # standing, and slipping within friction: 0
            [[50.0, 0.0, 10.0], [0.0, 0.0, 0.0]],  # a toe on a riser's face; a foot in the air: 1
            [[0.0, -21.0, 10.0], [-30.0, 0.0, -5.0]],  # both beyond twice the vertical force: 2
        ]
    )
    np.testing.assert_array_equal(rt.foot_stumble(f), [0.0, 1.0, 2.0])
    np.testing.assert_array_equal(rt.foot_stumble(f, ratio=0.4), [1.0, 1.0, 2.0])


def test_joint_limit_violations_hand_case() -> None:
    q_range = np.array([[-1.0, 1.0], [0.0, 2.0], [-0.5, 0.5]])
    q = _v((0.0, 1.0, 0.0), (1.5, -0.1, 0.45), (1.0, 0.0, -0.5))
    qd = _v((0.0, 0.0, 0.0), (11.0, -12.0, 0.0), (10.0, -10.0, 0.0))
    # No margin: env 0 -> 0; env 1 -> j0 (1.5 > 1), j1 (-0.1 < 0) + |11|, |-12| > 10 -> 2 + 2 = 4;
    # env 2 -> exactly on the limits (q and |qd| = 10) is not a violation -> 0.
    n = rt.joint_limit_violations(q, qd, q_range, qd_limit=10.0)
    assert n.shape == (3,) and n.dtype == np.float64
    np.testing.assert_array_equal(n, [0.0, 4.0, 0.0])
    # Margin 0.1 shrinks limits to [-0.9, 0.9], [0.1, 1.9], [-0.4, 0.4]:
    # env 0 -> 0; env 1 -> 3 positions (0.45 > 0.4 now counts) + 2 velocities = 5; env 2 -> j0, j1, j2 = 3.
    n = rt.joint_limit_violations(q, qd, q_range, qd_limit=10.0, margin=0.1)
    np.testing.assert_array_equal(n, [0.0, 5.0, 3.0])


# --- fusion -------------------------------------------------------------------------------------


def test_fuse_rfm_and_sum_hand_values() -> None:
    rs, rd, rm = np.array([0.8]), np.array([0.6]), np.array([0.5])
    # RFM: 0.8 + 0.5 * 0.6 + 0.5 * 0.8 * 0.5 = 0.8 + 0.3 + 0.2 = 1.3.
    np.testing.assert_allclose(rt.fuse_rfm(rs, rd, rm), [1.3], rtol=1e-12)
    # Sum: 0.8 + 0.3 + 0.25 = 1.35.
    np.testing.assert_allclose(rt.fuse_sum(rs, rd, rm), [1.35], rtol=1e-12)
    # Custom weights: 0.8 + 1.0 * 0.6 + 2.0 * 0.8 * 0.5 = 2.2.
    np.testing.assert_allclose(rt.fuse_rfm(rs, rd, rm, w_dir=1.0, w_mag=2.0), [2.2], rtol=1e-12)


@pytest.mark.parametrize("w_mag", [0.5, 1.3])
def test_fuse_rfm_magnitude_gradient_is_gated_by_stability(w_mag: float) -> None:
    rs = np.array([0.05, 0.4, 1.0])
    rd = np.array([0.3, 0.9, 0.1])
    rm = np.array([0.2, 0.5, 0.7])
    h = 1e-6
    d_mag = (rt.fuse_rfm(rs, rd, rm + h, w_mag=w_mag) - rt.fuse_rfm(rs, rd, rm - h, w_mag=w_mag)) / (2 * h)
    np.testing.assert_allclose(d_mag, w_mag * rs, rtol=1e-6)
    d_stab = (rt.fuse_rfm(rs + h, rd, rm, w_mag=w_mag) - rt.fuse_rfm(rs - h, rd, rm, w_mag=w_mag)) / (2 * h)
    np.testing.assert_allclose(d_stab, 1.0 + w_mag * rm, rtol=1e-6)
    # The ablation's magnitude gradient is the constant weight, independent of stability.
    d_sum = (rt.fuse_sum(rs, rd, rm + h, w_mag=w_mag) - rt.fuse_sum(rs, rd, rm - h, w_mag=w_mag)) / (2 * h)
    np.testing.assert_allclose(d_sum, np.full(3, w_mag), rtol=1e-6)


def test_all_terms_return_batch_shape() -> None:
    n, j = 5, 6
    rng = np.random.default_rng(1)
    v2 = rng.normal(size=(n, 2))
    vj = rng.normal(size=(n, j))
    s = rng.random(n)
    outs = [
        rt.direction_error(v2, v2[::-1]),
        rt.magnitude_error(v2, v2[::-1]),
        rt.track_direction(v2, v2[::-1]),
        rt.track_magnitude(v2, v2[::-1]),
        rt.track_lin_vel_l2(v2, v2[::-1]),
        rt.track_yaw_rate(s, s[::-1]),
        rt.lin_vel_z_sq(s),
        rt.joint_acc_sq(vj),
        rt.joint_power(vj, vj),
        rt.torque_sq(vj),
        rt.action_rate(vj, vj[::-1]),
        rt.action_smoothness(vj, vj[::-1], vj),
        rt.collisions(np.arange(n)),
        rt.joint_limit_violations(vj, vj, np.tile([-1.0, 1.0], (j, 1)), qd_limit=1.0),
        rt.fuse_rfm(s, s, s),
        rt.fuse_sum(s, s, s),
    ]
    for out in outs:
        assert out.shape == (n,)
        assert out.dtype == np.float64


def test_flat_orientation_is_the_squared_sine_of_the_tilt() -> None:
    pitch, roll = math.radians(11.0), math.radians(-4.0)
    # gravity in the base frame: a base pitched nose-up by 11 deg, one rolled by -4 deg, one upright
    g = _v(
        (-math.sin(pitch), 0.0, -math.cos(pitch)),
        (0.0, math.sin(roll), -math.cos(roll)),
        (0.0, 0.0, -1.0),
    )
    np.testing.assert_allclose(rt.flat_orientation_sq(g), [math.sin(pitch) ** 2, math.sin(roll) ** 2, 0.0])


def test_track_progress_pays_only_speed_along_the_command_clipped_at_it() -> None:
    cmd = np.array([[0.5, 0.0]] * 5 + [[0.3, 0.4]] * 3 + [[0.05, 0.0]])
    v = np.array(
        [[0.25, 0.0], [1.0, 0.0], [-0.3, 0.0], [0.0, 0.5], [0.0, 0.0]]  # half, over, back, across, still
        + [[0.3, 0.4], [0.6, 0.8], [0.4, 0.3]]  # exact, twice, off-axis (0.24 / 0.25)
        + [[0.05, 0.0]]  # a command under 0.1 m/s pays nothing
    )
    np.testing.assert_allclose(rt.track_progress(cmd, v), [0.5, 1.0, 0.0, 0.0, 0.0, 1.0, 1.0, 0.96, 0.0])
    np.testing.assert_allclose(rt.track_progress(cmd[-1:], v[-1:], min_cmd=0.01), [1.0])


def test_thigh_clearance_shortfall_ramps_from_the_margin_to_one_at_contact() -> None:
    gap = np.array([[0.10, 0.05], [0.025, 0.0], [-0.01, 0.04]])  # m, thighs L and R
    np.testing.assert_allclose(rt.thigh_clearance_shortfall(gap, 0.05), [0.0, 1.5, 1.2])
