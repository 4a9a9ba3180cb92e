"""The card's Markdown tables, from hand-made eval / push-test / deploy-sim JSON."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tron1cli.evaluation.metric_names import METRICS
from tron1cli.evaluation.paper import PAPER_TABLE_I
from tron1cli.viz.card_tables import (
    SE_NOTE,
    deploy_markdown,
    pushes_markdown,
    ship_tables,
    speeds_markdown,
    table1_markdown,
)

ROOT = Path(__file__).resolve().parents[1]


def _m(mean, std=0.0, n=1) -> dict:
    return {"mean": mean, "std": std, "n": n}


def _eval(results: dict, actor: str = "student", envs: int = 1024) -> dict:
    terrains = list(next(iter(results.values())))
    return {"protocol": {"terrains": terrains, "envs": envs, "actor": actor}, "results": results}


def _rows(text: str) -> list[list[str]]:
    rows = [line for line in text.splitlines() if line.startswith("|")][2:]
    return [[c.strip() for c in line.strip("|").split("|")] for line in rows]


def test_paper_table_names_our_metrics_and_terrains():
    assert list(PAPER_TABLE_I) == ["stairs", "slopes", "discrete", "rough"]
    for ref in PAPER_TABLE_I.values():
        assert set(ref) <= set(METRICS)
        assert 0.0 < ref["success_rate"][0] < 1.0


def test_table1_one_policy_shows_the_binomial_standard_error_and_the_paper_row():
    per = {"success_rate": _m(0.75), "command_progress": _m(0.6), "reconstruction_error_cm": _m(None)}
    rows = _rows(table1_markdown([_eval({"st": {"stairs": per, "flat": per}})]))
    # sqrt(0.75 * 0.25 / 1024) = 1.35 %; paper terrains first, then the others, paper row under its own
    assert rows[0][:4] == ["stairs", "st (student)", "75.0 (SE 1.4)", "0.60"]
    assert rows[0][-1] == "-"  # a metric without a figure (a blind policy's reconstruction)
    assert rows[1][:3] == ["stairs", "paper (Ours, 3 seeds)", "80.3 ± 4.4"]
    assert rows[1][3] == "-"  # the paper gives no command progress
    assert rows[2][:2] == ["flat", "st (student)"] and len(rows) == 3
    assert table1_markdown([_eval({"st": {"stairs": per}})]).endswith(SE_NOTE)  # what SE stands for


def test_table1_several_policies_show_mean_and_std_and_no_paper_row_when_asked():
    per = {"success_rate": _m(0.5, 0.1, 3)}
    rows = _rows(table1_markdown([_eval({"a": {"rough": per}}, actor="teacher")], paper=False))
    assert rows == [["rough", "a (teacher)", "50.0 ± 10.0", "-", "-", "-", "-", "-", "-"]]


def _speeds_report() -> dict:
    sweep = {"vx": {"unit": "m/s", "results": {"p": {"stairs": {"0.5": _m(0.9), "1": _m(0.4)}}}}}
    progress = {"vx": {"unit": "m/s", "results": {"p": {"stairs": {"0.5": _m(0.7), "1": _m(None)}}}}}
    return {"success_by_speed": sweep, "progress_by_speed": progress}


def test_speeds_table_has_one_column_per_speed():
    text = speeds_markdown([_speeds_report()])
    assert "| terrain | method | vx 0.5 m/s | vx 1 m/s |" in text
    assert "| stairs | p | 90.0 / 0.70 | 40.0 / - |" in text


def _push_report(name: str, terrain: str) -> dict:
    per = {"none": 1.0, "+Fx": 0.25}
    return {
        "protocol": {"name": name, "terrain": terrain},
        "methods": {"p": {"survival_rate": 0.625, "per_push": per}},
    }


def test_pushes_table_rows_per_protocol_and_terrain():
    rows = _rows(pushes_markdown([_push_report("moderate", "stairs"), _push_report("extreme", "flat")]))
    assert rows == [
        ["moderate", "stairs", "p", "62.5", "100", "25"],
        ["extreme", "flat", "p", "62.5", "100", "25"],
    ]


def _deploy() -> dict:
    return {
        "policy": "policies/x.onnx", "terrain_type": "stairs_up", "level": 9, "survived": True,
        "ended": "duration", "duration_s": 10.0, "requested_duration_s": 10.0, "vel_tracking_error": 0.2,
        "reconstruction_error_cm": 3.5, "realtime_factor": 1.5, "depth_rate_hz": 29.96,
        "depth_frames": 300, "depth_dropped": 0, "policy_ms_p50": 0.4, "policy_ms_p99": 0.9,
    }  # fmt: skip


def test_deploy_table():
    text = deploy_markdown(_deploy())
    assert "| survived | yes (duration) |" in text and "| depth rate (Hz) | 30.0 |" in text


def test_deploy_table_of_many_runs():
    """--runs N's JSON: the survival with its interval, each fall, and the worst pipeline figures."""
    from tron1cli.deploy.runs import runs_summary

    fell = {**_deploy(), "seed": 3, "survived": False, "ended": "fell", "fell_by": "base", "duration_s": 3.5}
    reps = [{**_deploy(), "seed": 2, "fell_by": None, "depth_age_ms_p99": 40.0}, fell]
    for r in reps:
        r["terrain"] = "stairs_up"
    text = deploy_markdown({"summary": runs_summary(reps), "runs": reps})
    assert "| runs | x.onnx, stairs_up level 9, 2 runs of 10 s (seeds 2-3) |" in text
    # Wilson, 1 of 2: centre (0.5 + 0.9604) / 2.9208 = 0.5, half 1.96 * sqrt(0.125 + 0.2401) / 2.9208
    assert "| survived (95 % Wilson interval) | 1 of 2 (50%; 9%-91%) |" in text
    assert "| falls (seed, time, cause) | seed 3 at 3.50 s (base) |" in text
    assert "| depth frame age p99, worst run (ms of sim time) | 40.0 |" in text


def test_ship_tables_names_what_is_not_run_yet_and_refuses_a_corrupt_file(tmp_path):
    (tmp_path / "table1_student").mkdir()
    per = {"success_rate": _m(0.5)}
    (tmp_path / "table1_student" / "results.json").write_text(json.dumps(_eval({"s": {"discrete": per}})))
    (tmp_path / "deploy_sim_stairs.json").write_text(json.dumps(_deploy()))
    text = ship_tables(tmp_path)
    assert "| discrete | s (student) | 50.0 (SE 1.6) |" in text
    assert f"(not yet run: {tmp_path / 'table1_teacher' / 'results.json'}, " in text
    assert f"(not yet run: {tmp_path / 'climb' / 'climb.json'})" in text
    assert "| real-time factor | 1.50 |" in text
    (tmp_path / "deploy_sim_stairs.json").write_text('{"policy": "x"}')
    with pytest.raises(ValueError, match="deploy_sim_stairs.json: not the output"):
        ship_tables(tmp_path)


def test_card_tables_tool_writes_tables_md_and_fails_in_one_line(tmp_path):
    tool = [sys.executable, str(ROOT / "tools" / "card_tables.py")]
    ok = subprocess.run([*tool, str(tmp_path)], capture_output=True, text=True)
    assert ok.returncode == 0 and "### Table I" in ok.stdout
    assert (tmp_path / "tables.md").read_text() == ok.stdout
    bad = subprocess.run([*tool, str(tmp_path / "nope")], capture_output=True, text=True)
    assert bad.returncode == 1 and bad.stderr.strip().count("\n") == 0 and "no such folder" in bad.stderr


def test_cells_hand_computed():
    from tron1cli.viz.cells import mean_std, speed_cell

    one = {"mean": 0.551, "std": 0.0, "n": 1}
    two = {"mean": 0.5, "std": 0.025, "n": 2}
    assert (
        mean_std(two, True) == "50.0 ± 2.5"
        and mean_std({"mean": 0.2346, "std": 0.01, "n": 2}, False) == "0.235 ± 0.010"
    )
    assert mean_std({"mean": None, "std": None, "n": 0}, True) == "-"
    assert speed_cell(one, {"mean": 0.624, "std": 0.0, "n": 1}) == "55.1 / 0.62"
    assert speed_cell(two, {"mean": 0.6, "std": 0.05, "n": 2}) == "50.0 ± 2.5 / 0.600 ± 0.050"
    assert speed_cell(one, None) == "55.1 / -" and speed_cell(None, None) == "-"
