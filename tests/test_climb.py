"""Learning to climb: the climb probe, the teacher stage, the terrain mix and the swing apex."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from tests.conftest import lab_tool, tron1
from tests.test_bad_input import one_error_line
from tron1cli.config import EnvConfig
from tron1cli.env.curriculum import RULES, EpisodeEnds, TerrainCurriculum, deal_types
from tron1cli.env.rewards import RewardConfig, swing_apex_m, with_settings
from tron1cli.env.terrain import TerrainBank, TerrainConfig, highest_ground_height, riser_m
from tron1cli.evaluation.climb import fall_shares, risers_climbed


def test_equal_shares_deal_round_robin():
    assert deal_types(14, np.ones(7)).tolist() == [i % 7 for i in range(14)]


def test_shares_are_met_and_interleaved():
    shares = np.array([4, 2, 1, 1, 1, 1, 0])
    kind = deal_types(1000, shares)
    assert np.bincount(kind, minlength=7).tolist() == [400, 200, 100, 100, 100, 100, 0]
    for block in (kind[:500], kind[500:]):  # teachers and students get the same mix, within one env
        assert np.abs(np.bincount(block, minlength=7) - 500 * shares / shares.sum()).max() <= 1.0


def test_curriculum_deals_types_by_the_mix():
    cfg = TerrainConfig(tile_size_m=2.0, num_levels=3, variants_per_level=1)
    bank = TerrainBank(("flat", "stairs_up"), cfg, seed=0)
    cur = TerrainCurriculum(bank, 8, np.random.default_rng(0), max_init_level=2, shares=np.array([1.0, 3.0]))
    assert cur.kind.tolist().count(1) == 6
    assert np.all(bank.kind[cur.tile] == cur.kind) and np.all(bank.level[cur.tile] == cur.level)


def _three_ends() -> EpisodeEnds:
    """Env 0 walked far, env 1 stood and survived, env 2 fell on the spot (10 m commanded each)."""
    return EpisodeEnds(
        distance=np.array([4.0, 0.1, 0.1]), commanded=np.full(3, 10.0), fell=np.array([False, False, True])
    )


@pytest.mark.parametrize("rule,levels", [("distance", [6, 4, 4]), ("falls", [6, 5, 4])])
def test_curriculum_rules_move_levels(rule, levels):
    bank = TerrainBank(("stairs_up",))
    cur = TerrainCurriculum(bank, 3, np.random.default_rng(0), rule=rule)
    cur.level[:] = 5
    cur.tile[:] = bank.tile_index(cur.kind, cur.level, np.zeros(3, int))
    cur.update(np.arange(3), _three_ends())
    assert cur.level.tolist() == levels
    assert (bank.level[cur.tile] == cur.level).all()


def test_the_uniform_rule_draws_every_level_whatever_the_episode():
    bank = TerrainBank(("stairs_up",), TerrainConfig(tile_size_m=2.0, num_levels=4, variants_per_level=1))

    def levels_drawn(seed: int, episodes: int = 40) -> list[list[int]]:
        cur = TerrainCurriculum(bank, 3, np.random.default_rng(seed), rule="uniform")
        drawn = []
        for _ in range(episodes):
            cur.update(np.arange(3), _three_ends())
            assert (bank.level[cur.tile] == cur.level).all()
            drawn.append(cur.level.tolist())
        return drawn

    assert levels_drawn(1) == levels_drawn(1)  # the same seed draws the same levels
    assert {lv for levels in levels_drawn(2) for lv in levels} == {0, 1, 2, 3}


def test_a_level_floor_holds_its_type_up_and_leaves_the_others():
    cfg = TerrainConfig(tile_size_m=2.0, num_levels=6, variants_per_level=1)
    bank = TerrainBank(("flat", "stairs_up"), cfg, seed=0)
    cur = TerrainCurriculum(bank, 6, np.random.default_rng(0), floors=[0, 3])
    up = cur.kind == 1
    assert (cur.level[up] == 3).all() and (cur.level[~up] == 0).all()  # started on the floor
    fell = EpisodeEnds(distance=np.zeros(6), commanded=np.full(6, 10.0), fell=np.ones(6, bool))
    cur.level[:] = 4
    cur.update(np.arange(6), fell)
    cur.update(np.arange(6), fell)  # two demotions: 4 -> 3 -> 3 on stairs up, 4 -> 2 on flat
    assert (cur.level[up] == 3).all() and (cur.level[~up] == 2).all()
    assert (bank.level[cur.tile] == cur.level).all()
    cur.level[:] = 1  # levels restored from a run without the floor
    cur.lift_to_floor()
    assert (cur.level[up] == 3).all() and (cur.level[~up] == 1).all()
    assert (bank.level[cur.tile[up]] == 3).all()


@pytest.mark.parametrize(
    "floor,text",
    [
        ({"lava": 3}, "'lava' is not a type of 'stairs'"),
        ({"stairs_up": 10}, "stairs_up=10 is not a level in 0..9"),
        ({"stairs_up": float("inf")}, "stairs_up=inf is not a level in 0..9"),
    ],
)
def test_a_bad_level_floor_is_refused(floor, text):
    with pytest.raises(ValueError, match=text):
        EnvConfig(terrain="stairs", level_floor=floor)


def test_an_unknown_curriculum_rule_is_refused():
    with pytest.raises(ValueError, match="rule 'lava'; choose from distance, falls, uniform"):
        EnvConfig(terrain="stairs", curriculum_rule="lava")
    assert set(RULES) == {"distance", "falls", "uniform"}


@pytest.mark.parametrize(
    "mix,text",
    [
        ({"lava": 1.0}, "'lava' is not a type of 'mixed'"),
        ({"stairs_up": -1.0}, "not a finite number >= 0"),
        ({"stairs_up": 0.0}, "every share is 0"),
        ({"flat": 1.0}, "'flat' is not a type of 'stairs'"),
    ],
)
def test_a_bad_terrain_mix_is_refused(mix, text):
    terrain = "stairs" if "flat" in mix else "mixed"
    with pytest.raises(ValueError, match=text):
        EnvConfig(terrain=terrain, terrain_mix=mix)


def test_type_shares_in_bank_order():
    cfg = EnvConfig(terrain="stairs", terrain_mix={"stairs_down": 1.0, "stairs_up": 3.0})
    assert cfg.type_shares() == [3.0, 1.0]
    assert EnvConfig(terrain="stairs").type_shares() is None


def test_swing_apex_rises_with_the_level_hand_computed():
    level = np.array([0, 9, 3])
    flat = swing_apex_m(RewardConfig(), level, 10)
    assert flat.shape == (3, 1) and np.allclose(flat, 0.1)
    rising = swing_apex_m(with_settings(RewardConfig(), {"gait_clearance_top_m": 0.2}), level, 10)
    assert np.allclose(rising[:, 0], [0.1, 0.2, 0.1 + 0.1 * 3 / 9])


def test_reward_settings_refuse_unknown_names_and_bad_lengths():
    with pytest.raises(ValueError, match="unknown reward setting 'gait_height'"):
        with_settings(RewardConfig(), {"gait_height": 0.2})
    with pytest.raises(ValueError, match="gait_clearance_top_m must be a positive length"):
        with_settings(RewardConfig(), {"gait_clearance_top_m": -0.2})
    cfg = with_settings(RewardConfig(), {"gait_clearance_top_m": 0.2})
    assert RewardConfig.from_dict(cfg.to_dict()) == cfg  # saved with the run and read back


def test_highest_ground_sees_the_tread_above_a_nearby_riser():
    """A 0.2 m step up at x = 0.05 m (columns right of the centre) on a 0.05 m grid: a foot 0.1 m
    before the riser sees the lower tread under it, the upper one within a 0.15 m reach."""
    heights = np.zeros((1, 21, 21), dtype=np.float32)
    heights[0, :, 11:] = 0.2
    xy = np.array([[-0.1, 0.0], [-0.3, 0.0], [0.2, 0.1]])
    tile = np.zeros(3, dtype=np.int64)
    np.testing.assert_allclose(highest_ground_height(heights, tile, xy, 0.05, 0.0), [0.0, 0.0, 0.2])
    np.testing.assert_allclose(highest_ground_height(heights, tile, xy, 0.05, 0.15), [0.2, 0.0, 0.2])


def test_clearance_reach_is_a_reward_setting_and_refused_out_of_range():
    cfg = with_settings(RewardConfig(), {"gait_clearance_reach_m": 0.15})
    assert cfg.gait_clearance_reach_m == 0.15
    assert RewardConfig.from_dict(cfg.to_dict()).gait_clearance_reach_m == 0.15
    assert "gait_clearance_reach_m" not in RewardConfig().to_dict()  # older runs' configs unchanged
    with pytest.raises(ValueError, match=r"gait_clearance_reach_m must lie in \[0, 1\) m"):
        with_settings(RewardConfig(), {"gait_clearance_reach_m": -0.1})


def test_riser_heights_of_the_probe_levels():
    cfg = TerrainConfig()
    assert [round(riser_m(cfg, lv), 6) for lv in (0, 3, 6, 9)] == [0.02, 0.08, 0.14, 0.2]


def test_risers_climbed_hand_computed():
    # 0 m: none; 0.19 m over 0.2 m risers: one (the base over the edge reads part of a riser);
    # 0.41 m: two; 0.09 m: none
    assert risers_climbed(np.array([0.0, 0.19, 0.41, 0.09]), 0.2) == pytest.approx(0.75)


def test_fall_shares_hand_computed():
    # columns tilt, base, thigh_L, thigh_R; env 1 tilted onto its base, env 2 on both thighs,
    # env 3 on one thigh, env 0 survived: a thigh counts once per env
    causes = np.array(
        [[0, 0, 0, 0], [1, 1, 0, 0], [0, 0, 1, 1], [0, 0, 0, 1]],
        dtype=bool,
    )
    assert fall_shares(causes) == (0.25, 0.25, 0.5)


@pytest.fixture(scope="module")
def teacher_stage_ckpt(tmp_path_factory):
    """One iteration of the teacher stage (every env a teacher) on stairs with perception."""
    from tron1cli.config import GaitConfig
    from tron1cli.learn import LearnerConfig
    from tron1cli.train.runner import RunConfig, Trainer

    run = tmp_path_factory.mktemp("teacher_stage")
    env = EnvConfig(num_envs=4, nthread=1, terrain="stairs", perception=True, depth_from=4, gait=GaitConfig())
    learner = replace(
        LearnerConfig(),
        num_steps_per_env=4,
        actor_hidden=(32,),
        critic_hidden=(32,),
        rec_batch_envs=4,
        teacher_ratio=1.0,
    )
    trainer = Trainer(run, RunConfig(env=env, learner=learner, iterations=1))
    trainer.run()
    trainer.close()
    return run / "checkpoints" / "latest.pt"


def test_the_probe_scores_teacher_and_student(tiny_ckpt_vision, tmp_path):
    r = tron1(
        "eval",
        str(tiny_ckpt_vision),
        "--climb",
        "--envs",
        "2",
        "--steps",
        "5",
        "--json",
        "--out",
        str(tmp_path),
    )
    assert r.returncode == 0, r.stderr
    report = json.loads(r.stdout)
    rows = report["rows"]
    assert [(x["actor"], x["level"]) for x in rows] == [
        (a, lv) for a in ("teacher", "student") for lv in (3, 6, 9)
    ]
    assert [round(x["riser_m"], 6) for x in rows[:3]] == [0.08, 0.14, 0.2]
    for x in rows:
        assert 0.0 <= x["success"] <= 1.0 and x["risers"] >= 0.0
    assert json.loads((tmp_path / "climb.json").read_text()) == report
    assert (tmp_path / "climb.csv").read_text().splitlines()[0].startswith("actor,level,riser_m")


def test_a_teacher_stage_checkpoint_has_no_student(teacher_stage_ckpt, tmp_path):
    r = tron1("eval", str(teacher_stage_ckpt), "--climb", "--envs", "2", "--steps", "3", "--json")
    assert r.returncode == 0, r.stderr
    assert [x["actor"] for x in json.loads(r.stdout)["rows"]] == ["teacher"] * 3
    assert "teacher-stage checkpoint" in r.stderr
    one_error_line(
        tron1("export-onnx", str(teacher_stage_ckpt), "-o", str(tmp_path / "x.onnx")),
        1,
        "teacher-stage checkpoint (no student was trained)",
    )


@pytest.mark.parametrize(
    "args,text",
    [
        (["--climb", "--terrain", "flat"], "--climb sets its own terrain and levels"),
        (["--climb", "--actor", "coach"], "unknown --actor 'coach'"),
    ],
)
def test_probe_options_refused(tiny_ckpt_vision, args, text):
    one_error_line(tron1("eval", str(tiny_ckpt_vision), *args), 2, text)


@pytest.mark.parametrize(
    "args,text",
    [
        (["--terrain", "mixed", "--terrain-mix", "lava=1"], "'lava' is not a type of 'mixed'"),
        (["--terrain", "mixed", "--terrain-mix", "stairs_up"], "--terrain-mix wants TYPE=NUMBER pairs"),
        (["--terrain", "stairs", "--init-level", "10"], "max_init_level must lie in 0..9"),
        (["--terrain", "stairs", "--reward-settings", "apex=1"], "unknown reward setting 'apex'"),
        (["--terrain", "stairs", "--curriculum-rule", "lava"], "unknown curriculum rule 'lava'"),
        (["--terrain", "stairs", "--init-std", "0.4"], "--init-std sets the action std over --init's"),
        (["--terrain", "stairs", "--init-std", "0"], "Invalid value for '--init-std'"),
        (["--terrain", "stairs", "--level-floor", "stairs_up=2.5"], "stairs_up=2.5 is not a whole level"),
        (["--terrain", "stairs", "--level-floor", "stairs_up"], "--level-floor wants TYPE=LEVEL pairs"),
        (["--terrain", "stairs", "--level-floor", "stairs_up=inf"], "stairs_up=inf is not a whole level"),
        (["--terrain", "stairs", "--level-floor", "stairs_up=nan"], "stairs_up=nan is not a whole level"),
        (["--terrain", "stairs", "--level-floor", "lava=1"], "'lava' is not a type of 'stairs'"),
        (["--terrain", "stairs", "--swing-fold", "0.5"], "--swing-fold wants two angles HIP,KNEE"),
        (["--terrain", "stairs", "--no-gait-prior", "--swing-fold", "0.5,0.8"], "needs the gait prior"),
        (
            ["--terrain", "stairs", "--swing-fold-keep", "0.5"],
            "a kept share of the swing fold needs a swing fold",
        ),
        (
            ["--terrain", "stairs", "--swing-fold", "0.5,0.8", "--swing-fold-keep", "2"],
            "must lie in [0, 1], got 2",
        ),
        (
            ["--terrain", "stairs", "--swing-fold", "0.5,0.8", "--swing-fold-keep", "nan"],
            "must lie in [0, 1], got nan",
        ),
        (["--terrain", "stairs", "--terminate-on", "knee"], "choose one or more of base, thigh_L, thigh_R"),
        (["--terrain", "stairs", "--terminate-on", ","], "each once; got (none)"),
        (["--terrain", "stairs", "--terminate-on", "base,base"], "each once; got base,base"),
    ],
)
def test_climb_training_options_refused(tmp_path, args, text):
    one_error_line(tron1("train", *args, "--run-dir", str(tmp_path / "r")), 2, text)


def test_a_policy_trained_on_a_terrain_mix_is_evaluated_on_one_type(tmp_path):
    run = tmp_path / "mix"
    r = tron1(
        "train", "--terrain", "stairs", "--terrain-mix", "stairs_up=3,stairs_down=1", "--init-level", "9",
        "--face-climb", "--heading", "--heading-spread", "30", "--level-floor", "stairs_up=2",
        "--swing-fold", "0.5,0.8",
        "--swing-fold-keep", "0.5",
        "--gait-freq-range", "2,2.5", "--terminate-on", "base", "--envs", "4", "--iterations", "1",
        "--steps-per-env", "2", "--hidden", "16",
        "--run-dir", str(run),
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    header = " ".join(r.stderr.split())
    assert (
        "tron1 train stairs (mix stairs_up=3, stairs_down=1; starting on levels 0-9; level floor "
        "stairs_up=2; commands facing the climb; heading commands within 30 deg; swing fold hip 0.5, "
        "knee 0.8 rad; "
        "0.5 of the fold kept; "
        "gait clock 2-2.5 Hz; falls on base contact), "
        "4 envs" in header
    )
    saved = json.loads((run / "config.json").read_text())["env"]
    assert saved["terrain_mix"] == {"stairs_up": 3.0, "stairs_down": 1.0} and saved["max_init_level"] == 9
    assert saved["commands"]["face_climb"] is True and saved["commands"]["heading"] is True
    assert saved["commands"]["heading_spread_rad"] == pytest.approx(math.radians(30))
    assert saved["level_floor"] == {"stairs_up": 2}
    assert saved["gait"]["swing_fold_rad"] == [0.5, 0.8] and saved["gait"]["swing_fold_keep"] == 0.5
    assert saved["gait"]["freq_hz"] == [2.0, 2.5] and saved["termination"]["bodies"] == ["base"]
    from tron1cli.evaluation.protocol import EvalSpec, make_env
    from tron1cli.policy.runtime import load_policy

    # the probe draws the training commands: facing the climb on the stairs under test
    env = make_env(
        load_policy(str(run / "checkpoints" / "latest.pt"), actor="teacher"),
        EvalSpec("stairs_up", 9, 64, 2, True),
    )
    assert env.cfg.termination.bodies == ("base", "thigh_L", "thigh_R")  # judged by every body
    env.reset()
    flat = make_env(load_policy(str(run / "checkpoints" / "latest.pt")), EvalSpec("flat", 0, 2, 2, True))
    flat.close()  # a floor on stairs up does not stop the policy being evaluated on flat ground
    assert env.commands.facing.all() and (env.commands.value[:, 0] >= 0).all()
    assert (env.commands.value[:, 1] == 0).all()
    env.close()
    r = tron1(
        "eval",
        str(run / "checkpoints" / "latest.pt"),
        "--climb",
        "--actor",
        "teacher",
        "--envs",
        "1",
        "--steps",
        "2",
    )
    assert r.returncode == 0, r.stderr


def test_gait_by_speed_reports_a_walking_teacher(teacher_stage_ckpt):
    from tron1cli.policy.runtime import load_policy

    tool = lab_tool("gait_by_speed")
    row = tool.gait_at_speed(load_policy(str(teacher_stage_ckpt), actor="teacher"), 3, 0.5, envs=2, steps=5)
    assert set(row) == set(tool.COLUMNS)
    assert 0.0 <= row["survival"] <= 1.0 and row["risers"] >= 0.0
    assert 0.5 < row["base_height_m"] < 1.0  # 5 steps after reset the robot still stands


def test_falls_by_command_splits_the_whole_exposure(teacher_stage_ckpt):
    tool = lab_tool("falls_by_command")
    rows = tool.falls_by_command(str(teacher_stage_ckpt), 9, envs=3, steps=40)
    assert [r[0] for r in rows] == [label for label, _ in tool.BANDS]
    exposure, falls = sum(r[1] for r in rows), sum(r[2] for r in rows)
    assert 0.0 < exposure <= 3 * 40 * 0.02 + 1e-9 and 0 <= falls <= 3


def test_climb_at_speed_scores_one_fixed_command(teacher_stage_ckpt):
    tool = lab_tool("climb_at_speed")
    row = tool.climb_at_speed(str(teacher_stage_ckpt), 0.5, 9, envs=3, steps=40)
    assert 0.0 <= row.traverse <= row.success <= 1.0  # a traverse is a success
    assert row.risers >= 0.0 and row.progress is not None  # every env was asked to walk
    assert all(0.0 <= f <= 1.0 - row.success + 1e-9 for f in (row.fell_tilt, row.fell_base, row.fell_thigh))


def test_climb_by_term_scores_each_term_alone(teacher_stage_ckpt):
    tool = lab_tool("climb_by_term")
    sets = tool.term_sets()
    labels = [label for label, _, _ in sets]
    assert labels[:4] == ["none", "all", "all + pushes", "pushes"]
    assert "restitution" in labels and not any(label.startswith("camera") for label in labels)
    skipped = tool.term_sets(("restitution",))
    assert "restitution" not in [label for label, _, _ in skipped] and "restitution" not in skipped[1][1]
    rows = tool.climb_by_term(str(teacher_stage_ckpt), 3, envs=2, steps=5)
    assert [label for label, _ in rows] == labels
    for _, row in rows:
        assert 0.0 <= row.traverse <= row.success <= 1.0 and row.risers >= 0.0


def test_latent_swap_variants_are_the_student_and_the_teacher_at_the_ends(tiny_ckpt_vision):
    from tron1cli.evaluation.protocol import EvalSpec, make_env
    from tron1cli.policy.runtime import load_policy

    tool = lab_tool("latent_swap")
    student, teacher = load_policy(tiny_ckpt_vision), load_policy(tiny_ckpt_vision, "teacher")
    env = make_env(student, EvalSpec("stairs_up", 6, num_envs=3, steps=10))
    try:
        obs, hidden = env.reset(), student.initial_hidden(3)
        for _ in range(3):  # a few steps: the GRU state and the history are no longer zeros
            action, hidden, _ = student.act(obs, hidden)
            obs = env.step(action).obs
    finally:
        env.close()
    acts = {
        name: tool.swapped(str(tiny_ckpt_vision), e, h).act(obs, hidden)
        for name, (e, h) in tool.VARIANTS.items()
    }
    own, own_hidden, _ = student.act(obs, hidden)
    np.testing.assert_allclose(acts["student"][0], own, atol=1e-5)
    np.testing.assert_allclose(acts["student"][1], own_hidden, atol=1e-5)
    np.testing.assert_allclose(acts["teacher"][0], teacher.act(obs, hidden)[0], atol=1e-5)
    for name in ("student+true_h", "student+true_e", "student+reencoded_h"):  # a swap changes the action
        assert not np.allclose(acts[name][0], own, atol=1e-6)
        np.testing.assert_allclose(acts[name][1], own_hidden, atol=1e-5)  # the GRU advances alike
    policy = tool.swapped(str(tiny_ckpt_vision), False, "true")
    success, traverse, progress, risers = tool.swap_row(policy, EvalSpec("discrete", 2, num_envs=2, steps=10))
    assert 0.0 <= traverse <= success <= 1.0 and progress is not None
    assert risers is None  # risers are counted on stairs up only
