"""PNG plots and the threshold times read off a run's metrics."""

import json

import pytest

from tron1cli.viz.plots import (
    campaign_curves,
    first_reached,
    push_survival,
    success_by_speed,
    training_curves,
)


def _rows():
    # (wall s, survival, tracking error): survival >= 0.9 first at 120 s, error <= 0.3 first at 180 s
    pts = [(60, 0.5, 0.6), (120, 0.92, 0.4), (180, 0.85, 0.28), (240, 0.95, 0.25)]
    return [{"wall_s": w, "student/survival": s, "student/vel_tracking_error": e} for w, s, e in pts]


def test_first_reached_hand_computed():
    assert first_reached(_rows()) == {"survival_min": 2.0, "tracking_min": 3.0, "both_min": 4.0}
    assert first_reached(_rows()[:2])["tracking_min"] is None


def test_plots_write_pngs(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    rows = [
        r | {"env_steps": 1000 * i, "terrain/level/stairs_up": i, "learn/heightmap_err_cm": 5.0 - i}
        for i, r in enumerate(_rows())
    ]
    (run / "metrics.jsonl").write_text("\n".join(json.dumps(r) for r in rows))
    pngs = [
        training_curves({"a": run}, tmp_path / "curves.png", mark=3.0),
        training_curves({"a": run}, tmp_path / "steps.png", x="env_steps"),
        success_by_speed(
            {"a": {0.5: {"mean": 0.9, "std": 0.1}, 1.0: {"mean": 0.5, "std": None}}}, tmp_path / "s.png"
        ),
        push_survival({"a": {"none": 1.0, "+Fx": 0.5}}, tmp_path / "p.png"),
        campaign_curves(run, tmp_path / "campaign.png", smooth=2),
        campaign_curves([run, run], tmp_path / "phases.png", smooth=2),
        campaign_curves([run, run], tmp_path / "phases_steps.png", smooth=2, x="env_steps"),
    ]
    for p in pngs:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(ValueError, match="x must be"):
        training_curves({"a": run}, tmp_path / "bad.png", x="iterations")
    with pytest.raises(ValueError, match="x must be"):
        campaign_curves(run, tmp_path / "bad.png", x="iterations")


def test_campaign_phases_are_one_cumulative_series(tmp_path):
    from tron1cli.viz.campaign import campaign_phases, campaign_table

    for name, n in (("a", 3), ("b", 2)):
        (tmp_path / name).mkdir()
        rows = [{"iteration": k, "wall_s": 60.0 * k, "env_steps": 10**5 * k} for k in range(1, n + 1)]
        (tmp_path / name / "metrics.jsonl").write_text("\n".join(json.dumps(r) for r in rows))
    rows = campaign_phases([tmp_path / "a", tmp_path / "b"])
    assert [r["wall_s"] for r in rows] == [60.0, 120.0, 180.0, 240.0, 300.0]
    assert [r["env_steps"] for r in rows] == [10**5 * k for k in range(1, 6)]
    assert [r["phase"] for r in rows] == [0, 0, 0, 1, 1]
    table = campaign_table(rows, every_min=2.0, smooth=2).splitlines()
    assert [line.split(" | ")[:4] for line in table[2:]] == [
        ["| 2", "1", "2", "0.2"],
        ["| 4", "2", "1", "0.4"],
        ["| 5", "2", "2", "0.5"],
    ]
