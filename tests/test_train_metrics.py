"""Training statistics: the rolling episode windows, what enters them, and their round trip
through a checkpoint."""

import io

import numpy as np
import pytest
import torch

from tron1cli.train.metrics import EpisodeStats


def test_staggered_episodes_are_left_out_of_training_statistics():
    stats = EpisodeStats()
    episode = {
        "time_out": np.array([True, True, False, True]),
        "length_s": np.array([0.5, 20.0, 3.0, 1.0]),
        "staggered": np.array([True, False, False, True]),
        "reward/alive": np.array([0.25, 10.0, 1.5, 0.5]),
    }
    stats.add_episodes(np.arange(4), episode, n_teacher=2)
    out = stats.summary()
    assert out["teacher/survival"] == 1.0 and out["teacher/episode_length_s"] == 20.0
    assert out["student/survival"] == 0.0 and out["student/episode_length_s"] == 3.0
    assert out["episode_reward/alive"] == pytest.approx(5.75) and stats.episodes == 4


def test_the_rolling_window_survives_a_checkpoint_round_trip():
    stats = EpisodeStats(window=3)
    episode = {
        "time_out": np.array([True, False, True, True, False]),
        "length_s": np.array([20.0, 1.5, 20.0, 20.0, 4.0]),
        "staggered": np.zeros(5, dtype=bool),
    }
    stats.add_episodes(np.array([0, 1, 4, 5, 6]), episode, n_teacher=3)  # teachers 0, 1; students 4-6
    before = stats.summary()
    buf = io.BytesIO()
    torch.save(stats.state_dict(), buf)
    buf.seek(0)
    again = EpisodeStats(window=3)
    again.load_state_dict(torch.load(buf, weights_only=True))
    after = again.summary()
    for g in ("teacher", "student"):
        for figure in ("survival", "episode_length_s"):
            assert after[f"{g}/{figure}"] == before[f"{g}/{figure}"]
    assert before["teacher/survival"] == 0.5 and before["student/survival"] == pytest.approx(2 / 3)


def test_falls_per_minute_count_this_iterations_falls_over_its_robot_time():
    """Hand count: 2 teachers and 3 students stepped 50 times at 0.02 s (teachers 2 robot-seconds,
    students 3); one teacher fell (a staggered episode: still a fall of this policy), one student
    fell, one timed out."""
    stats = EpisodeStats(step_s=0.02)
    for _ in range(50):
        stats.add_step(np.full(5, 0.1), n_teacher=2)
    episode = {
        "time_out": np.array([False, False, True]),
        "length_s": np.array([0.5, 3.0, 20.0]),
        "staggered": np.array([True, False, False]),
    }
    stats.add_episodes(np.array([1, 3, 4]), episode, n_teacher=2)
    out = stats.summary()
    assert out["teacher/falls_per_min"] == pytest.approx(1 / (2.0 / 60.0))
    assert out["student/falls_per_min"] == pytest.approx(1 / (3.0 / 60.0))
    assert out["student/vel_tracking_error"] == pytest.approx(0.1)
    again = stats.summary()  # a new iteration starts from zero
    assert np.isnan(again["teacher/falls_per_min"]) and np.isnan(again["student/falls_per_min"])
