"""Training presets: one registry entry per named factory; the paper's sizes and method."""

import pytest

from tron1cli.config.presets import PRESETS, make_preset
from tron1cli.env.randomization import ALL_TERMS, PushConfig


def test_registry_holds_the_named_factories():
    assert list(PRESETS) == ["flat", "perceptive", "teacher", "paper"]
    for name, factory in PRESETS.items():
        assert factory().name == name and factory() == factory()  # fresh, equal copies
    with pytest.raises(ValueError, match="choose from flat, perceptive, teacher, paper"):
        make_preset("fast")


def test_paper_preset_is_the_papers_method_and_sizes():
    p = make_preset("paper")
    assert (p.num_envs, p.steps_per_env, p.iterations, p.teacher_ratio) == (2048, 24, 10_000, 0.5)
    assert not p.gait_prior and dict(p.critic_weights) == {} and p.ablation == "none"
    assert p.perception and p.terrain == "mixed"
    assert p.randomization.terms == ALL_TERMS and p.pushes == PushConfig.moderate()


def test_teacher_stage_is_the_perceptive_preset_with_every_env_a_teacher():
    t, p = make_preset("teacher"), make_preset("perceptive")
    assert t.teacher_ratio == 1.0 and p.teacher_ratio == 0.5
    assert (t.perception, t.randomization, t.pushes, t.terrain) == (
        p.perception,
        p.randomization,
        p.pushes,
        p.terrain,
    )


def test_flat_preset_is_the_quick_start():
    p = make_preset("flat")
    assert p.terrain == "flat" and p.gait_prior and dict(p.critic_weights) == {"stable": 0.25}
    assert dict(p.reward_weights) == {"flat_orientation": -5.0, "track_lin_l2": 1.0}
    assert dict(p.reward_ramps) == {"track_lin_l2": (150, 200)} and not make_preset("perceptive").reward_ramps
    assert dict(make_preset("perceptive").critic_weights) == {"stable": 0.5}
    assert not p.perception and not p.randomization.terms and not p.pushes.enabled
    assert (p.num_envs, p.steps_per_env, p.iterations, p.epochs) == (512, 12, 600, 3)
    q = make_preset("perceptive")
    assert (q.num_envs, q.steps_per_env, q.iterations, q.epochs) == (1024, 24, 300, 5)


@pytest.mark.parametrize(
    "field, value", [("num_envs", 1), ("iterations", 0), ("steps_per_env", 0), ("epochs", 0)]
)
def test_a_preset_refuses_sizes_that_train_nothing(field, value):
    from dataclasses import replace

    with pytest.raises(ValueError, match="a preset needs"):
        replace(make_preset("flat"), **{field: value})
